#pragma once
// Evaluation of an estimated trajectory against ground truth, as evo and
// rpg_trajectory_evaluation do it: ground truth interpolated at the estimate's stamps, the
// estimate aligned to ground truth (SE(3), or 4-DoF position + yaw for visual-inertial
// estimators whose yaw and position are unobservable), then the absolute trajectory error
// (ATE) per sample and the relative pose error (RPE) over a fixed time delta. Plus TUM
// trajectory files ("t x y z qx qy qz qw", what evo reads) with exact nanosecond stamps.
//
// Which number to quote: for a method that fuses an absolute sensor (total station, GNSS)
// and whose frame L is tied to W, kSE3 (or kNone when L = W by construction); for
// VIO-like estimates (IMU + camera/LiDAR odometry, e.g. EuRoC), kPositionYaw, the
// convention of rpg_trajectory_evaluation, since roll and pitch are observable from
// gravity and must not be "aligned away". The README should quote
// ate_position_rmse_m under the alignment it names.

#include <cstddef>
#include <filesystem>
#include <limits>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include <Eigen/Core>
#include <Eigen/Geometry>

#include "core/time.h"

namespace tofu::replay {

/// One pose of a trajectory: an estimate of T_LI (IMU frame I in the estimator's frame L)
/// or ground truth T_WI. `q` is unit (readers normalise it).
struct PoseSample {
  core::Time t_ns = 0;
  Eigen::Vector3d p = Eigen::Vector3d::Zero();
  Eigen::Quaterniond q = Eigen::Quaterniond::Identity();
};

/// How the estimate's frame L is aligned to W before errors are taken.
enum class TrajectoryAlignment {
  kNone,         ///< T_WL = identity
  kSE3,          ///< rigid, no scale: Umeyama/Horn on the positions (evo `-a`)
  kPositionYaw,  ///< translation + rotation about gravity z (rpg "posyaw", 4-DoF)
};

struct TrajectoryErrorOptions {
  TrajectoryAlignment alignment = TrajectoryAlignment::kSE3;
  /// Only matched samples with align_from_ns <= t <= align_to_ns determine the alignment;
  /// errors are reported over every matched sample.
  core::Time align_from_ns = std::numeric_limits<core::Time>::min();
  core::Time align_to_ns = std::numeric_limits<core::Time>::max();
  /// Ground truth is interpolated (position linearly, attitude by slerp) between the two
  /// samples around an estimate stamp; the estimate sample is skipped unless both lie
  /// within this gap of it (a ground-truth sample at the very stamp is used directly).
  core::Time max_interpolation_gap_ns = 50'000'000;
  /// When the alignment samples' positions do not determine the rotation (hover: the
  /// second principal spread for kSE3, the largest horizontal spread for kPositionYaw, as
  /// a standard deviation below this), the rotation (yaw) comes from the attitudes
  /// instead: the chordal mean of R_WI_true R_LI_est^T. m.
  double min_alignment_spread_m = 0.05;
  /// RPE over time: pairs (i, j) of matched samples with t_j the first stamp at or after
  /// t_i + rpe_delta_ns and no later than rpe_delta_ns + rpe_tolerance_ns.
  core::Time rpe_delta_ns = 1'000'000'000;
  core::Time rpe_tolerance_ns = 100'000'000;
  /// Continuity: the position error's change is taken between consecutive matched
  /// samples at most this far apart (an output gap longer than this is not a step).
  core::Time max_step_gap_ns = 50'000'000;
};

/// The median of `values` (the mean of the two middle ones for an even count); NaN when
/// there is none.
double Median(std::vector<double> values);

struct TrajectoryErrors {
  std::size_t matched = 0;          ///< estimate samples with ground truth (and finite)
  std::size_t skipped_no_ground_truth = 0;  ///< no ground truth within the gap
  std::size_t skipped_non_finite = 0;       ///< NaN/Inf in the estimate or ground truth
  std::size_t aligned_on = 0;       ///< matched samples inside the alignment range
  /// True when the alignment's rotation came from the attitudes (positions too clustered,
  /// see min_alignment_spread_m).
  bool alignment_from_attitude = false;
  Eigen::Isometry3d T_WL = Eigen::Isometry3d::Identity();  ///< the alignment applied

