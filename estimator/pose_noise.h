#pragma once
// The noise of a pose stream's between factor from the stream's own error model (issue 34,
// item 4): a white error on every pose plus a random walk in the distance travelled, the
// model of a drifting odometry (a VIO, a LiDAR odometry; sim/odometry_frame.h):
//   T̂_As,k = T_As,k ⊞ (w_k + o_k),   w_k ~ N(0, W_k) white,   o_k+1 − o_k ~ N(0, Q d_k),
// with the perturbation [δθ_s; δp_A] of core::PoseMeasurement (δθ a right perturbation in
// s, δp in A) and d_k the distance travelled between the two poses.
//
// Consecutive displacements of one stream share a pose's white error: the factor from
// keyframe i to j and the one from j to l both hold w_j, with opposite signs. Fused as
// independent (the paper's eq. 2 with one constant weight), their joint covariance is
// misstated either way: the sum of n displacements gets n·(W_i + W_j) where the truth has
// W_first + W_last, and their difference (the curvature of the path, which the IMU also
// sees) gets half the variance it has. No set of independent between factors can state
// the tridiagonal covariance exactly (that takes a state per pose's white error). What
// they can state is a bound: for any two blocks of a covariance that share w_j through
// Jacobians J_a and J_b,
//   [J_a; J_b] W_j [J_a; J_b]ᵀ ⪯ 2 diag(J_a W_j J_aᵀ, J_b W_j J_bᵀ)
// (the difference is [J_a; −J_b] W_j [J_a; −J_b]ᵀ ⪰ 0), so the factor covariance
//   Σ_ij = 2 (J_i W_i J_iᵀ + J_j W_j J_jᵀ) + Q d_ij
// dominates the joint covariance of any chain of them: the fused information is never
// more than the stream holds, whatever the correlation. The doubling is the price; where
// the drift dominates the white error over a keyframe's travel (a VIO's position) it is
// small, and the drift, unlike the paper's one constant weight, grows with the distance
// flown between the keyframes.
// Library code: Eigen and core/ only.

#include <Eigen/Core>
#include <Eigen/Geometry>

namespace tofu::estimator {

/// A pose stream's drift: per axis, per square root of the distance travelled by s.
/// Position in A, rotation as a perturbation in s (taken isotropic: a VIO's heading
/// drift stands for its smaller tilt drift too).
struct PoseDriftRates {
  double position_random_walk_m_per_sqrtm = 0.0;
  double rotation_random_walk_rad_per_sqrtm = 0.0;
};

/// Jacobian of the relative motion of I between two poses of a sensor s mounted at T_Is,
///   T_IJ = T_Is (T_As,iᵀ T_As,j) T_Isᵀ,
/// in PoseBetweenFactor's residual order [δp_IJ (in I_i); δθ_IJ (right, in I_j)], with
/// respect to the two poses' perturbations [δθ_i; δp_i; δθ_j; δp_j] (core::PoseMeasurement's
/// order: δθ right in s, δp in A). First order in the perturbations.
Eigen::Matrix<double, 6, 12> PoseBetweenJacobian(const Eigen::Isometry3d& T_As_i,
                                                 const Eigen::Isometry3d& T_As_j,
                                                 const Eigen::Isometry3d& T_Is);

/// The between factor's covariance [δp_IJ; δθ_IJ] bounding the chain's joint covariance
/// (header comment): 2 (J_i W_i J_iᵀ + J_j W_j J_jᵀ) + Q d, W the two poses' white
/// covariances in core::PoseMeasurement's order [δθ_s; δp_A], d ≥ 0 the distance the mount
/// travelled between them. d must not come from the two poses themselves: a weight that
/// grows with the measurement's own error biases the estimate (displacements measured
/// short would be trusted more, and the fused path shrinks; measured in
/// LocalSmoother.ADriftingPoseStreamWeightedByItsOwnNoiseIsConsistent, where it did).
Eigen::Matrix<double, 6, 6> PoseBetweenCovariance(const Eigen::Isometry3d& T_As_i,
                                                  const Eigen::Matrix<double, 6, 6>& white_i,
                                                  const Eigen::Isometry3d& T_As_j,
                                                  const Eigen::Matrix<double, 6, 6>& white_j,
                                                  const Eigen::Isometry3d& T_Is,
                                                  const PoseDriftRates& drift, double distance_m);

}  // namespace tofu::estimator
