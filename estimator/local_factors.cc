#include "estimator/local_factors.h"

#include <cmath>
#include <stdexcept>
#include <string>

#include <Eigen/Cholesky>

#include "core/lie.h"

namespace tofu::estimator {
namespace {

using Matrix67RowMajor = Eigen::Matrix<double, 6, 7, Eigen::RowMajor>;
using Vector9d = Eigen::Matrix<double, 9, 1>;

// A pose block read for evaluation: the quaternion normalised, so that the residuals do not
// depend on its norm (which makes J_tangent · Lift the true ambient derivative).
struct PoseBlock {
  Eigen::Vector3d p_LI;
  Eigen::Quaterniond q_LI;
  Eigen::Matrix3d R_LI;
};

// False for non-finite numbers or a quaternion too close to zero to normalise.
bool ReadPose(const double* pose, PoseBlock* out) {
  const Eigen::Map<const Eigen::Matrix<double, kPoseSize, 1>> x(pose);
  if (!x.allFinite()) return false;
  const Eigen::Map<const Eigen::Quaterniond> q(pose + 3);
  const double norm = q.norm();
  if (!(norm > 1e-12)) return false;
  out->p_LI = x.head<3>();
  out->q_LI = Eigen::Quaterniond(q.coeffs() / norm);
  out->R_LI = out->q_LI.toRotationMatrix();
  return true;
}

// The unit quaternion of a pose block (for the manifold's own operations).
Eigen::Quaterniond UnitQuat(const double* pose) {
  return Eigen::Quaterniond(Eigen::Map<const Eigen::Quaterniond>(pose + 3).coeffs().normalized());
}

// 3x4 block 2 [w I − [v]x, −v] (columns x, y, z, w): ∂Log(q0^{-1} ⊗ q)/∂q at q = q0, and
// the pseudo-inverse of G(q0) = ½ [w I + [v]x; −vᵀ] (4 Gᵀ with Gᵀ G = I/4).
Eigen::Matrix<double, 3, 4> RotationLift(const Eigen::Quaterniond& q) {
  Eigen::Matrix<double, 3, 4> lift;
  lift.leftCols<3>() = 2.0 * (q.w() * Eigen::Matrix3d::Identity() - core::Hat(q.vec()));
  lift.col(3) = -2.0 * q.vec();
  return lift;
}

// Writes the ambient Jacobian J_tangent · Lift(pose) (row-major n x 7) of a pose block.
template <int N>
void SetPoseJacobian(const Eigen::Matrix<double, N, 6>& J_tangent, const double* pose,
                     double* jacobian) {
  Eigen::Map<Eigen::Matrix<double, N, kPoseSize, Eigen::RowMajor>>{jacobian} =
      J_tangent.lazyProduct(PoseLiftJacobian(pose));
}

template <int N, int M>
void SetJacobian(const Eigen::Matrix<double, N, M>& J, double* jacobian) {
  Eigen::Map<Eigen::Matrix<double, N, M, Eigen::RowMajor>>{jacobian} = J;
}

// Everything a cost function wrote is finite (residuals and the requested Jacobians).
bool AllFinite(const double* values, int count) {
  for (int k = 0; k < count; ++k) {
    if (!std::isfinite(values[k])) return false;
  }
  return true;
}

bool OutputsFinite(const ceres::CostFunction& cost, const double* residuals,
                   double* const* jacobians) {
  const int n = cost.num_residuals();
  if (!AllFinite(residuals, n)) return false;
  if (jacobians == nullptr) return true;
  const auto& sizes = cost.parameter_block_sizes();
  for (size_t b = 0; b < sizes.size(); ++b) {
    if (jacobians[b] != nullptr && !AllFinite(jacobians[b], n * sizes[b])) return false;
  }
  return true;
}

}  // namespace

// ---- the pose manifold ----

bool PoseManifold::Plus(const double* x, const double* delta, double* x_plus_delta) const {
  const Eigen::Map<const Eigen::Vector3d> p(x);
  const Eigen::Map<const Eigen::Vector3d> delta_p(delta);
  const Eigen::Map<const Eigen::Vector3d> delta_theta(delta + 3);
  Eigen::Map<Eigen::Vector3d>{x_plus_delta} = p + delta_p;
  Eigen::Map<Eigen::Quaterniond>{x_plus_delta + 3} =
      (UnitQuat(x) * core::ExpQuat(delta_theta)).normalized();
  return true;
}

bool PoseManifold::PlusJacobian(const double* x, double* jacobian) const {
  const Eigen::Quaterniond q = UnitQuat(x);
  // ∂(q ⊗ [½δθ; 1])/∂δθ: vector part ½ (w I + [v]x), scalar part −½ vᵀ.
  Eigen::Map<Eigen::Matrix<double, kPoseSize, kPoseTangentSize, Eigen::RowMajor>> J(jacobian);
  J.setZero();
  J.block<3, 3>(0, 0).setIdentity();
  J.block<3, 3>(3, 3) = 0.5 * (q.w() * Eigen::Matrix3d::Identity() + core::Hat(q.vec()));
  J.block<1, 3>(6, 3) = -0.5 * q.vec().transpose();
  return true;
}

bool PoseManifold::Minus(const double* y, const double* x, double* y_minus_x) const {
  Eigen::Map<Eigen::Vector3d>{y_minus_x} =
      Eigen::Map<const Eigen::Vector3d>(y) - Eigen::Map<const Eigen::Vector3d>(x);
  Eigen::Map<Eigen::Vector3d>{y_minus_x + 3} = core::LogQuat(UnitQuat(x).conjugate() * UnitQuat(y));
  return true;
}

bool PoseManifold::MinusJacobian(const double* x, double* jacobian) const {
  Eigen::Map<Matrix67RowMajor>{jacobian} = PoseLiftJacobian(x);
  return true;
}

Eigen::Matrix<double, 6, 7> PoseLiftJacobian(const double* pose) {
  Eigen::Matrix<double, 6, 7> lift = Eigen::Matrix<double, 6, 7>::Zero();
  lift.block<3, 3>(0, 0).setIdentity();
  lift.block<3, 4>(3, 3) = RotationLift(UnitQuat(pose));
  return lift;
}

bool EvaluateTangent(const ceres::CostFunction& cost, const std::vector<const double*>& blocks,
                     const std::vector<const ceres::Manifold*>& manifolds,
                     Eigen::VectorXd* residual, std::vector<Eigen::MatrixXd>* tangent_jacobians) {
  const std::vector<int32_t>& sizes = cost.parameter_block_sizes();
  if (blocks.size() != sizes.size()) return false;
  if (!manifolds.empty() && manifolds.size() != sizes.size()) return false;
  const int n = cost.num_residuals();
  Eigen::VectorXd r(n);

  using RowMajorMatrix = Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>;
  std::vector<RowMajorMatrix> ambient(sizes.size());
  std::vector<double*> jacobian_ptrs(sizes.size(), nullptr);
  if (tangent_jacobians != nullptr) {
    for (size_t b = 0; b < sizes.size(); ++b) {
      ambient[b].resize(n, sizes[b]);
      jacobian_ptrs[b] = ambient[b].data();
    }
  }
  if (!cost.Evaluate(blocks.data(), r.data(),
                     tangent_jacobians != nullptr ? jacobian_ptrs.data() : nullptr)) {
    return false;
  }
  if (residual != nullptr) *residual = r;
  if (tangent_jacobians == nullptr) return true;

  tangent_jacobians->assign(sizes.size(), Eigen::MatrixXd());
  for (size_t b = 0; b < sizes.size(); ++b) {
    const ceres::Manifold* manifold = manifolds.empty() ? nullptr : manifolds[b];
    if (manifold == nullptr) {
      (*tangent_jacobians)[b] = ambient[b];
      continue;
    }
    if (manifold->AmbientSize() != sizes[b]) return false;
    RowMajorMatrix plus_jacobian(manifold->AmbientSize(), manifold->TangentSize());
    if (!manifold->PlusJacobian(blocks[b], plus_jacobian.data())) return false;
    (*tangent_jacobians)[b] = ambient[b] * plus_jacobian;
  }
  return true;
}

// ---- IMU factor ----

ImuFactor::ImuFactor(const ImuPreintegration& preintegration, const Eigen::Vector3d& gravity_L_mps2)
    : preintegration_(preintegration), gravity_L_mps2_(gravity_L_mps2) {
  if (!(preintegration.dt_s() > 0.0)) {
    throw std::invalid_argument(
        "ImuFactor: empty preintegration (dt_s = " + std::to_string(preintegration.dt_s()) + ")");
  }
  // Σ = L Lᵀ  =>  Σ^{-1} = L^{-T} L^{-1}: S = L^{-1} whitens (Sᵀ S = Σ^{-1}).
  const Eigen::LLT<Eigen::Matrix<double, 9, 9>> llt(preintegration.covariance());
  if (llt.info() != Eigen::Success || !preintegration.covariance().allFinite()) {
    throw std::invalid_argument(
        "ImuFactor: preintegration covariance is not positive definite (zero noise or too "
        "few samples)");
  }
  sqrt_information_ = llt.matrixL().solve(Eigen::Matrix<double, 9, 9>::Identity());
}

bool ImuFactor::Evaluate(double const* const* parameters, double* residuals,
                         double** jacobians) const {
  PoseBlock pose_i;
  PoseBlock pose_j;
  if (!ReadPose(parameters[0], &pose_i) || !ReadPose(parameters[2], &pose_j)) return false;
  const Eigen::Map<const Vector9d> speed_bias_i(parameters[1]);
  const Eigen::Map<const Vector9d> speed_bias_j(parameters[3]);
  if (!speed_bias_i.allFinite() || !speed_bias_j.allFinite()) return false;

  const Eigen::Vector3d v_i = speed_bias_i.head<3>();
  const Eigen::Vector3d v_j = speed_bias_j.head<3>();
  const ImuPreintegration& pre = preintegration_;
  const ImuBias& bias_lin = pre.bias_linearisation();
  const Eigen::Vector3d d_ba = speed_bias_i.segment<3>(3) - bias_lin.accel_mps2;
  const Eigen::Vector3d d_bg = speed_bias_i.segment<3>(6) - bias_lin.gyro_radps;
  const double dt = pre.dt_s();
  const Eigen::Vector3d& g = gravity_L_mps2_;
  const Eigen::Matrix3d& R_i = pose_i.R_LI;
  const Eigen::Matrix3d& R_j = pose_j.R_LI;

  // Forster eq. 45 with the bias-corrected deltas of eq. 44.
  const Eigen::Vector3d phi_bg = pre.d_R_d_bg() * d_bg;
  const Eigen::Matrix3d delta_R_corrected = pre.delta_R() * core::ExpSO3(phi_bg);
  const Eigen::Matrix3d E_r = delta_R_corrected.transpose() * R_i.transpose() * R_j;
  const Eigen::Vector3d r_R = core::LogSO3(E_r);
  const Eigen::Vector3d u_v = R_i.transpose() * (v_j - v_i - g * dt);
  const Eigen::Vector3d u_p =
      R_i.transpose() * (pose_j.p_LI - pose_i.p_LI - v_i * dt - 0.5 * g * dt * dt);
  const Eigen::Vector3d r_v = u_v - (pre.delta_v() + pre.d_v_d_bg() * d_bg + pre.d_v_d_ba() * d_ba);
  const Eigen::Vector3d r_p = u_p - (pre.delta_p() + pre.d_p_d_bg() * d_bg + pre.d_p_d_ba() * d_ba);

  Vector9d r;
  r << r_R, r_v, r_p;
  Eigen::Map<Vector9d>{residuals} = sqrt_information_ * r;

  if (jacobians != nullptr) {
    // Forster Appendix C; the position perturbation is additive in L (p + δp), so
    // ∂r_Δp/∂δp = ∓R_iᵀ instead of Forster's ∓I (p + R δp).
    const Eigen::Matrix3d Jr_inv = core::InverseRightJacobianSO3(r_R);
    const Eigen::Matrix3d R_iT = R_i.transpose();
    if (jacobians[0] != nullptr) {  // pose_i: [δp_i, δθ_i]
      Eigen::Matrix<double, 9, 6> J = Eigen::Matrix<double, 9, 6>::Zero();
      J.block<3, 3>(0, 3) = -Jr_inv * R_j.transpose() * R_i;
      J.block<3, 3>(3, 3) = core::Hat(u_v);
      J.block<3, 3>(6, 0) = -R_iT;
      J.block<3, 3>(6, 3) = core::Hat(u_p);
      SetPoseJacobian<9>(sqrt_information_.lazyProduct(J), parameters[0], jacobians[0]);
    }
    if (jacobians[1] != nullptr) {  // speed_bias_i: [v_i, b_a, b_g]
      Eigen::Matrix<double, 9, 9> J = Eigen::Matrix<double, 9, 9>::Zero();
      // ∂r_ΔR/∂b_g = −Jr^{-1}(r) Exp(r)ᵀ Jr(J^R_bg δb_g) J^R_bg (Forster Appendix C).
      J.block<3, 3>(0, 6) =
          -Jr_inv * E_r.transpose() * core::RightJacobianSO3(phi_bg) * pre.d_R_d_bg();
      J.block<3, 3>(3, 0) = -R_iT;
      J.block<3, 3>(3, 3) = -pre.d_v_d_ba();
      J.block<3, 3>(3, 6) = -pre.d_v_d_bg();
      J.block<3, 3>(6, 0) = -R_iT * dt;
      J.block<3, 3>(6, 3) = -pre.d_p_d_ba();
      J.block<3, 3>(6, 6) = -pre.d_p_d_bg();
      SetJacobian<9, 9>(sqrt_information_.lazyProduct(J), jacobians[1]);
    }
    if (jacobians[2] != nullptr) {  // pose_j: [δp_j, δθ_j]
      Eigen::Matrix<double, 9, 6> J = Eigen::Matrix<double, 9, 6>::Zero();
      J.block<3, 3>(0, 3) = Jr_inv;
      J.block<3, 3>(6, 0) = R_iT;
      SetPoseJacobian<9>(sqrt_information_.lazyProduct(J), parameters[2], jacobians[2]);
    }
    if (jacobians[3] != nullptr) {  // speed_bias_j: only through v_j
      Eigen::Matrix<double, 9, 9> J = Eigen::Matrix<double, 9, 9>::Zero();
      J.block<3, 3>(3, 0) = R_iT;
      SetJacobian<9, 9>(sqrt_information_.lazyProduct(J), jacobians[3]);
    }
  }
  return OutputsFinite(*this, residuals, jacobians);
}

// ---- bias random walk ----

BiasRandomWalkFactor::BiasRandomWalkFactor(double dt_s, const ImuNoiseParams& noise) {
  const double sigma_ba = noise.accel_random_walk_mps3_per_sqrthz * std::sqrt(dt_s);
  const double sigma_bg = noise.gyro_random_walk_radps2_per_sqrthz * std::sqrt(dt_s);
  if (!(dt_s > 0.0) || !(sigma_ba > 0.0) || !(sigma_bg > 0.0) || !std::isfinite(sigma_ba) ||
      !std::isfinite(sigma_bg)) {
    throw std::invalid_argument(
        "BiasRandomWalkFactor: dt_s and both bias random walks must be positive and finite");
  }
  inv_sigma_ba_ = 1.0 / sigma_ba;
  inv_sigma_bg_ = 1.0 / sigma_bg;
}

bool BiasRandomWalkFactor::Evaluate(double const* const* parameters, double* residuals,
                                    double** jacobians) const {
  const Eigen::Map<const Vector9d> speed_bias_i(parameters[0]);
  const Eigen::Map<const Vector9d> speed_bias_j(parameters[1]);
  if (!speed_bias_i.allFinite() || !speed_bias_j.allFinite()) return false;
  Eigen::Map<Eigen::Matrix<double, 6, 1>> r(residuals);
  r.head<3>() = inv_sigma_ba_ * (speed_bias_j.segment<3>(3) - speed_bias_i.segment<3>(3));
  r.tail<3>() = inv_sigma_bg_ * (speed_bias_j.segment<3>(6) - speed_bias_i.segment<3>(6));
  if (jacobians != nullptr) {
    Eigen::Matrix<double, 6, 9> J = Eigen::Matrix<double, 6, 9>::Zero();
    J.block<3, 3>(0, 3) = inv_sigma_ba_ * Eigen::Matrix3d::Identity();
    J.block<3, 3>(3, 6) = inv_sigma_bg_ * Eigen::Matrix3d::Identity();
    if (jacobians[0] != nullptr) SetJacobian<6, 9>(-J, jacobians[0]);
    if (jacobians[1] != nullptr) SetJacobian<6, 9>(J, jacobians[1]);
  }
  return OutputsFinite(*this, residuals, jacobians);
}

// ---- pose between (seed paper eq. 2) ----

PoseBetweenFactor::PoseBetweenFactor(const Eigen::Isometry3d& T_IJ_measured,
                                     const Eigen::Matrix<double, 6, 6>& sqrt_information)
    : R_IJ_measured_(T_IJ_measured.linear()),
      p_IJ_measured_(T_IJ_measured.translation()),
      sqrt_information_(sqrt_information) {}

bool PoseBetweenFactor::Evaluate(double const* const* parameters, double* residuals,
                                 double** jacobians) const {
  PoseBlock pose_i;
  PoseBlock pose_j;
  if (!ReadPose(parameters[0], &pose_i) || !ReadPose(parameters[1], &pose_j)) return false;
  const Eigen::Matrix3d& R_i = pose_i.R_LI;
  const Eigen::Matrix3d& R_j = pose_j.R_LI;
  const Eigen::Vector3d u = R_i.transpose() * (pose_j.p_LI - pose_i.p_LI);  // p_IJ
  const Eigen::Matrix3d E_r = R_IJ_measured_.transpose() * R_i.transpose() * R_j;
  const Eigen::Vector3d r_theta = core::LogSO3(E_r);
  Eigen::Matrix<double, 6, 1> r;
  r << u - p_IJ_measured_, r_theta;
  Eigen::Map<Eigen::Matrix<double, 6, 1>>{residuals} = sqrt_information_ * r;

  if (jacobians != nullptr) {
    const Eigen::Matrix3d Jr_inv = core::InverseRightJacobianSO3(r_theta);
    if (jacobians[0] != nullptr) {
      Eigen::Matrix<double, 6, 6> J = Eigen::Matrix<double, 6, 6>::Zero();
      J.block<3, 3>(0, 0) = -R_i.transpose();
      J.block<3, 3>(0, 3) = core::Hat(u);  // R_i Exp(δθ): (I − [δθ]x) R_iᵀ Δp
      J.block<3, 3>(3, 3) = -Jr_inv * R_j.transpose() * R_i;
      SetPoseJacobian<6>(sqrt_information_.lazyProduct(J), parameters[0], jacobians[0]);
    }
    if (jacobians[1] != nullptr) {
      Eigen::Matrix<double, 6, 6> J = Eigen::Matrix<double, 6, 6>::Zero();
      J.block<3, 3>(0, 0) = R_i.transpose();
      J.block<3, 3>(3, 3) = Jr_inv;
      SetPoseJacobian<6>(sqrt_information_.lazyProduct(J), parameters[1], jacobians[1]);
    }
  }
  return OutputsFinite(*this, residuals, jacobians);
}

// ---- position between (seed paper eq. 3) ----

PositionBetweenFactor::PositionBetweenFactor(const Eigen::Vector3d& p_Is,
                                             const Eigen::Matrix3d& R_LA,
                                             const Eigen::Vector3d& delta_p_A_measured,
                                             const Eigen::Matrix3d& sqrt_information)
    : p_Is_(p_Is),
      delta_p_L_measured_(R_LA * delta_p_A_measured),
      sqrt_information_(sqrt_information) {}

bool PositionBetweenFactor::Evaluate(double const* const* parameters, double* residuals,
                                     double** jacobians) const {
  PoseBlock pose_i;
  PoseBlock pose_j;
  if (!ReadPose(parameters[0], &pose_i) || !ReadPose(parameters[1], &pose_j)) return false;
  const Eigen::Vector3d r = (pose_j.p_LI + pose_j.R_LI * p_Is_) -
                            (pose_i.p_LI + pose_i.R_LI * p_Is_) - delta_p_L_measured_;
  Eigen::Map<Eigen::Vector3d>{residuals} = sqrt_information_ * r;

  if (jacobians != nullptr) {
    // R Exp(δθ) p_Is ≈ R p_Is − R [p_Is]x δθ.
    const Eigen::Matrix3d lever_hat = core::Hat(p_Is_);
    if (jacobians[0] != nullptr) {
      Eigen::Matrix<double, 3, 6> J;
      J << -Eigen::Matrix3d::Identity(), pose_i.R_LI * lever_hat;
      SetPoseJacobian<3>(sqrt_information_.lazyProduct(J), parameters[0], jacobians[0]);
    }
    if (jacobians[1] != nullptr) {
      Eigen::Matrix<double, 3, 6> J;
      J << Eigen::Matrix3d::Identity(), -pose_j.R_LI * lever_hat;
      SetPoseJacobian<3>(sqrt_information_.lazyProduct(J), parameters[1], jacobians[1]);
    }
  }
  return OutputsFinite(*this, residuals, jacobians);
}

// ---- position in L (through the frozen T_AL) ----

PositionInLocalFactor::PositionInLocalFactor(const Eigen::Vector3d& p_Is,
                                             const Eigen::Vector3d& p_L_measured,
                                             const Eigen::Matrix3d& sqrt_information)
    : p_Is_(p_Is), p_L_measured_(p_L_measured), sqrt_information_(sqrt_information) {}

bool PositionInLocalFactor::Evaluate(double const* const* parameters, double* residuals,
                                     double** jacobians) const {
  PoseBlock pose;
  if (!ReadPose(parameters[0], &pose)) return false;
  const Eigen::Vector3d r = pose.p_LI + pose.R_LI * p_Is_ - p_L_measured_;
  Eigen::Map<Eigen::Vector3d>{residuals} = sqrt_information_ * r;
  if (jacobians != nullptr && jacobians[0] != nullptr) {
    // R Exp(δθ) p_Is ≈ R p_Is − R [p_Is]x δθ.
    Eigen::Matrix<double, 3, 6> J;
    J << Eigen::Matrix3d::Identity(), -pose.R_LI * core::Hat(p_Is_);
    SetPoseJacobian<3>(sqrt_information_.lazyProduct(J), parameters[0], jacobians[0]);
  }
  return OutputsFinite(*this, residuals, jacobians);
}

PositionWithOffsetFactor::PositionWithOffsetFactor(const Eigen::Vector3d& p_Is,
                                                   const Eigen::Vector3d& p_L_measured,
                                                   const Eigen::Matrix3d& sqrt_information)
    : p_Is_(p_Is), p_L_measured_(p_L_measured), sqrt_information_(sqrt_information) {}

bool PositionWithOffsetFactor::Evaluate(double const* const* parameters, double* residuals,
                                        double** jacobians) const {
  PoseBlock pose;
  if (!ReadPose(parameters[0], &pose)) return false;
  const Eigen::Map<const Eigen::Vector3d> o_L(parameters[1]);
  const Eigen::Vector3d r = pose.p_LI + pose.R_LI * p_Is_ - p_L_measured_ - o_L;
  Eigen::Map<Eigen::Vector3d>{residuals} = sqrt_information_ * r;
  if (jacobians != nullptr && jacobians[0] != nullptr) {
    Eigen::Matrix<double, 3, 6> J;
    J << Eigen::Matrix3d::Identity(), -pose.R_LI * core::Hat(p_Is_);
    SetPoseJacobian<3>(sqrt_information_.lazyProduct(J), parameters[0], jacobians[0]);
  }
  if (jacobians != nullptr && jacobians[1] != nullptr) {
    Eigen::Map<Eigen::Matrix<double, 3, 3, Eigen::RowMajor>>{jacobians[1]} = -sqrt_information_;
  }
  return OutputsFinite(*this, residuals, jacobians);
}

// ---- priors ----

PosePriorFactor::PosePriorFactor(const double* pose_prior,
                                 const Eigen::Matrix<double, 6, 6>& sqrt_information)
    : PosePriorFactor(
          Eigen::Vector3d(pose_prior[0], pose_prior[1], pose_prior[2]),
          Eigen::Quaterniond(pose_prior[6], pose_prior[3], pose_prior[4], pose_prior[5]),
          sqrt_information) {}

PosePriorFactor::PosePriorFactor(const Eigen::Vector3d& p_LI_prior,
                                 const Eigen::Quaterniond& q_LI_prior,
                                 const Eigen::Matrix<double, 6, 6>& sqrt_information)
    : p_LI_prior_(p_LI_prior),
      q_LI_prior_(q_LI_prior.normalized()),
      sqrt_information_(sqrt_information) {}

bool PosePriorFactor::Evaluate(double const* const* parameters, double* residuals,
                               double** jacobians) const {
  PoseBlock pose;
  if (!ReadPose(parameters[0], &pose)) return false;
  // x ⊟ x0 (PoseManifold::Minus).
  const Eigen::Vector3d delta_theta = core::LogQuat(q_LI_prior_.conjugate() * pose.q_LI);
  Eigen::Matrix<double, 6, 1> r;
  r << pose.p_LI - p_LI_prior_, delta_theta;
  Eigen::Map<Eigen::Matrix<double, 6, 1>>{residuals} = sqrt_information_ * r;
  if (jacobians != nullptr && jacobians[0] != nullptr) {
    Eigen::Matrix<double, 6, 6> J = Eigen::Matrix<double, 6, 6>::Identity();
    J.block<3, 3>(3, 3) = core::InverseRightJacobianSO3(delta_theta);
    SetPoseJacobian<6>(sqrt_information_.lazyProduct(J), parameters[0], jacobians[0]);
  }
  return OutputsFinite(*this, residuals, jacobians);
}

SpeedBiasPriorFactor::SpeedBiasPriorFactor(const double* speed_bias_prior,
                                           const Eigen::Matrix<double, 9, 9>& sqrt_information)
    : speed_bias_prior_(Eigen::Map<const Vector9d>(speed_bias_prior)),
      sqrt_information_(sqrt_information) {}

SpeedBiasPriorFactor::SpeedBiasPriorFactor(const Eigen::Matrix<double, 9, 1>& speed_bias_prior,
                                           const Eigen::Matrix<double, 9, 9>& sqrt_information)
    : speed_bias_prior_(speed_bias_prior), sqrt_information_(sqrt_information) {}

bool SpeedBiasPriorFactor::Evaluate(double const* const* parameters, double* residuals,
                                    double** jacobians) const {
  const Eigen::Map<const Vector9d> x(parameters[0]);
  if (!x.allFinite()) return false;
  Eigen::Map<Vector9d>{residuals} = sqrt_information_ * (x - speed_bias_prior_);
  if (jacobians != nullptr && jacobians[0] != nullptr) {
    SetJacobian<9, 9>(sqrt_information_, jacobians[0]);
  }
  return OutputsFinite(*this, residuals, jacobians);
}

}  // namespace tofu::estimator
