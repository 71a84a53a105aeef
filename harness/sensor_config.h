#pragma once
// Private to harness: the sensor options of every type behind one dispatch, for the
// scenario loader and for the run directory's calibration.yaml. Each type's own reader
// and writer live in sensor_config_<type>.cc.

#include <string_view>

#include <Eigen/Geometry>
#include <yaml-cpp/yaml.h>

#include "harness/sensor_suite.h"
#include "harness/yaml_reader.h"

namespace tofu::harness::internal {

/// Reads the options of a sensor of `type` (one of kSensorTypeNames).
SensorOptions ReadSensorOptions(std::string_view type, const YamlValue& value);

/// Writes the options' keys into the current map.
void EmitSensorOptions(YAML::Emitter& out, const SensorOptions& options);

/// `calibration_error: {translation_m: [x, y, z], rpy_deg: [r, p, y]}`: the error of the
/// nominal extrinsics given to the estimator, T_Bs_nominal = T_Bs_true * T_error.
Eigen::Isometry3d ReadCalibrationError(const YamlValue& value);

/// Writes `calibration_error:` into the current map unless it is the identity.
void EmitCalibrationError(YAML::Emitter& out, const Eigen::Isometry3d& error);

}  // namespace tofu::harness::internal
