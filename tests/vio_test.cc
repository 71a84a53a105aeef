// VIO model (T265-like): with every noise off it reproduces the camera's kinematics
// exactly; its feature score sees texture and depth (plain facade close up vs textured band
// vs indoor arena); starvation and blur flag and inflate the drift; a zero score diverges
// and then resets the tracker with a pose jump; the drift grows with the square root of the
// distance travelled; the YAML reader is strict. Models are driven directly: World::Reset
// to the start pose, then Step with a kinematic truth (constant twist or a smooth wobble).

#include "sim/vio.h"

#include <gtest/gtest.h>

#include <array>
#include <cmath>
#include <cstdio>
#include <functional>
#include <numbers>
#include <string>
#include <vector>

#include <yaml-cpp/yaml.h>

#include "core/error.h"
#include "core/lie.h"
#include "harness/sensor_config.h"
#include "harness/yaml_reader.h"
#include "sim/world.h"
#include "tests/sensor_model_test_support.h"

namespace tofu::sim {
namespace {

constexpr double kRadPerDeg = std::numbers::pi / 180.0;

using namespace tofu::sim::test;  // NOLINT: the shared sensor-test helpers

VioOptions NoiseFree() {
  VioOptions o;
  o.position_random_walk_m_per_sqrtm = 0.0;
  o.yaw_random_walk_rad_per_sqrtm = 0.0;
  o.tilt_random_walk_rad_per_sqrtm = 0.0;
  o.position_noise_m = 0.0;
  o.rotation_noise_rad = 0.0;
  o.velocity_noise_mps = 0.0;
  o.angular_rate_noise_radps = 0.0;
  o.lost_velocity_random_walk_mps_per_sqrts = 0.0;
  o.reset_jump_position_m = 0.0;
  o.reset_jump_yaw_rad = 0.0;
  return o;
}

// ---- noise off: exact kinematics ----

// A smooth motion with acceleration and rotation about a tilted axis:
// p = p0 + [A sin wt, A (1 - cos wt), c t], R = R0 Exp(omega_B t).
struct Wobble {
  Waypoint start = Pose({0.0, 0.0, 1.5}, 30.0);
  double amplitude_m = 0.8;
  double rate_radps = 1.3;
  double climb_mps = 0.2;
  Eigen::Vector3d omega_B{0.3, -0.2, 0.6};

