#pragma once
// All-or-nothing writes, one place for every writer of the harness (run directories,
// estimates, JUnit): DESIGN.md's "no half-written output" is this module's job. Reads:
// core/file_io.h.

#include <cstdio>
#include <filesystem>
#include <iterator>
#include <string>
#include <string_view>
#include <utility>
#include <vector>

#include <fmt/format.h>

namespace tofu::replay {

/// Writes `text` to `path` whole or not at all: into a temporary sibling
/// (<name>.tmp-<pid>) renamed into place, so a reader never sees a partial file. Creates
/// missing parent directories. Throws core::IoError (exit 4) naming the file (and `key`,
/// e.g. "--out", when given) on failure, leaving neither the temporary nor a partial file.
/// A check point of interruption (replay/interrupt.h): throws Interrupted, leaving no
/// temporary, once a signal was received.
void WriteFileAtomically(const std::filesystem::path& path, std::string_view text,
                         std::string_view key = "");

/// WriteFileAtomically for a file written row by row (a run's streams, an hour's estimate):
/// rows are formatted into a buffer that goes to the temporary sibling whenever it holds
/// 64 kB, so the file costs no memory beyond that; Commit() renames it into place. Dropped
/// uncommitted (an exception unwinding), the temporary is removed. Throws core::IoError
/// (exit 4) naming the file on failure; the constructor and Commit() are check points of
/// interruption, as WriteFileAtomically is.
class AtomicFileWriter {
 public:
  explicit AtomicFileWriter(std::filesystem::path path, std::string key = "");
  ~AtomicFileWriter();
  AtomicFileWriter(const AtomicFileWriter&) = delete;
  AtomicFileWriter& operator=(const AtomicFileWriter&) = delete;

  template <typename... Args>
  void Format(fmt::format_string<Args...> format, Args&&... args) {
    fmt::format_to(std::back_inserter(buffer_), format, std::forward<Args>(args)...);
    if (buffer_.size() >= kFlushBytes) Flush();
  }
  void Append(std::string_view text) {
    buffer_.append(text);
    if (buffer_.size() >= kFlushBytes) Flush();
  }
  /// Writes what is buffered, closes the file and renames it into place.
  void Commit();

 private:
  static constexpr std::size_t kFlushBytes = 1 << 16;
  void Flush();
  [[noreturn]] void Fail(int error);

  std::filesystem::path path_;
  std::filesystem::path staging_;
  std::string key_;
  std::FILE* file_ = nullptr;
  fmt::memory_buffer buffer_;
};

/// The staging sibling of `path` owned by this process: <path>.tmp-<pid>. Every
/// all-or-nothing writer (files here, run and report directories) stages there.
std::filesystem::path StagingPath(const std::filesystem::path& path);

/// Removes the staging siblings of `path` (<path>.tmp-<pid>, files or directories) that a
/// killed or crashed process left behind: those whose process is gone, or whose pid now
/// belongs to a process that is not tofu. A live tofu process's staging is never touched.
/// Returns what was removed. Errors while removing are ignored (the next run tries again).
std::vector<std::filesystem::path> SweepStaleStaging(const std::filesystem::path& path);

}  // namespace tofu::replay
