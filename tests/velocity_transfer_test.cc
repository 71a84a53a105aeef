// Paper eq. (1) end to end: two pose sensors on one rigid body, with different mounts,
// lever arms, reference frames and rates, differentiated and transferred to one frame,
// are consistent under the CM distance only when the lever arm is accounted for. Also the
// differentiation of jittered, gapped position streams against analytic velocities.

#include <algorithm>
#include <cmath>
#include <cstddef>
#include <cstdio>
#include <limits>
#include <numbers>
#include <string>
#include <vector>

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <gtest/gtest.h>

#include "core/lie.h"
#include "core/random.h"
#include "core/time.h"
#include "estimator/consistency.h"
#include "estimator/velocity.h"

namespace tofu::estimator {
namespace {

// ---- analytic rigid-body motion of the body frame I in the world W ----
// R_WI(t) = R0 Exp(omega_I t): constant body rate of 1 rad/s about a tilted axis.
// p_WI(t) = 0.4 t axis + 0.1 sin(0.7 t) e1 + 0.1 (1 − cos(0.5 t)) e2: a screw along the
// rotation axis with a small wobble across it (so the body-frame velocity varies).
struct RigidBody {
  Eigen::Matrix3d R0 = core::RotationFromRollPitchYaw(0.3, -0.2, 0.7);
  Eigen::Vector3d omega_I = Eigen::Vector3d(0.2, -0.3, 1.0).normalized();  // rad/s
  Eigen::Vector3d p0{1.0, 2.0, 3.0};
  Eigen::Vector3d axis_W = R0 * omega_I;
  Eigen::Vector3d e1 = axis_W.unitOrthogonal();
  Eigen::Vector3d e2 = axis_W.cross(e1);

  Eigen::Matrix3d R_WI(double t) const { return R0 * core::ExpSO3(omega_I * t); }
  Eigen::Vector3d p_WI(double t) const {
    return p0 + 0.4 * t * axis_W + 0.02 * std::sin(0.7 * t) * e1 +
           0.02 * (1.0 - std::cos(0.5 * t)) * e2;
  }
  Eigen::Vector3d v_WI(double t) const {
    return 0.4 * axis_W + 0.014 * std::cos(0.7 * t) * e1 + 0.01 * std::sin(0.5 * t) * e2;
  }
};

// A pose sensor: mount (R_Is, p_Is) on the body, reference frame (R_WS, p_WS) in W.
struct Mount {
  Eigen::Matrix3d R_Is;
  Eigen::Vector3d p_Is;
  Eigen::Matrix3d R_WS;
  Eigen::Vector3d p_WS;

