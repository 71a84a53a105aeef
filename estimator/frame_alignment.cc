#include "estimator/frame_alignment.h"

#include <cmath>

#include <Eigen/SVD>

namespace tofu::estimator {

std::optional<AlignmentResult> AlignPositions(const std::vector<Eigen::Vector3d>& p_L,
                                              const std::vector<Eigen::Vector3d>& p_A,
                                              double min_spread_m2) {
  const size_t n = std::min(p_L.size(), p_A.size());
  if (n < 3) return std::nullopt;
  Eigen::Matrix3Xd src(3, static_cast<Eigen::Index>(n));
  Eigen::Matrix3Xd dst(3, static_cast<Eigen::Index>(n));
  for (size_t i = 0; i < n; ++i) {
    src.col(static_cast<Eigen::Index>(i)) = p_L[i];
    dst.col(static_cast<Eigen::Index>(i)) = p_A[i];
  }
  AlignmentResult result;
  // Spread of the motion: eigenvalues of the covariance of the L positions.
  const Eigen::Vector3d mean = src.rowwise().mean();
  const Eigen::Matrix3Xd centred = src.colwise() - mean;
  const Eigen::Matrix3d covariance = centred * centred.transpose() / static_cast<double>(n);
  const Eigen::JacobiSVD<Eigen::Matrix3d> svd(covariance);
  result.spread_m2 = svd.singularValues();
  const int spanned = static_cast<int>((result.spread_m2.array() > min_spread_m2).count());
  if (spanned == 0) return std::nullopt;
  result.observable_rotation_dofs = spanned >= 2 ? 3 : 2;
  // Eigen's implementation of Umeyama's closed form (rotation + translation, no scale).
  const Eigen::Matrix4d T = Eigen::umeyama(src, dst, /*with_scaling=*/false);
  result.T_AL.matrix() = T;
  double sum_squares = 0.0;
  for (size_t i = 0; i < n; ++i) sum_squares += (result.T_AL * p_L[i] - p_A[i]).squaredNorm();
  result.rms_residual_m = std::sqrt(sum_squares / static_cast<double>(n));
  return result;
}

std::optional<Eigen::Isometry3d> AlignPositionsLevel(const std::vector<Eigen::Vector3d>& p_L,
                                                     const std::vector<Eigen::Vector3d>& p_A) {
  const size_t n = std::min(p_L.size(), p_A.size());
  if (n < 3) return std::nullopt;
  Eigen::Vector3d c_L = Eigen::Vector3d::Zero();
  Eigen::Vector3d c_A = Eigen::Vector3d::Zero();
  for (size_t i = 0; i < n; ++i) {
    c_L += p_L[i];
    c_A += p_A[i];
  }
  c_L /= static_cast<double>(n);
  c_A /= static_cast<double>(n);
  double sin_sum = 0.0;
  double cos_sum = 0.0;
  for (size_t i = 0; i < n; ++i) {
    const Eigen::Vector2d a = (p_L[i] - c_L).head<2>();
    const Eigen::Vector2d b = (p_A[i] - c_A).head<2>();
    sin_sum += a.x() * b.y() - a.y() * b.x();
    cos_sum += a.dot(b);
  }
  Eigen::Isometry3d T_AL = Eigen::Isometry3d::Identity();
  T_AL.linear() = Eigen::AngleAxisd(std::atan2(sin_sum, cos_sum), Eigen::Vector3d::UnitZ())
                      .toRotationMatrix();
  T_AL.translation() = c_A - T_AL.linear() * c_L;
  return T_AL;
}

}  // namespace tofu::estimator
