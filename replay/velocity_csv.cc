#include "replay/velocity_csv.h"

#include <algorithm>
#include <array>
#include <cerrno>
#include <charconv>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <optional>
#include <system_error>

#include <fmt/format.h>

#include "core/error.h"
#include "core/file_io.h"
#include "replay/csv_reader.h"

namespace tofu::replay {
namespace {

namespace fs = std::filesystem;
using core::InputError;
using core::SourceLocation;

constexpr int kFields = 4;
// Column names as errors show them, and as the header must spell them.
constexpr std::array<std::string_view, kFields> kColumnNames = {"timestamp [ns]", "v_x [m/s]",
                                                                "v_y [m/s]", "v_z [m/s]"};
constexpr std::array<std::string_view, kFields> kHeaderFields = {"#timestamp [ns]", "v_x [m/s]",
                                                                 "v_y [m/s]", "v_z [m/s]"};
// The EuRoC/ASL files spell the first column without its unit (always ns there).
constexpr std::string_view kEurocTimestampField = "#timestamp";

bool IsBlank(char c) { return c == ' ' || c == '\t'; }

std::string_view Trim(std::string_view s) {
  while (!s.empty() && IsBlank(s.front())) s.remove_prefix(1);
  while (!s.empty() && (IsBlank(s.back()) || s.back() == '\r')) s.remove_suffix(1);
  return s;
}

bool IsBlankLine(std::string_view line) { return Trim(line).empty(); }


// Splits text into lines ('\n'; a '\r' before it is dropped), counting them from 1.
class LineReader {
 public:
  explicit LineReader(std::string_view text) : text_(text) {}
  bool Next(std::string_view& line) {
    if (pos_ >= text_.size()) return false;
    const size_t end = std::min(text_.find('\n', pos_), text_.size());
    line = text_.substr(pos_, end - pos_);
    if (!line.empty() && line.back() == '\r') line.remove_suffix(1);
    pos_ = end + 1;
    ++number_;
    return true;
  }
  int number() const { return number_; }

