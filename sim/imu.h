#pragma once
// IMU model: specific force and angular rate at the IMU mount site, decimated from the
// physics rate by time-weighted averaging, with Kalibr-convention white noise and bias
// random walk, turn-on biases, scale factor and axis misalignment, saturation, and the
// rotor vibration that a (poorly) damped mount passes on to the sensor.

#include <array>
#include <span>
#include <cstdint>
#include <string>
#include <vector>

#include <Eigen/Core>
#include <Eigen/Geometry>

#include "core/random.h"
#include "core/option_fields.h"
#include "core/time.h"
#include "core/units.h"
#include "sim/allocation.h"
#include "sim/sensor.h"
#include "sim/world.h"

namespace tofu::sim {

/// Options of ImuModel. Defaults: an ADIS16448 (the IMU of the seed paper's robot) with
/// the noise parameters Kalibr's ADIS16448 config uses for EuRoC (continuous time:
/// white noise densities and bias random walks), the ADIS16448 data sheet's ranges
/// (±1000 °/s, ±18 g), and a well-damped mount.
struct ImuOptions {
  std::string site = "imu";  ///< mount site on the robot (frame I)
  double rate_hz = 400.0;    ///< output rate
  double latency_s = 0.0;    ///< arrival_ns = t_ns + latency

  /// false: a perfect IMU (no white noise, no biases, no vibration, no scale factor or
  /// misalignment); saturation still applies.
  bool enable_noise = true;

  // ---- Kalibr convention (continuous time); discretised with dt = 1 / rate_hz ----
  double gyro_noise_density_radps_per_sqrthz = 1.6968e-4;   ///< sigma_g
  double gyro_random_walk_radps2_per_sqrthz = 1.9393e-5;    ///< sigma_bg
  double accel_noise_density_mps2_per_sqrthz = 2.0e-3;      ///< sigma_a
  double accel_random_walk_mps3_per_sqrthz = 3.0e-3;        ///< sigma_ba

  // ---- constants drawn once per run (from the seed) ----
  double gyro_turn_on_bias_std_radps = 3.0e-3;   ///< std of the initial gyro bias, per axis
  double accel_turn_on_bias_std_mps2 = 0.05;     ///< std of the initial accel bias, per axis
  double gyro_scale_factor_std = 0.0;            ///< std of each axis' scale error [-]
  double accel_scale_factor_std = 0.0;           ///< std of each axis' scale error [-]
  double gyro_misalignment_std_rad = 0.0;        ///< std of each off-diagonal entry [rad]
  double accel_misalignment_std_rad = 0.0;       ///< std of each off-diagonal entry [rad]

  // ---- measurement range (ADIS16448: ±1000 °/s, ±18 g) ----
  double gyro_range_radps = 17.45;
  double accel_range_mps2 = 18.0 * core::kStandardGravity_mps2;

  // ---- rotor vibration ----
  /// Rotor thrust coefficient k_f in T = k_f w^2 [N/(rad/s)^2]: 3.68 N of hover thrust
  /// per rotor (4.5 kg / 12 rotors) spins at ~495 rad/s = 79 Hz.
  double rotor_thrust_coefficient_N_per_radps2 = 1.5e-5;
  /// Thrust at which a rotor's vibration has the amplitudes below [N] (hover).
  double vibration_reference_thrust_N = 3.68;
  /// Per-rotor acceleration amplitude at the reference thrust on a rigid mount [m/s^2].
  double vibration_accel_mps2 = 1.0;
  /// Per-rotor angular-rate amplitude at the reference thrust on a rigid mount [rad/s].
  double vibration_gyro_radps = 0.05;
  /// Relative amplitudes of the harmonics h = 1, 2 of the rotor frequency [-].
  std::array<double, 2> vibration_harmonic_gains = {1.0, 0.35};
  /// Mount transmissibility at the rotor frequencies: 0 perfectly damped, 1 rigid,
  /// > 1 a mount resonating near the rotor frequency. 0.15 gives ~0.16 m/s^2 RMS per axis
  /// at hover (12 rotors, random phases and directions; white noise alone 0.04 m/s^2).
  double mount_transmissibility = 0.15;

