#include "replay/file_io.h"

#include <signal.h>
#include <unistd.h>

#include <cerrno>
#include <charconv>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <string>

#include <fmt/format.h>

#include "core/error.h"
#include "replay/interrupt.h"

namespace tofu::replay {

namespace fs = std::filesystem;

namespace {

constexpr std::string_view kStagingInfix = ".tmp-";

// Whether `pid` is a running tofu process: then its staging is in use. A pid that is gone,
// a zombie (it writes nothing any more) or a reused pid of another program is not. When
// /proc cannot tell, the process is assumed to be tofu: never remove what may be in use.
bool IsLiveTofuProcess(pid_t pid) {
  if (pid <= 0) return false;
  if (pid == ::getpid()) return true;
  if (::kill(pid, 0) != 0 && errno == ESRCH) return false;
  const fs::path proc = fs::path("/proc") / std::to_string(pid);
  std::ifstream stat(proc / "stat");
  std::string stat_line;
  // Unreadable: gone since kill() (when /proc is there at all), else cannot tell.
  if (!std::getline(stat, stat_line)) return fs::exists(proc) || !fs::exists("/proc/self");
  // "pid (comm) S ...": the state follows the last ')', comm may hold anything.
  if (const auto close = stat_line.rfind(')');
      close != std::string::npos && close + 2 < stat_line.size() && stat_line[close + 2] == 'Z') {
    return false;
  }
  std::ifstream comm_file(proc / "comm");
  std::string comm;
  if (!std::getline(comm_file, comm)) return true;
  if (comm == "tofu") return true;
  // The tofu executable under another name is still tofu.
  std::error_code ec_self, ec_other;
  const fs::path self = fs::read_symlink("/proc/self/exe", ec_self);
  const fs::path other = fs::read_symlink(proc / "exe", ec_other);
  if (ec_other) return ec_other != std::errc::no_such_file_or_directory;  // EPERM: cannot tell
  return !ec_self && self == other;
}

}  // namespace

fs::path StagingPath(const fs::path& path) {
  return path.string() + fmt::format("{}{}", kStagingInfix, ::getpid());
}

std::vector<fs::path> SweepStaleStaging(const fs::path& path) {
  std::vector<fs::path> removed;
  const fs::path target = fs::absolute(path).lexically_normal();
  const fs::path name = target.filename().empty() ? target.parent_path().filename() : target.filename();
  const fs::path parent = target.filename().empty() ? target.parent_path().parent_path()
                                                    : target.parent_path();
  const std::string prefix = name.string() + std::string(kStagingInfix);
  std::error_code ec;
  std::vector<std::pair<fs::path, pid_t>> candidates;
  for (fs::directory_iterator it(parent, ec), end; !ec && it != end; it.increment(ec)) {
    const std::string entry = it->path().filename().string();
    if (!entry.starts_with(prefix)) continue;
    const std::string_view digits = std::string_view(entry).substr(prefix.size());
    pid_t pid = 0;
    const auto [last, error] = std::from_chars(digits.data(), digits.data() + digits.size(), pid);
    if (error != std::errc() || last != digits.data() + digits.size() || digits.empty()) continue;
    candidates.emplace_back(it->path(), pid);
  }
  for (const auto& [staging, pid] : candidates) {
    if (IsLiveTofuProcess(pid)) continue;
    std::error_code ignored;
    if (fs::remove_all(staging, ignored) > 0 && !ignored) removed.push_back(staging);
  }
  return removed;
}

void WriteFileAtomically(const fs::path& path, std::string_view text, std::string_view key) {
  AtomicFileWriter writer(path, std::string(key));
  writer.Append(text);
  writer.Commit();
}

AtomicFileWriter::AtomicFileWriter(fs::path path, std::string key)
    : path_(std::move(path)), staging_(StagingPath(path_)), key_(std::move(key)) {
  // A check point of interruption (replay/interrupt.h): every writer of the harness
  // passes here, so an interrupted command stops before its next file.
  ThrowIfInterrupted();
  std::error_code ec;
  if (path_.has_parent_path()) fs::create_directories(path_.parent_path(), ec);
  file_ = std::fopen(staging_.c_str(), "wb");
  if (file_ == nullptr) Fail(errno);
}

AtomicFileWriter::~AtomicFileWriter() {
  if (file_ == nullptr) return;
  std::fclose(file_);
  std::remove(staging_.c_str());
}

void AtomicFileWriter::Flush() {
  if (buffer_.size() == 0) return;
  if (std::fwrite(buffer_.data(), 1, buffer_.size(), file_) != buffer_.size()) {
    Fail(errno != 0 ? errno : EIO);
  }
  buffer_.clear();
}

void AtomicFileWriter::Fail(int error) {
  // Not the user's input but the machine (permissions, a full disk, a path through a
  // file): the I/O exit code, naming the file and what it was for. No temporary stays.
  if (file_ != nullptr) std::fclose(file_);
  file_ = nullptr;
  std::remove(staging_.c_str());
  throw core::IoError(fmt::format("cannot write {}{}: {}", path_.string(),
                                  key_.empty() ? "" : fmt::format(" ({})", key_),
                                  std::strerror(error)));
}

void AtomicFileWriter::Commit() {
  Flush();
  errno = 0;
  const bool closed = std::fclose(file_) == 0;
  const int close_errno = errno;
  file_ = nullptr;
  if (!closed) {
    std::remove(staging_.c_str());
    Fail(close_errno != 0 ? close_errno : EIO);
  }
  if (InterruptSignal() != 0) {
    // Interrupted while writing: the command will not finish, so its temporary goes
    // rather than into an output that is about to be abandoned.
    std::remove(staging_.c_str());
    ThrowIfInterrupted();
  }
  if (std::rename(staging_.c_str(), path_.c_str()) != 0) {
    const int rename_errno = errno;
    std::remove(staging_.c_str());
    Fail(rename_errno);
  }
}

}  // namespace tofu::replay
