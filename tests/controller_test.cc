// Geometric SE(3) controller: the wrench it commands for known errors.

#include "sim/controller.h"

#include <numbers>

#include <gtest/gtest.h>

#include "core/lie.h"

namespace tofu::sim {
namespace {

RigidBodyParams Body() {
  RigidBodyParams p;
  p.mass_kg = 4.5;
  p.inertia_B_kgm2 = Eigen::Vector3d(0.1, 0.11, 0.18).asDiagonal();
  p.gravity_mps2 = 9.81;
  return p;
}

TEST(GeometricController, AtTheReferenceCommandsGravityCompensationInBody) {
  ControllerOptions options;
  GeometricController controller(options, Body());
  RobotState state;
  state.q_WB = Eigen::Quaterniond(core::RotationFromRollPitchYaw(0.5, -0.2, 1.0));
  Reference ref;
  ref.q_WB = state.q_WB;
  const Wrench w = controller.Compute(state, ref);
  const Eigen::Vector3d expected_B =
      state.q_WB.toRotationMatrix().transpose() * Eigen::Vector3d(0, 0, 4.5 * 9.81);
  EXPECT_LT((w.force_B_N - expected_B).norm(), 1e-12);
  EXPECT_LT(w.torque_B_Nm.norm(), 1e-12);
}

TEST(GeometricController, PositionErrorPushesBackWithTheGain) {
  ControllerOptions options;
  options.position_integral_gain_per_s3.setZero();
  GeometricController controller(options, Body());
  RobotState state;
  state.p_WB = Eigen::Vector3d(0.1, 0.0, 0.0);
  const Wrench w = controller.Compute(state, Reference{});
  EXPECT_NEAR(w.force_B_N.x(), -4.5 * options.position_gain_per_s2.x() * 0.1, 1e-12);
  EXPECT_NEAR(w.force_B_N.z(), 4.5 * 9.81, 1e-12);
}

TEST(GeometricController, AttitudeErrorTorqueOpposesTheRotation) {
  ControllerOptions options;
  options.attitude_integral_gain_per_s3.setZero();
  GeometricController controller(options, Body());
  RobotState state;
  const double angle = 0.2;
  state.q_WB = Eigen::Quaterniond(Eigen::AngleAxisd(angle, Eigen::Vector3d::UnitX()));
  const Wrench w = controller.Compute(state, Reference{});
  // e_R = sin(angle) about x for a rotation about x (Lee et al. 2010).
  EXPECT_NEAR(w.torque_B_Nm.x(), -0.1 * options.attitude_gain_per_s2.x() * std::sin(angle), 1e-12);
  EXPECT_NEAR(w.torque_B_Nm.y(), 0.0, 1e-12);
  EXPECT_NEAR(w.torque_B_Nm.z(), 0.0, 1e-12);
}

TEST(GeometricController, IntegratorSeesOnlyTheClippedError) {
  ControllerOptions options;
  GeometricController controller(options, Body());
  RobotState state;
  state.p_WB = Eigen::Vector3d(0.0, 0.0, -1.0);  // a large transient
  Wrench w;
  for (int k = 0; k <= 200; ++k) {  // 1 s
    state.t_ns = static_cast<core::Time>(k) * 5'000'000;
    w = controller.Compute(state, Reference{});
  }
  const double integral_mps2 = options.position_integral_gain_per_s3.z() *
                               options.integral_error_band_m * 1.0;
  EXPECT_NEAR(w.force_B_N.z(),
              4.5 * (9.81 + options.position_gain_per_s2.z() * 1.0 + integral_mps2), 1e-9);
}

TEST(GeometricController, IntegralRemovesAConstantBiasAndIsBounded) {
  ControllerOptions options;
  options.position_integral_gain_per_s3 = Eigen::Vector3d(6.0, 6.0, 8.0);
  GeometricController controller(options, Body());
  RobotState state;
  state.p_WB = Eigen::Vector3d(0.0, 0.0, -0.05);  // persistently low
  Wrench w;
  // 20 s: the integrator sees the error clipped to the band, 0.02 m * 20 s * 8 > limit.
  for (int k = 0; k <= 4000; ++k) {
    state.t_ns = static_cast<core::Time>(k) * 5'000'000;
    w = controller.Compute(state, Reference{});
  }
  // Proportional part plus the integral saturated at its limit.
  const double expected = 4.5 * (9.81 + options.position_gain_per_s2.z() * 0.05 +
                                 options.integral_limit_mps2);
  EXPECT_NEAR(w.force_B_N.z(), expected, 1e-9);
}

}  // namespace
}  // namespace tofu::sim
