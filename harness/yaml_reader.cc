#include "harness/yaml_reader.h"

#include <fmt/format.h>
#include <fmt/ranges.h>
#include <yaml-cpp/eventhandler.h>
#include <yaml-cpp/parser.h>

#include <algorithm>
#include <cassert>
#include <charconv>
#include <cmath>
#include <limits>
#include <sstream>
#include <system_error>
#include <utility>

namespace tofu::harness {
namespace {

// yaml-cpp tags: "?" for plain scalars, "!" for quoted ones.
bool IsQuoted(const YAML::Node& node) { return node.IsScalar() && node.Tag() == "!"; }

// The YAML 1.2 core-schema spellings of infinities and NaN.
bool IsYamlNonFinite(std::string_view text) {
  if (!text.empty() && (text.front() == '+' || text.front() == '-')) text.remove_prefix(1);
  return text == ".inf" || text == ".Inf" || text == ".INF" || text == ".nan" || text == ".NaN" ||
         text == ".NAN";
}

// Scalar text for a message: one line, bounded length.
std::string Quote(std::string_view text) {
  std::string out;
  for (char c : text) {
    if (c == '\n') {
      out += "\\n";
    } else if (c == '\t') {
      out += "\\t";
    } else if (c == '\r') {
      out += "\\r";
    } else {
      out += c;
    }
  }
  constexpr size_t kMaxChars = 60;
  if (out.size() > kMaxChars) out = out.substr(0, kMaxChars) + "...";
  return "'" + out + "'";
}

std::string Join(const std::vector<std::string>& words) {
  return fmt::format("{}", fmt::join(words, ", "));
}

size_t EditDistance(std::string_view a, std::string_view b) {
  // Levenshtein distance, one row at a time.
  std::vector<size_t> row(b.size() + 1);
  for (size_t j = 0; j <= b.size(); ++j) row[j] = j;
  for (size_t i = 1; i <= a.size(); ++i) {
    size_t diagonal = row[0];
    row[0] = i;
    for (size_t j = 1; j <= b.size(); ++j) {
      const size_t above = row[j];
      const size_t substitution = diagonal + (a[i - 1] == b[j - 1] ? 0 : 1);
      row[j] = std::min({above + 1, row[j - 1] + 1, substitution});
      diagonal = above;
    }
  }
  return row[b.size()];
}

// The marks of one document as yaml-cpp's parser reports them: where it starts and
// where its root node was written. Every other event is ignored.
class DocumentMarks : public YAML::EventHandler {
 public:
  YAML::Mark start = YAML::Mark::null_mark();
  YAML::Mark root = YAML::Mark::null_mark();

  void OnDocumentStart(const YAML::Mark& mark) override { start = mark; }
  void OnDocumentEnd() override {}
  void OnNull(const YAML::Mark& mark, YAML::anchor_t) override { Node(mark); }
  void OnAlias(const YAML::Mark& mark, YAML::anchor_t) override { Node(mark); }
  void OnScalar(const YAML::Mark& mark, const std::string&, YAML::anchor_t,
                const std::string&) override {
    Node(mark);
  }
  void OnSequenceStart(const YAML::Mark& mark, const std::string&, YAML::anchor_t,
                       YAML::EmitterStyle::value) override {
    Node(mark);
  }
  void OnSequenceEnd() override {}
  void OnMapStart(const YAML::Mark& mark, const std::string&, YAML::anchor_t,
                  YAML::EmitterStyle::value) override {
    Node(mark);
  }
  void OnMapEnd() override {}

