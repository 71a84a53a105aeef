#pragma once
// A strict reader of the comma-separated files of a run directory (EuRoC/ASL-style
// header, columns found by name). Private to renders/: the renderer reads what harness
// wrote and never links its writers. Malformed input is a core::InputError naming file,
// line, column and the expected form.

#include <cstdint>
#include <filesystem>
#include <string>
#include <string_view>
#include <vector>

namespace tofu::renders {

class CsvTable {
 public:
  /// Reads `path` whole. Throws core::InputError if it cannot be read, has no header, or
  /// a data row's field count differs from the header's. `expected_header` is quoted in
  /// the messages as the form the file should have.
  /// With `last_column_takes_rest`, a row with more fields than the header joins the
  /// surplus into its last column (free text such as a reason may contain commas).
  CsvTable(const std::filesystem::path& path, std::string expected_header,
           bool last_column_takes_rest = false);

  const std::string& file() const { return file_; }
  size_t rows() const { return rows_.size(); }

  /// Column index of `key` (header text without '#' and " [unit]"), or -1.
  int Find(std::string_view key) const;
  /// Column index of `key`; InputError at the header line if it is missing.
  int Require(std::string_view key) const;

  /// Raw text of a field (trimmed).
  std::string_view Text(size_t row, int column) const;
  /// Integer field (timestamps in ns); InputError at file:line:column otherwise.
  int64_t Int(size_t row, int column) const;
  /// Floating-point field; `allow_empty` returns NaN for an empty field.
  double Double(size_t row, int column, bool allow_empty = false) const;
  /// 1-based line number of a data row in the file.
  int Line(size_t row) const { return rows_[row].line; }

 private:
  struct Field {
    std::string_view text;
    int column = 1;  ///< 1-based character column of the field's start
  };
  struct Row {
    int line = 0;
    std::vector<Field> fields;
  };
  [[noreturn]] void Fail(size_t row, int column, const std::string& message) const;

  std::string file_;
  std::string expected_header_;
  std::string text_;
  std::vector<std::string> keys_;
  std::vector<Row> rows_;
};

}  // namespace tofu::renders
