#pragma once
// What a method's run leaves in a directory (a run directory or `tofu estimate --out`):
// estimate_<method>.csv/.tum/.json, its errors against ground truth, its timing, the
// consensus decisions and consistency matrix, and a raw pose stream's baseline. The
// writers compute nothing they write but the timing: the scores are ScoreMethod's.

#include <filesystem>
#include <string>

#include "replay/method_evaluation.h"
#include "replay/method_runner.h"
#include "replay/recorded_log.h"

namespace tofu::replay {

/// The solver's cost WriteMethodResult wrote to timing_estimate_<method>.json.
struct MethodFiles {
  double solve_mean_ms = 0.0;
  double solve_p99_ms = 0.0;
  double update_budget_ms = 0.0;  ///< the keyframe period
};
/// Writes one method's estimate_<method>.csv/.tum/.json (with T_WL, the alignment of L
/// to W, and the scores when scored), estimate_<method>_errors.csv and
/// timing_estimate_<method>.json into out_dir; ':' and '+' in the method name become '_'
/// in file names. Computes nothing it writes but the timing: `scores` is ScoreMethod's.
MethodFiles WriteMethodResult(const RecordedLog& log, const ReplayResult& result,
                              const MethodScores& scores, const std::filesystem::path& out_dir);
/// decisions.csv: the header, and the rows of one consensus method (every evaluation:
/// t_ns, method, fused, excluded, unavailable, reason; sensor lists joined with '+').
inline constexpr const char* kDecisionsCsvHeader =
    "#timestamp [ns],method,fused,excluded,unavailable,reason\n";
std::string DecisionRows(const ReplayResult& result);
/// consistency_<method>.csv of a consensus method: t_ns (end of the window), pair ("a-b",
/// "a-local"), metric, value (empty when unavailable).
std::string ConsistencyMatrixCsv(const ReplayResult& result);
/// bias_<method>.csv: the χ² of each sensor pair's mean-difference test per evaluation
/// (empty: not taken), when the consensus method ran it.
std::string BiasTestCsv(const ReplayResult& result);

/// The consensus files of a directory, as the run loop and `tofu estimate` both leave
/// them: Add each method's result in method order (consistency_<method>.csv is written
/// for a consensus method at once), then Commit() writes decisions.csv with every
/// consensus method's rows, when one was added.
class ConsensusFiles {
 public:
  explicit ConsensusFiles(std::filesystem::path out_dir);
  void Add(const ReplayResult& result);
  void Commit() const;

 private:
  std::filesystem::path out_dir_;
  std::string decisions_csv_ = kDecisionsCsvHeader;
  bool any_consensus_ = false;
};
/// A pose stream on its own (ScoreRawStreams): estimate_raw_<stream>_errors.csv and
/// estimate_raw_<stream>.json (its ATE) into out_dir.
void WriteRawStreamResult(const RecordedLog& log, const RawStreamScore& raw,
                          const std::filesystem::path& out_dir);

}  // namespace tofu::replay
