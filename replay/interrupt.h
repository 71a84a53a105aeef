#pragma once
// Interruption of the commands that write outputs (`tofu run`, `check`, `estimate`,
// `report`): SIGINT, SIGTERM and SIGHUP must neither leave a staging directory behind
// nor let a half-written output pass for a complete one (issue 19, finding 7).
//
// The handler only records the signal (and wakes waiters through a self-pipe): nothing
// else is async-signal-safe. The work notices it at check points (the simulation's
// progress callback, every atomic file write, before a run directory is renamed into
// place, while waiting for a child process), which throw Interrupted; unwinding removes
// the staging directories (their owners' catch blocks), and main() exits with
// 128 + signal. A second signal while the first is being handled ends the process at
// once (default action), for a user who will not wait for the cleanup.
//
// Without InstallInterruptHandlers() (tests, `tofu corpus`, `tofu render`) the check
// points never throw and signals keep their default action.

#include <csignal>

namespace tofu::replay {

/// Thrown at a check point after SIGINT, SIGTERM or SIGHUP. Deliberately not a
/// std::exception: the handlers of errors (`catch (const std::exception&)`) must not
/// turn an interruption into a reported failure; only main() catches it.
struct Interrupted {
  int signal = 0;
};

/// Routes SIGINT, SIGTERM and SIGHUP to the recording handler (SA_RESTART: system calls
/// in progress resume, the check points decide). Idempotent.
void InstallInterruptHandlers();

/// The first interrupting signal received, 0 if none.
int InterruptSignal();

/// The read end of the self-pipe the handler writes to (-1 before
/// InstallInterruptHandlers): readable once a signal came, for waits that poll other fds
/// (a client's pipes, interface::SetInterruptCheck).
int InterruptWakeFd();

/// Throws Interrupted when a signal was received: the check point.
void ThrowIfInterrupted();

/// Waits up to `timeout_ms` for a signal (without busy waiting); true when one was
/// received, at once if one already was. For loops that wait for something else (child
/// processes) in slices.
bool WaitForInterrupt(int timeout_ms);

/// The exit status of a process ended by `signal` after its cleanup: 128 + signal, as a
/// shell reports a process killed by it.
inline int InterruptExitCode(int signal) { return 128 + signal; }

/// "SIGINT", "SIGTERM", "SIGHUP" (else "a signal").
const char* InterruptSignalName(int signal);

}  // namespace tofu::replay
