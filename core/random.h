#pragma once
// Seeded random streams: every stream draws from its own generator seeded from
// (scenario seed, stream name), so adding a stream never shifts another one's samples.

#include <cstdint>
#include <random>
#include <string_view>

#include <Eigen/Core>

namespace tofu::core {

/// 64-bit seed derived from a scenario seed and a stream name (FNV-1a of the name,
/// mixed with the seed through SplitMix64). Stable across platforms and builds.
uint64_t StreamSeed(uint64_t scenario_seed, std::string_view stream_name);

/// One named random stream. Not thread-safe; one owner per stream.
class RandomStream {
 public:
  RandomStream(uint64_t scenario_seed, std::string_view stream_name);

  /// Standard normal sample N(0, 1).
  double Normal();
  /// Three independent standard normal samples, drawn in the order z, y, x. Use this, not
  /// Eigen::Vector3d(Normal(), Normal(), Normal()): the order in which a constructor's
  /// arguments are evaluated is unspecified (GCC goes right to left, Clang left to right),
  /// so that expression gives different runs with different compilers. z-first is the
  /// order GCC gave the calls this replaced, which keeps every run directory as it was.
  Eigen::Vector3d Normal3();
  /// Uniform sample in [lo, hi).
  double Uniform(double lo, double hi);

 private:
  std::mt19937_64 engine_;
  std::normal_distribution<double> normal_{0.0, 1.0};
};

}  // namespace tofu::core
