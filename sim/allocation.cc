#include "sim/allocation.h"

#include <algorithm>
#include <cmath>

#include <Eigen/SVD>

#include "core/units.h"

namespace tofu::sim {
namespace {

Eigen::Matrix<double, 6, 1> Stack(const Wrench& w) {
  Eigen::Matrix<double, 6, 1> v;
  v << w.force_B_N, w.torque_B_Nm;
  return v;
}

// Among a + 2k*pi in [lo, hi], the value closest to `near`.
double ClosestEquivalentAngle(double a, double near, double lo, double hi) {
  const double two_pi = core::kTwoPi;
  double best = a;
  double best_distance = INFINITY;
  const double k0 = std::round((near - a) / two_pi);
  for (double k = k0 - 1.0; k <= k0 + 1.0; k += 1.0) {
    const double candidate = a + k * two_pi;
    if (candidate < lo || candidate > hi) continue;
    const double distance = std::abs(candidate - near);
    if (distance < best_distance) {
      best_distance = distance;
      best = candidate;
    }
  }
  return std::clamp(best, lo, hi);
}

}  // namespace

Allocator::Allocator(const AllocationParams& params) : params_(params) {
  const Eigen::Vector3d e_z = Eigen::Vector3d::UnitZ();
  for (int i = 0; i < kArmCount; ++i) {
    const ArmGeometry& arm = params_.arms[i];
    const Eigen::Vector3d e_tangent = arm.tilt_axis_B.normalized().cross(e_z);
    A_.block<3, 1>(0, 2 * i) = e_z;
    A_.block<3, 1>(3, 2 * i) = arm.p_CoM_hinge_B.cross(e_z);
    A_.block<3, 1>(0, 2 * i + 1) = e_tangent;
    A_.block<3, 1>(3, 2 * i + 1) = arm.p_CoM_hinge_B.cross(e_tangent);
  }
  // A has full row rank for any non-degenerate hexarotor layout; A^T (A A^T)^-1 is the
  // minimum-norm right inverse, which spreads effort over the arms.
  A_pinv_ = A_.transpose() * (A_ * A_.transpose()).inverse();
}

AllocationResult Allocator::Allocate(const Wrench& wrench,
                                     const std::array<double, kArmCount>& current_tilt_rad) const {
  AllocationResult result;
  Eigen::Matrix<double, 2 * kArmCount, 1> xy = A_pinv_ * Stack(wrench);

  // Saturation: scale the whole wrench so the most loaded rotor sits at its limit; the
  // direction of the wrench is kept, which keeps attitude and position errors coupled
  // to the same degree rather than sacrificing one axis arbitrarily.
  double max_rotor_thrust = 0.0;
  for (int i = 0; i < kArmCount; ++i) {
    max_rotor_thrust = std::max(max_rotor_thrust, xy.segment<2>(2 * i).norm() / kRotorsPerArm);
  }
  if (max_rotor_thrust > params_.rotor_max_thrust_N) {
    result.saturated = true;
    result.wrench_scale = params_.rotor_max_thrust_N / max_rotor_thrust;
    xy *= result.wrench_scale;
  }

  for (int i = 0; i < kArmCount; ++i) {
    const double x = xy(2 * i);
    const double y = xy(2 * i + 1);
    const double arm_thrust = std::hypot(x, y);
    double rotor_thrust = arm_thrust / kRotorsPerArm;
    if (rotor_thrust < params_.rotor_min_thrust_N) {
      rotor_thrust = params_.rotor_min_thrust_N;
      result.saturated = true;
    }
    result.command.rotor_thrust_N[i] = rotor_thrust;
    result.command.tilt_rad[i] =
        arm_thrust < params_.tilt_hold_thrust_N
            ? std::clamp(current_tilt_rad[i], params_.tilt_min_rad, params_.tilt_max_rad)
            : ClosestEquivalentAngle(std::atan2(y, x), current_tilt_rad[i],
                                     params_.tilt_min_rad, params_.tilt_max_rad);
  }
  return result;
}

Wrench Allocator::WrenchOf(const ActuatorCommand& command) const {
  Eigen::Matrix<double, 2 * kArmCount, 1> xy;
  for (int i = 0; i < kArmCount; ++i) {
    const double arm_thrust = kRotorsPerArm * command.rotor_thrust_N[i];
    xy(2 * i) = arm_thrust * std::cos(command.tilt_rad[i]);
    xy(2 * i + 1) = arm_thrust * std::sin(command.tilt_rad[i]);
  }
  const Eigen::Matrix<double, 6, 1> w = A_ * xy;
  return Wrench{w.head<3>(), w.tail<3>()};
}

}  // namespace tofu::sim
