#pragma once
// A small, stable, non-cryptographic hash of bytes: the same value on every platform and
// build, for seeds derived from names and for telling two texts apart (not for security).

#include <cstdint>
#include <string>
#include <string_view>

namespace tofu::core {

/// FNV-1a, 64 bit.
uint64_t Fnv1a64(std::string_view bytes);

/// FNV-1a, 64 bit, fed piece by piece: Fnv1a64(a + b) == hasher.Add(a).Add(b).value().
class Fnv1a64Hasher {
 public:
  Fnv1a64Hasher& Add(std::string_view bytes);
  /// The value's eight bytes, least significant first (the same on every platform).
  Fnv1a64Hasher& Add(uint64_t value);
  /// The IEEE-754 bits of the value (-0.0 and 0.0 differ: a sample is what it is).
  Fnv1a64Hasher& Add(double value);
  uint64_t value() const { return h_; }

 private:
  uint64_t h_ = 0xcbf29ce484222325ULL;
};

/// "0123456789abcdef": a hash as 16 lower-case hex digits.
std::string HexDigest(uint64_t value);

}  // namespace tofu::core
