#pragma once
// Private to harness: small readers and writers shared by every config section (the
// scenario's own keys and each sensor's options), on top of yaml_reader.h. Readers of
// optional keys leave the struct's in-class default when the key is absent, so default
// values are written exactly once, in the option structs.

#include <optional>
#include <string_view>

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <yaml-cpp/yaml.h>

#include "core/units.h"

#include "harness/yaml_reader.h"

namespace tofu::harness::internal::config {

using core::kDegPerRad;
using core::kRadPerDeg;

/// Attitude in YAML: roll, pitch, yaw in degrees, R = Rz(yaw) Ry(pitch) Rx(roll).
Eigen::Quaterniond QuatFromRpyDeg(const Eigen::Vector3d& rpy_deg);
/// Inverse of QuatFromRpyDeg, pitch in [-90, 90], roll and yaw in [-180, 180].
Eigen::Vector3d RpyDegFromQuat(const Eigen::Quaterniond& q);

void ReadNumber(YamlMap& map, std::string_view key, const NumberRule& rule, double* out);
void ReadVector(YamlMap& map, std::string_view key, const NumberRule& rule, bool allow_scalar,
                Eigen::Vector3d* out);
/// A key in degrees (or deg/s, ...) stored in radians.
void ReadDegrees(YamlMap& map, std::string_view key, const NumberRule& rule, double* out_rad);
/// Optional `rpy_deg` key as a quaternion.
std::optional<Eigen::Quaterniond> ReadRpy(YamlMap& map);
/// Optional key as a non-negative integer in [lo, hi].
void ReadInteger(YamlMap& map, std::string_view key, int lo, int hi, int* out);
void ReadBool(YamlMap& map, std::string_view key, bool* out);

/// Round-trip number formatting for the resolved scenario.
void EmitNumber(YAML::Emitter& out, std::string_view key, double value);
void EmitVector(YAML::Emitter& out, const Eigen::Vector3d& v);
void EmitVector(YAML::Emitter& out, std::string_view key, const Eigen::Vector3d& value);
/// An attitude as `key: [roll, pitch, yaw]` in degrees, rounded to 12 significant digits:
/// degrees -> quaternion -> degrees loses the last bits, and the rounding recovers the
/// value a person wrote, so a resolved scenario reloads to the very same quaternion.
void EmitRpyDeg(YAML::Emitter& out, std::string_view key, const Eigen::Quaterniond& q);
/// An angle stored in radians as degrees (same rounding as EmitRpyDeg).
void EmitDegrees(YAML::Emitter& out, std::string_view key, double value_rad);

}  // namespace tofu::harness::internal::config
