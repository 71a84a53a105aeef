#include "harness/config_io.h"

#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <string>

#include <fmt/format.h>

#include "core/lie.h"

namespace tofu::harness::internal::config {

// ---- attitude in YAML: roll, pitch, yaw in degrees, R = Rz(yaw) Ry(pitch) Rx(roll) ----

Eigen::Quaterniond QuatFromRpyDeg(const Eigen::Vector3d& rpy_deg) {
  const Eigen::Matrix3d R = core::RotationFromRollPitchYaw(
      rpy_deg.x() * kRadPerDeg, rpy_deg.y() * kRadPerDeg, rpy_deg.z() * kRadPerDeg);
  return core::CanonicalQuat(Eigen::Quaterniond(R).normalized());
}

// Inverse of QuatFromRpyDeg with pitch in [-90, 90] and roll, yaw in [-180, 180].
// Near gimbal lock yaw is ill-conditioned (cos(pitch) -> 0), so pitch and roll are
// taken from M = Rz(yaw)^T R = Ry(pitch) Rx(roll), where they absorb yaw's error and
// the angles reproduce R to rounding; at the lock itself yaw is set to 0.
Eigen::Vector3d RpyDegFromQuat(const Eigen::Quaterniond& q) {
  const Eigen::Matrix3d R = q.normalized().toRotationMatrix();
  const double yaw = std::hypot(R(0, 0), R(1, 0)) > 1e-12 ? std::atan2(R(1, 0), R(0, 0)) : 0.0;
  const Eigen::Matrix3d M =
      Eigen::AngleAxisd(-yaw, Eigen::Vector3d::UnitZ()).toRotationMatrix() * R;
  // Ry(p) Rx(r) = [cp, sp sr, sp cr; 0, cr, -sr; -sp, cp sr, cp cr].
  const double pitch = std::atan2(-M(2, 0), M(0, 0));
  const double roll = std::atan2(-M(1, 2), M(1, 1));
  // "+ 0.0" turns -0 into 0 for tidy output.
  return Eigen::Vector3d(roll + 0.0, pitch + 0.0, yaw + 0.0) * kDegPerRad;
}

// ---- readers of optional keys: leave the struct's default when the key is absent ----

void ReadNumber(YamlMap& map, std::string_view key, const NumberRule& rule, double* out) {
  if (const auto value = map.Optional(key)) *out = value->Number(rule);
}

void ReadVector(YamlMap& map, std::string_view key, const NumberRule& rule, bool allow_scalar,
                Eigen::Vector3d* out) {
  if (const auto value = map.Optional(key)) *out = value->Vector3(rule, allow_scalar);
}

void ReadDegrees(YamlMap& map, std::string_view key, const NumberRule& rule, double* out_rad) {
  if (const auto value = map.Optional(key)) *out_rad = value->Number(rule) * kRadPerDeg;
}

std::optional<Eigen::Quaterniond> ReadRpy(YamlMap& map) {
  if (const auto value = map.Optional("rpy_deg")) {
    return QuatFromRpyDeg(value->Vector3(NumberRule::Any("deg")));
  }
  return std::nullopt;
}


void ReadInteger(YamlMap& map, std::string_view key, int lo, int hi, int* out) {
  if (const auto value = map.Optional(key)) {
    const double x = value->Number(NumberRule::Between(lo, hi, ""));
    if (x != std::floor(x)) value->FailExpected(fmt::format("an integer in [{}, {}]", lo, hi));
    *out = static_cast<int>(x);
  }
}

void ReadBool(YamlMap& map, std::string_view key, bool* out) {
  if (const auto value = map.Optional(key)) *out = value->Bool();
}

void EmitNumber(YAML::Emitter& out, std::string_view key, double value) {
  out << YAML::Key << std::string(key) << YAML::Value << FormatDouble(value);
}

void EmitVector(YAML::Emitter& out, const Eigen::Vector3d& v) {
  out << YAML::Flow << YAML::BeginSeq;
  for (int i = 0; i < 3; ++i) out << FormatDouble(v[i]);
  out << YAML::EndSeq;
}

void EmitVector(YAML::Emitter& out, std::string_view key, const Eigen::Vector3d& value) {
  out << YAML::Key << std::string(key) << YAML::Value;
  EmitVector(out, value);
}

namespace {
double RoundSignificant(double value, int digits) {
  if (value == 0.0 || !std::isfinite(value)) return value;
  char text[64];
  std::snprintf(text, sizeof(text), "%.*g", digits, value);
  return std::strtod(text, nullptr) + 0.0;  // + 0.0: no "-0" in the output
}
}  // namespace

void EmitRpyDeg(YAML::Emitter& out, std::string_view key, const Eigen::Quaterniond& q) {
  const Eigen::Vector3d rpy = RpyDegFromQuat(q);
  // Each angle is rounded to whole nano-degrees (1e-9 deg = 1.7e-11 rad), not to
  // significant digits: near gimbal lock a significant-digit rounding often fails to
  // reproduce the attitude, the unrounded angles were then written, and atan2 put a roll
  // of ±180 on either side of the branch cut on every resolve (fuzz finding 5). A fixed
  // decimal grid is a fixed point of the round trip; -180 is written as 180, and an
  // angle within 1e-9 deg of zero as 0 (the `+ 0.0` drops a -0; fuzz finding 4).
  Eigen::Vector3d rounded;
  for (int k = 0; k < 3; ++k) {
    rounded(k) = std::round(rpy(k) * 1e9) / 1e9 + 0.0;
    if (rounded(k) == -180.0) rounded(k) = 180.0;
  }
  // Keep the rounding where it reproduces the attitude to 1e-10 rad (a few nano-degrees
  // of roll and yaw trade against each other near gimbal lock).
  const bool faithful =
      QuatFromRpyDeg(rounded).angularDistance(q.normalized()) < 1e-10;
  EmitVector(out, key, faithful ? rounded : rpy);
}

void EmitDegrees(YAML::Emitter& out, std::string_view key, double value_rad) {
  EmitNumber(out, key, RoundSignificant(value_rad * kDegPerRad, 12));
}

}  // namespace tofu::harness::internal::config
