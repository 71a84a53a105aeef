#pragma once
// Parameter blocks, manifold and cost functions of the local fixed-lag smoother: IMU
// preintegration factor (Forster et al., TRO 2016, eq. 45), bias random walk, the seed
// paper's pose between factor r^o (eq. 2) and position between factor r^p (eq. 3), and
// priors. Every factor has analytic Jacobians and a whitened residual S r with
// Sᵀ S = Σ^{-1}.
//
// Parameter blocks:
//   pose        double[7] = {p_x, p_y, p_z, q_x, q_y, q_z, q_w}: T_LI, position of I in L,
//               then the Eigen quaternion coefficients q_LI in Eigen's memory order.
//               Tangent [δp, δθ]: p + δp (in L), q ⊗ Exp(δθ) (right perturbation).
//   speed_bias  double[9] = {v_L (m/s), b_a (m/s²), b_g (rad/s)}: Euclidean.
//
// Jacobian convention: a factor's Jacobian w.r.t. a pose block is written in ambient form
// (n x 7) as J_tangent (n x 6) · PoseLiftJacobian(pose). PoseLiftJacobian is the
// pseudo-inverse of the PlusJacobian, so Ceres's J_ambient · PlusJacobian equals the
// analytic tangent Jacobian exactly; as the factors normalise the quaternion they read,
// J_ambient is also the true derivative w.r.t. the 7 stored numbers.
// Library code: no MuJoCo, no simulator, no I/O.

#include <vector>

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <ceres/cost_function.h>
#include <ceres/manifold.h>
#include <ceres/sized_cost_function.h>

#include "estimator/imu_preintegration.h"

namespace tofu::estimator {

constexpr int kPoseSize = 7;
constexpr int kPoseTangentSize = 6;
constexpr int kSpeedBiasSize = 9;

// ---- the pose manifold ----

/// SE(3) as R³ × S³ with a right-perturbed rotation and an additive position in L:
///   Plus(x, [δp, δθ]) = {p + δp, normalise(q ⊗ Exp(δθ))},
///   Minus(y, x)       = [p_y − p_x, Log(q_x^{-1} ⊗ q_y)].
/// Quaternions are expected unit (Plus keeps them so).
class PoseManifold final : public ceres::Manifold {
 public:
  int AmbientSize() const override { return kPoseSize; }
  int TangentSize() const override { return kPoseTangentSize; }
  bool Plus(const double* x, const double* delta, double* x_plus_delta) const override;
  /// 7x6 row-major: [I 0; 0 G(q)], G(q) = ½ [w I + [v]x; −vᵀ] = ∂(q ⊗ Exp(δθ))/∂δθ at 0.
  bool PlusJacobian(const double* x, double* jacobian) const override;
  bool Minus(const double* y, const double* x, double* y_minus_x) const override;
  /// 6x7 row-major: [I 0; 0 2 [w I − [v]x, −v]] = ∂Minus(y, x)/∂y at y = x.
  bool MinusJacobian(const double* x, double* jacobian) const override;
};

/// Pseudo-inverse of PoseManifold's PlusJacobian at `pose` (kPoseSize numbers):
/// [I 0; 0 4 G(q)ᵀ] = [I 0; 0 2 [w I − [v]x, −v]] (Gᵀ G = I/4 for a unit q), so
/// Lift · PlusJacobian = I6. Equal to the MinusJacobian.
Eigen::Matrix<double, 6, 7> PoseLiftJacobian(const double* pose);

/// Evaluates `cost` at `blocks` and returns each block's Jacobian times that block's
/// PlusJacobian (tangent Jacobians, n x TangentSize). manifolds[k] == nullptr means
/// Euclidean; `manifolds` may be empty (all Euclidean). tangent_jacobians may be null
/// (residual only). Returns false if the cost function does.
bool EvaluateTangent(const ceres::CostFunction& cost, const std::vector<const double*>& blocks,
                     const std::vector<const ceres::Manifold*>& manifolds,
                     Eigen::VectorXd* residual, std::vector<Eigen::MatrixXd>* tangent_jacobians);

// ---- factors ----

/// IMU preintegration factor (Forster eq. 45). Blocks (pose_i, speed_bias_i, pose_j,
/// speed_bias_j). Residual [r_ΔR, r_Δv, r_Δp] with δb = b_i − b̄ (b̄ the preintegration's
/// linearisation bias):
///   r_ΔR = Log((ΔR̃ Exp(J^R_bg δb_g))ᵀ R_iᵀ R_j)
///   r_Δv = R_iᵀ (v_j − v_i − g Δt) − (Δṽ + J^v_bg δb_g + J^v_ba δb_a)
///   r_Δp = R_iᵀ (p_j − p_i − v_i Δt − ½ g Δt²) − (Δp̃ + J^p_bg δb_g + J^p_ba δb_a)
/// whitened by S = L^{-1}, Σ = L Lᵀ the preintegration covariance. Jacobians: Forster
/// Appendix C, adapted to the additive position perturbation in L.
class ImuFactor : public ceres::SizedCostFunction<9, 7, 9, 7, 9> {
 public:
  /// Copies the preintegration. Throws std::invalid_argument if its dt_s() is not positive
  /// or its covariance is not positive definite (zero accelerometer or gyro noise).
  ImuFactor(const ImuPreintegration& preintegration, const Eigen::Vector3d& gravity_L_mps2);

