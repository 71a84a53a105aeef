// Trajectory evaluation as evo / rpg_trajectory_evaluation do it: SE(3) alignment recovers
// a known rigid offset and the ATE equals the injected noise, the 4-DoF alignment recovers
// yaw + translation but not roll, ground truth is interpolated exactly for linear motion,
// the RPE of a constant drift is drift x delta; TUM files with exact nanosecond stamps.

#include <unistd.h>

#include <gtest/gtest.h>

#include <cmath>
#include <cstdint>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <limits>
#include <random>
#include <sstream>
#include <string>
#include <vector>

#include <Eigen/Eigenvalues>

#include "core/error.h"
#include "core/lie.h"
#include "replay/recorded_log.h"
#include "replay/trajectory_metrics.h"
#include "tests/test_support.h"

namespace tofu::replay {
namespace {

namespace fs = std::filesystem;


constexpr double kPi = 3.14159265358979323846;
constexpr double kDeg = kPi / 180.0;
constexpr core::Time kMs = 1'000'000;

// A 3D flight with turning attitude: T_WI(t) at 200 Hz for 30 s.
std::vector<PoseSample> GroundTruth(core::Time period = 5 * kMs, double duration_s = 30.0) {
  std::vector<PoseSample> gt;
  for (core::Time t = 0; t <= core::SecondsToTime(duration_s); t += period) {
    const double s = core::TimeToSeconds(t);
    PoseSample p;
    p.t_ns = t;
    p.p = Eigen::Vector3d(3.0 * std::sin(0.3 * s), 2.0 * std::sin(0.5 * s + 1.0),
                          1.0 + 0.8 * std::sin(0.7 * s));
    p.q = Eigen::Quaterniond(core::RotationFromRollPitchYaw(0.2 * std::sin(0.4 * s),
                                                            0.15 * std::cos(0.6 * s), 0.5 * s));
    gt.push_back(p);
  }
  return gt;
}

Eigen::Isometry3d Pose(double roll, double pitch, double yaw, const Eigen::Vector3d& p) {
  Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
  T.linear() = core::RotationFromRollPitchYaw(roll, pitch, yaw);
  T.translation() = p;
  return T;
}

// The estimate T_LI = T_LW T_WI at every `step`-th ground-truth sample.
std::vector<PoseSample> Transformed(const std::vector<PoseSample>& gt, const Eigen::Isometry3d& T_LW,
                                    size_t step = 1) {
  std::vector<PoseSample> est;
  const Eigen::Quaterniond q_LW(T_LW.linear());
  for (size_t i = 0; i < gt.size(); i += step) {
    PoseSample e = gt[i];
    e.p = T_LW * gt[i].p;
    e.q = (q_LW * gt[i].q).normalized();
    est.push_back(e);
  }
  return est;
}

// ---- alignment and ATE ----

TEST(TrajectoryMetrics, Se3AlignmentRecoversARigidOffsetAndAteEqualsTheInjectedNoise) {
  const std::vector<PoseSample> gt = GroundTruth();
  const Eigen::Isometry3d T_LW = Pose(0.3, -0.2, 1.1, Eigen::Vector3d(4.0, -7.0, 2.5));
  std::vector<PoseSample> est = Transformed(gt, T_LW, 10);  // 20 Hz, 601 samples
  const double sigma = 0.01;  // m per axis
  std::mt19937_64 rng(7);
  std::normal_distribution<double> noise(0.0, sigma);
  for (PoseSample& e : est) e.p += Eigen::Vector3d(noise(rng), noise(rng), noise(rng));

  const TrajectoryErrors r = EvaluateTrajectory(est, gt);
  const double n = static_cast<double>(est.size());
  ASSERT_EQ(r.matched, est.size());
  EXPECT_EQ(r.aligned_on, est.size());
  EXPECT_FALSE(r.alignment_from_attitude);

  // ATE^2 / (3 sigma^2) is a chi-square mean over 3n - 6 degrees of freedom: mean
  // (1 - 2/n), relative std sqrt(2/(3n)); the RMSE's relative std is half that. 4 sigma.
  const double expected_rmse = std::sqrt(3.0) * sigma * std::sqrt(1.0 - 2.0 / n);
  const double tolerance = 4.0 * 0.5 * std::sqrt(2.0 / (3.0 * n)) * expected_rmse;
  EXPECT_NEAR(r.ate_position_rmse_m, expected_rmse, tolerance);
  EXPECT_EQ(r.position_error_m.size(), est.size());

  // The rotation is determined to about sigma / (sqrt(n) spread) rad; the trajectory's
  // smallest spread (std along the principal axes) is about 0.55 m.
  Eigen::Vector3d mean = Eigen::Vector3d::Zero();
  for (const PoseSample& g : gt) mean += g.p;
  mean /= static_cast<double>(gt.size());
  Eigen::Matrix3d scatter = Eigen::Matrix3d::Zero();
  for (const PoseSample& g : gt) scatter += (g.p - mean) * (g.p - mean).transpose();
  scatter /= static_cast<double>(gt.size());
  const double min_spread = std::sqrt(Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d>(scatter).eigenvalues()(0));
  const double rotation_tolerance_rad = 5.0 * sigma / (std::sqrt(n) * min_spread);
  const Eigen::Isometry3d T_WL = T_LW.inverse();
  EXPECT_LT(core::RotationAngleBetween(r.T_WL.linear(), T_WL.linear()), rotation_tolerance_rad);
  // The translation: noise of the centroid plus the rotation error's lever arm.
  const double translation_tolerance =
      5.0 * sigma / std::sqrt(n) + rotation_tolerance_rad * (T_LW * mean).norm();
  EXPECT_LT((r.T_WL.translation() - T_WL.translation()).norm(), translation_tolerance);
  // Attitudes were not perturbed: their error is the alignment's.
  EXPECT_LT(r.rotation_max_deg, rotation_tolerance_rad / kDeg);
  EXPECT_LE(r.ate_position_median_m, r.ate_position_max_m);
  EXPECT_GT(r.ate_position_mean_m, 0.0);
  EXPECT_LE(r.ate_position_mean_m, r.ate_position_rmse_m);
}

TEST(TrajectoryMetrics, PositionYawAlignmentRecoversYawAndTranslationButNotRoll) {
  const std::vector<PoseSample> gt = GroundTruth();
  TrajectoryErrorOptions four_dof;
  four_dof.alignment = TrajectoryAlignment::kPositionYaw;

  // Yaw + translation offset: recovered exactly.
  const Eigen::Isometry3d T_LW = Pose(0.0, 0.0, 2.0, Eigen::Vector3d(-3.0, 1.5, 0.7));
  const TrajectoryErrors yaw = EvaluateTrajectory(Transformed(gt, T_LW, 4), gt, four_dof);
  EXPECT_LT(yaw.ate_position_max_m, 1e-9);
  EXPECT_LT(yaw.rotation_max_deg, 1e-6);
  EXPECT_TRUE(yaw.T_WL.isApprox(T_LW.inverse(), 1e-12));

  // A roll offset is not an alignment a 4-DoF evaluation may remove: ATE and attitude
  // error grow (the attitude error is the roll itself), while SE(3) removes it.
  const Eigen::Isometry3d T_LW_roll = Pose(5.0 * kDeg, 0.0, 2.0, Eigen::Vector3d(-3.0, 1.5, 0.7));
  const std::vector<PoseSample> rolled = Transformed(gt, T_LW_roll, 4);
  const TrajectoryErrors roll = EvaluateTrajectory(rolled, gt, four_dof);
  EXPECT_GT(roll.ate_position_rmse_m, 0.05);
  EXPECT_NEAR(roll.rotation_rmse_deg, 5.0, 0.5);
  const TrajectoryErrors se3 = EvaluateTrajectory(rolled, gt);
  EXPECT_LT(se3.ate_position_max_m, 1e-9);
  EXPECT_LT(se3.rotation_max_deg, 1e-6);
  EXPECT_TRUE(se3.T_WL.isApprox(T_LW_roll.inverse(), 1e-12));

  // No alignment: the offset stays in the error.
  TrajectoryErrorOptions none;
  none.alignment = TrajectoryAlignment::kNone;
  const TrajectoryErrors raw = EvaluateTrajectory(Transformed(gt, T_LW, 4), gt, none);
  EXPECT_TRUE(raw.T_WL.isApprox(Eigen::Isometry3d::Identity()));
  EXPECT_GT(raw.ate_position_rmse_m, 1.0);
}

TEST(TrajectoryMetrics, AlignmentUsesOnlyItsTimeRange) {
  std::vector<PoseSample> gt = GroundTruth();
  const Eigen::Isometry3d T_LW = Pose(0.1, 0.2, 0.3, Eigen::Vector3d(1.0, 2.0, 3.0));
  std::vector<PoseSample> est = Transformed(gt, T_LW, 2);
  // After 20 s the estimate jumps by 1 m: aligning on [0, 20 s] leaves the jump visible.
  for (PoseSample& e : est) {
    if (e.t_ns > 20 * core::kNanosecondsPerSecond) e.p.x() += 1.0;
  }
  TrajectoryErrorOptions options;
  options.align_to_ns = 20 * core::kNanosecondsPerSecond;
  const TrajectoryErrors r = EvaluateTrajectory(est, gt, options);
  EXPECT_TRUE(r.T_WL.isApprox(T_LW.inverse(), 1e-9));
  EXPECT_EQ(r.aligned_on, static_cast<size_t>(20 * 200 / 2 + 1));
  EXPECT_NEAR(r.ate_position_max_m, 1.0, 1e-9);
  EXPECT_NEAR(r.position_error_m.front(), 0.0, 1e-9);
}

TEST(TrajectoryMetrics, HoverIsAlignedByItsAttitudes) {
  // Positions within millimetres: they cannot fix a rotation, the attitudes do.
  std::vector<PoseSample> gt;
  for (int i = 0; i < 400; ++i) {
    PoseSample p;
    p.t_ns = i * 5 * kMs;
    p.p = Eigen::Vector3d(0.001 * std::sin(0.1 * i), 0.001 * std::cos(0.13 * i), 1.0);
    p.q = Eigen::Quaterniond(core::RotationFromRollPitchYaw(0.01 * std::sin(0.05 * i), 0.0, 0.3));
    gt.push_back(p);
  }
  const Eigen::Isometry3d T_LW = Pose(0.0, 0.0, -0.8, Eigen::Vector3d(0.5, 0.2, -1.0));
  for (const TrajectoryAlignment a : {TrajectoryAlignment::kSE3, TrajectoryAlignment::kPositionYaw}) {
    TrajectoryErrorOptions options;
    options.alignment = a;
    const TrajectoryErrors r = EvaluateTrajectory(Transformed(gt, T_LW), gt, options);
    EXPECT_TRUE(r.alignment_from_attitude);
    EXPECT_TRUE(r.T_WL.isApprox(T_LW.inverse(), 1e-9)) << r.T_WL.matrix();
    EXPECT_LT(r.ate_position_max_m, 1e-9);
  }
}

// ---- interpolation, RPE, bookkeeping ----

TEST(TrajectoryMetrics, GroundTruthInterpolationIsExactForLinearMotion) {
  // Ground truth at 10 Hz: constant velocity, constant rate about a fixed axis (slerp is
  // exact for it); the estimate at off-grid stamps is the exact pose.
  const Eigen::Vector3d p0(1.0, -2.0, 0.5), v(0.7, 0.3, -0.2);
  const Eigen::Vector3d axis = Eigen::Vector3d(1.0, 2.0, 3.0).normalized();
  const double rate = 0.4;  // rad/s
  const auto exact = [&](core::Time t) {
    const double s = core::TimeToSeconds(t);
    PoseSample p;
    p.t_ns = t;
    p.p = p0 + v * s;
    p.q = Eigen::Quaterniond(Eigen::AngleAxisd(rate * s, axis));
    return p;
  };
  std::vector<PoseSample> gt;
  for (core::Time t = 0; t <= 5'000 * kMs; t += 100 * kMs) {
    if (t > 2'000 * kMs && t < 3'000 * kMs) continue;  // a 1 s hole
    gt.push_back(exact(t));
  }
  std::vector<PoseSample> est;
  for (core::Time t = 13 * kMs; t < 5'000 * kMs; t += 37 * kMs) est.push_back(exact(t));

  TrajectoryErrorOptions options;
  options.alignment = TrajectoryAlignment::kNone;
  options.max_interpolation_gap_ns = 100 * kMs;
  const TrajectoryErrors r = EvaluateTrajectory(est, gt, options);
  // Stamps in the open hole (2, 3) s have no ground truth within 100 ms on both sides.
  size_t in_hole = 0;
  for (const PoseSample& e : est) in_hole += (e.t_ns > 2'000 * kMs && e.t_ns < 3'000 * kMs);
  EXPECT_GT(in_hole, 20u);
  EXPECT_EQ(r.skipped_no_ground_truth, in_hole);
  EXPECT_EQ(r.matched, est.size() - in_hole);
  EXPECT_LT(r.ate_position_max_m, 1e-12);
  EXPECT_LT(r.rotation_max_deg, 1e-6);

  // A gap wider than allowed: skipped; an estimate outside the ground truth: skipped.
  options.max_interpolation_gap_ns = 50 * kMs;
  // Ground truth at 0, 100, 200 ms: 30 ms is 70 ms from the next sample, 60 ms is 60 ms
  // from the previous one, 5.1 s is after the end; 50 ms (50 and 50) and 200 ms (a sample)
  // have ground truth.
  const std::vector<PoseSample> few = {exact(30 * kMs), exact(50 * kMs), exact(60 * kMs),
                                       exact(200 * kMs), exact(5'100 * kMs)};
  const TrajectoryErrors s = EvaluateTrajectory(few, gt, options);
  EXPECT_EQ(s.matched, 2u);
  EXPECT_EQ(s.skipped_no_ground_truth, 3u);
  ASSERT_EQ(s.t_ns.size(), 2u);
  EXPECT_EQ(s.t_ns[0], 50 * kMs);
  EXPECT_EQ(s.t_ns[1], 200 * kMs);
  EXPECT_LT(s.ate_position_max_m, 1e-12);
}

TEST(TrajectoryMetrics, RpeOfAConstantDriftIsDriftTimesDelta) {
  const std::vector<PoseSample> gt = GroundTruth();
  const Eigen::Vector3d drift(0.01, -0.02, 0.005);  // m/s in W
  std::vector<PoseSample> est = gt;
  for (PoseSample& e : est) e.p += drift * core::TimeToSeconds(e.t_ns);

  TrajectoryErrors r = EvaluateTrajectory(est, gt);
  EXPECT_DOUBLE_EQ(r.rpe_delta_s, 1.0);
  EXPECT_EQ(r.rpe_pairs, gt.size() - 200);  // every sample with one 1 s later
  EXPECT_NEAR(r.rpe_translation_rmse_m, drift.norm() * 1.0, 1e-9);
  EXPECT_LT(r.rpe_rotation_rmse_deg, 1e-6);

  TrajectoryErrorOptions options;
  options.rpe_delta_ns = 2 * core::kNanosecondsPerSecond;
  r = EvaluateTrajectory(est, gt, options);
  EXPECT_NEAR(r.rpe_translation_rmse_m, drift.norm() * 2.0, 1e-9);
  EXPECT_DOUBLE_EQ(r.rpe_delta_s, 2.0);

  // A yaw-rate drift shows up in the rotation RPE: 0.5 deg/s -> 0.5 deg over 1 s.
  est = gt;
  for (PoseSample& e : est) {
    e.q = Eigen::Quaterniond(Eigen::AngleAxisd(0.5 * kDeg * core::TimeToSeconds(e.t_ns),
                                               Eigen::Vector3d::UnitZ())) * e.q;
  }
  r = EvaluateTrajectory(est, gt, {});
  EXPECT_NEAR(r.rpe_rotation_rmse_deg, 0.5, 1e-6);
}

// Continuity: a rigidly transformed estimate has no step however it moves; a 4 cm jump
// of the estimate at 12 s is found at 12 s with its size, and a gap in the outputs longer
// than max_step_gap_ns is not a step.
TEST(TrajectoryMetrics, TheLargestStepIsAJumpOfTheEstimateNotItsMotion) {
  const std::vector<PoseSample> gt = GroundTruth();
  const Eigen::Isometry3d T_LW = Pose(0.1, -0.2, 1.3, Eigen::Vector3d(4.0, -2.0, 0.5));
  std::vector<PoseSample> est = Transformed(gt, T_LW);
  TrajectoryErrors r = EvaluateTrajectory(est, gt);
  EXPECT_EQ(r.step_pairs, gt.size() - 1);
  EXPECT_LT(r.position_step_max_m, 1e-9);

  const Eigen::Vector3d jump_L(0.0, 0.04, 0.0);  // from 12 s on
  const core::Time jump_ns = core::SecondsToTime(12.0);
  for (PoseSample& e : est) {
    if (e.t_ns >= jump_ns) e.p += jump_L;
  }
  r = EvaluateTrajectory(est, gt);
  EXPECT_NEAR(r.position_step_max_m, 0.04, 1e-3);  // the alignment spreads nothing of a step
  EXPECT_EQ(r.position_step_max_t_ns, jump_ns);

  // The same jump across 100 ms without outputs: no consecutive pair spans it.
  std::vector<PoseSample> gapped;
  for (const PoseSample& e : est) {
    if (e.t_ns < jump_ns - 100 * kMs || e.t_ns >= jump_ns) gapped.push_back(e);
  }
  r = EvaluateTrajectory(gapped, gt);
  EXPECT_EQ(r.step_pairs, gapped.size() - 2);
  EXPECT_LT(r.position_step_max_m, 1e-3);
  TrajectoryErrorOptions options;
  options.max_step_gap_ns = 200 * kMs;
  r = EvaluateTrajectory(gapped, gt, options);
  EXPECT_NEAR(r.position_step_max_m, 0.04, 1e-3);
}

TEST(TrajectoryMetrics, NonFiniteSamplesAreSkippedAndCounted) {
  const std::vector<PoseSample> gt = GroundTruth(5 * kMs, 5.0);
  std::vector<PoseSample> est = gt;
  est[10].p.x() = std::numeric_limits<double>::quiet_NaN();
  est[20].q.w() = std::numeric_limits<double>::infinity();
  const TrajectoryErrors r = EvaluateTrajectory(est, gt);
  EXPECT_EQ(r.skipped_non_finite, 2u);
  EXPECT_EQ(r.matched, gt.size() - 2);
  EXPECT_TRUE(std::isfinite(r.ate_position_rmse_m));
  EXPECT_LT(r.ate_position_max_m, 1e-9);

  const TrajectoryErrors empty = EvaluateTrajectory({}, gt);
  EXPECT_EQ(empty.matched, 0u);
  EXPECT_TRUE(std::isnan(empty.ate_position_rmse_m));
  EXPECT_TRUE(std::isnan(empty.rpe_translation_rmse_m));
}

// ---- time text and TUM files ----

// A clean ground truth (sorted, finite, one sample per stamp) is read in place; any other is
// cleaned in a copy first. The two must give the same bits, or an hour-long run's scores
// would depend on whether its ground truth needed cleaning.
TEST(TrajectoryMetrics, GroundTruthReadInPlaceScoresLikeACleanedCopy) {
  std::vector<PoseSample> gt = GroundTruth(5 * kMs, 20.0);
  // Quaternions a little off unit, as read from a CSV with 9 decimals.
  for (std::size_t i = 0; i < gt.size(); ++i) gt[i].q.coeffs() *= 1.0 + 1e-9 * static_cast<double>(i % 7);
  std::vector<PoseSample> est =
      Transformed(gt, Pose(0.1, -0.05, 0.7, Eigen::Vector3d(1.0, -2.0, 0.5)), 3);
  for (std::size_t i = 0; i < est.size(); ++i) est[i].t_ns += 1'700'000;  // between truth samples
  // Out of order, a duplicate stamp (the first kept) and a NaN sample: the copy path.
  std::vector<PoseSample> messy(gt.rbegin(), gt.rend());
  std::stable_sort(messy.begin(), messy.end(),
                   [](const PoseSample& a, const PoseSample& b) { return a.t_ns < b.t_ns; });
  PoseSample duplicate = gt[100];
  duplicate.p.x() += 5.0;
  messy.insert(messy.begin() + 101, duplicate);
  PoseSample nan_sample = gt[200];
  nan_sample.t_ns += 1;
  nan_sample.p.y() = std::numeric_limits<double>::quiet_NaN();
  messy.push_back(nan_sample);
  std::swap(messy[10], messy[11]);

  const TrajectoryErrors in_place = EvaluateTrajectory(est, gt);
  const TrajectoryErrors copied = EvaluateTrajectory(est, messy);
  ASSERT_GT(in_place.matched, 1000u);
  EXPECT_EQ(in_place.matched, copied.matched);
  EXPECT_EQ(in_place.position_error_m, copied.position_error_m);
  EXPECT_EQ(in_place.rotation_error_deg, copied.rotation_error_deg);
  EXPECT_EQ(in_place.rpe_translation_rmse_m, copied.rpe_translation_rmse_m);
  EXPECT_TRUE(in_place.T_WL.matrix() == copied.T_WL.matrix());
  EXPECT_LT(in_place.ate_position_rmse_m, 0.005);  // the 1.7 ms shift at ~1 m/s
}

TEST(TrajectoryMetrics, SecondsTextParsesToExactNanoseconds) {
  EXPECT_EQ(ParseSecondsAsNanoseconds("1.403715529112143517e+09"), 1403715529112143517);
  EXPECT_EQ(ParseSecondsAsNanoseconds("1403715529.112143517"), 1403715529112143517);
  EXPECT_EQ(ParseSecondsAsNanoseconds("1403715529112143517e-9"), 1403715529112143517);
  // Through a double the stamp is off by tens of ns: why the text is parsed exactly.
  EXPECT_NE(static_cast<core::Time>(1.403715529112143517e+09 * 1e9), 1403715529112143517);
  EXPECT_EQ(ParseSecondsAsNanoseconds("0"), 0);
  EXPECT_EQ(ParseSecondsAsNanoseconds("-0.0"), 0);
  EXPECT_EQ(ParseSecondsAsNanoseconds("+2.5"), 2'500'000'000);
  EXPECT_EQ(ParseSecondsAsNanoseconds(".5"), 500'000'000);
  EXPECT_EQ(ParseSecondsAsNanoseconds("5."), 5'000'000'000);
  EXPECT_EQ(ParseSecondsAsNanoseconds("1E-09"), 1);
  EXPECT_EQ(ParseSecondsAsNanoseconds("0.0000000005"), 1);    // half: away from zero
  EXPECT_EQ(ParseSecondsAsNanoseconds("0.00000000049999"), 0);
  EXPECT_EQ(ParseSecondsAsNanoseconds("-1.5e-9"), -2);
  EXPECT_EQ(ParseSecondsAsNanoseconds("0.0000000014999999999999999"), 1);
  EXPECT_EQ(ParseSecondsAsNanoseconds("-12.000000001"), -12'000'000'001);
  EXPECT_EQ(ParseSecondsAsNanoseconds("9.223372036854775807e9"), std::numeric_limits<core::Time>::max());
  EXPECT_EQ(ParseSecondsAsNanoseconds("-9.223372036854775808e9"), std::numeric_limits<core::Time>::min());
  EXPECT_EQ(ParseSecondsAsNanoseconds("0e999999999999"), 0);
  for (const char* bad : {"", "nan", "inf", "-", ".", "1..2", "1.2.3", "1e", "1e+", "abc", "1.0x",
                          " 1", "9.223372036854775808e9", "1e30", "0x10"}) {
    EXPECT_FALSE(ParseSecondsAsNanoseconds(bad).has_value()) << "'" << bad << "'";
  }
  EXPECT_EQ(FormatNanosecondsAsSeconds(1403715529112143517), "1403715529.112143517");
  EXPECT_EQ(FormatNanosecondsAsSeconds(-1), "-0.000000001");
  EXPECT_EQ(FormatNanosecondsAsSeconds(std::numeric_limits<core::Time>::min()),
            "-9223372036.854775808");
}

class TumFileTest : public ::testing::Test {
 protected:
  void SetUp() override {
    const auto* info = ::testing::UnitTest::GetInstance()->current_test_info();
    dir_ = fs::path(::testing::TempDir()) /
           (std::string("tofu_tum_") + info->name() + "_" + std::to_string(::getpid()));
    fs::remove_all(dir_);
    fs::create_directories(dir_);
  }
  void TearDown() override { fs::remove_all(dir_); }
  std::string Read(const fs::path& p) {
    std::ifstream in(p, std::ios::binary);
    return std::string(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
  }
  std::string ErrorOf(const std::string& text) {
    std::ofstream(dir_ / "bad.tum", std::ios::binary) << text;
    try {
      ReadTumTrajectory(dir_ / "bad.tum");
    } catch (const core::InputError& e) {
      return e.what();
    }
    ADD_FAILURE() << "no InputError for " << text;
    return "";
  }
  fs::path dir_;
};

TEST_F(TumFileTest, WriteReadRoundTripIsExactInNanosecondsAndByteDeterministic) {
  std::vector<PoseSample> poses = GroundTruth(33 * kMs + 7, 3.0);
  poses.front().t_ns = 1403715529112143517;
  poses[1].t_ns = -1;
  poses[2].t_ns = 999'999'999;
  poses[3].t_ns = std::numeric_limits<core::Time>::max();
  poses[4].q.coeffs() *= -1.0;  // stored with w >= 0
  WriteTumTrajectory(dir_ / "a.tum", poses);
  const std::vector<PoseSample> back = ReadTumTrajectory(dir_ / "a.tum");
  ASSERT_EQ(back.size(), poses.size());
  for (size_t i = 0; i < poses.size(); ++i) {
    EXPECT_EQ(back[i].t_ns, poses[i].t_ns) << i;
    EXPECT_LT((back[i].p - poses[i].p).cwiseAbs().maxCoeff(), 5e-7) << i;
    EXPECT_LT(back[i].q.angularDistance(poses[i].q), 1e-8) << i;
    EXPECT_GE(back[i].q.w(), 0.0);
  }
  // Writing is byte-deterministic; written again after reading, stamps and positions are
  // the same text (quaternions are renormalised on reading: their 9th decimal may move).
  WriteTumTrajectory(dir_ / "a2.tum", poses);
  EXPECT_EQ(Read(dir_ / "a.tum"), Read(dir_ / "a2.tum"));
  WriteTumTrajectory(dir_ / "b.tum", back);
  const auto stamps_and_positions = [](const std::string& tum) {
    std::string out;
    std::istringstream in(tum);
    std::string line;
    while (std::getline(in, line)) {
      size_t end = 0;
      for (int k = 0; k < 4; ++k) end = line.find(' ', end + 1);
      out += line.substr(0, end) + "\n";
    }
    return out;
  };
  EXPECT_EQ(stamps_and_positions(Read(dir_ / "a.tum")), stamps_and_positions(Read(dir_ / "b.tum")));
  const std::string text = Read(dir_ / "a.tum");
  EXPECT_EQ(text.substr(0, text.find(' ')), "1403715529.112143517");
  EXPECT_NE(text.find("\n-0.000000001 "), std::string::npos);
  EXPECT_NE(text.find("\n9223372036.854775807 "), std::string::npos);
}

TEST_F(TumFileTest, CommentsBlankLinesAndNanAreRead) {
  std::ofstream(dir_ / "c.tum") << "# t x y z qx qy qz qw\n\n"
                                   "1.5 1 2 3 0 0 0 1\r\n"
                                   "  2.5\tnan 2 3 0 0 0 2\n";
  const std::vector<PoseSample> poses = ReadTumTrajectory(dir_ / "c.tum");
  ASSERT_EQ(poses.size(), 2u);
  EXPECT_EQ(poses[0].t_ns, 1'500'000'000);
  EXPECT_EQ(poses[0].p, Eigen::Vector3d(1, 2, 3));
  EXPECT_TRUE(std::isnan(poses[1].p.x()));
  EXPECT_EQ(poses[1].q.w(), 1.0);  // normalised
}

TEST_F(TumFileTest, MalformedLinesNameFileLineAndColumn) {
  std::string what = ErrorOf("1.0 0 0 0 0 0 0 1\n2.0 1 2\n");
  EXPECT_CONTAINS(what, "bad.tum:2");
  EXPECT_CONTAINS(what, "qx");  // the first missing column
  EXPECT_CONTAINS(what, "got 3");
  what = ErrorOf("1.0 0 abc 0 0 0 0 1\n");
  EXPECT_CONTAINS(what, "bad.tum:1:7");
  EXPECT_CONTAINS(what, "y [m]");
  EXPECT_CONTAINS(what, "'abc'");
  what = ErrorOf("1.0 0 0 0 0 0 0 1\n\n# c\n12:30 0 0 0 0 0 0 1\n");
  EXPECT_CONTAINS(what, "bad.tum:4:1");
  EXPECT_CONTAINS(what, "t [s]");
  what = ErrorOf("1.0 0 0 0 0 0 0 1 9\n");
  EXPECT_CONTAINS(what, "got 9");
  try {
    ReadTumTrajectory(dir_ / "missing.tum");
    ADD_FAILURE() << "no InputError for a missing file";
  } catch (const core::InputError& e) {
    EXPECT_CONTAINS(e.what(), "missing.tum");
  }
}

// ---- real data ----

TEST(TrajectoryMetricsEuroc, VisualEstimateOfV102HasTheDocumentedAte) {
  const fs::path dir = fs::path(TOFU_SOURCE_DIR) / ".." / "shared" / "data" / "euroc_v1_02";
  if (!fs::is_directory(dir)) GTEST_SKIP() << "EuRoC excerpt not found at " << dir;
  const std::vector<PoseSample> estimate = ReadTumTrajectory(dir / "pose_estimate.tum");
  const RecordedLog log = ReadRecordedLog(dir);
  const std::vector<PoseSample>& gt = log.ground_truth;
  const TrajectoryErrors se3 = EvaluateTrajectory(estimate, gt);
  // data/README.md: SE(3)-aligned, 0.092 m position RMSE.
  // The estimate runs 0.9 s past the end of the ground truth (608.41 s).
  EXPECT_GT(se3.matched, estimate.size() - 12);
  EXPECT_LT(se3.matched, estimate.size());
  EXPECT_NEAR(se3.ate_position_rmse_m, 0.092, 0.005);
  TrajectoryErrorOptions four_dof;
  four_dof.alignment = TrajectoryAlignment::kPositionYaw;
  const TrajectoryErrors posyaw = EvaluateTrajectory(estimate, gt, four_dof);
  EXPECT_GE(posyaw.ate_position_rmse_m, se3.ate_position_rmse_m - 1e-12);
  std::printf("EuRoC V1_02 visual estimate: ATE %.4f m (SE3), %.4f m (4-DoF), rotation %.3f deg, "
              "RPE(1 s) %.4f m / %.3f deg\n",
              se3.ate_position_rmse_m, posyaw.ate_position_rmse_m, se3.rotation_rmse_deg,
              se3.rpe_translation_rmse_m, se3.rpe_rotation_rmse_deg);
}

}  // namespace
}  // namespace tofu::replay
