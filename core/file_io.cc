#include "core/file_io.h"

#include <algorithm>
#include <array>
#include <cerrno>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <fstream>

#include <fmt/format.h>

#include "core/error.h"

namespace tofu::core {

namespace fs = std::filesystem;

namespace {

std::FILE* OpenForReading(const fs::path& path, std::string_view what) {
  std::error_code ec;
  if (fs::is_directory(path, ec)) {
    throw InputError({path.string()}, "", fmt::format("is a directory, expected a {}", what));
  }
  std::FILE* file = std::fopen(path.c_str(), "rb");
  if (file == nullptr) {
    throw InputError({path.string()}, "",
                           fmt::format("cannot open the {}: {}", what, std::strerror(errno)));
  }
  return file;
}

}  // namespace

LineReader::LineReader(const fs::path& path, std::string_view what)
    : path_(path), what_(what), file_(OpenForReading(path, what)) {}

LineReader::~LineReader() {
  std::fclose(file_);
  std::free(buffer_);
}

bool LineReader::Next(std::string& line, bool* had_newline) {
  // POSIX getline: the length it returns counts bytes, so a NUL inside a line stays in it
  // (and fails the field's parse) instead of cutting the line short.
  errno = 0;
  const ssize_t n = ::getline(&buffer_, &capacity_, file_);
  if (n < 0) {
    if (std::ferror(file_) != 0) {
      throw InputError({path_.string()}, "",
                       fmt::format("cannot read the {}: {}", what_, std::strerror(errno)));
    }
    line.clear();
    return false;
  }
  std::size_t length = static_cast<std::size_t>(n);
  const bool newline = length > 0 && buffer_[length - 1] == '\n';
  if (newline) --length;
  if (had_newline != nullptr) *had_newline = newline;
  line.assign(buffer_, length);
  return true;
}

std::size_t LineReader::CountRemainingLines() {
  const long position = std::ftell(file_);
  std::size_t lines = 0;
  std::array<char, 1 << 16> buffer;
  std::size_t n = 0;
  char last = '\n';
  while ((n = std::fread(buffer.data(), 1, buffer.size(), file_)) > 0) {
    lines += static_cast<std::size_t>(std::count(buffer.data(), buffer.data() + n, '\n'));
    last = buffer[n - 1];
  }
  if (last != '\n') ++lines;
  std::clearerr(file_);
  std::fseek(file_, position, SEEK_SET);
  return lines;
}

std::string ReadWholeFile(const fs::path& path, std::string_view what, std::size_t max_bytes) {
  std::error_code ec;
  std::FILE* file = OpenForReading(path, what);
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

std::vector<std::string> LogTail(const fs::path& path, std::size_t max_lines) {
  std::ifstream in(path);
  std::vector<std::string> lines;
  std::string line;
  while (std::getline(in, line)) {
    if (const std::size_t cr = line.find_last_of('\r'); cr != std::string::npos) {
      line = line.substr(cr + 1);
    }
    if (line.find_first_not_of(" \t") == std::string::npos) continue;
    if (line.size() > 400) line = line.substr(0, 400) + "...";
    lines.push_back(line);
  }
  if (lines.size() > max_lines) {
    lines.erase(lines.begin(), lines.end() - static_cast<std::ptrdiff_t>(max_lines));
  }
  return lines;
}

}  // namespace tofu::core