 private:
  std::string_view text_;
  size_t pos_ = 0;
  int number_ = 0;
};

// One field of a line, trimmed, with its 1-based column in the line.
struct Field {
  std::string_view text;
  int column = 0;
};

// Splits `line` at commas; returns the number of fields, filling at most kFields.
int SplitFields(std::string_view line, std::array<Field, kFields>& fields) {
  int count = 0;
  size_t start = 0;
  while (true) {
    const size_t comma = line.find(',', start);
    const size_t end = comma == std::string_view::npos ? line.size() : comma;
    if (count < kFields) {
      std::string_view raw = line.substr(start, end - start);
      size_t lead = 0;
      while (lead < raw.size() && IsBlank(raw[lead])) ++lead;
      fields[count] = {Trim(raw), static_cast<int>(start + lead) + 1};
    }
    ++count;
    if (comma == std::string_view::npos) return count;
    start = comma + 1;
  }
}

void CheckHeader(std::string_view line, const std::string& path) {
  const std::string expected = fmt::format(
      "expected the header '{}' (the EuRoC spelling '{}' is accepted for the first column)",
      kVelocityCsvHeader, kEurocTimestampField);
  std::array<Field, kFields> fields;
  const int count = SplitFields(line, fields);
  if (count != kFields) {
    throw InputError({path, 1, 1}, "",
                     fmt::format("{}, got {} ({} comma-separated columns, not {})", expected,
                                 CsvQuoted(line), count, kFields));
  }
  for (int i = 0; i < kFields; ++i) {
    const bool ok =
        fields[i].text == kHeaderFields[i] || (i == 0 && fields[i].text == kEurocTimestampField);
    if (!ok) {
      throw InputError({path, 1, fields[i].column}, "",
                       fmt::format("{}: column {} should be '{}', got {}", expected, i + 1,
                                   kHeaderFields[i], CsvQuoted(fields[i].text)));
    }
  }
}

}  // namespace

estimator::VelocitySeries ParseVelocityCsv(std::string_view text, const std::string& path) {
  // A UTF-8 byte-order mark (spreadsheet exports) is not part of the header.
  constexpr std::string_view kBom = "\xEF\xBB\xBF";
  if (text.substr(0, kBom.size()) == kBom) text.remove_prefix(kBom.size());

  if (std::all_of(text.begin(), text.end(),
                  [](char c) { return IsBlank(c) || c == '\r' || c == '\n'; })) {
    throw InputError({path, 1, 0}, "",
                     fmt::format("the file is empty, expected the header '{}' and then one "
                                 "sample per line",
                                 kVelocityCsvHeader));
  }

  LineReader lines(text);
  std::string_view line;
  lines.Next(line);
  CheckHeader(line, path);

  estimator::VelocitySeries series;
  const size_t expected_rows = static_cast<size_t>(std::count(text.begin(), text.end(), '\n'));
  series.t_ns.reserve(expected_rows);
  series.v_mps.reserve(expected_rows);

  int first_blank_line = 0;  // a blank line is fine only if nothing but blank lines follows
  int previous_line = 0;
  std::array<Field, kFields> fields;
  while (lines.Next(line)) {
    const int number = lines.number();
    if (IsBlankLine(line)) {
      if (first_blank_line == 0) first_blank_line = number;
      continue;
    }
    if (first_blank_line != 0) {
      throw InputError({path, first_blank_line, 0}, "",
                       fmt::format("blank line inside the data (line {} has another sample); "
                                   "blank lines are allowed only at the end of the file",
                                   number));
    }
    const int count = SplitFields(line, fields);
    if (count != kFields) {
      throw InputError({path, number, 0}, "",
                       fmt::format("expected {} comma-separated numbers (t_ns, v_x, v_y, v_z), "
                                   "got {} field{}",
                                   kFields, count, count == 1 ? "" : "s"));
    }
    for (int i = 0; i < kFields; ++i) {
      if (fields[i].text.empty()) {
        throw InputError({path, number, fields[i].column}, "",
                         fmt::format("field {} ({}) is empty, expected {}", i + 1, kColumnNames[i],
                                     i == 0 ? "an integer timestamp in ns" : "a number"));
      }
    }

    // Timestamp: an integer number of nanoseconds, strictly after the previous sample's.
    const Field& tf = fields[0];
    core::Time t = 0;
    const auto [t_end, t_ec] = std::from_chars(tf.text.data(), tf.text.data() + tf.text.size(), t);
    if (t_ec == std::errc::result_out_of_range) {
      throw InputError({path, number, tf.column}, "",
                       fmt::format("field 1 ({}): {} does not fit in a 64-bit integer",
                                   kColumnNames[0], CsvQuoted(tf.text)));
    }
    if (t_ec != std::errc() || t_end != tf.text.data() + tf.text.size()) {
      throw InputError({path, number, tf.column}, "",
                       fmt::format("field 1 ({}): expected an integer timestamp in ns, got {}",
                                   kColumnNames[0], CsvQuoted(tf.text)));
    }
    if (!series.t_ns.empty() && t <= series.t_ns.back()) {
      throw InputError(
          {path, number, tf.column}, "",
          fmt::format("timestamp {} ns is not after the previous sample's {} ns (line {}): "
                      "timestamps must increase strictly",
                      t, series.t_ns.back(), previous_line));
    }

    // Velocities: finite numbers in m/s.
    Eigen::Vector3d v;
    for (int i = 1; i < kFields; ++i) {
      const Field& f = fields[i];
      double value = 0.0;
      const auto [end, ec] = std::from_chars(f.text.data(), f.text.data() + f.text.size(), value);
      if (ec == std::errc::result_out_of_range) {
        throw InputError({path, number, f.column}, "",
                         fmt::format("field {} ({}): {} is out of the range of a double", i + 1,
                                     kColumnNames[i], CsvQuoted(f.text)));
      }
      if (ec != std::errc() || end != f.text.data() + f.text.size()) {
        throw InputError({path, number, f.column}, "",
                         fmt::format("field {} ({}): expected a number, got {}", i + 1,
                                     kColumnNames[i], CsvQuoted(f.text)));
      }
      if (!std::isfinite(value)) {
        throw InputError({path, number, f.column}, "",
                         fmt::format("field {} ({}): {} is not a finite number; NaN and Inf "
                                     "are not accepted in a velocity CSV",
                                     i + 1, kColumnNames[i], CsvQuoted(f.text)));
      }
      v[i - 1] = value;
    }
    series.t_ns.push_back(t);
    series.v_mps.push_back(v);
    previous_line = number;
  }

  if (series.t_ns.empty()) {
    throw InputError({path, first_blank_line != 0 ? first_blank_line : lines.number() + 1, 0}, "",
                     "no samples after the header: expected at least one line "
                     "'t_ns,v_x,v_y,v_z'");
  }
  return series;
}

estimator::VelocitySeries ReadVelocityCsv(const std::string& path) {
  const std::string text = core::ReadWholeFile(path, "velocity CSV");
  return ParseVelocityCsv(text, path);
}

}  // namespace tofu::replay
