#include "renders/csv_table.h"

#include <algorithm>
#include <cerrno>
#include <charconv>
#include <cmath>
#include <cstring>
#include <fstream>
#include <limits>
#include <sstream>

#include <fmt/format.h>

#include "core/error.h"

namespace tofu::renders {
namespace {

std::string_view Trim(std::string_view s) {
  while (!s.empty() && (s.front() == ' ' || s.front() == '\t')) s.remove_prefix(1);
  while (!s.empty() && (s.back() == ' ' || s.back() == '\t' || s.back() == '\r')) {
    s.remove_suffix(1);
  }
  return s;
}

// "#timestamp [ns]" -> "timestamp", "p_Ss_x [m]" -> "p_Ss_x".
std::string ColumnKey(std::string_view field) {
  field = Trim(field);
  if (!field.empty() && field.front() == '#') field = Trim(field.substr(1));
  const size_t bracket = field.find('[');
  if (bracket != std::string_view::npos) field = Trim(field.substr(0, bracket));
  return std::string(field);
}

}  // namespace

CsvTable::CsvTable(const std::filesystem::path& path, std::string expected_header,
                   bool last_column_takes_rest)
    : file_(path.string()), expected_header_(std::move(expected_header)) {
  std::ifstream in(path, std::ios::binary);
  if (!in) {
    throw core::InputError({file_}, "",
                           fmt::format("cannot open ({}); expected a CSV with header '{}'",
                                       std::strerror(errno), expected_header_));
  }
  std::ostringstream buffer;
  buffer << in.rdbuf();
  text_ = buffer.str();

  // Split into lines and fields; views point into text_, which never changes again.
  std::string_view all(text_);
  int line_number = 0;
  bool header_seen = false;
  while (!all.empty()) {
    const size_t end = all.find('\n');
    std::string_view line = all.substr(0, end);
    all = end == std::string_view::npos ? std::string_view() : all.substr(end + 1);
    ++line_number;
    if (Trim(line).empty()) continue;
    Row row;
    row.line = line_number;
    size_t start = 0;
    while (true) {
      const size_t comma = line.find(',', start);
      const std::string_view raw =
          line.substr(start, comma == std::string_view::npos ? std::string_view::npos : comma - start);
      row.fields.push_back({Trim(raw), static_cast<int>(start) + 1});
      if (comma == std::string_view::npos) break;
      start = comma + 1;
    }
    if (!header_seen) {
      if (Trim(line).front() != '#') {
        throw core::InputError({file_, line_number, 1}, "",
                               fmt::format("expected a header line '{}'", expected_header_));
      }
      for (const Field& f : row.fields) keys_.push_back(ColumnKey(f.text));
      header_seen = true;
      continue;
    }
    if (last_column_takes_rest && !keys_.empty() && row.fields.size() > keys_.size()) {
      const Field& last = row.fields[keys_.size() - 1];
      const size_t offset = static_cast<size_t>(last.column - 1);
      row.fields.resize(keys_.size());
      row.fields.back().text = Trim(line.substr(offset));
    }
    if (row.fields.size() != keys_.size()) {
      throw core::InputError(
          {file_, line_number, 0}, "",
          fmt::format("expected {} comma-separated fields as in the header '{}', got {}",
                      keys_.size(), expected_header_, row.fields.size()));
    }
    rows_.push_back(std::move(row));
  }
  if (!header_seen) {
    throw core::InputError({file_, 1, 0}, "",
                           fmt::format("the file is empty; expected a header line '{}'",
                                       expected_header_));
  }
}

int CsvTable::Find(std::string_view key) const {
  const auto it = std::find(keys_.begin(), keys_.end(), key);
  return it == keys_.end() ? -1 : static_cast<int>(it - keys_.begin());
}

int CsvTable::Require(std::string_view key) const {
  const int index = Find(key);
  if (index < 0) {
    throw core::InputError({file_, 1, 0}, "",
                           fmt::format("header has no column '{}'; expected a header '{}'", key,
                                       expected_header_));
  }
  return index;
}

void CsvTable::Fail(size_t row, int column, const std::string& message) const {
  throw core::InputError({file_, rows_[row].line, rows_[row].fields[column].column}, "",
                         fmt::format("column '{}': {}", keys_[column], message));
}

std::string_view CsvTable::Text(size_t row, int column) const {
  return rows_[row].fields[column].text;
}

int64_t CsvTable::Int(size_t row, int column) const {
  const std::string_view text = Text(row, column);
  int64_t value = 0;
  const auto [end, ec] = std::from_chars(text.data(), text.data() + text.size(), value);
  if (text.empty() || ec != std::errc() || end != text.data() + text.size()) {
    Fail(row, column, fmt::format("expected an integer, got '{}'", text));
  }
  return value;
}

double CsvTable::Double(size_t row, int column, bool allow_empty) const {
  const std::string_view text = Text(row, column);
  if (text.empty() && allow_empty) return std::numeric_limits<double>::quiet_NaN();
  double value = 0.0;
  const auto [end, ec] = std::from_chars(text.data(), text.data() + text.size(), value);
  if (text.empty() || ec != std::errc() || end != text.data() + text.size()) {
    Fail(row, column, fmt::format("expected a number, got '{}'", text));
  }
  return value;
}

}  // namespace tofu::renders
