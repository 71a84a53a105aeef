#include "harness/sensor_config_lidar_odometry.h"

#include <string>

#include "harness/config_io.h"

namespace tofu::harness::internal {

using config::EmitNumber;
using config::EmitVector;
using config::kDegPerRad;
using config::QuatFromRpyDeg;
using config::ReadDegrees;
using config::ReadInteger;
using config::ReadNumber;
using config::RpyDegFromQuat;

sim::LidarOdometryOptions ReadLidarOdometryOptions(const YamlValue& value) {
  sim::LidarOdometryOptions o;
  YamlMap map = value.Map({"type",
                           "site",
                           "frame_position_m",
                           "frame_rpy_deg",
                           "rate_hz",
                           "latency_s",
                           "azimuth_count",
                           "elevation_count",
                           "elevation_min_deg",
                           "elevation_max_deg",
                           "min_range_m",
                           "max_range_m",
                           "range_noise_m",
                           "degenerate_translation_threshold",
                           "degenerate_rotation_threshold_m2",
                           "min_returns",
                           "position_random_walk_m_per_sqrtm",
                           "degenerate_position_random_walk_m_per_sqrtm",
                           "rotation_random_walk_deg_per_sqrtm",
                           "degenerate_rotation_random_walk_rad_per_sqrtrad",
                           "divergence_velocity_mps",
                           "divergence_time_constant_s",
                           "velocity_noise_mps",
                           "angular_rate_noise_degps",
                           "max_reported_position_std_m",
                           "max_reported_rotation_std_deg"});
  (void)map.Optional("type");  // the caller's key (which model this map configures)
  if (const auto site = map.Optional("site")) o.site = site->Identifier();
  if (const auto p = map.Optional("frame_position_m")) o.p_WS_m = p->Vector3(NumberRule::Any("m"));
  if (const auto rpy = map.Optional("frame_rpy_deg")) {
    o.q_WS = QuatFromRpyDeg(rpy->Vector3(NumberRule::Any("deg")));
  }
  ReadNumber(map, "rate_hz", NumberRule::PositiveAtMost(1000.0, "Hz"), &o.rate_hz);
  ReadNumber(map, "latency_s", NumberRule::Between(0.0, 10.0, "s"), &o.latency_s);

  ReadInteger(map, "azimuth_count", 1, 3600, &o.azimuth_count);
  ReadInteger(map, "elevation_count", 1, 256, &o.elevation_count);
  ReadDegrees(map, "elevation_min_deg", NumberRule::Between(-90.0, 90.0, "deg"),
              &o.elevation_min_rad);
  ReadDegrees(map, "elevation_max_deg", NumberRule::Between(-90.0, 90.0, "deg"),
              &o.elevation_max_rad);
  ReadNumber(map, "min_range_m", NumberRule::NonNegative("m"), &o.min_range_m);
  ReadNumber(map, "max_range_m", NumberRule::Positive("m"), &o.max_range_m);
  ReadNumber(map, "range_noise_m", NumberRule::NonNegative("m"), &o.range_noise_m);

  ReadNumber(map, "degenerate_translation_threshold", NumberRule::NonNegative("returns"),
             &o.degenerate_translation_threshold);
  ReadNumber(map, "degenerate_rotation_threshold_m2", NumberRule::NonNegative("m^2"),
             &o.degenerate_rotation_threshold_m2);
  ReadInteger(map, "min_returns", 0, 1000000, &o.min_returns);

  ReadNumber(map, "position_random_walk_m_per_sqrtm", NumberRule::NonNegative("m/sqrt(m)"),
             &o.position_random_walk_m_per_sqrtm);
  ReadNumber(map, "degenerate_position_random_walk_m_per_sqrtm",
             NumberRule::NonNegative("m/sqrt(m)"), &o.degenerate_position_random_walk_m_per_sqrtm);
  ReadDegrees(map, "rotation_random_walk_deg_per_sqrtm", NumberRule::NonNegative("deg/sqrt(m)"),
              &o.rotation_random_walk_rad_per_sqrtm);
  ReadNumber(map, "degenerate_rotation_random_walk_rad_per_sqrtrad",
             NumberRule::NonNegative("rad/sqrt(rad)"),
             &o.degenerate_rotation_random_walk_rad_per_sqrtrad);

  ReadNumber(map, "divergence_velocity_mps", NumberRule::NonNegative("m/s"),
             &o.divergence_velocity_mps);
  ReadNumber(map, "divergence_time_constant_s", NumberRule::Positive("s"),
             &o.divergence_time_constant_s);
  ReadNumber(map, "velocity_noise_mps", NumberRule::NonNegative("m/s"), &o.velocity_noise_mps);
  ReadDegrees(map, "angular_rate_noise_degps", NumberRule::NonNegative("deg/s"),
              &o.angular_rate_noise_radps);
  ReadNumber(map, "max_reported_position_std_m", NumberRule::Positive("m"),
             &o.max_reported_position_std_m);
  ReadDegrees(map, "max_reported_rotation_std_deg", NumberRule::Positive("deg"),
              &o.max_reported_rotation_std_rad);
  map.Finish();

  if (!(o.min_range_m < o.max_range_m)) value.Fail("min_range_m must be less than max_range_m");
  if (!(o.elevation_min_rad <= o.elevation_max_rad)) {
    value.Fail("elevation_min_deg must not exceed elevation_max_deg");
  }
  return o;
}

void EmitLidarOdometryOptions(YAML::Emitter& out, const sim::LidarOdometryOptions& o) {
  out << YAML::Key << "site" << YAML::Value << o.site;
  if (o.p_WS_m) EmitVector(out, "frame_position_m", *o.p_WS_m);
  if (o.q_WS) EmitVector(out, "frame_rpy_deg", RpyDegFromQuat(*o.q_WS));
  EmitNumber(out, "rate_hz", o.rate_hz);
  EmitNumber(out, "latency_s", o.latency_s);
  out << YAML::Key << "azimuth_count" << YAML::Value << o.azimuth_count;
  out << YAML::Key << "elevation_count" << YAML::Value << o.elevation_count;
  EmitNumber(out, "elevation_min_deg", o.elevation_min_rad * kDegPerRad);
  EmitNumber(out, "elevation_max_deg", o.elevation_max_rad * kDegPerRad);
  EmitNumber(out, "min_range_m", o.min_range_m);
  EmitNumber(out, "max_range_m", o.max_range_m);
  EmitNumber(out, "range_noise_m", o.range_noise_m);
  EmitNumber(out, "degenerate_translation_threshold", o.degenerate_translation_threshold);
  EmitNumber(out, "degenerate_rotation_threshold_m2", o.degenerate_rotation_threshold_m2);
  out << YAML::Key << "min_returns" << YAML::Value << o.min_returns;
  EmitNumber(out, "position_random_walk_m_per_sqrtm", o.position_random_walk_m_per_sqrtm);
  EmitNumber(out, "degenerate_position_random_walk_m_per_sqrtm",
             o.degenerate_position_random_walk_m_per_sqrtm);
  EmitNumber(out, "rotation_random_walk_deg_per_sqrtm",
             o.rotation_random_walk_rad_per_sqrtm * kDegPerRad);
  EmitNumber(out, "degenerate_rotation_random_walk_rad_per_sqrtrad",
             o.degenerate_rotation_random_walk_rad_per_sqrtrad);
  EmitNumber(out, "divergence_velocity_mps", o.divergence_velocity_mps);
  EmitNumber(out, "divergence_time_constant_s", o.divergence_time_constant_s);
  EmitNumber(out, "velocity_noise_mps", o.velocity_noise_mps);
  EmitNumber(out, "angular_rate_noise_degps", o.angular_rate_noise_radps * kDegPerRad);
  EmitNumber(out, "max_reported_position_std_m", o.max_reported_position_std_m);
  EmitNumber(out, "max_reported_rotation_std_deg", o.max_reported_rotation_std_rad * kDegPerRad);
}

}  // namespace tofu::harness::internal
