#include "sim/controller.h"

#include "core/lie.h"

namespace tofu::sim {

// ---- options ----

std::span<const core::OptionField<ControllerOptions>> ControllerOptions::Fields() {
  using F = core::OptionField<ControllerOptions>;
  using R = core::NumberRule;
  using O = ControllerOptions;
  // Gains may be written as one number for all three axes.
  static const F kFields[] = {
      // At most the physics rate, which the scenario checks (the struct does not know it).
      F::Number("rate_hz", &O::rate_hz, R::Between(1.0, 10000.0, "Hz"))
          .Doc("controller update rate"),
      F::Vector("position_gain_per_s2", &O::position_gain_per_s2, R::NonNegative("1/s^2"), true)
          .Doc("gain on the position error, per axis"),
      F::Vector("velocity_gain_per_s", &O::velocity_gain_per_s, R::NonNegative("1/s"), true)
          .Doc("gain on the velocity error, per axis"),
      F::Vector("position_integral_gain_per_s3", &O::position_integral_gain_per_s3,
                R::NonNegative("1/s^3"), true)
          .Doc("gain on the integral of the position error, per axis"),
      F::Number("integral_limit_mps2", &O::integral_limit_mps2, R::NonNegative("m/s^2"))
          .Doc("anti-windup bound of the position integral term"),
      F::Vector("attitude_gain_per_s2", &O::attitude_gain_per_s2, R::NonNegative("1/s^2"), true)
          .Doc("gain on the attitude error, per axis"),
      F::Vector("angular_rate_gain_per_s", &O::angular_rate_gain_per_s, R::NonNegative("1/s"),
                true)
          .Doc("gain on the angular-rate error, per axis"),
      F::Vector("attitude_integral_gain_per_s3", &O::attitude_integral_gain_per_s3,
                R::NonNegative("1/s^3"), true)
          .Doc("gain on the integral of the attitude error, per axis"),
      F::Number("attitude_integral_limit_radps2", &O::attitude_integral_limit_radps2,
                R::NonNegative("rad/s^2"))
          .Doc("anti-windup bound of the attitude integral term"),
      F::Number("integral_error_band_m", &O::integral_error_band_m, R::NonNegative("m"))
          .Doc("anti-windup: the position integrators see the error clipped to this band"),
      F::Number("attitude_integral_error_band_rad", &O::attitude_integral_error_band_rad,
                R::NonNegative("rad"))
          .Doc("anti-windup: the attitude integrators see the error clipped to this band"),
  };
  return kFields;
}

bool ControllerOptions::IsValid(std::string* why) const {
  return core::CheckOptionFields<ControllerOptions>(*this, Fields(), why);
}
namespace {

Eigen::Vector3d ClampNorm(const Eigen::Vector3d& v, double limit) {
  const double n = v.norm();
  return n > limit ? Eigen::Vector3d(v * (limit / n)) : v;
}

// Advances an integrator and returns its term gain .* integral. Anti-windup twice: the
// integrator sees the error clipped to +-band (a large transient does not wind it up),
// and the term's norm is bounded by limit, the state clamped back to match.
Eigen::Vector3d UpdateIntegral(const Eigen::Vector3d& error, const Eigen::Vector3d& gain,
                               double band, double limit, double dt_s,
                               Eigen::Vector3d* integral) {
  *integral += dt_s * error.cwiseMax(-band).cwiseMin(band);
  const Eigen::Vector3d term = ClampNorm(gain.cwiseProduct(*integral), limit);
  for (int k = 0; k < 3; ++k) {
    if (gain(k) > 0.0) (*integral)(k) = term(k) / gain(k);
  }
  return term;
}

}  // namespace

GeometricController::GeometricController(const ControllerOptions& options,
                                         const RigidBodyParams& params)
    : options_(core::ValidOptions(options, "controller")), params_(params) {}

void GeometricController::Reset() {
  position_integral_.setZero();
  attitude_integral_.setZero();
  last_t_ns_ = -1;
}

Wrench GeometricController::Compute(const RobotState& state, const Reference& reference) {
  const double dt_s = last_t_ns_ < 0 ? 0.0 : core::TimeToSeconds(state.t_ns - last_t_ns_);
  last_t_ns_ = state.t_ns;

  const Eigen::Matrix3d R = state.q_WB.toRotationMatrix();
  const Eigen::Matrix3d R_d = reference.q_WB.toRotationMatrix();

  // Translation: PID on the position error with acceleration feed-forward; the robot is
  // fully actuated, so the commanded force is realised in any attitude.
  const Eigen::Vector3d e_p = state.p_WB - reference.p_WB;
  const Eigen::Vector3d e_v = state.v_WB_W - reference.v_WB_W;
  const Eigen::Vector3d integral_term = UpdateIntegral(
      e_p, options_.position_integral_gain_per_s3, options_.integral_error_band_m,
      options_.integral_limit_mps2, dt_s, &position_integral_);
  const Eigen::Vector3d a_cmd_W = reference.a_WB_W -
                                  options_.position_gain_per_s2.cwiseProduct(e_p) -
                                  options_.velocity_gain_per_s.cwiseProduct(e_v) - integral_term;
  const Eigen::Vector3d force_W =
      params_.mass_kg * (a_cmd_W + Eigen::Vector3d(0.0, 0.0, params_.gravity_mps2));

  // Rotation: Lee et al. (2010) eq. (11)-(12) on SO(3) with an integral term.
  const Eigen::Matrix3d R_T_Rd = R.transpose() * R_d;
  const Eigen::Vector3d e_R = 0.5 * core::Vee(R_T_Rd.transpose() - R_T_Rd);
  const Eigen::Vector3d omega_d_B = R_T_Rd * reference.omega_WB_B;
  const Eigen::Vector3d alpha_d_B = R_T_Rd * reference.alpha_WB_B;
  const Eigen::Vector3d e_omega = state.omega_WB_B - omega_d_B;
  const Eigen::Vector3d attitude_integral_term = UpdateIntegral(
      e_R, options_.attitude_integral_gain_per_s3, options_.attitude_integral_error_band_rad,
      options_.attitude_integral_limit_radps2, dt_s, &attitude_integral_);
  const Eigen::Matrix3d& J = params_.inertia_B_kgm2;
  const Eigen::Vector3d& w = state.omega_WB_B;
  const Eigen::Vector3d angular_acc_cmd = -options_.attitude_gain_per_s2.cwiseProduct(e_R) -
                                          options_.angular_rate_gain_per_s.cwiseProduct(e_omega) -
                                          attitude_integral_term;
  const Eigen::Vector3d torque_B = J * angular_acc_cmd + w.cross(J * w) -
                                   J * (core::Hat(w) * omega_d_B - alpha_d_B);

  return Wrench{R.transpose() * force_W, torque_B};
}

}  // namespace tofu::sim
