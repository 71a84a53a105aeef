#pragma once
// Whole-file reads for every module that loads text (sim's robot MJCF, harness's logs and
// CSVs): one reader with one error message. Writers live in replay/file_io.h.

#include <cstddef>
#include <cstdio>
#include <filesystem>
#include <string>
#include <string_view>
#include <vector>

namespace tofu::core {

/// The whole file, bytes as they are. Throws core::InputError naming the file when it is a
/// directory, cannot be opened or cannot be read, or holds more than `max_bytes` (a device
/// such as /dev/zero, a log given where a configuration belongs: refused before memory
/// runs out); `what` names what was expected ("velocity CSV", "scenario file") in the
/// message.
std::string ReadWholeFile(const std::filesystem::path& path, std::string_view what = "file",
                          std::size_t max_bytes = static_cast<std::size_t>(-1));

/// A file read line by line through a 64 kB buffer: a log of any length costs one line of
/// memory. Opening throws as ReadWholeFile does (naming the file and `what`).
class LineReader {
 public:
  explicit LineReader(const std::filesystem::path& path, std::string_view what = "file");
  ~LineReader();
  LineReader(const LineReader&) = delete;
  LineReader& operator=(const LineReader&) = delete;

  /// The next line without its '\n' into `line`; false at the end of the file.
  /// `had_newline` (optional): whether the line ended with one (the last may not). Throws
  /// core::InputError naming the file on a read error.
  bool Next(std::string& line, bool* had_newline = nullptr);
  /// Lines left from here (newlines, and a last line without one), by a scan of the file
  /// that leaves the reading position where it was: what to reserve for the rows.
  std::size_t CountRemainingLines();

 private:
  std::filesystem::path path_;
  std::string what_;
  std::FILE* file_ = nullptr;
  char* buffer_ = nullptr;  // getline's, grown to the longest line
  std::size_t capacity_ = 0;
};

/// The last `max_lines` lines of a log that hold more than blanks, as a terminal showed
/// them (a progress bar redraws with '\r': only what follows the last one), each cut to
/// 400 characters: what a failed command said, for a table or a report. A missing or
/// unreadable log has none.
std::vector<std::string> LogTail(const std::filesystem::path& path, std::size_t max_lines);

/// The size limit of configuration files a user writes by hand (scenarios, calibration,
/// corpus specs, sensor.yaml): 16 MiB, a thousand times the largest the project has.
inline constexpr std::size_t kMaxConfigFileBytes = std::size_t{16} << 20;

}  // namespace tofu::core
