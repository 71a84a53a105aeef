#include "sim/trajectory.h"

#include <algorithm>
#include <cmath>
#include <memory>
#include <optional>
#include <stdexcept>
#include <string>
#include <string_view>
#include <utility>
#include <variant>
#include <vector>

#include <fmt/format.h>

#include "core/lie.h"
#include "core/units.h"
#include "sim/min_snap.h"

// A trajectory is a sequence of pieces, each a reference over its own time [0, T] that
// starts and ends at rest (v = a = j = 0, ω = α = 0). A primitive of the spec becomes one
// or two pieces (a rest-to-rest transfer onto a curve, then the curve). Rest at every
// junction makes the concatenation C³ in position and C¹ in attitude rate.
//
// - waypoints, line, transfers, approach: min_snap::WaypointPath, a minimum-snap position
//   (Mellinger & Kumar 2011; KKT form of Richter, Bry & Roy 2013) that flies through
//   interior waypoints, with the attitude R_k Exp(s(τ) Log(R_kᵀ R_k+1)) rest-to-rest in
//   rotation at every waypoint (ω, α continuous, zero there).
// - circle, figure_eight: a planar curve f(φ) at constant attitude, φ(t) a ramp-cruise-
//   ramp profile whose septic ramps keep φ̈, φ⃛ continuous, derivatives by the chain rule.
//   The ramps are sized by the acceleration limit (tangential and normal together); the
//   angular limits do not apply since the attitude is held.
// - hover: the pose held at rest.

namespace tofu::sim {
namespace {

using min_snap::PhaseProfile;
using min_snap::PhaseState;

using core::kTwoPi;
/// Closer than this [m] to a curve's entry point, the robot needs no transfer.
constexpr double kOnCurveTolerance_m = 1e-9;

// ---- pieces ----

/// A reference over local time t_s ∈ [0, duration_s()], at rest at both ends.
class Piece {
 public:
  virtual ~Piece() = default;
  virtual double duration_s() const = 0;
  /// Reference at local time t_s, clamped to [0, duration_s()].
  virtual Reference Sample(double t_s) const = 0;
};

/// Holds a pose at rest.
class HoldPiece final : public Piece {
 public:
  HoldPiece(const Waypoint& pose, double duration_s) : duration_s_(duration_s) {
    ref_.p_WB = pose.p_WB;
    ref_.q_WB = core::CanonicalQuat(pose.q_WB.normalized());
  }
  double duration_s() const override { return duration_s_; }
  Reference Sample(double) const override { return ref_; }

 private:
  double duration_s_;
  Reference ref_;
};

/// Minimum-snap position with SO(3) attitude interpolation (waypoints, lines, transfers).
class WaypointPiece final : public Piece {
 public:
  explicit WaypointPiece(min_snap::WaypointPath path) : path_(std::move(path)) {}
  double duration_s() const override { return path_.duration_s(); }
  Reference Sample(double t_s) const override { return path_.Sample(t_s); }

 private:
  min_snap::WaypointPath path_;
};

// ---- curves parametrised by a phase φ ----

/// A point of a curve f(φ) in W and its derivatives with respect to φ.
struct CurvePoint {
  Eigen::Vector3d f;     ///< [m]
  Eigen::Vector3d df;    ///< [m/rad]
  Eigen::Vector3d ddf;   ///< [m/rad²]
  Eigen::Vector3d dddf;  ///< [m/rad³]
};

class Curve {
 public:
  virtual ~Curve() = default;
  virtual CurvePoint At(double phi) const = 0;
};

/// Horizontal circle f(φ) = c + r (cos φ, sin φ, 0); φ grows counter-clockwise from above.
class CircleCurve final : public Curve {
 public:
  CircleCurve(const Eigen::Vector3d& center_W, double radius_m)
      : center_W_(center_W), radius_m_(radius_m) {}
  CurvePoint At(double phi) const override {
    const double c = radius_m_ * std::cos(phi);
    const double s = radius_m_ * std::sin(phi);
    return {center_W_ + Eigen::Vector3d(c, s, 0.0), Eigen::Vector3d(-s, c, 0.0),
            Eigen::Vector3d(-c, -s, 0.0), Eigen::Vector3d(s, -c, 0.0)};
  }

