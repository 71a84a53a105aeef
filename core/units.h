#pragma once
// Units and constants, one place for each: π, degree conversions, gravity. Angles are
// radians inside the code; degrees only at the edges (YAML keys, CSV columns, messages).

#include <numbers>

namespace tofu::core {

inline constexpr double kPi = std::numbers::pi;
inline constexpr double kTwoPi = 2.0 * std::numbers::pi;
inline constexpr double kRadPerDeg = kPi / 180.0;
inline constexpr double kDegPerRad = 180.0 / kPi;
/// One arc second [rad] (total-station angle noise is specified in them).
inline constexpr double kArcSecondRad = kPi / (180.0 * 3600.0);

/// deg · π / 180, evaluated in that order (the order the readers have always used, so a
/// value read from YAML is the same double as before).
constexpr double RadFromDeg(double deg) { return deg * kPi / 180.0; }
/// rad · 180 / π, evaluated in that order.
constexpr double DegFromRad(double rad) { return rad * 180.0 / kPi; }

/// Standard gravity [m/s²] (ISO 80000-3): the unit of accelerometer ranges ("18 g").
inline constexpr double kStandardGravity_mps2 = 9.80665;
/// The gravity of tofu's worlds [m/s²]: models/*.xml's <option gravity="0 0 -9.81">, the
/// simulator's rigid body and the estimator's default; one value so that they agree.
inline constexpr double kWorldGravity_mps2 = 9.81;

}  // namespace tofu::core
