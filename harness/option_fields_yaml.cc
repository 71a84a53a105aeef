#include "harness/option_fields_yaml.h"

#include <cmath>

#include <fmt/format.h>

#include "harness/config_io.h"

namespace tofu::harness::internal {

using config::kDegPerRad;
using config::kRadPerDeg;

void ReadFieldValue(const YamlValue& value, const core::FieldFormat& format, double* out) {
  *out = value.Number(format.rule);
  if (format.degrees) *out *= kRadPerDeg;
}

void ReadFieldValue(const YamlValue& value, const core::FieldFormat& format, int* out) {
  const double x =
      value.Number(NumberRule::Between(format.min_integer, format.max_integer, ""));
  if (x != std::floor(x)) {
    value.FailExpected(
        fmt::format("an integer in [{}, {}]", format.min_integer, format.max_integer));
  }
  *out = static_cast<int>(x);
}

void ReadFieldValue(const YamlValue& value, const core::FieldFormat&, bool* out) {
  *out = value.Bool();
}

void ReadFieldValue(const YamlValue& value, const core::FieldFormat&, std::string* out) {
  *out = value.Identifier();
}

void ReadFieldValue(const YamlValue& value, const core::FieldFormat& format,
                    Eigen::Vector3d* out) {
  *out = value.Vector3(format.rule, format.scalar_for_vector);
}

void ReadFieldValue(const YamlValue& value, const core::FieldFormat& format,
                    std::array<double, 2>* out) {
  const std::vector<double> values = value.Numbers(2, format.rule);
  *out = {values[0], values[1]};
}

void ReadFieldValue(const YamlValue& value, const core::FieldFormat& format,
                    std::optional<Eigen::Vector3d>* out) {
  *out = value.Vector3(format.rule);
}

void ReadFieldValue(const YamlValue& value, const core::FieldFormat& format,
                    std::optional<Eigen::Quaterniond>* out) {
  *out = config::QuatFromRpyDeg(value.Vector3(format.rule));
}

void ReadFieldValue(const YamlValue& value, const core::FieldFormat& format,
                    std::optional<double>* out) {
  *out = value.Number(format.rule);
}

void ReadFieldValue(const YamlValue& value, const core::FieldFormat& format,
                    core::ChoiceValue* out) {
  const std::string word = value.String();
  for (const core::ChoiceName& choice : format.choices) {
    if (word == choice.name) {
      out->value = choice.value;
      return;
    }
  }
  value.FailExpected(core::ChoiceList(format));
}

void EmitFieldValue(YAML::Emitter& out, const core::FieldFormat& format, double value) {
  config::EmitNumber(out, format.key, format.degrees ? value * kDegPerRad : value);
}

void EmitFieldValue(YAML::Emitter& out, const core::FieldFormat& format, int value) {
  out << YAML::Key << std::string(format.key) << YAML::Value << value;
}

void EmitFieldValue(YAML::Emitter& out, const core::FieldFormat& format, bool value) {
  out << YAML::Key << std::string(format.key) << YAML::Value << value;
}

void EmitFieldValue(YAML::Emitter& out, const core::FieldFormat& format,
                    const std::string& value) {
  out << YAML::Key << std::string(format.key) << YAML::Value << value;
}

void EmitFieldValue(YAML::Emitter& out, const core::FieldFormat& format,
                    const Eigen::Vector3d& value) {
  config::EmitVector(out, format.key, value);
}

void EmitFieldValue(YAML::Emitter& out, const core::FieldFormat& format,
                    const std::array<double, 2>& value) {
  out << YAML::Key << std::string(format.key) << YAML::Value << YAML::Flow << YAML::BeginSeq
      << FormatDouble(value[0]) << FormatDouble(value[1]) << YAML::EndSeq;
}

void EmitFieldValue(YAML::Emitter& out, const core::FieldFormat& format,
                    const std::optional<Eigen::Vector3d>& value) {
  if (value) config::EmitVector(out, format.key, *value);
}

void EmitFieldValue(YAML::Emitter& out, const core::FieldFormat& format,
                    const std::optional<Eigen::Quaterniond>& value) {
  if (value) config::EmitVector(out, format.key, config::RpyDegFromQuat(*value));
}

void EmitFieldValue(YAML::Emitter& out, const core::FieldFormat& format,
                    const std::optional<double>& value) {
  if (value) config::EmitNumber(out, format.key, *value);
}

void EmitFieldValue(YAML::Emitter& out, const core::FieldFormat& format,
                    core::ChoiceValue value) {
  out << YAML::Key << std::string(format.key) << YAML::Value
      << std::string(core::ChoiceWord(format, value.value));
}

void FailInvalidOptions(YamlMap& map, const std::string& why) {
  const std::size_t colon = why.find(": ");
  if (colon != std::string::npos) {
    const std::string_view key(why.data(), colon);
    if (map.Has(key)) {
      // The map's allowed keys include every key of its table: Optional() is defined.
      map.Optional(key)->Fail(why.substr(colon + 2));
    }
  }
  map.self().Fail(why);
}

}  // namespace tofu::harness::internal