  /// The field table (core/option_fields.h): the YAML key, unit and limits of every
  /// option, which the reader, the writer and IsValid share.
  static std::span<const core::OptionField<ImuOptions>> Fields();
  /// Ceres style: false, with "<key>: <problem>" in *why, when an option is outside
  /// its limits.
  /// The model's constructor throws std::invalid_argument then.
  bool IsValid(std::string* why = nullptr) const;
};

/// Inertial measurement unit at a mount site I (p_BI, R_BI from the robot model).
///
/// Truth, for every physics step [t_k, t_k + dt), evaluated at the step's midpoint from
/// the state at t_k by a first-order expansion (midpoint rule for the step's average):
///   omega_B  = omega_WB_B + alpha_WB_B dt/2,   R_WB = R_WB(t_k) Exp(omega dt/2 + alpha dt^2/8)
///   f_I      = R_BI^T [ R_WB^T (a_WB_W - g_W) + alpha x r + omega x (omega x r) ],  r = p_BI
///   omega_I  = R_BI^T omega_B
/// i.e. f_I = R_WI^T (a_WI - g_W) with a_WI = a_WB + R_WB (alpha x r + omega x (omega x r))
/// and g_W = (0, 0, -g). a_WB_W is held over the step (no jerk in the truth; exact for
/// the simulator, whose integrator applies a_WB_W over the whole step).
///
/// Decimation: a sample stamped t_n (= t_first + n T, T = period rounded to ns) is the
/// time-weighted mean over [t_n - T, t_n) of the per-step values; steps that straddle
/// t_n are split at t_n in integer nanoseconds (1 kHz / 400 Hz: 2.5 steps per sample).
/// Time of validity = the interval's END t_n: the sample is the exact delta-velocity
/// and delta-angle of the preceding period divided by T (an estimator integrating y_n
/// over [t_{n-1}, t_n) reproduces the motion); as a point value it lags by T/2. The truth
/// sample is the same mean without noise, biases, vibration, scale or misalignment.
///
/// Sensed value per step segment (clipped per axis at ± range, as the ADC clips before
/// the decimation filter; any clip sets kSaturated for the sample):
///   s = (I + S + M) (truth + v) + b_n
/// S = diag(scale errors), M = off-diagonal misalignment (small angles), v the vibration.
/// Output: y_n = clip(mean(s) + sigma/sqrt(T) n_k), then b_{n+1} = b_n + sigma_b sqrt(T) n'_k
/// (Kalibr's discretisation; b_0 ~ N(0, turn_on_std^2)).
///
/// Vibration: rotor j spins at w_j = sqrt(T_j / k_f) from its actual thrust T_j; its phase
/// theta_j = integral of w_j dt is integrated at the physics rate (a coherent tone), and
///   v_acc  = kappa A_acc  sum_j sum_h c_h (T_j / T_ref) sin(h theta_j + phi_jh) d_j
///   v_gyro = kappa A_gyro sum_j sum_h c_h (T_j / T_ref) sin(h theta_j + phi_jh) e_j
/// with unit directions d_j, e_j (in I) and phases phi_jh drawn once, kappa the mount
/// transmissibility. The segment mean of each sine is computed in closed form (phase
/// linear over a step), so the IMU's averaging is the sensor's boxcar filter: tones
/// above the Nyquist rate alias into the output, as they do in a real sampled IMU.
class ImuModel final : public SensorModel {
 public:
  /// Throws std::invalid_argument naming the site if the robot has no such site, or
  /// naming the option if rate_hz is not positive.
  ImuModel(std::string name, const ImuOptions& options, const World& world, uint64_t seed);

