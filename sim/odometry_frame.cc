#include "sim/odometry_frame.h"

#include "core/lie.h"

namespace tofu::sim {

DriftingOdometryFrame::DriftingOdometryFrame(const std::optional<Eigen::Vector3d>& p_WS_m,
                                             const std::optional<Eigen::Quaterniond>& q_WS)
    : position_configured_(p_WS_m.has_value()), attitude_configured_(q_WS.has_value()) {
  if (p_WS_m) T_WS_.translation() = *p_WS_m;
  if (q_WS) T_WS_.linear() = q_WS->normalized().toRotationMatrix();
}

bool DriftingOdometryFrame::Boot(const MountMotion& now) {
  if (booted_) return false;
  if (!position_configured_) T_WS_.translation() = now.p_Ws;
  if (!attitude_configured_) T_WS_.linear() = now.R_Ws;
  booted_ = true;
  return true;
}

void DriftingOdometryFrame::IntegratePath(const Eigen::Vector3d& step_S) {
  dp_S_ += (R_err_ - Eigen::Matrix3d::Identity()) * step_S;
}

void DriftingOdometryFrame::RotateError(const Eigen::Vector3d& dtheta_S) {
  R_err_ = core::ExpSO3(dtheta_S) * R_err_;
}

core::PoseMeasurement DriftingOdometryFrame::TruePose(const MountMotion& at) const {
  const Eigen::Matrix3d R_WS = T_WS_.linear();
  const Eigen::Vector3d p_WS = T_WS_.translation();
  return sim::TruePose(at, R_WS, p_WS);
}

core::PoseMeasurement DriftingOdometryFrame::Measured(
    const MountMotion& at, const core::PoseMeasurement& truth,
    const std::optional<Eigen::Vector3d>& position_noise_S,
    const std::optional<Eigen::Vector3d>& rotation_noise_s,
    const std::optional<Eigen::Vector3d>& velocity_error_S) const {
  const Eigen::Matrix3d R_WS = T_WS_.linear();
  const Eigen::Matrix3d R_Ss = R_WS.transpose() * at.R_Ws;
  const Eigen::Matrix3d R_hat = R_err_ * R_Ss;
  core::PoseMeasurement measured;
  measured.p_Ss = truth.p_Ss + dp_S_;
  if (position_noise_S) measured.p_Ss += *position_noise_S;
  const Eigen::Matrix3d R_meas = rotation_noise_s ? R_hat * core::ExpSO3(*rotation_noise_s) : R_hat;
  measured.q_Ss = core::CanonicalQuat(Eigen::Quaterniond(R_meas));
  measured.has_twist = true;
  measured.v_s_s_mps = truth.v_s_s_mps;
  if (velocity_error_S) measured.v_s_s_mps += R_hat.transpose() * *velocity_error_S;
  measured.omega_s_s_radps = truth.omega_s_s_radps;
  return measured;
}

}  // namespace tofu::sim