  bool Evaluate(double const* const* parameters, double* residuals,
                double** jacobians) const override;

  const ImuPreintegration& preintegration() const { return preintegration_; }
  const Eigen::Matrix<double, 9, 9>& sqrt_information() const { return sqrt_information_; }

 private:
  ImuPreintegration preintegration_;
  Eigen::Vector3d gravity_L_mps2_;
  Eigen::Matrix<double, 9, 9> sqrt_information_;  ///< L^{-1}, lower triangular
};

/// Bias random walk between consecutive states (Kalibr convention). Blocks
/// (speed_bias_i, speed_bias_j); residual [b_a_j − b_a_i; b_g_j − b_g_i] divided per
/// component by σ_rw √dt.
class BiasRandomWalkFactor : public ceres::SizedCostFunction<6, 9, 9> {
 public:
  /// Throws std::invalid_argument unless dt_s > 0 and both random walks are > 0.
  BiasRandomWalkFactor(double dt_s, const ImuNoiseParams& noise);

  bool Evaluate(double const* const* parameters, double* residuals,
                double** jacobians) const override;

 private:
  double inv_sigma_ba_;  ///< 1 / (σ_ba √dt)
  double inv_sigma_bg_;  ///< 1 / (σ_bg √dt)
};

/// Pose between factor r^o (seed paper eq. 2), with the translation residual expressed in
/// I_i so that an anisotropic covariance given in I_i applies. Blocks (pose_i, pose_j);
/// residual S [r_p; r_θ]:
///   r_p = R_iᵀ (p_j − p_i) − p̄_IJ,   r_θ = Log(R̄_IJᵀ R_iᵀ R_j).
class PoseBetweenFactor : public ceres::SizedCostFunction<6, 7, 7> {
 public:
  PoseBetweenFactor(const Eigen::Isometry3d& T_IJ_measured,
                    const Eigen::Matrix<double, 6, 6>& sqrt_information);

  bool Evaluate(double const* const* parameters, double* residuals,
                double** jacobians) const override;

 private:
  Eigen::Matrix3d R_IJ_measured_;
  Eigen::Vector3d p_IJ_measured_;
  Eigen::Matrix<double, 6, 6> sqrt_information_;
};

/// Position between factor r^p (seed paper eq. 3, sign typo fixed): the displacement of
/// a sensor's mount point between two states, measured in the sensor's reference frame A.
/// Blocks (pose_i, pose_j); residual S r, in L:
///   r = (p_j + R_j p_Is) − (p_i + R_i p_Is) − R_LA Δp̄_A.
class PositionBetweenFactor : public ceres::SizedCostFunction<3, 7, 7> {
 public:
  /// p_Is: lever arm (sensor mount point in I) [m]; R_LA: rotation of A in L (q_AL^{-1}),
  /// held constant; delta_p_A_measured: p̄_b − p̄_a in A [m].
  PositionBetweenFactor(const Eigen::Vector3d& p_Is, const Eigen::Matrix3d& R_LA,
                        const Eigen::Vector3d& delta_p_A_measured,
                        const Eigen::Matrix3d& sqrt_information);

  bool Evaluate(double const* const* parameters, double* residuals,
                double** jacobians) const override;

