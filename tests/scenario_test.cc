// Scenario loading: every class of bad input is an InputError naming the file, the line
// of the offending key or value, the key path and the expected form; a full scenario
// parses into the typed structs; the resolved YAML loads back to an equal scenario.

#include "harness/scenario.h"

#include <gtest/gtest.h>

#include <cmath>
#include <numbers>
#include <string>
#include <type_traits>
#include <utility>
#include <variant>
#include <vector>

#include "core/error.h"
#include "core/lie.h"
#include "harness/evaluation.h"
#include "sim/faults.h"
#include "tests/test_support.h"

namespace tofu::harness {
namespace {

using replay::ConsensusScores;
using replay::LabelEvent;
using replay::LabelInterval;
using replay::MergedLabelIntervals;
using replay::PairedLabelIntervals;
using replay::ScoreConsensusDecisions;

constexpr double kRadPerDeg = std::numbers::pi / 180.0;
constexpr char kLabel[] = "inline.yaml";

std::string DataPath(const std::string& name) {
  return std::string(TOFU_SOURCE_DIR) + "/tests/data/scenarios/" + name;
}

// A valid scenario with only the required keys; tests append or replace lines.
// Line numbers: 1 name, 2 world, 3 duration_s, 4 trajectory, 5 start, 6 segments, 7 hover.
constexpr char kMinimal[] = R"yaml(name: hover_test
world: indoor_arena
duration_s: 10
trajectory:
  start: {position_m: [0, 0, 1]}
  segments:
    - hover: {duration_s: 1}
)yaml";

// The InputError ParseScenario throws for `yaml`; fails the test if there is none.
core::InputError ParseError(const std::string& yaml) {
  try {
    ParseScenario(yaml, kLabel);
  } catch (const core::InputError& e) {
    return e;
  }
  ADD_FAILURE() << "expected an InputError for:\n" << yaml;
  return core::InputError({}, "", "");
}

// Checks file, line, key path and that what() is one line carrying all of them.
void ExpectLocated(const core::InputError& e, int line, const std::string& key_path) {
  EXPECT_EQ(e.location().file, kLabel);
  EXPECT_EQ(e.location().line, line) << e.what();
  EXPECT_GT(e.location().column, 0) << e.what();
  EXPECT_EQ(e.key_path(), key_path) << e.what();
  const std::string what = e.what();
  EXPECT_CONTAINS(what, std::string(kLabel) + ":" + std::to_string(line) + ":");
  EXPECT_CONTAINS(what, "key '" + key_path + "'");
  EXPECT_EQ(what.find('\n'), std::string::npos) << what;
}

double AngleBetween(const Eigen::Quaterniond& a, const Eigen::Quaterniond& b) {
  return a.angularDistance(b);
}

Eigen::Quaterniond FromRpyDeg(double roll, double pitch, double yaw) {
  return Eigen::Quaterniond(
      core::RotationFromRollPitchYaw(roll * kRadPerDeg, pitch * kRadPerDeg, yaw * kRadPerDeg));
}

// ---- errors, one class each ----

TEST(ScenarioLoad, RejectsUnknownKeyWithLocation) {
  const core::InputError e = ParseError(R"yaml(name: hover_test
world: indoor_arena
duraton_s: 10
trajectory:
  start: {position_m: [0, 0, 1]}
  segments:
    - hover: {duration_s: 1}
)yaml");
  ExpectLocated(e, 3, "duraton_s");
  EXPECT_CONTAINS(e.message(), "unknown key 'duraton_s'");
  EXPECT_CONTAINS(e.message(), "did you mean 'duration_s'?");
  EXPECT_CONTAINS(e.message(), "allowed keys here: name, description, world");
}

// world, robot and physics.rate_hz are fields of sim::WorldOptions, read through its table:
// an unknown key or a value outside the table's form names the file, the line, the key
// and what was expected.
TEST(ScenarioLoad, WorldFieldsAreReadThroughTheWorldOptionsTable) {
  std::string bad_world = kMinimal;
  bad_world.replace(bad_world.find("indoor_arena"), 12, "Indoor-Arena");
  const core::InputError world = ParseError(bad_world);
  ExpectLocated(world, 2, "world");
  EXPECT_CONTAINS(world.message(), "a name of lowercase letters, digits and '_' ([a-z0-9_]+)");

  const core::InputError robot = ParseError(std::string(kMinimal) + "robot: 'omav 2'\n");
  ExpectLocated(robot, 8, "robot");
  EXPECT_CONTAINS(robot.message(), "a name of lowercase letters, digits and '_' ([a-z0-9_]+)");

  const core::InputError unknown = ParseError(std::string(kMinimal) + "physics:\n  rate: 500\n");
  ExpectLocated(unknown, 9, "physics.rate");
  EXPECT_CONTAINS(unknown.message(), "unknown key 'rate'");
  EXPECT_CONTAINS(unknown.message(), "did you mean 'rate_hz'?");

  // The distance horizon is a field of the table but no scenario option.
  const core::InputError horizon =
      ParseError(std::string(kMinimal) + "physics:\n  distance_horizon_m: 2\n");
  ExpectLocated(horizon, 9, "physics.distance_horizon_m");
  EXPECT_CONTAINS(horizon.message(), "unknown key 'distance_horizon_m'");
}

TEST(ScenarioLoad, RejectsUnknownNestedKeyWithDidYouMean) {
  const core::InputError e = ParseError(R"yaml(name: circle_test
world: indoor_arena
duration_s: 10
trajectory:
  start: {position_m: [0, 0, 1]}
  segments:
    - hover: {duration_s: 1}
    - circle:
        center_m: [0, 0, 1]
        radius: 1.5
)yaml");
  ExpectLocated(e, 10, "trajectory.segments[1].circle.radius");
  EXPECT_CONTAINS(e.message(), "did you mean 'radius_m'?");
}

TEST(ScenarioLoad, RejectsUnknownSegmentKind) {
  const core::InputError e = ParseError(std::string(kMinimal) + "    - hoover: {duration_s: 1}\n");
  ExpectLocated(e, 8, "trajectory.segments[1].hoover");
  EXPECT_CONTAINS(e.message(), "did you mean 'hover'?");
}

TEST(ScenarioLoad, RejectsMissingRequiredKey) {
  const core::InputError top = ParseError(R"yaml(name: hover_test
duration_s: 10
trajectory:
  start: {position_m: [0, 0, 1]}
  segments:
    - hover: {duration_s: 1}
)yaml");
  ExpectLocated(top, 1, "world");
  EXPECT_CONTAINS(top.message(), "missing required key 'world'");

  // Nested: located at the key that opens the enclosing map.
  const core::InputError nested = ParseError(R"yaml(name: hover_test
world: indoor_arena
duration_s: 10
trajectory:
  start:
    rpy_deg: [0, 0, 90]
  segments:
    - hover: {duration_s: 1}
)yaml");
  ExpectLocated(nested, 5, "trajectory.start.position_m");
  EXPECT_CONTAINS(nested.message(), "missing required key 'position_m' in 'trajectory.start'");
}

TEST(ScenarioLoad, RejectsWrongType) {
  const core::InputError number = ParseError(R"yaml(name: hover_test
world: indoor_arena
duration_s: abc
)yaml");
  ExpectLocated(number, 3, "duration_s");
  EXPECT_CONTAINS(number.message(), "expected a number in (0, 86400] (s), got 'abc'");

  const core::InputError quoted = ParseError(R"yaml(name: hover_test
world: indoor_arena
duration_s: "10"
)yaml");
  ExpectLocated(quoted, 3, "duration_s");
  EXPECT_CONTAINS(quoted.message(), "got the quoted string '10'");

  const core::InputError map_for_list = ParseError(R"yaml(name: hover_test
world: indoor_arena
duration_s: 10
trajectory:
  start: {position_m: [0, 0, 1]}
  segments:
    hover: {duration_s: 1}
)yaml");
  ExpectLocated(map_for_list, 7, "trajectory.segments");
  EXPECT_CONTAINS(map_for_list.message(), "expected a non-empty list, got a map");

  const core::InputError bad_name = ParseError(R"yaml(name: Hover-Test
world: indoor_arena
)yaml");
  ExpectLocated(bad_name, 1, "name");
  EXPECT_CONTAINS(bad_name.message(), "[a-z0-9_]+");

  const core::InputError bad_bool = ParseError(
      std::string(kMinimal) + "    - circle: {center_m: [0, 0, 1], radius_m: 1, clockwise: yes}\n");
  ExpectLocated(bad_bool, 8, "trajectory.segments[1].circle.clockwise");
  EXPECT_CONTAINS(bad_bool.message(), "expected true or false, got 'yes'");
}

TEST(ScenarioLoad, RejectsNegativeOrFractionalSeed) {
  const core::InputError negative = ParseError(std::string(kMinimal) + "seed: -1\n");
  ExpectLocated(negative, 8, "seed");
  EXPECT_CONTAINS(negative.message(), "expected a non-negative integer");
  EXPECT_CONTAINS(negative.message(), "got '-1'");

  const core::InputError fractional = ParseError(std::string(kMinimal) + "seed: 1.5\n");
  ExpectLocated(fractional, 8, "seed");
  EXPECT_CONTAINS(fractional.message(), "got '1.5'");

  const core::InputError too_large =
      ParseError(std::string(kMinimal) + "seed: 18446744073709551616\n");
  ExpectLocated(too_large, 8, "seed");
}

TEST(ScenarioLoad, RejectsNonFiniteValue) {
  const core::InputError nan =
      ParseError(std::string(kMinimal) + "    - circle: {center_m: [0, 0, 1], radius_m: .nan}\n");
  ExpectLocated(nan, 8, "trajectory.segments[1].circle.radius_m");
  EXPECT_CONTAINS(nan.message(), "expected a finite number > 0 (m), got '.nan'");

  const core::InputError inf = ParseError(R"yaml(name: hover_test
world: indoor_arena
duration_s: 10
trajectory:
  start:
    position_m: [0, 0, -.inf]
  segments:
    - hover: {duration_s: 1}
)yaml");
  ExpectLocated(inf, 6, "trajectory.start.position_m[2]");
  EXPECT_CONTAINS(inf.message(), "got '-.inf'");

  const core::InputError overflow =
      ParseError(std::string(kMinimal) + "wind: {gust_std_mps: 1e999}\n");
  ExpectLocated(overflow, 8, "wind.gust_std_mps");
  EXPECT_CONTAINS(overflow.message(), "expected a finite number");
}

TEST(ScenarioLoad, RejectsOutOfRangeValue) {
  const core::InputError physics = ParseError(std::string(kMinimal) + "physics:\n  rate_hz: 50\n");
  ExpectLocated(physics, 9, "physics.rate_hz");
  EXPECT_CONTAINS(physics.message(), "expected a number in [100, 10000] (Hz), got '50'");

  const core::InputError zero = ParseError(R"yaml(name: hover_test
world: indoor_arena
duration_s: 0
)yaml");
  ExpectLocated(zero, 3, "duration_s");

  // Bounded by another key: the controller may not run faster than the physics.
  const core::InputError controller =
      ParseError(std::string(kMinimal) + "physics: {rate_hz: 500}\ncontroller:\n  rate_hz: 800\n");
  ExpectLocated(controller, 10, "controller.rate_hz");
  EXPECT_CONTAINS(controller.message(), "in [1, 500] (Hz, at most physics.rate_hz)");

  // A default that the given physics rate cannot carry is blamed on the physics rate.
  const core::InputError default_rate =
      ParseError(std::string(kMinimal) + "physics: {rate_hz: 150}\n");
  ExpectLocated(default_rate, 8, "physics.rate_hz");
  EXPECT_CONTAINS(default_rate.message(),
                  "expected at least the default controller.rate_hz of 200 Hz, got '150'");

  const core::InputError limit = ParseError(R"yaml(name: hover_test
world: indoor_arena
duration_s: 10
trajectory:
  start: {position_m: [0, 0, 1]}
  limits:
    max_angular_rate_degps: -45
  segments:
    - hover: {duration_s: 1}
)yaml");
  ExpectLocated(limit, 7, "trajectory.limits.max_angular_rate_degps");
  EXPECT_CONTAINS(limit.message(), "expected a number > 0 (deg/s), got '-45'");

  const core::InputError direction = ParseError(
      std::string(kMinimal) + "    - approach: {direction: [0, 0, 0], standoff_m: 0.3}\n");
  ExpectLocated(direction, 8, "trajectory.segments[1].approach.direction");
  EXPECT_CONTAINS(direction.message(), "non-zero direction");
}

TEST(ScenarioLoad, RejectsWrongVectorLength) {
  const core::InputError e = ParseError(R"yaml(name: hover_test
world: indoor_arena
duration_s: 10
trajectory:
  start:
    position_m: [0, 0]
  segments:
    - hover: {duration_s: 1}
)yaml");
  ExpectLocated(e, 6, "trajectory.start.position_m");
  EXPECT_CONTAINS(e.message(), "expected a list of 3 numbers (m), got a list of 2");

  const core::InputError gain =
      ParseError(std::string(kMinimal) + "controller:\n  velocity_gain_per_s: [1, 2, 3, 4]\n");
  ExpectLocated(gain, 9, "controller.velocity_gain_per_s");
  EXPECT_CONTAINS(gain.message(), "got a list of 4");
}

TEST(ScenarioLoad, RejectsDuplicateKey) {
  const core::InputError e = ParseError(R"yaml(name: hover_test
world: indoor_arena
duration_s: 10
trajectory:
  start: {position_m: [0, 0, 1]}
  segments:
    - hover: {duration_s: 1}
duration_s: 20
)yaml");
  ExpectLocated(e, 8, "duration_s");
  EXPECT_CONTAINS(e.message(), "duplicate key 'duration_s' (first given at line 3, column 1)");
}

TEST(ScenarioLoad, RejectsUnknownMetricInExpect) {
  const core::InputError e = ParseError(std::string(kMinimal) + R"yaml(expect:
  - metric: tracking.position_rms_m
    max: 0.05
)yaml");
  ExpectLocated(e, 9, "expect[0].metric");
  EXPECT_CONTAINS(e.message(), "unknown metric 'tracking.position_rms_m'");
  EXPECT_CONTAINS(e.message(), "did you mean 'tracking.position_rmse_m'?");
}

TEST(ScenarioLoad, RejectsWindowOnNonWindowableMetric) {
  const core::InputError e = ParseError(std::string(kMinimal) + R"yaml(expect:
  - metric: tracking.position_rmse_m
    max: 0.05
  - metric: collisions.count
    max: 0
    window_s: [0, 5]
)yaml");
  ExpectLocated(e, 13, "expect[1].window_s");
  EXPECT_CONTAINS(e.message(), "'collisions.count' cannot be restricted to a time window");
}

TEST(ScenarioLoad, RejectsInvalidExpectationBounds) {
  const core::InputError no_bound = ParseError(std::string(kMinimal) + R"yaml(expect:
  - metric: collisions.count
)yaml");
  ExpectLocated(no_bound, 9, "expect[0]");
  EXPECT_CONTAINS(no_bound.message(), "at least one of 'min' and 'max'");

  const core::InputError inverted = ParseError(std::string(kMinimal) + R"yaml(expect:
  - metric: tracking.position_rmse_m
    min: 0.5
    max: 0.1
)yaml");
  ExpectLocated(inverted, 11, "expect[0].max");

  const core::InputError window = ParseError(std::string(kMinimal) + R"yaml(expect:
  - metric: tracking.position_rmse_m
    max: 0.1
    window_s: [5, 2]
)yaml");
  ExpectLocated(window, 11, "expect[0].window_s");
  EXPECT_CONTAINS(window.message(), "from < to");
}

TEST(ScenarioLoad, RejectsYamlSyntaxError) {
  const core::InputError e = ParseError(R"yaml(name: hover_test
world: indoor_arena
duration_s: 10
trajectory:
  start: {position_m: [0, 0, 1}
  segments:
    - hover: {duration_s: 1}
)yaml");
  EXPECT_EQ(e.location().file, kLabel);
  EXPECT_EQ(e.location().line, 5) << e.what();
  EXPECT_CONTAINS(std::string(e.what()), "inline.yaml:5:");
  EXPECT_CONTAINS(e.message(), "YAML syntax error");
}

TEST(ScenarioLoad, RejectsEmptyDocumentAndNonMapRoot) {
  const core::InputError empty = ParseError("# nothing but a comment\n");
  EXPECT_CONTAINS(std::string(empty.what()), "inline.yaml");
  EXPECT_CONTAINS(empty.message(), "empty");

  const core::InputError list = ParseError("- name: a\n- world: b\n");
  EXPECT_EQ(list.location().line, 1);
  EXPECT_CONTAINS(list.message(), "expected a map of scenario keys");

  const core::InputError two_documents = ParseError(std::string(kMinimal) + "---\nname: x\n");
  EXPECT_EQ(two_documents.location().line, 9);
  EXPECT_CONTAINS(two_documents.message(), "single YAML document");
}

// Issue 19, finding 10: a scenario "file" that never ends (/dev/zero) or is far larger than
// any configuration is refused at the size limit instead of read until memory runs out.
TEST(ScenarioLoad, RefusesAFileOverTheSizeLimitWithoutReadingItAll) {
  try {
    LoadScenario("/dev/zero");
    FAIL() << "expected an InputError";
  } catch (const core::InputError& e) {
    EXPECT_EQ(e.location().file, "/dev/zero");
    EXPECT_CONTAINS(e.message(), "larger than the limit of 16777216 bytes");
  }
}

TEST(ScenarioLoad, RejectsMissingFile) {
  const std::string path = DataPath("does_not_exist.yaml");
  try {
    LoadScenario(path);
    FAIL() << "expected an InputError";
  } catch (const core::InputError& e) {
    EXPECT_EQ(e.location().file, path);
    EXPECT_CONTAINS(std::string(e.what()), path);
    EXPECT_CONTAINS(e.message(), "cannot read scenario file");
  }
}

TEST(ScenarioLoad, RejectsSegmentWithTwoKeys) {
  const core::InputError e = ParseError(R"yaml(name: hover_test
world: indoor_arena
duration_s: 10
trajectory:
  start: {position_m: [0, 0, 1]}
  segments:
    - hover: {duration_s: 1}
    - hover: {duration_s: 2}
      line: {to_m: [1, 0, 1]}
)yaml");
  ExpectLocated(e, 9, "trajectory.segments[1]");
  EXPECT_CONTAINS(e.message(), "exactly one key naming its primitive, got 2 ('hover', 'line')");
}

TEST(ScenarioLoad, ReportsFileAndLineThroughLoadScenario) {
  const std::string path = DataPath("invalid_circle_radius.yaml");
  try {
    LoadScenario(path);
    FAIL() << "expected an InputError";
  } catch (const core::InputError& e) {
    EXPECT_EQ(e.location().file, path);
    EXPECT_EQ(e.location().line, 9);
    EXPECT_EQ(e.key_path(), "trajectory.segments[1].circle.radius_m");
    EXPECT_CONTAINS(std::string(e.what()), path + ":9:");
    EXPECT_CONTAINS(e.message(), "expected a number > 0 (m), got '-1.5'");
  }
}

// ---- typed values ----

TEST(ScenarioLoad, ParsesFullExample) {
  const Scenario s = LoadScenario(DataPath("figure_eight_arena.yaml"));
  EXPECT_EQ(s.name, "figure_eight_arena");
  EXPECT_EQ(s.description, "Figure-eight at 1 m/s in the indoor arena");
  EXPECT_EQ(s.source_file, DataPath("figure_eight_arena.yaml"));
  EXPECT_EQ(s.world, "indoor_arena");
  EXPECT_EQ(s.robot, "omav");
  EXPECT_EQ(s.duration_s, 30.0);
  EXPECT_EQ(s.seed, 7u);
  EXPECT_EQ(s.physics.rate_hz, 1000.0);
  EXPECT_EQ(s.controller.rate_hz, 200.0);
  EXPECT_EQ(s.controller.position_gain_per_s2, Eigen::Vector3d(16, 16, 20));
  // A scalar gain means all three axes.
  EXPECT_EQ(s.controller.position_integral_gain_per_s3, Eigen::Vector3d::Constant(5.0));
  EXPECT_EQ(s.wind.mean_velocity_W_mps, Eigen::Vector3d(0.5, 0, 0));
  EXPECT_EQ(s.wind.gust_std_mps, 0.3);
  EXPECT_EQ(s.output.groundtruth_rate_hz, 200.0);

  const sim::TrajectorySpec& t = s.trajectory;
  EXPECT_EQ(t.start.p_WB, Eigen::Vector3d(0, 0, 1));
  EXPECT_LT(AngleBetween(t.start.q_WB, Eigen::Quaterniond::Identity()), 1e-15);
  // Degrees in YAML, radians in the struct.
  EXPECT_NEAR(t.limits.max_angular_rate_radps, std::numbers::pi / 4.0, 1e-15);
  EXPECT_NEAR(t.limits.max_angular_acceleration_radps2, std::numbers::pi / 2.0, 1e-15);
  EXPECT_EQ(t.limits.max_speed_mps, 1.0);

  ASSERT_EQ(t.segments.size(), 6u);
  EXPECT_EQ(std::get<sim::HoverSpec>(t.segments[0]).duration_s, 2.0);
  const auto& line = std::get<sim::LineSpec>(t.segments[1]);
  EXPECT_EQ(line.to_W, Eigen::Vector3d(1, 0, 1));
  ASSERT_TRUE(line.q_WB.has_value());
  // yaw 90 deg: q = (cos 45, 0, 0, sin 45).
  EXPECT_NEAR(line.q_WB->w(), std::sqrt(0.5), 1e-15);
  EXPECT_NEAR(line.q_WB->z(), std::sqrt(0.5), 1e-15);
  EXPECT_NEAR(line.q_WB->x(), 0.0, 1e-15);
  EXPECT_NEAR(line.q_WB->y(), 0.0, 1e-15);
  const auto& waypoints = std::get<sim::WaypointsSpec>(t.segments[2]);
  ASSERT_EQ(waypoints.waypoints.size(), 2u);
  EXPECT_EQ(waypoints.waypoints[1].p_WB, Eigen::Vector3d(2, 0, 1.5));
  // No rpy_deg: keeps the previous waypoint's attitude (identity here).
  EXPECT_LT(AngleBetween(waypoints.waypoints[1].q_WB, Eigen::Quaterniond::Identity()), 1e-15);
  const auto& circle = std::get<sim::CircleSpec>(t.segments[3]);
  EXPECT_EQ(circle.radius_m, 1.5);
  EXPECT_EQ(circle.laps, 2.0);
  EXPECT_FALSE(circle.clockwise);
  const auto& figure = std::get<sim::FigureEightSpec>(t.segments[4]);
  EXPECT_EQ(figure.half_length_m, 2.0);
  EXPECT_EQ(figure.half_width_m, 1.0);
  const auto& approach = std::get<sim::ApproachSpec>(t.segments[5]);
  EXPECT_EQ(approach.direction_W, Eigen::Vector3d::UnitX());
  EXPECT_EQ(approach.standoff_m, 0.3);

  ASSERT_EQ(s.expect.size(), 2u);
  EXPECT_EQ(s.expect[0].metric, "tracking.position_rmse_m");
  EXPECT_FALSE(s.expect[0].min.has_value());
  EXPECT_EQ(s.expect[0].max, 0.05);
  EXPECT_EQ(s.expect[0].location.line, 47);
  ASSERT_TRUE(s.expect[1].window_s.has_value());
  EXPECT_EQ(*s.expect[1].window_s, std::make_pair(2.0, 10.0));
}

TEST(ScenarioLoad, KeepsStructDefaultsForOmittedKeys) {
  const Scenario s = ParseScenario(kMinimal, kLabel);
  const sim::ControllerOptions controller;
  const sim::WindOptions wind;
  const sim::DynamicLimits limits;
  EXPECT_EQ(s.robot, "omav");
  EXPECT_EQ(s.seed, 0u);
  EXPECT_EQ(s.physics.rate_hz, PhysicsOptions().rate_hz);
  EXPECT_EQ(s.controller.rate_hz, controller.rate_hz);
  EXPECT_EQ(s.controller.attitude_gain_per_s2, controller.attitude_gain_per_s2);
  EXPECT_EQ(s.wind.drag_area_m2, wind.drag_area_m2);
  EXPECT_EQ(s.output.groundtruth_rate_hz, OutputOptions().groundtruth_rate_hz);
  EXPECT_EQ(s.trajectory.limits.max_angular_rate_radps, limits.max_angular_rate_radps);
  EXPECT_TRUE(s.expect.empty());
}

TEST(ScenarioLoad, WaypointWithoutRpyKeepsPreviousAttitude) {
  const Scenario s = ParseScenario(
      std::string(kMinimal) + R"yaml(    - line: {to_m: [1, 0, 1], rpy_deg: [10, 20, 30]}
    - approach: {direction: [0, 3, 4], standoff_m: 0.5}
    - waypoints:
        - {position_m: [1, 1, 1]}
)yaml",
      kLabel);
  const auto& waypoints = std::get<sim::WaypointsSpec>(s.trajectory.segments[3]);
  EXPECT_LT(AngleBetween(waypoints.waypoints[0].q_WB, FromRpyDeg(10, 20, 30)), 1e-15);
  const auto& approach = std::get<sim::ApproachSpec>(s.trajectory.segments[2]);
  EXPECT_NEAR((approach.direction_W - Eigen::Vector3d(0, 0.6, 0.8)).norm(), 0.0, 1e-15);
  EXPECT_EQ(approach.speed_mps, sim::ApproachSpec().speed_mps);
}

// ---- resolved YAML ----

void ExpectVectorNear(const Eigen::Vector3d& a, const Eigen::Vector3d& b, double tol) {
  EXPECT_LE((a - b).cwiseAbs().maxCoeff(), tol) << a.transpose() << " vs " << b.transpose();
}

// Equal up to 1e-12 where degrees or normalisation are involved, exactly elsewhere.
void ExpectScenariosEqual(const Scenario& a, const Scenario& b) {
  constexpr double kTol = 1e-12;
  EXPECT_EQ(a.name, b.name);
  EXPECT_EQ(a.description, b.description);
  EXPECT_EQ(a.world, b.world);
  EXPECT_EQ(a.robot, b.robot);
  EXPECT_EQ(a.duration_s, b.duration_s);
  EXPECT_EQ(a.seed, b.seed);
  EXPECT_EQ(a.physics.rate_hz, b.physics.rate_hz);

  EXPECT_EQ(a.controller.rate_hz, b.controller.rate_hz);
  EXPECT_EQ(a.controller.position_gain_per_s2, b.controller.position_gain_per_s2);
  EXPECT_EQ(a.controller.velocity_gain_per_s, b.controller.velocity_gain_per_s);
  EXPECT_EQ(a.controller.position_integral_gain_per_s3, b.controller.position_integral_gain_per_s3);
  EXPECT_EQ(a.controller.integral_limit_mps2, b.controller.integral_limit_mps2);
  EXPECT_EQ(a.controller.attitude_gain_per_s2, b.controller.attitude_gain_per_s2);
  EXPECT_EQ(a.controller.angular_rate_gain_per_s, b.controller.angular_rate_gain_per_s);
  EXPECT_EQ(a.controller.attitude_integral_gain_per_s3, b.controller.attitude_integral_gain_per_s3);
  EXPECT_EQ(a.controller.attitude_integral_limit_radps2,
            b.controller.attitude_integral_limit_radps2);

  EXPECT_EQ(a.wind.mean_velocity_W_mps, b.wind.mean_velocity_W_mps);
  EXPECT_EQ(a.wind.gust_std_mps, b.wind.gust_std_mps);
  EXPECT_EQ(a.wind.gust_correlation_time_s, b.wind.gust_correlation_time_s);
  EXPECT_EQ(a.wind.drag_area_m2, b.wind.drag_area_m2);
  EXPECT_EQ(a.wind.air_density_kgpm3, b.wind.air_density_kgpm3);
  EXPECT_EQ(a.output.groundtruth_rate_hz, b.output.groundtruth_rate_hz);
  EXPECT_EQ(a.initial_offset.position_W_m, b.initial_offset.position_W_m);
  EXPECT_LT(AngleBetween(a.initial_offset.q_offset, b.initial_offset.q_offset), kTol);

  const sim::TrajectorySpec& ta = a.trajectory;
  const sim::TrajectorySpec& tb = b.trajectory;
  EXPECT_EQ(ta.start.p_WB, tb.start.p_WB);
  EXPECT_LT(AngleBetween(ta.start.q_WB, tb.start.q_WB), kTol);
  EXPECT_EQ(ta.limits.max_speed_mps, tb.limits.max_speed_mps);
  EXPECT_EQ(ta.limits.max_acceleration_mps2, tb.limits.max_acceleration_mps2);
  EXPECT_NEAR(ta.limits.max_angular_rate_radps, tb.limits.max_angular_rate_radps, kTol);
  EXPECT_NEAR(ta.limits.max_angular_acceleration_radps2, tb.limits.max_angular_acceleration_radps2,
              kTol);
  ASSERT_EQ(ta.segments.size(), tb.segments.size());
  for (size_t i = 0; i < ta.segments.size(); ++i) {
    SCOPED_TRACE("segment " + std::to_string(i));
    ASSERT_EQ(ta.segments[i].index(), tb.segments[i].index());
    std::visit(
        [&](const auto& sa) {
          using T = std::decay_t<decltype(sa)>;
          const T& sb = std::get<T>(tb.segments[i]);
          if constexpr (std::is_same_v<T, sim::HoverSpec>) {
            EXPECT_EQ(sa.duration_s, sb.duration_s);
          } else if constexpr (std::is_same_v<T, sim::LineSpec>) {
            EXPECT_EQ(sa.to_W, sb.to_W);
            ASSERT_EQ(sa.q_WB.has_value(), sb.q_WB.has_value());
            if (sa.q_WB) {
              EXPECT_LT(AngleBetween(*sa.q_WB, *sb.q_WB), kTol);
            }
          } else if constexpr (std::is_same_v<T, sim::WaypointsSpec>) {
            ASSERT_EQ(sa.waypoints.size(), sb.waypoints.size());
            for (size_t k = 0; k < sa.waypoints.size(); ++k) {
              EXPECT_EQ(sa.waypoints[k].p_WB, sb.waypoints[k].p_WB);
              EXPECT_LT(AngleBetween(sa.waypoints[k].q_WB, sb.waypoints[k].q_WB), kTol);
            }
          } else if constexpr (std::is_same_v<T, sim::CircleSpec>) {
            EXPECT_EQ(sa.center_W, sb.center_W);
            EXPECT_EQ(sa.radius_m, sb.radius_m);
            EXPECT_EQ(sa.speed_mps, sb.speed_mps);
            EXPECT_EQ(sa.laps, sb.laps);
            EXPECT_EQ(sa.clockwise, sb.clockwise);
          } else if constexpr (std::is_same_v<T, sim::FigureEightSpec>) {
            EXPECT_EQ(sa.center_W, sb.center_W);
            EXPECT_EQ(sa.half_length_m, sb.half_length_m);
            EXPECT_EQ(sa.half_width_m, sb.half_width_m);
            EXPECT_EQ(sa.speed_mps, sb.speed_mps);
            EXPECT_EQ(sa.laps, sb.laps);
          } else {
            ExpectVectorNear(sa.direction_W, sb.direction_W, kTol);
            EXPECT_EQ(sa.standoff_m, sb.standoff_m);
            EXPECT_EQ(sa.speed_mps, sb.speed_mps);
          }
        },
        ta.segments[i]);
  }

  ASSERT_EQ(a.expect.size(), b.expect.size());
  for (size_t i = 0; i < a.expect.size(); ++i) {
    EXPECT_EQ(a.expect[i].metric, b.expect[i].metric);
    EXPECT_EQ(a.expect[i].min, b.expect[i].min);
    EXPECT_EQ(a.expect[i].max, b.expect[i].max);
    EXPECT_EQ(a.expect[i].window_s, b.expect[i].window_s);
  }
}

TEST(ScenarioResolvedYaml, RoundTripsFullExample) {
  const Scenario original = LoadScenario(DataPath("figure_eight_arena.yaml"));
  const std::string text = ResolvedScenarioYaml(original);
  const Scenario reloaded = ParseScenario(text, "resolved.yaml");
  ExpectScenariosEqual(original, reloaded);
  // Deterministic text.
  EXPECT_EQ(text, ResolvedScenarioYaml(reloaded));
}

TEST(ScenarioResolvedYaml, FillsDefaultsInDegrees) {
  const Scenario original = ParseScenario(kMinimal, kLabel);
  const std::string text = ResolvedScenarioYaml(original);
  EXPECT_CONTAINS(text, "seed: 0\n");
  EXPECT_CONTAINS(text, "robot: omav\n");
  EXPECT_CONTAINS(text, "position_gain_per_s2: [16, 16, 20]\n");
  EXPECT_CONTAINS(text, "max_angular_rate_degps: ");
  EXPECT_CONTAINS(text, "rpy_deg: [0, 0, 0]");
  // Radians only where the key says so (one key in the controller).
  EXPECT_EQ(text.find("radps"), text.rfind("radps"));
  ExpectScenariosEqual(original, ParseScenario(text, "resolved.yaml"));
}

TEST(ScenarioResolvedYaml, RoundTripsAwkwardNumbersAndAttitudes) {
  const std::string yaml = R"yaml(name: awkward
description: "colon: and # hash, 'quotes'"
world: w
duration_s: 0.1
seed: 18446744073709551615
wind: {gust_std_mps: 3.3333333333333335e-07, mean_velocity_mps: [-0.1, 1e+20, 2.2250738585072014e-308]}
trajectory:
  start: {position_m: [0.30000000000000004, -0, 1], rpy_deg: [-179.9, 89.99999, 12.345]}
  limits: {max_angular_rate_degps: 33.3, max_angular_acceleration_degps2: 1e-3}
  segments:
    - waypoints:
        - {position_m: [1, 1, 1], rpy_deg: [0, 90, 0]}
        - {position_m: [1, 2, 1], rpy_deg: [45, -90, 10]}
        - {position_m: [1, 3, 1], rpy_deg: [180, 0, -180]}
        - {position_m: [1, 4, 1], rpy_deg: [720, 400, -1000]}
    - line: {to_m: [0.1, 0.2, 0.3]}
    - approach: {direction: [1, 1, 1], standoff_m: 0}
expect:
  - metric: structure.min_distance_m
    min: -0.1
)yaml";
  const Scenario original = ParseScenario(yaml, kLabel);
  const Scenario reloaded = ParseScenario(ResolvedScenarioYaml(original), "resolved.yaml");
  ExpectScenariosEqual(original, reloaded);
}

