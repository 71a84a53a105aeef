#pragma once
// Marginalisation of the states that leave a fixed-lag window into a linear Gaussian prior
// on the states they were connected to (Schur complement of the linearised factors, as in
// Sibley et al. 2010 "Sliding window filter" and Leutenegger et al. 2015 OKVIS, Sec. 3.3).
// Dropping the old states instead would throw away what they knew about the kept ones:
// the local graph's gauge (position, yaw), its velocity and its biases.
// Library code: Eigen + Ceres only.

#include <memory>
#include <vector>

#include <Eigen/Core>
#include <ceres/cost_function.h>
#include <ceres/loss_function.h>
#include <ceres/manifold.h>

namespace tofu::estimator {

/// A parameter block as the marginaliser sees it: its memory, ambient and tangent sizes,
/// and its manifold (nullptr: Euclidean).
struct MarginalBlock {
  double* data = nullptr;
  int ambient_size = 0;
  int tangent_size = 0;
  const ceres::Manifold* manifold = nullptr;
};

/// A linearised factor to be marginalised: the cost, its loss (may be null) and blocks
/// in the cost's parameter order.
struct MarginalFactor {
  const ceres::CostFunction* cost = nullptr;
  const ceres::LossFunction* loss = nullptr;
  std::vector<MarginalBlock> blocks;
};

/// The prior that marginalisation leaves behind:
///   cost = ½ ‖ r0 + J · (x ⊟ x0) ‖²
/// over the kept blocks, x0 their values at marginalisation time (the linearisation point,
/// fixed from then on: first-estimate Jacobians keep the prior's null space consistent).
struct LinearPrior {
  std::vector<MarginalBlock> blocks;            ///< kept blocks, in column order of J
  std::vector<Eigen::VectorXd> x0;              ///< ambient values at linearisation
  Eigen::MatrixXd J;                            ///< rank × Σ tangent sizes
  Eigen::VectorXd r0;                           ///< rank
};

/// Marginalises every block of `marginalised` out of the factors: builds the Gauss-Newton
/// system H δx = −b of the factors at the blocks' current values (tangent space, robust
/// losses applied by their first-order weight), forms the Schur complement
///   H* = H_kk − H_km H_mm⁺ H_mk,  b* = b_k − H_km H_mm⁺ b_m
/// and factors it as H* = Jᵀ J, b* = Jᵀ r0 by an eigen-decomposition (eigenvalues below
/// `relative_eigenvalue_floor` × the largest are dropped: directions the factors did not
/// constrain stay free instead of becoming an over-confident prior).
/// Returns false (and leaves `prior` untouched) if a factor does not evaluate to finite values.
bool Marginalize(const std::vector<MarginalFactor>& factors,
                 const std::vector<double*>& marginalised, LinearPrior* prior,
                 double relative_eigenvalue_floor = 1e-12);

/// The Ceres cost of a LinearPrior. Blocks with a manifold use its Minus for x ⊟ x0 and
/// are differentiated numerically through the manifold's Plus in the tangent space only
/// when no analytic form is known; for the pose manifold of the local graph the analytic
/// form is used (see .cc).
class LinearPriorFactor final : public ceres::CostFunction {
 public:
  explicit LinearPriorFactor(LinearPrior prior);
  bool Evaluate(double const* const* parameters, double* residuals,
                double** jacobians) const override;
  const LinearPrior& prior() const { return prior_; }

 private:
  LinearPrior prior_;
};

}  // namespace tofu::estimator
