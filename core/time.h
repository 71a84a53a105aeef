#pragma once
// Time in tofu: int64 nanoseconds since run start, end to end. Seconds appear only
// inside a computation (DESIGN.md, "Conventions").

#include <cstdint>

namespace tofu::core {

/// Nanoseconds since the start of a run (or since the log's first sample).
using Time = int64_t;

inline constexpr Time kNanosecondsPerSecond = 1'000'000'000;

/// Stamps beyond ±2^62 ns (±146 years, i.e. past 2116 for Unix time) are rejected as
/// data: differences and sums of two valid stamps then never overflow.
inline constexpr Time kMaxValidTimeNs = Time{1} << 62;

constexpr bool IsValidTime(Time t_ns) { return t_ns >= -kMaxValidTimeNs && t_ns <= kMaxValidTimeNs; }

/// Seconds to nanoseconds, rounded to the nearest nanosecond.
constexpr Time SecondsToTime(double t_s) {
  return static_cast<Time>(t_s * 1e9 + (t_s >= 0.0 ? 0.5 : -0.5));
}

/// Nanoseconds to seconds; use only inside computations, never as a key.
constexpr double TimeToSeconds(Time t_ns) { return static_cast<double>(t_ns) * 1e-9; }

/// Period of a rate in nanoseconds, rounded; `rate_hz` must be positive.
constexpr Time PeriodFromRate(double rate_hz) { return SecondsToTime(1.0 / rate_hz); }

}  // namespace tofu::core
