#pragma once
// An options struct's own description of its fields: the key it is written under in
// files (with the unit suffix of the file's value), the member, and the allowed range.
// One table per struct (a static `Fields()` next to the struct) drives its validation
// (`IsValid`, CheckOptionFields below), its YAML reader and writer and its list of keys
// (harness/option_fields_yaml.h): an option is declared in one line, once.

#include <array>
#include <optional>
#include <span>
#include <stdexcept>
#include <string>
#include <string_view>
#include <type_traits>
#include <variant>

#include <Eigen/Core>
#include <Eigen/Geometry>

namespace tofu::core {

/// Allowed range of a number and its unit, for checks and for the "expected ..." text.
struct NumberRule {
  std::optional<double> min;
  bool min_exclusive = false;
  std::optional<double> max;
  bool max_exclusive = false;
  std::string_view unit;  ///< e.g. "m", "Hz"; empty for unitless

  /// Any finite number.
  static NumberRule Any(std::string_view unit);
  /// A number > 0.
  static NumberRule Positive(std::string_view unit);
  /// A number >= 0.
  static NumberRule NonNegative(std::string_view unit);
  /// A number in [lo, hi].
  static NumberRule Between(double lo, double hi, std::string_view unit);
  /// A number in (0, hi].
  static NumberRule PositiveAtMost(double hi, std::string_view unit);

  /// The same rule on a value multiplied by factor > 0 (a bound in degrees applied to a
  /// value stored in radians: the bound is converted as the value was, so a value read at
  /// the bound is still accepted).
  NumberRule Scaled(double factor) const;
  /// True if the (finite) value satisfies the bounds.
  bool Accepts(double value) const;
  /// " in [100, 10000] (Hz)", " > 0 (m)", " (m)": the text after "a number".
  std::string Describe() const;
};

/// Shortest decimal text that parses back to exactly `value` (std::to_chars).
std::string FormatDouble(double value);

/// One word a choice field allows and the enumerator it stands for.
struct ChoiceName {
  std::string_view name;
  int value = 0;
};

/// What the file holds for a field, beyond its member's type.
struct FieldFormat {
  std::string_view key;  ///< as written in files, with the unit suffix of the file's value
  NumberRule rule = NumberRule::Any("");  ///< numbers and each element of vectors, in file units
  /// The file holds degrees (key ..._deg, ..._degps), the member radians.
  bool degrees = false;
  /// A vector field may be written as one number meaning all three components.
  bool scalar_for_vector = false;
  /// Integers: the inclusive range.
  int min_integer = 0;
  int max_integer = 0;
  /// Choice fields: the words allowed, in the order "expected ..." lists them.
  std::span<const ChoiceName> choices;
  /// One line for the reference of scenario keys (`tofu reference`); may be empty.
  std::string_view doc;
};

/// The format of a field under `key` with the number rule `rule` (every other property at
/// its default).
inline FieldFormat FormatOf(std::string_view key, NumberRule rule = NumberRule::Any("")) {
  FieldFormat format;
  format.key = key;
  format.rule = rule;
  return format;
}

/// An enum (or bool) member reached through its value as an int: the member variant
/// cannot name a pointer to every enum type, so a choice field carries these two instead.
template <typename Options>
struct ChoiceMember {
  int (*get)(const Options&) = nullptr;
  void (*set)(Options&, int) = nullptr;
};

/// A choice field's value as CheckField and the YAML reader and writer see it.
struct ChoiceValue {
  int value = 0;
};

/// The value type of a pointer to data member: MemberValue<int Options::*> is int.
template <typename Pointer>
struct MemberValueOf;
template <typename Value, typename Class>
struct MemberValueOf<Value Class::*> {
  using type = Value;
};
template <typename Pointer>
using MemberValue = typename MemberValueOf<Pointer>::type;

/// One field of `Options`: its file format and its member.
template <typename Options>
struct OptionField {
  /// The member kinds options structs hold. std::optional members are written only when
  /// set; an attitude is written as roll, pitch, yaw in degrees (harness/config_io.h).
  using Member = std::variant<double Options::*, int Options::*, bool Options::*,
                              std::string Options::*, Eigen::Vector3d Options::*,
                              std::array<double, 2> Options::*,
                              std::optional<Eigen::Vector3d> Options::*,
                              std::optional<Eigen::Quaterniond> Options::*,
                              std::optional<double> Options::*, ChoiceMember<Options>>;
  FieldFormat format;
  Member member;

