#pragma once
// The campaign's flights: each a `tofu run` subprocess (a scenario file at one seed into a
// run directory), at most `jobs` at a time, reaped and read back as typed records. Check,
// search and their shards share it: a campaign never flies in-process, so a crashing
// simulation or client ends one run, never the campaign.

#include <cstdint>
#include <string>
#include <string_view>
#include <vector>

#include <nlohmann/json.hpp>

namespace tofu::campaign {

/// One `tofu run` of a campaign: a scenario at one seed.
struct SeedRun {
  uint64_t seed = 0;
  std::string run_dir;   ///< absolute
  std::string log_path;  ///< the run's stdout and stderr
  int exit_code = -1;    ///< tofu run's exit status (core::ExitCode)
  std::string error;     ///< why the run failed or has no usable summary; empty if fine
  /// A run that exited kExitClientFailed: the summary's `failure` (a user's estimator or
  /// controller failed; the run itself is sound and scored). Empty otherwise.
  std::string client_failure;
  double wall_time_s = 0.0;
  nlohmann::json summary;  ///< summary.json; null when missing or unreadable
};

/// A run to start: `tofu run <scenario_path> --seed <run.seed> --out <run.run_dir>`, its
/// output into run.log_path. `label` names it in progress lines ("<label> seed <s>").
struct RunRequest {
  std::string scenario_path;
  std::string label;
  SeedRun run;
  std::vector<std::string> extra_args;  ///< more options of `tofu run` ("--no-plots")
};

/// This process's executable (/proc/self/exe resolved), to spawn `tofu run` with.
std::string SelfExecutable();

/// Runs every request, at most `jobs` at a time, each in a process group of its own with
/// the cores the pool leaves it (`--threads`). Fills run.exit_code, run.error (abnormal
/// ends) and run.wall_time_s; not the summary (ReadSummary). The pool owns this
/// process's children: it reaps with waitpid(-1). Interrupted (replay/interrupt.h): starts
/// nothing more, forwards the signal once to every running run, waits for them all, then
/// throws replay::Interrupted. `command` names the campaign in its progress lines.
void RunPool(const std::string& binary, const std::vector<RunRequest*>& queue, int jobs,
             bool quiet, std::string_view command);

/// Reads a finished run's summary.json into run.summary and completes run.error (a run
/// without a usable summary did not work: exit_code becomes kExitSimulationError) and
/// run.client_failure.
void ReadSummary(SeedRun& run);

/// "passed", "expectation failed", "a client failed", "simulation failed", ...
const char* RunVerdict(const SeedRun& run);

}  // namespace tofu::campaign
