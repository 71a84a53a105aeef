#pragma once
// Sim-internal: what the odometry sensors (VIO, LiDAR odometry) share. Each reports the
// pose of its mount s in its own odometry frame S, which starts where the sensor boots,
// and the pose drifts: the sensor's estimate carries an error that grows with the path.

#include <optional>

#include <Eigen/Core>
#include <Eigen/Geometry>

#include "core/measurement.h"
#include "sim/mount_motion.h"

namespace tofu::sim {

/// The odometry frame S in W and the accumulated error of the sensor's pose in it: the
/// estimate is R_hat = R_err R_Ss and p_hat = p_Ss + dp_S.
class DriftingOdometryFrame {
 public:
  /// The parts of S configured in the options (YAML frame_position_m, frame_rpy_deg) are
  /// known from the start; each unset part is taken at Boot.
  DriftingOdometryFrame(const std::optional<Eigen::Vector3d>& p_WS_m,
                        const std::optional<Eigen::Quaterniond>& q_WS);

  /// At the first call, takes the unset parts of S from the sensor's pose `now` (an
  /// odometry pipeline starts where it boots) and returns true; false afterwards.
  bool Boot(const MountMotion& now);
  /// S in W; with an unset part, valid after Boot.
  const Eigen::Isometry3d& T_WS() const { return T_WS_; }

  /// A step of the path (in S) integrated with the drifted attitude:
  /// dp_S += (R_err - I) step_S.
  void IntegratePath(const Eigen::Vector3d& step_S);
  /// Adds to the position error dp_S [m, in S].
  void AddPositionError(const Eigen::Vector3d& dp_S) { dp_S_ += dp_S; }
  /// Turns the attitude error: R_err = Exp(dtheta_S) R_err (dtheta in S).
  void RotateError(const Eigen::Vector3d& dtheta_S);
  /// The attitude error R_err (R_hat = R_err R_Ss).
  const Eigen::Matrix3d& R_err() const { return R_err_; }

  /// What a perfect sensor reports for the mount motion `at` (sim/mount_motion.h TruePose).
  core::PoseMeasurement TruePose(const MountMotion& at) const;
  /// What the drifting sensor reports for the motion `at` whose perfect report is `truth`:
  /// position p_Ss + dp_S (+ position_noise_S), attitude R_hat = R_err R_Ss (then
  /// R_hat Exp(rotation_noise_s), a right perturbation), body velocity v_s (+ R_hat^T
  /// velocity_error_S), angular rate as truth. An absent term is not added at all (so a
  /// noise-free sensor reports exactly the drifted truth). The covariances are the
  /// caller's to set.
  core::PoseMeasurement Measured(const MountMotion& at, const core::PoseMeasurement& truth,
                                 const std::optional<Eigen::Vector3d>& position_noise_S,
                                 const std::optional<Eigen::Vector3d>& rotation_noise_s,
                                 const std::optional<Eigen::Vector3d>& velocity_error_S) const;

 private:
  bool booted_ = false;
  bool position_configured_ = false;
  bool attitude_configured_ = false;
  Eigen::Isometry3d T_WS_ = Eigen::Isometry3d::Identity();
  Eigen::Matrix3d R_err_ = Eigen::Matrix3d::Identity();
  Eigen::Vector3d dp_S_ = Eigen::Vector3d::Zero();
};

}  // namespace tofu::sim