  const std::string& name() const override { return name_; }
  /// Steps must be contiguous (t_ns advancing by input.world.timestep_ns()). Any physics
  /// step works; a step longer than the period yields several samples of its value.
  void Step(const SensorInput& input, std::vector<SensorSample>* out) override;
  /// kSaturated while the current physics step's sensed value is clipped.
  uint32_t conditions() const override { return conditions_; }
  const std::string& site() const override { return options_.site; }

  const ImuOptions& options() const { return options_; }
  /// Output period T [ns].
  core::Time period_ns() const { return period_ns_; }
  /// The biases that apply to the next sample (true values, for evaluation).
  const Eigen::Vector3d& gyro_bias_radps() const { return gyro_bias_radps_; }
  const Eigen::Vector3d& accel_bias_mps2() const { return accel_bias_mps2_; }

 private:
  // Accumulates the segment [begin_ns, end_ns) of the current step.
  void Accumulate(core::Time begin_ns, core::Time end_ns);
  // Emits the sample of the interval ending at t_ns and resets the accumulators.
  void Emit(core::Time t_ns, std::vector<SensorSample>* out);

  static constexpr int kRotorCount = kArmCount * kRotorsPerArm;
  static constexpr int kHarmonicCount = 2;

  std::string name_;
  ImuOptions options_;
  core::RandomStream noise_stream_;  ///< white noise and bias random walk
  core::Time period_ns_ = 0;
  core::Time latency_ns_ = 0;
  double period_s_ = 0.0;  ///< period_ns_ in seconds (the discretisation's dt)

  // ---- static: mount and constants drawn once ----
  Eigen::Vector3d p_BI_ = Eigen::Vector3d::Zero();
  Eigen::Matrix3d R_BI_ = Eigen::Matrix3d::Identity();
  Eigen::Vector3d g_W_ = Eigen::Vector3d::Zero();
  Eigen::Matrix3d gyro_K_ = Eigen::Matrix3d::Identity();   ///< I + S + M
  Eigen::Matrix3d accel_K_ = Eigen::Matrix3d::Identity();  ///< I + S + M
  bool vibration_on_ = false;
  std::array<Eigen::Vector3d, kRotorCount> vibration_accel_dir_I_{};  ///< d_j, unit
  std::array<Eigen::Vector3d, kRotorCount> vibration_gyro_dir_I_{};   ///< e_j, unit
  std::array<std::array<double, kHarmonicCount>, kRotorCount> vibration_phase_rad_{};

  // ---- evolving state ----
  bool started_ = false;
  core::Time next_step_ns_ = 0;    ///< expected t_ns of the next Step (contiguity check)
  core::Time next_sample_ns_ = 0;  ///< t_n of the sample being accumulated
  Eigen::Vector3d gyro_bias_radps_ = Eigen::Vector3d::Zero();
  Eigen::Vector3d accel_bias_mps2_ = Eigen::Vector3d::Zero();
  std::array<double, kRotorCount> rotor_angle_rad_{};  ///< theta_j, wrapped to [0, 2 pi)
  uint32_t conditions_ = kConditionNone;

  // ---- the current step (set by Step, read by Accumulate) ----
  core::Time step_begin_ns_ = 0;
  Eigen::Vector3d step_acc_I_ = Eigen::Vector3d::Zero();   ///< truth f_I
  Eigen::Vector3d step_gyro_I_ = Eigen::Vector3d::Zero();  ///< truth omega_I
  std::array<double, kRotorCount> rotor_rate_radps_{};     ///< w_j
  std::array<double, kRotorCount> rotor_gain_{};           ///< T_j / T_ref (0: silent)

  // ---- accumulators of the current interval: sum of value * duration_ns ----
  Eigen::Vector3d sum_truth_acc_ = Eigen::Vector3d::Zero();
  Eigen::Vector3d sum_truth_gyro_ = Eigen::Vector3d::Zero();
  Eigen::Vector3d sum_sensed_acc_ = Eigen::Vector3d::Zero();
  Eigen::Vector3d sum_sensed_gyro_ = Eigen::Vector3d::Zero();
  bool interval_saturated_ = false;
};

}  // namespace tofu::sim
