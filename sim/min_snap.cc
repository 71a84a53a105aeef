#include "sim/min_snap.h"

#include <algorithm>
#include <cassert>
#include <cmath>
#include <stdexcept>
#include <utility>

#include <Eigen/SparseCore>
#include <Eigen/SparseLU>

#include "core/lie.h"

namespace tofu::sim::min_snap {
namespace {

constexpr int kN = PiecewisePolynomial::kNumCoefficients;

/// i! / (i − r)!: the factor of τ^(i−r) in d^r/dτ^r τⁱ (0 if r > i).
double FallingFactorial(int i, int r) {
  if (r > i) return 0.0;
  double f = 1.0;
  for (int m = i - r + 1; m <= i; ++m) f *= m;
  return f;
}

/// Row of d^r/dτ^r [1, τ, …, τ⁷] at τ.
Eigen::Matrix<double, 1, kN> DerivativeRow(int r, double tau) {
  Eigen::Matrix<double, 1, kN> row = Eigen::Matrix<double, 1, kN>::Zero();
  for (int i = r; i < kN; ++i) row(i) = FallingFactorial(i, r) * std::pow(tau, i - r);
  return row;
}

/// Q_r with cᵀQ_r c = ∫₀¹ (d^r p/dτ^r)² dτ: Q_ij = i!/(i−r)! j!/(j−r)! / (i + j − 2r + 1).
Eigen::Matrix<double, kN, kN> CostMatrix(int r) {
  Eigen::Matrix<double, kN, kN> q = Eigen::Matrix<double, kN, kN>::Zero();
  for (int i = r; i < kN; ++i) {
    for (int j = r; j < kN; ++j) {
      q(i, j) = FallingFactorial(i, r) * FallingFactorial(j, r) / (i + j - 2 * r + 1);
    }
  }
  return q;
}

}  // namespace

// ---- septic step ----

SepticStep EvaluateSepticStep(double tau) {
  const double t = std::clamp(tau, 0.0, 1.0);
  const double u = 1.0 - t;
  SepticStep step;
  step.s = t * t * t * t * (35.0 + t * (-84.0 + t * (70.0 - 20.0 * t)));
  step.ds = 140.0 * t * t * t * u * u * u;
  step.dds = 420.0 * t * t * u * u * (1.0 - 2.0 * t);
  // d/dτ [420 τ²(1−τ)²(1−2τ)] = 840 τ (1−τ) (1 − 5τ + 5τ²).
  step.ddds = 840.0 * t * u * (1.0 - 5.0 * t + 5.0 * t * t);
  return step;
}

double SepticStepIntegral(double tau) {
  const double t = std::clamp(tau, 0.0, 1.0);
  return t * t * t * t * t * (7.0 + t * (-14.0 + t * (10.0 - 2.5 * t)));
}

double SepticRestToRestDuration(double distance, double max_rate, double max_acceleration) {
  // Over T the step reaches rate d s'/T and acceleration d s''/T².
  const double d = std::abs(distance);
  return std::max(d * kSepticPeakRate / max_rate,
                  std::sqrt(d * kSepticPeakAcceleration / max_acceleration));
}

// ---- phase profile ----

PhaseState PhaseProfile::RampUp(double tau) const {
  const SepticStep step = EvaluateSepticStep(tau);
  const double w = cruise_rate;
  return {w * ramp_s * SepticStepIntegral(tau), w * step.s, w * step.ds / ramp_s,
          w * step.dds / (ramp_s * ramp_s)};
}

PhaseState PhaseProfile::RampDown(double u) const {
  const SepticStep step = EvaluateSepticStep(u);
  const double w = cruise_rate;
  return {total() - w * ramp_s * SepticStepIntegral(u), w * step.s, -w * step.ds / ramp_s,
          w * step.dds / (ramp_s * ramp_s)};
}

PhaseState PhaseProfile::At(double t_s) const {
  const double t = std::clamp(t_s, 0.0, duration_s());
  if (t < ramp_s) return RampUp(t / ramp_s);
  if (t > ramp_s + cruise_s) return RampDown((duration_s() - t) / ramp_s);
  return {cruise_rate * (0.5 * ramp_s + (t - ramp_s)), cruise_rate, 0.0, 0.0};
}

double PhaseProfile::TimeOf(double phi) const {
  const double ramp_phase = 0.5 * cruise_rate * ramp_s;
  const double x = std::clamp(phi, 0.0, total());
  // Ramps by bisection on the monotonic ∫s, mirrored for the last one.
  auto ramp_time = [&](double covered) {
    double lo = 0.0, hi = 1.0;
    for (int i = 0; i < 60; ++i) {
      const double mid = 0.5 * (lo + hi);
      (cruise_rate * ramp_s * SepticStepIntegral(mid) < covered ? lo : hi) = mid;
    }
    return 0.5 * (lo + hi) * ramp_s;
  };
  if (x <= ramp_phase) return ramp_time(x);
  if (x >= total() - ramp_phase) return duration_s() - ramp_time(total() - x);
  return ramp_s + (x - ramp_phase) / cruise_rate;
}

// ---- piecewise polynomial ----

PiecewisePolynomial::PiecewisePolynomial(std::vector<double> durations_s,
                                         std::vector<Coefficients> coefficients)
    : durations_s_(std::move(durations_s)), coefficients_(std::move(coefficients)) {
  assert(durations_s_.size() == coefficients_.size() && !durations_s_.empty());
  for (double t : durations_s_) {
    assert(t > 0.0);
    starts_s_.push_back(starts_s_.back() + t);
  }
}

int PiecewisePolynomial::SegmentAt(double t_s) const {
  const auto it = std::upper_bound(starts_s_.begin() + 1, starts_s_.end() - 1, t_s);
  return static_cast<int>(it - (starts_s_.begin() + 1));
}

Eigen::Vector3d PiecewisePolynomial::Evaluate(double t_s, int derivative) const {
  const int k = SegmentAt(t_s);
  const double tau = std::clamp((t_s - starts_s_[k]) / durations_s_[k], 0.0, 1.0);
  return EvaluateSegment(k, tau, derivative);
}

Eigen::Vector3d PiecewisePolynomial::EvaluateSegment(int k, double tau, int derivative) const {
  // d^r p/dt^r = T_k^(−r) d^r p/dτ^r.
  const Eigen::Vector3d d_dtau = (DerivativeRow(derivative, tau) * coefficients_[k]).transpose();
  return d_dtau / std::pow(durations_s_[k], derivative);
}

double PiecewisePolynomial::IntegratedSquaredDerivative(int derivative) const {
  // ∫₀^T (d^r p/dt^r)² dt = T^(1−2r) ∫₀¹ (d^r p/dτ^r)² dτ.
  const Eigen::Matrix<double, kN, kN> q = CostMatrix(derivative);
  double cost = 0.0;
  for (int k = 0; k < num_segments(); ++k) {
    const Coefficients& c = coefficients_[k];
    cost += (c.transpose() * q * c).trace() * std::pow(durations_s_[k], 1 - 2 * derivative);
  }
  return cost;
}

PiecewisePolynomial PiecewisePolynomial::TimeScaled(double factor) const {
  std::vector<double> durations = durations_s_;
  for (double& t : durations) t *= factor;
  return PiecewisePolynomial(std::move(durations), coefficients_);
}

// ---- minimum-derivative QP ----

std::span<const core::OptionField<MinimumDerivativeOptions>> MinimumDerivativeOptions::Fields() {
  using F = core::OptionField<MinimumDerivativeOptions>;
  using O = MinimumDerivativeOptions;
  static const F kFields[] = {
      // Degree-7 segments: snap (4) is the highest derivative the rest conditions leave free.
      F::Integer("cost_derivative", &O::cost_derivative, 1, 4)
          .Doc("derivative r whose squared norm the trajectory minimises: 4 = snap, 3 = jerk"),
      F::Integer("continuity_derivative", &O::continuity_derivative, 1, 6)
          .Doc("derivatives 1..this are constrained continuous at interior points"),
  };
  return kFields;
}

bool MinimumDerivativeOptions::IsValid(std::string* why) const {
  return core::CheckOptionFields<MinimumDerivativeOptions>(*this, Fields(), why);
}

namespace {

// The KKT system [σH ρAᵀ; ρA 0][c; μ] = [0; b] of the QP, before equilibration: the matrix
// as triplets (duplicates summed), one right-hand side per axis.
struct KktSystem {
  std::vector<Eigen::Triplet<double>> entries;
  Eigen::MatrixXd rhs;
  int size = 0;
  int first_continuity_row = 0;  ///< the first row of the continuity constraints
};

KktSystem BuildKktSystem(const std::vector<Eigen::Vector3d>& points,
                         const std::vector<double>& durations_s,
                         const Eigen::Matrix<double, kN, kN>& q, int r_cost, int r_cont) {
  const int num_segments = static_cast<int>(durations_s.size());
  const int num_variables = kN * num_segments;
  // Positions at both ends of each segment, v = a = j = 0 at both ends of the path,
  // derivatives 1..r_cont continuous at each interior point.
  const int num_constraints = 2 * num_segments + 6 + r_cont * (num_segments - 1);
  KktSystem kkt;
  kkt.size = num_variables + num_constraints;
  kkt.rhs = Eigen::MatrixXd::Zero(kkt.size, 3);
  std::vector<Eigen::Triplet<double>>& entries = kkt.entries;
  Eigen::MatrixXd& rhs = kkt.rhs;

  // Hessian: block k is σ T_k^(1−2r) Q_r (see IntegratedSquaredDerivative).
  const double t_min = *std::min_element(durations_s.begin(), durations_s.end());
  for (int k = 0; k < num_segments; ++k) {
    const double weight = std::pow(t_min / durations_s[k], 2 * r_cost - 1);
    for (int i = 0; i < kN; ++i) {
      for (int j = 0; j < kN; ++j) {
        if (q(i, j) != 0.0) entries.emplace_back(kN * k + i, kN * k + j, weight * q(i, j));
      }
    }
  }

  // Constraint rows A (and Aᵀ); positions relative to points[0] for conditioning.
  int row = num_variables;
  auto add_row = [&](int segment, const Eigen::Matrix<double, 1, kN>& a) {
    for (int i = 0; i < kN; ++i) {
      if (a(i) == 0.0) continue;
      entries.emplace_back(row, kN * segment + i, a(i));
      entries.emplace_back(kN * segment + i, row, a(i));
    }
  };
  for (int k = 0; k < num_segments; ++k) {
    add_row(k, DerivativeRow(0, 0.0));
    rhs.row(row++) = (points[k] - points[0]).transpose();
    add_row(k, DerivativeRow(0, 1.0));
    rhs.row(row++) = (points[k + 1] - points[0]).transpose();
  }
  for (int r = 1; r <= 3; ++r) {
    add_row(0, DerivativeRow(r, 0.0));
    ++row;
    add_row(num_segments - 1, DerivativeRow(r, 1.0));
    ++row;
  }
  // ρ (d^r p_k/dt^r at its end − d^r p_k+1/dt^r at its start) = 0, in normalised time:
  // (T/T_k)^r p_k^(r)(τ=1) − (T/T_k+1)^r p_k+1^(r)(τ=0) = 0.
  kkt.first_continuity_row = row;
  for (int k = 0; k + 1 < num_segments; ++k) {
    const double t_short = std::min(durations_s[k], durations_s[k + 1]);
    for (int r = 1; r <= r_cont; ++r) {
      add_row(k, DerivativeRow(r, 1.0) * std::pow(t_short / durations_s[k], r));
      add_row(k + 1, -DerivativeRow(r, 0.0) * std::pow(t_short / durations_s[k + 1], r));
      ++row;
    }
  }
  assert(row == kkt.size);
  return kkt;
}

// [c; μ] of the KKT system, solved after a symmetric (Ruiz) equilibration: K' = D K D with
// every row and column of K' of max-norm about 1; then K' y = D rhs and [c; μ] = D y.
Eigen::MatrixXd SolveKktSystem(const KktSystem& system) {
  const int size = system.size;
  Eigen::SparseMatrix<double> kkt(size, size);
  kkt.setFromTriplets(system.entries.begin(), system.entries.end());  // sums duplicates
  Eigen::VectorXd d = Eigen::VectorXd::Ones(size);
  for (int iteration = 0; iteration < 8; ++iteration) {
    Eigen::VectorXd row_max = Eigen::VectorXd::Zero(size);
    for (int col = 0; col < kkt.outerSize(); ++col) {
      for (Eigen::SparseMatrix<double>::InnerIterator it(kkt, col); it; ++it) {
        row_max(it.row()) = std::max(row_max(it.row()), std::abs(it.value()));
      }
    }
    const Eigen::VectorXd scale = row_max.cwiseSqrt().cwiseInverse();
    kkt = scale.asDiagonal() * kkt * scale.asDiagonal();
    d = d.cwiseProduct(scale);
  }

  // The KKT matrix [σH ρAᵀ; ρA 0] is symmetric indefinite and nonsingular (A has full row
  // rank, H is positive definite on null(A)); sparse LU with partial pivoting solves it.
  Eigen::SparseLU<Eigen::SparseMatrix<double>> lu;
  lu.compute(kkt);
  if (lu.info() != Eigen::Success) {
    throw std::runtime_error("minimum-snap KKT system is singular: " + lu.lastErrorMessage());
  }
  const Eigen::MatrixXd solution = d.asDiagonal() * lu.solve(d.asDiagonal() * system.rhs);
  if (!solution.allFinite()) {
    throw std::runtime_error("minimum-snap KKT system is singular");
  }
  return solution;
}

// ∂J/∂T_k of the optimal cost, by the envelope theorem on J(T) = min cᵀH(T)c s.t.
// A(T)c = b: with Hc = Aᵀλ, ∂J/∂T_k = cᵀ ∂H/∂T_k c − 2 λᵀ ∂A/∂T_k c. Only the cost blocks
// (∂/∂T_k of T_k^(1−2r) gives (1 − 2r)/T_k) and the continuity rows (∂/∂T of T^(−r)
// d^r p/dτ^r gives −r/T times the time derivative) depend on T. The solved multipliers μ
// belong to the scaled rows: λ = −ρ μ / σ.
std::vector<double> CostGradient(const PiecewisePolynomial& polynomial,
                                 const Eigen::MatrixXd& solution,
                                 const std::vector<double>& durations_s,
                                 const Eigen::Matrix<double, kN, kN>& q, int r_cost, int r_cont,
                                 double sigma, int first_continuity_row) {
  const int num_segments = static_cast<int>(durations_s.size());
  std::vector<double> gradient(num_segments, 0.0);
  for (int k = 0; k < num_segments; ++k) {
    const PiecewisePolynomial::Coefficients& c = polynomial.coefficients()[k];
    const double segment_cost =
        (c.transpose() * q * c).trace() * std::pow(durations_s[k], 1 - 2 * r_cost);
    gradient[k] += (1 - 2 * r_cost) * segment_cost / durations_s[k];
  }
  int row = first_continuity_row;
  for (int k = 0; k + 1 < num_segments; ++k) {
    const double t_short = std::min(durations_s[k], durations_s[k + 1]);
    for (int r = 1; r <= r_cont; ++r) {
      const Eigen::Vector3d lambda =
          -std::pow(t_short, r) / sigma * solution.row(row++).transpose();
      // Row: d^r p_k/dt^r(end) − d^r p_k+1/dt^r(start).
      const Eigen::Vector3d end_k = polynomial.EvaluateSegment(k, 1.0, r);
      const Eigen::Vector3d start_next = polynomial.EvaluateSegment(k + 1, 0.0, r);
      gradient[k] -= 2.0 * lambda.dot(-r / durations_s[k] * end_k);
      gradient[k + 1] -= 2.0 * lambda.dot(r / durations_s[k + 1] * start_next);
    }
  }
  return gradient;
}

}  // namespace

PiecewisePolynomial SolveMinimumDerivative(const std::vector<Eigen::Vector3d>& points,
                                           const std::vector<double>& durations_s,
                                           const MinimumDerivativeOptions& options,
                                           std::vector<double>* cost_gradient) {
  assert(points.size() == durations_s.size() + 1 && !durations_s.empty());
  core::ValidOptions(options, "SolveMinimumDerivative");
  const int num_segments = static_cast<int>(durations_s.size());
  const int r_cost = options.cost_derivative;
  const int r_cont = options.continuity_derivative;

  // Time is normalised per segment. Conditioning: the cost is multiplied by
  // σ = t_min^(2r−1) (t_min the shortest segment), each continuity row by ρ = T^r (T the
  // shorter of its two segments), and the whole KKT matrix is equilibrated, so segments
  // of very different durations still give an accurate solution.
  const double t_min = *std::min_element(durations_s.begin(), durations_s.end());
  const double sigma = std::pow(t_min, 2 * r_cost - 1);
  const Eigen::Matrix<double, kN, kN> q = CostMatrix(r_cost);
  const KktSystem kkt = BuildKktSystem(points, durations_s, q, r_cost, r_cont);
  const Eigen::MatrixXd solution = SolveKktSystem(kkt);

  std::vector<PiecewisePolynomial::Coefficients> coefficients(num_segments);
  for (int k = 0; k < num_segments; ++k) {
    coefficients[k] = solution.block<kN, 3>(kN * k, 0);
    coefficients[k].row(0) += points[0].transpose();
  }
  PiecewisePolynomial polynomial(durations_s, std::move(coefficients));
  if (cost_gradient != nullptr) {
    *cost_gradient = CostGradient(polynomial, solution, durations_s, q, r_cost, r_cont, sigma,
                                  kkt.first_continuity_row);
  }
  return polynomial;
}

std::vector<double> OptimizeSegmentRatios(const std::vector<Eigen::Vector3d>& points,
                                          std::vector<double> durations_s) {
  const int n = static_cast<int>(durations_s.size());
  if (n < 2) return durations_s;
  double total = 0.0;
  for (double t : durations_s) total += t;
  const double t_floor = 1e-2 * total / n;

  // J(T) (ΣT)^7 is invariant to uniform scaling (J(αT) = α⁻⁷ J(T)), so it ranks time
  // ratios alone. Gradient descent on θ = log T with F = log J + 7 log ΣT:
  // ∂F/∂θ_k = T_k (∂J/∂T_k / J + 7 / ΣT); the sum of these is 0 (Euler: Σ T_k ∂J/∂T_k = −7J).
  auto objective = [&](const std::vector<double>& t, std::vector<double>* gradient) {
    std::vector<double> dj;
    const PiecewisePolynomial p =
        SolveMinimumDerivative(points, t, {}, gradient != nullptr ? &dj : nullptr);
    const double cost = p.IntegratedSquaredDerivative(4);
    double sum = 0.0;
    for (double tk : t) sum += tk;
    if (gradient != nullptr) {
      gradient->resize(t.size());
      for (size_t k = 0; k < t.size(); ++k) (*gradient)[k] = t[k] * (dj[k] / cost + 7.0 / sum);
    }
    return std::log(cost) + 7.0 * std::log(sum);
  };

  std::vector<double> gradient;
  double f = objective(durations_s, &gradient);
  if (!std::isfinite(f)) return durations_s;  // no motion: nothing to rank
  double step = 0.5;
  for (int iteration = 0; iteration < 100; ++iteration) {
    double g_norm = 0.0;
    for (double g : gradient) g_norm = std::max(g_norm, std::abs(g));
    if (g_norm < 1e-4) break;
    // Backtracking (Armijo) line search, steps of at most 0.5 in log T.
    bool improved = false;
    for (int halving = 0; halving < 30 && !improved; ++halving, step *= 0.5) {
      std::vector<double> trial(n);
      double sum = 0.0;
      for (int k = 0; k < n; ++k) {
        trial[k] = std::max(t_floor, durations_s[k] * std::exp(-step * gradient[k] / g_norm));
        sum += trial[k];
      }
      for (double& t : trial) t *= total / sum;  // keep the total
      double g_dot_step = 0.0;
      for (int k = 0; k < n; ++k) g_dot_step += gradient[k] * std::log(trial[k] / durations_s[k]);
      const double f_trial = objective(trial, nullptr);
      if (f_trial <= f + 1e-4 * g_dot_step) {
        durations_s = std::move(trial);
        improved = true;
      }
    }
    if (!improved) break;
    step = std::min(0.5, step * 4.0);
    f = objective(durations_s, &gradient);
  }
  return durations_s;
}

// ---- waypoint path ----

WaypointPath::WaypointPath(PiecewisePolynomial position, std::vector<Eigen::Quaterniond> q_WB)
    : position_(std::move(position)), q_WB_(std::move(q_WB)) {
  assert(static_cast<int>(q_WB_.size()) == position_.num_segments() + 1);
  for (size_t k = 0; k + 1 < q_WB_.size(); ++k) {
    // Shortest rotation from R_k to R_k+1, as a rotation vector in B at R_k.
    rotation_vector_.push_back(core::LogQuat(q_WB_[k].conjugate() * q_WB_[k + 1]));
  }
}

Reference WaypointPath::Sample(double t_s) const {
  const double t = std::clamp(t_s, 0.0, duration_s());
  const int k = position_.SegmentAt(t);
  const double duration = position_.durations_s()[k];
  const double tau = std::clamp((t - position_.segment_start_s(k)) / duration, 0.0, 1.0);

  Reference ref;
  ref.p_WB = position_.EvaluateSegment(k, tau, 0);
  ref.v_WB_W = position_.EvaluateSegment(k, tau, 1);
  ref.a_WB_W = position_.EvaluateSegment(k, tau, 2);
  ref.j_WB_W = position_.EvaluateSegment(k, tau, 3);

  // R = R_k Exp(s φ_k) ⇒ Rᵀ Ṙ = Hat(ṡ φ_k): ω_B = ṡ φ_k, α_B = s̈ φ_k.
  const SepticStep step = EvaluateSepticStep(tau);
  const Eigen::Vector3d& phi = rotation_vector_[k];
  ref.q_WB = core::CanonicalQuat((q_WB_[k] * core::ExpQuat(step.s * phi)).normalized());
  ref.omega_WB_B = phi * (step.ds / duration);
  ref.alpha_WB_B = phi * (step.dds / (duration * duration));
  return ref;
}

WaypointPath PlanWaypoints(const Waypoint& start, const std::vector<Waypoint>& waypoints,
                           const DynamicLimits& limits) {
  assert(!waypoints.empty());
  std::vector<Eigen::Vector3d> points = {start.p_WB};
  std::vector<Eigen::Quaterniond> attitudes = {start.q_WB.normalized()};
  for (const Waypoint& w : waypoints) {
    points.push_back(w.p_WB);
    attitudes.push_back(w.q_WB.normalized());
  }
  const int num_segments = static_cast<int>(waypoints.size());

  // Initial allocation, before the uniform scaling: the times at which a smooth rest-to-
  // rest motion along the polyline's arc length (septic speed ramps to max_speed_mps within
  // max_acceleration_mps2, cruise, ramp down) passes the waypoints, then ratios optimised
  // for snap. (Each segment's own rest-to-rest time instead makes short segments
  // relatively fast, and the C⁶ spline then overshoots far beyond the long ones.)
  std::vector<double> arc_length = {0.0};
  for (int k = 0; k < num_segments; ++k) {
    arc_length.push_back(arc_length.back() + (points[k + 1] - points[k]).norm());
  }
  const double length = arc_length.back();
  std::vector<double> durations(num_segments, kMinimumSegmentDuration_s);
  if (length > 0.0) {
    double speed = limits.max_speed_mps;
    if (speed * speed * kSepticPeakRate / limits.max_acceleration_mps2 > length) {
      // Too short to reach max_speed_mps: the two ramps alone cover the length.
      speed = std::sqrt(length * limits.max_acceleration_mps2 / kSepticPeakRate);
    }
    const double ramp_s = speed * kSepticPeakRate / limits.max_acceleration_mps2;
    const PhaseProfile along{speed, ramp_s, std::max(0.0, length / speed - ramp_s)};
    for (int k = 0; k < num_segments; ++k) {
      durations[k] = std::max(kMinimumSegmentDuration_s,
                              along.TimeOf(arc_length[k + 1]) - along.TimeOf(arc_length[k]));
    }
    durations = OptimizeSegmentRatios(points, std::move(durations));
  }
  // The attitude is rest-to-rest on each segment: at least its own septic time.
  std::vector<double> angles(num_segments);
  for (int k = 0; k < num_segments; ++k) {
    angles[k] = core::LogQuat(attitudes[k].conjugate() * attitudes[k + 1]).norm();
    durations[k] = std::max({durations[k], kMinimumSegmentDuration_s,
                             SepticRestToRestDuration(angles[k], limits.max_angular_rate_radps,
                                                      limits.max_angular_acceleration_radps2)});
  }

  // Solve, measure the peaks, scale all durations by one factor; the second pass only
  // verifies (uniform scaling maps the minimum-snap solution onto itself).
  constexpr int kSamplesPerSegment = 200;
  constexpr int kMaxPasses = 3;
  PiecewisePolynomial position;
  for (int pass = 1;; ++pass) {
    position = SolveMinimumDerivative(points, durations);
    double peak_speed = 0.0;
    double peak_acceleration = 0.0;
    double scale = 0.0;
    for (int k = 0; k < num_segments; ++k) {
      for (int i = 0; i <= kSamplesPerSegment; ++i) {
        const double tau = static_cast<double>(i) / kSamplesPerSegment;
        peak_speed = std::max(peak_speed, position.EvaluateSegment(k, tau, 1).norm());
        peak_acceleration =
            std::max(peak_acceleration, position.EvaluateSegment(k, tau, 2).norm());
      }
      // Attitude peaks are analytic: θ s'_max / T and θ s''_max / T².
      scale = std::max({scale,
                        angles[k] * kSepticPeakRate / durations[k] / limits.max_angular_rate_radps,
                        std::sqrt(angles[k] * kSepticPeakAcceleration /
                                  (durations[k] * durations[k]) /
                                  limits.max_angular_acceleration_radps2)});
    }
    // Speed scales with 1/factor, accelerations with 1/factor².
    scale = std::max({scale, peak_speed / limits.max_speed_mps,
                      std::sqrt(peak_acceleration / limits.max_acceleration_mps2)});
    // Stop when there is no motion at all, or the most binding limit is met.
    if (scale <= 0.0 || std::abs(scale - 1.0) < 1e-9 || pass == kMaxPasses) break;
    for (double& t : durations) t *= scale;
  }
  return WaypointPath(std::move(position), std::move(attitudes));
}

}  // namespace tofu::sim::min_snap
