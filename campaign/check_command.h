#pragma once
// `tofu check`: scenario-driven CI. Loads and validates every scenario first (any bad
// input: exit 2 before anything runs), flies every (scenario, seed) as a `tofu run`
// subprocess in a pool of jobs, reads each run's summary.json, aggregates each
// expectation over the seeds (`pass_fraction`), prints a table, optionally writes
// JUnit XML, and tabulates the estimation methods over the seeds (check_methods.h). Across
// machines, a shard runs part of the grid and a merge takes the shards' runs in place of
// its own (check_shards.h). The CLI only parses arguments into CheckCommandOptions.

#include <cstdint>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include <nlohmann/json.hpp>

#include "harness/scenario.h"
#include "harness/shard.h"
#include "campaign/run_pool.h"

namespace tofu::campaign {

/// What `tofu check` was asked for, as typed on the command line (validated by
/// RunCheckCommand).
struct CheckCommandOptions {
  /// Scenario files or directories (a directory means its *.yaml files, not recursive,
  /// sorted by name). Empty: "scenarios".
  std::vector<std::string> inputs;
  std::optional<std::string> junit_path;  ///< JUnit XML file, written atomically
  int jobs = 0;                           ///< parallel runs; 0: core::UsableCores()
  int seeds = 1;                          ///< seeds per scenario, >= 1
  std::string out_dir = "runs/check";     ///< <out>/<scenario>/seed_<s>/ per run
  bool quiet = false;                     ///< no progress and no table (failures still)
  /// The `tofu` executable to spawn for each run; empty: this process's (/proc/self/exe).
  std::string tofu_binary;
  /// This process's part of the scenario x seed grid (check_shards.h); an empty origin:
  /// the whole grid. A shard writes its runs and its record, and no JUnit, table or
  /// method table: the merge does, over all shards.
  harness::Shard shard;
  /// Instead of running: the shards' --out directories to merge (`--merge DIR...`).
  std::vector<std::string> merge_dirs;
  /// A baseline (`tofu baseline` file or check directory) to compare the check with
  /// (campaign/compare.h): read and matched to the grid before anything runs; afterwards
  /// a regressed cell fails its scenario's JUnit test case "compared with the baseline",
  /// and <out>/compare.md and compare.json hold the comparison.
  std::optional<std::string> baseline_path;
};

/// Runs the check and returns the exit code: kExitOk when every expectation held over
/// the seeds, kExitExpectationFailed when one did not, kExitBadInput on bad input (the
/// message names file:line:column and key; nothing is run or written) or when a run
/// reported bad input, kExitSimulationError when a simulation failed, kExitClientFailed
/// when a user's estimator or controller failed in a run (and nothing worse happened);
/// with a baseline, kExitExpectationFailed also when a cell regressed, and kExitBadInput
/// (before anything runs) when the baseline is not of this grid. A shard returns
/// kExitOk once its runs have ended and its record is written, whatever their verdicts
/// (an expectation's pass_fraction needs every seed: the merge decides). A merge
/// (`merge_dirs`) runs nothing and returns what one machine's check of the same grid
/// would have; missing, repeated or foreign shards are bad input (nothing written).
int RunCheckCommand(const CheckCommandOptions& options);

/// Refuses a scenario's `compare: {minimal_effects: ...}` naming a metric tofu compare does
/// not have (campaign/compared_metrics.h) or a negative value: core::InputError at its
/// file:line. `tofu validate`, `run` and `check` call it with the other checks of a loaded
/// scenario.
void CheckScenarioMinimalEffects(const harness::Scenario& scenario);

/// The scenario files named by `inputs`, in order (directories expanded to their sorted
/// *.yaml files; the same file named twice is kept once). Throws core::InputError for a
/// path that does not exist or a directory without scenarios.
std::vector<std::string> ExpandScenarioInputs(const std::vector<std::string>& inputs);

/// Number of seeds out of `seeds` in which an expectation with `pass_fraction` must hold:
/// ceil(pass_fraction * seeds), robust to rounding (0.7 * 10 needs 7, not 8), >= 1.
int RequiredPasses(double pass_fraction, int seeds);


/// How one expectation fared in one seed.
struct SeedOutcome {
  uint64_t seed = 0;
  std::optional<double> value;  ///< nullopt: undefined, or the run has no summary
  bool held = false;
  /// The summary's `not_measurable`: the method or flight the metric names failed.
  std::string not_measurable;
};

/// One expectation over the seeds.
struct AggregatedExpectation {
  harness::Expectation expectation;
  std::vector<SeedOutcome> seeds;
  int held = 0;      ///< seeds in which it held
  int required = 0;  ///< RequiredPasses(pass_fraction, seeds.size())
  bool passed = false;
};

/// Counts the seeds in which `expectation` held and decides with its pass_fraction.
AggregatedExpectation AggregateExpectation(const harness::Expectation& expectation,
                                           std::vector<SeedOutcome> seeds);

/// An estimator method's figures from summary.json `methods`, over the seeds.
struct MethodStats {
  std::string method;
  int seeds_with_ate = 0;
  std::optional<double> ate_mean_m;  ///< mean of `ate_m` over the seeds that have it
  int faults = 0;                    ///< sum of `faults`
  int faults_detected = 0;           ///< sum of `faults_detected`
  bool has_detections = false;       ///< some seed reported `faults`
  int failed_seeds = 0;              ///< seeds in which the method failed
  std::string failure;               ///< the first failed seed's `failure`, first line
};

/// A closed-loop flight's figures from summary.json `closed_loop`, over the seeds.
struct ClosedLoopStats {
  std::string method;  ///< the method the controller flew on
  int seeds = 0;
  std::optional<double> tracking_rmse_mean_m;  ///< mean over the seeds that have it
  int collisions = 0;                          ///< sum over the seeds
  int failsafe_events = 0;                     ///< sum over the seeds
  int failed_seeds = 0;                        ///< seeds in which the flight failed
  std::string failure;                         ///< the first failed seed's `failure`, first line
};

/// One scenario of a check, over its seeds.
struct ScenarioCheck {
  std::string name;
  std::string source_file;
  std::vector<SeedRun> runs;  ///< in seed order
  std::vector<AggregatedExpectation> expectations;
  std::vector<MethodStats> methods;  ///< sorted by name
  /// Closed-loop flights (summary.json `closed_loop`), over the seeds, sorted by method.
  std::vector<ClosedLoopStats> closed_loop;
  int seeds_passed = 0;   ///< runs that exited 0 (every expectation held in that seed)
  bool runs_ok = true;    ///< no run exited with bad input or a failed simulation
  bool clients_ok = true; ///< no run's estimator or controller client failed
  bool passed = false;    ///< runs_ok, clients_ok and every aggregated expectation passed
  /// Compared with a baseline (CheckCommandOptions::baseline_path): one line of figures per
  /// regressed cell (empty: nothing regressed). Unset without a baseline.
  std::optional<std::vector<std::string>> baseline_regressions;
  /// Asked to compare with a baseline, the comparison could not be made after the runs:
  /// why (its JUnit case fails with it). Empty otherwise.
  std::string baseline_error;
};

/// Aggregates the runs of one scenario (their summaries read already). Expectations are
/// matched to the summary's `expectations` array by position and metric name.
ScenarioCheck EvaluateScenarioCheck(const harness::Scenario& scenario, std::vector<SeedRun> runs);

/// "tracking.position_max_m [2, 10] s <= 0.01": an expectation's metric, window and
/// bounds; the name of its JUnit test case.
std::string ExpectationLabel(const harness::Expectation& expectation);

/// Text with the five XML special characters escaped and the characters XML 1.0 cannot
/// hold replaced by '?'; tabs and line breaks are kept (as character references when
/// `attribute`, since parsers normalise them to spaces in attribute values).
std::string XmlEscape(std::string_view text, bool attribute);

/// The JUnit XML document: one <testsuite> per scenario, one <testcase> per expectation
/// aggregated over the seeds plus one named "run" for the runs themselves (and one per
/// failed client, and "compared with the baseline" when there is one); failing test
/// cases list each seed's value and the renders (*.png, *.mp4 under <run>/renders/) as
/// [[ATTACHMENT|/absolute/path]] in <system-out>.
std::string CheckJUnitXml(const std::vector<ScenarioCheck>& checks);

}  // namespace tofu::campaign
