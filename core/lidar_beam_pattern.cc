#include "core/lidar_beam_pattern.h"

#include <cmath>

namespace tofu::core {

std::span<const OptionField<LidarBeamPattern>> LidarBeamPattern::Fields() {
  using F = OptionField<LidarBeamPattern>;
  using R = NumberRule;
  using O = LidarBeamPattern;
  static const F kFields[] = {
      F::Integer("azimuth_count", &O::azimuth_count, 1, 3600)
          .Doc("rays per elevation row"),
      F::Integer("elevation_count", &O::elevation_count, 1, 256)
          .Doc("rows of rays, evenly spaced from the minimum to the maximum elevation"),
      F::Degrees("elevation_min_deg", &O::elevation_min_rad, R::Between(-90.0, 90.0, "deg"))
          .Doc("elevation of the lowest row"),
      F::Degrees("elevation_max_deg", &O::elevation_max_rad, R::Between(-90.0, 90.0, "deg"))
          .Doc("elevation of the highest row"),
      F::Number("min_range_m", &O::min_range_m, R::NonNegative("m"))
          .Doc("returns nearer than this are not seen (close blind zone)"),
      F::Number("max_range_m", &O::max_range_m, R::Positive("m"))
          .Doc("returns farther than this are not seen (Mid-360 spec at 10 % reflectivity)"),
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

void LidarBeamPattern::Directions_s(double azimuth_offset_rad,
                                    std::vector<Eigen::Vector3d>* directions_s) const {
  std::vector<double> cos_azimuth(azimuth_count), sin_azimuth(azimuth_count);
  for (int column = 0; column < azimuth_count; ++column) {
    const double a = azimuth_offset_rad + AzimuthStepRad() * column;
    cos_azimuth[column] = std::cos(a);
    sin_azimuth[column] = std::sin(a);
  }
  directions_s->resize(static_cast<std::size_t>(azimuth_count) * elevation_count);
  auto out = directions_s->begin();
  for (int row = 0; row < elevation_count; ++row) {
    const double e = ElevationRad(row);
    const double ce = std::cos(e);
    const double se = std::sin(e);
    for (int column = 0; column < azimuth_count; ++column) {
      *out++ = Eigen::Vector3d(ce * cos_azimuth[column], ce * sin_azimuth[column], se);
    }
  }
}

}  // namespace tofu::core
