#include "core/error.h"

#include <fmt/format.h>

namespace tofu::core {
namespace {

std::string Format(const SourceLocation& loc, const std::string& key_path,
                   const std::string& message) {
  std::string out = loc.file.empty() ? std::string("<input>") : loc.file;
  if (loc.line > 0) out += fmt::format(":{}", loc.line);
  if (loc.column > 0) out += fmt::format(":{}", loc.column);
  out += ": ";
  if (!key_path.empty()) out += fmt::format("key '{}': ", key_path);
  out += message;
  return out;
}

}  // namespace

InputError::InputError(SourceLocation location, std::string key_path, std::string message)
    : std::runtime_error(Format(location, key_path, message)),
      location_(std::move(location)),
      key_path_(std::move(key_path)),
      message_(std::move(message)) {}

}  // namespace tofu::core
