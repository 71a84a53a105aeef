#include "core/lidar_beam_pattern.h"

#include <cmath>

namespace tofu::core {

std::span<const OptionField<LidarBeamPattern>> LidarBeamPattern::Fields() {
  using F = OptionField<LidarBeamPattern>;
  using R = NumberRule;
  using O = LidarBeamPattern;
  static const F kFields[] = {
      F::Integer("azimuth_count", &O::azimuth_count, 1, 3600),
      F::Integer("elevation_count", &O::elevation_count, 1, 256),
      F::Degrees("elevation_min_deg", &O::elevation_min_rad, R::Between(-90.0, 90.0, "deg")),
      F::Degrees("elevation_max_deg", &O::elevation_max_rad, R::Between(-90.0, 90.0, "deg")),
      F::Number("min_range_m", &O::min_range_m, R::NonNegative("m")),
      F::Number("max_range_m", &O::max_range_m, R::Positive("m")),
  };
  return kFields;
}

bool LidarBeamPattern::IsValid(std::string* why) const {
  if (!CheckOptionFields<LidarBeamPattern>(*this, Fields(), why)) return false;
  const auto fail = [why](const char* message) {
    if (why != nullptr) *why = message;
    return false;
  };
  if (!(min_range_m < max_range_m)) return fail("max_range_m: must be greater than min_range_m");
  if (!(elevation_min_rad <= elevation_max_rad)) {
    return fail("elevation_max_deg: must not be less than elevation_min_deg");
  }
  return true;
}

double LidarBeamPattern::ElevationRad(int row) const {
  if (elevation_count == 1) return 0.5 * (elevation_min_rad + elevation_max_rad);
  return elevation_min_rad + (elevation_max_rad - elevation_min_rad) * row / (elevation_count - 1);
}

Eigen::Vector3d LidarBeamPattern::Direction_s(int row, int column,
                                              double azimuth_offset_rad) const {
  const double e = ElevationRad(row);
  const double a = azimuth_offset_rad + AzimuthStepRad() * column;
  const double ce = std::cos(e);
  return Eigen::Vector3d(ce * std::cos(a), ce * std::sin(a), std::sin(e));
}

}  // namespace tofu::core