 private:
  Eigen::Vector3d p_Is_;
  Eigen::Vector3d delta_p_L_measured_;  ///< R_LA Δp̄_A
  Eigen::Matrix3d sqrt_information_;
};

/// Position of a sensor's mount point in L (beyond the paper, which fuses positions only
/// as displacements, eq. 3): a unary factor on one pose through the sensor's frozen
/// alignment, p̄_L = T_LA p̄_A. Residual S r, in L:
///   r = (p + R p_Is) − p̄_L.
/// A displacement chain throws away what makes an absolute sensor absolute: fused with a
/// drifting odometry's displacements it drifts with it (docs/RESULTS.md, issue 16).
class PositionInLocalFactor : public ceres::SizedCostFunction<3, 7> {
 public:
  PositionInLocalFactor(const Eigen::Vector3d& p_Is, const Eigen::Vector3d& p_L_measured,
                        const Eigen::Matrix3d& sqrt_information);

  bool Evaluate(double const* const* parameters, double* residuals,
                double** jacobians) const override;

 private:
  Eigen::Vector3d p_Is_;
  Eigen::Vector3d p_L_measured_;
  Eigen::Matrix3d sqrt_information_;
};

/// Position of a sensor's mount point in L up to an offset the graph estimates: one
/// offset per chain (the translation of T_LA, o_L = p_LA, from the chain's first
/// position on). Residual S r, in L:
///   r = (p + R p_Is) − (R_LA p̄_A + o_L).
/// With white position noise this is exactly what the paper's displacements (eq. 3) carry
/// once their correlation is accounted for: consecutive displacements p̄_k+1 − p̄_k share
/// the noise of p̄_k, and a chain of them fused as independent factors states the sum of
/// n displacements as n times as uncertain as its two ends make it. The offset, free at
/// the chain's start, keeps the paper's seamless switching (a sensor fused again starts a
/// new chain at zero residual) without the frozen T_AL's translation taken as exact.
class PositionWithOffsetFactor : public ceres::SizedCostFunction<3, 7, 3> {
 public:
  PositionWithOffsetFactor(const Eigen::Vector3d& p_Is, const Eigen::Vector3d& p_L_measured,
                           const Eigen::Matrix3d& sqrt_information);

  bool Evaluate(double const* const* parameters, double* residuals,
                double** jacobians) const override;

 private:
  Eigen::Vector3d p_Is_;
  Eigen::Vector3d p_L_measured_;  ///< R_LA p̄_A
  Eigen::Matrix3d sqrt_information_;
};

/// Prior on a pose: r = S (x ⊟ x0) = S [p − p0; Log(q0^{-1} q)] (PoseManifold::Minus).
class PosePriorFactor : public ceres::SizedCostFunction<6, 7> {
 public:
  /// pose_prior: kPoseSize numbers in the pose block layout.
  PosePriorFactor(const double* pose_prior, const Eigen::Matrix<double, 6, 6>& sqrt_information);
  PosePriorFactor(const Eigen::Vector3d& p_LI_prior, const Eigen::Quaterniond& q_LI_prior,
                  const Eigen::Matrix<double, 6, 6>& sqrt_information);

  bool Evaluate(double const* const* parameters, double* residuals,
                double** jacobians) const override;

 private:
  Eigen::Vector3d p_LI_prior_;
  Eigen::Quaterniond q_LI_prior_;
  Eigen::Matrix<double, 6, 6> sqrt_information_;
};

/// Prior on a speed-bias block: r = S (x − x0).
class SpeedBiasPriorFactor : public ceres::SizedCostFunction<9, 9> {
 public:
  /// speed_bias_prior: kSpeedBiasSize numbers in the speed-bias block layout.
  SpeedBiasPriorFactor(const double* speed_bias_prior,
                       const Eigen::Matrix<double, 9, 9>& sqrt_information);
  SpeedBiasPriorFactor(const Eigen::Matrix<double, 9, 1>& speed_bias_prior,
                       const Eigen::Matrix<double, 9, 9>& sqrt_information);

  bool Evaluate(double const* const* parameters, double* residuals,
                double** jacobians) const override;

 private:
  Eigen::Matrix<double, 9, 1> speed_bias_prior_;
  Eigen::Matrix<double, 9, 9> sqrt_information_;
};

}  // namespace tofu::estimator
