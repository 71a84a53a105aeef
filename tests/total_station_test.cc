// Total station (sim::TotalStationModel) on the real bridge world: the line of sight is
// blocked exactly where an independent segment-vs-pillar geometry says so, lock is lost
// on occlusion and on fast angular motion and comes back only after the search delay,
// the robot's own body can hide the prism, the noise matches the reported covariance,
// and the YAML reader is strict.

#include "sim/total_station.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <functional>
#include <iostream>
#include <string>
#include <variant>
#include <vector>

#include <Eigen/Cholesky>
#include <Eigen/Eigenvalues>

#include "core/error.h"
#include "harness/sensor_config.h"
#include "harness/yaml_reader.h"

namespace tofu::sim {
namespace {

constexpr core::Time kStepNs = 1'000'000;  // 1 kHz physics
constexpr core::Time kMs = 1'000'000;

// Pose and velocity of B at a time: what the test drives the model with.
struct Motion {
  Eigen::Vector3d p_WB;
  Eigen::Vector3d v_WB_W;
};

// One step of the model: the world's robot at the truth pose (the ray casts see it), then
// Step with the matching TruthState. Conditions are recorded at every step.
struct Recording {
  std::vector<SensorSample> samples;
  std::vector<uint32_t> conditions;  ///< per step
};

Recording Drive(World& world, TotalStationModel& model, core::Time duration_ns,
                const std::function<Motion(double)>& motion) {
  Recording rec;
  const std::array<double, kArmCount * kRotorsPerArm> thrust{};
  for (core::Time t = 0; t < duration_ns; t += kStepNs) {
    const Motion m = motion(core::TimeToSeconds(t));
    world.Reset(Waypoint{m.p_WB, Eigen::Quaterniond::Identity()});
    TruthState x;
    x.t_ns = t;
    x.p_WB = m.p_WB;
    x.v_WB_W = m.v_WB_W;
    model.Step(SensorInput{x, world, thrust}, &rec.samples);
    rec.conditions.push_back(model.conditions());
  }
  return rec;
}

// Independent line-of-sight geometry: does the segment a-b pass through one of the
// bridge's pillars (vertical cylinders r = 0.6 at x in {-6, 0, 6}, y = +-3, z in [-2, 6],
// models/worlds/bridge.xml)? Returns the clearance (distance to the nearest pillar axis
// minus the radius, in the horizontal plane; negative = blocked).
double PillarClearance(const Eigen::Vector3d& a, const Eigen::Vector3d& b) {
  double clearance = 1e9;
  for (const double px : {-6.0, 0.0, 6.0}) {
    for (const double py : {-3.0, 3.0}) {
      const Eigen::Vector2d c(px, py), a2 = a.head<2>(), ab = (b - a).head<2>();
      const double s = std::clamp((c - a2).dot(ab) / ab.squaredNorm(), 0.0, 1.0);
      clearance = std::min(clearance, (a2 + s * ab - c).norm() - 0.6);
    }
  }
  return clearance;
}

const Eigen::Vector3d kStation_W(-15.0, 0.0, 1.5);  // bridge.xml station_tripod

Eigen::Vector3d Prism_W(const World& world, const Eigen::Vector3d& p_WB) {
  return p_WB + world.robot().FindSite("prism")->p_Bs;
}

TEST(TotalStation, StationFrameIsTheTripodSiteUnlessOverridden) {
  World world({.world = "bridge"});
  TotalStationModel at_tripod("ts", {}, world, 1);
  EXPECT_TRUE(at_tripod.T_WS().translation().isApprox(kStation_W, 1e-12));
  EXPECT_TRUE(at_tripod.T_WS().linear().isIdentity(1e-12));

  TotalStationOptions options;
  options.p_WS_m = Eigen::Vector3d(1.0, 2.0, 3.0);
  options.q_WS = Eigen::Quaterniond(Eigen::AngleAxisd(0.5, Eigen::Vector3d::UnitZ()));
  TotalStationModel overridden("ts", options, world, 1);
  EXPECT_TRUE(overridden.T_WS().translation().isApprox(*options.p_WS_m, 1e-12));
  EXPECT_TRUE(overridden.T_WS().linear().isApprox(options.q_WS->toRotationMatrix(), 1e-12));

  TotalStationOptions bad_site;
  bad_site.site = "no_such_site";
  EXPECT_THROW(TotalStationModel("ts", bad_site, world, 1), std::invalid_argument);
  TotalStationOptions bad_station;
  bad_station.station_site = "no_such_tripod";
  EXPECT_THROW(TotalStationModel("ts", bad_station, world, 1), std::invalid_argument);
}

// The robot flies along y at x = -3 behind the pillar at (-6, -3): samples stop exactly
// at the sample times where the independent geometry blocks the line of sight, the
// labels read occluded + lock_lost, then searching for search_delay_s once visible again,
// and samples resume at the first sample time after the search delay.
TEST(TotalStation, PillarOcclusionDropsSamplesAndRelocksAfterTheSearchDelay) {
  World world({.world = "bridge"});
  const TotalStationOptions options;  // defaults: 20 Hz, 2 s search delay
  TotalStationModel model("ts", options, world, 7);
  const double speed = 1.0;
  const auto motion = [&](double t_s) {
    return Motion{Eigen::Vector3d(-3.0, -8.0 + speed * t_s, 3.0), Eigen::Vector3d(0, speed, 0)};
  };
  const core::Time duration = 9'000 * kMs;
  const Recording rec = Drive(world, model, duration, motion);

  // Independent geometry at every sample time (50 ms grid).
  const core::Time period = core::PeriodFromRate(options.rate_hz);
  const core::Time search = core::SecondsToTime(options.search_delay_s);
  std::vector<bool> blocked;
  int first_blocked = -1, last_blocked = -1;
  for (core::Time t = 0; t < duration; t += period) {
    const Eigen::Vector3d prism = Prism_W(world, motion(core::TimeToSeconds(t)).p_WB);
    const double clearance = PillarClearance(kStation_W, prism);
    ASSERT_GT(std::abs(clearance), 1e-6) << "sample grazes a pillar; move the path";
    // The segment stays below the deck and above the ground: only pillars can block it.
    ASSERT_LT(std::max(prism.z(), kStation_W.z()), 6.0);
    blocked.push_back(clearance < 0.0);
    if (clearance < 0.0) {
      if (first_blocked < 0) first_blocked = static_cast<int>(blocked.size()) - 1;
      last_blocked = static_cast<int>(blocked.size()) - 1;
    }
  }
  ASSERT_GE(first_blocked, 0) << "the path never passes behind a pillar";
  for (int i = first_blocked; i <= last_blocked; ++i) ASSERT_TRUE(blocked[i]) << "not one gap";
  const core::Time t_block = first_blocked * period;       // first occluded sample
  const core::Time t_clear = (last_blocked + 1) * period;  // first visible again
  const core::Time t_relock = t_clear + search;
  ASSERT_LT(t_relock, duration);
  std::printf("occluded [%.3f, %.3f) s, searching [%.3f, %.3f) s\n", core::TimeToSeconds(t_block),
              core::TimeToSeconds(t_clear), core::TimeToSeconds(t_clear),
              core::TimeToSeconds(t_relock));

  // Exactly the sample times outside [t_block, t_relock) carry a sample.
  std::vector<core::Time> expected;
  for (core::Time t = 0; t < duration; t += period) {
    if (t < t_block || t >= t_relock) expected.push_back(t);
  }
  std::vector<core::Time> got;
  for (const SensorSample& s : rec.samples) got.push_back(s.t_ns);
  EXPECT_EQ(got, expected);

  // Labels at every physics step.
  for (size_t k = 0; k < rec.conditions.size(); ++k) {
    const core::Time t = static_cast<core::Time>(k) * kStepNs;
    uint32_t want = kConditionNone;
    if (t >= t_block && t < t_clear) want = kOccluded | kLockLost;
    if (t >= t_clear && t < t_relock) want = kSearching;
    ASSERT_EQ(rec.conditions[k], want) << "at t = " << core::TimeToSeconds(t) << " s";
  }

  // Samples: stamps, latency, truth in S (station axes = W axes here), error within 6 sigma.
  for (const SensorSample& s : rec.samples) {
    EXPECT_EQ(s.arrival_ns, s.t_ns + core::SecondsToTime(options.latency_s));
    EXPECT_EQ(s.conditions, kConditionNone);
    const auto& truth = std::get<core::PositionMeasurement>(s.truth);
    const auto& measured = std::get<core::PositionMeasurement>(s.measured);
    const Eigen::Vector3d p_Ss =
        Prism_W(world, motion(core::TimeToSeconds(s.t_ns)).p_WB) - kStation_W;
    EXPECT_LT((truth.p_Ss - p_Ss).norm(), 1e-9);
    const Eigen::Vector3d e = measured.p_Ss - truth.p_Ss;
    EXPECT_LT(e.dot(measured.covariance.inverse() * e), 6.0 * 6.0);
  }
}

// A jerk sideways near the station: the prism's angular rate seen from the station
// exceeds the tracking limit while it stays visible: lock_lost (not occluded) for the
// duration of the jerk, searching for search_delay_s, then samples again.
TEST(TotalStation, FastAngularMotionLosesLockAlthoughVisible) {
  World world({.world = "bridge"});
  const TotalStationOptions options;
  TotalStationModel model("ts", options, world, 3);
  // d ~ 5.2 m from the station: 3 m/s sideways is ~0.58 rad/s > 0.45 rad/s.
  const double t0 = 1.0, t1 = 1.3, v_jerk = 3.0;
  const auto motion = [&](double t_s) {
    const double y = v_jerk * std::clamp(t_s - t0, 0.0, t1 - t0);
    const double v = (t_s >= t0 && t_s < t1) ? v_jerk : 0.0;
    return Motion{Eigen::Vector3d(-10.0, -0.45 + y, 3.0), Eigen::Vector3d(0, v, 0)};
  };
  const core::Time duration = 4'000 * kMs;
  const Recording rec = Drive(world, model, duration, motion);

  const core::Time period = core::PeriodFromRate(options.rate_hz);
  const core::Time jerk_start = core::SecondsToTime(t0), jerk_end = core::SecondsToTime(t1);
  const core::Time relock = jerk_end + core::SecondsToTime(options.search_delay_s);
  // The rate during the jerk, from the geometry (prism at the jerk's midpoint).
  const Eigen::Vector3d mid = Prism_W(world, motion(0.5 * (t0 + t1)).p_WB) - kStation_W;
  const Eigen::Vector3d u = mid.normalized();
  const Eigen::Vector3d v(0, v_jerk, 0);
  const double rate = (v - u.dot(v) * u).norm() / mid.norm();
  std::printf("angular rate during the jerk %.3f rad/s (limit %.3f)\n", rate,
              options.max_angular_rate_radps);
  ASSERT_GT(rate, options.max_angular_rate_radps * 1.1);

  std::vector<core::Time> expected, got;
  for (core::Time t = 0; t < duration; t += period) {
    if (t < jerk_start || t >= relock) expected.push_back(t);
  }
  for (const SensorSample& s : rec.samples) got.push_back(s.t_ns);
  EXPECT_EQ(got, expected);
  for (size_t k = 0; k < rec.conditions.size(); ++k) {
    const core::Time t = static_cast<core::Time>(k) * kStepNs;
    uint32_t want = kConditionNone;
    if (t >= jerk_start && t < jerk_end) want = kLockLost;
    if (t >= jerk_end && t < relock) want = kSearching;
    ASSERT_EQ(rec.conditions[k], want) << "at t = " << core::TimeToSeconds(t) << " s";
  }
}

// The robot right above the station: the ray up to the prism passes through the robot's
// own hub, so the prism is hidden by the robot's body.
TEST(TotalStation, RobotBodyHidesThePrism) {
  World world({.world = "bridge"});
  TotalStationModel model("ts", {}, world, 5);
  const Eigen::Vector3d p_B_prism = world.robot().FindSite("prism")->p_Bs;
  const Eigen::Vector3d above = kStation_W + Eigen::Vector3d(0, 0, 2.5) -
                                Eigen::Vector3d(p_B_prism.x(), p_B_prism.y(), 0.0);
  const Recording rec = Drive(world, model, 200 * kMs, [&](double) {
    return Motion{above, Eigen::Vector3d::Zero()};
  });
  EXPECT_TRUE(rec.samples.empty());
  EXPECT_EQ(rec.conditions.back(), kOccluded | kLockLost);
}

// Many samples at a fixed pose: whitened errors L^-1 e (Sigma = L L^T, the reported
// covariance of each sample) have zero mean and identity covariance; NEES mean is 3.
// Tolerances: 4 sigma of the sample statistics for N samples.
TEST(TotalStation, NoiseMatchesTheReportedCovariance) {
  World world({.world = "bridge"});
  TotalStationOptions options;
  options.rate_hz = 1000.0;  // many samples in little time; the noise does not depend on rate
  TotalStationModel model("ts", options, world, 11);
  const Eigen::Vector3d p_WB(-4.0, 1.5, 4.5);  // off-axis: Hz, V and d all mix in x, y, z
  const int n = 20000;
  world.Reset(Waypoint{p_WB, Eigen::Quaterniond::Identity()});
  std::vector<SensorSample> samples;
  const std::array<double, kArmCount * kRotorsPerArm> thrust{};
  for (int k = 0; k < n; ++k) {
    TruthState x;
    x.t_ns = k * kStepNs;
    x.p_WB = p_WB;
    model.Step(SensorInput{x, world, thrust}, &samples);
  }
  ASSERT_EQ(static_cast<int>(samples.size()), n);

  Eigen::Vector3d mean = Eigen::Vector3d::Zero();
  Eigen::Matrix3d second = Eigen::Matrix3d::Zero();
  double nees = 0.0;
  const Eigen::Matrix3d reported_first =
      std::get<core::PositionMeasurement>(samples.front().measured).covariance;
  for (const SensorSample& s : samples) {
    const auto& m = std::get<core::PositionMeasurement>(s.measured);
    const auto& t = std::get<core::PositionMeasurement>(s.truth);
    const Eigen::LLT<Eigen::Matrix3d> llt(m.covariance);
    ASSERT_EQ(llt.info(), Eigen::Success);
    const Eigen::Vector3d z = llt.matrixL().solve(m.p_Ss - t.p_Ss);
    mean += z / n;
    second += z * z.transpose() / n;
    nees += z.squaredNorm() / n;
  }
  const double d = (Prism_W(world, p_WB) - kStation_W).norm();
  const Eigen::Vector3d sd =
      Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d>(reported_first).eigenvalues().cwiseSqrt();
  std::printf("d = %.2f m, reported std along principal axes [mm]: %.4f %.4f %.4f\n", d,
              1e3 * sd(0), 1e3 * sd(1), 1e3 * sd(2));
  std::printf("NEES mean %.4f (expected 3 +- %.4f), whitened mean %.4f %.4f %.4f\n", nees,
              4.0 * std::sqrt(6.0 / n), mean(0), mean(1), mean(2));
  std::cout << "whitened covariance:\n" << second - mean * mean.transpose() << "\n";
  EXPECT_NEAR(nees, 3.0, 4.0 * std::sqrt(6.0 / n));
  for (int i = 0; i < 3; ++i) {
    EXPECT_NEAR(mean(i), 0.0, 4.0 / std::sqrt(n));
    EXPECT_NEAR(second(i, i), 1.0, 4.0 * std::sqrt(2.0 / n));
    for (int j = 0; j < i; ++j) EXPECT_NEAR(second(i, j), 0.0, 4.0 / std::sqrt(n));
  }
  // The largest std is the distance noise a + b d (along the line of sight).
  EXPECT_NEAR(sd.maxCoeff(), options.distance_std_m + options.distance_std_ppm * 1e-6 * d, 1e-6);
}

// ---- YAML ----

harness::YamlValue SensorValue(const std::string& yaml) {
  const auto root = harness::ParseDocument(yaml, "ts.yaml");
  auto sensors = root.Map({"sensors"}).Required("sensors");
  return sensors.Map({"station"}).Required("station");
}

TEST(TotalStationYaml, ReadsEveryKeyAndRoundTrips) {
  const auto options = harness::internal::ReadSensorOptions<sim::TotalStationOptions>(SensorValue(R"yaml(sensors:
  station:
    type: total_station
    site: prism
    station_site: station_tripod
    station_position_m: [1, 2, 3]
    station_rpy_deg: [0, 0, 90]
    rate_hz: 10
    latency_s: 0.02
    horizontal_angle_std_deg: 0.0005
    vertical_angle_std_deg: 0.001
    distance_std_m: 0.001
    distance_std_ppm: 2
    max_angular_rate_degps: 20
    search_delay_s: 3
    prism_clearance_m: 0.04
)yaml"));
  EXPECT_EQ(options.site, "prism");
  ASSERT_TRUE(options.p_WS_m.has_value());
  EXPECT_TRUE(options.p_WS_m->isApprox(Eigen::Vector3d(1, 2, 3)));
  ASSERT_TRUE(options.q_WS.has_value());
  EXPECT_NEAR(options.q_WS->angularDistance(
                  Eigen::Quaterniond(Eigen::AngleAxisd(M_PI / 2, Eigen::Vector3d::UnitZ()))),
              0.0, 1e-12);
  EXPECT_EQ(options.rate_hz, 10.0);
  EXPECT_EQ(options.latency_s, 0.02);
  EXPECT_NEAR(options.horizontal_angle_std_rad, 0.0005 * M_PI / 180, 1e-18);
  EXPECT_NEAR(options.vertical_angle_std_rad, 0.001 * M_PI / 180, 1e-18);
  EXPECT_EQ(options.distance_std_m, 0.001);
  EXPECT_EQ(options.distance_std_ppm, 2.0);
  EXPECT_NEAR(options.max_angular_rate_radps, 20 * M_PI / 180, 1e-15);
  EXPECT_EQ(options.search_delay_s, 3.0);
  EXPECT_EQ(options.prism_clearance_m, 0.04);

  // Emit, read back: the same options.
  YAML::Emitter out;
  out << YAML::BeginMap << YAML::Key << "sensors" << YAML::Value << YAML::BeginMap;
  out << YAML::Key << "station" << YAML::Value << YAML::BeginMap;
  out << YAML::Key << "type" << YAML::Value << "total_station";
  harness::internal::EmitSensorOptions(out, options);
  out << YAML::EndMap << YAML::EndMap << YAML::EndMap;
  const auto again = harness::internal::ReadSensorOptions<sim::TotalStationOptions>(SensorValue(out.c_str()));
  EXPECT_EQ(again.site, options.site);
  EXPECT_TRUE(again.p_WS_m->isApprox(*options.p_WS_m, 1e-15));
  EXPECT_NEAR(again.q_WS->angularDistance(*options.q_WS), 0.0, 1e-12);
  EXPECT_EQ(again.rate_hz, options.rate_hz);
  EXPECT_NEAR(again.horizontal_angle_std_rad, options.horizontal_angle_std_rad, 1e-20);
  EXPECT_NEAR(again.max_angular_rate_radps, options.max_angular_rate_radps, 1e-15);
  EXPECT_EQ(again.search_delay_s, options.search_delay_s);

  // Defaults: an empty map keeps every default and emits no station override.
  const auto defaults = harness::internal::ReadSensorOptions<sim::TotalStationOptions>(
      SensorValue("sensors:\n  station:\n    type: total_station\n"));
  EXPECT_FALSE(defaults.p_WS_m.has_value());
  EXPECT_EQ(defaults.rate_hz, 20.0);
  EXPECT_NEAR(defaults.horizontal_angle_std_rad, kArcSecondRad, 1e-20);
}

TEST(TotalStationYaml, RejectsUnknownKeysAndOutOfRangeValues) {
  try {
    harness::internal::ReadSensorOptions<sim::TotalStationOptions>(SensorValue(
        "sensors:\n  station:\n    type: total_station\n    rate_hx: 10\n"));
    ADD_FAILURE() << "unknown key accepted";
  } catch (const core::InputError& e) {
    EXPECT_EQ(e.location().line, 4) << e.what();
    EXPECT_EQ(e.key_path(), "sensors.station.rate_hx") << e.what();
    EXPECT_NE(std::string(e.what()).find("did you mean 'rate_hz'"), std::string::npos) << e.what();
  }
  try {
    harness::internal::ReadSensorOptions<sim::TotalStationOptions>(SensorValue(
        "sensors:\n  station:\n    type: total_station\n    latency_s: 0.01\n"
        "    distance_std_m: -0.003\n"));
    ADD_FAILURE() << "negative distance noise accepted";
  } catch (const core::InputError& e) {
    EXPECT_EQ(e.location().line, 5) << e.what();
    EXPECT_EQ(e.key_path(), "sensors.station.distance_std_m") << e.what();
    EXPECT_NE(std::string(e.what()).find("ts.yaml:5:"), std::string::npos) << e.what();
  }
  try {
    harness::internal::ReadSensorOptions<sim::TotalStationOptions>(SensorValue(
        "sensors:\n  station:\n    station_position_m: [1, 2]\n"));
    ADD_FAILURE() << "two-element position accepted";
  } catch (const core::InputError& e) {
    EXPECT_EQ(e.location().line, 3) << e.what();
    EXPECT_EQ(e.key_path(), "sensors.station.station_position_m") << e.what();
  }
}

}  // namespace
}  // namespace tofu::sim
