#include "replay/run_calibration.h"

#include <algorithm>
#include <cmath>
#include <system_error>

#include <fmt/format.h>

#include "core/file_io.h"
#include "core/lidar_beam_pattern.h"
#include "core/units.h"
#include "replay/run_format.h"
#include "replay/yaml_fields.h"

namespace tofu::replay {
namespace {

namespace fs = std::filesystem;

std::string YamlText(const YAML::Node& node, const std::string& file, const std::string& key) {
  if (!node.IsScalar()) throw YamlError(file, node.Mark(), key, "expected a string");
  return node.Scalar();
}

std::vector<Eigen::Vector3d> YamlDirections(const YAML::Node& node, const std::string& file,
                                            const std::string& key) {
  if (!node.IsSequence()) {
    throw YamlError(file, node.Mark(), key, "expected a list of unit vectors [[x, y, z], ...]");
  }
  std::vector<Eigen::Vector3d> out;
  for (size_t i = 0; i < node.size(); ++i) {
    const YAML::Node v = node[i];
    const std::string element = fmt::format("{}[{}]", key, i);
    if (!v.IsSequence() || v.size() != 3) {
      throw YamlError(file, v.Mark(), element, "expected a unit vector [x, y, z]");
    }
    Eigen::Vector3d d;
    for (int k = 0; k < 3; ++k) d(k) = YamlNumber(v[k], file, element);
    if (!d.allFinite() || std::abs(d.norm() - 1.0) > 1e-6) {
      throw YamlError(file, v.Mark(), element, "expected a unit vector [x, y, z]");
    }
    out.push_back(d);
  }
  return out;
}

SensorCalibration ParseSensor(const YAML::Node& node, const std::string& file,
                              const std::string& key) {
  if (!node.IsMap()) throw YamlError(file, node.Mark(), key, "expected a map");
  SensorCalibration s;
  if (node["type"]) s.type = YamlText(node["type"], file, key + ".type");
  if (node["site"]) s.site = YamlText(node["site"], file, key + ".site");
  if (node["T_B_s"]) s.T_Bs = YamlPose(node["T_B_s"], file, key + ".T_B_s");
  if (node["true_T_B_s"]) s.true_T_Bs = YamlPose(node["true_T_B_s"], file, key + ".true_T_B_s");
  if (node["true_T_WS"]) s.true_T_WS = YamlPose(node["true_T_WS"], file, key + ".true_T_WS");
  if (node["sky_directions_S"]) {
    s.sky_directions_S = YamlDirections(node["sky_directions_S"], file, key + ".sky_directions_S");
  }
  if (const YAML::Node options = node["options"]; options && options.IsMap()) {
    s.has_options = true;
    for (const auto& entry : options) {
      if (!entry.first.IsScalar()) continue;
      // A value-less key has no mark of its own: its key's line is where to look.
      const YAML::Mark mark =
          entry.second.Mark().is_null() ? entry.first.Mark() : entry.second.Mark();
      const bool scalar = entry.second.IsScalar();
      s.options[entry.first.Scalar()] = {scalar, scalar ? entry.second.Scalar() : "",
                                         mark.is_null() ? 0 : mark.line + 1,
                                         mark.is_null() ? 0 : mark.column + 1};
    }
  }
  return s;
}

}  // namespace

std::optional<double> RunCalibration::OptionNumber(const std::string& sensor,
                                                   const std::string& key) const {
  const auto s = sensors.find(sensor);
  if (s == sensors.end()) return std::nullopt;
  const auto v = s->second.options.find(key);
  if (v == s->second.options.end()) return std::nullopt;
  if (!v->second.scalar) {
    throw core::InputError({file, v->second.line, v->second.column},
                           fmt::format("sensors.{}.options.{}", sensor, key), "expected a number");
  }
  // The scalar again as YAML: the same number syntax (and message) as every other field.
  YAML::Node scalar(v->second.text);
  try {
    return scalar.as<double>();
  } catch (const YAML::Exception&) {
    throw core::InputError({file, v->second.line, v->second.column},
                           fmt::format("sensors.{}.options.{}", sensor, key),
                           fmt::format("expected a number, got '{}'", v->second.text));
  }
}

std::optional<core::LidarBeamPattern> RunCalibration::LidarBeams(
    const std::string& sensor) const {
  const auto s = sensors.find(sensor);
  if (s == sensors.end() || SensorModelOfName(s->second.type) != SensorModel::kLidarOdometry) {
    return std::nullopt;
  }
  const auto fail = [&](std::string_view key, const std::string& expected) {
    const CalibrationScalar& at = s->second.options.at(std::string(key));
    throw core::InputError({file, at.line, at.column},
                           fmt::format("sensors.{}.options.{}", sensor, key), expected);
  };
  // Every field of the pattern's table, converted and checked as the scenario reader does:
  // a pattern outside the limits was not written by a run.
  const auto fields = core::LidarBeamPattern::Fields();
  std::vector<double> values;
  for (const core::OptionField<core::LidarBeamPattern>& field : fields) {
    const std::optional<double> value = OptionNumber(sensor, std::string(field.format.key));
    if (!value) return std::nullopt;
    values.push_back(*value);
  }
  core::LidarBeamPattern beams;
  for (size_t i = 0; i < fields.size(); ++i) {
    const core::OptionField<core::LidarBeamPattern>& field = fields[i];
    const core::FieldFormat& format = field.format;
    const double* value = &values[i];
    if (const auto* integer = std::get_if<int core::LidarBeamPattern::*>(&field.member)) {
      if (!(*value >= format.min_integer && *value <= format.max_integer &&
            *value == std::floor(*value))) {
        fail(format.key, fmt::format("expected an integer in [{}, {}], got {}",
                                     format.min_integer, format.max_integer, *value));
      }
      beams.**integer = static_cast<int>(*value);
    } else {
      const double stored = format.degrees ? *value * core::kRadPerDeg : *value;
      const std::string problem = core::CheckField(format, stored);
      if (!problem.empty()) fail(format.key, problem);
      beams.*std::get<double core::LidarBeamPattern::*>(field.member) = stored;
    }
  }
  std::string why;
  if (!beams.IsValid(&why)) {
    const size_t colon = why.find(':');
    fail(why.substr(0, colon), why.substr(std::min(why.size(), colon + 2)));
  }
  return beams;
}

namespace {

// A map of names (sites, sensors: `what`) to poses at `key`.
std::map<std::string, Eigen::Isometry3d> YamlPoseMap(const YAML::Node& node, const std::string& file,
                                                     const std::string& key, const std::string& what) {
  if (!node.IsMap()) {
    throw YamlError(file, node.Mark(), key, fmt::format("expected a map of {} name to pose", what));
  }
  std::map<std::string, Eigen::Isometry3d> poses;
  for (const auto& entry : node) {
    const std::string name = YamlText(entry.first, file, key);
    poses[name] = YamlPose(entry.second, file, key + "." + name);
  }
  return poses;
}

}  // namespace

RunCalibration ParseRunCalibration(const std::string& text, const std::string& file) {
  RunCalibration cal;
  cal.present = true;
  cal.file = file;
  const YAML::Node root = LoadYamlText(text, file);
  if (root.IsNull()) return cal;
  if (!root.IsMap()) throw YamlError(file, root.Mark(), "", "expected a map (tofu calibration)");
  if (const YAML::Node mounts = root["mounts"]) cal.mounts = YamlPoseMap(mounts, file, "mounts", "site");
  if (const YAML::Node mission = root["mission"]) {
    if (!mission.IsMap()) {
      throw YamlError(file, mission.Mark(), "mission",
                      "expected a map {T_MB_launch: pose, T_MS: {<sensor>: pose}}");
    }
    if (mission["T_MB_launch"]) {
      cal.T_MB_launch = YamlPose(mission["T_MB_launch"], file, "mission.T_MB_launch");
    }
    if (const YAML::Node surveyed = mission["T_MS"]) {
      cal.T_MS = YamlPoseMap(surveyed, file, "mission.T_MS", "sensor");
    }
  }
  const YAML::Node sensors = root["sensors"];
  if (!sensors) return cal;
  if (!sensors.IsMap()) {
    throw YamlError(file, sensors.Mark(), "sensors", "expected a map of sensor name to calibration");
  }
  for (const auto& entry : sensors) {
    if (!entry.first.IsScalar()) {
      throw YamlError(file, entry.first.Mark(), "sensors",
                      "expected a sensor name (a string) as each key of sensors");
    }
    const std::string name = entry.first.Scalar();
    cal.sensors[name] = ParseSensor(entry.second, file, "sensors." + name);
  }
  return cal;
}

std::string CalibrationWithoutTruth(const std::string& text, const std::string& file) {
  if (text.empty()) return text;
  YAML::Node root = YAML::Clone(LoadYamlText(text, file));
  if (!root.IsMap()) return text;
  root.remove("mounts");
  if (YAML::Node sensors = root["sensors"]; sensors && sensors.IsMap()) {
    for (auto entry : sensors) {
      if (!entry.second.IsMap()) continue;
      entry.second.remove("true_T_B_s");
      entry.second.remove("true_T_WS");
    }
  }
  YAML::Emitter out;
  out << root;
  return std::string(out.c_str()) + "\n";
}

RunCalibration ReadRunCalibration(const fs::path& path) {
  std::error_code ec;
  if (!fs::is_regular_file(path, ec)) return RunCalibration{};
  return ParseRunCalibration(
      core::ReadWholeFile(path, "calibration file", core::kMaxConfigFileBytes), path.string());
}

}  // namespace tofu::replay
