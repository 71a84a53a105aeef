#include "estimator/pose_noise.h"

#include <Eigen/Cholesky>

#include "core/lie.h"

namespace tofu::estimator {

// With R̂_k = R_k Exp(a_k), p̂_k = p_k + c_k (k = i, j), R_ij = R_iᵀ R_j, p_ij = R_iᵀ (p_j − p_i)
// and u = −R_Isᵀ p_Is (I's origin in s):
//   R̂_ij = R_ij Exp(ε), ε = a_j − R_ijᵀ a_i;         R̂_IJ = R_IJ Exp(R_Is ε);
//   p̂_ij = p_ij + [p_ij]× a_i + R_iᵀ (c_j − c_i);   R̂_ij u = R_ij u − R_ij [u]× ε;
//   p̂_IJ = R_Is (R̂_ij u + p̂_ij) + p_Is.
Eigen::Matrix<double, 6, 12> PoseBetweenJacobian(const Eigen::Isometry3d& T_As_i,
                                                 const Eigen::Isometry3d& T_As_j,
                                                 const Eigen::Isometry3d& T_Is) {
  const Eigen::Matrix3d R_i = T_As_i.linear();
  const Eigen::Matrix3d R_ij = R_i.transpose() * T_As_j.linear();
  const Eigen::Vector3d p_ij = R_i.transpose() * (T_As_j.translation() - T_As_i.translation());
  const Eigen::Matrix3d R_Is = T_Is.linear();
  const Eigen::Vector3d u = -R_Is.transpose() * T_Is.translation();
  const Eigen::Matrix3d lever = -R_Is * R_ij * core::Hat(u);  // ∂p_IJ/∂ε
  Eigen::Matrix<double, 6, 12> J = Eigen::Matrix<double, 6, 12>::Zero();
  // ε = a_j − R_ijᵀ a_i.
  J.block<3, 3>(0, 0) = lever * -R_ij.transpose() + R_Is * core::Hat(p_ij);
  J.block<3, 3>(0, 3) = -R_Is * R_i.transpose();
  J.block<3, 3>(0, 6) = lever;
  J.block<3, 3>(0, 9) = R_Is * R_i.transpose();
  J.block<3, 3>(3, 0) = -R_Is * R_ij.transpose();
  J.block<3, 3>(3, 6) = R_Is;
  return J;
}

Eigen::Matrix<double, 6, 6> PoseBetweenCovariance(const Eigen::Isometry3d& T_As_i,
                                                  const Eigen::Matrix<double, 6, 6>& white_i,
                                                  const Eigen::Isometry3d& T_As_j,
                                                  const Eigen::Matrix<double, 6, 6>& white_j,
                                                  const Eigen::Isometry3d& T_Is,
                                                  const PoseDriftRates& drift, double distance_m) {
  const Eigen::Matrix<double, 6, 12> J = PoseBetweenJacobian(T_As_i, T_As_j, T_Is);
  const auto J_i = J.leftCols<6>();
  const auto J_j = J.rightCols<6>();
  Eigen::Matrix<double, 6, 6> covariance =
      2.0 * (J_i * white_i * J_i.transpose() + J_j * white_j * J_j.transpose());
  // The drift's increment: a random walk of the position in A (seen in I_i through the
  // rotation R_Is R_iᵀ, isotropic) and of the attitude, per metre travelled.
  covariance.topLeftCorner<3, 3>().diagonal().array() +=
      drift.position_random_walk_m_per_sqrtm * drift.position_random_walk_m_per_sqrtm * distance_m;
  covariance.bottomRightCorner<3, 3>().diagonal().array() +=
      drift.rotation_random_walk_rad_per_sqrtm * drift.rotation_random_walk_rad_per_sqrtm *
      distance_m;
  return 0.5 * (covariance + covariance.transpose());
}

Eigen::Matrix<double, 6, 6> ObservedSqrtInformation(const Eigen::Matrix<double, 6, 6>& covariance,
                                                    const Eigen::Matrix<double, 6, 6>& projector) {
  using Matrix6 = Eigen::Matrix<double, 6, 6>;
  const Matrix6 kept = projector * covariance * projector + (Matrix6::Identity() - projector);
  const Matrix6 information = kept.ldlt().solve(Matrix6::Identity());
  return Eigen::LLT<Matrix6>(information).matrixU() * projector;
}

}  // namespace tofu::estimator
