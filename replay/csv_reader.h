#pragma once
// The one reader of the comma-separated files of a run directory and of EuRoC/ASL logs
// (README "Run directory"): a header line whose fields name the columns ("#timestamp
// [ns],p_WB_x [m],..."; columns are found by key, the text before " [unit]"), then one
// row per line. Strict: a malformed file is a core::InputError naming file, line, column
// and the expected form, never a silently shortened series. Blank lines are skipped, a
// CR before the newline and a UTF-8 byte-order mark are tolerated, spaces and tabs around
// a field are not part of it.
//
// The same reader takes the two neighbours of that form (CsvOptions): a velocity CSV of
// `tofu consistency` (a fixed header, no blank line inside the data) and a TUM trajectory
// ("t x y z qx qy qz qw": no header line, fields separated by spaces or tabs, '#' comment
// lines).
//
// Two ways to visit the rows: CsvReader streams them (an hour of IMU is 250 MB of text,
// never held whole); CsvTable holds the rows of a small file (summaries, decisions,
// estimates drawn by the renderer and the reports) for access by index. Both parse and
// fail the same way.

#include <cstddef>
#include <cstdint>
#include <filesystem>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "core/error.h"
#include "core/file_io.h"

namespace tofu::replay {

/// The key of a header field: "#timestamp [ns]" -> "timestamp", " p_RS_R_x [m]" -> "p_RS_R_x".
std::string_view CsvColumnKey(std::string_view field);

/// A field's text quoted for a message, cut at 60 characters.
std::string CsvQuoted(std::string_view text);

/// A number field as every reader parses it ("nan"/"inf" included; beyond the double
/// range an underflow to 0 or an overflow to +-Inf, as strtod); nullopt and the reason in
/// `error` for an empty or other field. Also the parse the run format's AsRecorded applies.
std::optional<double> ParseCsvNumber(std::string_view text, std::string* error);

struct CsvOptions {
  /// A row with more fields than the header joins the surplus into its last column (free
  /// text, such as a decision's reason, may contain commas).
  bool last_column_takes_rest = false;
  /// The header must name exactly the columns of the expected header, in order (spaces
  /// around a field aside; the EuRoC spelling '#timestamp', without its unit, is accepted
  /// for a first column '#timestamp [ns]'). Otherwise columns are found by key.
  bool header_must_match = false;
  /// A blank line may be followed only by blank lines: one inside the data is an error (a
  /// file cut and pasted together), not skipped.
  bool blank_lines_only_at_end = false;
  /// A file without a header line: these are its columns, as messages name them ("x [m]").
  /// The 'timestamp' column is then not required.
  std::vector<std::string> columns = {};
  /// Fields are separated by runs of spaces and tabs instead of commas (TUM), and a line
  /// whose first field starts with '#' is a comment.
  bool whitespace_separated = false;
};

/// Text to read as a file (a fuzzer's input); `name` names it in messages.
struct CsvText {
  std::string_view text;
  std::string name;
};

class CsvReader {
 public:
  /// Opens `path` and reads its header. Throws core::InputError if the file cannot be
  /// read, is empty, or its first line is not a header with a 'timestamp' column;
  /// `expected_header` is quoted in the messages as the form the file should have.
  CsvReader(const std::filesystem::path& path, std::string expected_header,
            CsvOptions options = {});
  /// The same over text held in memory (which must outlive the reader).
  CsvReader(const CsvText& text, std::string expected_header, CsvOptions options = {});
  CsvReader(const CsvReader&) = delete;
  CsvReader& operator=(const CsvReader&) = delete;

  const std::string& name() const { return name_; }
  /// Column keys of the header, in order, and the header's fields as written (with units).
  const std::vector<std::string>& keys() const { return keys_; }
  const std::vector<std::string>& header_fields() const { return raw_names_; }
  /// The rows left (a scan of the rest of the file): what to reserve.
  std::size_t RowsUpperBound();

  /// Index of the column `key`, or -1.
  int Find(std::string_view key) const;
  /// Index of the column `key`; InputError at the header if it is missing (`what` says
  /// what the column is for).
  int Require(std::string_view key, std::string_view what = "") const;

  /// Advances to the next non-blank row; false at the end. Throws InputError if the row's
  /// field count is not the header's.
  bool Next();
  /// 1-based line of the current row.
  int line() const { return line_; }

  /// 1-based character column of a field of the current row in its line.
  int FieldColumn(int column) const { return fields_[column].column; }
  /// Text of a field of the current row (trimmed).
  std::string_view Text(int column) const;
  bool Empty(int column) const { return Text(column).empty(); }
  /// An integer (timestamps in ns); `what` names the expected quantity in the message.
  int64_t Integer(int column, std::string_view what = "timestamp in ns") const;
  /// A number; "nan"/"inf" parse (and pass through), an empty or other field throws.
  double Number(int column) const;
  /// An InputError at the current row and `column`: "column '<header field>': message".
  core::InputError Error(int column, const std::string& message) const;

 private:
  struct Field {
    std::string_view text;
    int column = 0;  // 1-based character column in the line
  };
  void ReadHeader();
  void CheckHeaderMatches() const;
  bool NextLine(std::string_view& line, bool* had_newline = nullptr);
  bool IsComment(std::string_view line) const;
  void Split(std::string_view line);

  std::string name_;
  std::string expected_header_;
  CsvOptions options_;
  // The source: a file read line by line, or text in memory from text_pos_ on.
  std::optional<core::LineReader> file_;
  std::string_view text_;
  std::size_t text_pos_ = 0;
  std::string line_text_;
  std::vector<std::string> raw_names_;
  std::vector<std::string> keys_;
  std::vector<Field> fields_;
  int line_ = 0;
  int first_blank_line_ = 0;  // blank_lines_only_at_end: the first blank line after a row
};

/// The rows of a small file, held for access by index; read and checked by CsvReader.
class CsvTable {
 public:
  CsvTable(const std::filesystem::path& path, std::string expected_header,
           CsvOptions options = {});

  const std::string& file() const { return file_; }
  /// Column keys of the header, in order.
  const std::vector<std::string>& keys() const { return keys_; }
  std::size_t rows() const { return lines_.size(); }
  int Find(std::string_view key) const;
  /// Index of the column `key`; InputError at the header if it is missing.
  int Require(std::string_view key) const;

  std::string_view Text(std::size_t row, int column) const;
  int64_t Int(std::size_t row, int column) const;
  /// A number; `allow_empty` makes an empty field NaN.
  double Double(std::size_t row, int column, bool allow_empty = false) const;
  /// 1-based line of a row in the file.
  int Line(std::size_t row) const { return lines_[row]; }

 private:
  // The fields of all rows, row-major, as views into one text: a file of a million rows
  // costs its text and 12 bytes a field, not a string each.
  struct Cell {
    uint32_t offset = 0;
    uint32_t length = 0;
    int column = 0;  // 1-based character column in its line
  };
  const Cell& At(std::size_t row, int column) const { return cells_[row * keys_.size() + column]; }
  [[noreturn]] void Fail(std::size_t row, int column, const std::string& message) const;

  std::string file_;
  std::string expected_header_;
  std::vector<std::string> raw_names_;
  std::vector<std::string> keys_;
  std::string text_;
  std::vector<Cell> cells_;
  std::vector<int> lines_;
};

}  // namespace tofu::replay
