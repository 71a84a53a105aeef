#pragma once
// Recorded sensor streams read back from a directory into the measurement vocabulary of
// core/measurement.h, for replay through an estimator (`tofu estimate RUN_DIR`) and for
// evaluation against the ground truth recorded alongside. Two layouts, detected
// automatically:
//
// (a) a tofu run directory (DESIGN.md, "Run directory"), recognised by its sensors/
//     folder: sensors/<name>.csv, one stream each (sensors/clean/<name>.csv, the streams
//     before fault injection, with RecordedLogOptions::use_clean_streams), the stream's
//     kind told by its header columns; mounts and IMU noise densities from
//     calibration.yaml; ground truth from groundtruth.csv (T_WB, moved to the IMU frame).
//     The err_*, conditions and faults columns are ground-truth labels and never read.
// (b) a real-robot / EuRoC ASL layout: mav0/imu0/data.csv is the stream "imu"; every
//     *.tum file directly in the directory is a pose stream named after its stem (except
//     groundtruth.tum and estimate_*.tum, which tofu writes itself); ground truth from
//     mav0/state_groundtruth_estimate0/data.csv (the IMU frame S in the Vicon world R,
//     i.e. T_WI; its bias columns b_w_RS_S_*, b_a_RS_S_* when present). A calibration.yaml
//     there supplies mounts and IMU noise as in (a); EuRoC's own mav0/imu0/sensor.yaml
//     supplies the IMU noise densities (gyroscope_noise_density, gyroscope_random_walk,
//     accelerometer_noise_density, accelerometer_random_walk) when calibration.yaml does
//     not state them, and, without a calibration.yaml, the IMU mount T_BS (the other
//     streams and the ground truth then being of the body frame B).
//
// CSV columns are found by name (the header's text before " [unit]", without '#'; the
// sensor streams' columns are replay/run_format.h's), so extra columns are ignored.
// Reading is strict about form and lenient about values: a malformed file is a
// core::InputError naming file, line, column and the expected form, while a NaN/Inf value
// or an out-of-order stamp is passed through for the estimator to reject and count
// (DESIGN.md, "Errors").

#include <cstddef>
#include <filesystem>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include <Eigen/Core>
#include <Eigen/Geometry>

#include "core/measurement.h"
#include "core/time.h"
#include "replay/labels.h"
#include "replay/run_format.h"
#include "replay/trajectory_metrics.h"

