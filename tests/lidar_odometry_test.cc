// LiDAR odometry model (Mid-360 + FAST-LIO-like): the scan's point-to-plane information
// finds the direction along a single wall degenerate (ground + wall constrain x and z, not
// y) and nothing degenerate in the enclosed arena; drift follows the motion along the
// degenerate direction and not along the constrained one; too few returns make the output
// diverge; the reported pose and twist covariances reflect the degeneracy; with noise off
// the output is the LiDAR's kinematics; the YAML reader is strict. Models are driven directly:
// World::Reset to the start pose, then Step with a kinematic truth.

#include "sim/lidar_odometry.h"

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
#include "replay/run_calibration.h"
#include "sim/world.h"
#include "tests/sensor_model_test_support.h"

namespace tofu::sim {
namespace {

constexpr double kRadPerDeg = std::numbers::pi / 180.0;

using namespace tofu::sim::test;  // NOLINT: the shared sensor-test helpers

void PrintGeometry(const char* label, const LidarScanGeometry& g, double sigma) {
  const double s2 = sigma * sigma;
  std::printf("%s: %d/%d returns; translation eigenvalues x sigma^2 (effective returns) "
              "%.1f %.1f %.1f, directions (W):",
              label, g.return_count, g.ray_count, g.translation_eigenvalues[0] * s2,
              g.translation_eigenvalues[1] * s2, g.translation_eigenvalues[2] * s2);
  for (int k = 0; k < 3; ++k) {
    const Eigen::Vector3d u = g.translation_directions_W.col(k);
    std::printf(" [%.3f %.3f %.3f]%s", u.x(), u.y(), u.z(), g.translation_degenerate[k] ? "*" : "");
  }
  std::printf("; rotation x sigma^2 [m^2] %.0f %.0f %.0f\n", g.rotation_eigenvalues[0] * s2,
              g.rotation_eigenvalues[1] * s2, g.rotation_eigenvalues[2] * s2);
}

// ---- degeneracy from the information matrix ----

TEST(LidarOdometryModel, WallAndGroundLeaveOnlyTheAlongWallDirectionDegenerate) {
  // 1.5 m in front of the facade (front face x = 5), LiDAR at ~2.1 m height.
  World world = MakeWorld("inspection_wall");
  const Waypoint body = Pose({3.5, 0.0, 2.0});
  world.Reset(body);
  const LidarOdometryOptions options;
  LidarOdometryModel lio("lio", options, world, 1);
  const LidarScanGeometry g = lio.AnalyseScan(world, SitePose(world, body, "lidar"));
  PrintGeometry("wall", g, options.range_noise_m);

  ASSERT_GE(g.return_count, options.min_returns);
  EXPECT_FALSE(g.few_returns);
  EXPECT_TRUE(g.degenerate);
  // Smallest eigenvalue: ~0 along y (parallel to the wall, horizontal).
  EXPECT_TRUE(g.translation_degenerate[0]);
  EXPECT_LT(g.translation_eigenvalues[0] * options.range_noise_m * options.range_noise_m, 1e-6);
  EXPECT_GT(std::abs(g.translation_directions_W.col(0).y()), 0.999);
  // The others: z (ground, weaker) and x (the wall's normal, strongest), constrained.
  EXPECT_FALSE(g.translation_degenerate[1]);
  EXPECT_FALSE(g.translation_degenerate[2]);
  EXPECT_GT(std::abs(g.translation_directions_W.col(1).z()), 0.99);
  EXPECT_GT(std::abs(g.translation_directions_W.col(2).x()), 0.99);
  // The wall plus the ground constrain every rotation about the sensor.
  for (int k = 0; k < 3; ++k) EXPECT_FALSE(g.rotation_degenerate[k]);
  // The 6x6 decomposition agrees: its null direction is pure y translation.
  EXPECT_LT(g.eigenvalues[0], 1e-6);
  EXPECT_GT(std::abs(g.eigenvectors(4, 0)), 0.999);

  // Stepping the model flags kDegenerate, and the reported covariance is large along y
  // and small along the wall's normal (expressed in S, the LiDAR frame at t = 0).
  const auto samples = Drive(
      lio, world, [&](core::Time t) { return ConstantTwist(body, {0, 0, 0}, {0, 0, 0}, t); },
      0.05);
  ASSERT_EQ(samples.size(), 1u);
  EXPECT_EQ(samples[0].conditions, kDegenerate);
  EXPECT_EQ(lio.conditions(), kDegenerate);
  const Eigen::Matrix3d P = Measured(samples[0]).covariance.bottomRightCorner<3, 3>();
  const Eigen::Matrix3d R_WS = lio.T_WS().linear();
  const auto variance_along = [&](const Eigen::Vector3d& u_W) {
    const Eigen::Vector3d u_S = R_WS.transpose() * u_W;
    return u_S.dot(P * u_S);
  };
  std::printf("reported position std along x %.2e m, y %.3f m, z %.2e m\n",
              std::sqrt(variance_along(Eigen::Vector3d::UnitX())),
              std::sqrt(variance_along(Eigen::Vector3d::UnitY())),
              std::sqrt(variance_along(Eigen::Vector3d::UnitZ())));
  EXPECT_NEAR(std::sqrt(variance_along(Eigen::Vector3d::UnitY())),
              options.max_reported_position_std_m, 0.01);
  EXPECT_LT(std::sqrt(variance_along(Eigen::Vector3d::UnitX())), 0.005);
  EXPECT_LT(std::sqrt(variance_along(Eigen::Vector3d::UnitZ())), 0.01);

  // The twist states the same degeneracy: its velocity (in s) is unconstrained along y,
  // with the std of two poses one scan apart, and as noisy as the registration across;
  // the angular rate, the gyro's, is not degraded.
  const Eigen::Matrix<double, 6, 6> twist_covariance = Measured(samples[0]).twist_covariance;
  const Eigen::Matrix3d R_Ws = SitePose(world, body, "lidar").linear();
  const auto velocity_std_along = [&](const Eigen::Vector3d& u_W) {
    const Eigen::Vector3d u_s = R_Ws.transpose() * u_W;
    return std::sqrt(u_s.dot(twist_covariance.topLeftCorner<3, 3>() * u_s));
  };
  const double degenerate_std =
      std::sqrt(2.0 * options.max_reported_position_std_m * options.max_reported_position_std_m *
                    options.rate_hz * options.rate_hz +
                options.velocity_noise_mps * options.velocity_noise_mps);
  EXPECT_NEAR(velocity_std_along(Eigen::Vector3d::UnitY()), degenerate_std, 1e-3 * degenerate_std);
  EXPECT_NEAR(velocity_std_along(Eigen::Vector3d::UnitX()), options.velocity_noise_mps, 1e-3);
  EXPECT_NEAR(velocity_std_along(Eigen::Vector3d::UnitZ()), options.velocity_noise_mps, 1e-3);
  const Eigen::Matrix3d cross_covariance = twist_covariance.topRightCorner<3, 3>();
  const Eigen::Matrix3d angular_rate_covariance = twist_covariance.bottomRightCorner<3, 3>();
  EXPECT_TRUE(cross_covariance.isZero());
  EXPECT_TRUE(angular_rate_covariance.isApprox(options.angular_rate_noise_radps *
                                               options.angular_rate_noise_radps *
                                               Eigen::Matrix3d::Identity()));
}

TEST(LidarOdometryModel, EnclosedArenaHasNoDegenerateDirection) {
  World world = MakeWorld("indoor_arena");
  const Waypoint body = Pose({0.0, 0.0, 1.5});
  world.Reset(body);
  const LidarOdometryOptions options;
  LidarOdometryModel lio("lio", options, world, 1);
  const LidarScanGeometry g = lio.AnalyseScan(world, SitePose(world, body, "lidar"));
  PrintGeometry("arena", g, options.range_noise_m);
  EXPECT_EQ(g.return_count, g.ray_count);  // closed room: every ray returns
  EXPECT_FALSE(g.degenerate);
  const double s2 = options.range_noise_m * options.range_noise_m;
  EXPECT_GT(g.translation_eigenvalues[0] * s2, 10.0 * options.degenerate_translation_threshold);
  for (int k = 0; k < 3; ++k) EXPECT_FALSE(g.rotation_degenerate[k]);

  const auto samples = Drive(
      lio, world, [&](core::Time t) { return ConstantTwist(body, {0, 0, 0}, {0, 0, 0}, t); },
      0.05);
  ASSERT_EQ(samples.size(), 1u);
  EXPECT_EQ(samples[0].conditions, kConditionNone);
  // Nothing degenerate: the twist states the registration's velocity noise in every
  // direction.
  const Eigen::Matrix3d velocity_covariance =
      Measured(samples[0]).twist_covariance.topLeftCorner<3, 3>();
  EXPECT_TRUE(velocity_covariance.isApprox(
      options.velocity_noise_mps * options.velocity_noise_mps * Eigen::Matrix3d::Identity(),
      1e-9));
}

// ---- drift follows the motion along the degenerate direction ----

struct DriftRms {
  Eigen::Vector3d rms_W = Eigen::Vector3d::Zero();  ///< per W axis, over seeds
  uint32_t conditions = kConditionNone;
};

DriftRms FinalDrift(const Eigen::Vector3d& start_p, const Eigen::Vector3d& v_W, double duration_s) {
  World world = MakeWorld("inspection_wall");
  const Waypoint start = Pose(start_p);
  constexpr int kSeeds = 48;
  DriftRms out;
  for (int seed = 0; seed < kSeeds; ++seed) {
    world.Reset(start);
    LidarOdometryModel lio("lio", LidarOdometryOptions{}, world, 300 + seed);
    const auto samples = Drive(
        lio, world,
        [&](core::Time t) { return ConstantTwist(start, v_W, Eigen::Vector3d::Zero(), t); },
        duration_s + 1e-3);
    for (const auto& s : samples) out.conditions |= s.conditions;
    const Eigen::Vector3d e_W = lio.T_WS().linear() * PositionError_S(samples.back());
    out.rms_W += e_W.cwiseAbs2();
  }
  out.rms_W = (out.rms_W / kSeeds).cwiseSqrt();
  return out;
}

TEST(LidarOdometryModel, DriftFollowsTheMotionAlongTheDegenerateDirection) {
  const LidarOdometryOptions options;
  // 10 m along the wall (y, degenerate) vs 10 m away from it (x, constrained), 4 m/s,
  // LiDAR 1.5..11.5 m from the facade, wall and ground always in view.
  const DriftRms along = FinalDrift({3.5, -5.0, 2.0}, {0.0, 4.0, 0.0}, 2.5);
  const DriftRms away = FinalDrift({3.5, 0.0, 2.0}, {-4.0, 0.0, 0.0}, 2.5);
  std::printf("10 m along the wall: RMS error x %.4f y %.4f z %.4f m\n", along.rms_W.x(),
              along.rms_W.y(), along.rms_W.z());
  std::printf("10 m away from the wall: RMS error x %.4f y %.4f z %.4f m\n", away.rms_W.x(),
              away.rms_W.y(), away.rms_W.z());
  EXPECT_EQ(along.conditions, kDegenerate);
  EXPECT_EQ(away.conditions, kDegenerate);
  // Along y: the degenerate walk, sigma_deg sqrt(10 m) = 0.63 m; 48 seeds give ~10 %
  // relative spread of an RMS, so +-30 % is ~3 sigma.
  const double expected_y = options.degenerate_position_random_walk_m_per_sqrtm * std::sqrt(10.0);
  EXPECT_NEAR(along.rms_W.y(), expected_y, 0.3 * expected_y);
  // Along x: the constrained walk, 0.01 sqrt(10) = 0.03 m (+ mm white noise).
  const double expected_x = options.position_random_walk_m_per_sqrtm * std::sqrt(10.0);
  EXPECT_NEAR(away.rms_W.x(), expected_x, 0.3 * expected_x);
  EXPECT_GT(along.rms_W.y(), 10.0 * away.rms_W.x());
  // No motion along y in the second run: no degenerate drift either.
  EXPECT_LT(away.rms_W.y(), 0.02);
  EXPECT_LT(along.rms_W.x(), 0.05);
}

// ---- too few returns ----

TEST(LidarOdometryModel, FewReturnsDiverge) {
  // 60 m above open ground far from the facade: nothing within 40 m.
  World world = MakeWorld("inspection_wall");
  const Waypoint body = Pose({-20.0, 0.0, 60.0});
  world.Reset(body);
  const LidarOdometryOptions options;
  LidarOdometryModel lio("lio", options, world, 11);
  const auto samples = Drive(
      lio, world, [&](core::Time t) { return ConstantTwist(body, {0, 0, 0}, {0, 0, 0}, t); },
      3.05);
  ASSERT_EQ(samples.size(), 31u);
  EXPECT_EQ(lio.last_scan().return_count, 0);
  for (const auto& s : samples) EXPECT_TRUE(s.conditions & kFewReturns);
  const double e1 = PositionError_S(samples[10]).norm();
  const double e3 = PositionError_S(samples[30]).norm();
  // |e(t)| = |v0| tau (exp(t / tau) - 1): ratio (e^3 - 1) / (e - 1) = 11.1 at tau = 1 s.
  std::printf("few returns: |error| %.3f m at 1 s, %.3f m at 3 s (ratio %.1f, exp model 11.1)\n",
              e1, e3, e3 / e1);
  EXPECT_NEAR(e3 / e1, (std::exp(3.0) - 1.0) / (std::exp(1.0) - 1.0), 0.2);
  // The reported covariance is the prior: nothing constrained.
  const auto& cov = Measured(samples.back()).covariance;
  EXPECT_NEAR(cov(3, 3), 1.0, 1e-9);
  EXPECT_NEAR(cov(0, 0), 0.01, 1e-11);
}

TEST(LidarOdometryModel, NoiseOffReproducesTheLidarKinematics) {
  World world = MakeWorld("indoor_arena");
  const Waypoint start = Pose({-1.0, 0.5, 1.5}, 20.0);
  world.Reset(start);
  LidarOdometryOptions options;
  options.range_noise_m = 0.0;
  options.position_random_walk_m_per_sqrtm = 0.0;
  options.degenerate_position_random_walk_m_per_sqrtm = 0.0;
  options.rotation_random_walk_rad_per_sqrtm = 0.0;
  options.degenerate_rotation_random_walk_rad_per_sqrtrad = 0.0;
  options.divergence_velocity_mps = 0.0;
  options.velocity_noise_mps = 0.0;
  options.angular_rate_noise_radps = 0.0;
  LidarOdometryModel lio("lio", options, world, 3);
  const Eigen::Vector3d v_W(0.8, -0.3, 0.2), omega_B(0.1, -0.2, 0.5);
  const auto samples = Drive(
      lio, world, [&](core::Time t) { return ConstantTwist(start, v_W, omega_B, t); }, 2.0);
  ASSERT_EQ(samples.size(), 20u);
  EXPECT_TRUE(lio.T_WS().isApprox(world.SitePose_W("lidar"), 1e-9));
  const MountSite& mount = *world.robot().FindSite("lidar");
  for (size_t k = 0; k < samples.size(); ++k) {
    const SensorSample& s = samples[k];
    EXPECT_EQ(s.t_ns, static_cast<core::Time>(k) * 100'000'000);
    EXPECT_EQ(s.arrival_ns, s.t_ns + 20'000'000);
    EXPECT_EQ(Measured(s).p_Ss, Truth(s).p_Ss);
    EXPECT_EQ(Measured(s).q_Ss.coeffs(), Truth(s).q_Ss.coeffs());
    EXPECT_EQ(Measured(s).v_s_s_mps, Truth(s).v_s_s_mps);
    // Truth against the test's own kinematics.
    const TruthState x = ConstantTwist(start, v_W, omega_B, s.t_ns);
    const Eigen::Matrix3d R_Ws = x.q_WB.toRotationMatrix() * mount.q_Bs.toRotationMatrix();
    const Eigen::Vector3d p_Ws = x.p_WB + x.q_WB * mount.p_Bs;
    EXPECT_LT((Truth(s).p_Ss - lio.T_WS().inverse() * p_Ws).norm(), 1e-12);
    const Eigen::Vector3d v_s =
        R_Ws.transpose() * (v_W + x.q_WB * omega_B.cross(mount.p_Bs));
    EXPECT_LT((Truth(s).v_s_s_mps - v_s).norm(), 1e-12);
    EXPECT_LT((Truth(s).omega_s_s_radps - mount.q_Bs.conjugate() * omega_B).norm(), 1e-12);
  }
}

// ---- YAML ----

harness::YamlValue Root(const std::string& yaml) {
  return harness::ParseDocument(yaml, "lio.yaml");
}

TEST(LidarOdometryOptionsReader, ReadsAGoodMapAndRoundTrips) {
  const LidarOdometryOptions o = harness::internal::ReadSensorOptions<sim::LidarOdometryOptions>(Root(R"yaml(type: lidar_odometry
site: lidar
frame_position_m: [0, 1, 2]
frame_rpy_deg: [0, 10, 0]
rate_hz: 20
latency_s: 0.03
azimuth_count: 36
elevation_count: 8
elevation_min_deg: -10
elevation_max_deg: 50
min_range_m: 0.2
max_range_m: 70
range_noise_m: 0.03
degenerate_translation_threshold: 20
degenerate_rotation_threshold_m2: 15
min_returns: 40
position_random_walk_m_per_sqrtm: 0.02
degenerate_position_random_walk_m_per_sqrtm: 0.3
rotation_random_walk_deg_per_sqrtm: 0.05
degenerate_rotation_random_walk_rad_per_sqrtrad: 0.01
divergence_velocity_mps: 0.2
divergence_time_constant_s: 2
velocity_noise_mps: 0.05
angular_rate_noise_degps: 0.5
max_reported_position_std_m: 2
max_reported_rotation_std_deg: 10
)yaml"));
  ASSERT_TRUE(o.p_WS_m && o.q_WS);
  EXPECT_EQ(*o.p_WS_m, Eigen::Vector3d(0, 1, 2));
  EXPECT_EQ(o.rate_hz, 20.0);
  EXPECT_EQ(o.azimuth_count, 36);
  EXPECT_EQ(o.elevation_count, 8);
  EXPECT_NEAR(o.elevation_min_rad, -10 * kRadPerDeg, 1e-15);
  EXPECT_EQ(o.max_range_m, 70.0);
  EXPECT_EQ(o.min_returns, 40);
  EXPECT_EQ(o.degenerate_position_random_walk_m_per_sqrtm, 0.3);
  EXPECT_NEAR(o.rotation_random_walk_rad_per_sqrtm, 0.05 * kRadPerDeg, 1e-15);
  EXPECT_EQ(o.degenerate_rotation_random_walk_rad_per_sqrtrad, 0.01);
  EXPECT_NEAR(o.max_reported_rotation_std_rad, 10 * kRadPerDeg, 1e-15);

  YAML::Emitter out;
  out << YAML::BeginMap;
  harness::internal::EmitSensorOptions(out, o);
  out << YAML::EndMap;
  const LidarOdometryOptions back = harness::internal::ReadSensorOptions<sim::LidarOdometryOptions>(Root(out.c_str()));
  EXPECT_EQ(back.site, o.site);
  ASSERT_TRUE(back.p_WS_m && back.q_WS);
  EXPECT_EQ(*back.p_WS_m, *o.p_WS_m);
  EXPECT_NEAR(back.q_WS->angularDistance(*o.q_WS), 0.0, 1e-12);
  EXPECT_EQ(back.rate_hz, o.rate_hz);
  EXPECT_EQ(back.latency_s, o.latency_s);
  EXPECT_EQ(back.azimuth_count, o.azimuth_count);
  EXPECT_EQ(back.elevation_count, o.elevation_count);
  EXPECT_NEAR(back.elevation_min_rad, o.elevation_min_rad, 1e-15);
  EXPECT_NEAR(back.elevation_max_rad, o.elevation_max_rad, 1e-15);
  EXPECT_EQ(back.min_range_m, o.min_range_m);
  EXPECT_EQ(back.max_range_m, o.max_range_m);
  EXPECT_EQ(back.range_noise_m, o.range_noise_m);
  EXPECT_EQ(back.degenerate_translation_threshold, o.degenerate_translation_threshold);
  EXPECT_EQ(back.degenerate_rotation_threshold_m2, o.degenerate_rotation_threshold_m2);
  EXPECT_EQ(back.min_returns, o.min_returns);
  EXPECT_EQ(back.position_random_walk_m_per_sqrtm, o.position_random_walk_m_per_sqrtm);
  EXPECT_NEAR(back.rotation_random_walk_rad_per_sqrtm, o.rotation_random_walk_rad_per_sqrtm, 1e-18);
  EXPECT_EQ(back.divergence_velocity_mps, o.divergence_velocity_mps);
  EXPECT_EQ(back.divergence_time_constant_s, o.divergence_time_constant_s);
  EXPECT_EQ(back.velocity_noise_mps, o.velocity_noise_mps);
  EXPECT_NEAR(back.angular_rate_noise_radps, o.angular_rate_noise_radps, 1e-18);
  EXPECT_EQ(back.max_reported_position_std_m, o.max_reported_position_std_m);
  EXPECT_NEAR(back.max_reported_rotation_std_rad, o.max_reported_rotation_std_rad, 1e-15);
}

core::InputError ReadError(const std::string& yaml) {
  try {
    harness::internal::ReadSensorOptions<sim::LidarOdometryOptions>(Root(yaml));
  } catch (const core::InputError& e) {
    return e;
  }
  ADD_FAILURE() << "expected an InputError for:\n" << yaml;
  return core::InputError({}, "", "");
}

TEST(LidarOdometryOptionsReader, RejectsAnUnknownKey) {
  const core::InputError e = ReadError("rate_hz: 10\nmax_range: 40\n");
  std::printf("%s\n", e.what());
  EXPECT_EQ(e.location().file, "lio.yaml");
  EXPECT_EQ(e.location().line, 2);
  EXPECT_NE(std::string(e.what()).find("max_range"), std::string::npos);
}

TEST(LidarOdometryOptionsReader, RejectsAnOutOfRangeValue) {
  const core::InputError e = ReadError("rate_hz: 10\nelevation_max_deg: 120\n");
  std::printf("%s\n", e.what());
  EXPECT_EQ(e.location().line, 2);
  EXPECT_EQ(e.key_path(), "elevation_max_deg");
  EXPECT_EQ(ReadError("azimuth_count: 2.5\n").key_path(), "azimuth_count");
  EXPECT_EQ(ReadError("range_noise_m: -0.01\n").key_path(), "range_noise_m");
  const core::InputError ranges = ReadError("min_range_m: 50\n");
  EXPECT_NE(std::string(ranges.what()).find("min_range_m"), std::string::npos);
}

// ---- the beam pattern (core/lidar_beam_pattern.h), shared with the run's readers ----

// The scan's table of directions (what the model casts) is Direction_s, bit for bit, for
// any pattern and azimuth offset.
TEST(LidarBeamPattern, TheDirectionTableIsDirectionSBitForBit) {
  core::LidarBeamPattern beams;
  std::vector<Eigen::Vector3d> table;
  for (const auto& [columns, rows] : {std::pair{72, 12}, std::pair{5, 1}, std::pair{360, 32}}) {
    beams.azimuth_count = columns;
    beams.elevation_count = rows;
    for (const double offset_rad : {0.0, 0.031, -1.7, 1e-300}) {
      beams.Directions_s(offset_rad, &table);
      ASSERT_EQ(table.size(), static_cast<std::size_t>(columns * rows));
      for (int row = 0; row < rows; ++row) {
        for (int column = 0; column < columns; ++column) {
          ASSERT_EQ(table[static_cast<std::size_t>(row * columns + column)],
                    beams.Direction_s(row, column, offset_rad))
              << row << ", " << column << ", offset " << offset_rad;
        }
      }
    }
  }
}

TEST(LidarBeamPattern, RaysSpanTheElevationsAndTheFullTurn) {
  core::LidarBeamPattern beams;  // Mid-360: 72 x 12 over [-7, 52] deg
  for (int row = 0; row < beams.elevation_count; ++row) {
    for (int column = 0; column < beams.azimuth_count; ++column) {
      EXPECT_NEAR(beams.Direction_s(row, column).norm(), 1.0, 1e-15);
    }
  }
  const auto elevation = [](const Eigen::Vector3d& d) { return std::asin(d.z()); };
  EXPECT_NEAR(elevation(beams.Direction_s(0, 5)), beams.elevation_min_rad, 1e-12);
  EXPECT_NEAR(elevation(beams.Direction_s(beams.elevation_count - 1, 5)), beams.elevation_max_rad,
              1e-12);
  // Neighbouring columns a full turn / count apart; the offset turns every ray.
  const double step = 2.0 * std::numbers::pi / beams.azimuth_count;
  const Eigen::Vector3d a = beams.Direction_s(3, 10);
  const Eigen::Vector3d b = beams.Direction_s(3, 11);
  EXPECT_NEAR(std::atan2(b.y(), b.x()) - std::atan2(a.y(), a.x()), step, 1e-12);
  const Eigen::Vector3d turned = beams.Direction_s(3, 10, 0.25 * step);
  EXPECT_NEAR(std::atan2(turned.y(), turned.x()) - std::atan2(a.y(), a.x()), 0.25 * step, 1e-12);
  // One row: at the middle of the elevation band.
  beams.elevation_count = 1;
  EXPECT_NEAR(elevation(beams.Direction_s(0, 0)),
              0.5 * (beams.elevation_min_rad + beams.elevation_max_rad), 1e-12);
  EXPECT_TRUE(beams.InRange(beams.min_range_m));
  EXPECT_TRUE(beams.InRange(beams.max_range_m));
  EXPECT_FALSE(beams.InRange(0.5 * beams.min_range_m));
  EXPECT_FALSE(beams.InRange(std::nan("")));
}

TEST(LidarBeamPattern, RangesAndElevationsOutOfOrderAreInvalidUnderTheLaterKey) {
  std::string why;
  core::LidarBeamPattern beams;
  beams.min_range_m = beams.max_range_m;
  EXPECT_FALSE(beams.IsValid(&why));
  EXPECT_EQ(why.rfind("max_range_m: ", 0), 0u) << why;
  beams = {};
  std::swap(beams.elevation_min_rad, beams.elevation_max_rad);
  EXPECT_FALSE(beams.IsValid(&why));
  EXPECT_EQ(why.rfind("elevation_max_deg: ", 0), 0u) << why;
  // LiDAR odometry's options are a beam pattern and check it the same way.
  LidarOdometryOptions options;
  options.min_range_m = 2.0 * options.max_range_m;
  EXPECT_FALSE(options.IsValid(&why));
  EXPECT_EQ(why.rfind("max_range_m: ", 0), 0u) << why;
}

// What the scenario reader takes, calibration.yaml's reader takes the same: one table.
TEST(LidarBeamPattern, CalibrationReaderReadsTheScenarioKeysWithTheSameLimits) {
  const std::string beams_yaml =
      "azimuth_count: 36, elevation_count: 8, elevation_min_deg: -10, elevation_max_deg: 50, "
      "min_range_m: 0.2, max_range_m: 70";
  const LidarOdometryOptions o = harness::internal::ReadSensorOptions<sim::LidarOdometryOptions>(
      Root("{" + beams_yaml + "}"));
  const auto calibration = [](const std::string& options) {
    return replay::ParseRunCalibration(
        "sensors:\n  lidar:\n    type: lidar_odometry\n    options: {" + options + "}\n",
        "calibration.yaml");
  };
  const std::optional<core::LidarBeamPattern> read = calibration(beams_yaml).LidarBeams("lidar");
  ASSERT_TRUE(read.has_value());
  EXPECT_EQ(read->azimuth_count, o.azimuth_count);
  EXPECT_EQ(read->elevation_count, o.elevation_count);
  EXPECT_EQ(read->elevation_min_rad, o.elevation_min_rad);
  EXPECT_EQ(read->elevation_max_rad, o.elevation_max_rad);
  EXPECT_EQ(read->min_range_m, o.min_range_m);
  EXPECT_EQ(read->max_range_m, o.max_range_m);
  // Each limit of the table, and the order of the ranges, at the offending key.
  const std::pair<std::string, std::string> broken[] = {
      {"azimuth_count: 3601", "azimuth_count"},
      {"elevation_count: 2.5", "elevation_count"},
      {"elevation_min_deg: -91", "elevation_min_deg"},
      {"min_range_m: -1", "min_range_m"},
      {"max_range_m: 0.1", "max_range_m"},
      {"elevation_max_deg: -20", "elevation_max_deg"}};
  for (const auto& [replacement, key] : broken) {
    std::string text = beams_yaml;
    const size_t at = text.find(key + ":");
    text.replace(at, text.find(',', at) == std::string::npos ? std::string::npos
                                                             : text.find(',', at) - at,
                 replacement);
    try {
      (void)calibration(text).LidarBeams("lidar");
      ADD_FAILURE() << "no InputError for " << text;
    } catch (const core::InputError& e) {
      EXPECT_EQ(e.key_path(), "sensors.lidar.options." + key) << e.what();
      EXPECT_EQ(e.location().line, 4) << e.what();
    }
  }
  // A pattern with a key missing is no pattern (a run written before beams were recorded).
  EXPECT_FALSE(calibration("azimuth_count: 36").LidarBeams("lidar").has_value());
}

}  // namespace
}  // namespace tofu::sim
