#pragma once
// Private to harness: the sensor options of every type in YAML, for the scenario loader
// and for the run directory's calibration.yaml. Each type's keys, units, limits and
// writer come from its options struct's field table (sim::ImuOptions::Fields(), ...,
// through harness/option_fields_yaml.h); the rules between fields are the struct's
// IsValid.

#include <string_view>

#include <Eigen/Geometry>
#include <yaml-cpp/yaml.h>

#include "harness/sensor_suite.h"
#include "harness/yaml_reader.h"

namespace tofu::harness::internal {

/// Reads the options of a sensor of `type` (one of kSensorTypeNames). Strict: unknown
/// keys and out-of-range values are InputErrors naming line and key path; absent keys
/// keep the defaults; `type` itself is the caller's key, accepted and ignored here.
SensorOptions ReadSensorOptions(std::string_view type, const YamlValue& value);

/// The same for one type known at compile time (Options: sim::ImuOptions, sim::VioOptions,
/// sim::LidarOdometryOptions, sim::TotalStationOptions, sim::GnssOptions).
template <typename Options>
Options ReadSensorOptions(const YamlValue& value);

/// Writes every option's key into the current map (round-trip formatting).
void EmitSensorOptions(YAML::Emitter& out, const SensorOptions& options);

/// `calibration_error: {translation_m: [x, y, z], rpy_deg: [r, p, y]}`: the error of the
/// nominal extrinsics given to the estimator, T_Bs_nominal = T_Bs_true * T_error.
Eigen::Isometry3d ReadCalibrationError(const YamlValue& value);

/// Writes `calibration_error:` into the current map unless it is the identity.
void EmitCalibrationError(YAML::Emitter& out, const Eigen::Isometry3d& error);

}  // namespace tofu::harness::internal