  static OptionField Number(std::string_view key, double Options::*m, NumberRule rule) {
    return {FormatOf(key, rule), m};
  }
  /// A member in radians (or rad/s, rad/sqrt(m)) written in degrees; `rule` in degrees.
  static OptionField Degrees(std::string_view key, double Options::*m, NumberRule rule) {
    FieldFormat format = FormatOf(key, rule);
    format.degrees = true;
    return {format, m};
  }
  static OptionField Integer(std::string_view key, int Options::*m, int lo, int hi) {
    FieldFormat format = FormatOf(key);
    format.min_integer = lo;
    format.max_integer = hi;
    return {format, m};
  }
  static OptionField Flag(std::string_view key, bool Options::*m) { return {FormatOf(key), m}; }
  /// A name of [a-z0-9_] (a model site).
  static OptionField Name(std::string_view key, std::string Options::*m) {
    return {FormatOf(key), m};
  }
  static OptionField Vector(std::string_view key, Eigen::Vector3d Options::*m, NumberRule rule,
                            bool scalar_for_all_three = false) {
    FieldFormat format = FormatOf(key, rule);
    format.scalar_for_vector = scalar_for_all_three;
    return {format, m};
  }
  static OptionField Pair(std::string_view key, std::array<double, 2> Options::*m,
                          NumberRule rule) {
    return {FormatOf(key, rule), m};
  }
  /// A number that may be left unset (written only when set).
  static OptionField OptionalNumber(std::string_view key, std::optional<double> Options::*m,
                                    NumberRule rule) {
    return {FormatOf(key, rule), m};
  }
  /// An enum or bool member written as one of `choices`' words (each naming the member's
  /// value as an int); `choices` must outlive the table (a static array).
  template <auto kMember>
  static OptionField Choice(std::string_view key, std::span<const ChoiceName> choices) {
    using Value = MemberValue<decltype(kMember)>;
    FieldFormat format = FormatOf(key);
    format.choices = choices;
    return {format, ChoiceMember<Options>{
                        [](const Options& o) { return static_cast<int>(o.*kMember); },
                        [](Options& o, int v) { o.*kMember = static_cast<Value>(v); }}};
  }
  /// This field with its line of documentation.
  OptionField Doc(std::string_view text) const {
    OptionField field = *this;
    field.format.doc = text;
    return field;
  }
  static OptionField OptionalVector(std::string_view key,
                                    std::optional<Eigen::Vector3d> Options::*m, NumberRule rule) {
    return {FormatOf(key, rule), m};
  }
  /// An optional attitude, written as [roll, pitch, yaw] in degrees.
  static OptionField OptionalAttitude(std::string_view key,
                                      std::optional<Eigen::Quaterniond> Options::*m) {
    FieldFormat format = FormatOf(key, NumberRule::Any("deg"));
    format.degrees = true;
    return {format, m};
  }
};

/// A field of a base struct as a field of a struct derived from it: the same key, unit and
/// limits (an options struct that extends a shared one, such as LiDAR odometry's options
/// the beam pattern, lists the base's fields without writing them again).
template <typename Derived, typename Base>
OptionField<Derived> DerivedField(const OptionField<Base>& field) {
  static_assert(std::is_base_of_v<Base, Derived>);
  return {field.format,
          std::visit(
              [](auto member) -> typename OptionField<Derived>::Member {
                if constexpr (std::is_same_v<decltype(member), ChoiceMember<Base>>) {
                  // Its accessors take the base by reference; none is derived today.
                  throw std::logic_error("DerivedField: a choice field cannot be derived");
                } else {
                  return static_cast<MemberValue<decltype(member)> Derived::*>(member);
                }
              },
              field.member)};
}

// Checks of one value against its field's format: empty when valid, else what is wrong
// ("expected a number in [0, 1], got 2"), with numbers in the file's units.
std::string CheckField(const FieldFormat& format, double value);
std::string CheckField(const FieldFormat& format, int value);
std::string CheckField(const FieldFormat& format, bool value);
std::string CheckField(const FieldFormat& format, const std::string& value);
std::string CheckField(const FieldFormat& format, const Eigen::Vector3d& value);
std::string CheckField(const FieldFormat& format, const std::array<double, 2>& value);
std::string CheckField(const FieldFormat& format, const std::optional<Eigen::Vector3d>& value);
std::string CheckField(const FieldFormat& format, const std::optional<Eigen::Quaterniond>& value);
std::string CheckField(const FieldFormat& format, const std::optional<double>& value);
std::string CheckField(const FieldFormat& format, ChoiceValue value);

/// The word of a choice field's value (empty for a value the field does not list).
std::string_view ChoiceWord(const FieldFormat& format, int value);
/// "a, b or c": a choice field's words as an "expected" text lists them.
std::string ChoiceList(const FieldFormat& format);

/// Calls visitor(value) with the field's value in `options`: the member itself, or a
/// ChoiceValue for a choice field.
template <typename Options, typename Visitor>
decltype(auto) VisitFieldValue(const Options& options, const OptionField<Options>& field,
                               Visitor&& visitor) {
  return std::visit(
      [&](auto member) -> decltype(auto) {
        if constexpr (std::is_same_v<decltype(member), ChoiceMember<Options>>) {
          return visitor(ChoiceValue{member.get(options)});
        } else {
          return visitor(options.*member);
        }
      },
      field.member);
}

/// Whether `a` and `b` hold the same value in `field` (bitwise for numbers: a table's
/// values are parsed or defaulted, never computed, so equal means written alike).
template <typename Options>
bool SameFieldValue(const Options& a, const Options& b, const OptionField<Options>& field) {
  return std::visit(
      [&](auto member) {
        if constexpr (std::is_same_v<decltype(member), ChoiceMember<Options>>) {
          return member.get(a) == member.get(b);
        } else if constexpr (std::is_same_v<decltype(member),
                                            std::optional<Eigen::Quaterniond> Options::*>) {
          const auto& x = a.*member;
          const auto& y = b.*member;
          return x.has_value() == y.has_value() && (!x || x->coeffs() == y->coeffs());
        } else {
          return a.*member == b.*member;
        }
      },
      field.member);
}

/// Sets `field` of *to to its value in `from`.
template <typename Options>
void CopyFieldValue(const Options& from, Options* to, const OptionField<Options>& field) {
  std::visit(
      [&](auto member) {
        if constexpr (std::is_same_v<decltype(member), ChoiceMember<Options>>) {
          member.set(*to, member.get(from));
        } else {
          (*to).*member = from.*member;
        }
      },
      field.member);
}

/// Copies into *to every field of `fields` in which `from` differs from `baseline`.
template <typename Options>
void CopyFieldsThatDiffer(const Options& from, const Options& baseline, Options* to,
                          std::span<const OptionField<Options>> fields) {
  for (const OptionField<Options>& field : fields) {
    if (!SameFieldValue(from, baseline, field)) CopyFieldValue(from, to, field);
  }
}

/// Checks every field of `options` against its table; on the first violation sets *why
/// to "<prefix><key>: <what is wrong>" and returns false (Ceres' IsValid convention).
template <typename Options>
bool CheckOptionFields(const Options& options, std::span<const OptionField<Options>> fields,
                       std::string* why, std::string_view prefix = {}) {
  for (const OptionField<Options>& field : fields) {
    const std::string problem = VisitFieldValue(
        options, field, [&](const auto& value) { return CheckField(field.format, value); });
    if (!problem.empty()) {
      if (why != nullptr) *why = std::string(prefix) + std::string(field.format.key) + ": " + problem;
      return false;
    }
  }
  return true;
}

/// `options` if options.IsValid(), else std::invalid_argument "<who>: <key>: <problem>".
/// Called in a model's member initializers, before anything (periods, noise scales) is
/// derived from the options.
template <typename Options>
const Options& ValidOptions(const Options& options, const std::string& who) {
  std::string why;
  if (!options.IsValid(&why)) throw std::invalid_argument(who + ": " + why);
  return options;
}

}  // namespace tofu::core
