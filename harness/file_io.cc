#include "harness/file_io.h"

#include <unistd.h>

#include <cerrno>
#include <cstdio>
#include <cstring>

#include <fmt/format.h>

#include "core/error.h"

namespace tofu::harness {

namespace fs = std::filesystem;

void WriteFileAtomically(const fs::path& path, std::string_view text, std::string_view key) {
  // Not the user's input but the machine (permissions, a full disk, a path through a
  // file): the I/O exit code, naming the file and what it was for.
  const auto fail = [&](int error) {
    throw core::IoError(fmt::format("cannot write {}{}: {}", path.string(),
                                    key.empty() ? "" : fmt::format(" ({})", key), std::strerror(error)));
  };
  std::error_code ec;
  if (path.has_parent_path()) fs::create_directories(path.parent_path(), ec);
  const fs::path staging = path.string() + fmt::format(".tmp-{}", ::getpid());
  std::FILE* file = std::fopen(staging.c_str(), "wb");
  if (file == nullptr) fail(errno);
  const bool written = std::fwrite(text.data(), 1, text.size(), file) == text.size();
  const int write_errno = errno;
  const bool closed = std::fclose(file) == 0;
  if (!written || !closed) {
    std::remove(staging.c_str());
    fail(write_errno != 0 ? write_errno : EIO);
  }
  if (std::rename(staging.c_str(), path.c_str()) != 0) {
    const int rename_errno = errno;
    std::remove(staging.c_str());
    fail(rename_errno);
  }
}

}  // namespace tofu::harness
