#pragma once
// A small, stable, non-cryptographic hash of bytes: the same value on every platform and
// build, for seeds derived from names and for telling two texts apart (not for security).

#include <cstdint>
#include <string_view>

namespace tofu::core {

/// FNV-1a, 64 bit.
uint64_t Fnv1a64(std::string_view bytes);

}  // namespace tofu::core
