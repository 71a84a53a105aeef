#pragma once
// Strict YAML field readers of the logs' YAML files (a run's calibration.yaml, EuRoC's
// sensor.yaml): every failure is a core::InputError naming file, line, column, key and
// the expected form.

#include <string>

#include <Eigen/Geometry>
#include <yaml-cpp/yaml.h>

#include "core/error.h"

namespace tofu::replay {

/// An InputError at `mark` (1-based line and column; 0 when the mark is unknown).
core::InputError YamlError(const std::string& file, const YAML::Mark& mark, const std::string& key,
                           const std::string& message);

/// A YAML text's root; a syntax error is an InputError at its line and column.
YAML::Node LoadYamlText(const std::string& text, const std::string& file);

/// A scalar's text (a missing node or a map or list is an InputError: "expected a string").
std::string YamlString(const YAML::Node& node, const std::string& file, const std::string& key);

/// A scalar that parses as a number (not necessarily finite).
double YamlNumber(const YAML::Node& node, const std::string& file, const std::string& key);

/// {p_m: [x, y, z], q_wxyz: [w, x, y, z]} as an isometry (the quaternion normalised; one
/// farther than 0.5 from unit norm is refused).
Eigen::Isometry3d YamlPose(const YAML::Node& node, const std::string& file, const std::string& key);

}  // namespace tofu::replay
