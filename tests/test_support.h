#pragma once
// Small helpers shared by the test files (one place, not a copy per file): substring
// expectations without gmock, whole-file read/write, shell quoting for the tests that
// drive the tofu binary through std::system, and child processes for the tests that
// signal it while it works.

#include <fcntl.h>
#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <cerrno>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <optional>
#include <set>
#include <string>
#include <thread>
#include <vector>

#include <gtest/gtest.h>

#include "core/error.h"

#define EXPECT_CONTAINS(haystack, needle)                          \
  EXPECT_NE(std::string(haystack).find(needle), std::string::npos) \
      << "'" << (haystack) << "' does not contain '" << (needle) << "'"

namespace tofu::test {

/// The core::InputError that `read()` throws; a test failure (and an empty error) when it
/// throws none.
template <typename Read>
core::InputError InputErrorOf(const Read& read) {
  try {
    read();
  } catch (const core::InputError& e) {
    return e;
  }
  ADD_FAILURE() << "expected an InputError";
  return core::InputError({}, "", "");
}

inline std::string ReadFile(const std::filesystem::path& path) {
  std::ifstream in(path, std::ios::binary);
  EXPECT_TRUE(in.good()) << "cannot read " << path;
  return std::string(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
}

inline void WriteFile(const std::filesystem::path& path, const std::string& text) {
  std::ofstream out(path, std::ios::binary);
  out << text;
  ASSERT_TRUE(out.good()) << "cannot write " << path;
}

/// `s` as one single-quoted shell word.
inline std::string Quote(const std::string& s) {
  std::string out = "'";
  for (const char c : s) out += (c == '\'') ? std::string("'\\''") : std::string(1, c);
  return out + "'";
}

/// What a command run by a test printed and returned.
struct CommandResult {
  int exit_code = -1;
  std::string out;
  std::string err;
};

#ifdef TOFU_BINARY
/// `tofu ARGS` run in `cwd` (relative paths of ARGS are relative to it), its standard output
/// and error captured (in cwd/stdout.txt and cwd/stderr.txt).
inline CommandResult RunTofu(const std::string& args, const std::filesystem::path& cwd) {
  const std::string command = "cd " + Quote(cwd.string()) + " && " + Quote(TOFU_BINARY) + " " + args + " >" +
                              Quote((cwd / "stdout.txt").string()) + " 2>" +
                              Quote((cwd / "stderr.txt").string());
  const int status = std::system(command.c_str());
  CommandResult r;
  r.exit_code = WIFEXITED(status) ? WEXITSTATUS(status) : -1;
  r.out = ReadFile(cwd / "stdout.txt");
  r.err = ReadFile(cwd / "stderr.txt");
  return r;
}
#endif

/// A fresh, empty directory for the running test: <gtest temp dir>/<prefix><test>_<pid>
/// (unique per test and per process, so ctest -j never collides).
inline std::filesystem::path PerTestDirectory(const std::string& prefix) {
  const ::testing::TestInfo* info = ::testing::UnitTest::GetInstance()->current_test_info();
  const std::filesystem::path dir =
      std::filesystem::path(::testing::TempDir()) /
      (prefix + info->name() + "_" + std::to_string(::getpid()));
  std::filesystem::remove_all(dir);
  return dir;
}

/// The regular files below `dir`, as paths relative to it.
inline std::set<std::string> FilesIn(const std::filesystem::path& dir) {
  std::set<std::string> names;
  for (const auto& entry : std::filesystem::recursive_directory_iterator(dir)) {
    if (entry.is_regular_file()) names.insert(std::filesystem::relative(entry.path(), dir).string());
  }
  return names;
}

/// Polls `condition` every 5 ms until it holds (true) or `timeout` passed (false).
template <typename Condition>
bool WaitUntil(Condition condition, std::chrono::milliseconds timeout) {
  const auto deadline = std::chrono::steady_clock::now() + timeout;
  while (!condition()) {
    if (std::chrono::steady_clock::now() > deadline) return false;
    std::this_thread::sleep_for(std::chrono::milliseconds(5));
  }
  return true;
}

/// A program started by a test without waiting for it (the interruption tests signal it
/// while it works). Killed with SIGKILL and reaped when destroyed still running, so a
/// failing test leaves no process behind.
class ChildProcess {
 public:
  /// Starts argv[0] with `argv` in `dir`, stdout and stderr appended to `log`. SIGINT,
  /// SIGTERM and SIGHUP at their default action and unblocked in the child, as from a
  /// terminal (a test runner may ignore or block them).
  ChildProcess(const std::vector<std::string>& argv, const std::filesystem::path& dir,
               const std::filesystem::path& log) {
    std::vector<char*> args;
    for (const std::string& a : argv) args.push_back(const_cast<char*>(a.c_str()));
    args.push_back(nullptr);
    const std::string dir_text = dir.string();
    const std::string log_text = log.string();
    pid_ = ::fork();
    if (pid_ == 0) {  // only async-signal-safe calls until exec
      if (::chdir(dir_text.c_str()) != 0) ::_exit(126);
      const int fd = ::open(log_text.c_str(), O_WRONLY | O_CREAT | O_APPEND, 0644);
      if (fd < 0) ::_exit(126);
      ::dup2(fd, STDOUT_FILENO);
      ::dup2(fd, STDERR_FILENO);
      const int null = ::open("/dev/null", O_RDONLY);
      if (null >= 0) ::dup2(null, STDIN_FILENO);
      for (const int signal : {SIGINT, SIGTERM, SIGHUP}) ::signal(signal, SIG_DFL);
      sigset_t none;
      sigemptyset(&none);
      ::sigprocmask(SIG_SETMASK, &none, nullptr);
      ::execv(args[0], args.data());
      ::_exit(127);
    }
    EXPECT_GT(pid_, 0) << "fork failed";
  }
  ChildProcess(const ChildProcess&) = delete;
  ChildProcess& operator=(const ChildProcess&) = delete;
  ~ChildProcess() {
    if (pid_ > 0 && !Exited()) {
      ::kill(pid_, SIGKILL);
      Wait(std::chrono::seconds(30));
    }
  }

  pid_t pid() const { return pid_; }

  /// Whether it has ended (reaping it); never blocks.
  bool Exited() {
    int status = 0;
    if (!status_ && pid_ > 0 && ::waitpid(pid_, &status, WNOHANG) == pid_) status_ = status;
    return status_.has_value();
  }

  /// The wait status once it ended, nullopt if it did not within `timeout`.
  std::optional<int> Wait(std::chrono::milliseconds timeout) {
    WaitUntil([this] { return Exited(); }, timeout);
    return status_;
  }

 private:
  pid_t pid_ = -1;
  std::optional<int> status_;
};

/// The pids of the running processes whose parent is `parent` (from /proc/<pid>/stat).
inline std::vector<pid_t> ChildrenOf(pid_t parent) {
  std::vector<pid_t> children;
  std::error_code ec;
  for (std::filesystem::directory_iterator it("/proc", ec), end; !ec && it != end; it.increment(ec)) {
    const std::string name = it->path().filename().string();
    if (name.find_first_not_of("0123456789") != std::string::npos) continue;
    std::ifstream stat(it->path() / "stat");
    std::string line;
    if (!std::getline(stat, line)) continue;
    // "pid (comm) state ppid ...": comm may hold spaces and parentheses.
    const size_t close = line.rfind(')');
    if (close == std::string::npos) continue;
    char state = 0;
    long ppid = 0;
    if (std::sscanf(line.c_str() + close + 1, " %c %ld", &state, &ppid) != 2) continue;
    if (ppid == parent && state != 'Z') children.push_back(static_cast<pid_t>(std::stol(name)));
  }
  return children;
}

/// Whether process `pid` has a handler for `signal` installed (/proc/<pid>/status
/// SigCgt): a signal sent before that would meet the default action.
inline bool CatchesSignal(pid_t pid, int signal) {
  std::ifstream status("/proc/" + std::to_string(pid) + "/status");
  std::string line;
  while (std::getline(status, line)) {
    if (line.rfind("SigCgt:", 0) != 0) continue;
    const unsigned long long mask = std::stoull(line.substr(7), nullptr, 16);
    return (mask >> (signal - 1)) & 1u;
  }
  return false;
}

/// Whether `pid` names a process (running or not yet reaped).
inline bool ProcessExists(pid_t pid) { return ::kill(pid, 0) == 0 || errno == EPERM; }

}  // namespace tofu::test
