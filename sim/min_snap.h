#pragma once
// Private to sim/ (trajectory.cc builds on it, tests/trajectory_test.cc checks it):
// minimum-snap piecewise polynomials through waypoints (Mellinger & Kumar, ICRA 2011),
// solved as an equality-constrained QP through its KKT system (Richter, Bry & Roy,
// ISRR 2013, Sec. 3) with optimised segment-time ratios; the rest-to-rest septic step and
// the ramp-cruise-ramp phase profile built on it; and the waypoint path that combines a
// minimum-snap position with SO(3) attitude interpolation.

#include <span>
#include <string>
#include <vector>

#include <Eigen/Core>
#include <Eigen/Geometry>

#include "core/option_fields.h"
#include "sim/trajectory.h"

namespace tofu::sim::min_snap {

// ---- septic rest-to-rest step ----

/// s(τ) = 35τ⁴ − 84τ⁵ + 70τ⁶ − 20τ⁷ and its derivatives with respect to τ. s goes from 0 to
/// 1 on τ ∈ [0, 1] with zero first to third derivatives at both ends; τ is clamped there.
struct SepticStep {
  double s = 0.0;
  double ds = 0.0;    ///< s'(τ) = 140 τ³ (1 − τ)³
  double dds = 0.0;   ///< s''(τ) = 420 τ² (1 − τ)² (1 − 2τ)
  double ddds = 0.0;  ///< s'''(τ)
};
SepticStep EvaluateSepticStep(double tau);

/// ∫₀^τ s(u) du = 7τ⁵ − 14τ⁶ + 10τ⁷ − 2.5τ⁸ (= 1/2 at τ = 1); τ clamped to [0, 1].
double SepticStepIntegral(double tau);

/// max s' = s'(1/2) = 35/16.
inline constexpr double kSepticPeakRate = 35.0 / 16.0;
/// max |s''| = 16.8/√5, at τ = (1 ∓ 1/√5)/2.
inline constexpr double kSepticPeakAcceleration = 7.5131884043992930;

/// Shortest duration [s] of a septic rest-to-rest move over `distance` (any unit u) with
/// peak rate <= max_rate [u/s] and peak acceleration <= max_acceleration [u/s²]; both
/// limits positive. Zero for zero distance.
double SepticRestToRestDuration(double distance, double max_rate, double max_acceleration);

// ---- ramp-cruise-ramp profile of a scalar phase ----

/// A scalar phase (an angle along a curve, or an arc length) and its first three time
/// derivatives, in the phase's unit u: [u, u/s, u/s², u/s³].
struct PhaseState {
  double phi = 0.0;
  double rate = 0.0;
  double acceleration = 0.0;
  double jerk = 0.0;
};

/// Phase φ(t) from 0 to total(): the rate ramps from 0 to the cruise rate as a septic step
/// over ramp_s (so φ̈ and φ⃛ vanish at both ends of a ramp), holds for cruise_s, then ramps
/// back to 0. Each ramp covers cruise_rate · ramp_s / 2 (∫₀¹ s = 1/2); the peak φ̈ is
/// cruise_rate · s'_max / ramp_s. Requires ramp_s > 0.
struct PhaseProfile {
  double cruise_rate = 0.0;  ///< [u/s]
  double ramp_s = 0.0;
  double cruise_s = 0.0;

  double duration_s() const { return 2.0 * ramp_s + cruise_s; }
  double total() const { return cruise_rate * (ramp_s + cruise_s); }

  /// First ramp at τ = t / ramp_s: φ = ω T ∫s, φ̇ = ω s, φ̈ = ω s'/T, φ⃛ = ω s''/T².
  PhaseState RampUp(double tau) const;
  /// Last ramp, mirrored, at u = (duration − t) / ramp_s.
  PhaseState RampDown(double u) const;
  /// State at t_s, clamped to [0, duration_s()].
  PhaseState At(double t_s) const;
  /// The time [s] at which φ reaches phi (clamped to [0, total()]); φ is monotonic.
  double TimeOf(double phi) const;
};

// ---- piecewise polynomial ----

/// A 3-D piecewise polynomial of degree 7. Segment k lasts durations_s()[k] = T_k and is
/// stored in normalised time τ = (t − t_k) / T_k ∈ [0, 1], p_k(τ) = Σᵢ cᵢ τⁱ, which keeps
/// the coefficients O(1) whatever the segment duration (conditioning of the KKT system).
class PiecewisePolynomial {
 public:
  static constexpr int kDegree = 7;
  static constexpr int kNumCoefficients = kDegree + 1;
  /// Row i holds the 3-D coefficient of τⁱ.
  using Coefficients = Eigen::Matrix<double, kNumCoefficients, 3>;

  PiecewisePolynomial() = default;
  /// durations_s: positive, one per segment; coefficients: same count.
  PiecewisePolynomial(std::vector<double> durations_s, std::vector<Coefficients> coefficients);

  int num_segments() const { return static_cast<int>(durations_s_.size()); }
  const std::vector<double>& durations_s() const { return durations_s_; }
  const std::vector<Coefficients>& coefficients() const { return coefficients_; }
  /// Start time [s] of segment k; k = num_segments() gives the total duration.
  double segment_start_s(int k) const { return starts_s_[k]; }
  double duration_s() const { return starts_s_.back(); }

