#include "core/measurement.h"

#include <cstddef>
#include <type_traits>

namespace tofu::core {

template <MeasurementKind kind, typename Alternative>
constexpr bool kKindIsIndexOf =
    std::is_same_v<std::variant_alternative_t<static_cast<std::size_t>(kind), Measurement>,
                   Alternative>;
static_assert(kKindIsIndexOf<MeasurementKind::kImu, ImuMeasurement>);
static_assert(kKindIsIndexOf<MeasurementKind::kPose, PoseMeasurement>);
static_assert(kKindIsIndexOf<MeasurementKind::kPosition, PositionMeasurement>);
static_assert(std::variant_size_v<Measurement> == 3);

std::string_view MeasurementKindName(MeasurementKind kind) {
  switch (kind) {
    case MeasurementKind::kImu: return "imu";
    case MeasurementKind::kPose: return "pose";
    case MeasurementKind::kPosition: return "position";
  }
  return "unknown";
}

MeasurementKind MeasurementKindOf(const Measurement& measurement) {
  return static_cast<MeasurementKind>(measurement.index());
}

}  // namespace tofu::core
