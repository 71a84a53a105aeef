#pragma once
// The format of a run directory's sensor streams (sensors/<name>.csv and
// sensors/clean/<name>.csv, DESIGN.md "Run directory"): for each kind of stream, its
// columns in order, each with its key, unit and printing precision. One table serves every
// side of the file: the recorder writes rows with it, the run loop hands its in-loop
// estimators each value as a row holds it (AsRecorded: the estimator in the flight must see
// what `tofu estimate` reads, or a recorded run does not reproduce it), and the readers
// (ReadRecordedLog, the renderer, the MCAP export) find their columns through it. A column
// renamed or printed with other digits on one side only cannot happen.
//
// Built on core::Measurement alone: no simulator. The labels' texts (conditions, faults)
// are the caller's; this module only places them.

#include <array>
#include <cstddef>
#include <cstdint>
#include <optional>
#include <span>
#include <string>
#include <string_view>
#include <vector>

#include "core/measurement.h"
#include "core/time.h"

namespace tofu::replay {

class CsvReader;

/// The sensor models a run records, by the `type:` the scenario and calibration.yaml give
/// each sensor.
enum class SensorModel : uint8_t { kImu, kVio, kLidarOdometry, kTotalStation, kGnss };

/// Every model, in the order of its enum value.
inline constexpr std::array<SensorModel, 5> kSensorModels = {
    SensorModel::kImu, SensorModel::kVio, SensorModel::kLidarOdometry, SensorModel::kTotalStation,
    SensorModel::kGnss};

/// The `type:` of a model: "imu", "vio", "lidar_odometry", "total_station", "gnss".
constexpr std::string_view SensorModelName(SensorModel model) {
  switch (model) {
    case SensorModel::kImu: return "imu";
    case SensorModel::kVio: return "vio";
    case SensorModel::kLidarOdometry: return "lidar_odometry";
    case SensorModel::kTotalStation: return "total_station";
    case SensorModel::kGnss: return "gnss";
  }
  return "unknown";
}

/// The model of a `type:`; nullopt for any other name.
std::optional<SensorModel> SensorModelOfName(std::string_view type);

/// The kind of stream a model records: the IMU's; poses (VIO, LiDAR odometry); positions
/// (total station, GNSS).
core::MeasurementKind MeasurementKindOf(SensorModel model);

/// The kind of stream a sensor of `type:` records; nullopt for an unknown type.
std::optional<core::MeasurementKind> MeasurementKindOfSensorType(std::string_view type);

/// What a group of columns holds.
enum class SensorField : uint8_t {
  kTimestamp,           ///< time of validity [ns]
  kArrival,             ///< when the sample reached its consumers [ns]
  kGyro,                ///< IMU angular rate omega_WI_I [rad/s]
  kAccel,               ///< IMU specific force f_I [m/s^2]
  kPosition,            ///< p_Ss [m]
  kQuaternion,          ///< q_Ss, w x y z, w >= 0
  kVelocity,            ///< twist: v_s_s [m/s] (empty: none reported)
  kAngularRate,         ///< twist: omega_s_s [rad/s] (empty: none reported)
  kPoseCovariance,      ///< [delta_theta; delta_p] (rad, m), upper triangle
  kTwistCovariance,     ///< [v; omega], upper triangle (empty: no twist)
  kPositionCovariance,  ///< p_Ss [m^2], upper triangle
  kGyroError,           ///< label: measured - true angular rate [rad/s]
  kAccelError,          ///< label: measured - true specific force [m/s^2]
  kPositionError,       ///< label: measured - true p_Ss [m]
  kRotationError,       ///< label: err_theta with R_meas = R_true Exp(err_theta) [rad]
  kConditions,          ///< label: the conditions active at the sample, '|'-separated
  kFaults,              ///< label: the scheduled faults active at the sample, '|'-separated
};
inline constexpr std::size_t kSensorFieldCount = 17;

/// The columns of one field: keys <prefix><axis> for each character of `axes`, or
/// <prefix><r><k> over the upper triangle of an N x N matrix (row by row), or the bare
/// prefix for a single column.
struct SensorColumnGroup {
  SensorField field;
  std::string_view prefix;
  std::string_view axes;          ///< "xyz", "wxyz"; empty for one column or a triangle
  int triangle_size;              ///< N of the upper triangle; 0 otherwise
  std::string_view unit;          ///< the header's "[unit]" (empty brackets for none)
  bool bare;                      ///< the header names the column without brackets
  int decimals;                   ///< digits printed after the point; -1: integer or text
  bool exponent;                  ///< printed as d.dddddde±xx
  bool label;                     ///< ground truth the recorder adds; no estimator reads it
  std::string_view meaning;       ///< what a reader needs it for, quoted in messages