 private:
  Eigen::Vector3d center_W_;
  double radius_m_;
};

/// Horizontal lemniscate of Gerono around c:
/// f(φ) = c + (a sin φ, b sin φ cos φ, 0) = c + (a sin φ, (b/2) sin 2φ, 0).
class GeronoCurve final : public Curve {
 public:
  GeronoCurve(const Eigen::Vector3d& center_W, double half_length_m, double half_width_m)
      : center_W_(center_W), a_(half_length_m), b_(half_width_m) {}
  CurvePoint At(double phi) const override {
    const double s1 = std::sin(phi), c1 = std::cos(phi);
    const double s2 = std::sin(2.0 * phi), c2 = std::cos(2.0 * phi);
    return {center_W_ + Eigen::Vector3d(a_ * s1, 0.5 * b_ * s2, 0.0),
            Eigen::Vector3d(a_ * c1, b_ * c2, 0.0),
            Eigen::Vector3d(-a_ * s1, -2.0 * b_ * s2, 0.0),
            Eigen::Vector3d(-a_ * c1, -4.0 * b_ * c2, 0.0)};
  }
  /// max_φ |f'(φ)| = √(a² + b²), at φ = 0 (both cosines are ±1 there).
  double PeakSpeedPerRate() const { return std::hypot(a_, b_); }

 private:
  Eigen::Vector3d center_W_;
  double a_;
  double b_;
};

/// Motion along f(φ0 + σ φ(t)) by the chain rule (σ = ±1 the direction):
/// v = f'φ̇, a = f''φ̇² + f'φ̈, j = f'''φ̇³ + 3 f''φ̇φ̈ + f'φ⃛.
Reference AlongCurve(const Curve& curve, double phi0, double sign, const PhaseState& phase) {
  const CurvePoint c = curve.At(phi0 + sign * phase.phi);
  const double d1 = sign * phase.rate;
  const double d2 = sign * phase.acceleration;
  const double d3 = sign * phase.jerk;
  Reference ref;
  ref.p_WB = c.f;
  ref.v_WB_W = c.df * d1;
  ref.a_WB_W = c.ddf * (d1 * d1) + c.df * d2;
  ref.j_WB_W = c.dddf * (d1 * d1 * d1) + c.ddf * (3.0 * d1 * d2) + c.df * d3;
  return ref;
}

/// Constant attitude along a curve with a phase profile.
class CurvePiece final : public Piece {
 public:
  CurvePiece(std::unique_ptr<Curve> curve, double phi0, double sign, PhaseProfile profile,
             const Eigen::Quaterniond& q_WB)
      : curve_(std::move(curve)), phi0_(phi0), sign_(sign), profile_(profile),
        q_WB_(core::CanonicalQuat(q_WB.normalized())) {}
  double duration_s() const override { return profile_.duration_s(); }
  Reference Sample(double t_s) const override {
    Reference ref = AlongCurve(*curve_, phi0_, sign_, profile_.At(t_s));
    ref.q_WB = q_WB_;
    return ref;
  }

