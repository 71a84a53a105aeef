#pragma once
// What the renderer draws, read back from a run directory (README "Run directory"):
// ground truth, the sensors' measurements mapped into W, labels, collisions, and, when
// `tofu estimate` or the consensus evaluation wrote them, each method's estimate, its
// decisions, consistency values and errors. Files that a run may lack (estimates,
// decisions, consistency, errors) are optional; a file that is there but malformed is a
// core::InputError naming file, line and column.

#include <cstdint>
#include <filesystem>
#include <map>
#include <optional>
#include <string>
#include <vector>

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <nlohmann/json_fwd.hpp>

#include "core/time.h"
#include "replay/run_calibration.h"

namespace tofu::renders {

/// A pose of frame B (or I) in W at one instant.
struct TimedPose {
  core::Time t_ns = 0;
  Eigen::Vector3d p_W = Eigen::Vector3d::Zero();
  Eigen::Quaterniond q_W = Eigen::Quaterniond::Identity();
  /// The pose as a transform (T_WB, or T_LI for an estimate).
  Eigen::Isometry3d T_W() const;
};

/// Pose at `t_ns` by linear interpolation of position and slerp of attitude; clamped to
/// the first/last sample outside the span. `poses` sorted by time, not empty.
TimedPose InterpolatePose(const std::vector<TimedPose>& poses, core::Time t_ns);

/// One sensor stream, each sample mapped into W: p_W = T_WS p_Ss (the mount site s).
struct SensorTrack {
  std::string name;
  std::string type;  ///< imu, vio, lidar_odometry, total_station, gnss
  std::string site;  ///< robot mount site
  Eigen::Isometry3d true_T_WS = Eigen::Isometry3d::Identity();
  std::vector<core::Time> t_ns;
  std::vector<Eigen::Vector3d> p_W;
  std::vector<std::string> conditions;  ///< '|'-joined, per sample
  std::vector<std::string> faults;      ///< '|'-joined, per sample
};

/// labels.csv: a condition or fault of a sensor starts or ends.
struct LabelRow {
  core::Time t_ns = 0;
  std::string sensor;
  std::string label;
  std::string source;  ///< "condition" or "fault"
  bool active = false;
};

struct CollisionRow {
  core::Time t_ns = 0;
  std::string robot_geom;
  std::string structure_geom;
};

/// One method's estimate as the ghost robot: T_WB = T_WL T_LI(t) T_IB.
struct MethodEstimate {
  std::string method;  ///< "single:vio", "consensus", ...
  std::vector<TimedPose> T_WB;  ///< valid samples only, time order
  std::vector<std::string> fused;  ///< per sample of T_WB: '+'-joined fused sensors
  Eigen::Isometry3d T_WL = Eigen::Isometry3d::Identity();
  std::string alignment_source;  ///< "T_WL of estimate_<m>.json" or "first valid sample"
};

/// decisions.csv: one consensus evaluation.
struct DecisionRow {
  core::Time t_ns = 0;
  std::string method;
  std::vector<std::string> fused;
  std::vector<std::string> excluded;
  std::vector<std::string> unavailable;
  std::string reason;
};

/// consistency[_<method>].csv: one metric value of a pair ("a-b", b may be "local").
struct ConsistencyRow {
  core::Time t_ns = 0;
  std::string a;
  std::string b;
  std::string metric;
  double value = 0.0;  ///< NaN when unavailable
};

/// errors.csv or estimate_<method>_errors.csv: one error sample of a method.
struct ErrorRow {
  core::Time t_ns = 0;
  std::string method;
  double position_error_m = 0.0;
  double rotation_error_deg = 0.0;
};

/// A LiDAR's beams, to draw where they hit.
struct LidarGeometry {
  std::string site;
  core::LidarBeamPattern beams;
};

/// A GNSS antenna's sky: the satellites' directions, to draw which are blocked.
struct SkyGeometry {
  std::string site;
  Eigen::Isometry3d T_WS = Eigen::Isometry3d::Identity();
  std::vector<Eigen::Vector3d> directions_S;
  double ray_length_m = 200.0;  ///< an obstacle farther than this does not block
};

struct RunData {
  std::filesystem::path directory;
  std::string scenario_name;
  std::string world;
  std::string robot = "omav";
  std::vector<TimedPose> groundtruth;  ///< T_WB, time order, not empty
  /// Mount sites of calibration.yaml (`mounts:`): T_Bs.
  std::map<std::string, Eigen::Isometry3d> mounts;
  /// The IMU's nominal mount T_BI (the frame the estimates are of).
  Eigen::Isometry3d T_BI = Eigen::Isometry3d::Identity();
  std::vector<SensorTrack> sensors;  ///< sorted by name; IMU streams excluded
  /// calibration.yaml as replay reads it: the sensors' geometry is drawn from it on demand
  /// (LidarGeometries, SkyGeometries), so a layer not asked for is never read.
  replay::RunCalibration calibration;
  std::vector<LabelRow> labels;
  std::vector<CollisionRow> collisions;
  /// Sorted by method name, then the closed-loop flights' true paths ("flown on <m>").
  std::vector<MethodEstimate> estimates;
  std::vector<DecisionRow> decisions;
  /// Consistency rows by method ("" = the run's consistency.csv).
  std::map<std::string, std::vector<ConsistencyRow>> consistency;
  std::vector<ErrorRow> errors;
  std::vector<std::string> notes;  ///< what was read and what was assumed

