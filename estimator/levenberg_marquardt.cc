#include "estimator/levenberg_marquardt.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <limits>

namespace tofu::estimator {
namespace {

// Ceres's trust-region constants (ceres::Solver::Options defaults), so that this driver
// and ceres::Solve take the same steps.
constexpr double kMinRelativeDecrease = 1e-3;
constexpr double kMaxTrustRegionRadius = 1e16;
constexpr double kMinTrustRegionRadius = 1e-32;

}  // namespace

bool LmOptions::IsValid(std::string* why) const {
  auto fail = [why](const char* message) {
    if (why != nullptr) *why = message;
    return false;
  };
  if (max_iterations < 1) return fail("max_iterations must be at least 1");
  // Infinity is allowed: no time cap (a deterministic solve, as the alignment graph's).
  if (!(max_time_s > 0.0)) return fail("max_time_s must be positive");
  if (!(function_tolerance >= 0.0) || !std::isfinite(function_tolerance)) {
    return fail("function_tolerance must be >= 0 and finite");
  }
  if (!(parameter_tolerance >= 0.0) || !std::isfinite(parameter_tolerance)) {
    return fail("parameter_tolerance must be >= 0 and finite");
  }
  if (!(gradient_tolerance >= 0.0) || !std::isfinite(gradient_tolerance)) {
    return fail("gradient_tolerance must be >= 0 and finite");
  }
  if (!(initial_trust_region_radius > 0.0) || !std::isfinite(initial_trust_region_radius)) {
    return fail("initial_trust_region_radius must be positive and finite");
  }
  return true;
}

// Long by design: the Levenberg-Marquardt loop with its termination tests, as Madsen et al.
// write it; the tests share the step's model decrease and trust region.
LmSummary MinimizeLm(LmProblem& problem, const LmOptions& options) {
  using Clock = std::chrono::steady_clock;
  const Clock::time_point start = Clock::now();
  LmSummary summary;
  double cost = 0.0;
  if (!problem.Linearize(&cost)) {
    summary.initial_cost = summary.final_cost = std::numeric_limits<double>::quiet_NaN();
    return summary;  // kFailure, state untouched
  }
  summary.initial_cost = cost;
  double radius = options.initial_trust_region_radius;
  double decrease_factor = 2.0;
  const auto finish = [&](LmTermination termination) {
    summary.termination = termination;
    summary.final_cost = cost;
    return summary;
  };
  if (problem.GradientMaxNorm() <= options.gradient_tolerance) {
    return finish(LmTermination::kConverged);
  }
  for (int steps = 0;; ++steps) {
    if (steps >= options.max_iterations) return finish(LmTermination::kIterationCap);
    if (std::chrono::duration<double>(Clock::now() - start).count() >= options.max_time_s) {
      return finish(LmTermination::kTimeCap);
    }
    const double lambda = 1.0 / radius;
    bool step_valid = problem.Factorize(lambda);
    double model_decrease = 0.0;
    if (step_valid) {
      problem.SolveForDelta();
      // With (H + λD) δ = −g: model decrease −(gᵀδ + ½ δᵀHδ) = −½ gᵀδ + ½ λ δᵀDδ.
      model_decrease = -0.5 * problem.GradientDotDelta() + 0.5 * lambda * problem.DampingEnergy();
      step_valid = std::isfinite(model_decrease);
    }
    if (step_valid) {
      // Converged where even the quadratic model promises nothing worth a step (the GN
      // counterpart of Ceres's function tolerance, without evaluating the candidate).
      if (model_decrease <= options.function_tolerance * cost) {
        return finish(LmTermination::kConverged);
      }
      if (problem.DeltaNorm() <=
          options.parameter_tolerance * (problem.StateNorm() + options.parameter_tolerance)) {
        return finish(LmTermination::kConverged);
      }
    }
    double candidate_cost = std::numeric_limits<double>::infinity();
    if (step_valid) {
      ++summary.iterations;
      problem.ApplyDelta();
      if (!problem.EvaluateCost(&candidate_cost)) {
        candidate_cost = std::numeric_limits<double>::infinity();
      }
    }
    const double actual_decrease = cost - candidate_cost;
    const double relative_decrease = step_valid ? actual_decrease / model_decrease : -1.0;
    if (relative_decrease > kMinRelativeDecrease) {
      // Madsen et al. (Sec. 3.2): grow the region by how well the model predicted the step.
      radius = std::min(kMaxTrustRegionRadius,
                        radius / std::max(1.0 / 3.0,
                                          1.0 - std::pow(2.0 * relative_decrease - 1.0, 3)));
      decrease_factor = 2.0;
      const double previous_cost = cost;
      cost = candidate_cost;
      if (actual_decrease <= options.function_tolerance * previous_cost) {
        return finish(LmTermination::kConverged);
      }
      double relinearised_cost = 0.0;
      if (!problem.Linearize(&relinearised_cost)) {
        problem.Restore();
        cost = previous_cost;
        return finish(LmTermination::kFailure);
      }
      if (problem.GradientMaxNorm() <= options.gradient_tolerance) {
        return finish(LmTermination::kConverged);
      }
      // Simplified-Newton convergence test: the next step's model decrease estimated with
      // the factor of the previous linearisation. Converged there, the solve ends without
      // a new factorisation: the usual end of a warm-started solve is one step, then this.
      problem.SolveForDelta();
      if (-0.5 * problem.GradientDotDelta() + 0.5 * lambda * problem.DampingEnergy() <=
          options.function_tolerance * cost) {
        return finish(LmTermination::kConverged);
      }
    } else {
      if (step_valid) problem.Restore();
      radius /= decrease_factor;
      decrease_factor *= 2.0;
      if (radius < kMinTrustRegionRadius) {
        // No step reduces the cost any more: as Ceres, this is convergence.
        return finish(LmTermination::kConverged);
      }
    }
  }
}

}  // namespace tofu::estimator
