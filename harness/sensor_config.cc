#include "harness/sensor_config.h"

#include <string>
#include <type_traits>

#include "harness/config_io.h"
#include "harness/option_fields_yaml.h"
#include "replay/run_format.h"

namespace tofu::harness::internal {

using namespace config;

namespace {

// GNSS: one map per fix type (rtk_fixed:, rtk_float:, single:) after the flat options.
constexpr std::string_view kGnssFixKeys[] = {"rtk_fixed", "rtk_float", "single"};

// The fix type's options in a (const) sim::GnssOptions.
template <typename Gnss>
auto& GnssFix(Gnss& o, std::string_view key) {
  return key == "rtk_fixed" ? o.rtk_fixed : key == "rtk_float" ? o.rtk_float : o.single;
}

}  // namespace

template <typename Options>
Options ReadSensorOptions(const YamlValue& value) {
  constexpr bool kGnss = std::is_same_v<Options, sim::GnssOptions>;
  const auto fields = Options::Fields();
  std::vector<std::string_view> keys = OptionKeys(fields, {"type"});
  if constexpr (kGnss) keys.insert(keys.end(), std::begin(kGnssFixKeys), std::end(kGnssFixKeys));
  YamlMap map = value.Map(keys);
  (void)map.Optional("type");  // the caller's key (which model this map configures)
  Options o;
  ReadOptionFields(map, fields, &o);
  if constexpr (kGnss) {
    const auto fix_fields = sim::GnssFixErrorOptions::Fields();
    for (const std::string_view key : kGnssFixKeys) {
      if (const auto fix = map.Optional(key)) {
        YamlMap fix_map = fix->Map(OptionKeys(fix_fields));
        ReadOptionFields(fix_map, fix_fields, &GnssFix(o, key));
        FinishOptionsMap(fix_map, GnssFix(o, key));
      }
    }
  }
  FinishOptionsMap(map, o);
  return o;
}

template sim::ImuOptions ReadSensorOptions<sim::ImuOptions>(const YamlValue&);
template sim::VioOptions ReadSensorOptions<sim::VioOptions>(const YamlValue&);
template sim::LidarOdometryOptions ReadSensorOptions<sim::LidarOdometryOptions>(const YamlValue&);
template sim::TotalStationOptions ReadSensorOptions<sim::TotalStationOptions>(const YamlValue&);
template sim::GnssOptions ReadSensorOptions<sim::GnssOptions>(const YamlValue&);

SensorOptions ReadSensorOptions(std::string_view type, const YamlValue& value) {
  switch (replay::SensorModelOfName(type).value_or(replay::SensorModel::kGnss)) {
    case replay::SensorModel::kImu: return ReadSensorOptions<sim::ImuOptions>(value);
    case replay::SensorModel::kVio: return ReadSensorOptions<sim::VioOptions>(value);
    case replay::SensorModel::kLidarOdometry:
      return ReadSensorOptions<sim::LidarOdometryOptions>(value);
    case replay::SensorModel::kTotalStation:
      return ReadSensorOptions<sim::TotalStationOptions>(value);
    case replay::SensorModel::kGnss: break;
  }
  return ReadSensorOptions<sim::GnssOptions>(value);
}

void EmitSensorOptions(YAML::Emitter& out, const SensorOptions& options) {
  std::visit(
      [&out](const auto& o) {
        using Options = std::decay_t<decltype(o)>;
        EmitOptionFields(out, Options::Fields(), o);
        if constexpr (std::is_same_v<Options, sim::GnssOptions>) {
          for (const std::string_view key : kGnssFixKeys) {
            out << YAML::Key << std::string(key) << YAML::Value << YAML::BeginMap;
            EmitOptionFields(out, sim::GnssFixErrorOptions::Fields(), GnssFix(o, key));
            out << YAML::EndMap;
          }
        }
      },
      options);
}

Eigen::Isometry3d ReadCalibrationError(const YamlValue& value) {
  YamlMap map = value.Map({"translation_m", "rpy_deg"});
  Eigen::Vector3d translation = Eigen::Vector3d::Zero();
  ReadVector(map, "translation_m", NumberRule::Any("m"), false, &translation);
  Eigen::Isometry3d error = Eigen::Isometry3d::Identity();
  if (const auto q = ReadRpy(map)) error.linear() = q->toRotationMatrix();
  error.translation() = translation;
  map.Finish();
  return error;
}

void EmitCalibrationError(YAML::Emitter& out, const Eigen::Isometry3d& error) {
  if (error.matrix() == Eigen::Matrix4d::Identity()) return;
  out << YAML::Key << "calibration_error" << YAML::Value << YAML::BeginMap;
  EmitVector(out, "translation_m", error.translation());
  EmitRpyDeg(out, "rpy_deg", Eigen::Quaterniond(error.linear()));
  out << YAML::EndMap;
}

}  // namespace tofu::harness::internal
