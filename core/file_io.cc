#include "core/file_io.h"

#include <array>
#include <cerrno>
#include <cstdio>
#include <cstring>

#include <fmt/format.h>

#include "core/error.h"

namespace tofu::core {

namespace fs = std::filesystem;

std::string ReadWholeFile(const fs::path& path, std::string_view what, std::size_t max_bytes) {
  std::error_code ec;
  if (fs::is_directory(path, ec)) {
    throw InputError({path.string()}, "", fmt::format("is a directory, expected a {}", what));
  }
  std::FILE* file = std::fopen(path.c_str(), "rb");
  if (file == nullptr) {
    throw InputError({path.string()}, "",
                           fmt::format("cannot open the {}: {}", what, std::strerror(errno)));
  }
  std::string text;
  const auto size = fs::file_size(path, ec);
  if (!ec && size <= max_bytes) text.reserve(size);
  std::array<char, 1 << 16> buffer;
  std::size_t n = 0;
  while ((n = std::fread(buffer.data(), 1, buffer.size(), file)) > 0) {
    if (n > max_bytes - text.size()) {
      std::fclose(file);
      throw InputError({path.string()}, "",
                       fmt::format("the {} is larger than the limit of {} bytes", what, max_bytes));
    }
    text.append(buffer.data(), n);
  }
  const bool failed = std::ferror(file) != 0;
  const int read_errno = errno;
  std::fclose(file);
  if (failed) {
    throw InputError({path.string()}, "",
                           fmt::format("cannot read the {}: {}", what, std::strerror(read_errno)));
  }
  return text;
}

}  // namespace tofu::core