  // ATE over all matched samples; NaN when matched == 0.
  double ate_position_rmse_m = 0.0;
  double ate_position_mean_m = 0.0;
  double ate_position_median_m = 0.0;
  double ate_position_max_m = 0.0;
  /// Angle of R_WI_true^T (R_WL R_LI_est), degrees.
  double rotation_rmse_deg = 0.0;
  double rotation_max_deg = 0.0;

  /// RPE: E = (T_true,i^-1 T_true,j)^-1 (T_est,i^-1 T_est,j) over pairs rpe_delta_s apart;
  /// independent of the alignment. NaN when there is no pair.
  std::size_t rpe_pairs = 0;
  double rpe_translation_rmse_m = 0.0;
  double rpe_rotation_rmse_deg = 0.0;
  double rpe_delta_s = 0.0;

  /// Continuity: the largest change of the aligned position error between consecutive
  /// matched samples at most max_step_gap_ns apart, |e_k+1 - e_k| with e = T_WL p_LI -
  /// p_WI: a step of the estimate that the true motion does not explain, as a controller
  /// flying on it feels it (a switch of the fused set, a re-linearisation, an absolute
  /// sensor pulling the state back). Independent of the alignment's translation. NaN when
  /// there is no such pair.
  std::size_t step_pairs = 0;
  double position_step_max_m = 0.0;
  core::Time position_step_max_t_ns = 0;  ///< the later sample of the largest step

  /// Per matched sample, in time order (for errors.csv and plots).
  std::vector<core::Time> t_ns;
  std::vector<double> position_error_m;
  std::vector<double> rotation_error_deg;
};

/// Scores `estimate` (T_LI) against `ground_truth` (T_WI); both in any time order (sorted
/// internally, ground-truth duplicates keep the first). Samples with NaN/Inf are skipped
/// and counted, never propagated.
TrajectoryErrors EvaluateTrajectory(const std::vector<PoseSample>& estimate,
                                    const std::vector<PoseSample>& ground_truth,
                                    const TrajectoryErrorOptions& options = {});

/// Decimal seconds text ("12.5", "1403715529.112143517", "1.403715529112143517e+09",
/// "-3E-3") to nanoseconds, exactly: the digits are shifted, never multiplied in floating
/// point, and rounded to the nearest ns (halves away from zero). nullopt for anything
/// else (NaN/Inf, extra characters) or a value outside the int64 ns range.
std::optional<core::Time> ParseSecondsAsNanoseconds(std::string_view text);

/// "1.500000000" from 1'500'000'000: exact integer formatting with 9 decimals.
std::string FormatNanosecondsAsSeconds(core::Time t_ns);

/// Reads a TUM trajectory "t x y z qx qy qz qw" (t in seconds, whitespace separated, '#'
/// comments and blank lines skipped). Stamps via ParseSecondsAsNanoseconds; quaternions
/// normalised; NaN/Inf values pass through. Throws core::InputError naming file, line,
/// column and the expected form for a missing/unreadable file, a line without 8 fields or
/// a field that is not a number.
std::vector<PoseSample> ReadTumTrajectory(const std::filesystem::path& file);

/// Writes `poses` as TUM: seconds with 9 decimals (exact from ns), position with 6,
/// quaternion (w >= 0) with 9, '\n' line ends; byte-deterministic. Throws
/// std::runtime_error if the file cannot be written.
void WriteTumTrajectory(const std::filesystem::path& file, const std::vector<PoseSample>& poses);

}  // namespace tofu::replay