 private:
  void Node(const YAML::Mark& mark) {
    if (!seen_root_) root = mark;
    seen_root_ = true;
  }
  bool seen_root_ = false;
};

std::string ChildPath(const std::string& parent, std::string_view key) {
  return parent.empty() ? std::string(key) : parent + "." + std::string(key);
}

}  // namespace

std::string ClosestMatch(std::string_view word, const std::vector<std::string>& candidates) {
  std::string best;
  size_t best_distance = std::max<size_t>(2, word.size() / 3) + 1;
  for (const std::string& candidate : candidates) {
    const size_t distance = EditDistance(word, candidate);
    if (distance < best_distance) {
      best_distance = distance;
      best = candidate;
    }
  }
  if (!best.empty() || word.empty()) return best;
  // A key written without its unit suffix ("rpy" for "rpy_deg").
  for (const std::string& candidate : candidates) {
    if (candidate.size() > word.size() && candidate.compare(0, word.size(), word) == 0 &&
        candidate[word.size()] == '_') {
      return candidate;
    }
  }
  return best;
}

// ---- YamlValue ----

YamlValue::YamlValue(YAML::Node node, std::string path, std::shared_ptr<const std::string> file,
                     YAML::Mark key_mark)
    : node_(std::move(node)), path_(std::move(path)), file_(std::move(file)), key_mark_(key_mark) {}

core::SourceLocation YamlValue::LocationOf(const YAML::Mark& mark) const {
  core::SourceLocation location;
  location.file = *file_;
  if (!mark.is_null() && mark.line >= 0) {
    location.line = mark.line + 1;
    location.column = mark.column + 1;
  }
  return location;
}

core::SourceLocation YamlValue::location() const {
  // yaml-cpp marks an implicit null at the next token: point at the key instead.
  if (!node_.IsDefined() || node_.IsNull()) return LocationOf(key_mark_);
  return LocationOf(node_.Mark());
}

core::SourceLocation YamlValue::key_location() const { return LocationOf(key_mark_); }

void YamlValue::Fail(const std::string& message) const {
  throw core::InputError(location(), path_, message);
}

void YamlValue::FailAtKey(const std::string& message) const {
  throw core::InputError(key_location(), path_, message);
}

void YamlValue::FailExpected(const std::string& expected) const {
  Fail(fmt::format("expected {}, got {}", expected, Describe()));
}

std::string YamlValue::Describe() const {
  if (!node_.IsDefined() || node_.IsNull()) return "null (no value)";
  if (node_.IsMap()) return node_.size() == 0 ? "an empty map" : "a map";
  if (node_.IsSequence()) {
    return node_.size() == 0 ? std::string("an empty list")
                             : fmt::format("a list of {}", node_.size());
  }
  if (IsQuoted(node_)) return "the quoted string " + Quote(node_.Scalar());
  return Quote(node_.Scalar());
}

YamlValue YamlValue::Child(const YAML::Node& node, std::string path, YAML::Mark key_mark) const {
  return YamlValue(node, std::move(path), file_, key_mark);
}

double YamlValue::Number(const NumberRule& rule) const {
  const std::string expected = "a number" + rule.Describe();
  if (!node_.IsScalar() || IsQuoted(node_)) FailExpected(expected);
  std::string_view text = node_.Scalar();
  if (IsYamlNonFinite(text)) {
    Fail(fmt::format("expected a finite number{}, got {}", rule.Describe(), Quote(text)));
  }
  // YAML 1.2 core-schema decimal floats and integers only: no hex, no '_' separators.
  const bool decimal_chars = !text.empty() && std::all_of(text.begin(), text.end(), [](char c) {
    return (c >= '0' && c <= '9') || c == '.' || c == 'e' || c == 'E' || c == '+' || c == '-';
  });
  if (!decimal_chars) FailExpected(expected);
  std::string_view digits = text;
  if (digits.front() == '+') digits.remove_prefix(1);
  double value = 0.0;
  const auto result = std::from_chars(digits.data(), digits.data() + digits.size(), value,
                                      std::chars_format::general);
  if (result.ec == std::errc::result_out_of_range) {
    Fail(fmt::format("expected a finite number{}, got {} (outside the range of a double)",
                     rule.Describe(), Quote(text)));
  }
  if (result.ec != std::errc() || result.ptr != digits.data() + digits.size()) {
    FailExpected(expected);
  }
  if (!std::isfinite(value)) {
    Fail(fmt::format("expected a finite number{}, got {}", rule.Describe(), Quote(text)));
  }
  if (!rule.Accepts(value)) FailExpected(expected);
  return value;
}

std::vector<double> YamlValue::Numbers(size_t count, const NumberRule& rule) const {
  const std::string expected = fmt::format("a list of {} numbers{}", count, rule.Describe());
  if (!node_.IsSequence()) FailExpected(expected);
  if (node_.size() != count) FailExpected(expected);
  std::vector<double> values;
  values.reserve(count);
  for (size_t i = 0; i < count; ++i) {
    const YAML::Node element = node_[i];
    values.push_back(Child(element, fmt::format("{}[{}]", path_, i), element.Mark()).Number(rule));
  }
  return values;
}

Eigen::Vector3d YamlValue::Vector3(const NumberRule& rule, bool allow_scalar) const {
  if (allow_scalar && node_.IsScalar()) {
    const std::string expected = fmt::format("a number or a list of 3 numbers{}", rule.Describe());
    if (IsQuoted(node_)) FailExpected(expected);
    return Eigen::Vector3d::Constant(Number(rule));
  }
  if (allow_scalar && !node_.IsSequence()) {
    FailExpected(fmt::format("a number or a list of 3 numbers{}", rule.Describe()));
  }
  const std::vector<double> values = Numbers(3, rule);
  return Eigen::Vector3d(values[0], values[1], values[2]);
}

uint64_t YamlValue::UnsignedInteger() const {
  const std::string expected = "a non-negative integer (at most 18446744073709551615)";
  if (!node_.IsScalar() || IsQuoted(node_)) FailExpected(expected);
  std::string_view text = node_.Scalar();
  if (!text.empty() && text.front() == '+') text.remove_prefix(1);
  const bool all_digits = !text.empty() && std::all_of(text.begin(), text.end(),
                                                       [](char c) { return c >= '0' && c <= '9'; });
  if (!all_digits) FailExpected(expected);
  uint64_t value = 0;
  const auto result = std::from_chars(text.data(), text.data() + text.size(), value);
  if (result.ec != std::errc() || result.ptr != text.data() + text.size()) FailExpected(expected);
  return value;
}

bool YamlValue::Bool() const {
  const std::string expected = "true or false";
  if (!node_.IsScalar() || IsQuoted(node_)) FailExpected(expected);
  const std::string& text = node_.Scalar();
  if (text == "true" || text == "True" || text == "TRUE") return true;
  if (text == "false" || text == "False" || text == "FALSE") return false;
  FailExpected(expected);
}

std::string YamlValue::String() const {
  if (!node_.IsScalar()) FailExpected("a string");
  return node_.Scalar();
}

std::string YamlValue::Identifier() const {
  const std::string expected = "a name of lowercase letters, digits and '_' ([a-z0-9_]+)";
  if (!node_.IsScalar()) FailExpected(expected);
  const std::string& text = node_.Scalar();
  const bool valid = !text.empty() && std::all_of(text.begin(), text.end(), [](char c) {
    return (c >= 'a' && c <= 'z') || (c >= '0' && c <= '9') || c == '_';
  });
  if (!valid) FailExpected(expected);
  return text;
}

YamlMap YamlValue::Map(std::initializer_list<std::string_view> allowed) const {
  return Map(std::span<const std::string_view>(allowed.begin(), allowed.size()));
}

YamlMap YamlValue::Map(std::span<const std::string_view> allowed) const {
  std::vector<std::string> allowed_keys(allowed.begin(), allowed.end());
  std::vector<YamlValue> values;
  std::vector<std::string> keys;
  if (!node_.IsDefined() || node_.IsNull()) {
    return YamlMap(*this, std::move(allowed_keys), std::move(values), std::move(keys));
  }
  if (!node_.IsMap()) FailExpected(fmt::format("a map (keys: {})", Join(allowed_keys)));

  // Check every key in document order: a scalar, allowed, and not seen before (yaml-cpp
  // keeps duplicates; lookups would silently pick one of them).
  std::vector<YAML::Mark> key_marks;
  for (auto it = node_.begin(); it != node_.end(); ++it) {
    const YAML::Node key = it->first;
    if (!key.IsScalar()) {
      Child(key, path_, key.Mark())
          .FailExpected(fmt::format("a key name (one of: {})", Join(allowed_keys)));
    }
    const std::string& name = key.Scalar();
    const YamlValue value = Child(it->second, ChildPath(path_, name), key.Mark());
    const auto previous = std::find(keys.begin(), keys.end(), name);
    if (previous != keys.end()) {
      const YAML::Mark first = key_marks[static_cast<size_t>(previous - keys.begin())];
      value.FailAtKey(fmt::format("duplicate key '{}' (first given at line {}, column {})", name,
                                  first.line + 1, first.column + 1));
    }
    if (std::find(allowed_keys.begin(), allowed_keys.end(), name) == allowed_keys.end()) {
      const std::string suggestion = ClosestMatch(name, allowed_keys);
      value.FailAtKey(
          fmt::format("unknown key {}{}; allowed keys here: {}", Quote(name),
                      suggestion.empty() ? "" : fmt::format(" (did you mean '{}'?)", suggestion),
                      Join(allowed_keys)));
    }
    keys.push_back(name);
    key_marks.push_back(key.Mark());
    values.push_back(value);
  }
  return YamlMap(*this, std::move(allowed_keys), std::move(values), std::move(keys));
}

std::optional<YamlValue> YamlValue::Peek(std::string_view key) const {
  if (!node_.IsMap()) return std::nullopt;
  for (auto it = node_.begin(); it != node_.end(); ++it) {
    if (it->first.IsScalar() && it->first.Scalar() == key) {
      return Child(it->second, ChildPath(path_, key), it->first.Mark());
    }
  }
  return std::nullopt;
}

YamlValue YamlValue::Without(std::string_view key) const {
  if (!node_.IsMap()) return *this;
  // Rebuilt from the original nodes (YAML::Clone would drop their marks).
  YAML::Node copy(YAML::NodeType::Map);
  for (auto it = node_.begin(); it != node_.end(); ++it) {
    if (it->first.IsScalar() && it->first.Scalar() == key) continue;
    copy.force_insert(it->first, it->second);
  }
  // A new value: assigning to node_ would write through yaml-cpp's shared handle into
  // the original document.
  return YamlValue(copy, path_, file_, key_mark_);
}

std::vector<std::pair<std::string, YamlValue>> YamlValue::Entries() const {
  return EntriesNamedBy([](const YamlValue& key) { return key.Identifier(); },
                        "a map of names to maps");
}

std::vector<std::pair<std::string, YamlValue>> YamlValue::StringEntries() const {
  return EntriesNamedBy([](const YamlValue& key) {
    std::string name = key.String();
    if (name.empty()) key.FailExpected("a non-empty key");
    return name;
  }, "a map");
}

std::vector<std::pair<std::string, YamlValue>> YamlValue::EntriesNamedBy(
    std::string (*name_of)(const YamlValue& key), const char* expected) const {
  std::vector<std::pair<std::string, YamlValue>> entries;
  if (!node_.IsDefined() || node_.IsNull()) return entries;
  if (!node_.IsMap()) FailExpected(expected);
  std::vector<YAML::Mark> key_marks;
  for (auto it = node_.begin(); it != node_.end(); ++it) {
    const YAML::Node key = it->first;
    const YamlValue key_value = Child(key, path_, key.Mark());
    const std::string name = name_of(key_value);
    const YamlValue value = Child(it->second, ChildPath(path_, name), key.Mark());
    for (size_t i = 0; i < entries.size(); ++i) {
      if (entries[i].first == name) {
        value.FailAtKey(fmt::format("duplicate key '{}' (first given at line {}, column {})",
                                    name, key_marks[i].line + 1, key_marks[i].column + 1));
      }
    }
    entries.emplace_back(name, value);
    key_marks.push_back(key.Mark());
  }
  return entries;
}

std::vector<YamlValue> YamlValue::List(bool non_empty) const {
  std::vector<YamlValue> items;
  const char* expected = non_empty ? "a non-empty list" : "a list";
  if (!node_.IsDefined() || node_.IsNull()) {
    if (non_empty) FailExpected(expected);
    return items;
  }
  if (!node_.IsSequence()) FailExpected(expected);
  if (non_empty && node_.size() == 0) FailExpected(expected);
  for (size_t i = 0; i < node_.size(); ++i) {
    const YAML::Node item = node_[i];
    // A list item has no key: its own position stands in for the key's. yaml-cpp marks
    // an empty item ("-" alone) at the next token, so fall back to the list's position.
    const YAML::Mark mark = item.IsNull() ? node_.Mark() : item.Mark();
    items.push_back(Child(item, fmt::format("{}[{}]", path_, i), mark));
  }
  return items;
}

// ---- YamlMap ----

YamlMap::YamlMap(YamlValue self, std::vector<std::string> allowed, std::vector<YamlValue> values,
                 std::vector<std::string> keys)
    : self_(std::move(self)),
      allowed_(std::move(allowed)),
      values_(std::move(values)),
      keys_(std::move(keys)),
      consumed_(allowed_.size(), false) {}

std::optional<YamlValue> YamlMap::Optional(std::string_view key) {
  const auto allowed = std::find(allowed_.begin(), allowed_.end(), key);
  assert(allowed != allowed_.end() && "key looked up but not declared allowed");
  if (allowed != allowed_.end()) consumed_[static_cast<size_t>(allowed - allowed_.begin())] = true;
  const auto found = std::find(keys_.begin(), keys_.end(), key);
  if (found == keys_.end()) return std::nullopt;
  return values_[static_cast<size_t>(found - keys_.begin())];
}

YamlValue YamlMap::Required(std::string_view key) {
  std::optional<YamlValue> value = Optional(key);
  if (!value) {
    throw core::InputError(self_.key_location(), ChildPath(self_.path(), key),
                           fmt::format("missing required key '{}'{}", key,
                                       self_.path().empty() ? std::string(" at the top level")
                                                            : " in '" + self_.path() + "'"));
  }
  return *value;
}

bool YamlMap::Has(std::string_view key) const {
  return std::find(keys_.begin(), keys_.end(), key) != keys_.end();
}

void YamlMap::Finish() const {
  assert(std::all_of(consumed_.begin(), consumed_.end(), [](bool c) { return c; }) &&
         "an allowed key was never read by the loader");
}

// ---- document ----

YamlValue ParseDocument(const std::string& text, const std::string& file_label) {
  auto file = std::make_shared<const std::string>(file_label);
  const auto location_of = [&](const YAML::Mark& mark) {
    core::SourceLocation location{file_label, 0, 0};
    if (!mark.is_null() && mark.line >= 0) {
      location.line = mark.line + 1;
      location.column = mark.column + 1;
    }
    return location;
  };
  // Count the documents first, with yaml-cpp's parser directly rather than
  // YAML::LoadAll: on a stray flow indicator at the top level (a line that is just ','),
  // yaml-cpp 0.7 hands out an empty document without consuming the token, again and again,
  // so LoadAll never returns and its memory grows without bound (fuzz finding,
  // docs/FUZZING.md). A document that starts where the previous one did is that case.
  std::vector<DocumentMarks> documents;
  YAML::Node root;
  try {
    std::istringstream in(text);
    YAML::Parser parser(in);
    DocumentMarks marks;
    while (parser.HandleNextDocument(marks)) {
      if (!documents.empty() && marks.start.pos == documents.back().start.pos) {
        const size_t pos = static_cast<size_t>(std::max(marks.start.pos, 0));
        throw core::InputError(
            location_of(marks.start), "",
            fmt::format("YAML syntax error: unexpected {} outside a flow collection ('[...]' or "
                        "'{{...}}')",
                        pos < text.size() ? Quote(text.substr(pos, 1)) : "end of input"));
      }
      documents.push_back(marks);
      marks = DocumentMarks();
    }
    if (documents.size() == 1) root = YAML::Load(text);
  } catch (const YAML::Exception& e) {
    throw core::InputError(location_of(e.mark), "", "YAML syntax error: " + e.msg);
  }
  if (documents.empty() || (documents.size() == 1 && root.IsNull())) {
    throw core::InputError({file_label, 0, 0}, "",
                           "the file is empty: expected a YAML map of scenario keys");
  }
  if (documents.size() > 1) {
    // Where the second document's root was written (the key position of YamlValue for an
    // empty one, which is the same mark).
    throw core::InputError(location_of(documents[1].root), "",
                           fmt::format("expected a single YAML document, found {} (remove the "
                                       "'---' separators)",
                                       documents.size()));
  }
  YamlValue value(root, "", file, root.Mark());
  if (!value.node().IsMap()) value.FailExpected("a map of scenario keys at the top level");
  return value;
}

}  // namespace tofu::harness
