#include "interface/child_process.h"

#include <fcntl.h>
#include <poll.h>
#include <pthread.h>
#include <signal.h>
#include <sys/prctl.h>
#include <sys/resource.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <unistd.h>

#include <fmt/format.h>

#include <algorithm>
#include <cerrno>
#include <cstdlib>
#include <cstring>
#include <stdexcept>
#include <thread>
#include <utility>

namespace tofu::interface {
namespace {

using Clock = ChildProcess::Clock;

constexpr std::size_t kStderrLines = 20;
constexpr std::size_t kStderrLineBytes = 1000;
constexpr auto kInterruptSlice = std::chrono::milliseconds(50);
constexpr auto kTermGrace = std::chrono::milliseconds(200);

std::function<void()>& InterruptCheck() {
  static std::function<void()> check;
  return check;
}
int g_wake_fd = -1;

void CheckInterrupt() {
  if (const std::function<void()>& check = InterruptCheck()) check();
}

// What the child reports through its status pipe when it cannot exec.
struct StartFailure {
  enum Stage : int { kChdir = 1, kExec = 2 } stage;
  int error;
};

// argv[0] on PATH, as execvp would find it; empty when it is nowhere.
std::string FindOnPath(const std::string& name) {
  const char* path = std::getenv("PATH");
  const std::string dirs = path != nullptr ? path : "/usr/local/bin:/usr/bin:/bin";
  std::size_t begin = 0;
  for (;;) {
    const std::size_t end = std::min(dirs.find(':', begin), dirs.size());
    const std::string dir = dirs.substr(begin, end - begin);
    const std::string candidate = (dir.empty() ? std::string(".") : dir) + "/" + name;
    struct stat info;
    if (::stat(candidate.c_str(), &info) == 0 && S_ISREG(info.st_mode) &&
        ::access(candidate.c_str(), X_OK) == 0) {
      return candidate;
    }
    if (end == dirs.size()) return {};
    begin = end + 1;
  }
}

// A descriptor at 3 or above, so that the child's dup2 onto 0, 1, 2 never overwrites one
// still to be moved (tofu may run with a standard stream closed).
int AboveStdio(int fd) {
  if (fd > STDERR_FILENO) return fd;
  const int moved = ::fcntl(fd, F_DUPFD_CLOEXEC, STDERR_FILENO + 1);
  ::close(fd);
  return moved;
}

void SetNonBlocking(int fd) { ::fcntl(fd, F_SETFL, ::fcntl(fd, F_GETFL) | O_NONBLOCK); }

int MillisecondsUntil(Clock::time_point deadline) {
  const auto now = Clock::now();
  if (deadline <= now) return 0;
  const auto ms = std::chrono::ceil<std::chrono::milliseconds>(deadline - now).count();
  return static_cast<int>(std::min<long long>(ms, 1 << 30));
}

// The wait status of a waitid() result, as waitpid() would give it.
int WaitStatusOf(const siginfo_t& info) {
  if (info.si_code == CLD_EXITED) return (info.si_status & 0xff) << 8;
  return (info.si_status & 0x7f) | (info.si_code == CLD_DUMPED ? 0x80 : 0);
}

}  // namespace

std::string ResolveCommand(const std::vector<std::string>& argv,
                           const std::filesystem::path& working_dir) {
  if (argv.empty() || argv[0].empty()) throw std::runtime_error("the command is empty");
  std::error_code ec;
  if (!working_dir.empty() && !std::filesystem::is_directory(working_dir, ec)) {
    const int error = std::filesystem::exists(working_dir, ec) ? ENOTDIR : ENOENT;
    throw std::runtime_error(fmt::format("cannot enter the working directory {}: {}",
                                         working_dir.string(), std::strerror(error)));
  }
  if (argv[0].find('/') == std::string::npos) {
    const std::string program = FindOnPath(argv[0]);
    if (program.empty()) {
      throw std::runtime_error(
          fmt::format("`{}`: command not found (no executable of that name on PATH)", argv[0]));
    }
    return program;
  }
  const std::filesystem::path file =
      argv[0][0] == '/' || working_dir.empty() ? std::filesystem::path(argv[0]) : working_dir / argv[0];
  const std::string where =
      working_dir.empty() ? std::string() : " (working directory " + working_dir.string() + ")";
  struct stat info;
  if (::stat(file.c_str(), &info) != 0) {
    throw std::runtime_error(
        fmt::format("`{}`: cannot execute: {}{}", argv[0], std::strerror(errno), where));
  }
  if (!S_ISREG(info.st_mode)) {
    throw std::runtime_error(
        fmt::format("`{}`: cannot execute: {}{}", argv[0],
                    std::strerror(S_ISDIR(info.st_mode) ? EISDIR : EACCES), where));
  }
  if (::access(file.c_str(), X_OK) != 0) {
    throw std::runtime_error(fmt::format(
        "`{}`: cannot execute: {}{} (chmod +x it, or name its interpreter first: [/usr/bin/python3, "
        "{}])",
        argv[0], std::strerror(errno), where, argv[0]));
  }
  return argv[0];
}

void SetInterruptCheck(std::function<void()> check, int wake_fd) {
  InterruptCheck() = std::move(check);
  g_wake_fd = InterruptCheck() ? wake_fd : -1;
}

long WriteWithoutSigpipe(int fd, const void* data, std::size_t size) {
  sigset_t pipe_only;
  sigset_t previous;
  sigemptyset(&pipe_only);
  sigaddset(&pipe_only, SIGPIPE);
  ::pthread_sigmask(SIG_BLOCK, &pipe_only, &previous);
  // A SIGPIPE already pending (someone else's) must stay pending: only ours is consumed.
  sigset_t pending;
  sigemptyset(&pending);
  ::sigpending(&pending);
  const bool was_pending = sigismember(&pending, SIGPIPE) == 1;
  const ssize_t written = ::write(fd, data, size);
  const int error = errno;
  if (written < 0 && error == EPIPE && !was_pending) {
    const timespec zero{0, 0};
    while (::sigtimedwait(&pipe_only, nullptr, &zero) < 0 && errno == EINTR) {
    }
  }
  ::pthread_sigmask(SIG_SETMASK, &previous, nullptr);
  errno = error;
  return written;
}

// Long by design: pipes, fork, exec and the error path of each, one sequence whose cleanup
// order matters (no descriptor leaked, no child left behind).
ChildProcess::ChildProcess(const std::vector<std::string>& argv,
                           const std::filesystem::path& working_dir) {
  const std::string program = ResolveCommand(argv, working_dir);
  std::vector<char*> args;
  for (const std::string& arg : argv) args.push_back(const_cast<char*>(arg.c_str()));
  args.push_back(nullptr);
  const std::string dir = working_dir.string();

  int in[2], out[2], err[2], status[2];
  if (::pipe2(in, O_CLOEXEC) != 0) throw std::runtime_error(std::strerror(errno));
  if (::pipe2(out, O_CLOEXEC) != 0 || ::pipe2(err, O_CLOEXEC) != 0 ||
      ::pipe2(status, O_CLOEXEC) != 0) {
    throw std::runtime_error(fmt::format("cannot create pipes: {}", std::strerror(errno)));
  }
  for (int* fd : {&in[0], &in[1], &out[0], &out[1], &err[0], &err[1], &status[0], &status[1]}) {
    *fd = AboveStdio(*fd);
  }
  rlimit files{};
  const int max_fd = ::getrlimit(RLIMIT_NOFILE, &files) == 0 && files.rlim_cur != RLIM_INFINITY
                         ? static_cast<int>(std::min<rlim_t>(files.rlim_cur, 1 << 16))
                         : 1 << 16;
  const pid_t parent = ::getpid();

  const pid_t pid = ::fork();
  if (pid == 0) {
    // The child: async-signal-safe calls only, until exec.
    const auto fail = [&](StartFailure::Stage stage) {
      const StartFailure failure{stage, errno};
      [[maybe_unused]] const ssize_t n = ::write(status[1], &failure, sizeof(failure));
      ::_exit(127);
    };
    ::setpgid(0, 0);
    // SIGKILL when tofu dies; tofu may already have died before the request took effect.
    ::prctl(PR_SET_PDEATHSIG, SIGKILL);
    if (::getppid() != parent) ::_exit(127);
    // An ignored SIGPIPE and a blocked mask survive exec: give the client the defaults.
    ::signal(SIGPIPE, SIG_DFL);
    sigset_t none;
    sigemptyset(&none);
    ::sigprocmask(SIG_SETMASK, &none, nullptr);
    ::dup2(in[0], STDIN_FILENO);
    ::dup2(out[1], STDOUT_FILENO);
    ::dup2(err[1], STDERR_FILENO);
    if (!dir.empty() && ::chdir(dir.c_str()) != 0) fail(StartFailure::kChdir);
    // Every other descriptor tofu has open (other clients' pipes, output files) closes on
    // exec; the status pipe too, which tells the parent that exec succeeded.
#ifdef CLOSE_RANGE_CLOEXEC
    if (::close_range(STDERR_FILENO + 1, ~0U, CLOSE_RANGE_CLOEXEC) != 0)
#endif
    {
      for (int fd = STDERR_FILENO + 1; fd < max_fd; ++fd) {
        if (fd != status[1]) ::close(fd);
      }
    }
    ::execv(program.c_str(), args.data());
    fail(StartFailure::kExec);
  }
  const int fork_error = errno;
  for (const int fd : {in[0], out[1], err[1], status[1]}) ::close(fd);
  if (pid < 0) {
    for (const int fd : {in[1], out[0], err[0], status[0]}) ::close(fd);
    throw std::runtime_error(fmt::format("cannot fork: {}", std::strerror(fork_error)));
  }
  pid_ = pid;
  stdin_fd_ = in[1];
  stdout_fd_ = out[0];
  stderr_fd_ = err[0];

  // EOF on the status pipe: exec succeeded (the pipe closed on exec). A report: it failed.
  StartFailure failure{};
  ssize_t n = 0;
  do {
    n = ::read(status[0], &failure, sizeof(failure));
  } while (n < 0 && errno == EINTR);
  ::close(status[0]);
  if (n == static_cast<ssize_t>(sizeof(failure))) {
    Kill();
    const char* reason = std::strerror(failure.error);
    if (failure.stage == StartFailure::kChdir) {
      throw std::runtime_error(
          fmt::format("cannot enter the working directory {}: {}", dir, reason));
    }
    // ENOENT for a file that exists: a script whose #! interpreter does not.
    const std::filesystem::path file = dir.empty() || program[0] == '/' ? std::filesystem::path(program)
                                                                        : working_dir / program;
    std::error_code ec;
    const bool interpreter = failure.error == ENOENT && std::filesystem::exists(file, ec);
    throw std::runtime_error(fmt::format(
        "`{}`: cannot execute: {}{}{}", argv[0], reason,
        interpreter ? " (the file exists: its #! interpreter does not?)" : "",
        dir.empty() ? "" : " (working directory " + dir + ")"));
  }
  for (const int fd : {stdin_fd_, stdout_fd_, stderr_fd_}) SetNonBlocking(fd);
  StartWatchdog(max_fd);
}

// The client's group outlives a SIGKILLed tofu: PR_SET_PDEATHSIG reaches the client alone,
// not what it started. A watchdog joins the client's group and blocks reading a pipe whose
// only write end tofu holds; the end closes when tofu ends, however it ends, and the
// watchdog then kills its group, the client's, itself included. It is /bin/sh (`read`,
// then `kill -9 0`) rather than a bare fork of tofu, which would keep a copy-on-write image
// of tofu's whole memory for as long as the client lives; in the client's group, it
// outlives a signal to tofu's group (a CI's timeout) and keeps the group's id in use, so
// the id cannot pass to another group before it is killed. Without a watchdog (no fork,
// no /bin/sh) the client still has PR_SET_PDEATHSIG.
void ChildProcess::StartWatchdog(int max_fd) {
  int guard[2];
  if (::pipe2(guard, O_CLOEXEC) != 0) return;
  guard[0] = AboveStdio(guard[0]);
  guard[1] = AboveStdio(guard[1]);
  const pid_t group = pid_;
  static char sh[] = "sh", dash_c[] = "-c", script[] = "read line; kill -9 0";
  char* const argv[] = {sh, dash_c, script, nullptr};
  char* const envp[] = {nullptr};
  const pid_t watchdog = ::fork();
  if (watchdog == 0) {
    // Async-signal-safe calls only, until exec: tofu may have other threads. Ignored
    // signals stay ignored across exec: the terminal's reach tofu, not the watchdog.
    for (const int signal : {SIGINT, SIGTERM, SIGHUP, SIGQUIT, SIGPIPE}) ::signal(signal, SIG_IGN);
    // Outside the client's group `kill -9 0` would hit tofu's own: no watchdog then.
    if (::setpgid(0, group) != 0) ::_exit(127);
    if (::dup2(guard[0], STDIN_FILENO) < 0) ::_exit(127);
    // Every other descriptor, other clients' guards included: one kept open here would
    // keep that client's watchdog from ever seeing its end.
    for (int fd = STDIN_FILENO + 1; fd < max_fd; ++fd) ::close(fd);
    ::execve("/bin/sh", argv, envp);
    ::_exit(127);
  }
  ::close(guard[0]);
  if (watchdog < 0) {
    ::close(guard[1]);
    return;
  }
  watchdog_pid_ = watchdog;
  watchdog_fd_ = guard[1];
}

ChildProcess::~ChildProcess() { Kill(); }

void ChildProcess::CloseFd(int* fd) {
  if (*fd >= 0) ::close(*fd);
  *fd = -1;
}

void ChildProcess::CloseStdin() { CloseFd(&stdin_fd_); }

ChildProcess::Exchange ChildProcess::Communicate(std::string_view pending, std::string* received,
                                                 Clock::time_point deadline) {
  Exchange result;
  if (stdout_fd_ < 0) {
    result.stdout_closed = true;
    return result;
  }
  bool wake_fd_live = g_wake_fd >= 0;
  bool first_round = true;
  for (;;) {
    int timeout_ms = MillisecondsUntil(deadline);
    if (timeout_ms > 0) {
      CheckInterrupt();
      if (InterruptCheck()) {
        timeout_ms = std::min<int>(timeout_ms, static_cast<int>(kInterruptSlice.count()));
      }
    } else if (!first_round) {
      return result;
    }
    first_round = false;
    const bool want_write = stdin_fd_ >= 0 && result.written < pending.size();
    pollfd fds[4] = {{want_write ? stdin_fd_ : -1, POLLOUT, 0},
                     {stdout_fd_, POLLIN, 0},
                     {stderr_fd_, POLLIN, 0},
                     {wake_fd_live ? g_wake_fd : -1, POLLIN, 0}};
    if (::poll(fds, 4, timeout_ms) < 0) {
      if (errno == EINTR) continue;
      throw std::runtime_error(fmt::format("poll: {}", std::strerror(errno)));
    }
    if (fds[3].revents != 0) {
      CheckInterrupt();
      wake_fd_live = false;  // the check let it pass: do not spin on a readable fd
    }
    if (fds[0].revents != 0) {
      while (result.written < pending.size()) {
        const long n = WriteWithoutSigpipe(stdin_fd_, pending.data() + result.written,
                                           pending.size() - result.written);
        if (n > 0) {
          result.written += static_cast<std::size_t>(n);
          continue;
        }
        if (n < 0 && errno == EINTR) continue;
        if (n < 0 && errno != EAGAIN) {  // EPIPE: the client closed its standard input
          result.stdin_closed = true;
          CloseFd(&stdin_fd_);
        }
        break;
      }
    }
    if (fds[2].revents != 0) ReadStderr();
    if (fds[1].revents != 0) {
      char buffer[65536];
      // A bounded number of reads per round keeps a chatty client from starving the writes.
      for (int i = 0; i < 16; ++i) {
        const ssize_t n = ::read(stdout_fd_, buffer, sizeof(buffer));
        if (n > 0) {
          received->append(buffer, static_cast<std::size_t>(n));
          result.read += static_cast<std::size_t>(n);
          if (static_cast<std::size_t>(n) < sizeof(buffer)) break;
          continue;
        }
        if (n < 0 && errno == EINTR) continue;
        if (n == 0 || errno != EAGAIN) {
          result.stdout_closed = true;
          CloseFd(&stdout_fd_);
        }
        break;
      }
    }
    if (result.read > 0 || result.stdout_closed) return result;
  }
}

void ChildProcess::ReadStderr() {
  char buffer[16384];
  for (int i = 0; i < 8 && stderr_fd_ >= 0; ++i) {
    const ssize_t n = ::read(stderr_fd_, buffer, sizeof(buffer));
    if (n > 0) {
      AddStderr(std::string_view(buffer, static_cast<std::size_t>(n)));
      continue;
    }
    if (n < 0 && errno == EINTR) continue;
    if (n == 0 || errno != EAGAIN) CloseFd(&stderr_fd_);
    break;
  }
}

void ChildProcess::AddStderr(std::string_view bytes) {
  while (!bytes.empty()) {
    const std::size_t newline = bytes.find('\n');
    const std::string_view part = bytes.substr(0, newline);
    if (stderr_partial_.size() < kStderrLineBytes) {
      stderr_partial_.append(part.substr(0, kStderrLineBytes - stderr_partial_.size()));
    }
    if (newline == std::string_view::npos) return;
    if (!stderr_partial_.empty() && stderr_partial_.back() == '\r') stderr_partial_.pop_back();
    stderr_lines_.push_back(std::move(stderr_partial_));
    stderr_partial_.clear();
    if (stderr_lines_.size() > kStderrLines) stderr_lines_.pop_front();
    bytes.remove_prefix(newline + 1);
  }
}

void ChildProcess::DrainStderr(Clock::time_point deadline) {
  while (stderr_fd_ >= 0) {
    pollfd fd{stderr_fd_, POLLIN, 0};
    const int ready = ::poll(&fd, 1, MillisecondsUntil(deadline));
    if (ready < 0 && errno == EINTR) continue;
    if (ready <= 0) return;
    ReadStderr();
  }
}

std::vector<std::string> ChildProcess::stderr_tail() const {
  std::vector<std::string> tail(stderr_lines_.begin(), stderr_lines_.end());
  if (!stderr_partial_.empty()) tail.push_back(stderr_partial_);
  if (tail.size() > kStderrLines) tail.erase(tail.begin());
  return tail;
}

std::optional<int> ChildProcess::WaitForExit(Clock::time_point deadline) {
  auto sleep = std::chrono::milliseconds(1);
  while (!exit_status_ && pid_ > 0 && !reaped_) {
    siginfo_t info;
    std::memset(&info, 0, sizeof(info));
    // WNOWAIT: the client stays a zombie, so its pid (its group's id) cannot be reused
    // before Kill() has signalled the group.
    if (::waitid(P_PID, static_cast<id_t>(pid_), &info, WEXITED | WNOHANG | WNOWAIT) == 0 &&
        info.si_pid == pid_) {
      exit_status_ = WaitStatusOf(info);
      break;
    }
    const auto now = Clock::now();
    if (now >= deadline) break;
    CheckInterrupt();
    std::this_thread::sleep_for(std::min<Clock::duration>(sleep, deadline - now));
    sleep = std::min(sleep * 2, std::chrono::milliseconds(20));
  }
  return exit_status_;
}

void ChildProcess::Kill() {
  if (pid_ <= 0 || reaped_) return;
  CloseFd(&stdin_fd_);
  const auto signal_group = [this](int signal) {
    // The group reaches what the client started; a client that left it still gets it.
    if (::kill(-pid_, signal) != 0) ::kill(pid_, signal);
  };
  if (!exit_status_) {
    signal_group(SIGTERM);
    const auto deadline = Clock::now() + kTermGrace;
    while (!exit_status_) {
      siginfo_t info;
      std::memset(&info, 0, sizeof(info));
      if (::waitid(P_PID, static_cast<id_t>(pid_), &info, WEXITED | WNOHANG | WNOWAIT) == 0 &&
          info.si_pid == pid_) {
        exit_status_ = WaitStatusOf(info);
        break;
      }
      if (Clock::now() >= deadline) break;
      std::this_thread::sleep_for(std::chrono::milliseconds(2));
    }
  }
  signal_group(SIGKILL);  // whatever of the group is left (the watchdog too), the client
                          // itself if it hung on
  int status = 0;
  // The watchdog's end (it is gone, or kills what is left of the group and exits), reaped
  // before the client: until then the client's pid, the group's id, stays taken.
  CloseFd(&watchdog_fd_);
  if (watchdog_pid_ > 0) {
    while (::waitpid(watchdog_pid_, &status, 0) < 0 && errno == EINTR) {
    }
    watchdog_pid_ = -1;
  }
  pid_t reaped = 0;
  do {
    reaped = ::waitpid(pid_, &status, 0);
  } while (reaped < 0 && errno == EINTR);
  if (reaped == pid_ && !exit_status_) exit_status_ = status;
  reaped_ = true;
  // The last lines it wrote (a traceback) are in the pipe; EOF once the group is gone.
  DrainStderr(Clock::now() + std::chrono::milliseconds(100));
  CloseFd(&stdout_fd_);
  CloseFd(&stderr_fd_);
}

std::string ChildProcess::DescribeExit(int wait_status) {
  if (WIFEXITED(wait_status)) return fmt::format("exited with status {}", WEXITSTATUS(wait_status));
  if (WIFSIGNALED(wait_status)) {
    const int signal = WTERMSIG(wait_status);
    const char* name = ::strsignal(signal);
    return fmt::format("was killed by signal {} ({}){}", signal, name != nullptr ? name : "?",
                       WCOREDUMP(wait_status) ? ", core dumped" : "");
  }
  return fmt::format("ended with wait status {}", wait_status);
}

}  // namespace tofu::interface
