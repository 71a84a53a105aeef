#pragma once
// Private to harness: the total station's options in YAML (sensors.<name> with
// type: total_station). Keys are the option fields; angles in degrees (*_deg, *_degps).

#include <yaml-cpp/yaml.h>

#include "harness/yaml_reader.h"
#include "sim/total_station.h"

namespace tofu::harness::internal {

/// Reads the option keys of a total station (strict: unknown keys and out-of-range
/// values are InputErrors naming line and key path). Absent keys keep the defaults.
/// `type` is the caller's key and is accepted and ignored here.
sim::TotalStationOptions ReadTotalStationOptions(const YamlValue& value);

/// Emits every option as key/values into the caller's open map (round-trip formatting);
/// the station pose overrides only when set.
void EmitTotalStationOptions(YAML::Emitter& out, const sim::TotalStationOptions& options);

}  // namespace tofu::harness::internal
