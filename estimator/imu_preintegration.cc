#include "estimator/imu_preintegration.h"

#include <cmath>
#include <stdexcept>
#include <string>

#include "core/lie.h"

namespace tofu::estimator {

using Matrix93d = Eigen::Matrix<double, 9, 3>;
using Matrix9d = Eigen::Matrix<double, 9, 9>;

// ---- preintegration ----

ImuPreintegration::ImuPreintegration(const ImuBias& bias_linearisation, const ImuNoiseParams& noise)
    : bias_linearisation_(bias_linearisation), noise_(noise) {}

void ImuPreintegration::Reset(const ImuBias& bias_linearisation) {
  *this = ImuPreintegration(bias_linearisation, noise_);
}

// Long by design: one discrete step of Forster et al.'s preintegration (Jacobians, covariance,
// bias Jacobians, deltas) sharing the step's terms, in the paper's order.
void ImuPreintegration::Integrate(const Eigen::Vector3d& accel_I_mps2,
                                  const Eigen::Vector3d& gyro_I_radps, double dt_s) {
  if (!std::isfinite(dt_s) || dt_s < 0.0) {
    throw std::invalid_argument("ImuPreintegration::Integrate: dt_s must be finite and >= 0, got " +
                                std::to_string(dt_s));
  }
  if (!accel_I_mps2.allFinite() || !gyro_I_radps.allFinite()) {
    throw std::invalid_argument("ImuPreintegration::Integrate: non-finite IMU sample");
  }
  if (dt_s == 0.0) return;
  const double dt = dt_s;
  const double dt2 = dt * dt;
  const Eigen::Matrix3d I3 = Eigen::Matrix3d::Identity();

  // Bias-corrected sample at the linearisation point.
  const Eigen::Vector3d a = accel_I_mps2 - bias_linearisation_.accel_mps2;
  const Eigen::Vector3d w = gyro_I_radps - bias_linearisation_.gyro_radps;

  // Step rotation E = Exp(ω dt) and the half step E_h = Exp(½ ω dt) of the midpoint.
  const Eigen::Vector3d phi = w * dt;
  const Eigen::Matrix3d E = core::ExpSO3(phi);
  const Eigen::Matrix3d Jr = core::RightJacobianSO3(phi);
  const Eigen::Matrix3d E_h = core::ExpSO3(0.5 * phi);
  const Eigen::Matrix3d Jr_h = core::RightJacobianSO3(0.5 * phi);
  const Eigen::Matrix3d R_mid = delta_R_ * E_h;  // ΔR_ik^mid

  // Linearised error propagation of the discrete update (Forster eq. 62 / A.7-A.9 with the
  // midpoint attitude): for ΔR_k = ΔR̂_k Exp(δθ_k), ω = ω̂ + δω, f = f̂ + δf,
  //   R_mid ≈ R̂_mid Exp(E_hᵀ δθ_k + Jr_h dt/2 δω), so R_mid f ≈ R̂_mid f̂ + R̂_mid δf
  //   − ΔR̂_k [E_h f̂]x δθ_k − R̂_mid [f̂]x Jr_h dt/2 δω   (R̂_mid [f]x E_hᵀ = ΔR̂_k [E_h f]x).
  const Eigen::Matrix3d dR_fmid_hat = delta_R_ * core::Hat(E_h * a);  // ΔR̂_k [E_h f]x
  const Eigen::Matrix3d Rmid_f_hat_Jr_h = R_mid * core::Hat(a) * Jr_h;

  Matrix9d A = Matrix9d::Identity();
  A.block<3, 3>(0, 0) = E.transpose();
  A.block<3, 3>(3, 0) = -dR_fmid_hat * dt;
  A.block<3, 3>(6, 0) = -0.5 * dR_fmid_hat * dt2;
  A.block<3, 3>(6, 3) = I3 * dt;

  Matrix93d B_g = Matrix93d::Zero();  // ∂[δθ, δv, δp]_{k+1} / ∂δω
  B_g.block<3, 3>(0, 0) = Jr * dt;
  B_g.block<3, 3>(3, 0) = -0.5 * Rmid_f_hat_Jr_h * dt2;
  B_g.block<3, 3>(6, 0) = -0.25 * Rmid_f_hat_Jr_h * dt2 * dt;
  Matrix93d B_a = Matrix93d::Zero();  // ∂[δθ, δv, δp]_{k+1} / ∂δf
  B_a.block<3, 3>(3, 0) = R_mid * dt;
  B_a.block<3, 3>(6, 0) = 0.5 * R_mid * dt2;

  // Covariance: discrete white noise of the sample held over dt has variance σ²/dt.
  const double var_g =
      noise_.gyro_noise_density_radps_per_sqrthz * noise_.gyro_noise_density_radps_per_sqrthz / dt;
  const double var_a =
      noise_.accel_noise_density_mps2_per_sqrthz * noise_.accel_noise_density_mps2_per_sqrthz / dt;
  // Lazy (coefficient-wise) products: Eigen sends 9x9 products to its GEMM, whose packing
  // costs more than the arithmetic at this size (this runs at the IMU rate).
  const Eigen::Matrix<double, 9, 9> A_covariance = A.lazyProduct(covariance_);
  covariance_ = A_covariance.lazyProduct(A.transpose()) +
                var_g * B_g.lazyProduct(B_g.transpose()) + var_a * B_a.lazyProduct(B_a.transpose());
  // The sample-held noise alone ties δp to δv within a step (δp = δv dt/2: one sample
  // gives a singular covariance). White noise in continuous time (Kalibr) also moves the
  // position inside the step: Cov(δp) = σ_a² dt³/3 instead of the held sample's σ_a² dt³/4.
  // Adding the difference σ_a² dt³/12 keeps Σ positive definite for any interval, and is
  // 1/(4 N²) of the position variance after N steps (negligible at 400 Hz).
  covariance_.block<3, 3>(6, 6).diagonal().array() += var_a * dt2 * dt2 / 12.0;
  covariance_ = 0.5 * (covariance_ + covariance_.transpose()).eval();

  // Bias Jacobians (Forster Appendix B, recursive): a bias change δb enters as δω = −δb_g,
  // δf = −δb_a, so the stacked Jacobians follow the same linear map as the errors.
  Matrix93d J_bg;
  J_bg << d_R_d_bg_, d_v_d_bg_, d_p_d_bg_;
  Matrix93d J_ba;
  J_ba << Eigen::Matrix3d::Zero(), d_v_d_ba_, d_p_d_ba_;
  J_bg = (A.lazyProduct(J_bg) - B_g).eval();
  J_ba = (A.lazyProduct(J_ba) - B_a).eval();
  d_R_d_bg_ = J_bg.block<3, 3>(0, 0);
  d_v_d_bg_ = J_bg.block<3, 3>(3, 0);
  d_p_d_bg_ = J_bg.block<3, 3>(6, 0);
  d_v_d_ba_ = J_ba.block<3, 3>(3, 0);
  d_p_d_ba_ = J_ba.block<3, 3>(6, 0);

  // Deltas (Forster eqs. 35-38, midpoint attitude for the specific force); position
  // first, it uses the velocity at the start of the step.
  const Eigen::Vector3d f_mid = R_mid * a;
  delta_p_ += delta_v_ * dt + 0.5 * f_mid * dt2;
  delta_v_ += f_mid * dt;
  // Re-orthonormalise through the quaternion so that round-off does not accumulate.
  delta_R_ = Eigen::Quaterniond(delta_R_ * E).normalized().toRotationMatrix();
  dt_s_ += dt;
}

Eigen::Matrix3d ImuPreintegration::CorrectedDeltaR(const ImuBias& bias) const {
  const Eigen::Vector3d d_bg = bias.gyro_radps - bias_linearisation_.gyro_radps;
  return delta_R_ * core::ExpSO3(d_R_d_bg_ * d_bg);  // Forster eq. 44, first line
}

Eigen::Vector3d ImuPreintegration::CorrectedDeltaV(const ImuBias& bias) const {
  const Eigen::Vector3d d_bg = bias.gyro_radps - bias_linearisation_.gyro_radps;
  const Eigen::Vector3d d_ba = bias.accel_mps2 - bias_linearisation_.accel_mps2;
  return delta_v_ + d_v_d_bg_ * d_bg + d_v_d_ba_ * d_ba;
}

Eigen::Vector3d ImuPreintegration::CorrectedDeltaP(const ImuBias& bias) const {
  const Eigen::Vector3d d_bg = bias.gyro_radps - bias_linearisation_.gyro_radps;
  const Eigen::Vector3d d_ba = bias.accel_mps2 - bias_linearisation_.accel_mps2;
  return delta_p_ + d_p_d_bg_ * d_bg + d_p_d_ba_ * d_ba;
}

NavState ImuPreintegration::Predict(const NavState& start, const ImuBias& bias,
                                    const Eigen::Vector3d& gravity_L_mps2) const {
  // Forster eq. 33 with the bias-corrected deltas of eq. 44.
  const Eigen::Matrix3d R_LIi = start.q_LI.normalized().toRotationMatrix();
  const double dt = dt_s_;
  NavState end;
  end.q_LI = core::CanonicalQuat(Eigen::Quaterniond(R_LIi * CorrectedDeltaR(bias)).normalized());
  end.v_L_mps = start.v_L_mps + gravity_L_mps2 * dt + R_LIi * CorrectedDeltaV(bias);
  end.p_LI = start.p_LI + start.v_L_mps * dt + 0.5 * gravity_L_mps2 * dt * dt +
             R_LIi * CorrectedDeltaP(bias);
  return end;
}

}  // namespace tofu::estimator
