#pragma once
// The strict reader of tofu's YAML files (scenarios in harness/, corpus specs in corpus/)
// over yaml-cpp nodes. Every value it hands out knows
// its key path ("trajectory.segments[2].circle.radius_m") and where it was written, so a
// loader can turn any problem into a one-line core::InputError naming file:line:column,
// the key and the expected form. Maps are opened with the list of their allowed keys:
// unknown and duplicate keys are rejected at once, in document order, and the keys the
// loader reads are tracked so that Finish() can assert the loader read every allowed key.

#include <yaml-cpp/yaml.h>

#include <Eigen/Core>
#include <cstdint>
#include <initializer_list>
#include <memory>
#include <optional>
#include <span>
#include <string>
#include <string_view>
#include <utility>
#include <vector>

#include "core/error.h"
#include "core/option_fields.h"

namespace tofu::harness {

// The number rule and the round-trip formatting of option tables (core/option_fields.h).
using core::FormatDouble;
using core::NumberRule;

/// Closest candidate to `word` if its edit distance is small, else empty.
std::string ClosestMatch(std::string_view word, const std::vector<std::string>& candidates);

class YamlMap;

/// One node of the document together with its key path and the marks needed to locate
/// it. Cheap to copy (yaml-cpp nodes are handles).
class YamlValue {
 public:
  YamlValue(YAML::Node node, std::string path, std::shared_ptr<const std::string> file,
            YAML::Mark key_mark);

  const std::string& path() const { return path_; }
  const YAML::Node& node() const { return node_; }

  /// Where the value itself was written (the key's position if the value is an
  /// implicit null, whose yaml-cpp mark points elsewhere).
  core::SourceLocation location() const;
  /// Where the key that introduced this value was written (a list item's own position;
  /// the root's first key).
  core::SourceLocation key_location() const;

  /// Throws InputError at location() for this path.
  [[noreturn]] void Fail(const std::string& message) const;
  /// Throws InputError at key_location() for this path.
  [[noreturn]] void FailAtKey(const std::string& message) const;
  /// Throws "expected <expected>, got <what this value is>" at location().
  [[noreturn]] void FailExpected(const std::string& expected) const;

  bool IsNull() const { return node_.IsNull(); }

  /// A finite number in the rule's range. Quoted scalars are strings, not numbers.
  double Number(const NumberRule& rule) const;
  /// A list of exactly three numbers; with allow_scalar a single number means all three.
  Eigen::Vector3d Vector3(const NumberRule& rule, bool allow_scalar = false) const;
  /// A list of exactly `count` numbers.
  std::vector<double> Numbers(size_t count, const NumberRule& rule) const;
  /// A non-negative integer that fits 64 bits.
  uint64_t UnsignedInteger() const;
  /// true / false (YAML 1.2 core spellings).
  bool Bool() const;
  /// Any scalar's text.
  std::string String() const;
  /// A non-empty name of [a-z0-9_].
  std::string Identifier() const;

  /// This value as a map whose keys must be among `allowed`; a null value is an empty
  /// map. Throws on a non-map, a non-scalar key, a duplicate or unknown key.
  YamlMap Map(std::initializer_list<std::string_view> allowed) const;
  /// The same with the allowed keys of an option table (harness/option_fields_yaml.h).
  YamlMap Map(std::span<const std::string_view> allowed) const;
  /// The value of `key` if this is a map that has it (no unknown-key checks; for a
  /// selector such as `type` read before the map itself).
  std::optional<YamlValue> Peek(std::string_view key) const;
  /// A copy of this map without `key` (marks kept), e.g. to read a `type` selector first
  /// and hand the rest to the selected type's reader. A non-map is returned unchanged.
  YamlValue Without(std::string_view key) const;
  /// This value as a map whose keys are free names ([a-z0-9_]+, e.g. sensor names), in
  /// document order; a null value is an empty map. Duplicate keys are errors.
  std::vector<std::pair<std::string, YamlValue>> Entries() const;
  /// The same with keys that are any non-empty strings (metric names such as
  /// "methods.<method>.ate_m").
  std::vector<std::pair<std::string, YamlValue>> StringEntries() const;
  /// This value as a list (a null value is an empty list); with non_empty an empty list
  /// is an error.
  std::vector<YamlValue> List(bool non_empty) const;

  /// "a map", "a list", "null", "'abc'" or "the quoted string '5'": for messages.
  std::string Describe() const;

 private:
  YamlValue Child(const YAML::Node& node, std::string path, YAML::Mark key_mark) const;
  std::vector<std::pair<std::string, YamlValue>> EntriesNamedBy(
      std::string (*name_of)(const YamlValue& key), const char* expected) const;
  core::SourceLocation LocationOf(const YAML::Mark& mark) const;

  YAML::Node node_;
  std::string path_;
  std::shared_ptr<const std::string> file_;
  YAML::Mark key_mark_;
};

/// A map whose keys have been checked against an allowed set. Lookups of keys outside
/// that set are programming errors (asserted).
class YamlMap {
 public:
  YamlMap(YamlValue self, std::vector<std::string> allowed, std::vector<YamlValue> values,
          std::vector<std::string> keys);

  const YamlValue& self() const { return self_; }

  /// The value of `key` if present (an explicit null counts as present).
  std::optional<YamlValue> Optional(std::string_view key);
  /// The value of `key`; "missing required key" at the map's key location otherwise.
  YamlValue Required(std::string_view key);
  bool Has(std::string_view key) const;

  /// Keys in document order.
  const std::vector<std::string>& keys() const { return keys_; }

  /// Asserts that every allowed key has been looked up (keeps the loader and its
  /// allowed-key lists in step).
  void Finish() const;

 private:
  YamlValue self_;
  std::vector<std::string> allowed_;
  std::vector<YamlValue> values_;
  std::vector<std::string> keys_;
  std::vector<bool> consumed_;  ///< per allowed key
};

/// Parses one YAML document. Empty input, syntax errors (with yaml-cpp's mark), several
/// documents and a root that is not a map are InputErrors. Returns the root value.
YamlValue ParseDocument(const std::string& text, const std::string& file_label);

}  // namespace tofu::harness
