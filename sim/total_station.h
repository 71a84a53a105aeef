#pragma once
// Robotic total station (Leica MS60 class) tracking a 360° mini prism (Leica GRZ101) on
// the robot: a position stream of the prism in the station frame S, with the dropouts a
// tracker has (line of sight blocked, lock lost on fast motion, search before re-lock).

#include <cstdint>
#include <span>
#include <optional>
#include <string>
#include <vector>

#include <Eigen/Core>
#include <Eigen/Geometry>

#include "core/random.h"
#include "core/option_fields.h"
#include "core/time.h"
#include "core/units.h"
#include "sim/sensor.h"
#include "sim/world.h"

namespace tofu::sim {

/// One arc-second in radians (1" = pi / (180 * 3600)).
using core::kArcSecondRad;

struct TotalStationOptions {
  std::string site = "prism";  ///< robot mount site of the prism
  /// World site whose pose is the station frame S (instrument centre, z up, x = Hz zero).
  std::string station_site = "station_tripod";
  /// Overrides of the station pose in W (YAML station_position_m, station_rpy_deg); each
  /// unset part comes from station_site.
  std::optional<Eigen::Vector3d> p_WS_m;
  std::optional<Eigen::Quaterniond> q_WS;

  double rate_hz = 20.0;    ///< MS60 tracking output: up to 20 Hz
  double latency_s = 0.01;  ///< stamp-to-delivery delay [s] (assumed, serial streaming)
  /// 1-sigma angle noise [rad]: MS60 spec 1" (0.3 mgon), ISO 17123-3, Hz and V.
  double horizontal_angle_std_rad = kArcSecondRad;
  double vertical_angle_std_rad = kArcSecondRad;
  /// Distance noise sigma_d = distance_std_m + distance_std_ppm * 1e-6 * d. MS60 spec to a
  /// prism: 1 mm + 1.5 ppm (single, ~1.5 s), 3 mm + 1.5 ppm in continuous/tracking mode;
  /// the tracking figure is the default since the prism moves.
  double distance_std_m = 0.003;
  double distance_std_ppm = 1.5;
  /// Lock is lost when the prism's angular rate seen from the station, |v_perp| / d,
  /// exceeds this [rad/s]. Assumption from the LOCK-mode figure of the MS60/TS60 class
  /// (tangential speed ~9 m/s at 20 m => 0.45 rad/s).
  double max_angular_rate_radps = 0.45;
  /// After a loss the station searches; it re-locks once the prism has been continuously
  /// visible and slower than the limit for this long [s] (assumed; PowerSearch takes
  /// seconds).
  double search_delay_s = 2.0;
  /// A ray hit within this distance of the prism centre is the prism itself (GRZ101
  /// radius ~2.5 cm plus mount) [m].
  double prism_clearance_m = 0.05;

  /// The field table (core/option_fields.h): the YAML key, unit and limits of every
  /// option, which the reader, the writer and IsValid share.
  static std::span<const core::OptionField<TotalStationOptions>> Fields();
  /// Ceres style: false, with "<key>: <problem>" in *why, when an option is outside
  /// its limits.
  /// The model's constructor throws std::invalid_argument then.
  bool IsValid(std::string* why = nullptr) const;
};

/// Total station: the position of the prism site s in the station frame S.
///
/// Physics. With p = R_WS^T (p_Ws - p_WS) = [x, y, z] the instrument measures the
/// spherical coordinates
///   Hz = atan2(y, x),  V = atan2(z, sqrt(x^2 + y^2)) (elevation),  d = |p|,
/// each with independent white Gaussian noise:
///   Hz~ = Hz + sigma_hz n,  V~ = V + sigma_v n,  d~ = d + (a + b d) n,
/// and reports p~ = d~ [cos V~ cos Hz~, cos V~ sin Hz~, sin V~] with the first-order
/// covariance Sigma_p = J diag(sigma_hz^2, sigma_v^2, sigma_d^2) J^T,
///   J = d p / d(Hz, V, d) = [-d cV sHz, -d sV cHz, cV cHz;
///                             d cV cHz, -d sV sHz, cV sHz;
///                             0,         d cV,      sV     ]   (evaluated at p~).
/// Line of sight: at every sample a ray from the station to the prism against the scene
/// and the robot's visual body; a hit closer than d - prism_clearance_m blocks it.
/// Tracking state machine (angular rate |v_perp| / d, v_perp = v_Ws - (v_Ws . u) u,
/// u = unit line of sight, checked every physics step; visibility at every sample):
///   locked    --(occluded | rate > limit)-->  lost       [kLockLost (+kOccluded)]
///   lost      --(visible & slow)----------->  searching  [kSearching]
///   searching --(occluded | fast)---------->  lost
///   searching --(visible & slow for search_delay_s)--> locked (samples again)
/// Samples come out only while locked. The station pose T_WS is unknown to estimators.
class TotalStationModel final : public SensorModel {
 public:
  /// Throws std::invalid_argument if the prism site or the station site is missing.
  TotalStationModel(std::string name, const TotalStationOptions& options, const World& world,
                    uint64_t seed);

  const std::string& name() const override { return name_; }
  void Step(const SensorInput& input, std::vector<SensorSample>* out) override;
  uint32_t conditions() const override { return conditions_; }
  Eigen::Isometry3d T_WS() const override { return T_WS_; }
  const std::string& site() const override { return options_.site; }

  /// Covariance of the Cartesian position for spherical coordinates (Hz, V, d) [rad, m]:
  /// J diag(sigma_hz^2, sigma_v^2, sigma_d(d)^2) J^T.
  Eigen::Matrix3d CartesianCovariance(double hz_rad, double v_rad, double d_m) const;

 private:
  enum class Track { kLocked, kLost, kSearching };

  std::string name_;
  TotalStationOptions options_;
  core::RandomStream stream_;
  Eigen::Vector3d p_Bs_;
  Eigen::Isometry3d T_WS_;
  core::Time period_ns_;
  core::Time latency_ns_;
  core::Time search_delay_ns_;
  core::Time next_sample_ns_ = 0;

  Track track_ = Track::kLocked;  ///< the station starts locked onto the prism
  core::Time search_start_ns_ = 0;
  bool occluded_ = false;  ///< result of the latest line-of-sight ray
  uint32_t conditions_ = kConditionNone;
};

}  // namespace tofu::sim
