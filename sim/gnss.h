#pragma once
// GNSS RTK receiver (u-blox ZED-F9P class with a base station): the antenna position in a
// local ENU frame, with the fix type set by how much of the sky the scene leaves open.

#include <array>
#include <span>
#include <cstdint>
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

/// Error model of one fix type. The receiver reports diag(h^2, h^2, v^2) in ENU; the true
/// error per axis is a white part plus a first-order Gauss-Markov ("brown") part sharing
/// that variance, plus multipath (not reported).
struct GnssFixErrorOptions {
  double std_horizontal_m = 0.01;    ///< reported 1-sigma per horizontal axis (E, N)
  double std_vertical_m = 0.02;      ///< reported 1-sigma on U
  double correlated_fraction = 0.5;  ///< share of the variance in the Gauss-Markov part, [0, 1]
  double correlation_time_s = 30.0;  ///< Gauss-Markov time constant
  /// Multipath: a Gauss-Markov error per axis with std = multipath_std_m * blocked sky
  /// fraction (blocked = satellites above the mask hidden by the scene).
  double multipath_std_m = 0.08;

  /// The field table of one fix type's map (rtk_fixed:, rtk_float:, single:).
  static std::span<const core::OptionField<GnssFixErrorOptions>> Fields();
  /// Ceres style: false, with "<key>: <problem>" in *why, when an option is outside its
  /// limits (GnssOptions::IsValid checks its three maps so, with their prefix).
  bool IsValid(std::string* why = nullptr) const;
};

/// Fix types, best last.
enum class GnssFix { kNone, kSingle, kFloat, kFixed };

struct GnssOptions {
  std::string site = "gnss_antenna";  ///< robot mount site of the antenna phase centre
  double rate_hz = 10.0;              ///< RTK output rate (F9P: up to 20 Hz RTK)
  double latency_s = 0.03;            ///< stamp-to-delivery delay [s] (assumed)
  /// The ENU frame S in W: origin [m] (YAML enu_origin_m) and yaw of E from x_W
  /// (YAML enu_yaw_deg); S's z is W's z.
  Eigen::Vector3d enu_origin_W_m = Eigen::Vector3d::Zero();
  double enu_yaw_rad = 0.0;

  /// Sky: satellites drawn once per scenario, uniform over the sky cap above the mask
  /// (azimuth uniform, sin(elevation) uniform), static during a run (GNSS satellites move
  /// ~0.5 deg/min, negligible over a few-minute mission).
  int satellite_count = 22;  ///< GPS + Galileo in view, typical open sky (assumed)
  double elevation_mask_rad = core::RadFromDeg(10.0);
  double sky_ray_length_m = 200.0;  ///< hits beyond count as clear sky

  /// Fix type from the visible count n: n < min_satellites_single: none;
  /// n < min_satellites_float: single; else RTK float, becoming RTK fixed once
  /// n >= min_satellites_fixed has held continuously for time_to_fix_s.
  int min_satellites_single = 4;
  int min_satellites_float = 6;
  int min_satellites_fixed = 8;
  /// Time from (re-)acquisition to RTK fixed [s]: ambiguity resolution of a mobile
  /// receiver takes ~10-60 s (the seed paper's indoor-outdoor run took longer).
  double time_to_fix_s = 20.0;
  /// If true, the receiver is already fixed at the run's start (ambiguities solved on
  /// the ground before take-off) when enough satellites are visible.
  bool fixed_at_start = false;

  /// kMultipath is reported when at least this fraction of the sky is blocked.
  double multipath_min_blocked_fraction = 0.1;
  double multipath_correlation_time_s = 5.0;

  /// Defaults: RTK fixed 1 cm / 2 cm (F9P spec 0.01 m + 1 ppm CEP), float and single from
  /// typical receiver reports; multipath a few cm fixed, decimetres float, metres single.
  GnssFixErrorOptions rtk_fixed{0.01, 0.02, 0.5, 30.0, 0.08};
  GnssFixErrorOptions rtk_float{0.3, 0.5, 0.8, 30.0, 0.8};
  GnssFixErrorOptions single{1.5, 3.0, 0.9, 60.0, 3.0};