 private:
  std::unique_ptr<Curve> curve_;
  double phi0_;
  double sign_;
  PhaseProfile profile_;
  Eigen::Quaterniond q_WB_;
};

/// Peak |a| [m/s²] over both ramps of a profile, by dense sampling (the cruise has
/// φ̈ = 0 and is checked separately, from the curve alone).
double PeakRampAcceleration(const Curve& curve, double phi0, double sign,
                            const PhaseProfile& profile) {
  // At least 256 samples per ramp, and 512 per turn the ramp covers.
  const double ramp_angle = 0.5 * profile.cruise_rate * profile.ramp_s;
  const int samples = std::max(256, static_cast<int>(std::ceil(ramp_angle / kTwoPi * 512.0)));
  double peak = 0.0;
  for (int i = 0; i <= samples; ++i) {
    const double tau = static_cast<double>(i) / samples;
    peak = std::max({peak, AlongCurve(curve, phi0, sign, profile.RampUp(tau)).a_WB_W.norm(),
                     AlongCurve(curve, phi0, sign, profile.RampDown(tau)).a_WB_W.norm()});
  }
  return peak;
}

/// Shortest ramp duration [s] (to a relative 1e-6) for which the acceleration of both
/// ramps, tangential and normal together, stays within max_acceleration at the given
/// cruise rate and total angle; nullopt if none below ~10⁶ s. The returned ramp is
/// always one that was checked feasible.
std::optional<double> ShortestRamp(const Curve& curve, double phi0, double sign,
                                   double rate, double total_rad, double max_acceleration) {
  auto feasible = [&](double ramp_s) {
    const PhaseProfile profile{rate, ramp_s, total_rad / rate - ramp_s};
    return PeakRampAcceleration(curve, phi0, sign, profile) <= max_acceleration;
  };
  double lo = 0.0;
  double hi = 1e-3;
  while (!feasible(hi)) {
    lo = hi;
    hi *= 2.0;
    if (hi > 1e6) return std::nullopt;
  }
  while (hi - lo > 1e-6 * hi) {
    const double mid = 0.5 * (lo + hi);
    (feasible(mid) ? hi : lo) = mid;
  }
  return hi;
}

/// Phase profile covering total_rad at up to cruise_rate [rad/s] within the acceleration
/// limit. If the angle is too short for both ramps at that rate, the cruise rate is
/// lowered (bisection) to the highest one whose ramps fit. nullopt if no ramp works.
std::optional<PhaseProfile> PlanPhase(const Curve& curve, double phi0, double sign,
                                      double cruise_rate, double total_rad,
                                      double max_acceleration) {
  auto ramp_at = [&](double rate) {
    return ShortestRamp(curve, phi0, sign, rate, total_rad, max_acceleration);
  };
  std::optional<double> ramp = ramp_at(cruise_rate);
  if (!ramp) return std::nullopt;
  double rate = cruise_rate;
  if (rate * *ramp > total_rad) {
    double lo = 0.0;
    double hi = cruise_rate;
    for (int i = 0; i < 40; ++i) {
      const double mid = 0.5 * (lo + hi);
      const std::optional<double> r = ramp_at(mid);
      (r && mid * *r <= total_rad ? lo : hi) = mid;
    }
    rate = lo;
    ramp = ramp_at(rate);
    if (rate <= 0.0 || !ramp) return std::nullopt;
  }
  return PhaseProfile{rate, *ramp, std::max(0.0, total_rad / rate - *ramp)};
}

// ---- the trajectory ----

/// A piece placed on the trajectory's time axis.
struct PlacedPiece {
  core::Time start_ns = 0;
  std::unique_ptr<Piece> piece;
};

class PiecewiseTrajectory final : public Trajectory {
 public:
  PiecewiseTrajectory(std::vector<PlacedPiece> pieces, std::vector<SegmentInfo> segments,
                      const Reference& start, const Reference& end, core::Time duration_ns)
      : pieces_(std::move(pieces)), segments_(std::move(segments)), start_(start), end_(end),
        duration_ns_(duration_ns) {}

  core::Time duration_ns() const override { return duration_ns_; }
  const std::vector<SegmentInfo>& segments() const override { return segments_; }

  Reference Sample(core::Time t_ns) const override {
    if (t_ns < 0 || pieces_.empty()) return t_ns < duration_ns_ ? start_ : end_;
    if (t_ns >= duration_ns_) return end_;
    // Last piece starting at or before t: zero-length pieces share their start with the
    // next one, so they are never chosen.
    const auto next = std::upper_bound(
        pieces_.begin(), pieces_.end(), t_ns,
        [](core::Time t, const PlacedPiece& placed) { return t < placed.start_ns; });
    const PlacedPiece& placed = *(next - 1);
    return placed.piece->Sample(core::TimeToSeconds(t_ns - placed.start_ns));
  }

