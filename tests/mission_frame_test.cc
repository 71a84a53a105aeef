// The estimator's global output T_ML (estimator/mission_frame.h): the launch pad's
// registration, the surveyed sensors' 4-DoF fit (recovered frame, reported variance
// against the error over many noise draws), the heading kept in a hover, the rate limit
// on the state the controller sees, trust and forgetting.

#include "estimator/mission_frame.h"

#include <cmath>
#include <random>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "core/lie.h"
#include "core/units.h"

namespace tofu::estimator {
namespace {

constexpr core::Time kMs = 1'000'000;

Eigen::Isometry3d YawPose(double yaw_deg, const Eigen::Vector3d& p) {
  Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
  T.linear() = Eigen::AngleAxisd(core::RadFromDeg(yaw_deg), Eigen::Vector3d::UnitZ()).toRotationMatrix();
  T.translation() = p;
  return T;
}

// A robot flying a horizontal circle of `radius_m` in L (radius 0: a hover).
Eigen::Isometry3d CircleT_LI(double t_s, double radius_m) {
  const double angle = 0.5 * t_s;
  Eigen::Isometry3d T_LI = Eigen::Isometry3d::Identity();
  T_LI.linear() = Eigen::AngleAxisd(angle, Eigen::Vector3d::UnitZ()).toRotationMatrix();
  T_LI.translation() = Eigen::Vector3d(radius_m * std::cos(angle), radius_m * std::sin(angle),
                                       1.0 + 0.2 * std::sin(0.3 * t_s));
  return T_LI;
}

struct Flight {
  MissionSurvey survey;
  Eigen::Isometry3d T_SL;  // truth: the sensor's frame S against L
  double noise_std_m = 0.01;
  double radius_m = 3.0;
};

// Flies `duration_s` at 100 Hz outputs and 10 Hz positions of "leica" (its mount at I's
// origin), trusted throughout. Returns the published frames, one per output.
std::vector<MissionFrameEstimate> Fly(MissionFrame& frame, const Flight& flight, double duration_s,
                                      std::mt19937& rng, double start_s = 0.0) {
  std::normal_distribution<double> noise(0.0, flight.noise_std_m);
  std::vector<MissionFrameEstimate> published;
  for (int k = 0; k * 0.01 < duration_s; ++k) {
    const double t_s = start_s + k * 0.01;
    const core::Time t_ns = static_cast<core::Time>(std::llround(t_s * 1e9));
    const Eigen::Isometry3d T_LI = CircleT_LI(t_s, flight.radius_m);
    if (k % 10 == 0) {
      const Eigen::Vector3d p_S = flight.T_SL * T_LI.translation() +
                                  Eigen::Vector3d(noise(rng), noise(rng), noise(rng));
      frame.AddPair("leica", t_ns, p_S, T_LI.translation(),
                    flight.noise_std_m * flight.noise_std_m * Eigen::Matrix3d::Identity());
    }
    frame.Update(t_ns, T_LI, {"leica"});
    published.push_back(*frame.published());
  }
  return published;
}

Flight SurveyedFlight() {
  Flight flight;
  flight.survey.T_MS["leica"] = YawPose(-40.0, Eigen::Vector3d(10.0, -5.0, 0.5));
  flight.T_SL = YawPose(30.0, Eigen::Vector3d(2.0, 1.0, -0.3));
  return flight;
}

TEST(MissionFrame, LaunchPadRegistersTheFirstOutputToThePad) {
  MissionSurvey survey;
  const Eigen::Isometry3d T_MI_launch = YawPose(75.0, Eigen::Vector3d(-3.5, 2.0, 1.5));
  survey.T_MI_launch = T_MI_launch;
  MissionFrame frame({}, survey);
  EXPECT_FALSE(frame.published());
  // L: any heading and origin, a small tilt of the IMU (the pad's roll and pitch are not
  // part of a gravity-aligned registration).
  Eigen::Isometry3d T_LI = YawPose(-20.0, Eigen::Vector3d(0.3, -0.1, 0.05));
  T_LI.linear() = T_LI.linear() * Eigen::AngleAxisd(0.02, Eigen::Vector3d::UnitX()).toRotationMatrix();
  frame.Update(0, T_LI, {});
  ASSERT_TRUE(frame.published());
  const MissionFrameEstimate& T_ML = *frame.published();
  EXPECT_LT((T_ML.T_ML() * T_LI.translation() - T_MI_launch.translation()).norm(), 1e-12);
  EXPECT_NEAR(core::DegFromRad(T_ML.yaw_rad()), 95.0, 1e-6);
  const MissionFrameOptions defaults;
  EXPECT_DOUBLE_EQ(T_ML.variance.x(), defaults.launch_position_std_m * defaults.launch_position_std_m);
  EXPECT_DOUBLE_EQ(T_ML.variance.w(), defaults.launch_yaw_std_rad * defaults.launch_yaw_std_rad);
  EXPECT_TRUE(frame.source().empty());
}

TEST(MissionFrame, FollowsTheSurveyedSensorToItsFrame) {
  const Flight flight = SurveyedFlight();
  MissionFrame frame({}, flight.survey);  // no launch pad: the first fit is the frame
  std::mt19937 rng(7);
  const std::vector<MissionFrameEstimate> published = Fly(frame, flight, 30.0, rng);
  EXPECT_EQ(frame.source(), "leica");
  const Eigen::Isometry3d T_ML_true = flight.survey.T_MS.at("leica") * flight.T_SL;
  const MissionFrameEstimate& last = published.back();
  EXPECT_NEAR(core::DegFromRad(last.yaw_rad()), core::DegFromRad(core::YawOfNearestZRotation(T_ML_true.linear())),
              0.1);
  const Eigen::Vector3d p_LI = CircleT_LI(29.99, flight.radius_m).translation();
  EXPECT_LT((last.T_ML() * p_LI - T_ML_true * p_LI).norm(), 0.01);
}

// The reported variance is the error's: over many noise draws the squared error of the
// robot's position in M, divided by the reported variance, averages 1 per axis.
TEST(MissionFrame, ReportedVarianceMatchesTheErrorOverNoiseDraws) {
  const Flight flight = SurveyedFlight();
  const Eigen::Isometry3d T_ML_true = flight.survey.T_MS.at("leica") * flight.T_SL;
  constexpr int kTrials = 200;
  double normalised_sum = 0.0;
  double yaw_normalised_sum = 0.0;
  MissionFrameOptions options;
  options.local_position_std_m = 0.0;  // the positions' noise is all there is
  for (int trial = 0; trial < kTrials; ++trial) {
    MissionFrame frame(options, flight.survey);
    std::mt19937 rng(1000 + trial);
    const MissionFrameEstimate last = Fly(frame, flight, 12.0, rng).back();
    const Eigen::Vector3d p_LI = CircleT_LI(11.99, flight.radius_m).translation();
    const Eigen::Vector3d error = last.T_ML() * p_LI - T_ML_true * p_LI;
    normalised_sum += (error.cwiseAbs2().array() / last.variance.head<3>().array()).sum() / 3.0;
    const double yaw_error = std::remainder(
        last.yaw_rad() - core::YawOfNearestZRotation(T_ML_true.linear()), 2.0 * core::kPi);
    yaw_normalised_sum += yaw_error * yaw_error / last.variance.w();
  }
  // Each mean of kTrials χ² terms (1 DoF each, 3 axes averaged per trial: ≥ 1 DoF) has a
  // standard deviation of at most sqrt(2 / kTrials) = 0.1: 4σ either way.
  const double tolerance = 4.0 * std::sqrt(2.0 / kTrials);
  EXPECT_NEAR(normalised_sum / kTrials, 1.0, tolerance);
  EXPECT_NEAR(yaw_normalised_sum / kTrials, 1.0, tolerance);
}

TEST(MissionFrame, HoverKeepsTheHeadingAndFollowsThePosition) {
  Flight flight = SurveyedFlight();
  flight.radius_m = 0.0;  // the heading is unobservable
  // The pad: 0.37 m and 10 degrees off the truth.
  const Eigen::Isometry3d T_MI_true = flight.survey.T_MS.at("leica") * flight.T_SL * CircleT_LI(0.0, 0.0);
  Eigen::Isometry3d T_MI_launch = T_MI_true;
  T_MI_launch.linear() = YawPose(10.0, Eigen::Vector3d::Zero()).linear() * T_MI_true.linear();
  T_MI_launch.translation() += Eigen::Vector3d(0.3, -0.2, 0.1);
  flight.survey.T_MI_launch = T_MI_launch;
  MissionFrame frame({}, flight.survey);
  std::mt19937 rng(3);
  const std::vector<MissionFrameEstimate> published = Fly(frame, flight, 20.0, rng);
  // The heading is the launch pad's registration's, untouched.
  EXPECT_NEAR(published.back().yaw_rad(), published.front().yaw_rad(), 1e-12);
  // The robot's position follows the sensor: T_MS T_SL p_LI.
  const Eigen::Vector3d p_LI = CircleT_LI(19.99, 0.0).translation();
  const Eigen::Vector3d p_M_true = flight.survey.T_MS.at("leica") * flight.T_SL * p_LI;
  EXPECT_LT((published.back().T_ML() * p_LI - p_M_true).norm(), 0.01);
}

// The state the controller sees moves at most max_rate_mps because of T_ML, however far
// the launch pad's registration is from the surveyed frame.
TEST(MissionFrame, TheChangeOfFrameIsRateLimited) {
  Flight flight = SurveyedFlight();
  // The pad's registration 1.5 m and 20 degrees away from the truth.
  const Eigen::Isometry3d T_ML_true = flight.survey.T_MS.at("leica") * flight.T_SL;
  const Eigen::Isometry3d T_LI0 = CircleT_LI(0.0, flight.radius_m);
  flight.survey.T_MI_launch = YawPose(20.0, Eigen::Vector3d(1.0, -1.0, 0.5)) * T_ML_true * T_LI0;
  MissionFrameOptions options;
  MissionFrame frame(options, flight.survey);
  std::mt19937 rng(11);
  const std::vector<MissionFrameEstimate> published = Fly(frame, flight, 60.0, rng);
  double largest_mps = 0.0;
  double largest_radps = 0.0;
  for (std::size_t k = 1; k < published.size(); ++k) {
    const Eigen::Vector3d p_LI = CircleT_LI(k * 0.01, flight.radius_m).translation();
    const double moved_m = (published[k].T_ML() * p_LI - published[k - 1].T_ML() * p_LI).norm();
    largest_mps = std::max(largest_mps, moved_m / 0.01);
    largest_radps = std::max(largest_radps,
                             std::abs(std::remainder(published[k].yaw_rad() - published[k - 1].yaw_rad(),
                                                     2.0 * core::kPi)) / 0.01);
  }
  EXPECT_LE(largest_mps, options.max_rate_mps * (1.0 + 1e-6));
  EXPECT_LE(largest_radps, options.max_rate_radps * (1.0 + 1e-6));
  EXPECT_GT(largest_mps, 0.5 * options.max_rate_mps);  // it did move, at the limit
  // ...and arrived.
  const Eigen::Vector3d p_LI = CircleT_LI(59.99, flight.radius_m).translation();
  EXPECT_LT((published.back().T_ML() * p_LI - T_ML_true * p_LI).norm(), 0.01);
}

TEST(MissionFrame, OnlyTrustedSensorsMoveTheFrameAndForgetDropsTheirPositions) {
  Flight flight = SurveyedFlight();
  flight.survey.T_MI_launch = YawPose(0.0, Eigen::Vector3d::Zero());
  MissionFrame frame({}, flight.survey);
  std::mt19937 rng(5);
  Fly(frame, flight, 5.0, rng);
  const MissionFrameEstimate before = *frame.published();
  // Not trusted: the frame stays.
  for (int k = 0; k < 100; ++k) frame.Update(5'000 * kMs + k * 10 * kMs, CircleT_LI(5.0 + k * 0.01, 3.0), {});
  EXPECT_EQ(frame.published()->p_ML_m, before.p_ML_m);
  EXPECT_TRUE(frame.source().empty());
  // Forgotten: no fit until min_pairs new positions over min_span_ns.
  frame.Forget("leica");
  frame.Update(6'000 * kMs, CircleT_LI(6.0, 3.0), {"leica"});
  EXPECT_TRUE(frame.source().empty());
  EXPECT_FALSE(frame.Surveyed("vio"));
}

// L drifts against S at 1.1 cm/s (the odometries fused, as VIO does in
// closed_loop_indoor_outdoor_window): the translation is fitted at the newest instant, not
// at the window's middle, which would lag 5.5 cm behind. What is left (2.5 cm at most) is
// the heading's: fitted rigidly over the window, the drift biases it a little.
TEST(MissionFrame, FollowsALocalFrameThatDrifts) {
  Flight flight = SurveyedFlight();
  MissionFrame frame({}, flight.survey);
  std::mt19937 rng(17);
  std::normal_distribution<double> noise(0.0, flight.noise_std_m);
  const Eigen::Vector3d drift_mps(0.01, -0.005, 0.0025);
  Eigen::Isometry3d T_SL_now = flight.T_SL;
  for (int k = 0; k < 3000; ++k) {
    const double t_s = k * 0.01;
    const core::Time t_ns = k * 10 * kMs;
    T_SL_now = flight.T_SL;
    T_SL_now.translation() += t_s * drift_mps;
    const Eigen::Isometry3d T_LI = CircleT_LI(t_s, flight.radius_m);
    if (k % 10 == 0) {
      frame.AddPair("leica", t_ns, T_SL_now * T_LI.translation() + Eigen::Vector3d(noise(rng), noise(rng), noise(rng)),
                    T_LI.translation(), flight.noise_std_m * flight.noise_std_m * Eigen::Matrix3d::Identity());
    }
    frame.Update(t_ns, T_LI, {"leica"});
  }
  const Eigen::Vector3d p_LI = CircleT_LI(29.99, flight.radius_m).translation();
  const Eigen::Vector3d p_M_true = flight.survey.T_MS.at("leica") * T_SL_now * p_LI;
  EXPECT_LT((frame.published()->T_ML() * p_LI - p_M_true).norm(), 0.025);
}

// A fix that states 0.3 m (RTK float) is not flown on, however well it fits; a window
// that holds a jump is not explained by one transform and is not flown on either.
TEST(MissionFrame, ImpreciseOrMisfittingSensorsAreNotFollowed) {
  Flight imprecise = SurveyedFlight();
  imprecise.noise_std_m = 0.3;
  imprecise.survey.T_MI_launch = YawPose(0.0, Eigen::Vector3d::Zero());
  MissionFrame frame({}, imprecise.survey);
  std::mt19937 rng(13);
  const std::vector<MissionFrameEstimate> published = Fly(frame, imprecise, 15.0, rng);
  EXPECT_TRUE(frame.source().empty());
  EXPECT_EQ(published.back().p_ML_m, published.front().p_ML_m);

  Flight jumping = SurveyedFlight();
  MissionFrame jumped({}, jumping.survey);
  Fly(jumped, jumping, 12.0, rng);
  EXPECT_EQ(jumped.source(), "leica");
  // The sensor's frame jumps by 0.5 m: the window now holds both frames.
  jumping.T_SL.translation() += Eigen::Vector3d(0.5, 0.0, 0.0);
  Fly(jumped, jumping, 3.0, rng, 12.0);
  EXPECT_TRUE(jumped.source().empty());
  // Once the window holds the new frame only, it is followed again.
  Fly(jumped, jumping, 12.0, rng, 15.0);
  EXPECT_EQ(jumped.source(), "leica");
}

TEST(MissionFrame, OptionsAreChecked) {
  std::string why;
  EXPECT_TRUE(MissionFrameOptions{}.IsValid(&why)) << why;
  MissionFrameOptions options;
  options.max_rate_mps = 0.0;
  EXPECT_FALSE(options.IsValid(&why));
  EXPECT_EQ(why, "max_rate_mps must be > 0");
  options = {};
  options.min_span_ns = options.window_ns;
  EXPECT_FALSE(options.IsValid(&why));
  EXPECT_EQ(why, "min_span_ns must be in [0, window_ns)");
}

TEST(YawPositionRegistration, MapsThePoseAndKeepsGravity) {
  Eigen::Isometry3d T_AX = YawPose(120.0, Eigen::Vector3d(1.0, 2.0, 3.0));
  T_AX.linear() = T_AX.linear() * Eigen::AngleAxisd(0.05, Eigen::Vector3d::UnitY()).toRotationMatrix();
  const Eigen::Isometry3d T_BX = YawPose(-30.0, Eigen::Vector3d(-4.0, 0.5, 0.2));
  const Eigen::Isometry3d T_AB = core::YawPositionRegistration(T_AX, T_BX);
  EXPECT_LT((T_AB * T_BX.translation() - T_AX.translation()).norm(), 1e-12);
  EXPECT_NEAR(core::DegFromRad(core::YawOfNearestZRotation(T_AB.linear())), 150.0, 1e-9);
  EXPECT_LT((T_AB.linear() * Eigen::Vector3d::UnitZ() - Eigen::Vector3d::UnitZ()).norm(), 1e-12);
}

}  // namespace
}  // namespace tofu::estimator
