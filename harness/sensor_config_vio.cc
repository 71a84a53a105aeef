#include "harness/sensor_config_vio.h"

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

sim::VioOptions ReadVioOptions(const YamlValue& value) {
  sim::VioOptions o;
  YamlMap map = value.Map({"type",
                           "site",
                           "frame_position_m",
                           "frame_rpy_deg",
                           "rate_hz",
                           "latency_s",
                           "position_random_walk_m_per_sqrtm",
                           "yaw_random_walk_deg_per_sqrtm",
                           "tilt_random_walk_deg_per_sqrtm",
                           "position_noise_m",
                           "rotation_noise_deg",
                           "velocity_noise_mps",
                           "angular_rate_noise_degps",
                           "feature_check_rate_hz",
                           "feature_grid_columns",
                           "feature_grid_rows",
                           "feature_fov_horizontal_deg",
                           "feature_fov_vertical_deg",
                           "feature_min_depth_m",
                           "feature_max_depth_m",
                           "starved_score_threshold",
                           "starved_drift_factor",
                           "blur_angular_rate_degps",
                           "blur_drift_factor",
                           "lost_velocity_random_walk_mps_per_sqrts",
                           "reset_after_s",
                           "reset_jump_position_m",
                           "reset_jump_yaw_deg",
                           "reported_pose_variance_base",
                           "reported_twist_variance_base"});
  (void)map.Optional("type");  // the caller's key (which model this map configures)
  if (const auto site = map.Optional("site")) o.site = site->Identifier();
  if (const auto p = map.Optional("frame_position_m")) o.p_WS_m = p->Vector3(NumberRule::Any("m"));
  if (const auto rpy = map.Optional("frame_rpy_deg")) {
    o.q_WS = QuatFromRpyDeg(rpy->Vector3(NumberRule::Any("deg")));
  }
  ReadNumber(map, "rate_hz", NumberRule::PositiveAtMost(10000.0, "Hz"), &o.rate_hz);
  ReadNumber(map, "latency_s", NumberRule::Between(0.0, 10.0, "s"), &o.latency_s);

  ReadNumber(map, "position_random_walk_m_per_sqrtm", NumberRule::NonNegative("m/sqrt(m)"),
             &o.position_random_walk_m_per_sqrtm);
  ReadDegrees(map, "yaw_random_walk_deg_per_sqrtm", NumberRule::NonNegative("deg/sqrt(m)"),
              &o.yaw_random_walk_rad_per_sqrtm);
  ReadDegrees(map, "tilt_random_walk_deg_per_sqrtm", NumberRule::NonNegative("deg/sqrt(m)"),
              &o.tilt_random_walk_rad_per_sqrtm);

  ReadNumber(map, "position_noise_m", NumberRule::NonNegative("m"), &o.position_noise_m);
  ReadDegrees(map, "rotation_noise_deg", NumberRule::NonNegative("deg"), &o.rotation_noise_rad);
  ReadNumber(map, "velocity_noise_mps", NumberRule::NonNegative("m/s"), &o.velocity_noise_mps);
  ReadDegrees(map, "angular_rate_noise_degps", NumberRule::NonNegative("deg/s"),
              &o.angular_rate_noise_radps);

  ReadNumber(map, "feature_check_rate_hz", NumberRule::PositiveAtMost(1000.0, "Hz"),
             &o.feature_check_rate_hz);
  ReadInteger(map, "feature_grid_columns", 1, 64, &o.feature_grid_columns);
  ReadInteger(map, "feature_grid_rows", 1, 64, &o.feature_grid_rows);
  ReadDegrees(map, "feature_fov_horizontal_deg", NumberRule::Between(1.0, 179.0, "deg"),
              &o.feature_fov_horizontal_rad);
  ReadDegrees(map, "feature_fov_vertical_deg", NumberRule::Between(1.0, 179.0, "deg"),
              &o.feature_fov_vertical_rad);
  ReadNumber(map, "feature_min_depth_m", NumberRule::NonNegative("m"), &o.feature_min_depth_m);
  ReadNumber(map, "feature_max_depth_m", NumberRule::Positive("m"), &o.feature_max_depth_m);
  ReadNumber(map, "starved_score_threshold", NumberRule::Between(0.0, 1.0, ""),
             &o.starved_score_threshold);
  ReadNumber(map, "starved_drift_factor", NumberRule::Between(1.0, 1000.0, ""),
             &o.starved_drift_factor);
  ReadDegrees(map, "blur_angular_rate_degps", NumberRule::Positive("deg/s"),
              &o.blur_angular_rate_radps);
  ReadNumber(map, "blur_drift_factor", NumberRule::Between(1.0, 1000.0, ""),
             &o.blur_drift_factor);

  ReadNumber(map, "lost_velocity_random_walk_mps_per_sqrts", NumberRule::NonNegative("m/s/sqrt(s)"),
             &o.lost_velocity_random_walk_mps_per_sqrts);
  ReadNumber(map, "reset_after_s", NumberRule::NonNegative("s"), &o.reset_after_s);
  ReadNumber(map, "reset_jump_position_m", NumberRule::NonNegative("m"), &o.reset_jump_position_m);
  ReadDegrees(map, "reset_jump_yaw_deg", NumberRule::NonNegative("deg"), &o.reset_jump_yaw_rad);
  ReadNumber(map, "reported_pose_variance_base", NumberRule::Positive("m^2 or rad^2"),
             &o.reported_pose_variance_base);
  ReadNumber(map, "reported_twist_variance_base", NumberRule::Positive("(m/s)^2 or (rad/s)^2"),
             &o.reported_twist_variance_base);
  map.Finish();

  if (!(o.feature_min_depth_m < o.feature_max_depth_m)) {
    value.Fail("feature_min_depth_m must be less than feature_max_depth_m");
  }
  return o;
}

