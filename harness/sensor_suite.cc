#include "harness/sensor_suite.h"

#include <type_traits>

namespace tofu::harness {

std::string_view SensorTypeName(const SensorOptions& options) {
  return kSensorTypeNames[options.index()];
}

replay::SensorModel SensorModelOf(const SensorOptions& options) {
  return kSensorOptionModels[options.index()];
}

core::MeasurementKind SensorMeasurementKind(const SensorOptions& options) {
  return replay::MeasurementKindOf(SensorModelOf(options));
}

const std::string& SensorSite(const SensorOptions& options) {
  return std::visit([](const auto& o) -> const std::string& { return o.site; }, options);
}

double SensorRate_hz(const SensorOptions& options) {
  return std::visit([](const auto& o) { return o.rate_hz; }, options);
}

std::unique_ptr<sim::SensorModel> MakeSensorModel(const SensorConfig& config,
                                                  const sim::World& world, uint64_t seed) {
  return std::visit(
      [&](const auto& options) -> std::unique_ptr<sim::SensorModel> {
        using Options = std::decay_t<decltype(options)>;
        if constexpr (std::is_same_v<Options, sim::ImuOptions>) {
          return std::make_unique<sim::ImuModel>(config.name, options, world, seed);
        } else if constexpr (std::is_same_v<Options, sim::VioOptions>) {
          return std::make_unique<sim::VioModel>(config.name, options, world, seed);
        } else if constexpr (std::is_same_v<Options, sim::LidarOdometryOptions>) {
          return std::make_unique<sim::LidarOdometryModel>(config.name, options, world, seed);
        } else if constexpr (std::is_same_v<Options, sim::TotalStationOptions>) {
          return std::make_unique<sim::TotalStationModel>(config.name, options, world, seed);
        } else {
          static_assert(std::is_same_v<Options, sim::GnssOptions>);
          return std::make_unique<sim::GnssModel>(config.name, options, world, seed);
        }
      },
      config.options);
}

}  // namespace tofu::harness
