#include "harness/sensor_config.h"

#include <type_traits>

#include "harness/config_io.h"
#include "harness/sensor_config_gnss.h"
#include "harness/sensor_config_imu.h"
#include "harness/sensor_config_lidar_odometry.h"
#include "harness/sensor_config_total_station.h"
#include "harness/sensor_config_vio.h"

namespace tofu::harness::internal {

using namespace config;

SensorOptions ReadSensorOptions(std::string_view type, const YamlValue& value) {
  if (type == "imu") return ReadImuOptions(value);
  if (type == "vio") return ReadVioOptions(value);
  if (type == "lidar_odometry") return ReadLidarOdometryOptions(value);
  if (type == "total_station") return ReadTotalStationOptions(value);
  return ReadGnssOptions(value);
}

void EmitSensorOptions(YAML::Emitter& out, const SensorOptions& options) {
  std::visit(
      [&out](const auto& o) {
        using Options = std::decay_t<decltype(o)>;
        if constexpr (std::is_same_v<Options, sim::ImuOptions>) {
          EmitImuOptions(out, o);
        } else if constexpr (std::is_same_v<Options, sim::VioOptions>) {
          EmitVioOptions(out, o);
        } else if constexpr (std::is_same_v<Options, sim::LidarOdometryOptions>) {
          EmitLidarOdometryOptions(out, o);
        } else if constexpr (std::is_same_v<Options, sim::TotalStationOptions>) {
          EmitTotalStationOptions(out, o);
        } else {
          static_assert(std::is_same_v<Options, sim::GnssOptions>);
          EmitGnssOptions(out, o);
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
