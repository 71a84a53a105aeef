#include "core/option_fields.h"

#include <algorithm>
#include <cassert>
#include <charconv>
#include <cmath>
#include <system_error>

#include <fmt/format.h>

#include "core/units.h"

namespace tofu::core {

// ---- NumberRule ----

NumberRule NumberRule::Any(std::string_view unit) {
  NumberRule rule;
  rule.unit = unit;
  return rule;
}

NumberRule NumberRule::Positive(std::string_view unit) {
  NumberRule rule;
  rule.min = 0.0;
  rule.min_exclusive = true;
  rule.unit = unit;
  return rule;
}

NumberRule NumberRule::NonNegative(std::string_view unit) {
  NumberRule rule;
  rule.min = 0.0;
  rule.unit = unit;
  return rule;
}

NumberRule NumberRule::Between(double lo, double hi, std::string_view unit) {
  NumberRule rule;
  rule.min = lo;
  rule.max = hi;
  rule.unit = unit;
  return rule;
}

NumberRule NumberRule::PositiveAtMost(double hi, std::string_view unit) {
  NumberRule rule = Positive(unit);
  rule.max = hi;
  return rule;
}

bool NumberRule::Accepts(double value) const {
  if (min && (min_exclusive ? !(value > *min) : !(value >= *min))) return false;
  if (max && (max_exclusive ? !(value < *max) : !(value <= *max))) return false;
  return true;
}

std::string NumberRule::Describe() const {
  std::string bounds;
  if (min && max) {
    bounds = fmt::format(" in {}{}, {}{}", min_exclusive ? "(" : "[", FormatDouble(*min),
                         FormatDouble(*max), max_exclusive ? ")" : "]");
  } else if (min) {
    bounds = fmt::format(" {} {}", min_exclusive ? ">" : ">=", FormatDouble(*min));
  } else if (max) {
    bounds = fmt::format(" {} {}", max_exclusive ? "<" : "<=", FormatDouble(*max));
  }
  if (!unit.empty()) bounds += fmt::format(" ({})", unit);
  return bounds;
}

std::string FormatDouble(double value) {
  char buffer[64];
  const auto result = std::to_chars(buffer, buffer + sizeof(buffer), value);
  assert(result.ec == std::errc());
  return std::string(buffer, result.ptr);
}

NumberRule NumberRule::Scaled(double factor) const {
  assert(factor > 0.0);
  NumberRule rule = *this;
  if (rule.min) *rule.min *= factor;
  if (rule.max) *rule.max *= factor;
  return rule;
}

// ---- checks of a field's value (CheckOptionFields) ----

namespace {

// The value as the file writes it (degrees for an angle stored in radians).
double InFileUnits(const FieldFormat& format, double stored) {
  return format.degrees ? stored * kDegPerRad : stored;
}

// The rule on the stored value: the rule's bounds converted as a read value is.
NumberRule StoredRule(const FieldFormat& format) {
  return format.degrees ? format.rule.Scaled(kRadPerDeg) : format.rule;
}

template <std::size_t N>
std::string CheckNumbers(const FieldFormat& format, const std::array<double, N>& values) {
  const NumberRule stored_rule = StoredRule(format);
  bool ok = true;
  std::string text = "[";
  for (std::size_t i = 0; i < N; ++i) {
    ok = ok && std::isfinite(values[i]) && stored_rule.Accepts(values[i]);
    text += (i > 0 ? ", " : "") + FormatDouble(InFileUnits(format, values[i]));
  }
  if (ok) return {};
  return fmt::format("expected {} finite numbers{}, got {}]", N, format.rule.Describe(), text);
}

}  // namespace

std::string CheckField(const FieldFormat& format, double value) {
  if (!std::isfinite(value)) {
    return fmt::format("expected a finite number{}, got {}", format.rule.Describe(), value);
  }
  if (!StoredRule(format).Accepts(value)) {
    return fmt::format("expected a number{}, got {}", format.rule.Describe(),
                       FormatDouble(InFileUnits(format, value)));
  }
  return {};
}

std::string CheckField(const FieldFormat& format, int value) {
  if (value < format.min_integer || value > format.max_integer) {
    return fmt::format("expected an integer in [{}, {}], got {}", format.min_integer,
                       format.max_integer, value);
  }
  return {};
}

std::string CheckField(const FieldFormat&, bool) { return {}; }

std::string CheckField(const FieldFormat&, const std::string& value) {
  const bool valid = !value.empty() && std::all_of(value.begin(), value.end(), [](char c) {
    return (c >= 'a' && c <= 'z') || (c >= '0' && c <= '9') || c == '_';
  });
  if (valid) return {};
  return fmt::format("expected a name of lowercase letters, digits and '_' ([a-z0-9_]+), got '{}'",
                     value);
}

std::string CheckField(const FieldFormat& format, const Eigen::Vector3d& value) {
  return CheckNumbers<3>(format, {value.x(), value.y(), value.z()});
}

std::string CheckField(const FieldFormat& format, const std::array<double, 2>& value) {
  return CheckNumbers<2>(format, value);
}

std::string CheckField(const FieldFormat& format, const std::optional<Eigen::Vector3d>& value) {
  return value ? CheckField(format, *value) : std::string();
}

std::string CheckField(const FieldFormat&, const std::optional<Eigen::Quaterniond>& value) {
  if (!value) return {};
  // An attitude: a unit quaternion (the models use it as a rotation without normalizing).
  const double norm = value->coeffs().norm();
  if (std::isfinite(norm) && std::abs(norm - 1.0) <= 1e-6) return {};
  return fmt::format("expected a finite unit quaternion, got norm {}", norm);
}

std::string CheckField(const FieldFormat& format, const std::optional<double>& value) {
  return value ? CheckField(format, *value) : std::string();
}

std::string_view ChoiceWord(const FieldFormat& format, int value) {
  for (const ChoiceName& choice : format.choices) {
    if (choice.value == value) return choice.name;
  }
  return {};
}

std::string ChoiceList(const FieldFormat& format) {
  std::string text;
  for (std::size_t i = 0; i < format.choices.size(); ++i) {
    text += (i == 0 ? "" : i + 1 == format.choices.size() ? " or " : ", ");
    text += format.choices[i].name;
  }
  return text;
}

std::string CheckField(const FieldFormat& format, ChoiceValue value) {
  if (!ChoiceWord(format, value.value).empty()) return {};
  return fmt::format("expected {}, got the value {}", ChoiceList(format), value.value);
}

}  // namespace tofu::core
