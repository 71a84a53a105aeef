#include "replay/csv_reader.h"

#include <algorithm>
#include <charconv>
#include <cstdlib>
#include <limits>
#include <optional>
#include <system_error>
#include <utility>

#include <fmt/format.h>

namespace tofu::replay {
namespace {

using core::InputError;

constexpr std::string_view kByteOrderMark = "\xEF\xBB\xBF";

bool IsBlank(char c) { return c == ' ' || c == '\t'; }

std::string_view Trim(std::string_view s) {
  while (!s.empty() && IsBlank(s.front())) s.remove_prefix(1);
  while (!s.empty() && (IsBlank(s.back()) || s.back() == '\r')) s.remove_suffix(1);
  return s;
}

// An integer field, or the message saying why it is not one.
std::optional<int64_t> ParseInteger(std::string_view s, std::string_view what, std::string* error) {
  int64_t value = 0;
  const char* first = s.data();
  const char* last = first + s.size();
  if (first != last && *first == '+') ++first;
  const auto [end, ec] = std::from_chars(first, last, value);
  if (ec != std::errc() || end != last || s.empty()) {
    *error = fmt::format("expected an integer{}{}{}, got {}", what.empty() ? "" : " ", what,
                         ec == std::errc::result_out_of_range ? " (64-bit)" : "", CsvQuoted(s));
    return std::nullopt;
  }
  return value;
}

int FindKey(const std::vector<std::string>& keys, std::string_view key) {
  const auto it = std::find(keys.begin(), keys.end(), key);
  return it == keys.end() ? -1 : static_cast<int>(it - keys.begin());
}

}  // namespace

std::optional<double> ParseCsvNumber(std::string_view s, std::string* error) {
  if (s.empty()) {
    *error = "empty field, expected a number";
    return std::nullopt;
  }
  double value = 0.0;
  const char* first = s.data();
  const char* last = first + s.size();
  if (first != last && *first == '+') ++first;  // from_chars rejects a leading '+'
  const auto [end, ec] = std::from_chars(first, last, value);
  if (end != last || (ec != std::errc() && ec != std::errc::result_out_of_range)) {
    *error = fmt::format("expected a number, got {}", CsvQuoted(s));
    return std::nullopt;
  }
  if (ec == std::errc::result_out_of_range) {
    // Beyond the double range: an underflow to 0 or an overflow to +-Inf, as strtod.
    value = std::strtod(std::string(s).c_str(), nullptr);
  }
  return value;
}

std::string CsvQuoted(std::string_view s) {
  constexpr size_t kMax = 60;
  if (s.size() <= kMax) return fmt::format("'{}'", s);
  return fmt::format("'{}...'", s.substr(0, kMax));
}

std::string_view CsvColumnKey(std::string_view field) {
  field = Trim(field);
  if (!field.empty() && field.front() == '#') field = Trim(field.substr(1));
  const size_t bracket = field.find('[');
  if (bracket != std::string_view::npos) field = Trim(field.substr(0, bracket));
  return field;
}

// ---- CsvReader ----

CsvReader::CsvReader(const std::filesystem::path& path, std::string expected_header,
                     CsvOptions options)
    : name_(path.string()),
      expected_header_(std::move(expected_header)),
      options_(std::move(options)) {
  file_.emplace(path);
  ReadHeader();
}

CsvReader::CsvReader(const CsvText& text, std::string expected_header, CsvOptions options)
    : name_(text.name),
      expected_header_(std::move(expected_header)),
      options_(std::move(options)),
      text_(text.text) {
  ReadHeader();
}

void CsvReader::ReadHeader() {
  if (!options_.columns.empty()) {
    for (const std::string& column : options_.columns) {
      raw_names_.push_back(column);
      keys_.emplace_back(CsvColumnKey(column));
    }
    return;
  }
  std::string_view line;
  bool had_newline = false;
  const bool any = NextLine(line, &had_newline);
  if (!any || Trim(line).empty()) {
    // Nothing but a byte-order mark is an empty file too.
    const bool empty =
        !any || (!had_newline && (line_text_.empty() || line_text_ == kByteOrderMark));
    throw InputError({name_, 1, 0}, "",
                     fmt::format("missing header: {}, expected a header line like '{}'",
                                 empty ? "the file is empty" : "line 1 is blank",
                                 expected_header_));
  }
  Split(line);
  for (const Field& f : fields_) {
    raw_names_.emplace_back(Trim(f.text));
    keys_.emplace_back(CsvColumnKey(f.text));
  }
  if (options_.header_must_match) {
    CheckHeaderMatches();
    return;
  }
  const bool has_timestamp = std::find(keys_.begin(), keys_.end(), "timestamp") != keys_.end();
  if (Trim(line).front() != '#' && !has_timestamp) {
    throw InputError({name_, 1, 1}, "",
                     fmt::format("missing header: expected a header line like '{}' (columns "
                                 "named, '#timestamp [ns]' first), got {}",
                                 expected_header_, CsvQuoted(line)));
  }
  if (!has_timestamp) {
    throw InputError({name_, 1, 1}, "",
                     fmt::format("header has no 'timestamp' column, expected a header like "
                                 "'{}'",
                                 expected_header_));
  }
}

void CsvReader::CheckHeaderMatches() const {
  std::vector<std::string_view> expected;
  for (size_t start = 0;;) {
    const size_t comma = expected_header_.find(',', start);
    expected.push_back(Trim(std::string_view(expected_header_).substr(
        start, comma == std::string::npos ? std::string::npos : comma - start)));
    if (comma == std::string::npos) break;
    start = comma + 1;
  }
  // The EuRoC/ASL files spell the first column without its unit (always ns there).
  constexpr std::string_view kEurocTimestamp = "#timestamp";
  const std::string what =
      fmt::format("expected the header '{}' (the EuRoC spelling '{}' is accepted for the "
                  "first column)",
                  expected_header_, kEurocTimestamp);
  if (raw_names_.size() != expected.size()) {
    throw InputError({name_, 1, 1}, "",
                     fmt::format("{}, got {} ({} comma-separated columns, not {})", what,
                                 CsvQuoted(line_text_), raw_names_.size(), expected.size()));
  }
  for (size_t i = 0; i < expected.size(); ++i) {
    const bool euroc_timestamp = i == 0 && raw_names_[i] == kEurocTimestamp &&
                                 expected[i].starts_with(kEurocTimestamp);
    if (raw_names_[i] != expected[i] && !euroc_timestamp) {
      throw InputError({name_, 1, fields_[i].column}, "",
                       fmt::format("{}: column {} should be '{}', got {}", what, i + 1,
                                   expected[i], CsvQuoted(raw_names_[i])));
    }
  }
}

std::size_t CsvReader::RowsUpperBound() {
  if (file_) return file_->CountRemainingLines() + 1;
  return static_cast<std::size_t>(std::count(text_.begin() + static_cast<std::ptrdiff_t>(
                                                 std::min(text_pos_, text_.size())),
                                             text_.end(), '\n')) +
         1;
}

int CsvReader::Find(std::string_view key) const { return FindKey(keys_, key); }

int CsvReader::Require(std::string_view key, std::string_view what) const {
  const int index = Find(key);
  if (index < 0) {
    throw InputError({name_, 1, 0}, "",
                     what.empty()
                         ? fmt::format("header: missing column '{}', expected a header like '{}'",
                                       key, expected_header_)
                         : fmt::format("header: missing column '{}' ({})", key, what));
  }
  return index;
}

bool CsvReader::Next() {
  std::string_view line;
  while (NextLine(line)) {
    if (Trim(line).empty()) {
      if (options_.blank_lines_only_at_end && first_blank_line_ == 0) first_blank_line_ = line_;
      continue;
    }
    if (IsComment(line)) continue;
    if (first_blank_line_ != 0) {
      throw InputError({name_, first_blank_line_, 0}, "",
                       fmt::format("blank line inside the data (line {} has another row); "
                                   "blank lines are allowed only at the end of the file",
                                   line_));
    }
    Split(line);
    if (options_.last_column_takes_rest && fields_.size() > keys_.size()) {
      const size_t offset = static_cast<size_t>(fields_[keys_.size() - 1].column - 1);
      fields_.resize(keys_.size());
      fields_.back().text = line.substr(offset);
    }
    if (fields_.size() != keys_.size()) {
      const size_t n = fields_.size();
      throw InputError(
          {name_, line_, 0}, "",
          fmt::format("expected {} {}-separated fields as in the {}, got {} ({})",
                      keys_.size(), options_.whitespace_separated ? "whitespace" : "comma",
                      options_.columns.empty() ? "header" : fmt::format("form '{}'", expected_header_),
                      n,
                      n < keys_.size()
                          ? fmt::format("column {} '{}' and later are missing", n + 1,
                                        raw_names_[n])
                          : fmt::format("extra field after the last column '{}'",
                                        raw_names_.back())));
    }
    return true;
  }
  return false;
}

std::string_view CsvReader::Text(int column) const { return Trim(fields_[column].text); }

int64_t CsvReader::Integer(int column, std::string_view what) const {
  std::string error;
  const std::optional<int64_t> value = ParseInteger(Text(column), what, &error);
  if (!value) throw Error(column, error);
  return *value;
}

double CsvReader::Number(int column) const {
  std::string error;
  const std::optional<double> value = ParseCsvNumber(Text(column), &error);
  if (!value) throw Error(column, error);
  return *value;
}

InputError CsvReader::Error(int column, const std::string& message) const {
  return InputError({name_, line_, fields_[column].column}, "",
                    fmt::format("column '{}': {}", raw_names_[column], message));
}

bool CsvReader::NextLine(std::string_view& line, bool* had_newline) {
  if (file_) {
    if (!file_->Next(line_text_, had_newline)) return false;
  } else {
    if (text_pos_ >= text_.size()) return false;
    const size_t end = std::min(text_.find('\n', text_pos_), text_.size());
    line_text_.assign(text_.substr(text_pos_, end - text_pos_));
    if (had_newline != nullptr) *had_newline = end < text_.size();
    text_pos_ = end + 1;
  }
  line = line_text_;
  if (!line.empty() && line.back() == '\r') line.remove_suffix(1);
  ++line_;
  // A UTF-8 byte-order mark (spreadsheet exports) is not part of the first line.
  if (line_ == 1 && line.starts_with(kByteOrderMark)) line.remove_prefix(kByteOrderMark.size());
  return true;
}

bool CsvReader::IsComment(std::string_view line) const {
  line = Trim(line);
  return options_.whitespace_separated && !line.empty() && line.front() == '#';
}

void CsvReader::Split(std::string_view line) {
  fields_.clear();
  if (options_.whitespace_separated) {
    const auto blank = [](char c) { return IsBlank(c) || c == '\r'; };
    for (size_t k = 0;;) {
      while (k < line.size() && blank(line[k])) ++k;
      if (k >= line.size()) return;
      const size_t start = k;
      while (k < line.size() && !blank(line[k])) ++k;
      fields_.push_back({line.substr(start, k - start), static_cast<int>(start) + 1});
    }
  }
  size_t start = 0;
  while (true) {
    const size_t comma = line.find(',', start);
    const size_t end = comma == std::string_view::npos ? line.size() : comma;
    fields_.push_back({line.substr(start, end - start), static_cast<int>(start) + 1});
    if (comma == std::string_view::npos) return;
    start = comma + 1;
  }
}

// ---- CsvTable ----

CsvTable::CsvTable(const std::filesystem::path& path, std::string expected_header,
                   CsvOptions options)
    : file_(path.string()), expected_header_(expected_header) {
  CsvReader reader(path, std::move(expected_header), std::move(options));
  keys_ = reader.keys();
  raw_names_ = reader.header_fields();
  const int columns = static_cast<int>(keys_.size());
  while (reader.Next()) {
    lines_.push_back(reader.line());
    for (int c = 0; c < columns; ++c) {
      const std::string_view text = reader.Text(c);
      if (text_.size() + text.size() > std::numeric_limits<uint32_t>::max()) {
        throw InputError({file_, reader.line(), 0}, "",
                         "over 4 GB of fields: too large to hold, expected a run's file");
      }
      cells_.push_back({static_cast<uint32_t>(text_.size()), static_cast<uint32_t>(text.size()),
                        reader.FieldColumn(c)});
      text_.append(text);
    }
  }
}

int CsvTable::Find(std::string_view key) const { return FindKey(keys_, key); }

int CsvTable::Require(std::string_view key) const {
  const int index = Find(key);
  if (index < 0) {
    throw InputError({file_, 1, 0}, "",
                     fmt::format("header: missing column '{}', expected a header like '{}'", key,
                                 expected_header_));
  }
  return index;
}

void CsvTable::Fail(std::size_t row, int column, const std::string& message) const {
  throw InputError({file_, lines_[row], At(row, column).column}, "",
                   fmt::format("column '{}': {}", raw_names_[column], message));
}

std::string_view CsvTable::Text(std::size_t row, int column) const {
  const Cell& cell = At(row, column);
  return std::string_view(text_).substr(cell.offset, cell.length);
}

int64_t CsvTable::Int(std::size_t row, int column) const {
  std::string error;
  const std::optional<int64_t> value = ParseInteger(Text(row, column), "", &error);
  if (!value) Fail(row, column, error);
  return *value;
}

double CsvTable::Double(std::size_t row, int column, bool allow_empty) const {
  const std::string_view text = Text(row, column);
  if (text.empty() && allow_empty) return std::numeric_limits<double>::quiet_NaN();
  std::string error;
  const std::optional<double> value = ParseCsvNumber(text, &error);
  if (!value) Fail(row, column, error);
  return *value;
}

}  // namespace tofu::replay
