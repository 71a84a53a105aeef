#include "harness/sensor_config_imu.h"

#include <string>
#include <vector>

#include "harness/config_io.h"

namespace tofu::harness::internal {

using namespace config;  // NOLINT: the small readers of config_io.h

sim::ImuOptions ReadImuOptions(const YamlValue& value) {
  sim::ImuOptions o;
  YamlMap map = value.Map({"type",
                           "site",
                           "rate_hz",
                           "latency_s",
                           "enable_noise",
                           "gyro_noise_density_radps_per_sqrthz",
                           "gyro_random_walk_radps2_per_sqrthz",
                           "accel_noise_density_mps2_per_sqrthz",
                           "accel_random_walk_mps3_per_sqrthz",
                           "gyro_turn_on_bias_std_radps",
                           "accel_turn_on_bias_std_mps2",
                           "gyro_scale_factor_std",
                           "accel_scale_factor_std",
                           "gyro_misalignment_std_deg",
                           "accel_misalignment_std_deg",
                           "gyro_range_radps",
                           "accel_range_mps2",
                           "rotor_thrust_coefficient_N_per_radps2",
                           "vibration_reference_thrust_N",
                           "vibration_accel_mps2",
                           "vibration_gyro_radps",
                           "vibration_harmonic_gains",
                           "mount_transmissibility"});
  (void)map.Optional("type");  // the caller's key (which model this map configures)
  if (const auto site = map.Optional("site")) o.site = site->Identifier();
  ReadNumber(map, "rate_hz", NumberRule::Between(200.0, 1000.0, "Hz"), &o.rate_hz);
  ReadNumber(map, "latency_s", NumberRule::Between(0.0, 1.0, "s"), &o.latency_s);
  ReadBool(map, "enable_noise", &o.enable_noise);
  ReadNumber(map, "gyro_noise_density_radps_per_sqrthz", NumberRule::NonNegative("rad/s/sqrt(Hz)"),
             &o.gyro_noise_density_radps_per_sqrthz);
  ReadNumber(map, "gyro_random_walk_radps2_per_sqrthz", NumberRule::NonNegative("rad/s^2/sqrt(Hz)"),
             &o.gyro_random_walk_radps2_per_sqrthz);
  ReadNumber(map, "accel_noise_density_mps2_per_sqrthz", NumberRule::NonNegative("m/s^2/sqrt(Hz)"),
             &o.accel_noise_density_mps2_per_sqrthz);
  ReadNumber(map, "accel_random_walk_mps3_per_sqrthz", NumberRule::NonNegative("m/s^3/sqrt(Hz)"),
             &o.accel_random_walk_mps3_per_sqrthz);
  ReadNumber(map, "gyro_turn_on_bias_std_radps", NumberRule::NonNegative("rad/s"),
             &o.gyro_turn_on_bias_std_radps);
  ReadNumber(map, "accel_turn_on_bias_std_mps2", NumberRule::NonNegative("m/s^2"),
             &o.accel_turn_on_bias_std_mps2);
  ReadNumber(map, "gyro_scale_factor_std", NumberRule::Between(0.0, 0.1, ""),
             &o.gyro_scale_factor_std);
  ReadNumber(map, "accel_scale_factor_std", NumberRule::Between(0.0, 0.1, ""),
             &o.accel_scale_factor_std);
  // Small-angle model: a few degrees at most.
  ReadDegrees(map, "gyro_misalignment_std_deg", NumberRule::Between(0.0, 5.0, "deg"),
              &o.gyro_misalignment_std_rad);
  ReadDegrees(map, "accel_misalignment_std_deg", NumberRule::Between(0.0, 5.0, "deg"),
              &o.accel_misalignment_std_rad);
  ReadNumber(map, "gyro_range_radps", NumberRule::Positive("rad/s"), &o.gyro_range_radps);
  ReadNumber(map, "accel_range_mps2", NumberRule::Positive("m/s^2"), &o.accel_range_mps2);
  ReadNumber(map, "rotor_thrust_coefficient_N_per_radps2", NumberRule::Positive("N/(rad/s)^2"),
             &o.rotor_thrust_coefficient_N_per_radps2);
  ReadNumber(map, "vibration_reference_thrust_N", NumberRule::Positive("N"),
             &o.vibration_reference_thrust_N);
  ReadNumber(map, "vibration_accel_mps2", NumberRule::NonNegative("m/s^2"),
             &o.vibration_accel_mps2);
  ReadNumber(map, "vibration_gyro_radps", NumberRule::NonNegative("rad/s"),
             &o.vibration_gyro_radps);
  if (const auto gains = map.Optional("vibration_harmonic_gains")) {
    const std::vector<double> g = gains->Numbers(2, NumberRule::NonNegative(""));
    o.vibration_harmonic_gains = {g[0], g[1]};
  }
  // > 1: a mount resonating near the rotor frequency amplifies the vibration.
  ReadNumber(map, "mount_transmissibility", NumberRule::Between(0.0, 10.0, ""),
             &o.mount_transmissibility);
  map.Finish();
  return o;
}

void EmitImuOptions(YAML::Emitter& out, const sim::ImuOptions& o) {
  out << YAML::Key << "site" << YAML::Value << o.site;
  EmitNumber(out, "rate_hz", o.rate_hz);
  EmitNumber(out, "latency_s", o.latency_s);
  out << YAML::Key << "enable_noise" << YAML::Value << o.enable_noise;
  EmitNumber(out, "gyro_noise_density_radps_per_sqrthz", o.gyro_noise_density_radps_per_sqrthz);
  EmitNumber(out, "gyro_random_walk_radps2_per_sqrthz", o.gyro_random_walk_radps2_per_sqrthz);
  EmitNumber(out, "accel_noise_density_mps2_per_sqrthz", o.accel_noise_density_mps2_per_sqrthz);
  EmitNumber(out, "accel_random_walk_mps3_per_sqrthz", o.accel_random_walk_mps3_per_sqrthz);
  EmitNumber(out, "gyro_turn_on_bias_std_radps", o.gyro_turn_on_bias_std_radps);
  EmitNumber(out, "accel_turn_on_bias_std_mps2", o.accel_turn_on_bias_std_mps2);
  EmitNumber(out, "gyro_scale_factor_std", o.gyro_scale_factor_std);
  EmitNumber(out, "accel_scale_factor_std", o.accel_scale_factor_std);
  EmitNumber(out, "gyro_misalignment_std_deg", o.gyro_misalignment_std_rad * kDegPerRad);
  EmitNumber(out, "accel_misalignment_std_deg", o.accel_misalignment_std_rad * kDegPerRad);
  EmitNumber(out, "gyro_range_radps", o.gyro_range_radps);
  EmitNumber(out, "accel_range_mps2", o.accel_range_mps2);
  EmitNumber(out, "rotor_thrust_coefficient_N_per_radps2", o.rotor_thrust_coefficient_N_per_radps2);
  EmitNumber(out, "vibration_reference_thrust_N", o.vibration_reference_thrust_N);
  EmitNumber(out, "vibration_accel_mps2", o.vibration_accel_mps2);
  EmitNumber(out, "vibration_gyro_radps", o.vibration_gyro_radps);
  out << YAML::Key << "vibration_harmonic_gains" << YAML::Value << YAML::Flow << YAML::BeginSeq
      << FormatDouble(o.vibration_harmonic_gains[0]) << FormatDouble(o.vibration_harmonic_gains[1])
      << YAML::EndSeq;
  EmitNumber(out, "mount_transmissibility", o.mount_transmissibility);
}

}  // namespace tofu::harness::internal
