#include "sim/imu.h"

#include <algorithm>
#include <cassert>
#include <cmath>
#include <stdexcept>
#include <utility>

#include "core/lie.h"
#include "core/units.h"

namespace tofu::sim {

// ---- options ----

std::span<const core::OptionField<ImuOptions>> ImuOptions::Fields() {
  using F = core::OptionField<ImuOptions>;
  using R = core::NumberRule;
  static const F kFields[] = {
      F::Name("site", &ImuOptions::site)
          .Doc("mount site on the robot (frame I)"),
      F::Number("rate_hz", &ImuOptions::rate_hz, R::Between(200.0, 1000.0, "Hz"))
          .Doc("output rate"),
      F::Number("latency_s", &ImuOptions::latency_s, R::Between(0.0, 1.0, "s"))
          .Doc("delay from a sample's time to its arrival"),
      F::Flag("enable_noise", &ImuOptions::enable_noise)
          .Doc("false: a perfect IMU (no white noise, biases, vibration, scale factor or "
               "misalignment); saturation still applies"),
      F::Number("gyro_noise_density_radps_per_sqrthz",
                &ImuOptions::gyro_noise_density_radps_per_sqrthz, R::NonNegative("rad/s/sqrt(Hz)"))
          .Doc("white-noise density of the gyroscope, sigma_g (Kalibr convention, continuous "
               "time)"),
      F::Number("gyro_random_walk_radps2_per_sqrthz",
                &ImuOptions::gyro_random_walk_radps2_per_sqrthz,
                R::NonNegative("rad/s^2/sqrt(Hz)"))
          .Doc("bias random walk of the gyroscope, sigma_bg (Kalibr convention, continuous time)"),
      F::Number("accel_noise_density_mps2_per_sqrthz",
                &ImuOptions::accel_noise_density_mps2_per_sqrthz,
                R::NonNegative("m/s^2/sqrt(Hz)"))
          .Doc("white-noise density of the accelerometer, sigma_a (Kalibr convention, continuous "
               "time)"),
      F::Number("accel_random_walk_mps3_per_sqrthz", &ImuOptions::accel_random_walk_mps3_per_sqrthz,
                R::NonNegative("m/s^3/sqrt(Hz)"))
          .Doc("bias random walk of the accelerometer, sigma_ba (Kalibr convention, continuous "
               "time)"),
      F::Number("gyro_turn_on_bias_std_radps", &ImuOptions::gyro_turn_on_bias_std_radps,
                R::NonNegative("rad/s"))
          .Doc("std of the initial gyro bias per axis, drawn once per run"),
      F::Number("accel_turn_on_bias_std_mps2", &ImuOptions::accel_turn_on_bias_std_mps2,
                R::NonNegative("m/s^2"))
          .Doc("std of the initial accelerometer bias per axis, drawn once per run"),
      F::Number("gyro_scale_factor_std", &ImuOptions::gyro_scale_factor_std,
                R::Between(0.0, 0.1, ""))
          .Doc("std of each gyro axis' scale error, drawn once per run"),
      F::Number("accel_scale_factor_std", &ImuOptions::accel_scale_factor_std,
                R::Between(0.0, 0.1, ""))
          .Doc("std of each accelerometer axis' scale error, drawn once per run"),
      // Small-angle model: a few degrees at most.
      F::Degrees("gyro_misalignment_std_deg", &ImuOptions::gyro_misalignment_std_rad,
                 R::Between(0.0, 5.0, "deg"))
          .Doc("std of each off-diagonal entry of the gyro misalignment, drawn once per run"),
      F::Degrees("accel_misalignment_std_deg", &ImuOptions::accel_misalignment_std_rad,
                 R::Between(0.0, 5.0, "deg"))
          .Doc("std of each off-diagonal entry of the accelerometer misalignment, drawn once per "
               "run"),
      F::Number("gyro_range_radps", &ImuOptions::gyro_range_radps, R::Positive("rad/s"))
          .Doc("measurement range of the gyroscope; rates beyond it saturate"),
      F::Number("accel_range_mps2", &ImuOptions::accel_range_mps2, R::Positive("m/s^2"))
          .Doc("measurement range of the accelerometer; accelerations beyond it saturate"),
      F::Number("rotor_thrust_coefficient_N_per_radps2",
                &ImuOptions::rotor_thrust_coefficient_N_per_radps2, R::Positive("N/(rad/s)^2"))
          .Doc("rotor thrust coefficient k_f in T = k_f w^2, which gives the rotor frequency from "
               "the thrust"),
      F::Number("vibration_reference_thrust_N", &ImuOptions::vibration_reference_thrust_N,
                R::Positive("N"))
          .Doc("rotor thrust at which the vibration has the amplitudes below (hover)"),
      F::Number("vibration_accel_mps2", &ImuOptions::vibration_accel_mps2,
                R::NonNegative("m/s^2"))
          .Doc("per-rotor acceleration amplitude of the vibration at the reference thrust on a "
               "rigid mount"),
      F::Number("vibration_gyro_radps", &ImuOptions::vibration_gyro_radps,
                R::NonNegative("rad/s"))
          .Doc("per-rotor angular-rate amplitude of the vibration at the reference thrust on a "
               "rigid mount"),
      F::Pair("vibration_harmonic_gains", &ImuOptions::vibration_harmonic_gains,
              R::NonNegative(""))
          .Doc("relative amplitudes of the harmonics 1 and 2 of the rotor frequency"),
      // > 1: a mount resonating near the rotor frequency amplifies the vibration.
      F::Number("mount_transmissibility", &ImuOptions::mount_transmissibility,
                R::Between(0.0, 10.0, ""))
          .Doc("mount transmissibility at the rotor frequencies: 0 perfectly damped, 1 rigid, > 1 "
               "resonating"),
  };
  return kFields;
}

bool ImuOptions::IsValid(std::string* why) const {
  return core::CheckOptionFields<ImuOptions>(*this, Fields(), why);
}
namespace {

using core::kTwoPi;

Eigen::Vector3d NormalVector(core::RandomStream& stream) {
  const double x = stream.Normal();
  const double y = stream.Normal();
  const double z = stream.Normal();
  return Eigen::Vector3d(x, y, z);
}

// I + S + M: S = diag(scale errors), M = the six off-diagonal misalignment angles.
Eigen::Matrix3d DrawSensitivity(core::RandomStream& stream, double scale_std,
                                double misalignment_std_rad) {
  Eigen::Matrix3d K = Eigen::Matrix3d::Identity();
  for (int i = 0; i < 3; ++i) K(i, i) += scale_std * stream.Normal();
  for (int i = 0; i < 3; ++i) {
    for (int j = 0; j < 3; ++j) {
      if (i != j) K(i, j) = misalignment_std_rad * stream.Normal();
    }
  }
  return K;
}

// Clips each axis to [-range, range]; true if any axis was clipped.
bool Clip(double range, Eigen::Vector3d* v) {
  bool clipped = false;
  for (int i = 0; i < 3; ++i) {
    if (std::abs((*v)[i]) > range) {
      (*v)[i] = std::copysign(range, (*v)[i]);
      clipped = true;
    }
  }
  return clipped;
}

}  // namespace

ImuModel::ImuModel(std::string name, const ImuOptions& options, const World& world,
                   uint64_t seed)
    : name_(std::move(name)),
      options_(core::ValidOptions(options, "IMU '" + name_ + "'")),
      noise_stream_(seed, "sensor/" + name_) {
  const MountSite& site = world.robot().Site(options_.site, "IMU '" + name_ + "'");
  p_BI_ = site.p_Bs;
  R_BI_ = site.q_Bs.normalized().toRotationMatrix();
  g_W_ = Eigen::Vector3d(0.0, 0.0, -world.robot().rigid_body.gravity_mps2);
  period_ns_ = core::PeriodFromRate(options_.rate_hz);
  period_s_ = core::TimeToSeconds(period_ns_);
  latency_ns_ = core::SecondsToTime(options_.latency_s);

  // Constants drawn once, from their own streams (always drawn, so that options never
  // shift another quantity's draws).
  core::RandomStream calibration(seed, "sensor/" + name_ + "/calibration");
  const Eigen::Vector3d gyro_bias_unit = NormalVector(calibration);
  const Eigen::Vector3d accel_bias_unit = NormalVector(calibration);
  const Eigen::Matrix3d gyro_K = DrawSensitivity(calibration, options_.gyro_scale_factor_std,
                                                 options_.gyro_misalignment_std_rad);
  const Eigen::Matrix3d accel_K = DrawSensitivity(calibration, options_.accel_scale_factor_std,
                                                  options_.accel_misalignment_std_rad);
  core::RandomStream vibration(seed, "sensor/" + name_ + "/vibration");
  for (int j = 0; j < kRotorCount; ++j) {
    vibration_accel_dir_I_[j] = NormalVector(vibration).normalized();
    vibration_gyro_dir_I_[j] = NormalVector(vibration).normalized();
    for (int h = 0; h < kHarmonicCount; ++h) {
      vibration_phase_rad_[j][h] = vibration.Uniform(0.0, kTwoPi);
    }
  }

  if (options_.enable_noise) {
    gyro_bias_radps_ = options_.gyro_turn_on_bias_std_radps * gyro_bias_unit;
    accel_bias_mps2_ = options_.accel_turn_on_bias_std_mps2 * accel_bias_unit;
    gyro_K_ = gyro_K;
    accel_K_ = accel_K;
    vibration_on_ = options_.mount_transmissibility > 0.0 &&
                    (options_.vibration_accel_mps2 > 0.0 || options_.vibration_gyro_radps > 0.0) &&
                    options_.rotor_thrust_coefficient_N_per_radps2 > 0.0 &&
                    options_.vibration_reference_thrust_N > 0.0;
  }
}

void ImuModel::Step(const SensorInput& input, std::vector<SensorSample>* out) {
  const TruthState& x = input.truth;
  const core::Time dt_ns = input.world.timestep_ns();
  assert(dt_ns > 0);
  if (!started_) {
    started_ = true;
    next_step_ns_ = x.t_ns;
    next_sample_ns_ = x.t_ns + period_ns_;
  }
  assert(x.t_ns == next_step_ns_ && "IMU steps must be contiguous");
  const double dt_s = core::TimeToSeconds(dt_ns);

  // Truth at the step's midpoint (first-order expansion from t_k; a_WB held).
  const Eigen::Vector3d omega_B = x.omega_WB_B + 0.5 * dt_s * x.alpha_WB_B;
  const Eigen::Matrix3d R_WB =
      x.q_WB.toRotationMatrix() *
      core::ExpSO3(0.5 * dt_s * x.omega_WB_B + 0.125 * dt_s * dt_s * x.alpha_WB_B);
  const Eigen::Vector3d& r = p_BI_;
  const Eigen::Vector3d f_B = R_WB.transpose() * (x.a_WB_W - g_W_) +
                              x.alpha_WB_B.cross(r) + omega_B.cross(omega_B.cross(r));
  step_acc_I_ = R_BI_.transpose() * f_B;
  step_gyro_I_ = R_BI_.transpose() * omega_B;

  // Rotor speeds from the actual thrusts, T = k_f w^2.
  if (vibration_on_) {
    for (int j = 0; j < kRotorCount; ++j) {
      const double thrust_N = std::max(0.0, input.rotor_thrust_N[j]);
      rotor_rate_radps_[j] =
          std::sqrt(thrust_N / options_.rotor_thrust_coefficient_N_per_radps2);
      rotor_gain_[j] = thrust_N / options_.vibration_reference_thrust_N;
    }
  }

  // Split the step at every sample boundary inside it; emit each completed interval.
  step_begin_ns_ = x.t_ns;
  const core::Time step_end_ns = x.t_ns + dt_ns;
  core::Time segment_begin_ns = x.t_ns;
  while (next_sample_ns_ < step_end_ns) {
    Accumulate(segment_begin_ns, next_sample_ns_);
    Emit(next_sample_ns_, out);
    segment_begin_ns = next_sample_ns_;
    next_sample_ns_ += period_ns_;
  }
  Accumulate(segment_begin_ns, step_end_ns);

  // Advance each rotor's phase over the step (coherent tone).
  if (vibration_on_) {
    for (int j = 0; j < kRotorCount; ++j) {
      rotor_angle_rad_[j] = std::fmod(rotor_angle_rad_[j] + rotor_rate_radps_[j] * dt_s, kTwoPi);
    }
  }
  next_step_ns_ = step_end_ns;
}

void ImuModel::Accumulate(core::Time begin_ns, core::Time end_ns) {
  if (end_ns <= begin_ns) return;
  const double weight = static_cast<double>(end_ns - begin_ns);

  // Mean vibration over the segment: phase linear in time over the step, so
  // mean sin(psi) = (cos psi_a - cos psi_b) / (psi_b - psi_a).
  Eigen::Vector3d vibration_acc = Eigen::Vector3d::Zero();
  Eigen::Vector3d vibration_gyro = Eigen::Vector3d::Zero();
  if (vibration_on_) {
    const double tau_a = core::TimeToSeconds(begin_ns - step_begin_ns_);
    const double tau_b = core::TimeToSeconds(end_ns - step_begin_ns_);
    for (int j = 0; j < kRotorCount; ++j) {
      if (rotor_gain_[j] <= 0.0) continue;
      double coefficient = 0.0;
      for (int h = 0; h < kHarmonicCount; ++h) {
        const double gain = options_.vibration_harmonic_gains[h];
        if (gain == 0.0) continue;
        const double harmonic = h + 1.0;
        const double base = harmonic * rotor_angle_rad_[j] + vibration_phase_rad_[j][h];
        const double psi_a = base + harmonic * rotor_rate_radps_[j] * tau_a;
        const double psi_b = base + harmonic * rotor_rate_radps_[j] * tau_b;
        const double span = psi_b - psi_a;
        const double mean = span > 1e-9 ? (std::cos(psi_a) - std::cos(psi_b)) / span
                                        : std::sin(0.5 * (psi_a + psi_b));
        coefficient += gain * mean;
      }
      coefficient *= rotor_gain_[j];
      vibration_acc += coefficient * vibration_accel_dir_I_[j];
      vibration_gyro += coefficient * vibration_gyro_dir_I_[j];
    }
    vibration_acc *= options_.mount_transmissibility * options_.vibration_accel_mps2;
    vibration_gyro *= options_.mount_transmissibility * options_.vibration_gyro_radps;
  }

  // Sensed value, clipped at the range as the ADC does before the decimation filter.
  Eigen::Vector3d sensed_acc = accel_K_ * (step_acc_I_ + vibration_acc) + accel_bias_mps2_;
  Eigen::Vector3d sensed_gyro = gyro_K_ * (step_gyro_I_ + vibration_gyro) + gyro_bias_radps_;
  const bool clipped_acc = Clip(options_.accel_range_mps2, &sensed_acc);
  const bool clipped_gyro = Clip(options_.gyro_range_radps, &sensed_gyro);
  const bool saturated = clipped_acc || clipped_gyro;
  conditions_ = saturated ? kSaturated : kConditionNone;
  interval_saturated_ = interval_saturated_ || saturated;

  sum_truth_acc_ += weight * step_acc_I_;
  sum_truth_gyro_ += weight * step_gyro_I_;
  sum_sensed_acc_ += weight * sensed_acc;
  sum_sensed_gyro_ += weight * sensed_gyro;
}

void ImuModel::Emit(core::Time t_ns, std::vector<SensorSample>* out) {
  const double inv_period = 1.0 / static_cast<double>(period_ns_);
  core::ImuMeasurement truth;
  truth.acc_I_mps2 = sum_truth_acc_ * inv_period;
  truth.gyro_I_radps = sum_truth_gyro_ * inv_period;

  core::ImuMeasurement measured;
  measured.acc_I_mps2 = sum_sensed_acc_ * inv_period;
  measured.gyro_I_radps = sum_sensed_gyro_ * inv_period;
  bool saturated = interval_saturated_;
  if (options_.enable_noise) {
    // Kalibr: white noise sigma_d = sigma_c / sqrt(dt); bias walk sigma_b sqrt(dt).
    const double sqrt_dt = std::sqrt(period_s_);
    const double gyro_white = options_.gyro_noise_density_radps_per_sqrthz / sqrt_dt;
    const double accel_white = options_.accel_noise_density_mps2_per_sqrthz / sqrt_dt;
    measured.gyro_I_radps += gyro_white * NormalVector(noise_stream_);
    measured.acc_I_mps2 += accel_white * NormalVector(noise_stream_);
    saturated = Clip(options_.gyro_range_radps, &measured.gyro_I_radps) || saturated;
    saturated = Clip(options_.accel_range_mps2, &measured.acc_I_mps2) || saturated;
    gyro_bias_radps_ +=
        options_.gyro_random_walk_radps2_per_sqrthz * sqrt_dt * NormalVector(noise_stream_);
    accel_bias_mps2_ +=
        options_.accel_random_walk_mps3_per_sqrthz * sqrt_dt * NormalVector(noise_stream_);
  }

  SensorSample& sample = out->emplace_back();
  sample.t_ns = t_ns;
  sample.arrival_ns = t_ns + latency_ns_;
  sample.measured = measured;
  sample.truth = truth;
  sample.conditions = saturated ? kSaturated : kConditionNone;

  sum_truth_acc_.setZero();
  sum_truth_gyro_.setZero();
  sum_sensed_acc_.setZero();
  sum_sensed_gyro_.setZero();
  interval_saturated_ = false;
}

}  // namespace tofu::sim
