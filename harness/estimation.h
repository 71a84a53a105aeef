#pragma once
// The estimation methods of a run (a scenario's `estimation:` block): every method
// replays the very same recorded samples of the run directory (seed paper Sec. 3.3:
// consensus, the naive baseline, single sensors on the corrupted and on the uncorrupted
// streams). Each is scored by the evaluation module (replay/method_evaluation.h) against
// the ground truth and the fault labels, as `tofu estimate` scores it.
// Files written into the run directory: estimate_<method>.csv/.tum/.json,
// errors.csv, decisions.csv and consistency_<method>.csv.

#include <filesystem>
#include <functional>
#include <map>
#include <optional>
#include <string>
#include <vector>

#include "core/time.h"
#include "replay/estimation_config.h"
#include "replay/method_evaluation.h"

namespace tofu::replay {
struct ReplayResult;
}  // namespace tofu::replay

namespace tofu::harness {

using replay::FaultDetection;
using replay::MethodEvaluation;

/// Scores the methods that ran in the loop (`results`, in the order of config.methods)
/// against the run directory `run_dir` (its ground truth and stream descriptions), writes
/// the files listed above into it and returns the evaluations. `labels` are the run's
/// fault labels. Each result's outputs are released once written (left empty): an hour
/// of them is 280 MB, and nothing after the scoring reads them. Up to `threads` methods
/// are scored at once in runs of at most kScoreSideBySideMaxS (each holds a trajectory
/// and errors as long as the run while scored; longer runs score one at a time, so that
/// their peak is one method's); the files are the same for any count.
inline constexpr double kScoreSideBySideMaxS = 600.0;
std::vector<MethodEvaluation> EvaluateEstimation(const std::filesystem::path& run_dir,
                                                 const replay::EstimationConfig& config,
                                                 const std::vector<replay::LabelEvent>& labels,
                                                 double run_duration_s,
                                                 std::vector<replay::ReplayResult>& results,
                                                 int threads = 1);

}  // namespace tofu::harness
