#include "core/hash.h"

#include <cstring>

#include <fmt/format.h>

namespace tofu::core {

uint64_t Fnv1a64(std::string_view bytes) { return Fnv1a64Hasher().Add(bytes).value(); }

Fnv1a64Hasher& Fnv1a64Hasher::Add(std::string_view bytes) {
  for (const char c : bytes) {
    h_ ^= static_cast<uint8_t>(c);
    h_ *= 0x100000001b3ULL;
  }
  return *this;
}

Fnv1a64Hasher& Fnv1a64Hasher::Add(uint64_t value) {
  for (int i = 0; i < 8; ++i) {
    h_ ^= static_cast<uint8_t>(value >> (8 * i));
    h_ *= 0x100000001b3ULL;
  }
  return *this;
}

Fnv1a64Hasher& Fnv1a64Hasher::Add(double value) {
  uint64_t bits = 0;
  std::memcpy(&bits, &value, sizeof bits);
  return Add(bits);
}

std::string HexDigest(uint64_t value) { return fmt::format("{:016x}", value); }

}  // namespace tofu::core