 private:
  std::vector<PlacedPiece> pieces_;
  std::vector<SegmentInfo> segments_;
  Reference start_;  ///< returned before t = 0
  Reference end_;    ///< returned from duration_ns() on
  core::Time duration_ns_;
};

/// The reference at rest at a pose.
Reference AtRest(const Waypoint& pose) {
  Reference ref;
  ref.p_WB = pose.p_WB;
  ref.q_WB = core::CanonicalQuat(pose.q_WB.normalized());
  return ref;
}

bool IsUsableQuaternion(const Eigen::Quaterniond& q) {
  return q.coeffs().allFinite() && q.norm() > 1e-6;
}

/// Turns the spec's primitives into placed pieces, tracking the pose where each ends.
class Builder {
 public:
  Builder(const TrajectorySpec& spec, const TrajectoryContext& context)
      : limits_(spec.limits), context_(context) {
    CheckLimits();
    if (!spec.start.p_WB.allFinite() || !IsUsableQuaternion(spec.start.q_WB)) {
      throw std::invalid_argument("trajectory start: position and quaternion must be finite, "
                                  "the quaternion non-zero");
    }
    current_ = {spec.start.p_WB, core::CanonicalQuat(spec.start.q_WB.normalized())};
  }

  std::unique_ptr<Trajectory> Build(const TrajectorySpec& spec) {
    const Reference start = AtRest(current_);
    for (size_t i = 0; i < spec.segments.size(); ++i) {
      index_ = i;
      SegmentInfo info;
      info.start_ns = now_ns_;
      std::visit([&](const auto& primitive) { Add(primitive, info); }, spec.segments[i]);
      info.end_ns = now_ns_;
      segments_.push_back(std::move(info));
    }
    return std::make_unique<PiecewiseTrajectory>(std::move(pieces_), std::move(segments_),
                                                 start, AtRest(current_), now_ns_);
  }

 private:
  [[noreturn]] void Fail(std::string_view kind, const std::string& message) const {
    throw std::invalid_argument(
        fmt::format("trajectory segment {} ({}): {}", index_, kind, message));
  }

  void CheckLimits() const {
    const std::pair<const char*, double> limits[] = {
        {"max_speed_mps", limits_.max_speed_mps},
        {"max_acceleration_mps2", limits_.max_acceleration_mps2},
        {"max_angular_rate_radps", limits_.max_angular_rate_radps},
        {"max_angular_acceleration_radps2", limits_.max_angular_acceleration_radps2}};
    for (const auto& [name, value] : limits) {
      if (!(std::isfinite(value) && value > 0.0)) {
        throw std::invalid_argument(
            fmt::format("trajectory limits: {} must be positive and finite, got {}", name, value));
      }
    }
  }

  /// Appends a piece and moves the current pose to its end.
  void Append(std::unique_ptr<Piece> piece) {
    const core::Time duration_ns = core::SecondsToTime(piece->duration_s());
    const Reference end = piece->Sample(piece->duration_s());
    pieces_.push_back({now_ns_, std::move(piece)});
    now_ns_ += duration_ns;
    current_ = {end.p_WB, end.q_WB};
  }

  /// Rest-to-rest minimum-snap path from the current pose through `waypoints`.
  void AppendPath(const std::vector<Waypoint>& waypoints, const DynamicLimits& limits) {
    Append(std::make_unique<WaypointPiece>(min_snap::PlanWaypoints(current_, waypoints, limits)));
  }

  /// Rest-to-rest straight line to p_W keeping the attitude, unless already there.
  void TransferTo(const Eigen::Vector3d& p_W) {
    if ((p_W - current_.p_WB).norm() < kOnCurveTolerance_m) return;
    AppendPath({Waypoint{p_W, current_.q_WB}}, limits_);
  }

  void Add(const HoverSpec& spec, SegmentInfo& info) {
    info.kind = "hover";
    if (!(std::isfinite(spec.duration_s) && spec.duration_s >= 0.0)) {
      Fail(info.kind, fmt::format("duration_s must be >= 0, got {}", spec.duration_s));
    }
    Append(std::make_unique<HoldPiece>(current_, spec.duration_s));
  }

  void Add(const WaypointsSpec& spec, SegmentInfo& info) {
    info.kind = "waypoints";
    if (spec.waypoints.empty()) Fail(info.kind, "needs at least one waypoint");
    for (size_t k = 0; k < spec.waypoints.size(); ++k) {
      const Waypoint& w = spec.waypoints[k];
      if (!w.p_WB.allFinite() || !IsUsableQuaternion(w.q_WB)) {
        Fail(info.kind, fmt::format("waypoint {} has a non-finite position or a zero or "
                                    "non-finite quaternion", k));
      }
    }
    AppendPath(spec.waypoints, limits_);
  }

