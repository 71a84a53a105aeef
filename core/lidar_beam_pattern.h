#pragma once
// The beam pattern of a scanning LiDAR, one concept for the three places that need it: the
// LiDAR-odometry model casts these rays (sim/lidar_odometry.h), and a run directory's
// calibration.yaml records them so that the renderer draws the same rays without the
// model (replay/run_calibration.h). Its options table (core/option_fields.h) holds the
// limits once, for the scenario reader, the calibration reader and IsValid.

#include <span>
#include <string>
#include <vector>

#include <Eigen/Core>

#include "core/option_fields.h"
#include "core/units.h"

namespace tofu::core {

/// Elevation rows evenly spaced over [elevation_min, elevation_max] (one row: at the
/// middle), azimuth columns evenly spaced over the full turn about the scanner's z axis,
/// and the ranges at which a return counts. Defaults: a Livox Mid-360 (360 deg x
/// [-7, 52] deg), thinned from its 200 kpts/s to what a scan's registration needs.
struct LidarBeamPattern {
  int azimuth_count = 72;    ///< rays per elevation row
  int elevation_count = 12;  ///< rows, evenly spaced from min to max
  double elevation_min_rad = RadFromDeg(-7.0);
  double elevation_max_rad = RadFromDeg(52.0);
  double min_range_m = 0.1;  ///< Mid-360 close blind zone 0.1 m
  /// Mid-360 spec: 40 m at 10 % reflectivity, 70 m at 80 %; 40 m (dark, weathered
  /// concrete and grass are ~10-30 %) is the default.
  double max_range_m = 40.0;

  /// The field table: keys azimuth_count, elevation_count, elevation_min_deg,
  /// elevation_max_deg, min_range_m, max_range_m with their limits.
  static std::span<const OptionField<LidarBeamPattern>> Fields();
  /// Ceres style: false, with "<key>: <problem>" in *why, when a field is outside its
  /// limits or the ranges or elevations are not in order.
  bool IsValid(std::string* why = nullptr) const;

  /// Angle between neighbouring columns: the full turn / azimuth_count [rad].
  double AzimuthStepRad() const { return 2.0 * kPi / azimuth_count; }
  /// Elevation of row `row` in [0, elevation_count) [rad].
  double ElevationRad(int row) const;
  /// Unit direction in the scanner frame s (z = scanner axis) of the ray in row `row` and
  /// column `column`, the azimuths turned by `azimuth_offset_rad` (a scan pattern that
  /// does not repeat from scan to scan).
  Eigen::Vector3d Direction_s(int row, int column, double azimuth_offset_rad = 0.0) const;
  /// Every ray's Direction_s(row, column, azimuth_offset_rad), row by row, into
  /// *directions_s (resized): the same values, each angle's sine and cosine taken once.
  void Directions_s(double azimuth_offset_rad, std::vector<Eigen::Vector3d>* directions_s) const;
  /// Whether a return at `distance_m` is inside [min_range_m, max_range_m].
  bool InRange(double distance_m) const {
    return distance_m >= min_range_m && distance_m <= max_range_m;
  }
};

}  // namespace tofu::core