  /// Number of columns of the group.
  int Count() const;
  /// Key of its i-th column (0 <= i < Count()).
  std::string Key(int i) const;
};

/// The columns of a stream of `kind`, in the order they are written.
std::span<const SensorColumnGroup> SensorColumnGroups(core::MeasurementKind kind);

/// The form of a sensor CSV's header, as messages quote it.
inline constexpr std::string_view kSensorCsvForm =
    "#timestamp [ns],w_RS_S_x [rad s^-1],... (IMU) or #timestamp [ns],arrival [ns],"
    "p_Ss_x [m],... (pose, position)";

/// The header line of a stream of `kind`, newline included: "#timestamp [ns],...\n".
std::string SensorCsvHeader(core::MeasurementKind kind);

/// What one row of a sensor CSV is made of. `measured` and `truth` hold the same
/// alternative; the label columns (err_*) are measured - truth.
struct SensorCsvRow {
  core::Time t_ns = 0;
  core::Time arrival_ns = 0;
  const core::Measurement* measured = nullptr;
  const core::Measurement* truth = nullptr;
  std::string_view conditions;
  std::string_view faults;
};

/// Appends the row, newline included, to `out`, each value at its column's precision; a
/// pose without a twist leaves the twist and its covariance empty.
void AppendSensorCsvRow(const SensorCsvRow& row, std::string& out);

/// Appends only `fields` of the row, in that order, comma-separated, and a newline: the
/// same values at the same precisions in another file's layout (EuRoC's imu0/data.csv is
/// timestamp, gyro, accel). `fields` must begin with kTimestamp.
void AppendSensorCsvFields(const SensorCsvRow& row, std::span<const SensorField> fields,
                           std::string& out);

/// A quaternion as every reader of a run directory takes it: normalised when its norm is
/// finite and non-zero, else as written (the estimator rejects and counts it).
Eigen::Quaterniond QuaternionAsRead(double w, double x, double y, double z);

/// `value` as its row in a sensor CSV holds it: each number printed as AppendSensorCsvRow
/// prints it and parsed back as the reader parses it, the quaternion normalised as the
/// reader normalises it. What the run loop gives its in-loop consumers.
core::Measurement AsRecorded(const core::Measurement& value);

/// Where a sensor CSV's columns are, found by key in its header.
class SensorCsvColumns {
 public:
  core::MeasurementKind kind() const { return kind_; }
  /// Column index of the field's i-th column; -1 when the header does not have it.
  int Column(SensorField field, int i = 0) const {
    const std::vector<int>& c = columns_[static_cast<std::size_t>(field)];
    return c.empty() ? -1 : c[static_cast<std::size_t>(i)];
  }
  /// Whether the header has the field's columns (all of them: a field is whole or absent).
  bool Has(SensorField field) const { return Column(field) >= 0; }
  /// The field's columns in order (-1 where missing); empty when the kind has no such field.
  std::span<const int> Columns(SensorField field) const {
    return columns_[static_cast<std::size_t>(field)];
  }
  /// Whether the column with this key is one of the kind's columns that estimators read
  /// (the label columns and unknown ones are not).
  bool IsReadKey(std::string_view key) const;
  /// Whether the column with this key is a ground-truth label of the kind.
  bool IsLabelKey(std::string_view key) const;

 private:
  friend SensorCsvColumns LocateSensorCsvColumns(const std::vector<std::string>&,
                                                 const std::string&);
  core::MeasurementKind kind_ = core::MeasurementKind::kImu;
  std::array<std::vector<int>, kSensorFieldCount> columns_;  // by SensorField
};

/// The kind of a sensor CSV told from its header keys (IMU: w_RS_S_x; pose: p_Ss_x and
/// q_Ss_w; position: p_Ss_x), and where each of its fields is. Throws core::InputError at
/// `file`'s header naming the column and the expected form when the kind cannot be told, a
/// field the kind needs is missing (timestamp, the measurement itself), or a field that
/// may be absent (the twist, a covariance) is only partly there. Labels are optional,
/// column by column.
SensorCsvColumns LocateSensorCsvColumns(const std::vector<std::string>& keys,
                                        const std::string& file);

/// What a reader assumes for a row whose header has no covariance columns.
struct SensorCsvDefaults {
  Eigen::Matrix<double, 6, 6> pose_covariance = Eigen::Matrix<double, 6, 6>::Identity();
  Eigen::Matrix3d position_covariance = Eigen::Matrix3d::Identity();
};

/// The measurement of the reader's current row. A pose's twist is six numbers or six
/// empty fields (else an InputError at the first empty one); a twist without covariance
/// columns keeps PoseMeasurement's default. Throws what CsvReader::Number throws.
core::Measurement ReadSensorCsvRow(const CsvReader& csv, const SensorCsvColumns& columns,
                                   const SensorCsvDefaults& defaults);

}  // namespace tofu::replay
