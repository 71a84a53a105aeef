#include "harness/sensor_config_gnss.h"

#include <optional>
#include <string>

#include <fmt/format.h>

#include "harness/config_io.h"

namespace tofu::harness::internal {

using namespace config;  // NOLINT: the small readers of config_io.h

namespace {

sim::GnssFixErrorOptions ReadFixError(const YamlValue& value, sim::GnssFixErrorOptions e) {
  YamlMap map = value.Map({"std_horizontal_m", "std_vertical_m", "correlated_fraction",
                           "correlation_time_s", "multipath_std_m"});
  ReadNumber(map, "std_horizontal_m", NumberRule::Positive("m"), &e.std_horizontal_m);
  ReadNumber(map, "std_vertical_m", NumberRule::Positive("m"), &e.std_vertical_m);
  ReadNumber(map, "correlated_fraction", NumberRule::Between(0.0, 1.0, ""),
             &e.correlated_fraction);
  ReadNumber(map, "correlation_time_s", NumberRule::Positive("s"), &e.correlation_time_s);
  ReadNumber(map, "multipath_std_m", NumberRule::NonNegative("m"), &e.multipath_std_m);
  map.Finish();
  return e;
}

void EmitFixError(YAML::Emitter& out, const char* key, const sim::GnssFixErrorOptions& e) {
  out << YAML::Key << key << YAML::Value << YAML::BeginMap;
  EmitNumber(out, "std_horizontal_m", e.std_horizontal_m);
  EmitNumber(out, "std_vertical_m", e.std_vertical_m);
  EmitNumber(out, "correlated_fraction", e.correlated_fraction);
  EmitNumber(out, "correlation_time_s", e.correlation_time_s);
  EmitNumber(out, "multipath_std_m", e.multipath_std_m);
  out << YAML::EndMap;
}

}  // namespace

sim::GnssOptions ReadGnssOptions(const YamlValue& value) {
  sim::GnssOptions o;
  YamlMap map = value.Map({"type", "site", "rate_hz", "latency_s", "enu_origin_m", "enu_yaw_deg",
                           "satellite_count", "elevation_mask_deg", "sky_ray_length_m",
                           "min_satellites_single", "min_satellites_float",
                           "min_satellites_fixed", "time_to_fix_s", "fixed_at_start",
                           "multipath_min_blocked_fraction", "multipath_correlation_time_s",
                           "rtk_fixed", "rtk_float", "single"});
  (void)map.Optional("type");  // the caller's key (which model this map configures)
  if (const auto site = map.Optional("site")) o.site = site->Identifier();
  ReadNumber(map, "rate_hz", NumberRule::PositiveAtMost(100.0, "Hz"), &o.rate_hz);
  ReadNumber(map, "latency_s", NumberRule::Between(0.0, 10.0, "s"), &o.latency_s);
  ReadVector(map, "enu_origin_m", NumberRule::Any("m"), false, &o.enu_origin_W_m);
  ReadDegrees(map, "enu_yaw_deg", NumberRule::Between(-360.0, 360.0, "deg"), &o.enu_yaw_rad);
  ReadInteger(map, "satellite_count", 0, 200, &o.satellite_count);
  ReadDegrees(map, "elevation_mask_deg", NumberRule::Between(0.0, 89.0, "deg"),
              &o.elevation_mask_rad);
  ReadNumber(map, "sky_ray_length_m", NumberRule::Positive("m"), &o.sky_ray_length_m);

  // Satellite thresholds: each in range and in order single <= float <= fixed.
  const std::optional<YamlValue> single_count = map.Optional("min_satellites_single");
  const std::optional<YamlValue> float_count = map.Optional("min_satellites_float");
  const std::optional<YamlValue> fixed_count = map.Optional("min_satellites_fixed");
  const auto read_count = [](const std::optional<YamlValue>& v, int lo, int* out) {
    if (!v) return;
    const double x = v->Number(NumberRule::Between(lo, 200, ""));
    if (x != static_cast<double>(static_cast<int>(x))) {
      v->FailExpected(fmt::format("an integer in [{}, 200]", lo));
    }
    *out = static_cast<int>(x);
  };
  read_count(single_count, 4, &o.min_satellites_single);
  read_count(float_count, 4, &o.min_satellites_float);
  read_count(fixed_count, 4, &o.min_satellites_fixed);
  if (o.min_satellites_float < o.min_satellites_single) {
    const YamlValue& at = float_count ? *float_count : *single_count;
    at.Fail(fmt::format("expected min_satellites_single ({}) <= min_satellites_float ({})",
                        o.min_satellites_single, o.min_satellites_float));
  }
  if (o.min_satellites_fixed < o.min_satellites_float) {
    const YamlValue& at = fixed_count ? *fixed_count : *float_count;
    at.Fail(fmt::format("expected min_satellites_float ({}) <= min_satellites_fixed ({})",
                        o.min_satellites_float, o.min_satellites_fixed));
  }

  ReadNumber(map, "time_to_fix_s", NumberRule::NonNegative("s"), &o.time_to_fix_s);
  ReadBool(map, "fixed_at_start", &o.fixed_at_start);
  ReadNumber(map, "multipath_min_blocked_fraction", NumberRule::Between(0.0, 1.0, ""),
             &o.multipath_min_blocked_fraction);
  ReadNumber(map, "multipath_correlation_time_s", NumberRule::Positive("s"),
             &o.multipath_correlation_time_s);
  if (const auto e = map.Optional("rtk_fixed")) o.rtk_fixed = ReadFixError(*e, o.rtk_fixed);
  if (const auto e = map.Optional("rtk_float")) o.rtk_float = ReadFixError(*e, o.rtk_float);
  if (const auto e = map.Optional("single")) o.single = ReadFixError(*e, o.single);
  map.Finish();
  return o;
}

void EmitGnssOptions(YAML::Emitter& out, const sim::GnssOptions& o) {
  out << YAML::Key << "site" << YAML::Value << o.site;
  EmitNumber(out, "rate_hz", o.rate_hz);
  EmitNumber(out, "latency_s", o.latency_s);
  EmitVector(out, "enu_origin_m", o.enu_origin_W_m);
  EmitNumber(out, "enu_yaw_deg", o.enu_yaw_rad * kDegPerRad);
  out << YAML::Key << "satellite_count" << YAML::Value << o.satellite_count;
  EmitNumber(out, "elevation_mask_deg", o.elevation_mask_rad * kDegPerRad);
  EmitNumber(out, "sky_ray_length_m", o.sky_ray_length_m);
  out << YAML::Key << "min_satellites_single" << YAML::Value << o.min_satellites_single;
  out << YAML::Key << "min_satellites_float" << YAML::Value << o.min_satellites_float;
  out << YAML::Key << "min_satellites_fixed" << YAML::Value << o.min_satellites_fixed;
  EmitNumber(out, "time_to_fix_s", o.time_to_fix_s);
  out << YAML::Key << "fixed_at_start" << YAML::Value << o.fixed_at_start;
  EmitNumber(out, "multipath_min_blocked_fraction", o.multipath_min_blocked_fraction);
  EmitNumber(out, "multipath_correlation_time_s", o.multipath_correlation_time_s);
  EmitFixError(out, "rtk_fixed", o.rtk_fixed);
  EmitFixError(out, "rtk_float", o.rtk_float);
  EmitFixError(out, "single", o.single);
}

}  // namespace tofu::harness::internal
