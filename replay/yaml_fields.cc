#include "replay/yaml_fields.h"

#include <cmath>
#include <vector>

#include <fmt/format.h>

namespace tofu::replay {

core::InputError YamlError(const std::string& file, const YAML::Mark& mark, const std::string& key,
                           const std::string& message) {
  return core::InputError(
      {file, mark.is_null() ? 0 : mark.line + 1, mark.is_null() ? 0 : mark.column + 1}, key,
      message);
}

YAML::Node LoadYamlText(const std::string& text, const std::string& file) {
  try {
    return YAML::Load(text);
  } catch (const YAML::Exception& e) {
    throw YamlError(file, e.mark, "", fmt::format("not valid YAML: {}", e.msg));
  }
}

std::string YamlString(const YAML::Node& node, const std::string& file, const std::string& key) {
  if (!node || !node.IsScalar()) {
    throw YamlError(file, node ? node.Mark() : YAML::Mark::null_mark(), key, "expected a string");
  }
  return node.Scalar();
}

double YamlNumber(const YAML::Node& node, const std::string& file, const std::string& key) {
  if (!node.IsScalar()) throw YamlError(file, node.Mark(), key, "expected a number");
  try {
    return node.as<double>();
  } catch (const YAML::Exception&) {
    throw YamlError(file, node.Mark(), key,
                    fmt::format("expected a number, got '{}'", node.Scalar()));
  }
}

Eigen::Isometry3d YamlPose(const YAML::Node& node, const std::string& file, const std::string& key) {
  if (!node.IsMap()) {
    throw YamlError(file, node.Mark(), key, "expected a map {p_m: [x, y, z], q_wxyz: [w, x, y, z]}");
  }
  const auto vector = [&](const char* name, size_t n) {
    const YAML::Node v = node[name];
    const std::string sub = key + "." + name;
    if (!v || !v.IsSequence() || v.size() != n) {
      throw YamlError(file, v ? v.Mark() : node.Mark(), sub,
                      fmt::format("expected a list of {} numbers", n));
    }
    std::vector<double> out;
    for (size_t i = 0; i < n; ++i) {
      const std::string element = fmt::format("{}[{}]", sub, i);
      out.push_back(YamlNumber(v[i], file, element));
      if (!std::isfinite(out.back())) {
        throw YamlError(file, v[i].Mark(), element, "expected a finite number");
      }
    }
    return out;
  };
  const std::vector<double> p = vector("p_m", 3);
  const std::vector<double> q = vector("q_wxyz", 4);
  Eigen::Quaterniond quat(q[0], q[1], q[2], q[3]);
  if (!(quat.norm() > 0.5 && quat.norm() < 1.5)) {
    throw YamlError(file, node["q_wxyz"].Mark(), key + ".q_wxyz",
                    "expected a unit quaternion [w, x, y, z]");
  }
  Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
  T.linear() = quat.normalized().toRotationMatrix();
  T.translation() = Eigen::Vector3d(p[0], p[1], p[2]);
  return T;
}

}  // namespace tofu::replay
