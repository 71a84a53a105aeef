#include "campaign/run_pool.h"

#include <fcntl.h>
#include <spawn.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <chrono>
#include <csignal>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <map>
#include <stdexcept>
#include <thread>

#include <fmt/format.h>
#include <fmt/ranges.h>

#include "core/cores.h"
#include "core/error.h"
#include "core/file_io.h"
#include "replay/interrupt.h"

extern char** environ;

namespace tofu::campaign {

using replay::InterruptSignal;
using replay::InterruptSignalName;
using replay::ThrowIfInterrupted;
using replay::WaitForInterrupt;

namespace fs = std::filesystem;

std::string SelfExecutable() {
  std::error_code ec;
  const fs::path self = fs::read_symlink("/proc/self/exe", ec);
  // Fall back to the link itself: exec follows it just as well.
  return ec ? std::string("/proc/self/exe") : self.string();
}


namespace {

// Starts `tofu run` for a job with stdin from /dev/null and stdout+stderr into its log.
// Returns the child's pid, or -1 with the reason in job.run.error.
pid_t SpawnRun(const std::string& binary, RunRequest& job, int threads) {
  const std::string seed = std::to_string(job.run.seed);
  // --force: the seed's directory is the check's own, an earlier check's run is replaced.
  std::vector<std::string> args = {binary,  "run",         job.scenario_path,
                                   "--seed", seed,         "--out",
                                   job.run.run_dir, "--quiet", "--force",
                                   "--threads", std::to_string(threads)};
  args.insert(args.end(), job.extra_args.begin(), job.extra_args.end());
  std::vector<char*> argv;
  for (std::string& a : args) argv.push_back(a.data());
  argv.push_back(nullptr);

  posix_spawn_file_actions_t actions;
  posix_spawn_file_actions_init(&actions);
  posix_spawn_file_actions_addopen(&actions, STDIN_FILENO, "/dev/null", O_RDONLY, 0);
  posix_spawn_file_actions_addopen(&actions, STDOUT_FILENO, job.run.log_path.c_str(),
                                   O_WRONLY | O_CREAT | O_TRUNC, 0644);
  posix_spawn_file_actions_adddup2(&actions, STDOUT_FILENO, STDERR_FILENO);
  // Each run in a process group of its own: a Ctrl-C at the terminal reaches the check
  // alone, which forwards it once to every run (a run given the signal twice would stop
  // at once, without its cleanup), and a forwarded signal reaches the run's own children
  // (its plots) too.
  posix_spawnattr_t attributes;
  posix_spawnattr_init(&attributes);
  posix_spawnattr_setflags(&attributes, POSIX_SPAWN_SETPGROUP);
  posix_spawnattr_setpgroup(&attributes, 0);
  pid_t pid = -1;
  const int rc = posix_spawn(&pid, binary.c_str(), &actions, &attributes, argv.data(), environ);
  posix_spawnattr_destroy(&attributes);
  posix_spawn_file_actions_destroy(&actions);
  if (rc != 0) {
    job.run.error = fmt::format("cannot start {}: {}", binary, std::strerror(rc));
    return -1;
  }
  return pid;
}

// Exit status of a child as a core::ExitCode, with a message for the abnormal ends.
void RecordExit(int status, SeedRun& run) {
  if (WIFEXITED(status)) {
    run.exit_code = WEXITSTATUS(status);
    if (run.exit_code == core::kExitBadInput) {
      run.error = "bad input (exit 2)";
    } else if (run.exit_code == core::kExitSimulationError) {
      run.error = "simulation failed (exit 3)";
    } else if (run.exit_code == core::kExitClientFailed) {
      // The run is sound: the failed client is named from its summary (ReadSummary).
    } else if (run.exit_code == core::kExitIoError) {
      run.error = "its output could not be written (exit 4)";
    } else if (run.exit_code > 128 && run.exit_code < 128 + NSIG) {
      // A run stopped by a signal sent to it alone (interrupt.h): cleaned up, not run.
      run.error = fmt::format("interrupted by signal {} ({}; exit {})", run.exit_code - 128,
                              strsignal(run.exit_code - 128), run.exit_code);
      run.exit_code = core::kExitSimulationError;
    } else if (run.exit_code != core::kExitOk && run.exit_code != core::kExitExpectationFailed) {
      run.error = fmt::format("exited with unexpected status {}", run.exit_code);
      run.exit_code = core::kExitSimulationError;
    }
  } else if (WIFSIGNALED(status)) {
    run.error = fmt::format("killed by signal {} ({})", WTERMSIG(status),
                            strsignal(WTERMSIG(status)));
    run.exit_code = core::kExitSimulationError;
  } else {
    run.error = "ended in an unknown way";
    run.exit_code = core::kExitSimulationError;
  }
}

}  // namespace

const char* RunVerdict(const SeedRun& run) {
  if (run.exit_code == core::kExitOk) return "passed";
  if (run.exit_code == core::kExitExpectationFailed) return "expectation failed";
  if (run.exit_code == core::kExitBadInput) return "bad input";
  if (run.exit_code == core::kExitIoError) return "output not written";
  if (run.exit_code == core::kExitClientFailed) return "a client failed";
  return "simulation failed";
}

// Runs every job, at most `jobs` at a time. The check owns this process's children: it
// reaps with waitpid(-1), so it must not share the process with other child-spawning code.
// Interrupted (interrupt.h): starts nothing more, forwards the signal to every running
// run (each removes its staging directory and exits 128 + signal), waits for them all,
// then throws Interrupted: no run is left writing when the check exits.
// Each run gets the cores the pool leaves it (`tofu run --threads`).
void RunPool(const std::string& binary, const std::vector<RunRequest*>& queue, int jobs,
             bool quiet, std::string_view command) {
  const int threads = std::max(1, core::UsableCores() / jobs);
  using Clock = std::chrono::steady_clock;
  std::map<pid_t, std::pair<size_t, Clock::time_point>> running;
  size_t next = 0;
  size_t finished = 0;
  const auto report = [&](const RunRequest& job) {
    ++finished;
    if (quiet) return;
    fmt::print(stderr, "[{}/{}] {} seed {}: {} ({:.1f} s)\n", finished, queue.size(), job.label,
               job.run.seed, RunVerdict(job.run), job.run.wall_time_s);
  };
  int forwarded = 0;  // the signal forwarded to the runs, 0 before an interruption
  while (next < queue.size() || !running.empty()) {
    if (const int signal = InterruptSignal(); signal != 0 && forwarded == 0) {
      forwarded = signal;
      next = queue.size();
      for (const auto& [child, job] : running) {
        if (::kill(-child, signal) != 0) ::kill(child, signal);  // its group, else itself
      }
      if (!quiet) {
        fmt::print(stderr, "tofu {}: {}: waiting for {} running runs to stop\n",
                   command, InterruptSignalName(signal), running.size());
      }
    }
    while (next < queue.size() && running.size() < static_cast<size_t>(jobs)) {
      RunRequest& job = *queue[next];
      const pid_t pid = SpawnRun(binary, job, threads);
      if (pid < 0) {
        job.run.exit_code = core::kExitSimulationError;
        report(job);
      } else {
        running.emplace(pid, std::make_pair(next, Clock::now()));
      }
      ++next;
    }
    if (running.empty()) continue;
    int status = 0;
    // Polled in slices: a blocking waitpid would sleep through a signal (SA_RESTART).
    const pid_t pid = ::waitpid(-1, &status, WNOHANG);
    if (pid == 0) {
      // Before an interruption, wake up at once for it; after, only the runs matter.
      if (forwarded == 0) {
        WaitForInterrupt(50);
      } else {
        std::this_thread::sleep_for(std::chrono::milliseconds(20));
      }
      continue;
    }
    if (pid < 0) {
      if (errno == EINTR) continue;
      throw std::runtime_error(fmt::format("waitpid: {}", std::strerror(errno)));
    }
    const auto it = running.find(pid);
    if (it == running.end()) continue;
    RunRequest& job = *queue[it->second.first];
    job.run.wall_time_s =
        std::chrono::duration<double>(Clock::now() - it->second.second).count();
    RecordExit(status, job.run);
    running.erase(it);
    report(job);
  }
  ThrowIfInterrupted();
}

// Reads a finished run's summary.json and completes its error message.
void ReadSummary(SeedRun& run) {
  const fs::path path = fs::path(run.run_dir) / "summary.json";
  if (run.exit_code == core::kExitOk || run.exit_code == core::kExitExpectationFailed ||
      run.exit_code == core::kExitSimulationError || run.exit_code == core::kExitClientFailed) {
    std::ifstream in(path);
    if (in) {
      try {
        run.summary = nlohmann::json::parse(in);
        if (!run.summary.is_object()) throw std::runtime_error("not a JSON object");
      } catch (const std::exception& e) {
        run.summary = nullptr;
        if (run.error.empty()) {
          run.error = fmt::format("unreadable {}: {}", path.string(), e.what());
        }
      }
    } else if (run.error.empty()) {
      run.error = fmt::format("no {}", path.string());
    }
  }
  if (run.error.empty() && run.exit_code == core::kExitClientFailed) {
    const auto failure = run.summary.find("failure");
    run.client_failure = failure != run.summary.end() && failure->is_string()
                             ? failure->get<std::string>()
                             : std::string("a client failed (exit 5), and its summary does not say which");
  }
  if (run.error.empty()) return;
  if (run.exit_code == core::kExitOk || run.exit_code == core::kExitExpectationFailed ||
      run.exit_code == core::kExitClientFailed) {
    run.exit_code = core::kExitSimulationError;  // no usable summary: the run did not work
  }
  // Say why: the simulation's own failure text, else what the run printed last.
  if (run.summary.is_object() && run.summary.contains("failure") &&
      run.summary["failure"].is_string()) {
    run.error += ": " + run.summary["failure"].get<std::string>();
  } else if (const std::vector<std::string> tail = core::LogTail(run.log_path, 5); !tail.empty()) {
    run.error += fmt::format(":\n{}", fmt::join(tail, "\n"));
  }
}

}  // namespace tofu::campaign