  void Add(const LineSpec& spec, SegmentInfo& info) {
    info.kind = "line";
    const Eigen::Quaterniond q_end = spec.q_WB.value_or(current_.q_WB);
    if (!spec.to_W.allFinite() || !IsUsableQuaternion(q_end)) {
      Fail(info.kind, "to_W and q_WB must be finite, q_WB non-zero");
    }
    AppendPath({Waypoint{spec.to_W, q_end}}, limits_);
  }

  void Add(const CircleSpec& spec, SegmentInfo& info) {
    info.kind = "circle";
    if (!spec.center_W.allFinite()) Fail(info.kind, "center_W must be finite");
    if (!(spec.radius_m > 0.0 && std::isfinite(spec.radius_m))) {
      Fail(info.kind, fmt::format("radius_m must be > 0, got {}", spec.radius_m));
    }
    CheckCruise(info.kind, spec.speed_mps, spec.laps);
    const double centripetal = spec.speed_mps * spec.speed_mps / spec.radius_m;
    if (centripetal > limits_.max_acceleration_mps2) {
      Fail(info.kind, fmt::format("centripetal acceleration speed_mps^2 / radius_m = {:.4g} "
                                  "m/s^2 exceeds max_acceleration_mps2 = {:.4g}",
                                  centripetal, limits_.max_acceleration_mps2));
    }

    // Enter at the circle point closest to the robot, in the plane z = center_W.z.
    Eigen::Vector3d radial = current_.p_WB - spec.center_W;
    radial.z() = 0.0;
    const double phi0 = radial.norm() > kOnCurveTolerance_m ? std::atan2(radial.y(), radial.x())
                                                            : 0.0;
    auto curve = std::make_unique<CircleCurve>(spec.center_W, spec.radius_m);
    TransferTo(curve->At(phi0).f);
    AppendCurve(info.kind, std::move(curve), phi0, spec.clockwise ? -1.0 : 1.0,
                spec.speed_mps / spec.radius_m, spec.laps);
  }

  void Add(const FigureEightSpec& spec, SegmentInfo& info) {
    info.kind = "figure_eight";
    if (!spec.center_W.allFinite()) Fail(info.kind, "center_W must be finite");
    if (!(spec.half_length_m > 0.0 && std::isfinite(spec.half_length_m) &&
          spec.half_width_m >= 0.0 && std::isfinite(spec.half_width_m))) {
      Fail(info.kind, fmt::format("needs half_length_m > 0 and half_width_m >= 0, got {} and {}",
                                  spec.half_length_m, spec.half_width_m));
    }
    CheckCruise(info.kind, spec.speed_mps, spec.laps);
    auto curve =
        std::make_unique<GeronoCurve>(spec.center_W, spec.half_length_m, spec.half_width_m);
    // Cruise rate such that the peak speed, at the crossing φ = 0 mod π, is speed_mps.
    const double rate = spec.speed_mps / curve->PeakSpeedPerRate();

    // At constant rate a = f''φ̇²; its peak over one turn must respect the limit.
    double peak_ddf = 0.0;
    constexpr int kSamples = 4096;
    for (int i = 0; i < kSamples; ++i) {
      peak_ddf = std::max(peak_ddf, curve->At(kTwoPi * i / kSamples).ddf.norm());
    }
    const double peak_acceleration = peak_ddf * rate * rate;
    if (peak_acceleration > limits_.max_acceleration_mps2) {
      Fail(info.kind, fmt::format("peak acceleration {:.4g} m/s^2 at speed_mps = {:.4g} exceeds "
                                  "max_acceleration_mps2 = {:.4g}",
                                  peak_acceleration, spec.speed_mps,
                                  limits_.max_acceleration_mps2));
    }
    // The curve starts at its centre, φ = 0.
    TransferTo(curve->At(0.0).f);
    AppendCurve(info.kind, std::move(curve), 0.0, 1.0, rate, spec.laps);
  }