  Eigen::Vector3d Position(double t) const {
    return start.p_WB + Eigen::Vector3d(amplitude_m * std::sin(rate_radps * t),
                                        amplitude_m * (1.0 - std::cos(rate_radps * t)),
                                        climb_mps * t);
  }
  Eigen::Matrix3d Rotation(double t) const {
    return start.q_WB.toRotationMatrix() * core::ExpSO3(omega_B * t);
  }
  TruthState At(core::Time t_ns) const {
    const double t = core::TimeToSeconds(t_ns);
    const double w = rate_radps, a = amplitude_m;
    TruthState x;
    x.t_ns = t_ns;
    x.p_WB = Position(t);
    x.q_WB = Eigen::Quaterniond(Rotation(t)).normalized();
    x.v_WB_W = Eigen::Vector3d(a * w * std::cos(w * t), a * w * std::sin(w * t), climb_mps);
    x.a_WB_W = Eigen::Vector3d(-a * w * w * std::sin(w * t), a * w * w * std::cos(w * t), 0.0);
    x.omega_WB_B = omega_B;
    return x;
  }
};

TEST(VioModel, NoiseOffReproducesTheCameraKinematics) {
  World world = MakeWorld("indoor_arena");
  const Wobble motion;
  world.Reset(motion.start);
  VioModel vio("vio", NoiseFree(), world, 7);
  const std::vector<SensorSample> samples =
      Drive(vio, world, [&](core::Time t) { return motion.At(t); }, 2.0);

  // 200 Hz on the 5 ms grid, latency 5 ms.
  ASSERT_EQ(samples.size(), 400u);
  const MountSite& cam = *world.robot().FindSite("vio_camera");
  // S is the camera pose at t = 0, which MuJoCo's own site pose confirms after Reset.
  const Eigen::Isometry3d T_WS = vio.T_WS();
  EXPECT_TRUE(T_WS.isApprox(world.SitePose_W("vio_camera"), 1e-9));

  const Eigen::Matrix3d R_Bs = cam.q_Bs.toRotationMatrix();
  auto p_Ws = [&](double t) -> Eigen::Vector3d {
    return motion.Position(t) + motion.Rotation(t) * cam.p_Bs;
  };
  auto R_Ws = [&](double t) -> Eigen::Matrix3d { return motion.Rotation(t) * R_Bs; };
  double worst_pose = 0.0, worst_twist = 0.0;
  for (size_t k = 0; k < samples.size(); ++k) {
    const SensorSample& s = samples[k];
    EXPECT_EQ(s.t_ns, static_cast<core::Time>(k) * 5'000'000);
    EXPECT_EQ(s.arrival_ns, s.t_ns + 5'000'000);
    const core::PoseMeasurement& m = Measured(s);
    const core::PoseMeasurement& truth = Truth(s);
    // Noise off: the measurement is the truth, bit for bit.
    EXPECT_EQ(m.p_Ss, truth.p_Ss);
    EXPECT_EQ(m.q_Ss.coeffs(), truth.q_Ss.coeffs());
    EXPECT_EQ(m.v_s_s_mps, truth.v_s_s_mps);
    EXPECT_EQ(m.omega_s_s_radps, truth.omega_s_s_radps);
    ASSERT_TRUE(m.has_twist);

    // The truth is the camera's kinematics: pose from the test's own chain of frames,
    // twist from central differences of that pose.
    const double t = core::TimeToSeconds(s.t_ns);
    const Eigen::Vector3d p_expected = T_WS.inverse() * p_Ws(t);
    const Eigen::Matrix3d R_expected = T_WS.linear().transpose() * R_Ws(t);
    const double h = 1e-5;
    const Eigen::Vector3d v_expected = R_Ws(t).transpose() * (p_Ws(t + h) - p_Ws(t - h)) / (2 * h);
    const Eigen::Vector3d w_expected =
        core::LogSO3(R_Ws(t - h).transpose() * R_Ws(t + h)) / (2 * h);
    worst_pose = std::max({worst_pose, (truth.p_Ss - p_expected).norm(),
                           core::RotationAngleBetween(truth.q_Ss.toRotationMatrix(), R_expected)});
    worst_twist = std::max({worst_twist, (truth.v_s_s_mps - v_expected).norm(),
                            (truth.omega_s_s_radps - w_expected).norm()});
  }
  std::printf("noise off: worst pose mismatch %.2e, worst twist mismatch %.2e\n", worst_pose,
              worst_twist);
  EXPECT_LT(worst_pose, 1e-12);
  EXPECT_LT(worst_twist, 1e-6);  // central-difference truncation and rounding
}

TEST(VioModel, ConfiguredFrameIsKeptAndMissingSiteThrows) {
  World world = MakeWorld("indoor_arena");
  world.Reset(Pose({1.0, 0.0, 1.5}));
  VioOptions options = NoiseFree();
  options.p_WS_m = Eigen::Vector3d(1.0, 2.0, 3.0);
  options.q_WS = Eigen::Quaterniond(Eigen::AngleAxisd(0.5, Eigen::Vector3d::UnitZ()));
  VioModel vio("vio", options, world, 1);
  const Waypoint start = Pose({1.0, 0.0, 1.5});
  const auto samples = Drive(
      vio, world, [&](core::Time t) { return ConstantTwist(start, {0.5, 0, 0}, {0, 0, 0}, t); },
      0.1);
  ASSERT_FALSE(samples.empty());
  EXPECT_TRUE(vio.T_WS().translation().isApprox(Eigen::Vector3d(1.0, 2.0, 3.0)));
  const Eigen::Isometry3d T_Ws = SitePose(world, start, "vio_camera");
  EXPECT_TRUE(Truth(samples[0]).p_Ss.isApprox(vio.T_WS().inverse() * T_Ws.translation(), 1e-12));

  options.site = "no_such_site";
  EXPECT_THROW(VioModel("vio", options, world, 1), std::invalid_argument);
}

// ---- features ----

TEST(VioModel, FeatureScoreFallsOnThePlainFacade) {
  World wall = MakeWorld("inspection_wall");
  World arena = MakeWorld("indoor_arena");
  const VioModel model("vio", VioOptions{}, wall, 1);
  // Camera 0.5 m from the plain concrete (x = 5) at z = 5: only textureless wall in view.
  const double plain = model.FeatureScore(wall, SitePose(wall, Pose({4.3, 0, 5.12}), "vio_camera"));
  // Partly plain, partly the textured band (z < 3) at the bottom of the image.
  const double partial =
      model.FeatureScore(wall, SitePose(wall, Pose({4.3, 0, 3.8}), "vio_camera"));
  // 1.5 m from the textured band at z = 1.4, grass below.
  const double band = model.FeatureScore(wall, SitePose(wall, Pose({3.3, 0, 1.5}), "vio_camera"));
  const double room =
      model.FeatureScore(arena, SitePose(arena, Pose({0, 0, 1.5}), "vio_camera"));
  std::printf("feature scores: plain facade %.3f, partial %.3f, textured band %.3f, arena %.3f\n",
              plain, partial, band, room);
  EXPECT_EQ(plain, 0.0);
  EXPECT_GT(partial, 0.0);
  EXPECT_LT(partial, VioOptions{}.starved_score_threshold);
  EXPECT_GT(band, 0.8);
  EXPECT_GT(room, 0.8);
}

// Final-position error RMS over seeds for a 5 m pass along the facade (y) at `p_WB`.
double RmsDriftAlongFacade(const Eigen::Vector3d& p_WB, uint32_t* conditions_seen) {
  World world = MakeWorld("inspection_wall");
  const Waypoint start = Pose(p_WB);
  double sum = 0.0;
  constexpr int kSeeds = 40;
  for (int seed = 0; seed < kSeeds; ++seed) {
    world.Reset(start);
    VioModel vio("vio", VioOptions{}, world, 1000 + seed);
    const auto samples = Drive(
        vio, world,
        [&](core::Time t) { return ConstantTwist(start, {0, 2.0, 0}, Eigen::Vector3d::Zero(), t); },
        2.5);
    for (const auto& s : samples) *conditions_seen |= s.conditions;
    sum += PositionError_S(samples.back()).squaredNorm();
  }
  return std::sqrt(sum / kSeeds);
}

TEST(VioModel, StarvationFlagsAndInflatesDrift) {
  uint32_t starved_conditions = 0, good_conditions = 0;
  const double starved = RmsDriftAlongFacade({4.3, -2.5, 3.8}, &starved_conditions);
  const double good = RmsDriftAlongFacade({3.3, -2.5, 1.5}, &good_conditions);
  std::printf("5 m along the facade: RMS error starved %.3f m, textured %.3f m (ratio %.2f)\n",
              starved, good, starved / good);
  EXPECT_TRUE(starved_conditions & kFeatureStarved);
  EXPECT_FALSE(starved_conditions & kLockLost);
  EXPECT_EQ(good_conditions, kConditionNone);
  // Every drift rate is multiplied by starved_drift_factor = 5 (same seeds, same path).
  EXPECT_NEAR(starved / good, VioOptions{}.starved_drift_factor, 0.5);
  // Textured: the 3D RMS of the random walk, sigma sqrt(3 d) (+ small heading terms).
  EXPECT_NEAR(good, 0.02 * std::sqrt(3.0 * 5.0), 0.25 * 0.02 * std::sqrt(15.0));
}

TEST(VioModel, ZeroScoreDivergesThenResetsWithAPoseJump) {
  World world = MakeWorld("inspection_wall");
  const Waypoint start = Pose({4.3, 0, 5.12});  // 0.5 m from the plain concrete
  world.Reset(start);
  VioModel vio("vio", VioOptions{}, world, 42);
  const auto samples = Drive(
      vio, world, [&](core::Time t) { return ConstantTwist(start, {0, 0, 0}, {0, 0, 0}, t); },
      2.5);
  ASSERT_EQ(samples.size(), 500u);
  EXPECT_EQ(vio.feature_score(), 0.0);
  std::vector<size_t> resets;
  for (size_t k = 0; k < samples.size(); ++k) {
    EXPECT_TRUE(samples[k].conditions & kFeatureStarved);
    EXPECT_TRUE(samples[k].conditions & kLockLost);
    // Tracker confidence 0: pose variance 0.01 * 10^3.
    EXPECT_DOUBLE_EQ(Measured(samples[k]).covariance(0, 0), 10.0);
    if (samples[k].conditions & kTrackerReset) resets.push_back(k);
  }
  // Zero score since t = 0: resets at 1.0 s and 2.0 s, each flagged on one sample.
  ASSERT_EQ(resets.size(), 2u);
  EXPECT_EQ(samples[resets[0]].t_ns, 1'000'000'000);
  EXPECT_EQ(samples[resets[1]].t_ns, 2'000'000'000);

  // Diverging while lost: the error at 0.99 s is far above the one at 0.1 s (hovering,
  // so no distance-driven drift at all).
  const double early = PositionError_S(samples[20]).norm();
  const double late = PositionError_S(samples[resets[0] - 1]).norm();
  // The jump: the error change over the reset sample against the typical change per sample.
  const double jump =
      (PositionError_S(samples[resets[0]]) - PositionError_S(samples[resets[0] - 1])).norm();
  double typical = 0.0;
  for (size_t k = resets[0] - 21; k < resets[0] - 1; ++k) {
    typical = std::max(
        typical, (PositionError_S(samples[k + 1]) - PositionError_S(samples[k])).norm());
  }
  // After the reset the velocity error is cleared.
  const double v_before = (Measured(samples[resets[0] - 1]).v_s_s_mps -
                           Truth(samples[resets[0] - 1]).v_s_s_mps).norm();
  const double v_after =
      (Measured(samples[resets[0]]).v_s_s_mps - Truth(samples[resets[0]]).v_s_s_mps).norm();
  std::printf("lost: |error| %.3f m at 0.1 s, %.3f m at 0.995 s; reset jump %.3f m (largest "
              "step before %.4f m); |v error| %.3f -> %.3f m/s\n",
              early, late, jump, typical, v_before, v_after);
  EXPECT_GT(late, 5.0 * early);
  EXPECT_GT(jump, 10.0 * typical);
  EXPECT_LT(v_after, 0.1);
}

TEST(VioModel, TrackingResumesWhenFeaturesReturn) {
  // Lost at the plain facade for 0.5 s (no reset yet), then the camera drops to the band.
  World world = MakeWorld("inspection_wall");
  const Waypoint start = Pose({4.3, 0, 5.12});
  world.Reset(start);
  VioModel vio("vio", VioOptions{}, world, 3);
  const auto samples = Drive(
      vio, world,
      [&](core::Time t) {
        // Hover 0.5 s, then descend at 4 m/s (a kinematic jump is fine for the model).
        const double s = core::TimeToSeconds(t);
        TruthState x = ConstantTwist(start, {0, 0, 0}, {0, 0, 0}, t);
        if (s > 0.5) {
          x.p_WB.z() -= 4.0 * (s - 0.5);
          x.p_WB.x() = 3.3;
          x.v_WB_W = Eigen::Vector3d(0, 0, -4.0);
        }
        return x;
      },
      1.4);
  EXPECT_TRUE(samples.front().conditions & kLockLost);
  EXPECT_EQ(samples.back().conditions, kConditionNone);
  EXPECT_GT(vio.feature_score(), 0.8);
  for (const auto& s : samples) EXPECT_FALSE(s.conditions & kTrackerReset);
  EXPECT_DOUBLE_EQ(Measured(samples.back()).covariance(0, 0), 0.01);  // confidence 3
}

TEST(VioModel, FastRotationBlurs) {
  World world = MakeWorld("indoor_arena");
  const Waypoint start = Pose({0, 0, 1.5});
  world.Reset(start);
  VioModel vio("vio", VioOptions{}, world, 5);
  // 3 rad/s yaw > 2.5 rad/s blur limit.
  const auto samples = Drive(
      vio, world, [&](core::Time t) { return ConstantTwist(start, {0, 0, 0}, {0, 0, 3.0}, t); },
      0.2);
  ASSERT_FALSE(samples.empty());
  EXPECT_TRUE(samples.back().conditions & kMotionBlur);
  EXPECT_FALSE(samples.back().conditions & kFeatureStarved);
  EXPECT_DOUBLE_EQ(Measured(samples.back()).covariance(0, 0), 0.1);  // confidence 2
  EXPECT_DOUBLE_EQ(Measured(samples.back()).twist_covariance(0, 0), 0.001);
}

// ---- drift statistics ----

TEST(VioModel, DriftGrowsWithTheSquareRootOfDistance) {
  // Straight flight over the textured grass away from the facade at 4 m/s: errors after
  // 10 m (2.5 s) and 40 m (10 s), over seeds.
  World world = MakeWorld("inspection_wall");
  const Waypoint start = Pose({0, 0, 2.0});
  const VioOptions options;
  constexpr int kSeeds = 96;
  double sum10 = 0.0, sum40 = 0.0, yaw10 = 0.0, yaw40 = 0.0, lat10 = 0.0, lat40 = 0.0;
  for (int seed = 0; seed < kSeeds; ++seed) {
    world.Reset(start);
    VioModel vio("vio", options, world, 5000 + seed);
    const auto samples = Drive(
        vio, world,
        [&](core::Time t) { return ConstantTwist(start, {-4.0, 0, 0}, Eigen::Vector3d::Zero(), t); },
        10.0 + 1e-3);
    const Eigen::Matrix3d R_WS = vio.T_WS().linear();
    const SensorSample& at10 = samples[500];   // t = 2.5 s
    const SensorSample& at40 = samples[2000];  // t = 10 s
    ASSERT_EQ(at10.t_ns, 2'500'000'000);
    ASSERT_EQ(at40.t_ns, 10'000'000'000);
    ASSERT_EQ(at40.conditions, kConditionNone);
    // Along-track (x) and vertical (z) errors in W: the position random walk alone (the
    // heading error bends the path sideways, into y).
    const Eigen::Vector3d e10 = R_WS * PositionError_S(at10);
    const Eigen::Vector3d e40 = R_WS * PositionError_S(at40);
    sum10 += e10.x() * e10.x() + e10.z() * e10.z();
    sum40 += e40.x() * e40.x() + e40.z() * e40.z();
    lat10 += e10.y() * e10.y();
    lat40 += e40.y() * e40.y();
    const double y10 = (R_WS * RotationError_S(at10)).z();
    const double y40 = (R_WS * RotationError_S(at40)).z();
    yaw10 += y10 * y10;
    yaw40 += y40 * y40;
  }
  const double rms10 = std::sqrt(sum10 / (2 * kSeeds)), rms40 = std::sqrt(sum40 / (2 * kSeeds));
  const double yaw_rms10 = std::sqrt(yaw10 / kSeeds), yaw_rms40 = std::sqrt(yaw40 / kSeeds);
  const double lat_rms10 = std::sqrt(lat10 / kSeeds), lat_rms40 = std::sqrt(lat40 / kSeeds);
  std::printf("RMS per axis along-track/vertical: %.4f m at 10 m, %.4f m at 40 m (ratio %.3f; "
              "model sigma sqrt(d): %.4f, %.4f)\n",
              rms10, rms40, rms40 / rms10, options.position_random_walk_m_per_sqrtm * std::sqrt(10.0),
              options.position_random_walk_m_per_sqrtm * std::sqrt(40.0));
  std::printf("RMS yaw: %.5f rad at 10 m, %.5f rad at 40 m (ratio %.3f); lateral %.4f m, "
              "%.4f m (ratio %.2f, heading-driven ~ d^1.5)\n",
              yaw_rms10, yaw_rms40, yaw_rms40 / yaw_rms10, lat_rms10, lat_rms40,
              lat_rms40 / lat_rms10);
  // sqrt(40 / 10) = 2. Relative std of an RMS over n samples ~ 1 / sqrt(2 n): with n = 192
  // (x and z pooled) ~5 % each, so +-15 % on the ratio is about 3 sigma. The vertical axis
  // also carries the tilt walk times distance (+~3 % on the ratio).
  EXPECT_NEAR(rms40 / rms10, 2.0, 0.3);
  EXPECT_NEAR(yaw_rms40 / yaw_rms10, 2.0, 0.4);
  EXPECT_NEAR(rms40, options.position_random_walk_m_per_sqrtm * std::sqrt(40.0),
              0.2 * options.position_random_walk_m_per_sqrtm * std::sqrt(40.0));
  EXPECT_GT(lat_rms40 / lat_rms10, 3.0);
}

// ---- YAML ----

harness::YamlValue Root(const std::string& yaml) {
  return harness::ParseDocument(yaml, "vio.yaml");
}

TEST(VioOptionsReader, ReadsAGoodMapAndRoundTrips) {
  const VioOptions o = harness::internal::ReadSensorOptions<sim::VioOptions>(Root(R"yaml(type: vio
site: vio_camera
frame_position_m: [1, 2, 3]
frame_rpy_deg: [0, 0, 90]
rate_hz: 100
latency_s: 0.01
position_random_walk_m_per_sqrtm: 0.03
yaw_random_walk_deg_per_sqrtm: 0.2
tilt_random_walk_deg_per_sqrtm: 0.01
position_noise_m: 0.001
rotation_noise_deg: 0.05
velocity_noise_mps: 0.02
angular_rate_noise_degps: 0.1
feature_check_rate_hz: 20
feature_grid_columns: 10
feature_grid_rows: 8
feature_fov_horizontal_deg: 120
feature_fov_vertical_deg: 100
feature_min_depth_m: 0.2
feature_max_depth_m: 8
starved_score_threshold: 0.3
starved_drift_factor: 4
blur_angular_rate_degps: 180
blur_drift_factor: 2
lost_velocity_random_walk_mps_per_sqrts: 0.4
reset_after_s: 1.5
reset_jump_position_m: 0.2
reset_jump_yaw_deg: 2
reported_pose_variance_base: 0.02
reported_twist_variance_base: 0.03
)yaml"));
  ASSERT_TRUE(o.p_WS_m.has_value());
  EXPECT_EQ(*o.p_WS_m, Eigen::Vector3d(1, 2, 3));
  ASSERT_TRUE(o.q_WS.has_value());
  EXPECT_NEAR(o.q_WS->angularDistance(Eigen::Quaterniond(
                  Eigen::AngleAxisd(std::numbers::pi / 2, Eigen::Vector3d::UnitZ()))),
              0.0, 1e-12);
  EXPECT_EQ(o.rate_hz, 100.0);
  EXPECT_EQ(o.latency_s, 0.01);
  EXPECT_EQ(o.position_random_walk_m_per_sqrtm, 0.03);
  EXPECT_NEAR(o.yaw_random_walk_rad_per_sqrtm, 0.2 * kRadPerDeg, 1e-15);
  EXPECT_NEAR(o.feature_fov_horizontal_rad, 120 * kRadPerDeg, 1e-15);
  EXPECT_EQ(o.feature_grid_columns, 10);
  EXPECT_EQ(o.feature_grid_rows, 8);
  EXPECT_EQ(o.starved_score_threshold, 0.3);
  EXPECT_NEAR(o.blur_angular_rate_radps, std::numbers::pi, 1e-12);
  EXPECT_EQ(o.reset_after_s, 1.5);
  EXPECT_EQ(o.reported_twist_variance_base, 0.03);

  // Emit and read back: the same options.
  YAML::Emitter out;
  out << YAML::BeginMap;
  harness::internal::EmitSensorOptions(out, o);
  out << YAML::EndMap;
  const VioOptions back = harness::internal::ReadSensorOptions<sim::VioOptions>(Root(out.c_str()));
  EXPECT_EQ(back.site, o.site);
  ASSERT_TRUE(back.p_WS_m && back.q_WS);
  EXPECT_EQ(*back.p_WS_m, *o.p_WS_m);
  EXPECT_NEAR(back.q_WS->angularDistance(*o.q_WS), 0.0, 1e-12);
  EXPECT_EQ(back.rate_hz, o.rate_hz);
  EXPECT_EQ(back.position_random_walk_m_per_sqrtm, o.position_random_walk_m_per_sqrtm);
  EXPECT_NEAR(back.yaw_random_walk_rad_per_sqrtm, o.yaw_random_walk_rad_per_sqrtm, 1e-18);
  EXPECT_NEAR(back.tilt_random_walk_rad_per_sqrtm, o.tilt_random_walk_rad_per_sqrtm, 1e-18);
  EXPECT_NEAR(back.rotation_noise_rad, o.rotation_noise_rad, 1e-18);
  EXPECT_NEAR(back.angular_rate_noise_radps, o.angular_rate_noise_radps, 1e-18);
  EXPECT_EQ(back.feature_check_rate_hz, o.feature_check_rate_hz);
  EXPECT_EQ(back.feature_grid_columns, o.feature_grid_columns);
  EXPECT_EQ(back.feature_grid_rows, o.feature_grid_rows);
  EXPECT_NEAR(back.feature_fov_horizontal_rad, o.feature_fov_horizontal_rad, 1e-15);
  EXPECT_NEAR(back.feature_fov_vertical_rad, o.feature_fov_vertical_rad, 1e-15);
  EXPECT_EQ(back.feature_min_depth_m, o.feature_min_depth_m);
  EXPECT_EQ(back.feature_max_depth_m, o.feature_max_depth_m);
  EXPECT_EQ(back.starved_drift_factor, o.starved_drift_factor);
  EXPECT_NEAR(back.blur_angular_rate_radps, o.blur_angular_rate_radps, 1e-15);
  EXPECT_EQ(back.blur_drift_factor, o.blur_drift_factor);
  EXPECT_EQ(back.lost_velocity_random_walk_mps_per_sqrts, o.lost_velocity_random_walk_mps_per_sqrts);
  EXPECT_EQ(back.reset_jump_position_m, o.reset_jump_position_m);
  EXPECT_NEAR(back.reset_jump_yaw_rad, o.reset_jump_yaw_rad, 1e-18);
  EXPECT_EQ(back.reported_pose_variance_base, o.reported_pose_variance_base);

  // Defaults: absent frame keys stay absent (the frame is the start pose).
  const VioOptions defaults = harness::internal::ReadSensorOptions<sim::VioOptions>(Root("rate_hz: 200\n"));
  EXPECT_FALSE(defaults.p_WS_m || defaults.q_WS);
  YAML::Emitter d;
  d << YAML::BeginMap;
  harness::internal::EmitSensorOptions(d, defaults);
  d << YAML::EndMap;
  EXPECT_EQ(std::string(d.c_str()).find("frame_"), std::string::npos);
}

core::InputError ReadError(const std::string& yaml) {
  try {
    harness::internal::ReadSensorOptions<sim::VioOptions>(Root(yaml));
  } catch (const core::InputError& e) {
    return e;
  }
  ADD_FAILURE() << "expected an InputError for:\n" << yaml;
  return core::InputError({}, "", "");
}

TEST(VioOptionsReader, RejectsAnUnknownKey) {
  const core::InputError e = ReadError("rate_hz: 200\nfeature_grid_colums: 8\n");
  std::printf("%s\n", e.what());
  EXPECT_EQ(e.location().file, "vio.yaml");
  EXPECT_EQ(e.location().line, 2);
  EXPECT_NE(std::string(e.what()).find("feature_grid_colums"), std::string::npos);
  EXPECT_NE(std::string(e.what()).find("feature_grid_columns"), std::string::npos);  // hint
}

TEST(VioOptionsReader, RejectsAnOutOfRangeValue) {
  const core::InputError e = ReadError("rate_hz: 200\nlatency_s: 0.005\nstarved_score_threshold: 1.5\n");
  std::printf("%s\n", e.what());
  EXPECT_EQ(e.location().line, 3);
  EXPECT_EQ(e.key_path(), "starved_score_threshold");
  const core::InputError grid = ReadError("feature_grid_rows: 0\n");
  EXPECT_EQ(grid.key_path(), "feature_grid_rows");
  const core::InputError depth = ReadError("feature_min_depth_m: 12\n");
  EXPECT_NE(std::string(depth.what()).find("feature_min_depth_m"), std::string::npos);
}

}  // namespace
}  // namespace tofu::sim