void EmitVioOptions(YAML::Emitter& out, const sim::VioOptions& o) {
  out << YAML::Key << "site" << YAML::Value << o.site;
  if (o.p_WS_m) EmitVector(out, "frame_position_m", *o.p_WS_m);
  if (o.q_WS) EmitVector(out, "frame_rpy_deg", RpyDegFromQuat(*o.q_WS));
  EmitNumber(out, "rate_hz", o.rate_hz);
  EmitNumber(out, "latency_s", o.latency_s);
  EmitNumber(out, "position_random_walk_m_per_sqrtm", o.position_random_walk_m_per_sqrtm);
  EmitNumber(out, "yaw_random_walk_deg_per_sqrtm", o.yaw_random_walk_rad_per_sqrtm * kDegPerRad);
  EmitNumber(out, "tilt_random_walk_deg_per_sqrtm",
             o.tilt_random_walk_rad_per_sqrtm * kDegPerRad);
  EmitNumber(out, "position_noise_m", o.position_noise_m);
  EmitNumber(out, "rotation_noise_deg", o.rotation_noise_rad * kDegPerRad);
  EmitNumber(out, "velocity_noise_mps", o.velocity_noise_mps);
  EmitNumber(out, "angular_rate_noise_degps", o.angular_rate_noise_radps * kDegPerRad);
  EmitNumber(out, "feature_check_rate_hz", o.feature_check_rate_hz);
  out << YAML::Key << "feature_grid_columns" << YAML::Value << o.feature_grid_columns;
  out << YAML::Key << "feature_grid_rows" << YAML::Value << o.feature_grid_rows;
  EmitNumber(out, "feature_fov_horizontal_deg", o.feature_fov_horizontal_rad * kDegPerRad);
  EmitNumber(out, "feature_fov_vertical_deg", o.feature_fov_vertical_rad * kDegPerRad);
  EmitNumber(out, "feature_min_depth_m", o.feature_min_depth_m);
  EmitNumber(out, "feature_max_depth_m", o.feature_max_depth_m);
  EmitNumber(out, "starved_score_threshold", o.starved_score_threshold);
  EmitNumber(out, "starved_drift_factor", o.starved_drift_factor);
  EmitNumber(out, "blur_angular_rate_degps", o.blur_angular_rate_radps * kDegPerRad);
  EmitNumber(out, "blur_drift_factor", o.blur_drift_factor);
  EmitNumber(out, "lost_velocity_random_walk_mps_per_sqrts",
             o.lost_velocity_random_walk_mps_per_sqrts);
  EmitNumber(out, "reset_after_s", o.reset_after_s);
  EmitNumber(out, "reset_jump_position_m", o.reset_jump_position_m);
  EmitNumber(out, "reset_jump_yaw_deg", o.reset_jump_yaw_rad * kDegPerRad);
  EmitNumber(out, "reported_pose_variance_base", o.reported_pose_variance_base);
  EmitNumber(out, "reported_twist_variance_base", o.reported_twist_variance_base);
}

}  // namespace tofu::harness::internal