  void Add(const ApproachSpec& spec, SegmentInfo& info) {
    info.kind = "approach";
    const double norm = spec.direction_W.norm();
    if (!(std::isfinite(norm) && norm > 1e-9)) Fail(info.kind, "direction_W must be non-zero");
    if (!(std::isfinite(spec.standoff_m) && spec.standoff_m >= 0.0)) {
      Fail(info.kind, fmt::format("standoff_m must be >= 0, got {}", spec.standoff_m));
    }
    if (!(std::isfinite(spec.speed_mps) && spec.speed_mps > 0.0)) {
      Fail(info.kind, fmt::format("speed_mps must be > 0, got {}", spec.speed_mps));
    }
    if (!context_.surface_distance) Fail(info.kind, "no surface distance query in the context");

    // Ray from the tool tip p_WB + R_WB p_B_tool along the direction.
    const Eigen::Vector3d direction_W = spec.direction_W / norm;
    const Eigen::Vector3d tip_W = current_.p_WB + current_.q_WB * context_.p_B_tool;
    const std::optional<double> distance = context_.surface_distance(tip_W, direction_W);
    if (!distance) {
      Fail(info.kind, fmt::format("the ray from the tool tip ({:.3f}, {:.3f}, {:.3f}) along "
                                  "({:.3f}, {:.3f}, {:.3f}) hits no surface",
                                  tip_W.x(), tip_W.y(), tip_W.z(), direction_W.x(),
                                  direction_W.y(), direction_W.z()));
    }
    if (!(*distance >= spec.standoff_m)) {
      Fail(info.kind, fmt::format("the surface is {:.4g} m away, closer than standoff_m = {:.4g}",
                                  *distance, spec.standoff_m));
    }
    info.approach_target_distance_m = *distance;
    info.approach_standoff_m = spec.standoff_m;
    info.approach_direction_W = direction_W;

    // Rest-to-rest line, peak speed capped by the approach speed.
    DynamicLimits limits = limits_;
    limits.max_speed_mps = std::min(spec.speed_mps, limits_.max_speed_mps);
    const Eigen::Vector3d target_W = current_.p_WB + direction_W * (*distance - spec.standoff_m);
    AppendPath({Waypoint{target_W, current_.q_WB}}, limits);
  }

  /// Common checks of a curve's cruise speed and lap count.
  void CheckCruise(std::string_view kind, double speed_mps, double laps) const {
    if (!(std::isfinite(speed_mps) && speed_mps > 0.0)) {
      Fail(kind, fmt::format("speed_mps must be > 0, got {}", speed_mps));
    }
    if (speed_mps > limits_.max_speed_mps) {
      Fail(kind, fmt::format("speed_mps = {:.4g} exceeds max_speed_mps = {:.4g}", speed_mps,
                             limits_.max_speed_mps));
    }
    if (!(std::isfinite(laps) && laps > 0.0)) {
      Fail(kind, fmt::format("laps must be > 0, got {}", laps));
    }
  }

  /// laps · 2π along the curve from φ0 in direction σ, attitude held.
  void AppendCurve(std::string_view kind, std::unique_ptr<Curve> curve, double phi0, double sign,
                   double cruise_rate, double laps) {
    const std::optional<PhaseProfile> profile = PlanPhase(
        *curve, phi0, sign, cruise_rate, laps * kTwoPi, limits_.max_acceleration_mps2);
    if (!profile) {
      Fail(kind, "no speed ramp keeps the acceleration within max_acceleration_mps2");
    }
    Append(std::make_unique<CurvePiece>(std::move(curve), phi0, sign, *profile, current_.q_WB));
  }

  DynamicLimits limits_;
  const TrajectoryContext& context_;
  Waypoint current_;
  core::Time now_ns_ = 0;
  size_t index_ = 0;
  std::vector<PlacedPiece> pieces_;
  std::vector<SegmentInfo> segments_;
};

}  // namespace

std::unique_ptr<Trajectory> BuildTrajectory(const TrajectorySpec& spec,
                                            const TrajectoryContext& context) {
  return Builder(spec, context).Build(spec);
}

}  // namespace tofu::sim
