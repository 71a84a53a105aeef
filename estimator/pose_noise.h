#pragma once
// The noise of a pose stream's between factor from the stream's own error model (issue 34,
// item 4). A drifting odometry (a VIO, a LiDAR odometry; sim/odometry_frame.h) reports
//   R̂_As,k = R_err,k R_As,k Exp(w_θ,k),   p̂_As,k = p_As,k + o_k + w_p,k:
// a white error w_k = [w_θ; w_p] ~ N(0, W_k) in core::PoseMeasurement's perturbation
// [δθ_s; δp_A] (δθ right in s, δp in A), and a drift of its frame, R_err and o_k, whose
// increment between two poses d metres apart is isotropic, σ_θ² d and σ_p² d per axis
// (the frame's common error cancels in their relative motion, and an isotropic increment
// has the same covariance in I_i and I_j; the lever arm's share of the rotation increment,
// below 0.1 mm at 10 cm and 1 mrad, is left out).
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
///   T_IJ = T_Is (T_As,i⁻¹ T_As,j) T_Is⁻¹,
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

/// Square-root information of the directions a symmetric projector P keeps of a residual
/// with covariance Σ: their marginal information (P Σ P)⁺, as U P with Uᵀ U =
/// (P Σ P + I − P)⁻¹. Multiplying the square root of Σ⁻¹ by P instead would fuse the
/// conditional information, over-confident wherever Σ couples kept and dropped directions
/// (a LiDAR odometry's degenerate axis, left out, and its observed ones).
Eigen::Matrix<double, 6, 6> ObservedSqrtInformation(const Eigen::Matrix<double, 6, 6>& covariance,
                                                    const Eigen::Matrix<double, 6, 6>& projector);

}  // namespace tofu::estimator
