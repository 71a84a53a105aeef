#pragma once
// The sensor suite of a scenario: typed sensor configurations, the factory that builds
// the sim models, and what a run records of their streams: the clean samples, the
// samples as delivered after scheduled faults, and the labels of every condition and
// fault (labels.csv).

#include <array>
#include <cstdint>
#include <memory>
#include <string>
#include <string_view>
#include <utility>
#include <variant>
#include <vector>

#include <Eigen/Geometry>

#include "core/time.h"
#include "replay/labels.h"
#include "replay/run_format.h"
#include "sim/faults.h"
#include "sim/gnss.h"
#include "sim/imu.h"
#include "sim/lidar_odometry.h"
#include "sim/sensor.h"
#include "sim/total_station.h"
#include "sim/vio.h"
#include "sim/world.h"

namespace tofu::harness {

/// Options of one sensor; the alternative says its type.
using SensorOptions = std::variant<sim::ImuOptions, sim::VioOptions, sim::LidarOdometryOptions,
                                   sim::TotalStationOptions, sim::GnssOptions>;

/// The model of each alternative of SensorOptions, in its order.
inline constexpr std::array<replay::SensorModel, 5> kSensorOptionModels = {
    replay::SensorModel::kImu, replay::SensorModel::kVio, replay::SensorModel::kLidarOdometry,
    replay::SensorModel::kTotalStation, replay::SensorModel::kGnss};
static_assert(kSensorOptionModels.size() == std::variant_size_v<SensorOptions>);

/// Type names as written in YAML (`type:`), in the order of SensorOptions: the run
/// format's (replay/run_format.h), which calibration.yaml records.
inline constexpr std::array<std::string_view, 5> kSensorTypeNames = {
    replay::SensorModelName(kSensorOptionModels[0]), replay::SensorModelName(kSensorOptionModels[1]),
    replay::SensorModelName(kSensorOptionModels[2]), replay::SensorModelName(kSensorOptionModels[3]),
    replay::SensorModelName(kSensorOptionModels[4])};

struct SensorConfig {
  std::string name;  ///< stream name: [a-z0-9_]+, the key under `sensors:`
  SensorOptions options;
  /// Error of the nominal extrinsics an estimator is given (calibration.yaml):
  /// T_Bs_nominal = T_Bs_true * calibration_error. The simulation uses the truth.
  Eigen::Isometry3d calibration_error = Eigen::Isometry3d::Identity();
};

std::string_view SensorTypeName(const SensorOptions& options);

/// The sensor's model (its `type:`).
replay::SensorModel SensorModelOf(const SensorOptions& options);

/// The kind of stream the sensor records (its rows' columns, replay/run_format.h).
core::MeasurementKind SensorMeasurementKind(const SensorOptions& options);

/// The mount site a sensor's options name.
const std::string& SensorSite(const SensorOptions& options);

/// The sensor's nominal output rate [Hz].
double SensorRate_hz(const SensorOptions& options);

/// Builds the model of `config`; its random streams derive from (seed, sensor name) only,
/// so adding or removing another sensor never changes this one's samples.
std::unique_ptr<sim::SensorModel> MakeSensorModel(const SensorConfig& config,
                                                  const sim::World& world, uint64_t seed);

/// What a run recorded of one sensor. The sample vectors are kept only by a run held in
/// memory (RunRecord::recorded_to unset); the counts and the digest by every run.
struct SensorStream {
  std::string name;
  std::string type;  ///< kSensorTypeNames
  core::MeasurementKind kind = core::MeasurementKind::kImu;
  std::string site;
  Eigen::Isometry3d T_WS = Eigen::Isometry3d::Identity();  ///< true reference frame in W
  std::vector<Eigen::Vector3d> sky_directions_S;  ///< GNSS satellites in S (fixed for the run)
  std::size_t produced_count = 0;   ///< clean samples
  std::size_t delivered_count = 0;  ///< samples after scheduled faults
  /// Digest of the delivered samples for windowed metrics (evaluation.h): their times,
  /// and for position and pose streams |p_measured - p_true|² [m²] of each.
  std::vector<core::Time> delivered_t_ns;
  std::vector<double> delivered_position_error_m2;
  std::vector<sim::SensorSample> clean;      ///< as the model produced them
  std::vector<sim::SensorSample> delivered;  ///< after scheduled faults: what a consumer gets
  std::vector<uint32_t> delivered_faults;    ///< active fault bits per delivered sample
  /// IMU only: the true biases (gyro, accel) of each clean sample.
  std::vector<std::pair<Eigen::Vector3d, Eigen::Vector3d>> imu_biases;
};

}  // namespace tofu::harness
