// Allocation of a body wrench to six tilt angles and twelve rotor thrusts.

#include "sim/allocation.h"

#include <cmath>
#include <numbers>

#include <gtest/gtest.h>

#include "core/random.h"

namespace tofu::sim {
namespace {

// A symmetric hexarotor like models/robots/omav.xml: arms at 60 deg spacing, 0.35 m.
AllocationParams Hexarotor() {
  AllocationParams p;
  for (int k = 0; k < kArmCount; ++k) {
    const double yaw = k * std::numbers::pi / 3.0;
    const Eigen::Vector3d u(std::cos(yaw), std::sin(yaw), 0.0);
    p.arms[k].p_CoM_hinge_B = 0.35 * u;
    p.arms[k].tilt_axis_B = u;
  }
  p.rotor_max_thrust_N = 12.0;
  return p;
}

Eigen::Matrix<double, 6, 1> Stack(const Wrench& w) {
  Eigen::Matrix<double, 6, 1> v;
  v << w.force_B_N, w.torque_B_Nm;
  return v;
}

TEST(Allocator, ReproducesRandomFeasibleWrenches) {
  const Allocator allocator(Hexarotor());
  core::RandomStream rng(1, "allocation_test");
  for (int trial = 0; trial < 200; ++trial) {
    Wrench w;
    for (int k = 0; k < 3; ++k) {
      w.force_B_N(k) = rng.Uniform(-15.0, 15.0);
      w.torque_B_Nm(k) = rng.Uniform(-2.0, 2.0);
    }
    w.force_B_N.z() += 44.0;  // carry the weight of a 4.5 kg robot
    const AllocationResult r = allocator.Allocate(w, {});
    ASSERT_FALSE(r.saturated) << "trial " << trial;
    EXPECT_LT((Stack(allocator.WrenchOf(r.command)) - Stack(w)).norm(), 1e-9) << "trial " << trial;
  }
}

TEST(Allocator, HoverUsesEqualThrustsAndZeroTilt) {
  const Allocator allocator(Hexarotor());
  const AllocationResult r = allocator.Allocate({Eigen::Vector3d(0, 0, 48.0), Eigen::Vector3d::Zero()}, {});
  for (int k = 0; k < kArmCount; ++k) {
    EXPECT_NEAR(r.command.rotor_thrust_N[k], 4.0, 1e-9);
    EXPECT_NEAR(r.command.tilt_rad[k], 0.0, 1e-9);
  }
}

TEST(Allocator, PureLateralForceTiltsArmsInsteadOfTheBody) {
  const Allocator allocator(Hexarotor());
  // Hovering while pushing sideways: only possible with tilted arms.
  const Wrench w{Eigen::Vector3d(0.0, 20.0, 44.0), Eigen::Vector3d::Zero()};
  const AllocationResult r = allocator.Allocate(w, {});
  double max_tilt = 0.0;
  for (double a : r.command.tilt_rad) max_tilt = std::max(max_tilt, std::abs(a));
  EXPECT_GT(max_tilt, 0.3);
  EXPECT_LT((Stack(allocator.WrenchOf(r.command)) - Stack(w)).norm(), 1e-9);
}

TEST(Allocator, SaturationScalesTheWrenchAndIsReported) {
  const Allocator allocator(Hexarotor());
  const Wrench w{Eigen::Vector3d(0.0, 0.0, 400.0), Eigen::Vector3d(0.0, 0.0, 0.0)};
  const AllocationResult r = allocator.Allocate(w, {});
  EXPECT_TRUE(r.saturated);
  EXPECT_NEAR(r.wrench_scale, 144.0 / 400.0, 1e-9);
  for (double t : r.command.rotor_thrust_N) EXPECT_LE(t, 12.0 + 1e-9);
  EXPECT_LT((Stack(allocator.WrenchOf(r.command)) - r.wrench_scale * Stack(w)).norm(), 1e-9);
}

TEST(Allocator, TiltPicksTheEquivalentAngleClosestToTheCurrentOne) {
  AllocationParams params = Hexarotor();
  const Allocator allocator(params);
  // Force pointing "down" in B (robot upside down holding position): tilts near +-pi.
  const Wrench w{Eigen::Vector3d(0.0, 0.0, -44.0), Eigen::Vector3d::Zero()};
  std::array<double, kArmCount> near_plus{}, near_minus{};
  near_plus.fill(3.0);
  near_minus.fill(-3.0);
  const AllocationResult a = allocator.Allocate(w, near_plus);
  const AllocationResult b = allocator.Allocate(w, near_minus);
  for (int k = 0; k < kArmCount; ++k) {
    EXPECT_NEAR(a.command.tilt_rad[k], std::numbers::pi, 1e-6);
    EXPECT_NEAR(b.command.tilt_rad[k], -std::numbers::pi, 1e-6);
  }
}

TEST(Allocator, HoldsTiltWhenArmThrustVanishes) {
  const Allocator allocator(Hexarotor());
  std::array<double, kArmCount> current{};
  current.fill(0.7);
  const AllocationResult r = allocator.Allocate(Wrench{}, current);
  for (int k = 0; k < kArmCount; ++k) EXPECT_DOUBLE_EQ(r.command.tilt_rad[k], 0.7);
}

}  // namespace
}  // namespace tofu::sim
