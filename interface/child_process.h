#pragma once
// A client process with pipes on its standard streams, for the process protocol
// (docs/INTERFACE.md). It runs in a process group of its own (so that Kill() reaches
// whatever it started), gets SIGKILL if tofu dies (PR_SET_PDEATHSIG), and a watchdog in
// its group (/bin/sh) kills the whole group when tofu ends in any way, SIGKILL included;
// it inherits no descriptor besides its three streams. The I/O is poll()-based and never blocks on one
// direction: tofu writes its messages while it reads the answers, so a client that writes
// answers before reading on can never deadlock against tofu writing measurements. The
// client's standard error is drained all along into a ring of its last 20 lines.
//
// Not thread-safe. PR_SET_PDEATHSIG follows the thread that started the client: create it
// on a thread that outlives it (tofu's run loop). Nothing in the process may reap children
// it did not start (waitpid(-1)): the client's exit status would be lost.

#include <sys/types.h>

#include <chrono>
#include <cstddef>
#include <deque>
#include <filesystem>
#include <functional>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

namespace tofu::interface {

/// An interruption hook for every wait of this module. While tofu waits for a client,
/// `check` is called before the wait, at least every 50 ms during it, and at once when
/// `wake_fd` (if >= 0) becomes readable; it throws to abandon the wait (tofu's CLI installs
/// replay::ThrowIfInterrupted with the interrupt self-pipe's read end), and the client is
/// then ended by its owner's destructor. interface/ cannot include replay/, hence the hook.
/// An empty `check` removes it. Set it before any client starts (not synchronised).
void SetInterruptCheck(std::function<void()> check, int wake_fd = -1);

/// write(2) on a pipe without SIGPIPE: SIGPIPE is blocked in the calling thread for the
/// call and a SIGPIPE it raised is consumed, so a reader gone away is errno EPIPE and the
/// process's signal dispositions are never touched. Returns what write(2) returns.
long WriteWithoutSigpipe(int fd, const void* data, std::size_t size);

/// The program `argv` would run in `working_dir` (empty: tofu's own), without starting it:
/// argv[0] without a '/' looked up on PATH, with a '/' relative to `working_dir`; it must be
/// a regular, executable file and the working directory must exist. Throws
/// std::runtime_error naming argv[0] and the reason (`tofu validate` finds a bad command
/// before anything flies; ChildProcess throws the same).
std::string ResolveCommand(const std::vector<std::string>& argv,
                           const std::filesystem::path& working_dir);

class ChildProcess {
 public:
  using Clock = std::chrono::steady_clock;

  /// Starts argv (argv[0] looked up on PATH when it has no '/'; a relative path with a '/'
  /// is relative to `working_dir`) in `working_dir` (empty: tofu's own). Throws
  /// std::runtime_error naming argv[0] and the reason when it cannot: not found, not
  /// executable, a working directory that does not exist.
  ChildProcess(const std::vector<std::string>& argv, const std::filesystem::path& working_dir);
  ~ChildProcess();  ///< Kill()
  ChildProcess(const ChildProcess&) = delete;
  ChildProcess& operator=(const ChildProcess&) = delete;

  pid_t pid() const { return pid_; }

  struct Exchange {
    std::size_t written = 0;   ///< bytes of `pending` written
    std::size_t read = 0;      ///< bytes appended to *received
    bool stdout_closed = false;  ///< EOF on the client's standard output
    bool stdin_closed = false;   ///< the client no longer reads its standard input (EPIPE)
  };
  /// Writes as much of `pending` as the pipe takes, appends what the client wrote to
  /// *received, drains its standard error. Returns once something was read, the output was
  /// closed, `pending` is all written while nothing is to be read, or `deadline` passed;
  /// a deadline already past makes it one round that never waits. Interruptible
  /// (SetInterruptCheck).
  Exchange Communicate(std::string_view pending, std::string* received, Clock::time_point deadline);

  /// Closes the client's standard input (it reads EOF).
  void CloseStdin();
  /// The wait status once the client exited, waiting until `deadline`; nullopt while it
  /// runs. It is not reaped until Kill(), so its group stays addressable.
  std::optional<int> WaitForExit(Clock::time_point deadline);
  /// Ends the client's process group: SIGTERM, up to 200 ms of grace, SIGKILL, then reaps
  /// the client. Idempotent, never throws, never waits for an interruption.
  void Kill();
  /// Reads what the client's standard error still holds, until EOF or `deadline`.
  void DrainStderr(Clock::time_point deadline);

  /// The client's last lines of standard error (at most 20, each cut at 1000 bytes).
  std::vector<std::string> stderr_tail() const;

  /// "exited with status 3", "was killed by signal 11 (Segmentation fault)".
  static std::string DescribeExit(int wait_status);

 private:
  void ReadStderr();
  void AddStderr(std::string_view bytes);
  void CloseFd(int* fd);
  void StartWatchdog(int max_fd);

  pid_t pid_ = -1;
  pid_t watchdog_pid_ = -1;  ///< kills the client's group when watchdog_fd_ closes
  int watchdog_fd_ = -1;     ///< the only write end of the watchdog's pipe
  bool reaped_ = false;
  std::optional<int> exit_status_;
  int stdin_fd_ = -1;
  int stdout_fd_ = -1;
  int stderr_fd_ = -1;
  std::deque<std::string> stderr_lines_;
  std::string stderr_partial_;
};

}  // namespace tofu::interface
