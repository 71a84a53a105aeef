#include "core/error.h"

#include <fmt/format.h>

namespace tofu::core {
namespace {

std::string Format(const SourceLocation& loc, const std::string& key_path,
                   const std::string& message) {
  // One fmt::format: GCC 12 warns (-Wrestrict, falsely) on chains of string appends here.
  return fmt::format("{}{}{}: {}{}", loc.file.empty() ? std::string_view("<input>") : loc.file,
                     loc.line > 0 ? fmt::format(":{}", loc.line) : std::string(),
                     loc.column > 0 ? fmt::format(":{}", loc.column) : std::string(),
                     key_path.empty() ? std::string() : fmt::format("key '{}': ", key_path),
                     message);
}

}  // namespace

InputError::InputError(SourceLocation location, std::string key_path, std::string message)
    : std::runtime_error(Format(location, key_path, message)),
      location_(std::move(location)),
      key_path_(std::move(key_path)),
      message_(std::move(message)) {}

}  // namespace tofu::core
