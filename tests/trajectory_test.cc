// Tests of sim/trajectory: minimum-snap waypoints, the curve primitives, approach, and the
// smoothness, consistency and limit properties the controller relies on.

#include "sim/trajectory.h"

#include <algorithm>
#include <cmath>
#include <numbers>
#include <optional>
#include <stdexcept>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "core/lie.h"
#include "core/time.h"
#include "sim/min_snap.h"

namespace tofu::sim {
namespace {

using core::Time;
constexpr double kPi = std::numbers::pi;
constexpr Time kMs = 1'000'000;

Eigen::Quaterniond Rpy(double roll, double pitch, double yaw) {
  return Eigen::Quaterniond(core::RotationFromRollPitchYaw(roll, pitch, yaw));
}

double AngleBetween(const Eigen::Quaterniond& a, const Eigen::Quaterniond& b) {
  return core::LogQuat(a.conjugate() * b).norm();
}

/// Surface query of a wall filling the plane x = wall_x (hit only moving towards +x).
SurfaceDistanceQuery WallAtX(double wall_x) {
  return [wall_x](const Eigen::Vector3d& origin_W,
                  const Eigen::Vector3d& direction_W) -> std::optional<double> {
    if (direction_W.x() <= 1e-12 || origin_W.x() > wall_x) return std::nullopt;
    return (wall_x - origin_W.x()) / direction_W.x();
  };
}

DynamicLimits TestLimits() {
  DynamicLimits limits;
  limits.max_speed_mps = 1.0;
  limits.max_acceleration_mps2 = 0.8;
  limits.max_angular_rate_radps = 0.8;
  limits.max_angular_acceleration_radps2 = 1.5;
  return limits;
}

std::vector<Waypoint> TestWaypoints() {
  return {{Eigen::Vector3d(2.0, 0.0, 1.2), Rpy(0.0, 0.0, 0.6)},
          {Eigen::Vector3d(2.0, 1.5, 1.5), Rpy(0.2, -0.1, 1.2)},
          {Eigen::Vector3d(0.5, 2.0, 1.0), Rpy(0.0, 0.0, 2.0)},
          {Eigen::Vector3d(0.0, 0.0, 1.0), Rpy(0.0, 0.0, 0.0)}};
}

/// Every primitive kind, with transfers onto the circle and the figure-eight.
TrajectorySpec MixedMission() {
  TrajectorySpec spec;
  spec.start = {Eigen::Vector3d(0.0, 0.0, 1.0), Eigen::Quaterniond::Identity()};
  spec.limits = TestLimits();
  spec.segments.push_back(WaypointsSpec{TestWaypoints()});
  spec.segments.push_back(HoverSpec{0.5});
  spec.segments.push_back(LineSpec{Eigen::Vector3d(1.0, 0.0, 1.5), Rpy(0.0, 0.3, -0.5)});
  spec.segments.push_back(CircleSpec{Eigen::Vector3d(2.5, 0.5, 1.2), 0.8, 0.6, 1.25, true});
  spec.segments.push_back(FigureEightSpec{Eigen::Vector3d(0.0, 0.0, 1.5), 1.2, 0.8, 0.5, 1.0});
  spec.segments.push_back(ApproachSpec{Eigen::Vector3d(1.0, 0.0, 0.0), 0.3, 0.4});
  return spec;
}

TrajectoryContext WallContext() {
  TrajectoryContext context;
  context.p_B_tool = Eigen::Vector3d(0.5, 0.1, -0.2);
  context.surface_distance = WallAtX(5.0);
  return context;
}

bool AtRest(const Reference& ref, double tolerance) {
  return ref.v_WB_W.norm() <= tolerance && ref.a_WB_W.norm() <= tolerance &&
         ref.j_WB_W.norm() <= tolerance && ref.omega_WB_B.norm() <= tolerance &&
         ref.alpha_WB_B.norm() <= tolerance;
}

/// Largest of v/v_max, |a|/a_max, |ω|/ω_max, |α|/α_max over a segment, sampled at 1 ms.
double PeakLimitUsage(const Trajectory& trajectory, const SegmentInfo& segment,
                      const DynamicLimits& limits) {
  double usage = 0.0;
  for (Time t = segment.start_ns; t <= segment.end_ns; t += kMs) {
    const Reference ref = trajectory.Sample(t);
    usage = std::max({usage, ref.v_WB_W.norm() / limits.max_speed_mps,
                      ref.a_WB_W.norm() / limits.max_acceleration_mps2,
                      ref.omega_WB_B.norm() / limits.max_angular_rate_radps,
                      ref.alpha_WB_B.norm() / limits.max_angular_acceleration_radps2});
  }
  return usage;
}

// ---- minimum snap ----

TEST(TrajectoryMinSnap, PassesThroughWaypointsAtSegmentTimesAndRestsAtEnds) {
  const Waypoint start{Eigen::Vector3d(0.0, 0.0, 1.0), Eigen::Quaterniond::Identity()};
  const std::vector<Waypoint> waypoints = TestWaypoints();
  const min_snap::WaypointPath path = min_snap::PlanWaypoints(start, waypoints, TestLimits());

  ASSERT_EQ(path.position().num_segments(), static_cast<int>(waypoints.size()));
  for (size_t k = 0; k <= waypoints.size(); ++k) {
    const Waypoint& w = k == 0 ? start : waypoints[k - 1];
    const Reference ref = path.Sample(path.waypoint_time_s(static_cast<int>(k)));
    EXPECT_LT((ref.p_WB - w.p_WB).norm(), 1e-9) << "waypoint " << k;
    EXPECT_LT(AngleBetween(ref.q_WB, w.q_WB), 1e-9) << "waypoint " << k;
    // Attitude is rest-to-rest at each waypoint; position flies through interior ones.
    EXPECT_LT(ref.omega_WB_B.norm(), 1e-12) << "waypoint " << k;
    if (k > 0 && k < waypoints.size()) {
      EXPECT_GT(ref.v_WB_W.norm(), 0.05) << "waypoint " << k;
    }
  }
  EXPECT_TRUE(AtRest(path.Sample(0.0), 1e-9));
  EXPECT_TRUE(AtRest(path.Sample(path.duration_s()), 1e-9));

  // Through the public API: the same times, offset by the primitive's start.
  TrajectorySpec spec;
  spec.start = start;
  spec.limits = TestLimits();
  spec.segments.push_back(HoverSpec{1.0});
  spec.segments.push_back(WaypointsSpec{waypoints});
  const auto trajectory = BuildTrajectory(spec, {});
  const SegmentInfo& info = trajectory->segments().at(1);
  EXPECT_EQ(info.kind, "waypoints");
  for (size_t k = 1; k <= waypoints.size(); ++k) {
    const Time t_ns =
        info.start_ns + core::SecondsToTime(path.waypoint_time_s(static_cast<int>(k)));
    const Reference ref = trajectory->Sample(std::min(t_ns, trajectory->duration_ns()));
    EXPECT_LT((ref.p_WB - waypoints[k - 1].p_WB).norm(), 1e-6) << "waypoint " << k;
    EXPECT_LT(AngleBetween(ref.q_WB, waypoints[k - 1].q_WB), 1e-6) << "waypoint " << k;
  }
  EXPECT_TRUE(AtRest(trajectory->Sample(info.start_ns), 1e-9));
  EXPECT_TRUE(AtRest(trajectory->Sample(info.end_ns), 1e-9));
}

TEST(TrajectoryMinSnap, IsTheConstrainedOptimumAndBeatsNaiveAlternatives) {
  const std::vector<Eigen::Vector3d> points = {
      Eigen::Vector3d(0.0, 0.0, 0.0), Eigen::Vector3d(1.0, 2.0, 0.5),
      Eigen::Vector3d(3.0, 1.0, 1.0), Eigen::Vector3d(2.0, -1.0, 0.0),
      Eigen::Vector3d(4.0, 0.0, 0.5)};
  const std::vector<double> durations = {1.5, 2.0, 1.0, 2.5};
  using min_snap::PiecewisePolynomial;
  const PiecewisePolynomial snap = min_snap::SolveMinimumDerivative(points, durations);
  const double snap_cost = snap.IntegratedSquaredDerivative(4);

  // Naive alternative: septic rest-to-rest on every segment (stops at each waypoint).
  std::vector<PiecewisePolynomial::Coefficients> septic(durations.size());
  for (size_t k = 0; k < durations.size(); ++k) {
    const Eigen::RowVector3d delta = (points[k + 1] - points[k]).transpose();
    septic[k].setZero();
    septic[k].row(0) = points[k].transpose();
    septic[k].row(4) = 35.0 * delta;
    septic[k].row(5) = -84.0 * delta;
    septic[k].row(6) = 70.0 * delta;
    septic[k].row(7) = -20.0 * delta;
  }
  const double septic_cost = PiecewisePolynomial(durations, septic).IntegratedSquaredDerivative(4);
  EXPECT_LT(snap_cost, 0.5 * septic_cost);

  // A feasible point of the same QP (same constraints, minimum jerk instead): it is worse,
  // and along the feasible direction d = c_jerk − c_snap the cost J(c_snap + εd) is a
  // parabola with its minimum at ε = 0 (zero slope: KKT stationarity).
  min_snap::MinimumDerivativeOptions jerk_options;
  jerk_options.cost_derivative = 3;
  const PiecewisePolynomial jerk = min_snap::SolveMinimumDerivative(points, durations, jerk_options);
  for (int k = 0; k <= static_cast<int>(durations.size()); ++k) {
    ASSERT_LT((jerk.Evaluate(jerk.segment_start_s(k)) - points[k]).norm(), 1e-9);
  }
  EXPECT_GT(jerk.IntegratedSquaredDerivative(4), snap_cost * 1.01);
  auto perturbed_cost = [&](double epsilon) {
    std::vector<PiecewisePolynomial::Coefficients> c = snap.coefficients();
    for (size_t k = 0; k < c.size(); ++k) {
      c[k] += epsilon * (jerk.coefficients()[k] - snap.coefficients()[k]);
    }
    return PiecewisePolynomial(durations, c).IntegratedSquaredDerivative(4);
  };
  const double epsilon = 0.1;
  const double slope = (perturbed_cost(epsilon) - perturbed_cost(-epsilon)) / (2.0 * epsilon);
  const double curvature =
      (perturbed_cost(epsilon) + perturbed_cost(-epsilon) - 2.0 * snap_cost) / (epsilon * epsilon);
  EXPECT_GT(curvature, 0.0);
  EXPECT_LT(std::abs(slope), 1e-6 * curvature);

  // Only derivatives 1..4 are constrained continuous; the optimum is C⁶ by its natural
  // (Euler–Lagrange) conditions, which the non-optimal feasible point is not.
  double snap_jump = 0.0;
  double jerk_jump = 0.0;
  for (int k = 0; k + 1 < static_cast<int>(durations.size()); ++k) {
    for (int r = 5; r <= 6; ++r) {
      const double scale = snap.EvaluateSegment(k, 1.0, r).norm() + 1.0;
      snap_jump = std::max(snap_jump, (snap.EvaluateSegment(k, 1.0, r) -
                                       snap.EvaluateSegment(k + 1, 0.0, r)).norm() / scale);
      jerk_jump = std::max(jerk_jump, (jerk.EvaluateSegment(k, 1.0, r) -
                                       jerk.EvaluateSegment(k + 1, 0.0, r)).norm() / scale);
    }
  }
  EXPECT_LT(snap_jump, 1e-6);
  EXPECT_GT(jerk_jump, 1e-2);
}

TEST(TrajectoryMinSnap, RefusesOptionsOutsideTheirFieldTable) {
  const std::vector<Eigen::Vector3d> points = {Eigen::Vector3d::Zero(), Eigen::Vector3d::Ones()};
  min_snap::MinimumDerivativeOptions options;
  options.continuity_derivative = 7;
  std::string why;
  EXPECT_FALSE(options.IsValid(&why));
  EXPECT_EQ(why, "continuity_derivative: expected an integer in [1, 6], got 7");
  try {
    min_snap::SolveMinimumDerivative(points, {1.0}, options);
    FAIL() << "continuity_derivative 7 was accepted";
  } catch (const std::invalid_argument& e) {
    EXPECT_EQ(std::string(e.what()),
              "SolveMinimumDerivative: continuity_derivative: expected an integer in [1, 6], got 7");
  }
}

TEST(TrajectoryMinSnap, CostGradientMatchesFiniteDifferences) {
  const std::vector<Eigen::Vector3d> points = {
      Eigen::Vector3d(0.0, 0.0, 0.0), Eigen::Vector3d(1.0, 2.0, 0.5),
      Eigen::Vector3d(3.0, 1.0, 1.0), Eigen::Vector3d(2.0, -1.0, 0.0)};
  const std::vector<double> durations = {1.5, 2.0, 0.7};
  std::vector<double> gradient;
  min_snap::SolveMinimumDerivative(points, durations, {}, &gradient);
  ASSERT_EQ(gradient.size(), durations.size());
  auto cost = [&](const std::vector<double>& t) {
    return min_snap::SolveMinimumDerivative(points, t).IntegratedSquaredDerivative(4);
  };
  double euler = 0.0;
  for (size_t k = 0; k < durations.size(); ++k) {
    const double h = 1e-5 * durations[k];
    std::vector<double> plus = durations, minus = durations;
    plus[k] += h;
    minus[k] -= h;
    const double numeric = (cost(plus) - cost(minus)) / (2.0 * h);
    EXPECT_NEAR(gradient[k], numeric, 1e-6 * std::abs(numeric)) << "segment " << k;
    euler += durations[k] * gradient[k];
  }
  // J(αT) = α⁻⁷ J(T) ⇒ Σ T_k ∂J/∂T_k = −7 J.
  EXPECT_NEAR(euler, -7.0 * cost(durations), 1e-8 * cost(durations));
}

TEST(TrajectoryMinSnap, OptimisedTimeAllocationDoesNotOvershootCollinearWaypoints) {
  // A short first leg then a long one, all on the x axis: with badly proportioned segment
  // times the C⁶ spline runs backwards past the start and beyond the end.
  TrajectorySpec spec;
  spec.limits = TestLimits();
  WaypointsSpec line;
  line.waypoints = {{Eigen::Vector3d(0.2, 0.0, 0.0), Eigen::Quaterniond::Identity()},
                    {Eigen::Vector3d(10.2, 0.0, 0.0), Eigen::Quaterniond::Identity()}};
  spec.segments.push_back(line);
  const auto trajectory = BuildTrajectory(spec, {});
  double previous_x = 0.0;
  for (Time t = 0; t <= trajectory->duration_ns(); t += 10 * kMs) {
    const Eigen::Vector3d p = trajectory->Sample(t).p_WB;
    EXPECT_GE(p.x(), previous_x - 1e-9) << "t_ns " << t;
    EXPECT_LE(p.x(), 10.2 + 1e-9) << "t_ns " << t;
    EXPECT_LT(p.tail<2>().norm(), 1e-9);
    previous_x = p.x();
  }

  // The optimised ratios lower the scale-free cost J(T)(ΣT)⁷ of a turning path.
  const std::vector<Eigen::Vector3d> points = {
      Eigen::Vector3d(0.0, 0.0, 0.0), Eigen::Vector3d(1.0, 0.0, 0.0),
      Eigen::Vector3d(1.0, 10.0, 0.0), Eigen::Vector3d(2.0, 10.0, 0.0)};
  const std::vector<double> initial = {1.0, 10.0, 1.0};
  const std::vector<double> optimised = min_snap::OptimizeSegmentRatios(points, initial);
  auto scale_free_cost = [&](const std::vector<double>& t) {
    double total = 0.0;
    for (double tk : t) total += tk;
    return min_snap::SolveMinimumDerivative(points, t).IntegratedSquaredDerivative(4) *
           std::pow(total, 7);
  };
  EXPECT_NEAR(optimised[0] + optimised[1] + optimised[2], 12.0, 1e-9);
  EXPECT_LT(scale_free_cost(optimised), 0.5 * scale_free_cost(initial));
}

TEST(TrajectorySepticStep, PeakConstantsMatchDenseSampling) {
  double peak_rate = 0.0;
  double peak_acceleration = 0.0;
  for (int i = 0; i <= 100000; ++i) {
    const min_snap::SepticStep step = min_snap::EvaluateSepticStep(i * 1e-5);
    peak_rate = std::max(peak_rate, step.ds);
    peak_acceleration = std::max(peak_acceleration, std::abs(step.dds));
  }
  EXPECT_NEAR(peak_rate, min_snap::kSepticPeakRate, 1e-9);
  EXPECT_NEAR(peak_acceleration, min_snap::kSepticPeakAcceleration, 1e-6);
  EXPECT_NEAR(min_snap::SepticStepIntegral(1.0), 0.5, 1e-15);
}

// ---- whole-trajectory properties ----

TEST(TrajectoryContinuity, DerivativesContinuousAndConsistentWithFiniteDifferences) {
  const auto trajectory = BuildTrajectory(MixedMission(), WallContext());
  ASSERT_GT(trajectory->duration_ns(), 0);

  // No jump of v, a, j across any primitive boundary.
  const Time epsilon = 1000;  // 1 µs
  for (const SegmentInfo& info : trajectory->segments()) {
    for (const Time t : {info.start_ns, info.end_ns}) {
      const Reference before = trajectory->Sample(t - epsilon);
      const Reference after = trajectory->Sample(t + epsilon);
      EXPECT_LT((after.p_WB - before.p_WB).norm(), 1e-6) << info.kind << " t_ns " << t;
      EXPECT_LT((after.v_WB_W - before.v_WB_W).norm(), 1e-5) << info.kind << " t_ns " << t;
      EXPECT_LT((after.a_WB_W - before.a_WB_W).norm(), 1e-4) << info.kind << " t_ns " << t;
      EXPECT_LT((after.j_WB_W - before.j_WB_W).norm(), 1e-3) << info.kind << " t_ns " << t;
      EXPECT_LT(AngleBetween(after.q_WB, before.q_WB), 1e-6) << info.kind << " t_ns " << t;
      EXPECT_LT((after.omega_WB_B - before.omega_WB_B).norm(), 1e-5) << info.kind;
    }
  }

  // Central differences everywhere (a jump anywhere, e.g. between a transfer and its
  // curve or at a speed ramp, shows as a finite-difference error of at least a quarter of
  // it). The snap is not continuous at rest junctions, which bounds the jerk error by
  // about |snap| h / 4 there, hence the short step.
  const Time h = kMs / 5;
  double v_error = 0.0, a_error = 0.0, j_error = 0.0;
  for (Time t = 0; t <= trajectory->duration_ns(); t += 3 * kMs) {
    const Reference prev = trajectory->Sample(t - h);
    const Reference now = trajectory->Sample(t);
    const Reference next = trajectory->Sample(t + h);
    const double two_h = 2.0 * core::TimeToSeconds(h);
    v_error = std::max(v_error, ((next.p_WB - prev.p_WB) / two_h - now.v_WB_W).norm());
    a_error = std::max(a_error, ((next.v_WB_W - prev.v_WB_W) / two_h - now.a_WB_W).norm());
    j_error = std::max(j_error, ((next.a_WB_W - prev.a_WB_W) / two_h - now.j_WB_W).norm());
  }
  EXPECT_LT(v_error, 1e-6);
  EXPECT_LT(a_error, 1e-5);
  EXPECT_LT(j_error, 1e-3);
}

TEST(TrajectoryAttitude, AngularRateAndAccelerationMatchFiniteDifferencesOfAttitude) {
  const auto trajectory = BuildTrajectory(MixedMission(), WallContext());
  const Time h = kMs;
  const double two_h = 2.0 * core::TimeToSeconds(h);
  double omega_error = 0.0, alpha_error = 0.0, peak_omega = 0.0;
  for (Time t = 0; t <= trajectory->duration_ns(); t += 3 * kMs) {
    const Reference prev = trajectory->Sample(t - h);
    const Reference now = trajectory->Sample(t);
    const Reference next = trajectory->Sample(t + h);
    // ω_B ≈ Log(R(t−h)ᵀ R(t+h)) / 2h, since Ṙ = R Hat(ω_B).
    const Eigen::Vector3d omega_fd = core::LogQuat(prev.q_WB.conjugate() * next.q_WB) / two_h;
    omega_error = std::max(omega_error, (omega_fd - now.omega_WB_B).norm());
    alpha_error = std::max(
        alpha_error, ((next.omega_WB_B - prev.omega_WB_B) / two_h - now.alpha_WB_B).norm());
    peak_omega = std::max(peak_omega, now.omega_WB_B.norm());
  }
  EXPECT_GT(peak_omega, 0.3);  // the mission does rotate
  EXPECT_LT(omega_error, 1e-5);
  EXPECT_LT(alpha_error, 1e-4);
}

TEST(TrajectoryLimits, DenseSamplingStaysWithinLimitsAndWaypointsUseThem) {
  const TrajectorySpec spec = MixedMission();
  const DynamicLimits& limits = spec.limits;
  const auto trajectory = BuildTrajectory(spec, WallContext());
  double speed = 0.0, acceleration = 0.0, rate = 0.0, angular_acceleration = 0.0;
  for (Time t = 0; t <= trajectory->duration_ns(); t += kMs) {
    const Reference ref = trajectory->Sample(t);
    speed = std::max(speed, ref.v_WB_W.norm());
    acceleration = std::max(acceleration, ref.a_WB_W.norm());
    rate = std::max(rate, ref.omega_WB_B.norm());
    angular_acceleration = std::max(angular_acceleration, ref.alpha_WB_B.norm());
  }
  EXPECT_LE(speed, limits.max_speed_mps * 1.001);
  EXPECT_LE(acceleration, limits.max_acceleration_mps2 * 1.001);
  EXPECT_LE(rate, limits.max_angular_rate_radps * 1.001);
  EXPECT_LE(angular_acceleration, limits.max_angular_acceleration_radps2 * 1.001);

  // The uniform time scaling makes the waypoints primitive meet its most binding limit.
  EXPECT_NEAR(PeakLimitUsage(*trajectory, trajectory->segments().at(0), limits), 1.0, 1e-3);

  // Also when only the translational limits can bind (no rotation).
  TrajectorySpec translation;
  translation.limits = limits;
  WaypointsSpec square;
  for (const Eigen::Vector3d& p : {Eigen::Vector3d(3.0, 0.0, 0.0), Eigen::Vector3d(3.0, 2.0, 0.5),
                                   Eigen::Vector3d(0.5, 2.5, 0.0), Eigen::Vector3d(0.0, 0.0, 0.0)}) {
    square.waypoints.push_back({p, Eigen::Quaterniond::Identity()});
  }
  translation.segments.push_back(square);
  for (const double max_acceleration : {0.3, 3.0}) {  // acceleration-, then speed-bound
    translation.limits.max_acceleration_mps2 = max_acceleration;
    const auto path = BuildTrajectory(translation, {});
    EXPECT_NEAR(PeakLimitUsage(*path, path->segments().at(0), translation.limits), 1.0, 1e-3)
        << "max_acceleration_mps2 " << max_acceleration;
  }
}

TEST(TrajectorySegments, ContiguousAndSampleClampsOutsideTheDuration) {
  const TrajectorySpec spec = MixedMission();
  const auto trajectory = BuildTrajectory(spec, WallContext());
  const std::vector<SegmentInfo>& segments = trajectory->segments();
  ASSERT_EQ(segments.size(), spec.segments.size());
  const std::vector<std::string> kinds = {"waypoints", "line", "circle", "figure_eight",
                                          "approach"};
  EXPECT_EQ(segments[0].start_ns, 0);
  for (size_t i = 0; i < segments.size(); ++i) {
    EXPECT_GT(segments[i].end_ns, segments[i].start_ns);
    if (i > 0) {
      EXPECT_EQ(segments[i].start_ns, segments[i - 1].end_ns);
    }
  }
  EXPECT_EQ(segments.back().end_ns, trajectory->duration_ns());
  EXPECT_EQ(segments[1].kind, "hover");
  EXPECT_EQ(segments[1].end_ns - segments[1].start_ns, 500 * kMs);

  const Reference before = trajectory->Sample(-5 * core::kNanosecondsPerSecond);
  EXPECT_LT((before.p_WB - spec.start.p_WB).norm(), 1e-12);
  EXPECT_TRUE(AtRest(before, 1e-12));
  const Reference last = trajectory->Sample(trajectory->duration_ns() - 1);
  const Reference after = trajectory->Sample(trajectory->duration_ns() + 7 * kMs);
  EXPECT_LT((after.p_WB - last.p_WB).norm(), 1e-9);
  EXPECT_LT(AngleBetween(after.q_WB, last.q_WB), 1e-9);
  EXPECT_TRUE(AtRest(after, 0.0));
}

// ---- circle ----

TEST(TrajectoryCircle, HoldsRadiusAndHeightAtRequestedSpeedThenRests) {
  const Eigen::Vector3d center(1.0, 1.0, 2.0);
  const double radius = 1.5;
  const double speed = 0.9;
  for (const bool clockwise : {false, true}) {
    TrajectorySpec spec;
    // Off the circle and below it: transfer to (2.5, 1, 2), the closest point in z = 2.
    spec.start = {Eigen::Vector3d(4.0, 1.0, 1.0), Rpy(0.1, 0.0, 0.4)};
    spec.limits.max_speed_mps = 1.0;
    spec.limits.max_acceleration_mps2 = 1.0;
    spec.segments.push_back(CircleSpec{center, radius, speed, 2.0, clockwise});
    const auto trajectory = BuildTrajectory(spec, {});
    const SegmentInfo& info = trajectory->segments().at(0);
    EXPECT_EQ(info.kind, "circle");

    bool on_circle = false;
    double peak_speed = 0.0, angle = 0.0, previous_angle = 0.0;
    for (Time t = info.start_ns; t <= info.end_ns; t += kMs) {
      const Reference ref = trajectory->Sample(t);
      EXPECT_LT(AngleBetween(ref.q_WB, spec.start.q_WB), 1e-12);
      const Eigen::Vector3d offset = ref.p_WB - center;
      const double rho = offset.head<2>().norm();
      if (!on_circle && std::abs(rho - radius) < 1e-9 && std::abs(offset.z()) < 1e-9) {
        on_circle = true;
        previous_angle = std::atan2(offset.y(), offset.x());
      }
      if (!on_circle) continue;
      // Once on the circle, it stays on it, at its centre's height.
      ASSERT_NEAR(rho, radius, 1e-9) << "t_ns " << t;
      ASSERT_NEAR(offset.z(), 0.0, 1e-9) << "t_ns " << t;
      peak_speed = std::max(peak_speed, ref.v_WB_W.norm());
      const double a = std::atan2(offset.y(), offset.x());
      angle += std::remainder(a - previous_angle, 2.0 * kPi);
      previous_angle = a;
    }
    ASSERT_TRUE(on_circle);
    EXPECT_NEAR(peak_speed, speed, 1e-6 * speed);
    EXPECT_NEAR(angle, (clockwise ? -1.0 : 1.0) * 2.0 * 2.0 * kPi, 1e-6);
    const Reference end = trajectory->Sample(info.end_ns);
    EXPECT_TRUE(AtRest(end, 1e-9));
    EXPECT_LT((end.p_WB - Eigen::Vector3d(2.5, 1.0, 2.0)).norm(), 1e-9);
  }
}

TEST(TrajectoryCircle, ThrowsWhenCentripetalAccelerationOrSpeedExceedsLimits) {
  TrajectorySpec spec;
  spec.limits.max_speed_mps = 2.0;
  spec.limits.max_acceleration_mps2 = 1.0;
  spec.segments.push_back(HoverSpec{1.0});
  spec.segments.push_back(LineSpec{Eigen::Vector3d(1.0, 0.0, 0.0), std::nullopt});
  spec.segments.push_back(CircleSpec{Eigen::Vector3d::Zero(), 0.5, 1.0, 1.0, false});
  try {
    BuildTrajectory(spec, {});
    FAIL() << "speed^2 / radius = 2 m/s^2 > 1 m/s^2 must be rejected";
  } catch (const std::invalid_argument& e) {
    const std::string message = e.what();
    EXPECT_NE(message.find("segment 2"), std::string::npos) << message;
    EXPECT_NE(message.find("max_acceleration_mps2"), std::string::npos) << message;
  }
  // Just within the limit it builds.
  std::get<CircleSpec>(spec.segments[2]).speed_mps = std::sqrt(0.5) * 0.999;
  EXPECT_NO_THROW(BuildTrajectory(spec, {}));
  // Faster than max_speed_mps on a large circle.
  spec.segments[2] = CircleSpec{Eigen::Vector3d::Zero(), 10.0, 2.5, 1.0, false};
  EXPECT_THROW(BuildTrajectory(spec, {}), std::invalid_argument);
}

// ---- figure-eight ----

TEST(TrajectoryFigureEight, FollowsTheLemniscateWithRequestedPeakSpeed) {
  const Eigen::Vector3d center(0.5, -0.5, 1.5);
  const double a = 1.5, b = 1.0, speed = 0.7;
  TrajectorySpec spec;
  spec.start = {center, Eigen::Quaterniond::Identity()};
  spec.limits.max_speed_mps = 1.0;
  spec.limits.max_acceleration_mps2 = 1.0;
  spec.segments.push_back(FigureEightSpec{center, a, b, speed, 1.0});
  const auto trajectory = BuildTrajectory(spec, {});
  const SegmentInfo& info = trajectory->segments().at(0);
  EXPECT_EQ(info.kind, "figure_eight");

  double peak_speed = 0.0, peak_acceleration = 0.0, x_min = 0.0, x_max = 0.0;
  for (Time t = info.start_ns; t <= info.end_ns; t += kMs) {
    const Reference ref = trajectory->Sample(t);
    const Eigen::Vector3d d = ref.p_WB - center;
    // Gerono: (y/b)² = (x/a)² (1 − (x/a)²).
    const double xa = d.x() / a, yb = d.y() / b;
    ASSERT_NEAR(yb * yb, xa * xa * (1.0 - xa * xa), 1e-9) << "t_ns " << t;
    ASSERT_NEAR(d.z(), 0.0, 1e-12);
    peak_speed = std::max(peak_speed, ref.v_WB_W.norm());
    peak_acceleration = std::max(peak_acceleration, ref.a_WB_W.norm());
    x_min = std::min(x_min, d.x());
    x_max = std::max(x_max, d.x());
  }
  EXPECT_NEAR(peak_speed, speed, 0.01 * speed);
  EXPECT_LE(peak_acceleration, spec.limits.max_acceleration_mps2 * 1.001);
  EXPECT_NEAR(x_max, a, 1e-6);  // both lobes are flown
  EXPECT_NEAR(x_min, -a, 1e-6);
  const Reference end = trajectory->Sample(info.end_ns);
  EXPECT_TRUE(AtRest(end, 1e-9));
  EXPECT_LT((end.p_WB - center).norm(), 1e-9);

  // Too fast for the acceleration limit: rejected, naming the segment.
  spec.limits.max_acceleration_mps2 = 0.2;
  EXPECT_THROW(BuildTrajectory(spec, {}), std::invalid_argument);
}

// ---- approach ----

TEST(TrajectoryApproach, StopsWithToolTipAtStandoffFromTheSurface) {
  TrajectorySpec spec;
  spec.start = {Eigen::Vector3d(0.0, 0.5, 1.0), Rpy(0.0, 0.0, 0.3)};
  spec.limits.max_speed_mps = 1.0;
  spec.limits.max_acceleration_mps2 = 1.0;
  spec.segments.push_back(HoverSpec{0.2});
  spec.segments.push_back(ApproachSpec{Eigen::Vector3d(2.0, 0.0, 0.0), 0.4, 0.3});
  const TrajectoryContext context = WallContext();
  const auto trajectory = BuildTrajectory(spec, context);
  const SegmentInfo& info = trajectory->segments().at(1);
  EXPECT_EQ(info.kind, "approach");

  const Eigen::Vector3d tip_start = spec.start.p_WB + spec.start.q_WB * context.p_B_tool;
  ASSERT_TRUE(info.approach_target_distance_m.has_value());
  EXPECT_NEAR(*info.approach_target_distance_m, 5.0 - tip_start.x(), 1e-12);
  EXPECT_EQ(info.approach_standoff_m, 0.4);
  EXPECT_LT((info.approach_direction_W - Eigen::Vector3d::UnitX()).norm(), 1e-15);

  const Reference end = trajectory->Sample(info.end_ns);
  const Eigen::Vector3d tip_end = end.p_WB + end.q_WB * context.p_B_tool;
  EXPECT_NEAR(5.0 - tip_end.x(), 0.4, 1e-9);
  EXPECT_NEAR(tip_end.y(), tip_start.y(), 1e-9);
  EXPECT_NEAR(tip_end.z(), tip_start.z(), 1e-9);
  EXPECT_LT(AngleBetween(end.q_WB, spec.start.q_WB), 1e-12);
  EXPECT_TRUE(AtRest(end, 1e-9));

  // The approach speed (below max_speed_mps) is the peak speed.
  double peak_speed = 0.0;
  for (Time t = info.start_ns; t <= info.end_ns; t += kMs) {
    peak_speed = std::max(peak_speed, trajectory->Sample(t).v_WB_W.norm());
  }
  EXPECT_NEAR(peak_speed, 0.3, 1e-4);
}

TEST(TrajectoryApproach, ThrowsWhenTheRayHitsNothingOrThereIsNoQuery) {
  TrajectorySpec spec;
  spec.segments.push_back(HoverSpec{0.2});
  spec.segments.push_back(ApproachSpec{Eigen::Vector3d(-1.0, 0.0, 0.0), 0.4, 0.3});
  try {
    BuildTrajectory(spec, WallContext());
    FAIL() << "a ray away from the wall hits nothing";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("segment 1"), std::string::npos) << e.what();
  }
  EXPECT_THROW(BuildTrajectory(spec, {}), std::invalid_argument);
  // A surface closer than the standoff.
  spec.segments[1] = ApproachSpec{Eigen::Vector3d::UnitX(), 0.4, 0.3};
  TrajectoryContext close = WallContext();
  close.surface_distance = WallAtX(0.6);  // tool tip at x = 0.5
  EXPECT_THROW(BuildTrajectory(spec, close), std::invalid_argument);
}

}  // namespace
}  // namespace tofu::sim
