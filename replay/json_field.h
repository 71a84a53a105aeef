#pragma once
// One field of a JSON record tofu wrote (a check's shard record, check.json, a baseline),
// read with the file, the key and the expected form named when it is missing or of the
// wrong type: the one reader of such fields, for harness and campaign.

#include <filesystem>
#include <optional>
#include <string>

#include <fmt/format.h>
#include <nlohmann/json.hpp>

#include "core/error.h"

namespace tofu::replay {

/// object[key] as T; throws core::InputError({file}, key, "expected <expected>").
template <typename T>
T JsonField(const nlohmann::json& object, const char* key, const std::filesystem::path& file,
            const std::string& expected) {
  const auto it = object.find(key);
  try {
    if (it != object.end()) return it->get<T>();
  } catch (const nlohmann::json::exception&) {
    // Said below, with the expected form.
  }
  throw core::InputError({file.string()}, key, fmt::format("expected {}", expected));
}

/// A figure that may be undefined, as tofu's records write it: the number, or null.
inline nlohmann::json NumberOrNull(const std::optional<double>& value) {
  return value ? nlohmann::json(*value) : nlohmann::json(nullptr);
}

}  // namespace tofu::replay
