// core: SO(3) helpers and seeded random streams.

#include <sched.h>

#include <cmath>
#include <numbers>

#include <gtest/gtest.h>

#include "core/cores.h"
#include "core/lie.h"
#include "core/random.h"
#include "core/time.h"

namespace tofu::core {
namespace {

TEST(Lie, ExpLogRoundTripIncludingSmallAndNearPiAngles) {
  RandomStream rng(3, "lie");
  for (double angle : {1e-12, 1e-6, 0.1, 1.0, 3.0, std::numbers::pi - 1e-7}) {
    for (int k = 0; k < 20; ++k) {
      Eigen::Vector3d axis(rng.Normal(), rng.Normal(), rng.Normal());
      const Eigen::Vector3d w = angle * axis.normalized();
      EXPECT_LT((LogSO3(ExpSO3(w)) - w).norm(), 1e-9 * std::max(1.0, angle)) << angle;
    }
  }
}

TEST(Lie, ExpMatchesEigenAngleAxis) {
  const Eigen::Vector3d w(0.3, -0.4, 1.2);
  const Eigen::Matrix3d expected = Eigen::AngleAxisd(w.norm(), w.normalized()).toRotationMatrix();
  EXPECT_LT((ExpSO3(w) - expected).norm(), 1e-14);
}

TEST(Lie, HatVeeAreInverse) {
  const Eigen::Vector3d v(1.0, -2.0, 3.0);
  EXPECT_EQ(Vee(Hat(v)), v);
  EXPECT_LT((Hat(v) * Eigen::Vector3d(0.5, 0.1, -0.7) - v.cross(Eigen::Vector3d(0.5, 0.1, -0.7))).norm(), 1e-15);
}

TEST(Lie, CanonicalQuaternionHasNonNegativeW) {
  const Eigen::Quaterniond q(-0.5, 0.5, 0.5, 0.5);
  const Eigen::Quaterniond c = CanonicalQuat(q);
  EXPECT_GE(c.w(), 0.0);
  EXPECT_LT((c.toRotationMatrix() - q.toRotationMatrix()).norm(), 1e-15);
}

TEST(Lie, RollPitchYawConvention) {
  const Eigen::Matrix3d R = RotationFromRollPitchYaw(0.0, 0.0, std::numbers::pi / 2);
  EXPECT_LT((R * Eigen::Vector3d::UnitX() - Eigen::Vector3d::UnitY()).norm(), 1e-15);
  EXPECT_NEAR(RotationAngleBetween(Eigen::Matrix3d::Identity(),
                                   RotationFromRollPitchYaw(0.3, 0.0, 0.0)),
              0.3, 1e-12);
}

TEST(Lie, RightJacobianAndItsInverseMatchNumericDifferentiation) {
  // Exp(φ + δ) = Exp(φ) Exp(Jr(φ) δ) and Log(Exp(φ) Exp(δ)) = φ + Jr⁻¹(φ) δ to first order,
  // checked column by column with central differences, small to near-π angles.
  const double h = 1e-6;
  for (const Eigen::Vector3d& phi :
       {Eigen::Vector3d(1e-7, -2e-7, 3e-7), Eigen::Vector3d(0.3, -0.2, 0.1),
        Eigen::Vector3d(1.5, 2.0, -0.5), Eigen::Vector3d(0.0, 3.0, 0.1)}) {
    Eigen::Matrix3d Jr_numeric, Jr_inv_numeric;
    for (int k = 0; k < 3; ++k) {
      const Eigen::Vector3d d = h * Eigen::Vector3d::Unit(k);
      Jr_numeric.col(k) = (LogSO3(ExpSO3(phi).transpose() * ExpSO3(phi + d)) -
                           LogSO3(ExpSO3(phi).transpose() * ExpSO3(phi - d))) / (2 * h);
      Jr_inv_numeric.col(k) =
          (LogSO3(ExpSO3(phi) * ExpSO3(d)) - LogSO3(ExpSO3(phi) * ExpSO3(-d))) / (2 * h);
    }
    EXPECT_LT((RightJacobianSO3(phi) - Jr_numeric).norm(), 1e-6) << phi.transpose();
    EXPECT_LT((InverseRightJacobianSO3(phi) - Jr_inv_numeric).norm(), 1e-6) << phi.transpose();
    EXPECT_LT((RightJacobianSO3(phi) * InverseRightJacobianSO3(phi) -
               Eigen::Matrix3d::Identity()).norm(), 1e-9);
  }
  // Exactly π: finite (the (1 + cos θ)/sin θ form is 0/0 there).
  EXPECT_TRUE(InverseRightJacobianSO3(Eigen::Vector3d(0, 0, std::numbers::pi)).allFinite());
}

TEST(Time, ConversionsRoundToTheNearestNanosecond) {
  EXPECT_EQ(SecondsToTime(1.0), 1'000'000'000);
  EXPECT_EQ(SecondsToTime(0.001), 1'000'000);
  EXPECT_EQ(PeriodFromRate(200.0), 5'000'000);
  EXPECT_EQ(PeriodFromRate(3.0), 333'333'333);
  EXPECT_EQ(SecondsToTime(-0.5), -500'000'000);
}

TEST(RandomStream, SameSeedAndNameGiveTheSameSequence) {
  RandomStream a(42, "imu"), b(42, "imu");
  for (int k = 0; k < 100; ++k) EXPECT_EQ(a.Normal(), b.Normal());
}

// The components of a random vector come in one defined order, whatever the compiler
// (a three-argument constructor would leave it to the compiler's argument order).
TEST(RandomStream, Normal3DrawsZThenYThenX) {
  RandomStream a(42, "vio"), b(42, "vio");
  for (int k = 0; k < 10; ++k) {
    const Eigen::Vector3d v = a.Normal3();
    const double first = b.Normal();
    const double second = b.Normal();
    const double third = b.Normal();
    EXPECT_EQ(v.z(), first);
    EXPECT_EQ(v.y(), second);
    EXPECT_EQ(v.x(), third);
  }
}

TEST(RandomStream, StreamsAreIndependentOfEachOtherAndOfTheSeed) {
  EXPECT_NE(StreamSeed(42, "imu"), StreamSeed(42, "vio"));
  EXPECT_NE(StreamSeed(42, "imu"), StreamSeed(43, "imu"));
  // The sample correlation of two streams is within its 4-sigma bound 4/sqrt(n).
  RandomStream a(42, "imu"), b(42, "vio");
  const int n = 20000;
  double sum = 0.0;
  for (int k = 0; k < n; ++k) sum += a.Normal() * b.Normal();
  EXPECT_LT(std::abs(sum / n), 4.0 / std::sqrt(n));
}

TEST(RandomStream, NormalHasUnitVariance) {
  RandomStream rng(7, "variance");
  const int n = 40000;
  double sum = 0.0, sum_sq = 0.0;
  for (int k = 0; k < n; ++k) {
    const double x = rng.Normal();
    sum += x;
    sum_sq += x * x;
  }
  const double mean = sum / n;
  const double var = sum_sq / n - mean * mean;
  // Standard errors: mean 1/sqrt(n), variance sqrt(2/n); 5-sigma bounds.
  EXPECT_LT(std::abs(mean), 5.0 / std::sqrt(n));
  EXPECT_LT(std::abs(var - 1.0), 5.0 * std::sqrt(2.0 / n));
}

// The cores a run may use follow the process's affinity (taskset, a Slurm allocation), not
// the machine's count: restricted to one processor, one.
TEST(UsableCores, FollowsTheAffinityNotTheMachine) {
  cpu_set_t all;
  CPU_ZERO(&all);
  ASSERT_EQ(sched_getaffinity(0, sizeof(all), &all), 0);
  EXPECT_EQ(UsableCores(), CPU_COUNT(&all));
  int first = 0;
  while (!CPU_ISSET(first, &all)) ++first;
  cpu_set_t one;
  CPU_ZERO(&one);
  CPU_SET(first, &one);
  ASSERT_EQ(sched_setaffinity(0, sizeof(one), &one), 0);
  EXPECT_EQ(UsableCores(), 1);
  ASSERT_EQ(sched_setaffinity(0, sizeof(all), &all), 0);
}

}  // namespace
}  // namespace tofu::core
