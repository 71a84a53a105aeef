#include "core/lie.h"

#include <algorithm>
#include <cmath>

namespace tofu::core {

Eigen::Matrix3d Hat(const Eigen::Vector3d& v) {
  Eigen::Matrix3d m;
  m << 0.0, -v.z(), v.y(),  //
      v.z(), 0.0, -v.x(),   //
      -v.y(), v.x(), 0.0;
  return m;
}

Eigen::Vector3d Vee(const Eigen::Matrix3d& m) {
  return 0.5 * Eigen::Vector3d(m(2, 1) - m(1, 2), m(0, 2) - m(2, 0), m(1, 0) - m(0, 1));
}

Eigen::Matrix3d ExpSO3(const Eigen::Vector3d& rotation_vector) {
  return ExpQuat(rotation_vector).toRotationMatrix();
}

Eigen::Vector3d LogSO3(const Eigen::Matrix3d& R) { return LogQuat(Eigen::Quaterniond(R)); }

Eigen::Quaterniond ExpQuat(const Eigen::Vector3d& rotation_vector) {
  const double theta = rotation_vector.norm();
  const double half = 0.5 * theta;
  // sin(theta/2)/theta by its Taylor series below 1e-4 rad keeps full precision.
  const double k = theta < 1e-4 ? 0.5 - theta * theta / 48.0 : std::sin(half) / theta;
  Eigen::Quaterniond q(std::cos(half), k * rotation_vector.x(), k * rotation_vector.y(),
                       k * rotation_vector.z());
  return q.normalized();
}

Eigen::Vector3d LogQuat(const Eigen::Quaterniond& q_in) {
  const Eigen::Quaterniond q = CanonicalQuat(q_in.normalized());
  const double sin_half = q.vec().norm();
  // atan2 form is accurate for every angle; the series handles sin_half -> 0.
  if (sin_half < 1e-8) return 2.0 * q.vec() / q.w();
  const double theta = 2.0 * std::atan2(sin_half, q.w());
  return q.vec() * (theta / sin_half);
}

Eigen::Quaterniond CanonicalQuat(const Eigen::Quaterniond& q) {
  if (q.w() < 0.0) return Eigen::Quaterniond(-q.w(), -q.x(), -q.y(), -q.z());
  return q;
}

Eigen::Matrix3d RotationFromRollPitchYaw(double roll_rad, double pitch_rad, double yaw_rad) {
  return (Eigen::AngleAxisd(yaw_rad, Eigen::Vector3d::UnitZ()) *
          Eigen::AngleAxisd(pitch_rad, Eigen::Vector3d::UnitY()) *
          Eigen::AngleAxisd(roll_rad, Eigen::Vector3d::UnitX()))
      .toRotationMatrix();
}

double RotationAngleBetween(const Eigen::Matrix3d& R_a, const Eigen::Matrix3d& R_b) {
  return LogSO3(R_a.transpose() * R_b).norm();
}

double YawOfNearestZRotation(const Eigen::Matrix3d& R) {
  return std::atan2(R(1, 0) - R(0, 1), R(0, 0) + R(1, 1));
}

Eigen::Isometry3d YawPositionRegistration(const Eigen::Isometry3d& T_AX,
                                          const Eigen::Isometry3d& T_BX) {
  const double yaw_rad = YawOfNearestZRotation(T_AX.linear() * T_BX.linear().transpose());
  Eigen::Isometry3d T_AB = Eigen::Isometry3d::Identity();
  T_AB.linear() = Eigen::AngleAxisd(yaw_rad, Eigen::Vector3d::UnitZ()).toRotationMatrix();
  T_AB.translation() = T_AX.translation() - T_AB.linear() * T_BX.translation();
  return T_AB;
}

Eigen::Matrix3d RightJacobianSO3(const Eigen::Vector3d& phi) {
  const double theta = phi.norm();
  const Eigen::Matrix3d phi_hat = Hat(phi);
  if (theta < 1e-5) return Eigen::Matrix3d::Identity() - 0.5 * phi_hat + phi_hat * phi_hat / 6.0;
  const double theta2 = theta * theta;
  return Eigen::Matrix3d::Identity() - (1.0 - std::cos(theta)) / theta2 * phi_hat +
         (theta - std::sin(theta)) / (theta2 * theta) * phi_hat * phi_hat;
}

Eigen::Matrix3d InverseRightJacobianSO3(const Eigen::Vector3d& phi) {
  const double theta = phi.norm();
  const Eigen::Matrix3d phi_hat = Hat(phi);
  if (theta < 1e-5) return Eigen::Matrix3d::Identity() + 0.5 * phi_hat + phi_hat * phi_hat / 12.0;
  const double theta2 = theta * theta;
  // (1 + cos θ) / sin θ written as cot(θ/2): finite at θ = π, where the former is 0/0.
  return Eigen::Matrix3d::Identity() + 0.5 * phi_hat +
         (1.0 / theta2 - 1.0 / (2.0 * theta * std::tan(0.5 * theta))) * phi_hat * phi_hat;
}

}  // namespace tofu::core
