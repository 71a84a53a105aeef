#pragma once
// Private to harness: the `vio` sensor's options in YAML (strict reader and round-trip
// writer). Keys are the VioOptions field names; radian fields are written in degrees
// (`*_rad` -> `*_deg`, `*_radps` -> `*_degps`); the odometry frame is frame_position_m and
// frame_rpy_deg (absent: the camera pose at t = 0).

#include <yaml-cpp/yaml.h>

#include "harness/yaml_reader.h"
#include "sim/vio.h"

namespace tofu::harness::internal {

/// Reads a `vio` options map; every key optional (defaults from VioOptions). Throws
/// core::InputError naming line and key path on an unknown key or a value out of range.
sim::VioOptions ReadVioOptions(const YamlValue& value);

/// Emits every option as key/value pairs into the caller's open map.
void EmitVioOptions(YAML::Emitter& out, const sim::VioOptions& options);

}  // namespace tofu::harness::internal
