#pragma once
// Private to harness: an options struct in YAML through its field table
// (core/option_fields.h). The table gives the allowed keys (in its order, which is also
// the order of the writer and of "allowed keys here: ..." messages), the reader of each
// key with its range, and the writer; the struct's IsValid adds the rules between fields.

#include <initializer_list>
#include <span>
#include <stdexcept>
#include <string>
#include <string_view>
#include <type_traits>
#include <variant>
#include <vector>

#include <yaml-cpp/yaml.h>

#include "core/option_fields.h"
#include "harness/yaml_reader.h"

namespace tofu::harness::internal {

// One field's value read from its present key, in the field's format.
void ReadFieldValue(const YamlValue& value, const core::FieldFormat& format, double* out);
void ReadFieldValue(const YamlValue& value, const core::FieldFormat& format, int* out);
void ReadFieldValue(const YamlValue& value, const core::FieldFormat& format, bool* out);
void ReadFieldValue(const YamlValue& value, const core::FieldFormat& format, std::string* out);
void ReadFieldValue(const YamlValue& value, const core::FieldFormat& format, Eigen::Vector3d* out);
void ReadFieldValue(const YamlValue& value, const core::FieldFormat& format,
                    std::array<double, 2>* out);
void ReadFieldValue(const YamlValue& value, const core::FieldFormat& format,
                    std::optional<Eigen::Vector3d>* out);
void ReadFieldValue(const YamlValue& value, const core::FieldFormat& format,
                    std::optional<Eigen::Quaterniond>* out);
void ReadFieldValue(const YamlValue& value, const core::FieldFormat& format,
                    std::optional<double>* out);
void ReadFieldValue(const YamlValue& value, const core::FieldFormat& format,
                    core::ChoiceValue* out);

// One field as `key: value` into the caller's open map (nothing for an unset optional).
void EmitFieldValue(YAML::Emitter& out, const core::FieldFormat& format, double value);
void EmitFieldValue(YAML::Emitter& out, const core::FieldFormat& format, int value);
void EmitFieldValue(YAML::Emitter& out, const core::FieldFormat& format, bool value);
void EmitFieldValue(YAML::Emitter& out, const core::FieldFormat& format, const std::string& value);
void EmitFieldValue(YAML::Emitter& out, const core::FieldFormat& format,
                    const Eigen::Vector3d& value);
void EmitFieldValue(YAML::Emitter& out, const core::FieldFormat& format,
                    const std::array<double, 2>& value);
void EmitFieldValue(YAML::Emitter& out, const core::FieldFormat& format,
                    const std::optional<Eigen::Vector3d>& value);
void EmitFieldValue(YAML::Emitter& out, const core::FieldFormat& format,
                    const std::optional<Eigen::Quaterniond>& value);
void EmitFieldValue(YAML::Emitter& out, const core::FieldFormat& format,
                    const std::optional<double>& value);
void EmitFieldValue(YAML::Emitter& out, const core::FieldFormat& format, core::ChoiceValue value);

/// The allowed keys of a map holding `fields`: `leading` (keys the caller reads itself,
/// such as a sensor's `type`), the table's keys in order, then `trailing`.
template <typename Options>
std::vector<std::string_view> OptionKeys(std::span<const core::OptionField<Options>> fields,
                                         std::initializer_list<std::string_view> leading = {},
                                         std::initializer_list<std::string_view> trailing = {}) {
  std::vector<std::string_view> keys(leading);
  for (const core::OptionField<Options>& field : fields) keys.push_back(field.format.key);
  keys.insert(keys.end(), trailing);
  return keys;
}

/// The format of the field written under `key` (a key of the table: a file whose keys
/// stand in different maps, such as a scenario's world, reads each where it stands).
template <typename Options>
const core::FieldFormat& FieldFormatOf(std::span<const core::OptionField<Options>> fields,
                                       std::string_view key) {
  for (const core::OptionField<Options>& field : fields) {
    if (field.format.key == key) return field.format;
  }
  throw std::logic_error("no option field '" + std::string(key) + "'");
}

/// One field read from `value` into *options.
template <typename Options>
void ReadOptionField(const YamlValue& value, const core::OptionField<Options>& field,
                     Options* options) {
  std::visit(
      [&](auto member) {
        if constexpr (std::is_same_v<decltype(member), core::ChoiceMember<Options>>) {
          core::ChoiceValue choice;
          ReadFieldValue(value, field.format, &choice);
          member.set(*options, choice.value);
        } else {
          ReadFieldValue(value, field.format, &(options->*member));
        }
      },
      field.member);
}

/// Reads every field whose key `map` has into *options; absent keys keep the values
/// *options already holds (the struct's defaults), so defaults are written once.
template <typename Options>
void ReadOptionFields(YamlMap& map, std::span<const core::OptionField<Options>> fields,
                      Options* options) {
  for (const core::OptionField<Options>& field : fields) {
    if (const auto value = map.Optional(field.format.key)) ReadOptionField(*value, field, options);
  }
}

/// Writes every field into the caller's open map, in the table's order.
template <typename Options>
void EmitOptionFields(YAML::Emitter& out, std::span<const core::OptionField<Options>> fields,
                      const Options& options) {
  for (const core::OptionField<Options>& field : fields) {
    core::VisitFieldValue(options, field,
                          [&](const auto& value) { EmitFieldValue(out, field.format, value); });
  }
}

/// Turns a failed IsValid into an InputError: `why` is "<key>: <problem>" (the options
/// convention of core/option_fields.h); it is reported at that key's value when `map`
/// has the key, else at the map itself.
[[noreturn]] void FailInvalidOptions(YamlMap& map, const std::string& why);

/// Ends the reading of an options map: unknown keys refused (YamlMap::Finish), then the
/// struct's own IsValid, whose verdict is reported at the offending key.
template <typename Options>
void FinishOptionsMap(YamlMap& map, const Options& options) {
  map.Finish();
  std::string why;
  if (!options.IsValid(&why)) FailInvalidOptions(map, why);
}

}  // namespace tofu::harness::internal
