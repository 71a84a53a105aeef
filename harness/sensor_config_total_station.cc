#include "harness/sensor_config_total_station.h"

#include <string>

#include "harness/config_io.h"

namespace tofu::harness::internal {

using namespace config;  // NOLINT: the small readers of config_io.h

sim::TotalStationOptions ReadTotalStationOptions(const YamlValue& value) {
  sim::TotalStationOptions o;
  YamlMap map = value.Map({"type", "site", "station_site", "station_position_m", "station_rpy_deg",
                           "rate_hz", "latency_s", "horizontal_angle_std_deg",
                           "vertical_angle_std_deg", "distance_std_m", "distance_std_ppm",
                           "max_angular_rate_degps", "search_delay_s", "prism_clearance_m"});
  (void)map.Optional("type");  // the caller's key (which model this map configures)
  if (const auto site = map.Optional("site")) o.site = site->Identifier();
  if (const auto site = map.Optional("station_site")) o.station_site = site->Identifier();
  if (const auto p = map.Optional("station_position_m")) {
    o.p_WS_m = p->Vector3(NumberRule::Any("m"));
  }
  if (const auto rpy = map.Optional("station_rpy_deg")) {
    o.q_WS = QuatFromRpyDeg(rpy->Vector3(NumberRule::Any("deg")));
  }
  ReadNumber(map, "rate_hz", NumberRule::PositiveAtMost(1000.0, "Hz"), &o.rate_hz);
  ReadNumber(map, "latency_s", NumberRule::Between(0.0, 10.0, "s"), &o.latency_s);
  ReadDegrees(map, "horizontal_angle_std_deg", NumberRule::Between(0.0, 1.0, "deg"),
              &o.horizontal_angle_std_rad);
  ReadDegrees(map, "vertical_angle_std_deg", NumberRule::Between(0.0, 1.0, "deg"),
              &o.vertical_angle_std_rad);
  ReadNumber(map, "distance_std_m", NumberRule::Between(0.0, 1.0, "m"), &o.distance_std_m);
  ReadNumber(map, "distance_std_ppm", NumberRule::Between(0.0, 1000.0, "ppm"),
             &o.distance_std_ppm);
  ReadDegrees(map, "max_angular_rate_degps", NumberRule::Positive("deg/s"),
              &o.max_angular_rate_radps);
  ReadNumber(map, "search_delay_s", NumberRule::NonNegative("s"), &o.search_delay_s);
  ReadNumber(map, "prism_clearance_m", NumberRule::Between(0.0, 1.0, "m"), &o.prism_clearance_m);
  map.Finish();
  return o;
}

void EmitTotalStationOptions(YAML::Emitter& out, const sim::TotalStationOptions& o) {
  out << YAML::Key << "site" << YAML::Value << o.site;
  out << YAML::Key << "station_site" << YAML::Value << o.station_site;
  if (o.p_WS_m) EmitVector(out, "station_position_m", *o.p_WS_m);
  if (o.q_WS) EmitVector(out, "station_rpy_deg", RpyDegFromQuat(*o.q_WS));
  EmitNumber(out, "rate_hz", o.rate_hz);
  EmitNumber(out, "latency_s", o.latency_s);
  EmitNumber(out, "horizontal_angle_std_deg", o.horizontal_angle_std_rad * kDegPerRad);
  EmitNumber(out, "vertical_angle_std_deg", o.vertical_angle_std_rad * kDegPerRad);
  EmitNumber(out, "distance_std_m", o.distance_std_m);
  EmitNumber(out, "distance_std_ppm", o.distance_std_ppm);
  EmitNumber(out, "max_angular_rate_degps", o.max_angular_rate_radps * kDegPerRad);
  EmitNumber(out, "search_delay_s", o.search_delay_s);
  EmitNumber(out, "prism_clearance_m", o.prism_clearance_m);
}

}  // namespace tofu::harness::internal
