#pragma once
// The estimation methods of a run (a scenario's `estimation:` block): every method
// replays the very same recorded samples of the run directory (seed paper Sec. 3.3:
// consensus, the naive baseline, single sensors on the corrupted and on the uncorrupted
// streams), and each is scored against the ground truth and the fault labels:
//  - ATE: position RMSE after an SE(3) alignment of the whole estimate to the ground
//    truth (evo `-a`, Umeyama), rotation RMSE under the same alignment, RPE over 1 s;
//  - NEES of the reported position covariance: e_Lᵀ P_pp⁻¹ e_L with e_L the aligned
//    position error rotated into L (3 on average for a consistent 3-D estimate);
//  - fault detection (consensus methods): per fault interval of a sensor and kind
//    (overlapping scheduled faults of one kind merged: evaluation.h MergedLabelIntervals)
//    except dropouts (a dropout is no data, not wrong data), the delay from its onset to
//    the first decision that excludes the sensor, or missed when none did before it ended;
//  - false exclusions: time a sensor was excluded while none of its faults was active;
//  - switches: changes of the fused set.
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

namespace tofu::replay {
struct LabelEvent;
struct ReplayResult;
}  // namespace tofu::replay

namespace tofu::harness {

/// One fault interval of a sensor and kind (overlapping faults merged) and whether (and
/// when) a method noticed it.
struct FaultDetection {
  std::string sensor;
  std::string fault;  ///< fault kind name, e.g. "divergence"
  core::Time onset_ns = 0;
  core::Time end_ns = 0;
  std::optional<core::Time> detected_ns;  ///< first exclusion in [onset, end]
  bool ends_in_run = false;  ///< the fault ended before the run did
  /// Detected faults that ended: from the end on, the first decision from which the
  /// sensor stays eligible (available, trusted, fusable: ConsensusDecision::eligible) for
  /// at least 1 s (a blip of trust before the fault's trailing edge is seen does not
  /// count), or to the end of the run.
  std::optional<core::Time> readmitted_ns;
  std::optional<double> delay_s() const;
  /// Seconds from the fault's end to readmitted_ns; +inf when never re-admitted; nullopt
  /// for a fault that was not detected or did not end.
  std::optional<double> readmission_delay_s() const;
};

struct MethodEvaluation {
  std::string method;
  bool consensus = false;
  std::optional<double> threshold;  ///< consensus methods
  std::size_t outputs = 0;
  double valid_fraction = 0.0;  ///< valid outputs / outputs
  // Trajectory errors (nullopt without enough valid outputs).
  std::optional<double> ate_m;
  std::optional<double> ate_max_m;
  std::optional<double> rotation_rmse_deg;
  std::optional<double> rpe_m;
  std::optional<double> rpe_deg;
  /// NEES of the reported position covariance against the true error, e_Lᵀ P⁻¹ e_L, over
  /// the outputs with a covariance and ground truth: its mean and median (3 and 2.37 for
  /// a consistent 3-DoF covariance), and the fraction of samples inside the covariance's
  /// 95 % ellipsoid (NEES ≤ χ²₃(0.95) = 7.81; 0.95 when consistent).
  std::optional<double> nees_position_mean;
  std::optional<double> nees_position_median;
  std::optional<double> position_containment_95;
  std::size_t nees_samples = 0;
  // Consensus methods.
  int switches = 0;
  std::vector<FaultDetection> detections;
  /// Per sensor: seconds excluded while healthy.
  std::map<std::string, double> false_exclusion_s;
  double run_duration_s = 0.0;
  // Cost (wall clock: kept out of summary.json).
  double wall_time_s = 0.0;
  /// A client method that failed: why, with its last standard-error lines (what it
  /// produced before is scored as any method's).
  std::optional<std::string> failure;

  int missed_faults() const;
  /// The largest detection delay over the faults of `kind` ("" = every detectable fault);
  /// nullopt when there is none; +inf when one was missed.
  std::optional<double> max_detection_delay_s(const std::string& kind = "") const;
  /// The largest re-admission delay (nullopt when no detected fault ended).
  std::optional<double> max_readmission_delay_s() const;
  /// The largest false-exclusion time of any sensor as a fraction of the run.
  double false_exclusion_fraction() const;
};

/// Scores the methods that ran in the loop (`results`, in the order of config.methods)
/// against the run directory `run_dir` (its ground truth and stream descriptions), writes
/// the files listed above into it and returns the evaluations. `labels` are the run's
/// fault labels. Each result's outputs are released once written (left empty): an hour
/// of them is 280 MB, and nothing after the scoring reads them.
std::vector<MethodEvaluation> EvaluateEstimation(const std::filesystem::path& run_dir,
                                                 const replay::EstimationConfig& config,
                                                 const std::vector<replay::LabelEvent>& labels,
                                                 double run_duration_s,
                                                 std::vector<replay::ReplayResult>& results);

}  // namespace tofu::harness