  Eigen::Matrix3d R_Ss(const RigidBody& body, double t) const {
    return R_WS.transpose() * body.R_WI(t) * R_Is;
  }
  Eigen::Vector3d p_Ss(const RigidBody& body, double t) const {
    return R_WS.transpose() * (body.p_WI(t) + body.R_WI(t) * p_Is - p_WS);
  }
  // True velocity of the mount point, in the mount frame s.
  Eigen::Vector3d v_s_s(const RigidBody& body, double t) const {
    const Eigen::Vector3d v_I = body.R_WI(t).transpose() * body.v_WI(t) +
                                body.omega_I.cross(p_Is);
    return R_Is.transpose() * v_I;
  }
};

Mount SensorA() {
  return {core::RotationFromRollPitchYaw(0.1, -0.2, 0.5), Eigen::Vector3d(0.3, -0.1, 0.2),
          core::RotationFromRollPitchYaw(0.05, 0.1, 1.0), Eigen::Vector3d(5.0, -3.0, 1.0)};
}
Mount SensorB() {
  return {core::RotationFromRollPitchYaw(2.8, 0.3, -1.2), Eigen::Vector3d(-0.25, 0.2, -0.15),
          core::RotationFromRollPitchYaw(-0.1, 0.05, -2.0), Eigen::Vector3d(-10.0, 4.0, 0.5)};
}

// A sampled pose stream: nominal period plus uniform jitter, strictly increasing.
struct PoseStream {
  std::vector<core::Time> t_ns;
  std::vector<Eigen::Vector3d> p;
  std::vector<Eigen::Quaterniond> q;
};

PoseStream Sample(const RigidBody& body, const Mount& mount, double rate_hz, double jitter_s,
                  double duration_s, const char* stream_name) {
  core::RandomStream random(7, stream_name);
  PoseStream stream;
  const double period = 1.0 / rate_hz;
  for (int k = 1; k * period < duration_s; ++k) {
    const double t = k * period + random.Uniform(-jitter_s, jitter_s);
    stream.t_ns.push_back(core::SecondsToTime(t));
    const double t_exact = core::TimeToSeconds(stream.t_ns.back());
    stream.p.push_back(mount.p_Ss(body, t_exact));
    stream.q.push_back(core::CanonicalQuat(Eigen::Quaterniond(mount.R_Ss(body, t_exact))));
  }
  return stream;
}

// Attitude of a stream at time t by slerp between the bracketing samples.
Eigen::Matrix3d AttitudeAt(const PoseStream& s, core::Time t_ns) {
  const auto it = std::lower_bound(s.t_ns.begin(), s.t_ns.end(), t_ns);
  const auto k = static_cast<std::size_t>(it - s.t_ns.begin());
  if (k < s.t_ns.size() && s.t_ns[k] == t_ns) return s.q[k].toRotationMatrix();
  const double w = static_cast<double>(t_ns - s.t_ns[k - 1]) /
                   static_cast<double>(s.t_ns[k] - s.t_ns[k - 1]);
  return s.q[k - 1].slerp(w, s.q[k]).toRotationMatrix();
}

std::size_t IndexOf(const std::vector<core::Time>& t_ns, core::Time t) {
  return static_cast<std::size_t>(std::lower_bound(t_ns.begin(), t_ns.end(), t) - t_ns.begin());
}

TEST(TransferVelocity, MatchesRigidBodyTruth) {
  const RigidBody body;
  const Mount a = SensorA();
  const Mount b = SensorB();
  const Eigen::Matrix3d R_AB = a.R_WS.transpose() * b.R_WS;
  const Eigen::Vector3d p_ba = b.R_Is.transpose() * (a.p_Is - b.p_Is);
  for (const double t : {0.0, 0.37, 1.9, 4.2}) {
    const Eigen::Matrix3d R_Bb = b.R_Ss(body, t);
    const Eigen::Vector3d omega_b_b = b.R_Is.transpose() * body.omega_I;
    const Eigen::Vector3d v_b_b = b.v_s_s(body, t);
    const Eigen::Vector3d v_a_a =
        TransferVelocity(a.R_Ss(body, t), R_AB, R_Bb, v_b_b, omega_b_b, p_ba);
    EXPECT_LT((v_a_a - a.v_s_s(body, t)).norm(), 1e-12) << "t = " << t;
    // The position-only form with b's velocity in B gives the same.
    const Eigen::Vector3d v_a_a_ref = TransferVelocityFromReference(
        a.R_Ss(body, t), R_AB, R_Bb * v_b_b, R_Bb, omega_b_b, p_ba);
    EXPECT_LT((v_a_a_ref - a.v_s_s(body, t)).norm(), 1e-12) << "t = " << t;
  }
}

// The acceptance test of eq. (1): a at 200 Hz, b at 20 Hz, both jittered, differentiated,
// b transferred to a with the true R_AB; CM over 1 s windows.
TEST(VelocityTransfer, TwoMountsAreConsistentOnlyWithTheLeverArm) {
  const RigidBody body;
  const Mount mount_a = SensorA();
  const Mount mount_b = SensorB();
  const double duration_s = 10.0;
  const PoseStream a = Sample(body, mount_a, 200.0, 1e-3, duration_s, "a");
  const PoseStream b = Sample(body, mount_b, 20.0, 5e-3, duration_s, "b");

  // a: velocity in A by differentiation, rotated into a with a's own attitude.
  DifferentiationOptions fast;
  fast.half_window_ns = 25'000'000;
  const VelocitySeries v_A = DifferentiatePositions(a.t_ns, a.p, fast);
  ASSERT_GT(v_A.t_ns.size(), 1900u);
  VelocitySeries a_in_a;
  for (std::size_t k = 0; k < v_A.t_ns.size(); ++k) {
    const std::size_t i = IndexOf(a.t_ns, v_A.t_ns[k]);
    a_in_a.t_ns.push_back(v_A.t_ns[k]);
    a_in_a.v_mps.push_back(a.q[i].toRotationMatrix().transpose() * v_A.v_mps[k]);
  }

  // b: velocity in B and body rate in b, transferred to a by eq. (1); negative controls
  // without the lever arm, and with the frame alignment R_AB off by 10 degrees of yaw
  // (the paper's failure mode i).
  DifferentiationOptions slow;
  slow.half_window_ns = 70'000'000;
  const VelocitySeries v_B = DifferentiatePositions(b.t_ns, b.p, slow);
  const AngularRateSeries omega_b = DifferentiateOrientations(b.t_ns, b.q, slow);
  ASSERT_EQ(v_B.t_ns, omega_b.t_ns);
  ASSERT_GT(v_B.t_ns.size(), 190u);
  const Eigen::Matrix3d R_AB = mount_a.R_WS.transpose() * mount_b.R_WS;
  const Eigen::Vector3d p_ba = mount_b.R_Is.transpose() * (mount_a.p_Is - mount_b.p_Is);
  const Eigen::Matrix3d R_AB_misaligned =
      R_AB * core::RotationFromRollPitchYaw(0.0, 0.0, 10.0 * std::numbers::pi / 180.0);
  VelocitySeries b_in_a;
  VelocitySeries b_in_a_no_lever;
  VelocitySeries b_in_a_misaligned;
  for (std::size_t k = 0; k < v_B.t_ns.size(); ++k) {
    const core::Time t = v_B.t_ns[k];
    if (t <= a.t_ns.front() || t >= a.t_ns.back()) continue;
    const Eigen::Matrix3d R_Bb = b.q[IndexOf(b.t_ns, t)].toRotationMatrix();
    const Eigen::Matrix3d R_Aa = AttitudeAt(a, t);
    const Eigen::Vector3d v_b_b = R_Bb.transpose() * v_B.v_mps[k];
    b_in_a.t_ns.push_back(t);
    b_in_a.v_mps.push_back(
        TransferVelocity(R_Aa, R_AB, R_Bb, v_b_b, omega_b.omega_radps[k], p_ba));
    b_in_a_no_lever.t_ns.push_back(t);
    b_in_a_no_lever.v_mps.push_back(TransferVelocity(R_Aa, R_AB, R_Bb, v_b_b,
                                                     omega_b.omega_radps[k],
                                                     Eigen::Vector3d::Zero()));
    b_in_a_misaligned.t_ns.push_back(t);
    b_in_a_misaligned.v_mps.push_back(TransferVelocity(R_Aa, R_AB_misaligned, R_Bb, v_b_b,
                                                       omega_b.omega_radps[k], p_ba));
  }

  // Pointwise, the transferred velocity matches a's true velocity up to the truncation of
  // the 20 Hz fit, |p'''| h^2 / 6 with |p'''| <= |omega|^3 |p_Ib| + wobble ~ 0.4 m/s^3 and
  // h = 70 ms: 3.3e-4 m/s.
  for (std::size_t k = 0; k < b_in_a.t_ns.size(); ++k) {
    const double t = core::TimeToSeconds(b_in_a.t_ns[k]);
    ASSERT_LT((b_in_a.v_mps[k] - mount_a.v_s_s(body, t)).norm(), 3.3e-4) << "t = " << t;
  }

  // The CM of two finite samples of the same signal is not zero: with m samples over a
  // velocity range R the ECDFs differ by up to 1/m, D ~ (2R/3)^½ / m per axis (0.02 to
  // 0.04 for R = 1 m/s and m = 20). The true velocities at the very same stamps give this
  // sampling floor, reported for comparison; the motion keeps R small (a screw along the
  // rotation axis, whose body-frame velocity is constant, plus a 0.014 m/s wobble) so the
  // floor stays well below 0.02.
  VelocitySeries truth_a;
  VelocitySeries truth_b;
  for (const core::Time t : a_in_a.t_ns) {
    truth_a.t_ns.push_back(t);
    truth_a.v_mps.push_back(mount_a.v_s_s(body, core::TimeToSeconds(t)));
  }
  for (const core::Time t : b_in_a.t_ns) {
    truth_b.t_ns.push_back(t);
    truth_b.v_mps.push_back(mount_a.v_s_s(body, core::TimeToSeconds(t)));
  }

  double worst_consistent = 0.0;
  double worst_floor = 0.0;
  double best_inconsistent = 1e9;
  double best_misaligned = 1e9;
  for (core::Time t = core::SecondsToTime(1.5); t <= core::SecondsToTime(9.5);
       t += 100'000'000) {
    const auto consistent = WindowConsistency(a_in_a, b_in_a, t, ConsistencyMetric::kCm);
    const auto no_lever = WindowConsistency(a_in_a, b_in_a_no_lever, t, ConsistencyMetric::kCm);
    const auto misaligned =
        WindowConsistency(a_in_a, b_in_a_misaligned, t, ConsistencyMetric::kCm);
    const auto floor = WindowConsistency(truth_a, truth_b, t, ConsistencyMetric::kCm);
    ASSERT_TRUE(consistent.has_value());
    ASSERT_TRUE(no_lever.has_value());
    ASSERT_TRUE(misaligned.has_value());
    ASSERT_TRUE(floor.has_value());
    EXPECT_LT(*consistent, 0.02) << "t = " << core::TimeToSeconds(t);
    EXPECT_GT(*no_lever, 0.1) << "t = " << core::TimeToSeconds(t);
    EXPECT_GT(*misaligned, 0.1) << "t = " << core::TimeToSeconds(t);
    worst_consistent = std::max(worst_consistent, *consistent);
    worst_floor = std::max(worst_floor, *floor);
    best_inconsistent = std::min(best_inconsistent, *no_lever);
    best_misaligned = std::min(best_misaligned, *misaligned);
  }
  RecordProperty("worst_consistent_cm", std::to_string(worst_consistent));
  RecordProperty("best_no_lever_arm_cm", std::to_string(best_inconsistent));
  RecordProperty("worst_sampling_floor_cm", std::to_string(worst_floor));
  RecordProperty("best_misaligned_cm", std::to_string(best_misaligned));
  std::printf("CM over 1 s windows: with lever arm <= %.4f (sampling floor <= %.4f), "
              "without >= %.4f, R_AB off by 10 deg >= %.4f\n",
              worst_consistent, worst_floor, best_inconsistent, best_misaligned);
}

// Two quadratics, one before and one after a 0.4 s gap (as after a relocalisation jump),
// sampled at 50 Hz with ±4 ms jitter. A degree-2 fit is exact for a quadratic whatever
// the spacing, so the tolerance is round-off; a fit across the gap would mix the two
// pieces and fail, and the samples bordering the gap have no neighbour on their outer
// side, so they get no velocity.
TEST(DifferentiatePositions, ExactForQuadraticMotionDespiteJitterAndNothingAcrossAGap) {
  const Eigen::Vector3d p1(1.0, -2.0, 0.5), v1(0.3, -0.7, 1.1), acc1(0.5, 0.2, -0.9);
  const Eigen::Vector3d p2(40.0, 3.0, -2.0), v2(-1.3, 0.4, 0.2), acc2(-0.4, 1.0, 0.3);
  const double gap_begin = 1.8;
  const double gap_end = 2.2;
  auto position = [&](double t) -> Eigen::Vector3d {
    if (t < gap_begin) return p1 + v1 * t + 0.5 * acc1 * t * t;
    return p2 + v2 * t + 0.5 * acc2 * t * t;
  };
  auto velocity = [&](double t) -> Eigen::Vector3d {
    if (t < gap_begin) return v1 + acc1 * t;
    return v2 + acc2 * t;
  };
  core::RandomStream random(11, "jitter");
  std::vector<core::Time> t_ns;
  std::vector<Eigen::Vector3d> p;
  for (int k = 0; k < 200; ++k) {
    const double t = 0.02 * k + random.Uniform(-0.004, 0.004);
    if (t > gap_begin - 0.01 && t < gap_end) continue;
    t_ns.push_back(core::SecondsToTime(t));
    p.push_back(position(core::TimeToSeconds(t_ns.back())));
  }
  DifferentiationOptions options;
  options.half_window_ns = 50'000'000;
  options.max_gap_ns = 100'000'000;
  DifferentiationStats stats;
  const VelocitySeries v = DifferentiatePositions(t_ns, p, options, &stats);
  EXPECT_EQ(stats.segments, 2);
  EXPECT_EQ(stats.rejected_non_finite, 0);
  // Every sample but the first and last of each segment has a velocity.
  EXPECT_EQ(stats.without_output, 4);
  ASSERT_EQ(v.t_ns.size(), t_ns.size() - 4);
  const auto first_after_it =
      std::lower_bound(t_ns.begin(), t_ns.end(), core::SecondsToTime(gap_begin));
  const core::Time first_after = *first_after_it;
  const core::Time last_before = *(first_after_it - 1);
  for (std::size_t k = 0; k < v.t_ns.size(); ++k) {
    const double t = core::TimeToSeconds(v.t_ns[k]);
    EXPECT_LT((v.v_mps[k] - velocity(t)).norm(), 1e-9) << "t = " << t;
    EXPECT_NE(v.t_ns[k], last_before);
    EXPECT_NE(v.t_ns[k], first_after);
  }
}

// A sinusoid: the degree-2 fit's truncation error is bounded by the third derivative,
// |error| <= |p'''| h^2 / 6 for symmetric samples; jitter makes them slightly asymmetric,
// hence the factor 2.
TEST(DifferentiatePositions, SinusoidWithinTheTruncationBoundOfTheFit) {
  const double amplitude = 2.0;
  const double omega = 3.0;  // rad/s
  const double h = 0.05;     // s
  core::RandomStream random(12, "jitter");
  std::vector<core::Time> t_ns;
  std::vector<Eigen::Vector3d> p;
  for (int k = 0; k < 300; ++k) {
    const double t = 0.01 * k + random.Uniform(-0.002, 0.002);
    t_ns.push_back(core::SecondsToTime(t));
    const double ts = core::TimeToSeconds(t_ns.back());
    p.push_back(amplitude * Eigen::Vector3d(std::sin(omega * ts), std::cos(omega * ts),
                                            std::sin(omega * ts + 1.0)));
  }
  DifferentiationOptions options;
  options.half_window_ns = core::SecondsToTime(h);
  const VelocitySeries v = DifferentiatePositions(t_ns, p, options);
  ASSERT_GT(v.t_ns.size(), 290u);
  const double bound = 2.0 * amplitude * omega * omega * omega * h * h / 6.0;
  double worst = 0.0;
  for (std::size_t k = 0; k < v.t_ns.size(); ++k) {
    const double t = core::TimeToSeconds(v.t_ns[k]);
    const Eigen::Vector3d truth =
        amplitude * omega *
        Eigen::Vector3d(std::cos(omega * t), -std::sin(omega * t), std::cos(omega * t + 1.0));
    worst = std::max(worst, (v.v_mps[k] - truth).cwiseAbs().maxCoeff());
  }
  EXPECT_LT(worst, bound);
  // And the bound is not vacuous: the error is of its order.
  EXPECT_GT(worst, 0.05 * bound);
}

TEST(DifferentiatePositions, RejectsNonFiniteAndOutOfOrderSamples) {
  std::vector<core::Time> t_ns;
  std::vector<Eigen::Vector3d> p;
  const Eigen::Vector3d velocity(1.0, 2.0, -3.0);
  for (int k = 0; k < 20; ++k) {
    t_ns.push_back(k * 10'000'000);
    p.push_back(velocity * (0.01 * k));
  }
  // A NaN sample, a repeated stamp and a stamp going back.
  p[5].x() = std::numeric_limits<double>::quiet_NaN();
  t_ns.insert(t_ns.begin() + 10, t_ns[9]);
  p.insert(p.begin() + 10, Eigen::Vector3d(100.0, 100.0, 100.0));
  t_ns.insert(t_ns.begin() + 15, t_ns[12]);
  p.insert(p.begin() + 15, Eigen::Vector3d(-100.0, 0.0, 0.0));
  DifferentiationOptions options;
  options.half_window_ns = 30'000'000;
  DifferentiationStats stats;
  const VelocitySeries v = DifferentiatePositions(t_ns, p, options, &stats);
  EXPECT_EQ(stats.rejected_non_finite, 1);
  EXPECT_EQ(stats.rejected_out_of_order, 2);
  EXPECT_EQ(v.t_ns.size(), 17u);  // 19 accepted, minus the two ends
  for (const Eigen::Vector3d& value : v.v_mps) EXPECT_LT((value - velocity).norm(), 1e-9);
}

TEST(DifferentiateOrientations, ConstantBodyRateIsExactDespiteJitter) {
  const Eigen::Matrix3d R0 = core::RotationFromRollPitchYaw(1.0, -0.5, 2.5);
  const Eigen::Vector3d omega(0.8, -1.5, 2.0);  // rad/s, body frame
  core::RandomStream random(13, "jitter");
  std::vector<core::Time> t_ns;
  std::vector<Eigen::Quaterniond> q;
  for (int k = 0; k < 100; ++k) {
    t_ns.push_back(core::SecondsToTime(0.02 * k + random.Uniform(-0.005, 0.005)));
    const Eigen::Matrix3d R = R0 * core::ExpSO3(omega * core::TimeToSeconds(t_ns.back()));
    q.push_back(core::CanonicalQuat(Eigen::Quaterniond(R)));
  }
  DifferentiationOptions options;
  options.half_window_ns = 60'000'000;
  const AngularRateSeries rates = DifferentiateOrientations(t_ns, q, options);
  ASSERT_EQ(rates.t_ns.size(), 98u);
  for (const Eigen::Vector3d& value : rates.omega_radps) {
    EXPECT_LT((value - omega).norm(), 1e-9);
  }
}

// The velocity's stated covariance is what its fit's weights make of the positions'
// covariance: over 4000 outputs of one noisy 10 Hz stream the empirical variance of each
// axis's error matches the stated one. Neighbouring outputs share samples (a fit spans
// about 3), so the effective count is ~4000/3: the variance ratio's sd is √(2/1300) =
// 0.04, and 0.16 is 4 of them.
TEST(DifferentiatePositions, StatedVelocityCovarianceMatchesTheScatterOfTheFit) {
  core::RandomStream random(5, "diff_cov");
  const Eigen::Vector3d sd_m(0.01, 0.03, 0.3);
  std::vector<core::Time> t_ns;
  std::vector<Eigen::Vector3d> p;
  std::vector<Eigen::Matrix3d> cov;
  const Eigen::Vector3d v_true(0.4, -0.2, 0.1);
  for (int k = 0; k < 4000; ++k) {
    const core::Time t = 100'000'000LL * k + (k % 3) * 7'000'000;  // jittered 10 Hz
    Eigen::Vector3d noise;
    for (int axis = 0; axis < 3; ++axis) noise[axis] = sd_m[axis] * random.Normal();
    t_ns.push_back(t);
    p.push_back(v_true * core::TimeToSeconds(t) + noise);
    cov.push_back(sd_m.cwiseAbs2().asDiagonal());
  }
  DifferentiationOptions options;
  options.half_window_ns = 160'000'000;
  const VelocitySeries v = DifferentiatePositions(t_ns, p, cov, options);
  ASSERT_EQ(v.cov_m2ps2.size(), v.t_ns.size());
  ASSERT_GT(v.t_ns.size(), 3900u);
  Eigen::Vector3d scatter = Eigen::Vector3d::Zero();
  Eigen::Vector3d stated = Eigen::Vector3d::Zero();
  for (std::size_t k = 0; k < v.t_ns.size(); ++k) {
    scatter += (v.v_mps[k] - v_true).cwiseAbs2();
    stated += v.cov_m2ps2[k].diagonal();
  }
  for (int axis = 0; axis < 3; ++axis) {
    EXPECT_NEAR(scatter[axis] / stated[axis], 1.0, 0.16) << "axis " << axis;
  }
  // Without covariances the velocities are the same numbers, and none is stated.
  const VelocitySeries plain = DifferentiatePositions(t_ns, p, options);
  EXPECT_EQ(plain.v_mps, v.v_mps);
  EXPECT_TRUE(plain.cov_m2ps2.empty());
}

}  // namespace
}  // namespace tofu::estimator