TEST(ScenarioRender, RenderKeyIsReadValidatedAndResolved) {
  const Scenario s = ParseScenario(std::string(kMinimal) +
                                       "render: {when: always, size: [320, 240], camera: overview}\n",
                                   kLabel);
  ASSERT_TRUE(s.render.has_value());
  EXPECT_TRUE(s.render->always);
  EXPECT_EQ(s.render->width_px, 320);
  EXPECT_EQ(s.render->camera, "overview");
  EXPECT_EQ(ParseScenario(ResolvedScenarioYaml(s), kLabel).render->height_px, 240);
  ExpectLocated(ParseError(std::string(kMinimal) + "render: {when: sometimes}\n"), 8, "render.when");
  ExpectLocated(ParseError(std::string(kMinimal) + "render: {size: [320.5, 240]}\n"), 8, "render.size");
  ExpectLocated(ParseError(std::string(kMinimal) + "render: {fps: 0}\n"), 8, "render.fps");
}

// ---- what needs the models but not the simulation (issue 19, finding 8) ----

TEST(ScenarioModels, AValidScenarioPassesAndMissingModelsAreNamedAtTheirKey) {
  EXPECT_NO_THROW(CheckScenarioModels(ParseScenario(kMinimal, kLabel)));
  const auto error = [](const std::string& yaml) {
    try {
      CheckScenarioModels(ParseScenario(yaml, kLabel));
    } catch (const core::InputError& e) {
      return e;
    }
    ADD_FAILURE() << "expected an InputError for:\n" << yaml;
    return core::InputError({}, "", "");
  };
  std::string no_world = kMinimal;
  no_world.replace(no_world.find("indoor_arena"), 12, "atlantis");
  core::InputError e = error(no_world);
  ExpectLocated(e, 2, "world");
  EXPECT_CONTAINS(e.what(), "atlantis.xml");
  EXPECT_CONTAINS(e.what(), "available: bridge");
  ExpectLocated(error(std::string(kMinimal) + "robot: nobody\n"), 8, "robot");
  ExpectLocated(error(std::string(kMinimal) + "sensors:\n  leica: {type: total_station, site: nowhere}\n"),
                9, "sensors.leica");
  ExpectLocated(error(std::string(kMinimal) + "render: {camera: nocam}\n"), 8, "render.camera");
}

