#include "replay/interrupt.h"

#include <fcntl.h>
#include <poll.h>
#include <unistd.h>

#include <atomic>
#include <cerrno>
#include <cstring>

namespace tofu::replay {
namespace {

// Written by the handler, read by check points on any thread: a lock-free atomic is the
// one kind of object a signal handler may touch besides volatile sig_atomic_t.
std::atomic<int> g_signal{0};
static_assert(std::atomic<int>::is_always_lock_free);
// Self-pipe: the handler writes a byte so that WaitForInterrupt wakes up at once.
int g_pipe[2] = {-1, -1};
std::atomic<bool> g_installed{false};

void OnSignal(int signal) {
  const int saved_errno = errno;
  int expected = 0;
  if (!g_signal.compare_exchange_strong(expected, signal)) {
    // A second signal: the user does not wait for the cleanup. End now, by the signal.
    ::signal(signal, SIG_DFL);
    ::raise(signal);
    errno = saved_errno;
    return;
  }
  if (g_pipe[1] >= 0) {
    const char byte = 1;
    [[maybe_unused]] const ssize_t woke = ::write(g_pipe[1], &byte, 1);
  }
  errno = saved_errno;
}

}  // namespace

void InstallInterruptHandlers() {
  if (g_installed.exchange(true)) return;
  // Close-on-exec: children spawned by tofu (runs, plots) must not hold the pipe.
  if (::pipe2(g_pipe, O_CLOEXEC | O_NONBLOCK) != 0) g_pipe[0] = g_pipe[1] = -1;
  struct sigaction action;
  std::memset(&action, 0, sizeof(action));
  action.sa_handler = OnSignal;
  sigemptyset(&action.sa_mask);
  action.sa_flags = SA_RESTART;
  for (const int signal : {SIGINT, SIGTERM, SIGHUP}) {
    // A signal ignored by whoever started tofu (nohup, a background job's SIGINT) stays
    // ignored: the caller asked not to be stopped by it.
    struct sigaction previous;
    if (::sigaction(signal, nullptr, &previous) == 0 && previous.sa_handler == SIG_IGN) continue;
    ::sigaction(signal, &action, nullptr);
  }
}

int InterruptSignal() { return g_signal.load(); }

int InterruptWakeFd() { return g_pipe[0]; }

void ThrowIfInterrupted() {
  if (const int signal = g_signal.load(); signal != 0) throw Interrupted{signal};
}

bool WaitForInterrupt(int timeout_ms) {
  if (g_signal.load() != 0) return true;
  if (g_pipe[0] < 0) {
    ::usleep(static_cast<useconds_t>(timeout_ms) * 1000u);
  } else {
    pollfd fd{g_pipe[0], POLLIN, 0};
    ::poll(&fd, 1, timeout_ms);  // EINTR and timeouts alike: the flag decides
  }
  return g_signal.load() != 0;
}

const char* InterruptSignalName(int signal) {
  switch (signal) {
    case SIGINT: return "SIGINT";
    case SIGTERM: return "SIGTERM";
    case SIGHUP: return "SIGHUP";
    default: return "a signal";
  }
}

}  // namespace tofu::replay
