#pragma once
// The evaluation module: one method's scores from its in-memory record (ReplayResult: the
// outputs, in memory or spilled, and the consensus decisions) against a recorded log's
// ground truth and labels. The run loop (harness/estimation.h) and `tofu estimate` both
// score through ScoreMethod; the writers (method_files.h) only write what it returns.
//  - ATE: position RMSE after an SE(3) alignment of the whole estimate to the ground
//    truth (evo `-a`, Umeyama), rotation RMSE under the same alignment, RPE over 1 s;
//  - NEES of the reported position covariance: e_Lᵀ P_pp⁻¹ e_L with e_L the aligned
//    position error rotated into L (3 on average for a consistent 3-D estimate), and the
//    95 % containment;
//  - continuity: the largest step of the position error between consecutive outputs;
//  - tilt and IMU-bias errors, and the input check (the fused estimate against the pose
//    stream it fused, on the same span);
//  - fault detection (consensus methods, and clients that say what they fuse): per fault
//    interval of a sensor and kind (overlapping scheduled faults of one kind merged:
//    labels.h MergedLabelIntervals) except dropouts (a dropout is no data, not wrong
//    data), the delay from its onset to the first decision that excludes the sensor, or
//    missed when none did before it ended; re-admission after it ended;
//  - false exclusions: time a sensor was excluded while none of its faults was active;
//  - switches: changes of the fused set.
// No simulator, no file output.

#include <map>
#include <optional>
#include <string>
#include <vector>

#include <Eigen/Core>
#include <nlohmann/json.hpp>

#include "core/time.h"
#include "estimator/consensus_estimator.h"
#include "replay/labels.h"
#include "replay/trajectory_metrics.h"

namespace tofu::replay {

struct RecordedLog;
struct ReplayResult;

/// The 95 % quantile of χ² with 3 degrees of freedom: the NEES bound of the position
/// covariance's 95 % ellipsoid.
inline constexpr double kChiSquare3Dof95 = 7.814727903251178;

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

/// What a consensus method's decisions score against the run's labels.
struct ConsensusScores {
  int switches = 0;  ///< changes of the fused set once something was fused
  /// Per fault interval (MergedLabelIntervals) except dropouts, by onset.
  std::vector<FaultDetection> detections;
  /// Per sensor of `sensors` (and any other excluded one): seconds excluded while none of
  /// its fault or condition intervals was active.
  std::map<std::string, double> false_exclusion_s;
};
ConsensusScores ScoreConsensusDecisions(const std::vector<estimator::ConsensusRecord>& decisions,
                                        const std::vector<LabelEvent>& labels,
                                        core::Time run_end_ns,
                                        const std::vector<std::string>& sensors);

/// A client's decisions are its fused set at each change: a sensor it had already stopped
/// fusing when a fault began has no decision in the fault's interval. The decision in
/// force at each fault onset is stated again there, so that such a sensor counts as
/// excluded from the onset (delay 0), as sampling its fused set would.
std::vector<estimator::ConsensusRecord> RestatedAtFaultOnsets(
    std::vector<estimator::ConsensusRecord> records, const std::vector<LabelEvent>& labels);

/// The fused estimate against the pose stream it fused, on the same span.
struct InputCheck {
  std::string input;  ///< "raw:<stream>"
  double input_ate_m = 0.0;
  double input_rotation_deg = 0.0;
  bool worse_in_position = false;
  bool worse_in_rotation = false;
  double ate_m = 0.0;
  double rotation_deg = 0.0;
};

/// The estimated gravity direction against the true one over the valid outputs: roll and
/// pitch error, free of the yaw and origin an SE(3) alignment hides.
struct TiltError {
  double rms_deg = 0.0;
  double max_deg = 0.0;
  double final_deg = 0.0;
};

/// The estimated IMU biases against the ground truth's (EuRoC carries them).
struct BiasError {
  double gyro_rms_radps = 0.0;
  double accel_rms_mps2 = 0.0;
  Eigen::Vector3d gyro_final_radps = Eigen::Vector3d::Zero();
  Eigen::Vector3d gyro_true_final_radps = Eigen::Vector3d::Zero();
  Eigen::Vector3d accel_final_mps2 = Eigen::Vector3d::Zero();
  Eigen::Vector3d accel_true_final_mps2 = Eigen::Vector3d::Zero();
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
  /// Continuity (TrajectoryErrors::position_step_max_m): the largest step of the position
  /// error between consecutive outputs, and when (run time, s).
  std::optional<double> position_step_max_m;
  std::optional<double> position_step_max_t_s;
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

/// One method's figures as every record writes them (summary.json's `methods.<name>`,
/// `tofu estimate`'s evaluation.json): a failed method's figures are null, with the
/// failure and what it measured before under `partial` (FailedFiguresJson).
nlohmann::json MethodEvaluationJson(const MethodEvaluation& evaluation);

/// `figures` of something that failed: each figure null, the measured values kept apart
/// under `partial` (they would read as healthy ones) and `failure` saying why; the keys
/// that say what the figures are of (ate_alignment, corridor_m, digests) kept.
nlohmann::json FailedFiguresJson(nlohmann::json figures, const std::string& failure);

/// Everything ScoreMethod measured: the evaluation, and what the method's files show.
struct MethodScores {
  MethodEvaluation evaluation;
  std::vector<PoseSample> trajectory;      ///< the valid outputs (T_LI)
  std::optional<TrajectoryErrors> errors;  ///< with ground truth and > 10 valid outputs
  /// Per matched sample of `errors` (errors->t_ns): the position NEES, NaN where the
  /// output had no usable covariance or the ground truth a gap.
  std::vector<double> nees;
  std::optional<TiltError> tilt;
  std::optional<BiasError> bias;
  std::optional<InputCheck> input_check;  ///< with ground truth and a fused pose stream
  /// Per ReplayResult::initialisations: the angle between the estimated and the true down
  /// direction in I when the graph started (nullopt without ground truth).
  std::vector<std::optional<double>> initialisation_tilt_error_deg;
};

/// What the scoring needs beyond the method's record and the log.
struct ScoringContext {
  /// The run's labels (faults and conditions); empty: nothing to detect.
  const std::vector<LabelEvent>* labels = nullptr;
  double run_duration_s = 0.0;
  /// The sensors a false exclusion is reported for (each with 0 s when never excluded).
  std::vector<std::string> sensors;
  std::optional<double> consensus_threshold;  ///< reported with a consensus method
};

/// Scores one method. Reads its outputs (ForEachOutput) and keeps none of them.
MethodScores ScoreMethod(const RecordedLog& log, const ReplayResult& result,
                         const ScoringContext& context);

/// A pose stream alone (T_AI = T_As T_Is⁻¹) over the span the methods covered, scored
/// against the ground truth: what fusion has to beat.
struct RawStreamScore {
  std::string stream;
  std::vector<PoseSample> trajectory;
  TrajectoryErrors errors;
};
/// Every pose stream of `log` with more than 10 samples in [from_ns, to_ns]; none without
/// ground truth or for an empty span.
std::vector<RawStreamScore> ScoreRawStreams(const RecordedLog& log, core::Time from_ns,
                                            core::Time to_ns);

}  // namespace tofu::replay
