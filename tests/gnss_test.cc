// GNSS RTK (sim::GnssModel) on the real building_window world: no fix under the roof,
// float then fixed after the time-to-fix in the open, the time-to-fix restarts after a
// loss, multipath near the building, the error statistics per fix type match the stated
// model (white + Gauss-Markov, reported covariance = the fix type's std), and the YAML
// reader is strict.

#include "sim/gnss.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <functional>
#include <string>
#include <variant>
#include <vector>

#include "core/error.h"
#include "harness/sensor_config.h"
#include "harness/yaml_reader.h"

namespace tofu::sim {
namespace {

constexpr core::Time kStepNs = 1'000'000;  // 1 kHz physics
constexpr core::Time kSecond = core::kNanosecondsPerSecond;
constexpr double kPi = 3.14159265358979323846;

const Eigen::Vector3d kIndoors(-3.0, 0.0, 1.5);   // inside the room (roof at z = 3.5)
const Eigen::Vector3d kOutdoors(20.0, 0.0, 2.0);  // open field, 20 m from the building

struct Recording {
  std::vector<SensorSample> samples;
  std::vector<uint32_t> conditions;  ///< per step
  std::vector<int> visible;          ///< per step (latest epoch)
};

// Steps the model at 1 kHz for `duration_ns`, the robot resting at position(t) (the
// world is reset only when the position changes: the rays must see the robot where the
// truth says).
Recording Drive(World& world, GnssModel& model, core::Time duration_ns,
                const std::function<Eigen::Vector3d(core::Time)>& position) {
  Recording rec;
  const std::array<double, kArmCount * kRotorsPerArm> thrust{};
  Eigen::Vector3d placed = Eigen::Vector3d::Constant(1e9);
  for (core::Time t = 0; t < duration_ns; t += kStepNs) {
    const Eigen::Vector3d p = position(t);
    if (p != placed) {
      world.Reset(Waypoint{p, Eigen::Quaterniond::Identity()});
      placed = p;
    }
    TruthState x;
    x.t_ns = t;
    x.p_WB = p;
    model.Step(SensorInput{x, world, thrust}, &rec.samples);
    rec.conditions.push_back(model.conditions());
    rec.visible.push_back(model.visible_satellites());
  }
  return rec;
}

Recording DriveStill(World& world, GnssModel& model, core::Time duration_ns,
                     const Eigen::Vector3d& p) {
  return Drive(world, model, duration_ns, [&](core::Time) { return p; });
}

WorldOptions Building() {
  WorldOptions options;
  options.world = "building_window";
  return options;
}

Eigen::Vector3d Error(const SensorSample& s) {
  return std::get<core::PositionMeasurement>(s.measured).p_Ss -
         std::get<core::PositionMeasurement>(s.truth).p_Ss;
}

TEST(Gnss, SkyLiesAboveTheMaskAndIsFixedBySeed) {
  World world(Building());
  GnssOptions options;
  GnssModel a("gnss", options, world, 42), b("gnss", options, world, 42);
  GnssModel c("gnss", options, world, 43);
  const std::vector<Eigen::Vector3d> sky_a = a.sky_directions_S();
  const std::vector<Eigen::Vector3d> sky_b = b.sky_directions_S();
  ASSERT_EQ(static_cast<int>(sky_a.size()), options.satellite_count);
  ASSERT_EQ(sky_b.size(), sky_a.size());
  for (size_t i = 0; i < sky_a.size(); ++i) {
    const Eigen::Vector3d& d = sky_a[i];
    EXPECT_NEAR(d.norm(), 1.0, 1e-12);
    EXPECT_GE(std::asin(d.z()), options.elevation_mask_rad);
    EXPECT_EQ(d, sky_b[i]);
  }
  EXPECT_NE(sky_a[0], c.sky_directions_S()[0]);

  GnssOptions bad = options;
  bad.min_satellites_fixed = 5;  // below min_satellites_float
  EXPECT_THROW(GnssModel("gnss", bad, world, 1), std::invalid_argument);
  GnssOptions bad_site = options;
  bad_site.site = "no_such_site";
  EXPECT_THROW(GnssModel("gnss", bad_site, world, 1), std::invalid_argument);
}

TEST(Gnss, NoFixIndoors) {
  World world(Building());
  GnssModel model("gnss", {}, world, 1);
  const Recording rec = DriveStill(world, model, 3 * kSecond, kIndoors);
  EXPECT_TRUE(rec.samples.empty());
  EXPECT_EQ(model.fix(), GnssFix::kNone);
  EXPECT_EQ(model.visible_satellites(), 0);
  for (const uint32_t c : rec.conditions) ASSERT_EQ(c, kNoFix);
}

// In the open the receiver starts in RTK float and reports fixed exactly time_to_fix_s
// after acquisition, with the fix type's stated covariance.
TEST(Gnss, OutdoorsFloatThenFixedAfterTimeToFix) {
  World world(Building());
  GnssOptions options;
  options.time_to_fix_s = 5.0;
  GnssModel model("gnss", options, world, 2);
  const Recording rec = DriveStill(world, model, 8 * kSecond, kOutdoors);
  std::printf("visible satellites outdoors: %d of %d\n", model.visible_satellites(),
              options.satellite_count);
  EXPECT_EQ(model.visible_satellites(), options.satellite_count);

  const core::Time period = core::PeriodFromRate(options.rate_hz);
  ASSERT_EQ(static_cast<core::Time>(rec.samples.size()), 8 * kSecond / period);
  const core::Time t_fix = core::SecondsToTime(options.time_to_fix_s);
  for (size_t i = 0; i < rec.samples.size(); ++i) {
    const SensorSample& s = rec.samples[i];
    EXPECT_EQ(s.t_ns, static_cast<core::Time>(i) * period);
    EXPECT_EQ(s.arrival_ns, s.t_ns + core::SecondsToTime(options.latency_s));
    const Eigen::Matrix3d& cov = std::get<core::PositionMeasurement>(s.measured).covariance;
    const GnssFixErrorOptions& e = s.t_ns < t_fix ? options.rtk_float : options.rtk_fixed;
    EXPECT_EQ(s.conditions, s.t_ns < t_fix ? kFloatFix : kConditionNone) << s.t_ns;
    EXPECT_TRUE(cov.isApprox(Eigen::Vector3d(e.std_horizontal_m * e.std_horizontal_m,
                                             e.std_horizontal_m * e.std_horizontal_m,
                                             e.std_vertical_m * e.std_vertical_m)
                                 .asDiagonal().toDenseMatrix()));
    EXPECT_EQ(std::get<core::PositionMeasurement>(s.truth).p_Ss,
              kOutdoors + world.robot().FindSite("gnss_antenna")->p_Bs);
  }
  EXPECT_EQ(model.fix(), GnssFix::kFixed);
  EXPECT_EQ(model.conditions(), kConditionNone);
}

// Fixed from the start, then 2 s inside the building (no fix), then out again: RTK float
// for time_to_fix_s after re-acquisition, then fixed.
TEST(Gnss, LosingTheSkyRestartsTheTimeToFix) {
  World world(Building());
  GnssOptions options;
  options.time_to_fix_s = 3.0;
  options.fixed_at_start = true;
  GnssModel model("gnss", options, world, 3);
  const core::Time in = 2 * kSecond, out = 4 * kSecond;
  const Recording rec = Drive(world, model, 9 * kSecond, [&](core::Time t) {
    return (t >= in && t < out) ? kIndoors : kOutdoors;
  });
  const core::Time t_fix = out + core::SecondsToTime(options.time_to_fix_s);
  for (size_t k = 0; k < rec.conditions.size(); ++k) {
    const core::Time t = static_cast<core::Time>(k) * kStepNs;
    uint32_t want = kConditionNone;
    if (t >= in && t < out) want = kNoFix;
    if (t >= out && t < t_fix) want = kFloatFix;
    ASSERT_EQ(rec.conditions[k], want) << "at t = " << core::TimeToSeconds(t) << " s";
  }
  for (const SensorSample& s : rec.samples) EXPECT_FALSE(s.t_ns >= in && s.t_ns < out);
}

// Many epochs with a fast-decorrelating error (tau << epoch interval): the NEES against
// the reported covariance has mean 3 (tolerance 4 sigma of the mean of N chi-square(3)).
TEST(Gnss, ReportedCovarianceMatchesTheErrorUnderOpenSky) {
  World world(Building());
  GnssOptions options;
  options.fixed_at_start = true;
  options.rtk_fixed.correlation_time_s = 0.01;  // 10 tau per epoch: independent epochs
  GnssModel model("gnss", options, world, 4);
  const Recording rec = DriveStill(world, model, 300 * kSecond, kOutdoors);
  const int n = static_cast<int>(rec.samples.size());
  ASSERT_EQ(n, 3000);
  double nees = 0.0;
  for (const SensorSample& s : rec.samples) {
    ASSERT_EQ(s.conditions, kConditionNone);
    const Eigen::Vector3d e = Error(s);
    nees += e.dot(std::get<core::PositionMeasurement>(s.measured).covariance.inverse() * e) / n;
  }
  std::printf("fixed, open sky: NEES mean %.4f (3 +- %.4f)\n", nees, 4.0 * std::sqrt(6.0 / n));
  EXPECT_NEAR(nees, 3.0, 4.0 * std::sqrt(6.0 / n));
}

// Default error model in RTK fixed over 10 minutes: per-axis RMS error ~1 cm horizontal,
// ~2 cm vertical. The Gauss-Markov half (tau = 30 s) dominates the spread of the
// estimate: var(s^2)/sigma^4 ~ 2 f^2 tau / T per axis (f = correlated fraction).
TEST(Gnss, FixedErrorIsCentimetres) {
  World world(Building());
  GnssOptions options;
  options.fixed_at_start = true;
  GnssModel model("gnss", options, world, 5);
  const double duration_s = 600.0;
  const Recording rec = DriveStill(world, model, core::SecondsToTime(duration_s), kOutdoors);
  Eigen::Vector3d ms = Eigen::Vector3d::Zero();
  for (const SensorSample& s : rec.samples) ms += Error(s).cwiseAbs2() / rec.samples.size();
  const double rms_h = std::sqrt(0.5 * (ms(0) + ms(1))), rms_v = std::sqrt(ms(2));
  const GnssFixErrorOptions& e = options.rtk_fixed;
  const double rel_var_std_1axis = std::sqrt(2.0 * e.correlated_fraction * e.correlated_fraction *
                                             e.correlation_time_s / duration_s);
  std::printf("fixed, 600 s: RMS error E/N %.4f m (stated %.3f), U %.4f m (stated %.3f); "
              "relative std of a variance estimate %.3f\n",
              rms_h, e.std_horizontal_m, rms_v, e.std_vertical_m, rel_var_std_1axis);
  EXPECT_NEAR(rms_h * rms_h / (e.std_horizontal_m * e.std_horizontal_m), 1.0,
              4.0 * rel_var_std_1axis / std::sqrt(2.0));
  EXPECT_NEAR(rms_v * rms_v / (e.std_vertical_m * e.std_vertical_m), 1.0, 4.0 * rel_var_std_1axis);
}

// The correlated part is a first-order Gauss-Markov process: with the whole variance
// correlated and tau = 1 s, the autocorrelation of the error at 1 s lag is e^-1
// (tolerance 4 / sqrt(n_eff), n_eff = T / (2 tau) per axis, three axes pooled).
TEST(Gnss, CorrelatedErrorHasTheConfiguredCorrelationTime) {
  World world(Building());
  GnssOptions options;
  options.fixed_at_start = true;
  options.rtk_fixed.correlated_fraction = 1.0;
  options.rtk_fixed.correlation_time_s = 1.0;
  options.rtk_fixed.std_vertical_m = options.rtk_fixed.std_horizontal_m;
  GnssModel model("gnss", options, world, 6);
  const double duration_s = 600.0;
  const Recording rec = DriveStill(world, model, core::SecondsToTime(duration_s), kOutdoors);
  const int lag = 10;  // 1 s at 10 Hz
  double c0 = 0.0, c1 = 0.0;
  const size_t n = rec.samples.size();
  for (size_t i = 0; i < n; ++i) {
    const Eigen::Vector3d e = Error(rec.samples[i]);
    c0 += e.squaredNorm();
    if (i + lag < n) c1 += e.dot(Error(rec.samples[i + lag]));
  }
  const double rho = (c1 / (n - lag)) / (c0 / n);
  const double n_eff = 3.0 * duration_s / (2.0 * options.rtk_fixed.correlation_time_s);
  std::printf("autocorrelation at 1 s: %.4f (e^-1 = %.4f +- %.4f)\n", rho, std::exp(-1.0),
              4.0 / std::sqrt(n_eff));
  EXPECT_NEAR(rho, std::exp(-1.0), 4.0 / std::sqrt(n_eff));
}

// Next to the building's front wall part of the sky is hidden: fewer satellites, the
// multipath label, and a true error larger than the receiver reports (multipath is
// not in the reported covariance).
TEST(Gnss, MultipathNearTheBuilding) {
  World world(Building());
  GnssOptions options;
  options.fixed_at_start = true;
  GnssModel model("gnss", options, world, 7);
  const Eigen::Vector3d near_wall(1.2, 2.5, 1.0);  // 1 m in front of the 3.75 m high wall
  const Recording rec = DriveStill(world, model, 120 * kSecond, near_wall);
  const int visible = model.visible_satellites();
  const double blocked = 1.0 - static_cast<double>(visible) / options.satellite_count;
  ASSERT_FALSE(rec.samples.empty());
  double nees = 0.0;
  for (const SensorSample& s : rec.samples) {
    EXPECT_TRUE(s.conditions & kMultipath);
    const Eigen::Vector3d e = Error(s);
    nees += e.dot(std::get<core::PositionMeasurement>(s.measured).covariance.inverse() * e) /
            rec.samples.size();
  }
  std::printf("near the wall: %d of %d visible (blocked %.2f), fix %d, conditions 0x%x, "
              "NEES mean %.2f\n",
              visible, options.satellite_count, blocked, static_cast<int>(model.fix()),
              model.conditions(), nees);
  EXPECT_GE(blocked, options.multipath_min_blocked_fraction);
  EXPECT_TRUE(model.conditions() & kMultipath);
  EXPECT_GT(nees, 3.0 * 1.5);  // true error beyond the stated std
}

TEST(Gnss, EnuFrameIsConfigurable) {
  World world(Building());
  GnssOptions options;
  options.enu_origin_W_m = Eigen::Vector3d(10.0, -5.0, 0.5);
  options.enu_yaw_rad = 30.0 * kPi / 180.0;
  GnssModel model("gnss", options, world, 8);
  const Recording rec = DriveStill(world, model, 200'000'000, kOutdoors);
  ASSERT_FALSE(rec.samples.empty());
  const Eigen::Matrix3d R_WS =
      Eigen::AngleAxisd(options.enu_yaw_rad, Eigen::Vector3d::UnitZ()).toRotationMatrix();
  EXPECT_TRUE(model.T_WS().linear().isApprox(R_WS, 1e-15));
  const Eigen::Vector3d p_Ws = kOutdoors + world.robot().FindSite("gnss_antenna")->p_Bs;
  EXPECT_TRUE(std::get<core::PositionMeasurement>(rec.samples[0].truth)
                  .p_Ss.isApprox(R_WS.transpose() * (p_Ws - options.enu_origin_W_m), 1e-12));
}

// ---- YAML ----

harness::YamlValue SensorValue(const std::string& yaml) {
  const auto root = harness::ParseDocument(yaml, "gnss.yaml");
  return root.Map({"sensors"}).Required("sensors").Map({"rtk"}).Required("rtk");
}

core::InputError ReadError(const std::string& yaml) {
  try {
    harness::internal::ReadSensorOptions<sim::GnssOptions>(SensorValue(yaml));
  } catch (const core::InputError& e) {
    return e;
  }
  ADD_FAILURE() << "expected an InputError for:\n" << yaml;
  return core::InputError({}, "", "");
}

TEST(GnssYaml, ReadsEveryKeyAndRoundTrips) {
  const GnssOptions o = harness::internal::ReadSensorOptions<sim::GnssOptions>(SensorValue(R"yaml(sensors:
  rtk:
    type: gnss
    site: gnss_antenna
    rate_hz: 5
    latency_s: 0.05
    enu_origin_m: [1, 2, 3]
    enu_yaw_deg: 90
    satellite_count: 18
    elevation_mask_deg: 15
    sky_ray_length_m: 150
    min_satellites_single: 4
    min_satellites_float: 5
    min_satellites_fixed: 9
    time_to_fix_s: 30
    fixed_at_start: true
    multipath_min_blocked_fraction: 0.2
    multipath_correlation_time_s: 3
    rtk_fixed: {std_horizontal_m: 0.015, std_vertical_m: 0.03, correlated_fraction: 0.4,
                correlation_time_s: 20, multipath_std_m: 0.05}
    rtk_float: {std_horizontal_m: 0.4}
    single: {multipath_std_m: 4}
)yaml"));
  EXPECT_EQ(o.rate_hz, 5.0);
  EXPECT_EQ(o.latency_s, 0.05);
  EXPECT_EQ(o.enu_origin_W_m, Eigen::Vector3d(1, 2, 3));
  EXPECT_NEAR(o.enu_yaw_rad, kPi / 2, 1e-15);
  EXPECT_EQ(o.satellite_count, 18);
  EXPECT_NEAR(o.elevation_mask_rad, 15 * kPi / 180, 1e-15);
  EXPECT_EQ(o.sky_ray_length_m, 150.0);
  EXPECT_EQ(o.min_satellites_float, 5);
  EXPECT_EQ(o.min_satellites_fixed, 9);
  EXPECT_EQ(o.time_to_fix_s, 30.0);
  EXPECT_TRUE(o.fixed_at_start);
  EXPECT_EQ(o.multipath_min_blocked_fraction, 0.2);
  EXPECT_EQ(o.multipath_correlation_time_s, 3.0);
  EXPECT_EQ(o.rtk_fixed.std_horizontal_m, 0.015);
  EXPECT_EQ(o.rtk_fixed.correlated_fraction, 0.4);
  EXPECT_EQ(o.rtk_fixed.multipath_std_m, 0.05);
  EXPECT_EQ(o.rtk_float.std_horizontal_m, 0.4);
  EXPECT_EQ(o.rtk_float.std_vertical_m, GnssOptions().rtk_float.std_vertical_m);  // default kept
  EXPECT_EQ(o.single.multipath_std_m, 4.0);

  YAML::Emitter out;
  out << YAML::BeginMap << YAML::Key << "sensors" << YAML::Value << YAML::BeginMap;
  out << YAML::Key << "rtk" << YAML::Value << YAML::BeginMap;
  out << YAML::Key << "type" << YAML::Value << "gnss";
  harness::internal::EmitSensorOptions(out, o);
  out << YAML::EndMap << YAML::EndMap << YAML::EndMap;
  const GnssOptions again = harness::internal::ReadSensorOptions<sim::GnssOptions>(SensorValue(out.c_str()));
  EXPECT_EQ(again.rate_hz, o.rate_hz);
  EXPECT_EQ(again.enu_origin_W_m, o.enu_origin_W_m);
  EXPECT_NEAR(again.enu_yaw_rad, o.enu_yaw_rad, 1e-15);
  EXPECT_EQ(again.satellite_count, o.satellite_count);
  EXPECT_NEAR(again.elevation_mask_rad, o.elevation_mask_rad, 1e-15);
  EXPECT_EQ(again.min_satellites_fixed, o.min_satellites_fixed);
  EXPECT_EQ(again.fixed_at_start, o.fixed_at_start);
  EXPECT_EQ(again.rtk_fixed.correlation_time_s, o.rtk_fixed.correlation_time_s);
  EXPECT_EQ(again.rtk_float.std_horizontal_m, o.rtk_float.std_horizontal_m);
  EXPECT_EQ(again.single.multipath_std_m, o.single.multipath_std_m);
}

TEST(GnssYaml, RejectsUnknownKeysAndOutOfRangeValues) {
  const core::InputError unknown =
      ReadError("sensors:\n  rtk:\n    type: gnss\n    rtk_fixed: {std_horizontal: 0.01}\n");
  EXPECT_EQ(unknown.location().line, 4) << unknown.what();
  EXPECT_EQ(unknown.key_path(), "sensors.rtk.rtk_fixed.std_horizontal") << unknown.what();
  EXPECT_NE(std::string(unknown.what()).find("did you mean 'std_horizontal_m'"),
            std::string::npos)
      << unknown.what();

  const core::InputError range =
      ReadError("sensors:\n  rtk:\n    type: gnss\n    rate_hz: 10\n    elevation_mask_deg: 95\n");
  EXPECT_EQ(range.location().line, 5) << range.what();
  EXPECT_EQ(range.key_path(), "sensors.rtk.elevation_mask_deg") << range.what();
  EXPECT_NE(std::string(range.what()).find("gnss.yaml:5:"), std::string::npos) << range.what();

  const core::InputError fraction = ReadError(
      "sensors:\n  rtk:\n    rtk_float:\n      correlated_fraction: 1.5\n");
  EXPECT_EQ(fraction.location().line, 4) << fraction.what();
  EXPECT_EQ(fraction.key_path(), "sensors.rtk.rtk_float.correlated_fraction") << fraction.what();

  const core::InputError order = ReadError(
      "sensors:\n  rtk:\n    min_satellites_float: 7\n    min_satellites_fixed: 6\n");
  EXPECT_EQ(order.location().line, 4) << order.what();
  EXPECT_EQ(order.key_path(), "sensors.rtk.min_satellites_fixed") << order.what();

  const core::InputError integer = ReadError("sensors:\n  rtk:\n    satellite_count: 20.5\n");
  EXPECT_EQ(integer.location().line, 3) << integer.what();
}

}  // namespace
}  // namespace tofu::sim