  /// The field table (core/option_fields.h): the YAML key, unit and limits of every
  /// option, which the reader, the writer and IsValid share.
  static std::span<const core::OptionField<GnssOptions>> Fields();
  /// Ceres style: false, with "<key>: <problem>" in *why, when an option is outside
  /// its limits or the satellite thresholds are not in order.
  /// The model's constructor throws std::invalid_argument then.
  bool IsValid(std::string* why = nullptr) const;
};

/// GNSS RTK: the antenna site s in the ENU frame S.
///
/// Physics. Each epoch casts a ray from the antenna towards every satellite (unit
/// direction [cos el cos az, cos el sin az, sin el] in S) against the scene; n = number of
/// rays with no hit within sky_ray_length_m. The fix type follows from n (GnssOptions).
/// The reported position is
///   p~_Ss = p_Ss + w + b + m,
///   w ~ N(0, (1 - f) diag(h^2, h^2, v^2)),                  white,
///   b_k+1 = e^(-dt/tau) b_k + sqrt(1 - e^(-2dt/tau)) sqrt(f) diag(h, h, v) n_k,  brown,
///   m = beta * s_mp * g,  g_k+1 = e^(-dt/tau_mp) g_k + sqrt(1 - e^(-2dt/tau_mp)) n_k,
/// with f the correlated fraction, (h, v, tau, s_mp) of the current fix type and beta the
/// blocked fraction of the sky; each fix type's b runs continuously, so a change of fix
/// type jumps the error. The reported covariance is diag(h^2, h^2, v^2) (what a receiver
/// states), not the multipath-inflated true error.
/// Conditions: kNoFix / kSingleFix / kFloatFix by fix type (fixed: none of them),
/// kMultipath when beta >= multipath_min_blocked_fraction and there is a fix.
class GnssModel final : public SensorModel {
 public:
  /// Throws std::invalid_argument if the antenna site is missing or the options are
  /// inconsistent (counts out of order, non-positive rate).
  GnssModel(std::string name, const GnssOptions& options, const World& world, uint64_t seed);

  const std::string& name() const override { return name_; }
  void Step(const SensorInput& input, std::vector<SensorSample>* out) override;
  uint32_t conditions() const override { return conditions_; }
  Eigen::Isometry3d T_WS() const override { return T_WS_; }
  const std::string& site() const override { return options_.site; }
  /// Satellite unit directions in S, drawn at construction from the sensor's own stream.
  std::vector<Eigen::Vector3d> sky_directions_S() const override { return sky_S_; }

  /// Fix type of the latest epoch.
  GnssFix fix() const { return fix_; }
  /// Satellites visible at the latest epoch.
  int visible_satellites() const { return visible_; }

 private:
  const GnssFixErrorOptions& ErrorOptions(GnssFix fix) const;
  void AdvanceErrors(double dt_s);

  std::string name_;
  GnssOptions options_;
  core::RandomStream stream_;
  Eigen::Vector3d p_Bs_;
  Eigen::Isometry3d T_WS_;
  core::Time period_ns_;
  core::Time latency_ns_;
  core::Time time_to_fix_ns_;
  core::Time next_sample_ns_ = 0;
  std::vector<Eigen::Vector3d> sky_S_;

  // Error states (ENU, m): brown error of single, float, fixed; unit multipath process.
  std::array<Eigen::Vector3d, 3> brown_S_;
  Eigen::Vector3d multipath_unit_ = Eigen::Vector3d::Zero();
  std::optional<core::Time> last_epoch_ns_;

  std::optional<core::Time> fixable_since_ns_;  ///< n >= min_satellites_fixed since then
  bool first_epoch_ = true;
  GnssFix fix_ = GnssFix::kNone;
  int visible_ = 0;
  uint32_t conditions_ = kNoFix;
};

}  // namespace tofu::sim