  /// Index of the segment holding t_s (the later one at a junction), clamped.
  int SegmentAt(double t_s) const;
  /// d^r p / dt^r at t_s [m/s^r], 0 <= r <= 7; t_s clamped to [0, duration_s()].
  Eigen::Vector3d Evaluate(double t_s, int derivative = 0) const;
  /// Same, of segment k at its normalised time τ (one-sided at the segment ends).
  Eigen::Vector3d EvaluateSegment(int k, double tau, int derivative) const;
  /// Exact ∫ |d^r p / dt^r|² dt over the whole polynomial (r = 4: integrated snap).
  double IntegratedSquaredDerivative(int derivative) const;
  /// The same path traversed `factor` times slower (every T_k multiplied by factor > 0).
  PiecewisePolynomial TimeScaled(double factor) const;

 private:
  std::vector<double> durations_s_;
  std::vector<double> starts_s_ = {0.0};
  std::vector<Coefficients> coefficients_;
};

/// What the minimum-derivative QP minimises and which continuity it imposes.
struct MinimumDerivativeOptions {
  /// r in Σ_k ∫ |d^r p/dt^r|² dt: 4 = snap (Mellinger & Kumar), 3 = jerk.
  int cost_derivative = 4;
  /// Derivatives 1..this are constrained continuous at interior points (1..6). The
  /// minimum-snap optimum is C⁶ anyway (its natural conditions); imposing 4 leaves
  /// 2(N − 1) free coefficients per axis for the QP to optimise.
  int continuity_derivative = 4;

  /// Each option's key and range (cost_derivative 1..4, continuity_derivative 1..6).
  static std::span<const core::OptionField<MinimumDerivativeOptions>> Fields();
  /// The fields within their ranges; otherwise false, *why = "<key>: <problem>".
  bool IsValid(std::string* why = nullptr) const;
};

/// Minimises the cost of degree-7 segments through `points` (segment k from points[k] to
/// points[k+1] in durations_s[k] seconds) at rest (v = a = j = 0) at the first and last
/// point, by solving the KKT system [H Aᵀ; A 0][c; λ] = [0; b] of the equality-
/// constrained QP min cᵀHc s.t. Ac = b (Richter, Bry & Roy 2013, eq. 3), one right-hand
/// side per axis. If cost_gradient is given, it receives ∂J/∂T_k of the optimal cost
/// J = Σ ∫ |d^r p/dt^r|² dt [m²/s^(2r) per s], by the envelope theorem. Requires
/// points.size() == durations_s.size() + 1 >= 2 and positive durations; throws
/// std::invalid_argument when !options.IsValid().
PiecewisePolynomial SolveMinimumDerivative(const std::vector<Eigen::Vector3d>& points,
                                           const std::vector<double>& durations_s,
                                           const MinimumDerivativeOptions& options = {},
                                           std::vector<double>* cost_gradient = nullptr);

/// Segment durations with the same total that (locally) minimise the scale-free minimum-
/// snap cost J(T)·(ΣT)⁷, by gradient descent on log T (the time allocation of Mellinger
/// & Kumar 2011, Sec. IV). Bad ratios make the C⁶ spline swing far past the waypoints;
/// optimised ones follow the polyline closely. Durations stay >= 1 % of the mean.
std::vector<double> OptimizeSegmentRatios(const std::vector<Eigen::Vector3d>& points,
                                          std::vector<double> durations_s);

// ---- waypoint path: minimum-snap position + SO(3) interpolation ----

/// Pose reference through waypoints. Position: minimum snap through all points, at rest at
/// the first and last only (it flies through interior points). Attitude on segment k:
/// R(t) = R_k Exp(s(τ) φ_k), φ_k = Log(R_kᵀ R_{k+1}), s the septic step, so
/// ω_B = ṡ φ_k and α_B = s̈ φ_k (φ_k is the same vector in the rotating frame since it
/// commutes with Exp(s φ_k)). The attitude is rest-to-rest at every waypoint (ω = α = 0
/// there), which keeps ω and α continuous while the position does not stop.
class WaypointPath {
 public:
  WaypointPath(PiecewisePolynomial position, std::vector<Eigen::Quaterniond> q_WB);

  double duration_s() const { return position_.duration_s(); }
  const PiecewisePolynomial& position() const { return position_; }
  /// Time [s] at which the path passes through point k (0 = start).
  double waypoint_time_s(int k) const { return position_.segment_start_s(k); }
  /// Reference at t_s, clamped to [0, duration_s()].
  Reference Sample(double t_s) const;

 private:
  PiecewisePolynomial position_;
  std::vector<Eigen::Quaterniond> q_WB_;          ///< one per point
  std::vector<Eigen::Vector3d> rotation_vector_;  ///< φ_k [rad], one per segment
};

/// Plans start → waypoints[0] → ... with the limits. Segment times: first when a smooth
/// rest-to-rest motion along the polyline's arc length (speed ramps within
/// max_acceleration_mps2 up to max_speed_mps) passes each waypoint, then their ratios are
/// optimised for snap (OptimizeSegmentRatios), and each is raised to at least the rest-
/// to-rest time of the segment's rotation and kMinimumSegmentDuration_s. The minimum-snap
/// polynomial is solved, its peak speed and acceleration measured by dense sampling and
/// all times scaled by one factor so that the most binding of the four limits is just
/// met. Uniform scaling keeps the minimum-snap solution (the cost scales by a constant),
/// so one rescale is exact; it is verified once more. Requires at least one waypoint and
/// positive limits.
WaypointPath PlanWaypoints(const Waypoint& start, const std::vector<Waypoint>& waypoints,
                           const DynamicLimits& limits);

/// Floor on a segment's allocated duration [s] (a segment that neither moves nor rotates).
inline constexpr double kMinimumSegmentDuration_s = 0.1;

}  // namespace tofu::sim::min_snap
