#pragma once
// Private to harness: the GNSS RTK receiver's options in YAML (sensors.<name> with
// type: gnss). Keys are the option fields; angles in degrees (*_deg); the error model of
// each fix type is a nested map (rtk_fixed, rtk_float, single).

#include <yaml-cpp/yaml.h>

#include "harness/yaml_reader.h"
#include "sim/gnss.h"

namespace tofu::harness::internal {

/// Reads the option keys of a GNSS receiver (strict: unknown keys, out-of-range values
/// and satellite thresholds out of order are InputErrors naming line and key path).
/// Absent keys keep the defaults. `type` is the caller's key, accepted and ignored here.
sim::GnssOptions ReadGnssOptions(const YamlValue& value);

/// Emits every option as key/values into the caller's open map (round-trip formatting).
void EmitGnssOptions(YAML::Emitter& out, const sim::GnssOptions& options);

}  // namespace tofu::harness::internal
