#include "core/measurement.h"

#include "core/digest.h"

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

namespace {

template <typename Derived>
void HashValues(const Eigen::DenseBase<Derived>& values, Fnv1a64Hasher& hasher) {
  for (Eigen::Index i = 0; i < values.size(); ++i) hasher.Add(static_cast<double>(values(i)));
}

}  // namespace

void HashMeasurement(const Measurement& measurement, Fnv1a64Hasher& hasher) {
  hasher.Add(uint64_t{measurement.index()});
  if (const auto* imu = std::get_if<ImuMeasurement>(&measurement)) {
    HashValues(imu->acc_I_mps2, hasher);
    HashValues(imu->gyro_I_radps, hasher);
  } else if (const auto* pose = std::get_if<PoseMeasurement>(&measurement)) {
    HashValues(pose->p_Ss, hasher);
    HashValues(pose->q_Ss.coeffs(), hasher);
    HashValues(pose->covariance, hasher);
    hasher.Add(uint64_t{pose->has_twist});
    if (pose->has_twist) {
      HashValues(pose->v_s_s_mps, hasher);
      HashValues(pose->omega_s_s_radps, hasher);
      HashValues(pose->twist_covariance, hasher);
    }
  } else if (const auto* position = std::get_if<PositionMeasurement>(&measurement)) {
    HashValues(position->p_Ss, hasher);
    HashValues(position->covariance, hasher);
  }
}

}  // namespace tofu::core
