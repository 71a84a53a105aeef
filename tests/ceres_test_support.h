#pragma once
// The reference solver the estimator tests compare against: ceres::Solve run to the
// tightest tolerances a double allows, so that any difference is the solver under test's.

#include <ceres/solver.h>

namespace tofu::test {

inline ceres::Solver::Options ReferenceCeresOptions(
    ceres::LinearSolverType linear_solver = ceres::DENSE_QR) {
  ceres::Solver::Options options;
  options.linear_solver_type = linear_solver;
  options.max_num_iterations = 200;
  options.function_tolerance = 1e-15;
  options.gradient_tolerance = 1e-15;
  options.parameter_tolerance = 1e-15;
  options.logging_type = ceres::SILENT;
  return options;
}

}  // namespace tofu::test