TEST(ScenarioModels, AnEstimationBlockWithoutAnImuIsRejectedAtParse) {
  const core::InputError e = ParseError(std::string(kMinimal) +
                                        "sensors:\n  vio: {}\n  lio: {type: lidar_odometry}\n"
                                        "estimation:\n  methods: [consensus, naive]\n");
  ExpectLocated(e, 11, "estimation");
  EXPECT_CONTAINS(e.what(), "needs an IMU");
  EXPECT_CONTAINS(e.what(), "vio, lio");
}

// `position_factors` takes each of its three kinds, keeps it through the resolved YAML,
// and names the three when given another.
TEST(ScenarioLoad, PositionFactorsAreReadResolvedAndABadKindIsNamed) {
  const std::string base = std::string(kMinimal) +
                           "sensors:\n  imu: {}\n  leica: {type: total_station}\n"
                           "estimation:\n  methods: [consensus]\n  position_factors: ";
  const std::pair<const char*, estimator::PositionFactors> kinds[] = {
      {"between", estimator::PositionFactors::kBetween},
      {"absolute", estimator::PositionFactors::kAbsolute},
      {"offset", estimator::PositionFactors::kOffset}};
  for (const auto& [name, kind] : kinds) {
    const Scenario scenario = ParseScenario(base + name + "\n", kLabel);
    ASSERT_TRUE(scenario.estimation.has_value()) << name;
    EXPECT_EQ(scenario.estimation->position_factors, kind) << name;
    const Scenario reloaded = ParseScenario(ResolvedScenarioYaml(scenario), "resolved.yaml");
    EXPECT_EQ(reloaded.estimation->position_factors, kind) << name;
  }
  const core::InputError e = ParseError(base + "relative\n");
  ExpectLocated(e, 13, "estimation.position_factors");
  EXPECT_CONTAINS(e.what(), "between, absolute or offset");
}

