#pragma once
// What makes two flights comparable sample by sample: a digest of the measurements the
// methods were given, and the ledger of the random streams that generated them.

#include <cstdint>
#include <map>
#include <string>
#include <string_view>

#include "core/hash.h"
#include "core/measurement.h"

namespace tofu::core {

/// Feeds every value of the measurement (its kind, then its fields' IEEE-754 bits) to
/// `hasher`: equal digests, the same measurement.
void HashMeasurement(const Measurement& measurement, Fnv1a64Hasher& hasher);

/// The random streams a flight draws from, by name and seed: two flights with the same
/// ledger draw common random numbers (the same noise, however differently they fly), the
/// fact a paired comparison of closed-loop flights rests on. A RandomStream (random.h)
/// constructed on a thread while a Scope of a ledger is open there is entered in it.
class RandomStreamLedger {
 public:
  /// Enters every stream constructed on this thread until destroyed (scopes nest: the
  /// innermost ledger is the one written).
  class Scope {
   public:
    explicit Scope(RandomStreamLedger& ledger);
    ~Scope();
    Scope(const Scope&) = delete;
    Scope& operator=(const Scope&) = delete;

   private:
    RandomStreamLedger* previous_;
  };

  /// The ledger of this thread's innermost open Scope, or null.
  static RandomStreamLedger* Current();

  void Add(std::string_view stream_name, uint64_t seed);
  /// FNV-1a over the streams sorted by name, each name and seed: independent of the order
  /// in which they were constructed.
  uint64_t Digest() const;
  std::size_t size() const { return seeds_.size(); }

 private:
  std::map<std::string, uint64_t, std::less<>> seeds_;
};

}  // namespace tofu::core
