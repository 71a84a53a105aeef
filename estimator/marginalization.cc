#include "estimator/marginalization.h"

#include <algorithm>
#include <map>

#include <Eigen/Eigenvalues>

#include "core/lie.h"
#include "estimator/local_factors.h"

namespace tofu::estimator {
namespace {

// Tangent Jacobian of the block's local coordinates (x ⊞ ε) ⊟ x0 w.r.t. ε at ε = 0.
// The pose manifold (right perturbation of R, additive p): [I 0; 0 Jr⁻¹(R0ᵀR)].
// Any other manifold: central differences through its Plus and Minus.
Eigen::MatrixXd LocalCoordinateJacobian(const MarginalBlock& block, const double* x,
                                        const double* x0) {
  const int n = block.tangent_size;
  Eigen::MatrixXd J = Eigen::MatrixXd::Identity(n, n);
  if (block.manifold == nullptr) return J;
  if (dynamic_cast<const PoseManifold*>(block.manifold) != nullptr) {
    Eigen::Matrix<double, 6, 1> delta;
    block.manifold->Minus(x, x0, delta.data());
    J.bottomRightCorner<3, 3>() = core::InverseRightJacobianSO3(delta.tail<3>());
    return J;
  }
  const double step = 1e-7;
  Eigen::VectorXd x_plus(block.ambient_size), x_minus(block.ambient_size);
  Eigen::VectorXd d_plus(n), d_minus(n), eps = Eigen::VectorXd::Zero(n);
  for (int k = 0; k < n; ++k) {
    eps.setZero();
    eps[k] = step;
    block.manifold->Plus(x, eps.data(), x_plus.data());
    eps[k] = -step;
    block.manifold->Plus(x, eps.data(), x_minus.data());
    block.manifold->Minus(x_plus.data(), x0, d_plus.data());
    block.manifold->Minus(x_minus.data(), x0, d_minus.data());
    J.col(k) = (d_plus - d_minus) / (2.0 * step);
  }
  return J;
}

// Ambient (what Ceres asks for) from tangent Jacobian: J_amb = J_tan · pinv(PlusJacobian),
// so that Ceres's J_amb · PlusJacobian recovers J_tan exactly.
Eigen::MatrixXd AmbientFromTangent(const MarginalBlock& block, const double* x,
                                   const Eigen::MatrixXd& J_tangent) {
  if (block.manifold == nullptr) return J_tangent;
  if (dynamic_cast<const PoseManifold*>(block.manifold) != nullptr) {
    return J_tangent * PoseLiftJacobian(x);
  }
  Eigen::MatrixXd plus_jacobian(block.ambient_size, block.tangent_size);
  block.manifold->PlusJacobian(x, plus_jacobian.data());
  // Ceres stores PlusJacobian row-major; Eigen's default is column-major.
  Eigen::Map<Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>> P(
      plus_jacobian.data(), block.ambient_size, block.tangent_size);
  const Eigen::MatrixXd P_col = P;
  const Eigen::MatrixXd lift =
      (P_col.transpose() * P_col).ldlt().solve(P_col.transpose());
  return J_tangent * lift;
}

}  // namespace

// Long by design: one linear-algebra sequence (column layout, H and b, Schur complement,
// factor into a prior) whose steps share the column layout; kept in the order of the math.
bool Marginalize(const std::vector<MarginalFactor>& factors,
                 const std::vector<double*>& marginalised, LinearPrior* prior,
                 double relative_eigenvalue_floor) {
  // Column layout: marginalised blocks first, then kept blocks in first-seen order.
  std::vector<MarginalBlock> order;
  std::map<const double*, int> offset_of;
  int marginal_size = 0;
  int total_size = 0;
  auto add_block = [&](const MarginalBlock& block) {
    if (offset_of.count(block.data) != 0) return;
    offset_of[block.data] = total_size;
    total_size += block.tangent_size;
    order.push_back(block);
  };
  for (double* data : marginalised) {
    for (const MarginalFactor& factor : factors) {
      for (const MarginalBlock& block : factor.blocks) {
        if (block.data == data) add_block(block);
      }
    }
  }
  marginal_size = total_size;
  const std::size_t marginal_blocks = order.size();
  for (const MarginalFactor& factor : factors) {
    for (const MarginalBlock& block : factor.blocks) add_block(block);
  }
  const int kept_size = total_size - marginal_size;
  if (kept_size == 0) return false;

  Eigen::MatrixXd H = Eigen::MatrixXd::Zero(total_size, total_size);
  Eigen::VectorXd b = Eigen::VectorXd::Zero(total_size);
  for (const MarginalFactor& factor : factors) {
    std::vector<const double*> data;
    std::vector<const ceres::Manifold*> manifolds;
    for (const MarginalBlock& block : factor.blocks) {
      data.push_back(block.data);
      manifolds.push_back(block.manifold);
    }
    Eigen::VectorXd residual;
    std::vector<Eigen::MatrixXd> jacobians;
    if (!EvaluateTangent(*factor.cost, data, manifolds, &residual, &jacobians)) return false;
    if (!residual.allFinite()) return false;
    // Robust loss: the first-order (IRLS) weight ρ'(s) scales the information, which is
    // what the solver itself used at this point (Triggs et al. 2000, Sec. 4.3 without the
    // second-order correction).
    double weight = 1.0;
    if (factor.loss != nullptr) {
      double rho[3];
      factor.loss->Evaluate(residual.squaredNorm(), rho);
      weight = std::max(rho[1], 0.0);
    }
    for (std::size_t a = 0; a < factor.blocks.size(); ++a) {
      if (!jacobians[a].allFinite()) return false;
      const int oa = offset_of.at(factor.blocks[a].data);
      const int na = factor.blocks[a].tangent_size;
      b.segment(oa, na) += weight * jacobians[a].transpose() * residual;
      for (std::size_t c = 0; c < factor.blocks.size(); ++c) {
        const int oc = offset_of.at(factor.blocks[c].data);
        const int nc = factor.blocks[c].tangent_size;
        H.block(oa, oc, na, nc) += weight * jacobians[a].transpose() * jacobians[c];
      }
    }
  }

  // Schur complement with a pseudo-inverse of H_mm (symmetric eigen-decomposition: a
  // marginalised direction that nothing constrained carries no information, not infinity).
  const Eigen::MatrixXd H_mm =
      0.5 * (H.topLeftCorner(marginal_size, marginal_size) +
             H.topLeftCorner(marginal_size, marginal_size).transpose());
  Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> eig_mm(H_mm);
  const Eigen::VectorXd lambda_mm = eig_mm.eigenvalues();
  const double floor_mm = relative_eigenvalue_floor * std::max(lambda_mm.maxCoeff(), 0.0);
  Eigen::VectorXd inv_lambda_mm = Eigen::VectorXd::Zero(marginal_size);
  for (int k = 0; k < marginal_size; ++k) {
    if (lambda_mm[k] > floor_mm && lambda_mm[k] > 0.0) inv_lambda_mm[k] = 1.0 / lambda_mm[k];
  }
  const Eigen::MatrixXd H_mm_pinv =
      eig_mm.eigenvectors() * inv_lambda_mm.asDiagonal() * eig_mm.eigenvectors().transpose();
  const Eigen::MatrixXd H_km = H.bottomLeftCorner(kept_size, marginal_size);
  Eigen::MatrixXd H_star =
      H.bottomRightCorner(kept_size, kept_size) - H_km * H_mm_pinv * H_km.transpose();
  H_star = 0.5 * (H_star + H_star.transpose()).eval();  // eval: no aliasing
  const Eigen::VectorXd b_star = b.tail(kept_size) - H_km * H_mm_pinv * b.head(marginal_size);

  // H* = V Λ Vᵀ = Jᵀ J with J = Λ^½ Vᵀ; b* = Jᵀ r0 with r0 = Λ^-½ Vᵀ b*.
  Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> eig(H_star);
  const Eigen::VectorXd lambda = eig.eigenvalues();
  const double floor = relative_eigenvalue_floor * std::max(lambda.maxCoeff(), 0.0);
  std::vector<int> kept_directions;
  for (int k = 0; k < kept_size; ++k) {
    if (lambda[k] > floor && lambda[k] > 0.0) kept_directions.push_back(k);
  }
  if (kept_directions.empty()) return false;
  LinearPrior result;
  const int rank = static_cast<int>(kept_directions.size());
  result.J.resize(rank, kept_size);
  result.r0.resize(rank);
  for (int row = 0; row < rank; ++row) {
    const int k = kept_directions[row];
    const Eigen::VectorXd v = eig.eigenvectors().col(k);
    result.J.row(row) = std::sqrt(lambda[k]) * v.transpose();
    result.r0[row] = v.dot(b_star) / std::sqrt(lambda[k]);
  }
  if (!result.J.allFinite() || !result.r0.allFinite()) return false;
  for (std::size_t i = marginal_blocks; i < order.size(); ++i) {
    result.blocks.push_back(order[i]);
    result.x0.push_back(Eigen::Map<const Eigen::VectorXd>(order[i].data, order[i].ambient_size));
  }
  *prior = std::move(result);
  return true;
}

LinearPriorFactor::LinearPriorFactor(LinearPrior prior) : prior_(std::move(prior)) {
  set_num_residuals(static_cast<int>(prior_.r0.size()));
  for (const MarginalBlock& block : prior_.blocks) {
    mutable_parameter_block_sizes()->push_back(block.ambient_size);
  }
}

bool LinearPriorFactor::Evaluate(double const* const* parameters, double* residuals,
                                 double** jacobians) const {
  const int rank = num_residuals();
  Eigen::Map<Eigen::VectorXd> r(residuals, rank);
  r = prior_.r0;
  int column = 0;
  for (std::size_t i = 0; i < prior_.blocks.size(); ++i) {
    const MarginalBlock& block = prior_.blocks[i];
    const int n = block.tangent_size;
    Eigen::VectorXd delta(n);
    if (block.manifold == nullptr) {
      delta = Eigen::Map<const Eigen::VectorXd>(parameters[i], n) - prior_.x0[i];
    } else if (!block.manifold->Minus(parameters[i], prior_.x0[i].data(), delta.data())) {
      return false;
    }
    r += prior_.J.middleCols(column, n) * delta;
    if (jacobians != nullptr && jacobians[i] != nullptr) {
      const Eigen::MatrixXd J_tangent =
          prior_.J.middleCols(column, n) *
          LocalCoordinateJacobian(block, parameters[i], prior_.x0[i].data());
      const Eigen::MatrixXd J_ambient = AmbientFromTangent(block, parameters[i], J_tangent);
      Eigen::Map<Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>>(
          jacobians[i], rank, block.ambient_size) = J_ambient;
    }
    column += n;
  }
  return r.allFinite();
}

}  // namespace tofu::estimator