  core::Time start_ns() const { return groundtruth.front().t_ns; }
  core::Time end_ns() const { return groundtruth.back().t_ns; }
  const SensorTrack* FindSensor(const std::string& name) const;
  /// Whether label (sensor, label) is active at t (the last transition at or before t).
  bool LabelActive(const std::string& sensor, const std::string& label, core::Time t_ns) const;
  /// Labels of `sensor` from `source` ("fault" or "condition") active at t, sorted.
  std::vector<std::string> ActiveLabels(const std::string& sensor, const std::string& source,
                                        core::Time t_ns) const;
  /// Faults of `sensor` active at t.
  std::vector<std::string> ActiveFaults(const std::string& sensor, core::Time t_ns) const {
    return ActiveLabels(sensor, "fault", t_ns);
  }
};

/// The LiDARs' beam patterns (sensors of type lidar_odometry), in sensor name order.
/// Throws core::InputError at the option's line for a malformed pattern.
std::vector<LidarGeometry> LidarGeometries(const RunData& run);

/// The GNSS antennas' skies, in sensor name order. Throws core::InputError for a GNSS
/// sensor without `sky_directions_S` (a run directory written before runs recorded it:
/// run the scenario again to draw its sky).
std::vector<SkyGeometry> SkyGeometries(const RunData& run);

/// Reads a run directory. Required: scenario.yaml (keys name, world, robot),
/// groundtruth.csv, calibration.yaml. Optional: sensors/*.csv, labels.csv, summary.json,
/// estimate_*.csv/.json, decisions.csv, consistency*.csv, errors.csv. Throws
/// core::InputError for a missing directory or required file and for malformed content.
RunData ReadRunData(const std::filesystem::path& directory);

/// A JSON file of a run directory (summary.json, estimate_<m>.json, ...); malformed JSON is
/// a core::InputError naming file:line:column.
nlohmann::json ReadRunJson(const std::filesystem::path& path);

/// The sensor streams of a run: sensors/*.csv (not sensors/clean/), sorted; empty without
/// sensors/.
std::vector<std::filesystem::path> SensorCsvFiles(const std::filesystem::path& run_dir);

/// The closed-loop flights of a run: closed_loop/<stem>/ folders that hold a
/// groundtruth.csv, sorted; empty without closed_loop/.
std::vector<std::filesystem::path> ClosedLoopFlightDirs(const std::filesystem::path& run_dir);

}  // namespace tofu::renders
