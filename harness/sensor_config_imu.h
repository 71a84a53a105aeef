#pragma once
// Private to harness: the IMU's options in YAML (sensors.<name> with type: imu). Keys are
// the option fields (Kalibr-convention noise densities in rad and m units, so Kalibr's
// imu.yaml values paste in); the misalignment angles are in degrees (*_deg).

#include <yaml-cpp/yaml.h>

#include "harness/yaml_reader.h"
#include "sim/imu.h"

namespace tofu::harness::internal {

/// Reads the option keys of an IMU (strict: unknown keys and out-of-range values are
/// InputErrors naming line and key path). Absent keys keep the defaults. `type` is the
/// caller's key, accepted and ignored here.
sim::ImuOptions ReadImuOptions(const YamlValue& value);

/// Emits every option as key/values into the caller's open map (round-trip formatting).
void EmitImuOptions(YAML::Emitter& out, const sim::ImuOptions& options);

}  // namespace tofu::harness::internal