// ---- faults scored as intervals per sensor and kind (issue 19, finding 4) ----

// Two overlapping divergence faults on the VIO, 8-14 s and 10-16 s. Before, the scoring
// paired the first start with the first end and dropped the second fault: one fault 8-14
// s, and the exclusion 14-16 s, while the VIO was still diverging (its samples labelled
// so), counted as a false exclusion.
TEST(FaultScoring, OverlappingFaultsOfOneKindOnOneSensorAreScoredAsOneInterval) {
  std::string twenty_seconds = kMinimal;
  twenty_seconds.replace(twenty_seconds.find("duration_s: 10"), 14, "duration_s: 20");
  const Scenario scenario = ParseScenario(twenty_seconds + R"yaml(sensors:
  imu: {}
  vio: {}
  lio: {type: lidar_odometry}
faults:
  - {sensor: vio, kind: divergence, start_s: 8, end_s: 14, axis: [0, 1, 0]}
  - {sensor: vio, kind: divergence, start_s: 10, end_s: 16, axis: [1, 0, 0]}
estimation:
  methods: [consensus]
)yaml", kLabel);
  const core::Time end_ns = core::SecondsToTime(scenario.duration_s);
  // The labels a run records (Simulate: sim::FaultLabels).
  std::vector<LabelEvent> labels;
  for (const sim::FaultLabel& l : sim::FaultLabels(scenario.faults, end_ns)) {
    labels.push_back({l.t_ns, l.sensor, l.fault, "fault", l.active});
  }
  const core::Time s = core::kNanosecondsPerSecond;

  const std::vector<LabelInterval> merged = MergedLabelIntervals(labels, end_ns);
  ASSERT_EQ(merged.size(), 1u);
  EXPECT_EQ(merged[0].sensor, "vio");
  EXPECT_EQ(merged[0].label, "divergence");
  EXPECT_EQ(merged[0].start_ns, 8 * s);
  EXPECT_EQ(merged[0].end_ns, 16 * s);
  EXPECT_FALSE(merged[0].open);
  // The corpus's event table keeps one row per fault: the same transitions paired.
  const std::vector<LabelInterval> paired = PairedLabelIntervals(labels, end_ns);
  ASSERT_EQ(paired.size(), 2u);
  EXPECT_EQ(std::make_pair(paired[0].start_ns, paired[0].end_ns), std::make_pair(8 * s, 14 * s));
  EXPECT_EQ(std::make_pair(paired[1].start_ns, paired[1].end_ns), std::make_pair(10 * s, 16 * s));

  // Consensus decisions at 10 Hz that exclude the VIO from 8.4 s until the fault ends.
  std::vector<estimator::ConsensusRecord> decisions;
  for (core::Time t = 0; t < end_ns; t += s / 10) {
    estimator::ConsensusRecord rec;
    rec.t_ns = t;
    rec.decision.t_ns = t;
    const bool excluded = t >= 8 * s + 4 * s / 10 && t < 16 * s;
    rec.decision.fused = excluded ? std::vector<std::string>{"lio"}
                                  : std::vector<std::string>{"vio", "lio"};
    if (excluded) rec.decision.excluded = {"vio"};
    decisions.push_back(rec);
  }
  const ConsensusScores scores = ScoreConsensusDecisions(decisions, labels, end_ns, {"vio", "lio"});
  ASSERT_EQ(scores.detections.size(), 1u);
  const FaultDetection& d = scores.detections[0];
  EXPECT_EQ(d.sensor, "vio");
  EXPECT_EQ(d.fault, "divergence");
  EXPECT_EQ(d.onset_ns, 8 * s);
  EXPECT_EQ(d.end_ns, 16 * s);
  ASSERT_TRUE(d.delay_s().has_value());
  EXPECT_NEAR(*d.delay_s(), 0.4, 1e-9);
  EXPECT_EQ(scores.false_exclusion_s.at("vio"), 0.0) << "the exclusion 14-16 s is not false";
  EXPECT_EQ(scores.false_exclusion_s.at("lio"), 0.0);
  EXPECT_EQ(scores.switches, 2);
}

}  // namespace
}  // namespace tofu::harness
