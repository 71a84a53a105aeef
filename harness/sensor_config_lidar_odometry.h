#pragma once
// Private to harness: the `lidar_odometry` sensor's options in YAML (strict reader and
// round-trip writer). Keys are the LidarOdometryOptions field names; radian fields are
// written in degrees (`*_rad` -> `*_deg`, `*_radps` -> `*_degps`), except the degenerate
// rotation walk in rad/sqrt(rad), whose unit does not scale linearly to degrees; the
// odometry frame is frame_position_m and frame_rpy_deg (absent: the LiDAR pose at t = 0).

#include <yaml-cpp/yaml.h>

#include "harness/yaml_reader.h"
#include "sim/lidar_odometry.h"

namespace tofu::harness::internal {

/// Reads a `lidar_odometry` options map; every key optional (defaults from
/// LidarOdometryOptions). Throws core::InputError naming line and key path on an unknown
/// key or a value out of range.
sim::LidarOdometryOptions ReadLidarOdometryOptions(const YamlValue& value);

/// Emits every option as key/value pairs into the caller's open map.
void EmitLidarOdometryOptions(YAML::Emitter& out, const sim::LidarOdometryOptions& options);

}  // namespace tofu::harness::internal
