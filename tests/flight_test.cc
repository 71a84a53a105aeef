// Closed-loop flights through the harness without files: LoadScenario -> Simulate ->
// Evaluate. Hover (level and tilted) holds pose, the figure-eight is tracked at its
// requested speed, an approach stops the tool at its standoff, flying into a wall is
// recorded as a named collision that fails the run, and the seed alone decides the
// random disturbances.

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <numbers>
#include <set>
#include <string>
#include <variant>

#include "core/lie.h"
#include "harness/evaluation.h"
#include "harness/run.h"
#include "harness/scenario.h"
#include "sim/trajectory.h"

namespace tofu::harness {
namespace {

constexpr double kRadPerDeg = std::numbers::pi / 180.0;
using Window = std::optional<std::pair<double, double>>;

Scenario Load(const std::string& relative_path) {
  return LoadScenario(std::string(TOFU_SOURCE_DIR) + "/" + relative_path);
}

double Metric(const RunRecord& record, const std::string& name, Window window = std::nullopt) {
  const std::optional<double> value = MetricValue(record, name, window);
  EXPECT_TRUE(value.has_value()) << name;
  return value.value_or(std::nan(""));
}

// Largest distance of the true position from `p` and of the true attitude from `q` over
// ground-truth samples at t >= from_s (independent of the tracking bookkeeping).
std::pair<double, double> MaxHoverErrors(const RunRecord& record, const sim::Waypoint& pose,
                                         double from_s) {
  double position = 0.0, attitude = 0.0;
  int count = 0;
  for (const sim::TruthState& s : record.groundtruth) {
    if (core::TimeToSeconds(s.t_ns) < from_s) continue;
    position = std::max(position, (s.p_WB - pose.p_WB).norm());
    attitude = std::max(attitude, s.q_WB.angularDistance(pose.q_WB));
    ++count;
  }
  EXPECT_GT(count, 100);
  return {position, attitude};
}

void ExpectHoverHolds(const Scenario& scenario, const RunRecord& record) {
  ASSERT_FALSE(record.failure.has_value()) << *record.failure;
  EXPECT_EQ(record.physics_steps, std::llround(scenario.duration_s * scenario.physics.rate_hz));
  const Window settled{{2.0, scenario.duration_s}};
  EXPECT_LT(Metric(record, "tracking.position_max_m", settled), 0.01);
  EXPECT_LT(Metric(record, "tracking.attitude_max_deg", settled), 0.5);
  const auto [position, attitude] = MaxHoverErrors(record, scenario.trajectory.start, 2.0);
  EXPECT_LT(position, 0.01);
  EXPECT_LT(attitude, 0.5 * kRadPerDeg);
  // The run really started off the reference (the initial offset), so settling happened.
  const sim::TruthState& first = record.groundtruth.front();
  EXPECT_GT((first.p_WB - scenario.trajectory.start.p_WB).norm(), 0.05);
  EXPECT_TRUE(record.collisions.empty());
  const Evaluation evaluation = Evaluate(record);
  EXPECT_TRUE(evaluation.passed) << evaluation.summary.dump(2);
}

// ---- hover ----

TEST(FlightHover, LevelHoverHoldsPositionAndAttitude) {
  const Scenario scenario = Load("scenarios/hover_arena.yaml");
  const RunRecord record = Simulate(scenario);
  ExpectHoverHolds(scenario, record);
}

TEST(FlightHover, EachSimulatedMinuteRecordsItsWallTimeAndResidentSet) {
  // timing.json's per-minute figures (the soak benchmark reads them): one mark at the end
  // of each whole simulated minute, wall times increasing, a resident set read.
  Scenario scenario = Load("scenarios/hover_arena.yaml");
  scenario.duration_s = 150.0;  // the trajectory holds its last hover to the end
  const RunRecord record = Simulate(scenario);
  ASSERT_FALSE(record.failure.has_value()) << *record.failure;
  ASSERT_EQ(record.minutes.size(), 2u);
  EXPECT_GT(record.minutes[0].wall_time_s, 0.0);
  EXPECT_GT(record.minutes[1].wall_time_s, record.minutes[0].wall_time_s);
  EXPECT_LE(record.minutes[1].wall_time_s, record.wall_time_s);
  EXPECT_GT(record.minutes[0].resident_mb, 1.0);
}

TEST(FlightHover, TiltedHoverHoldsThirtyDegreesOfRoll) {
  const Scenario scenario = Load("scenarios/hover_tilted_arena.yaml");
  const RunRecord record = Simulate(scenario);
  ExpectHoverHolds(scenario, record);
  // The body itself is rolled 30 deg: its z axis leans 30 deg from vertical towards -y
  // (roll about x), and it stays there; the arms tilt to keep the thrust vertical.
  for (const sim::TruthState& s : record.groundtruth) {
    if (core::TimeToSeconds(s.t_ns) < 2.0) continue;
    const Eigen::Vector3d z_B_W = s.q_WB * Eigen::Vector3d::UnitZ();
    ASSERT_NEAR(std::acos(z_B_W.z()), 30.0 * kRadPerDeg, 0.5 * kRadPerDeg);
    ASSERT_LT(z_B_W.y(), -0.45);
    const Eigen::Vector3d x_B_W = s.q_WB * Eigen::Vector3d::UnitX();
    ASSERT_NEAR(x_B_W.x(), 1.0, 1e-3);
  }
  const sim::TruthState& last = record.groundtruth.back();
  double max_tilt = 0.0;
  for (const double tilt : last.tilt_rad) max_tilt = std::max(max_tilt, std::abs(tilt));
  EXPECT_GT(max_tilt, 10.0 * kRadPerDeg);
}

// ---- figure-eight ----

TEST(FlightFigureEight, TracksOneLapAtOneMetrePerSecondPeak) {
  Scenario scenario = Load("scenarios/figure_eight_arena.yaml");
  // One lap instead of two: the same dynamics, half the time.
  bool shortened = false;
  for (sim::PrimitiveSpec& segment : scenario.trajectory.segments) {
    if (auto* eight = std::get_if<sim::FigureEightSpec>(&segment)) {
      ASSERT_DOUBLE_EQ(eight->speed_mps, 1.0);
      eight->laps = 1.0;
      shortened = true;
    }
  }
  ASSERT_TRUE(shortened);
  const std::unique_ptr<sim::Trajectory> trajectory =
      sim::BuildTrajectory(scenario.trajectory, sim::TrajectoryContext{});
  scenario.duration_s = core::TimeToSeconds(trajectory->duration_ns()) + 1.0;

  const RunRecord record = Simulate(scenario);
  ASSERT_FALSE(record.failure.has_value()) << *record.failure;
  EXPECT_LT(Metric(record, "tracking.position_rmse_m"), 0.05);
  EXPECT_LT(Metric(record, "tracking.attitude_rmse_deg"), 1.0);
  EXPECT_TRUE(record.collisions.empty());

  // The robot really flew the figure at the requested speed (ground truth, not reference).
  double peak_speed = 0.0, max_x = -1e9, min_x = 1e9, max_y = -1e9, min_y = 1e9;
  for (const sim::TruthState& s : record.groundtruth) {
    peak_speed = std::max(peak_speed, s.v_WB_W.norm());
    max_x = std::max(max_x, s.p_WB.x());
    min_x = std::min(min_x, s.p_WB.x());
    max_y = std::max(max_y, s.p_WB.y());
    min_y = std::min(min_y, s.p_WB.y());
  }
  EXPECT_GE(peak_speed, 0.9);
  EXPECT_LE(peak_speed, 1.1);
  EXPECT_NEAR(max_x - min_x, 4.0, 0.1);  // 2 * half_length_m
  EXPECT_NEAR(max_y - min_y, 1.2, 0.1);  // 2 * half_width_m / 2 (Gerono: y = w sin cos)
}

// ---- approach ----

TEST(FlightApproach, ToolTipStopsAtTheStandoffWithoutTouching) {
  const Scenario scenario = Load("scenarios/approach_wall.yaml");
  const RunRecord record = Simulate(scenario);
  ASSERT_FALSE(record.failure.has_value()) << *record.failure;
  ASSERT_EQ(record.approaches.size(), 1u);
  const ApproachResult& approach = record.approaches.front();
  EXPECT_DOUBLE_EQ(approach.standoff_m, 0.3);
  ASSERT_TRUE(approach.distance_m.has_value());
  EXPECT_NEAR(*approach.distance_m, 0.3, 0.02);
  EXPECT_LE(Metric(record, "approach.max_standoff_error_m"), 0.02);

  // Independently of the ray: the tool tip (0.6 m ahead of B) stands 0.3 m before the
  // textured skin of the facade (x = 4.998) when the approach ends.
  const auto at = std::min_element(
      record.groundtruth.begin(), record.groundtruth.end(),
      [&](const sim::TruthState& a, const sim::TruthState& b) {
        return std::abs(a.t_ns - approach.t_ns) < std::abs(b.t_ns - approach.t_ns);
      });
  const Eigen::Vector3d p_W_tip = at->p_WB + at->q_WB * record.robot.FindSite("tool_tip")->p_Bs;
  EXPECT_NEAR(p_W_tip.x(), 4.998 - 0.3, 0.02);

  EXPECT_TRUE(record.collisions.empty());
  EXPECT_GE(Metric(record, "structure.min_distance_m"), 0.1);
  const Evaluation evaluation = Evaluate(record);
  EXPECT_TRUE(evaluation.passed) << evaluation.summary.dump(2);
  ASSERT_EQ(evaluation.summary["approaches"].size(), 1u);
  EXPECT_NEAR(evaluation.summary["approaches"][0]["tool_tip_distance_m"].get<double>(), 0.3,
              0.02);
}

// ---- crash ----

TEST(FlightCollision, FlyingIntoAWallIsRecordedNamedAndFailsTheRun) {
  const Scenario scenario = Load("tests/data/scenarios/crash_into_wall.yaml");
  const RunRecord record = Simulate(scenario);
  ASSERT_FALSE(record.failure.has_value()) << *record.failure;
  ASSERT_FALSE(record.collisions.empty());

  const std::set<std::string> robot_geoms = {"hub",           "tool",          "foot_1",
                                             "foot_2",        "foot_3",        "foot_4",
                                             "rotor_guard_1", "rotor_guard_2", "rotor_guard_3",
                                             "rotor_guard_4", "rotor_guard_5", "rotor_guard_6"};
  const CollisionEvent& first = *std::min_element(
      record.collisions.begin(), record.collisions.end(),
      [](const CollisionEvent& a, const CollisionEvent& b) { return a.start_ns < b.start_ns; });
  EXPECT_EQ(first.structure_geom, "wall_east");
  EXPECT_EQ(first.robot_geom, "tool");  // the tool sticks out furthest ahead
  for (const CollisionEvent& c : record.collisions) {
    EXPECT_TRUE(robot_geoms.count(c.robot_geom)) << c.robot_geom;
    EXPECT_EQ(c.structure_geom, "wall_east");
    EXPECT_LE(c.start_ns, c.end_ns);
    EXPECT_GE(c.max_penetration_m, 0.0);
    EXPECT_LT(c.max_penetration_m, 0.05);
  }

  // Plausible time: the contact starts when the tool tip has reached the wall face
  // (x = 6) and not before; the robot never got past it.
  const sim::MountSite& tip = *record.robot.FindSite("tool_tip");
  core::Time reached_ns = -1;
  for (const sim::TruthState& s : record.groundtruth) {
    const Eigen::Vector3d p_W_tip = s.p_WB + s.q_WB * tip.p_Bs;
    if (reached_ns < 0 && p_W_tip.x() >= 5.97) reached_ns = s.t_ns;
    EXPECT_LT(s.p_WB.x(), 6.0 - 0.4);
  }
  ASSERT_GE(reached_ns, 0) << "the tool tip never reached the wall";
  EXPECT_GT(first.start_ns, core::SecondsToTime(2.0));
  EXPECT_NEAR(core::TimeToSeconds(first.start_ns), core::TimeToSeconds(reached_ns), 0.1);

  EXPECT_GE(Metric(record, "collisions.count"), 1.0);
  EXPECT_LT(Metric(record, "structure.min_distance_m"), 0.0);
  const Evaluation evaluation = Evaluate(record);
  EXPECT_FALSE(evaluation.passed);
  ASSERT_EQ(evaluation.expectations.size(), 1u);
  EXPECT_FALSE(evaluation.expectations[0].passed);
  EXPECT_EQ(evaluation.summary["passed"], false);

  // The summary lists every collision with its time and geoms.
  const nlohmann::json& listed = evaluation.summary["collisions"];
  ASSERT_TRUE(listed.is_array());
  ASSERT_EQ(listed.size(), record.collisions.size());
  for (size_t i = 0; i < listed.size(); ++i) {
    EXPECT_DOUBLE_EQ(listed[i]["start_s"].get<double>(),
                     core::TimeToSeconds(record.collisions[i].start_ns));
    EXPECT_DOUBLE_EQ(listed[i]["end_s"].get<double>(),
                     core::TimeToSeconds(record.collisions[i].end_ns));
    EXPECT_EQ(listed[i]["robot_geom"], record.collisions[i].robot_geom);
    EXPECT_EQ(listed[i]["structure_geom"], "wall_east");
  }
}

// ---- seeds ----

bool BitwiseEqual(const Eigen::Vector3d& a, const Eigen::Vector3d& b) {
  return std::memcmp(a.data(), b.data(), sizeof(double) * 3) == 0;
}

bool BitwiseEqual(const sim::TruthState& a, const sim::TruthState& b) {
  return a.t_ns == b.t_ns && BitwiseEqual(a.p_WB, b.p_WB) &&
         std::memcmp(a.q_WB.coeffs().data(), b.q_WB.coeffs().data(), sizeof(double) * 4) == 0 &&
         BitwiseEqual(a.v_WB_W, b.v_WB_W) && BitwiseEqual(a.omega_WB_B, b.omega_WB_B) &&
         BitwiseEqual(a.a_WB_W, b.a_WB_W) &&
         std::memcmp(a.tilt_rad.data(), b.tilt_rad.data(), sizeof(a.tilt_rad)) == 0;
}

TEST(FlightSeed, SameSeedGivesBitwiseIdenticalTruthAndAnotherSeedDoesNot) {
  Scenario scenario = Load("tests/data/scenarios/gusty_hover_short.yaml");
  ASSERT_GT(scenario.wind.gust_std_mps, 0.0);
  const RunRecord a = Simulate(scenario);
  const RunRecord b = Simulate(scenario);
  scenario.seed += 1;
  const RunRecord c = Simulate(scenario);
  ASSERT_FALSE(a.failure || b.failure || c.failure);
  ASSERT_EQ(a.groundtruth.size(), b.groundtruth.size());
  ASSERT_EQ(a.groundtruth.size(), c.groundtruth.size());
  ASSERT_GT(a.groundtruth.size(), 100u);
  size_t differing = 0;
  for (size_t i = 0; i < a.groundtruth.size(); ++i) {
    ASSERT_TRUE(BitwiseEqual(a.groundtruth[i], b.groundtruth[i])) << "sample " << i;
    if (!BitwiseEqual(a.groundtruth[i], c.groundtruth[i])) ++differing;
  }
  // The gusts push the robot around differently from early on.
  EXPECT_GT(differing, a.groundtruth.size() / 2);
  EXPECT_GT((a.groundtruth.back().p_WB - c.groundtruth.back().p_WB).norm(), 1e-5);
  EXPECT_EQ(Evaluate(a).summary.dump(), Evaluate(b).summary.dump());
}

TEST(FlightSeed, WithoutRandomDisturbancesTheSeedDoesNotMatter) {
  Scenario scenario = Load("tests/data/scenarios/gusty_hover_short.yaml");
  scenario.wind.gust_std_mps = 0.0;
  const RunRecord a = Simulate(scenario);
  scenario.seed = 12345;
  const RunRecord b = Simulate(scenario);
  ASSERT_EQ(a.groundtruth.size(), b.groundtruth.size());
  for (size_t i = 0; i < a.groundtruth.size(); ++i) {
    ASSERT_TRUE(BitwiseEqual(a.groundtruth[i], b.groundtruth[i])) << "sample " << i;
  }
}

}  // namespace
}  // namespace tofu::harness
