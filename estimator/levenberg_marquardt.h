#pragma once
// Levenberg-Marquardt with Ceres's trust-region strategy, for the estimator's small
// problems that ceres::Solve would spend most of its time setting up: the local window
// (window_solver.h, block-banded) and the frame alignment (alignment_graph.h, one pose).
// The problem owns its state, its normal equations and their factorisation; this driver
// owns the strategy:
// - steps δ = −(H + λD)⁻¹ g with D = diag(H) clamped to [1e-6, 1e32] and λ = 1/radius;
// - the radius grows by how well the quadratic model predicted the cost decrease
//   (Madsen, Nielsen & Tingleff 2004, "Methods for non-linear least squares problems",
//   Sec. 3.2) and shrinks by a doubling factor after a rejected step;
// - it stops on Ceres's function, parameter and gradient tolerances, and on a
//   simplified-Newton test: after an accepted step, the next step's model decrease is
//   estimated with the previous factor (H barely changes over a converging step), which
//   saves the confirming factorisation of a warm-started solve.
// Robust losses are the problem's business (Triggs et al. 1999's correction, as Ceres).
// Library code: no dependencies beyond the standard library.

#include <string>

namespace tofu::estimator {

struct LmOptions {
  /// LM steps (accepted or rejected) at most.
  int max_iterations = 6;
  double max_time_s = 0.005;
  /// Stops when a step's (predicted or actual) cost decrease is below this × the cost.
  double function_tolerance = 1e-5;
  /// Stops when ‖δ‖ ≤ parameter_tolerance (‖x‖ + parameter_tolerance).
  double parameter_tolerance = 1e-8;
  /// Stops when max |Jᵀ r| is below this.
  double gradient_tolerance = 1e-10;
  /// 1/λ of the first step (D = diag(H)); Ceres's default. A warm-started problem can
  /// start almost as Gauss-Newton (the local smoother uses 1e8).
  double initial_trust_region_radius = 1e4;

  /// True when the options are usable; otherwise false with the broken constraint in
  /// *why (if why is not null).
  bool IsValid(std::string* why = nullptr) const;
};

enum class LmTermination {
  kConverged,
  kIterationCap,
  kTimeCap,
  kFailure,  ///< cost not finite at the start, or no step could be taken: state unchanged
};

struct LmSummary {
  LmTermination termination = LmTermination::kFailure;
  int iterations = 0;         ///< LM steps whose candidate was evaluated
  double initial_cost = 0.0;  ///< ½ Σ ρ(‖r‖²)
  double final_cost = 0.0;
};

/// A least-squares problem as the driver sees it: a state x it can linearise at, step
/// from and step back to.
class LmProblem {
 public:
  virtual ~LmProblem() = default;
  /// Cost ½ Σ ρ(‖r‖²), gradient g = Jᵀ r and H = JᵀJ at x (robust losses applied).
  /// False when a residual or Jacobian cannot be evaluated or is not finite.
  virtual bool Linearize(double* cost) = 0;
  virtual double GradientMaxNorm() const = 0;
  /// Factorises H + λD of the last linearisation; false if it is not positive definite.
  virtual bool Factorize(double lambda) = 0;
  /// δ = −(H + λD)⁻¹ g with the last factor and the last gradient.
  virtual void SolveForDelta() = 0;
  virtual double GradientDotDelta() const = 0;  ///< gᵀδ
  virtual double DampingEnergy() const = 0;     ///< δᵀDδ, D of the last linearisation
  virtual double DeltaNorm() const = 0;
  virtual double StateNorm() const = 0;
  /// x ← x ⊞ δ, keeping x for Restore.
  virtual void ApplyDelta() = 0;
  /// Back to x before the last ApplyDelta.
  virtual void Restore() = 0;
  /// ½ Σ ρ(‖r‖²) at x; false if it cannot be evaluated or is not finite.
  virtual bool EvaluateCost(double* cost) = 0;
};

/// Minimises the problem's cost from its current x (in place). options must be IsValid():
/// this driver never throws, so it does not check them (WindowSolver::Solve does; the
/// alignment graph builds them from its own checked options).
LmSummary MinimizeLm(LmProblem& problem, const LmOptions& options);

}  // namespace tofu::estimator
