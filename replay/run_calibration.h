#pragma once
// The one reader of a run directory's calibration.yaml (harness/run_directory.cc writes
// it; a user may write one beside a recorded log). Simulator-free: `tofu estimate`,
// `tofu consistency` and the renderer read mounts, extrinsics, sensor options and the
// geometry a picture needs from the run directory itself, never from the scenario.
// Strict as every reader of tofu's: a malformed field (a mount, a pose with a NaN, a sky
// direction that is not a unit vector, a root that is not a map) is an InputError at its
// line, also where an older reader ignored it.
//
// Schema (every key optional unless named; poses {p_m: [x, y, z], q_wxyz: [w, x, y, z]}):
//   mounts:  {<site>: pose}                   mount frame s in body frame B, T_Bs (true)
//   sensors: {<name>: {                       one per stream sensors/<name>.csv
//     type: imu|vio|lidar_odometry|total_station|gnss
//     site: <site>
//     T_B_s: pose                             nominal mount T_Bs: what an estimator is given
//     true_T_B_s: pose                        the truth, only where the two differ
//     true_T_WS: pose                         the stream's reference frame S in W (scoring)
//     sky_directions_S: [[x, y, z], ...]      GNSS: unit satellite directions in S
//     options: {<key>: <scalar>, ...}}}       the sensor's options, units in the key names
//   mission:                                  what the operator knows of the mission frame M
//     T_MB_launch: pose                       the launch pad: the body's pose in M
//     T_MS: {<name>: pose}                    surveyed reference frames of absolute sensors

#include <filesystem>
#include <map>
#include <optional>
#include <string>
#include <vector>

#include <Eigen/Geometry>

#include "core/lidar_beam_pattern.h"

namespace tofu::replay {

/// One entry of a sensor's `options:` block, as written, with where it sits.
struct CalibrationScalar {
  bool scalar = true;  ///< false: a list, a map or nothing (not a number, when one is asked)
  std::string text;
  int line = 0;    ///< 1-based
  int column = 0;  ///< 1-based
};

struct SensorCalibration {
  std::string type;  ///< empty when not stated (a user's calibration may omit it)
  std::string site;
  std::optional<Eigen::Isometry3d> T_Bs;       ///< nominal mount
  std::optional<Eigen::Isometry3d> true_T_Bs;  ///< only where a calibration error was set
  std::optional<Eigen::Isometry3d> true_T_WS;   ///< the true reference frame (scoring only)
  /// Whether an `options:` map is present; its entries by key (a nested map, such as a
  /// GNSS fix class's error model, is kept as a non-scalar entry, not parsed).
  bool has_options = false;
  std::map<std::string, CalibrationScalar> options;
  std::vector<Eigen::Vector3d> sky_directions_S;  ///< GNSS only
};

struct RunCalibration {
  bool present = false;  ///< false: no calibration.yaml (the fields are empty)
  std::string file;      ///< named in error messages
  std::map<std::string, Eigen::Isometry3d> mounts;
  std::map<std::string, SensorCalibration> sensors;
  /// `mission:` (absent in a user's calibration of a recorded log).
  std::optional<Eigen::Isometry3d> T_MB_launch;
  std::map<std::string, Eigen::Isometry3d> T_MS;

  /// sensors.<sensor>.options.<key> as a number; nullopt when the sensor, its options or
  /// the key is absent. Throws core::InputError at the value's line when it is not a number.
  std::optional<double> OptionNumber(const std::string& sensor, const std::string& key) const;

  /// The beam pattern of a lidar_odometry sensor, read by its field table; nullopt for
  /// another type or when its options do not state all six numbers. Throws
  /// core::InputError at the offending key on a malformed one (outside its limits, ranges
  /// or elevations out of order).
  std::optional<core::LidarBeamPattern> LidarBeams(const std::string& sensor) const;
};

/// Parses calibration.yaml's text; `file` names it in messages. Throws core::InputError
/// (file:line:column, key, expected form) on anything malformed.
RunCalibration ParseRunCalibration(const std::string& text, const std::string& file);

/// Reads `path` (bounded like every configuration file); a missing file gives
/// `present == false`, not an error.
RunCalibration ReadRunCalibration(const std::filesystem::path& path);

/// calibration.yaml as a user's estimator is told it: without the truth (the true mounts
/// `mounts:`, `true_T_B_s`, `true_T_WS`), which is for scoring only. Throws as the parser.
std::string CalibrationWithoutTruth(const std::string& text, const std::string& file);

}  // namespace tofu::replay
