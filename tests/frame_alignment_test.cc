// Closed-form frame alignment and its observability.

#include "estimator/frame_alignment.h"

#include <cmath>

#include <gtest/gtest.h>

#include "core/lie.h"
#include "core/random.h"

namespace tofu::estimator {
namespace {

Eigen::Isometry3d PaperOffset() {
  // The seed paper's metric evaluation: 30, 60, 120 deg in roll, pitch, yaw.
  Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
  T.linear() = core::RotationFromRollPitchYaw(30.0 * M_PI / 180.0, 60.0 * M_PI / 180.0,
                                              120.0 * M_PI / 180.0);
  T.translation() = Eigen::Vector3d(1.0, -2.0, 0.5);
  return T;
}

TEST(AlignPositions, RecoversTheTransformFromPlanarMotionWithNoise) {
  const Eigen::Isometry3d T_AL = PaperOffset();
  core::RandomStream rng(4, "alignment");
  std::vector<Eigen::Vector3d> p_L, p_A;
  for (int i = 0; i < 400; ++i) {
    const double t = 0.05 * i;
    const Eigen::Vector3d p(2.0 * std::sin(0.3 * t), 1.5 * std::sin(0.6 * t), 1.5 + 0.2 * std::sin(t));
    p_L.push_back(p);
    p_A.push_back(T_AL * p + 0.002 * Eigen::Vector3d(rng.Normal(), rng.Normal(), rng.Normal()));
  }
  const auto result = AlignPositions(p_L, p_A);
  ASSERT_TRUE(result.has_value());
  EXPECT_EQ(result->observable_rotation_dofs, 3);
  EXPECT_LT(core::RotationAngleBetween(result->T_AL.linear(), T_AL.linear()), 0.005);
  EXPECT_LT((result->T_AL.translation() - T_AL.translation()).norm(), 0.01);
  EXPECT_NEAR(result->rms_residual_m, 0.002 * std::sqrt(3.0), 0.001);
}

TEST(AlignPositions, VerticalOnlyMotionLeavesYawUnobservable) {
  std::vector<Eigen::Vector3d> p_L, p_A;
  const Eigen::Isometry3d T_AL = PaperOffset();
  for (int i = 0; i < 100; ++i) {
    const Eigen::Vector3d p(0.0, 0.0, 0.5 + 0.015 * i);
    p_L.push_back(p);
    p_A.push_back(T_AL * p);
  }
  const auto result = AlignPositions(p_L, p_A);
  ASSERT_TRUE(result.has_value());
  EXPECT_EQ(result->observable_rotation_dofs, 2);
  // The vertical axis itself is mapped right (the data constrain it) ...
  EXPECT_LT((result->T_AL.linear() * Eigen::Vector3d::UnitZ() -
             T_AL.linear() * Eigen::Vector3d::UnitZ()).norm(), 1e-9);
}

TEST(AlignPositions, TooFewOrCollapsedPointsGiveNothing) {
  EXPECT_FALSE(AlignPositions({Eigen::Vector3d::Zero(), Eigen::Vector3d::Ones()},
                              {Eigen::Vector3d::Zero(), Eigen::Vector3d::Ones()}).has_value());
  const std::vector<Eigen::Vector3d> same(10, Eigen::Vector3d(1, 2, 3));
  EXPECT_FALSE(AlignPositions(same, same).has_value());
}

TEST(AlignPositionsLevel, RecoversYawAndTranslationFromOneStraightLeg) {
  // A straight level leg, which leaves Umeyama the roll about it: the level closed form
  // takes yaw from the horizontal components and the translation from the centroids.
  Eigen::Isometry3d T_AL = Eigen::Isometry3d::Identity();
  T_AL.linear() = Eigen::AngleAxisd(-2.4, Eigen::Vector3d::UnitZ()).toRotationMatrix();
  T_AL.translation() = Eigen::Vector3d(-11.7, 3.2, 0.4);
  std::vector<Eigen::Vector3d> p_L, p_A;
  for (int i = 0; i < 50; ++i) {
    const Eigen::Vector3d p = Eigen::Vector3d(1.0, -2.0, 2.5) + 0.2 * i * Eigen::Vector3d(0.8, 0.6, 0.0);
    p_L.push_back(p);
    p_A.push_back(T_AL * p);
  }
  const auto level = AlignPositionsLevel(p_L, p_A);
  ASSERT_TRUE(level.has_value());
  EXPECT_LT(core::RotationAngleBetween(level->linear(), T_AL.linear()), 1e-12);
  EXPECT_LT((level->translation() - T_AL.translation()).norm(), 1e-9);
  // Vertical motion only: no heading information, a level guess all the same.
  std::vector<Eigen::Vector3d> up_L, up_A;
  for (int i = 0; i < 10; ++i) {
    up_L.emplace_back(0.0, 0.0, 0.3 * i);
    up_A.push_back(T_AL * up_L.back());
  }
  const auto vertical = AlignPositionsLevel(up_L, up_A);
  ASSERT_TRUE(vertical.has_value());
  EXPECT_LT((vertical->linear() * Eigen::Vector3d::UnitZ() - Eigen::Vector3d::UnitZ()).norm(), 1e-12);
  EXPECT_FALSE(AlignPositionsLevel({Eigen::Vector3d::Zero(), Eigen::Vector3d::Ones()},
                                   {Eigen::Vector3d::Zero(), Eigen::Vector3d::Ones()})
                   .has_value());
}

}  // namespace
}  // namespace tofu::estimator