namespace tofu::replay {

struct RecordedStream {
  std::string name;
  /// Told from the header (replay/run_format.h) or from the layout (EuRoC imu0, TUM).
  core::MeasurementKind kind = core::MeasurementKind::kImu;
  std::filesystem::path file;
  /// Mount frame s of the sensor in the IMU frame I: T_Is = T_BI^-1 T_Bs with the
  /// nominal mounts T_Bs of calibration.yaml (what an estimator is given, not the true
  /// ones); T_BI = identity without an IMU mount, T_Bs = identity without the sensor's.
  Eigen::Isometry3d T_Is = Eigen::Isometry3d::Identity();
  std::size_t rows = 0;  ///< data rows read (= measurements of this stream)
  /// Whether the samples carry their own covariance (a tofu sensor CSV's cov_* columns);
  /// false for a TUM file or a CSV without them, whose samples hold the default.
  bool covariance_stated = true;
  /// Odometry noise from calibration.yaml (sensors.<name>.options) when stated: white
  /// noise per sample (position_noise_m, rotation_noise_deg) and drift
  /// (position_random_walk_m_per_sqrtm; the rotation's, the largest of
  /// rotation_random_walk_deg_per_sqrtm, yaw_random_walk_deg_per_sqrtm and
  /// tilt_random_walk_deg_per_sqrtm). They set the weights of the between factors.
  std::optional<double> position_noise_m;
  std::optional<double> rotation_noise_rad;
  std::optional<double> position_random_walk_m_per_sqrtm;
  std::optional<double> rotation_random_walk_rad_per_sqrtm;
  /// A LiDAR odometry's degeneracy test from calibration.yaml (range_noise_m σ_r,
  /// degenerate_translation_threshold, degenerate_rotation_threshold_m2): a direction is
  /// degenerate when its information λ has λ σ_r² below the threshold, i.e. a conditional
  /// std above σ_r / √threshold (m, rad). What estimator::SensorSpec's
  /// unobserved_position_std_m and unobserved_rotation_std_rad take.
  std::optional<double> unobserved_position_std_m;
  std::optional<double> unobserved_rotation_std_rad;
  /// The true pose of the stream's reference frame S in W (calibration.yaml true_T_WS):
  /// scoring only, and the privileged information of the `naive` baseline.
  std::optional<Eigen::Isometry3d> true_T_WS;
  /// The reference frame S as surveyed in the mission frame M (calibration.yaml
  /// mission.T_MS): what an estimator is told of an absolute sensor's frame.
  std::optional<Eigen::Isometry3d> T_MS;
};

/// IMU noise densities as calibration.yaml gives them (the IMU sensor's options).
struct RecordedImuNoise {
  double gyro_noise_density_radps_per_sqrthz = 0.0;
  double accel_noise_density_mps2_per_sqrthz = 0.0;
  double gyro_random_walk_radps2_per_sqrthz = 0.0;
  double accel_random_walk_mps3_per_sqrthz = 0.0;
};

/// The IMU biases a ground truth carries (EuRoC: b_w_RS_S_*, b_a_RS_S_*).
struct GroundTruthBias {
  Eigen::Vector3d b_g_radps = Eigen::Vector3d::Zero();
  Eigen::Vector3d b_a_mps2 = Eigen::Vector3d::Zero();
};

struct RecordedLogOptions {
  /// Layout (a): read sensors/clean/<name>.csv (the un-faulted streams) instead.
  bool use_clean_streams = false;
  /// Without an IMU stream, ReadRecordedLog throws (an estimator replay needs one); false
  /// reads the other streams anyway (imu_stream is then empty).
  bool require_imu = true;
  /// Covariance of [delta_theta; delta_p] (rad^2, m^2) for pose streams that carry none
  /// (TUM files, CSVs without cov_pose_* columns).
  Eigen::Matrix<double, 6, 6> default_pose_covariance =
      (Eigen::Matrix<double, 6, 1>() << 0.01 * 0.01, 0.01 * 0.01, 0.01 * 0.01, 0.02 * 0.02,
       0.02 * 0.02, 0.02 * 0.02)
          .finished()
          .asDiagonal();
  /// Covariance of positions (m^2) for position streams without cov_p_* columns.
  Eigen::Matrix3d default_position_covariance = 0.02 * 0.02 * Eigen::Matrix3d::Identity();
  /// False: the streams' descriptions, calibration and ground truth only, no samples
  /// (scoring a run whose estimators ran in the loop).
  bool read_measurements = true;
};

struct RecordedLog {
  std::filesystem::path directory;
  std::string imu_stream;               ///< name of the IMU stream (empty only if not required)
  std::vector<RecordedStream> streams;  ///< sorted by name
  /// Every sample of every stream in arrival order (what an online estimator sees), ties
  /// broken by stream name, then time of validity, then row. t_ns = time of validity.
  std::vector<core::StampedMeasurement> measurements;
  std::vector<core::Time> arrival_ns;   ///< parallel to measurements
  /// From calibration.yaml (the IMU sensor's options) when all four densities are there.
  std::optional<RecordedImuNoise> imu_noise;
  /// tofu's simulated IMU reports each interval's average (layout (a)); recorded real
  /// IMUs (EuRoC's ADIS16448) are taken as instantaneous samples.
  bool imu_samples_are_interval_averages = false;
  /// Pose of the IMU frame I in W, in file order; empty without ground truth. Layout (a):
  /// T_WI = T_WB T_BI with the IMU's true mount (true_T_Bs when calibration.yaml has one).
  /// Kept as PoseSample, the form scoring reads, so an hour of it is never copied.
  std::vector<PoseSample> ground_truth;
  /// One per ground_truth sample when the ground truth carries both biases; else empty
  /// (kept apart: optional biases in every sample doubled an hour's 46 MB).
  std::vector<GroundTruthBias> ground_truth_biases;
  /// Layout (a): labels.csv (conditions and scheduled faults), by time; empty otherwise.
  std::vector<LabelEvent> labels;
  std::vector<std::string> notes;       ///< what was read and what was assumed
  /// calibration.yaml's text ("" without one): what a user's estimator is told.
  std::string calibration_yaml;
  /// The IMU's pose in M at launch (mission.T_MB_launch through the nominal IMU mount);
  /// unset when calibration.yaml states no launch pad (a recorded real log).
  std::optional<Eigen::Isometry3d> T_MI_launch;
};

/// Reads the recorded streams of `directory` (layout (a) or (b) above).
///
/// Pose rows: twist (v_s_*, omega_s_*) present and non-empty -> has_twist; covariances
/// from the cov_pose_ij / cov_twist_ij / cov_p_ij columns (upper triangle, row-major:
/// replay/run_format.h), else the options' defaults. Quaternions are normalised when
/// finite and non-zero. Arrival from the `arrival` column when present, else t.
///
/// Throws core::InputError (file, 1-based line and column, column name, expected form)
/// for a missing directory, no recognisable stream, no IMU stream (unless
/// !options.require_imu), a missing or unknown header, a row whose field count differs
/// from the header's, an empty or non-numeric field (timestamps: integers in ns; TUM:
/// decimal seconds), and a malformed calibration.yaml. Empty streams are allowed.
RecordedLog ReadRecordedLog(const std::filesystem::path& directory,
                            const RecordedLogOptions& options = {});

/// A run directory's streams as ReadRecordedLog describes them (kinds, the IMU, mounts,
/// odometry noise, true reference frames, IMU noise), from the kinds and the text of the
/// calibration.yaml the run will write, without samples. The run loop configures its
/// in-loop estimators from this, so that `tofu estimate` on the written directory
/// configures them identically (same parser, same rounding of the file's numbers).
RecordedLog DescribeRunStreams(std::vector<std::pair<std::string, core::MeasurementKind>> streams,
                               const std::string& calibration_yaml,
                               const std::filesystem::path& directory);

}  // namespace tofu::replay
