#include "replay/run_format.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <iterator>
#include <variant>

#include <fmt/compile.h>
#include <fmt/format.h>

#include "core/error.h"
#include "core/lie.h"
#include "replay/csv_reader.h"

namespace tofu::replay {
namespace {

using F = SensorField;

// The tables. The IMU's first seven columns are EuRoC's imu0/data.csv, so that VIO tools
// read a stream; the precisions are 1 nrad/s, 0.1 µm/s², 1 µm, 1e-9 of a unit quaternion
// and six significant digits of covariance: far below every sensor's noise, so the
// estimator loses nothing by seeing the recorded value (DESIGN.md, "One code path").
// clang-format off
constexpr std::array kImuColumns = {
    SensorColumnGroup{F::kTimestamp, "timestamp", "", 0, "ns", false, -1, false, false, "time of validity in ns"},
    SensorColumnGroup{F::kGyro, "w_RS_S_", "xyz", 0, "rad s^-1", false, 9, false, false, "IMU angular rate in rad/s"},
    SensorColumnGroup{F::kAccel, "a_RS_S_", "xyz", 0, "m s^-2", false, 7, false, false, "IMU specific force in m/s^2"},
    SensorColumnGroup{F::kArrival, "arrival", "", 0, "ns", false, -1, false, false, "arrival in ns"},
    SensorColumnGroup{F::kGyroError, "err_w_", "xyz", 0, "rad s^-1", false, 9, false, true, "angular rate error in rad/s"},
    SensorColumnGroup{F::kAccelError, "err_a_", "xyz", 0, "m s^-2", false, 7, false, true, "specific force error in m/s^2"},
    SensorColumnGroup{F::kConditions, "conditions", "", 0, "", true, -1, false, true, "active conditions"},
    SensorColumnGroup{F::kFaults, "faults", "", 0, "", true, -1, false, true, "active faults"},
};

constexpr std::array kPoseColumns = {
    SensorColumnGroup{F::kTimestamp, "timestamp", "", 0, "ns", false, -1, false, false, "time of validity in ns"},
    SensorColumnGroup{F::kArrival, "arrival", "", 0, "ns", false, -1, false, false, "arrival in ns"},
    SensorColumnGroup{F::kPosition, "p_Ss_", "xyz", 0, "m", false, 6, false, false, "position of s in S in m"},
    SensorColumnGroup{F::kQuaternion, "q_Ss_", "wxyz", 0, "", false, 9, false, false, "attitude of s in S, Hamilton"},
    SensorColumnGroup{F::kVelocity, "v_s_", "xyz", 0, "m s^-1", false, 6, false, false, "twist: velocity of s in s, m/s"},
    SensorColumnGroup{F::kAngularRate, "omega_s_", "xyz", 0, "rad s^-1", false, 6, false, false, "twist: angular rate of s, rad/s"},
    SensorColumnGroup{F::kPoseCovariance, "cov_pose_", "", 6, "rad|m", false, 6, true, false, "pose covariance"},
    SensorColumnGroup{F::kTwistCovariance, "cov_twist_", "", 6, "m/s|rad/s", false, 6, true, false, "twist covariance"},
    SensorColumnGroup{F::kPositionError, "err_p_", "xyz", 0, "m", false, 6, false, true, "position error in m"},
    SensorColumnGroup{F::kRotationError, "err_theta_", "xyz", 0, "rad", false, 7, false, true, "rotation error in rad"},
    SensorColumnGroup{F::kConditions, "conditions", "", 0, "", true, -1, false, true, "active conditions"},
    SensorColumnGroup{F::kFaults, "faults", "", 0, "", true, -1, false, true, "active faults"},
};

constexpr std::array kPositionColumns = {
    SensorColumnGroup{F::kTimestamp, "timestamp", "", 0, "ns", false, -1, false, false, "time of validity in ns"},
    SensorColumnGroup{F::kArrival, "arrival", "", 0, "ns", false, -1, false, false, "arrival in ns"},
    SensorColumnGroup{F::kPosition, "p_Ss_", "xyz", 0, "m", false, 6, false, false, "position of s in S in m"},
    SensorColumnGroup{F::kPositionCovariance, "cov_p_", "", 3, "m^2", false, 6, true, false, "position covariance"},
    SensorColumnGroup{F::kPositionError, "err_p_", "xyz", 0, "m", false, 6, false, true, "position error in m"},
    SensorColumnGroup{F::kConditions, "conditions", "", 0, "", true, -1, false, true, "active conditions"},
    SensorColumnGroup{F::kFaults, "faults", "", 0, "", true, -1, false, true, "active faults"},
};
// clang-format on

// The most numbers a field holds: a 6 x 6 upper triangle.
constexpr int kMaxFieldValues = 21;
using FieldValues = std::array<double, kMaxFieldValues>;

static_assert(static_cast<std::size_t>(F::kFaults) + 1 == kSensorFieldCount);

// The group of `field` in the table of `kind`, which must have it.
const SensorColumnGroup& GroupOf(core::MeasurementKind kind, SensorField field) {
  const std::span<const SensorColumnGroup> groups = SensorColumnGroups(kind);
  return *std::find_if(groups.begin(), groups.end(),
                       [&](const SensorColumnGroup& g) { return g.field == field; });
}

template <int N>
void UpperTriangle(const Eigen::Matrix<double, N, N>& c, FieldValues& out) {
  int i = 0;
  for (int r = 0; r < N; ++r) {
    for (int k = r; k < N; ++k) out[i++] = c(r, k);
  }
}

template <int N>
Eigen::Matrix<double, N, N> FromUpperTriangle(const FieldValues& v) {
  Eigen::Matrix<double, N, N> c;
  int i = 0;
  for (int r = 0; r < N; ++r) {
    for (int k = r; k < N; ++k) c(r, k) = c(k, r) = v[i++];
  }
  return c;
}

void Put(const Eigen::Vector3d& v, FieldValues& out) {
  out[0] = v.x();
  out[1] = v.y();
  out[2] = v.z();
}

// The numbers of an IMU field; truth is needed for the error fields only.
void ImuValues(SensorField field, const core::ImuMeasurement& m, const core::ImuMeasurement* t,
               FieldValues& out) {
  switch (field) {
    case F::kGyro: return Put(m.gyro_I_radps, out);
    case F::kAccel: return Put(m.acc_I_mps2, out);
    case F::kGyroError: return Put(m.gyro_I_radps - t->gyro_I_radps, out);
    case F::kAccelError: return Put(m.acc_I_mps2 - t->acc_I_mps2, out);
    default: return;
  }
}

// The numbers of a pose field; false for a twist field of a pose without a twist.
bool PoseValues(SensorField field, const core::PoseMeasurement& m, const core::PoseMeasurement* t,
                FieldValues& out) {
  switch (field) {
    case F::kPosition:
      Put(m.p_Ss, out);
      return true;
    case F::kQuaternion: {
      // Stored with w >= 0 (DESIGN.md, Frames): q and -q are the same rotation.
      const Eigen::Quaterniond q = core::CanonicalQuat(m.q_Ss);
      out[0] = q.w();
      out[1] = q.x();
      out[2] = q.y();
      out[3] = q.z();
      return true;
    }
    case F::kVelocity:
      if (m.has_twist) Put(m.v_s_s_mps, out);
      return m.has_twist;
    case F::kAngularRate:
      if (m.has_twist) Put(m.omega_s_s_radps, out);
      return m.has_twist;
    case F::kPoseCovariance:
      UpperTriangle<6>(m.covariance, out);
      return true;
    case F::kTwistCovariance:
      if (m.has_twist) UpperTriangle<6>(m.twist_covariance, out);
      return m.has_twist;
    case F::kPositionError:
      Put(m.p_Ss - t->p_Ss, out);
      return true;
    case F::kRotationError:
      // The error as the covariance defines it: R_meas = R_true Exp(err_theta).
      Put(core::LogQuat(t->q_Ss.conjugate() * m.q_Ss), out);
      return true;
    default:
      return true;
  }
}

void PositionValues(SensorField field, const core::PositionMeasurement& m,
                    const core::PositionMeasurement* t, FieldValues& out) {
  switch (field) {
    case F::kPosition: return Put(m.p_Ss, out);
    case F::kPositionCovariance: return UpperTriangle<3>(m.covariance, out);
    case F::kPositionError: return Put(m.p_Ss - t->p_Ss, out);
    default: return;
  }
}

// The numbers of a numeric field of `measured`; false when the row leaves it empty.
bool ValuesOf(SensorField field, const core::Measurement& measured, const core::Measurement* truth,
              FieldValues& out) {
  if (const auto* imu = std::get_if<core::ImuMeasurement>(&measured)) {
    ImuValues(field, *imu, truth ? &std::get<core::ImuMeasurement>(*truth) : nullptr, out);
    return true;
  }
  if (const auto* pose = std::get_if<core::PoseMeasurement>(&measured)) {
    return PoseValues(field, *pose, truth ? &std::get<core::PoseMeasurement>(*truth) : nullptr, out);
  }
  PositionValues(field, std::get<core::PositionMeasurement>(measured),
                 truth ? &std::get<core::PositionMeasurement>(*truth) : nullptr, out);
  return true;
}

// The one printing of a number, shared by the writer and AsRecorded. The tables'
// precisions are compiled: a pose row is 61 numbers, and a format string parsed for each
// made `tofu run` of wall_sensors 9 % slower than one format call per row (compiled: 10 %
// faster).
template <typename Out>
Out FormatNumber(Out out, double value, const SensorColumnGroup& group) {
  if (group.exponent && group.decimals == 6) return fmt::format_to(out, FMT_COMPILE("{:.6e}"), value);
  if (!group.exponent && group.decimals == 6) return fmt::format_to(out, FMT_COMPILE("{:.6f}"), value);
  if (!group.exponent && group.decimals == 7) return fmt::format_to(out, FMT_COMPILE("{:.7f}"), value);
  if (!group.exponent && group.decimals == 9) return fmt::format_to(out, FMT_COMPILE("{:.9f}"), value);
  return group.exponent ? fmt::format_to(out, "{:.{}e}", value, group.decimals)
                        : fmt::format_to(out, "{:.{}f}", value, group.decimals);
}

double AsWritten(double value, const SensorColumnGroup& group) {
  std::array<char, 400> text;  // a double printed %f: at most 309 digits before the point
  const char* end = FormatNumber(text.data(), value, group);
  std::string error;
  return ParseCsvNumber(std::string_view(text.data(), static_cast<std::size_t>(end - text.data())),
                        &error)
      .value_or(std::nan(""));
}

Eigen::Vector3d Vector(const FieldValues& v) { return {v[0], v[1], v[2]}; }

// A measurement of `kind` from its fields' numbers as a reader has them: `get(field, out)`
// fills a field's numbers and returns false when the field is absent or empty. One
// assembly for the reader and AsRecorded, so that both normalise alike.
template <typename Get>
core::Measurement Assemble(core::MeasurementKind kind, const SensorCsvDefaults& defaults, Get&& get) {
  FieldValues v{};
  if (kind == core::MeasurementKind::kImu) {
    core::ImuMeasurement m;
    if (get(F::kGyro, v)) m.gyro_I_radps = Vector(v);
    if (get(F::kAccel, v)) m.acc_I_mps2 = Vector(v);
    return m;
  }
  if (kind == core::MeasurementKind::kPose) {
    core::PoseMeasurement m;
    if (get(F::kPosition, v)) m.p_Ss = Vector(v);
    if (get(F::kQuaternion, v)) m.q_Ss = QuaternionAsRead(v[0], v[1], v[2], v[3]);
    m.covariance = get(F::kPoseCovariance, v) ? FromUpperTriangle<6>(v) : defaults.pose_covariance;
    FieldValues w{};
    if (get(F::kVelocity, v) && get(F::kAngularRate, w)) {
      m.has_twist = true;
      m.v_s_s_mps = Vector(v);
      m.omega_s_s_radps = Vector(w);
      if (get(F::kTwistCovariance, v)) m.twist_covariance = FromUpperTriangle<6>(v);
    }
    return m;
  }
  core::PositionMeasurement m;
  if (get(F::kPosition, v)) m.p_Ss = Vector(v);
  m.covariance =
      get(F::kPositionCovariance, v) ? FromUpperTriangle<3>(v) : defaults.position_covariance;
  return m;
}

void AppendGroup(const SensorColumnGroup& group, const SensorCsvRow& row, std::string& out) {
  auto it = std::back_inserter(out);
  switch (group.field) {
    case F::kTimestamp: fmt::format_to(it, "{}", row.t_ns); return;
    case F::kArrival: fmt::format_to(it, ",{}", row.arrival_ns); return;
    case F::kConditions: out += ','; out += row.conditions; return;
    case F::kFaults: out += ','; out += row.faults; return;
    default: break;
  }
  FieldValues values;
  const int n = group.Count();
  if (!ValuesOf(group.field, *row.measured, row.truth, values)) {
    out.append(static_cast<std::size_t>(n), ',');
    return;
  }
  for (int i = 0; i < n; ++i) {
    out += ',';
    FormatNumber(it, values[static_cast<std::size_t>(i)], group);
  }
}

// The error of a field only partly in a header: the first of its keys that is missing.
core::InputError PartialField(const SensorColumnGroup& group, const std::vector<int>& columns,
                              const std::string& file) {
  int missing = 0;
  while (columns[static_cast<std::size_t>(missing)] >= 0) ++missing;
  if (group.triangle_size > 0) {
    const int n = group.triangle_size;
    return core::InputError(
        {file, 1, 0}, "",
        fmt::format("header: has {}* columns but not '{}': expected all {} upper-triangle "
                    "entries {}00..{}{}{}",
                    group.prefix, group.Key(missing), n * (n + 1) / 2, group.prefix, group.prefix,
                    n - 1, n - 1));
  }
  return core::InputError({file, 1, 0}, "",
                          fmt::format("header: missing column '{}' ({})", group.Key(missing),
                                      group.meaning));
}

core::MeasurementKind KindOfHeader(const std::vector<std::string>& keys, const std::string& file) {
  const auto has = [&](std::string_view key) {
    return std::find(keys.begin(), keys.end(), key) != keys.end();
  };
  if (has("w_RS_S_x")) return core::MeasurementKind::kImu;
  if (has("p_Ss_x") && has("q_Ss_w")) return core::MeasurementKind::kPose;
  if (has("p_Ss_x")) return core::MeasurementKind::kPosition;
  throw core::InputError({file, 1, 0}, "",
                         "header: cannot tell the stream kind: expected the columns "
                         "w_RS_S_x/y/z + a_RS_S_x/y/z (IMU), p_Ss_x/y/z + q_Ss_w/x/y/z (pose) "
                         "or p_Ss_x/y/z (position)");
}

// Whether a reader cannot do without the field: the time and the measurement itself.
bool Required(SensorField field) {
  return field == F::kTimestamp || field == F::kGyro || field == F::kAccel ||
         field == F::kPosition || field == F::kQuaternion;
}

// Whether the current row's twist is six empty fields; an InputError at the first empty
// field when only some are.
bool TwistIsEmpty(const CsvReader& csv, const SensorCsvColumns& columns) {
  int empty = 0;
  int first_empty = -1;
  for (const SensorField field : {F::kVelocity, F::kAngularRate}) {
    for (int i = 0; i < 3; ++i) {
      if (!csv.Empty(columns.Column(field, i))) continue;
      if (first_empty < 0) first_empty = columns.Column(field, i);
      ++empty;
    }
  }
  if (empty != 0 && empty != 6) {
    throw csv.Error(first_empty, "empty twist field, expected a number: the twist (v_s_*, "
                                 "omega_s_*) is six numbers or six empty fields");
  }
  return empty == 6;
}

}  // namespace

std::optional<SensorModel> SensorModelOfName(std::string_view type) {
  for (const SensorModel model : kSensorModels) {
    if (SensorModelName(model) == type) return model;
  }
  return std::nullopt;
}

core::MeasurementKind MeasurementKindOf(SensorModel model) {
  switch (model) {
    case SensorModel::kImu: return core::MeasurementKind::kImu;
    case SensorModel::kVio:
    case SensorModel::kLidarOdometry: return core::MeasurementKind::kPose;
    case SensorModel::kTotalStation:
    case SensorModel::kGnss: return core::MeasurementKind::kPosition;
  }
  return core::MeasurementKind::kPosition;
}

std::optional<core::MeasurementKind> MeasurementKindOfSensorType(std::string_view type) {
  const std::optional<SensorModel> model = SensorModelOfName(type);
  if (!model) return std::nullopt;
  return MeasurementKindOf(*model);
}

int SensorColumnGroup::Count() const {
  if (triangle_size > 0) return triangle_size * (triangle_size + 1) / 2;
  return axes.empty() ? 1 : static_cast<int>(axes.size());
}

std::string SensorColumnGroup::Key(int i) const {
  if (triangle_size > 0) {
    int r = 0;
    while (i >= triangle_size - r) i -= triangle_size - r++;
    return fmt::format("{}{}{}", prefix, r, r + i);
  }
  if (axes.empty()) return std::string(prefix);
  return fmt::format("{}{}", prefix, axes[static_cast<std::size_t>(i)]);
}

std::span<const SensorColumnGroup> SensorColumnGroups(core::MeasurementKind kind) {
  switch (kind) {
    case core::MeasurementKind::kImu: return kImuColumns;
    case core::MeasurementKind::kPose: return kPoseColumns;
    case core::MeasurementKind::kPosition: return kPositionColumns;
  }
  return {};
}

std::string SensorCsvHeader(core::MeasurementKind kind) {
  std::string header = "#";
  for (const SensorColumnGroup& group : SensorColumnGroups(kind)) {
    for (int i = 0; i < group.Count(); ++i) {
      if (header.size() > 1) header += ',';
      header += group.Key(i);
      if (!group.bare) header += fmt::format(" [{}]", group.unit);
    }
  }
  header += '\n';
  return header;
}

void AppendSensorCsvRow(const SensorCsvRow& row, std::string& out) {
  for (const SensorColumnGroup& group : SensorColumnGroups(core::MeasurementKindOf(*row.measured))) {
    AppendGroup(group, row, out);
  }
  out += '\n';
}

void AppendSensorCsvFields(const SensorCsvRow& row, std::span<const SensorField> fields,
                           std::string& out) {
  const core::MeasurementKind kind = core::MeasurementKindOf(*row.measured);
  for (const SensorField field : fields) AppendGroup(GroupOf(kind, field), row, out);
  out += '\n';
}

Eigen::Quaterniond QuaternionAsRead(double w, double x, double y, double z) {
  Eigen::Quaterniond q(w, x, y, z);
  const double norm = q.norm();
  if (std::isfinite(norm) && norm > 0.0) q.coeffs() /= norm;
  return q;
}

core::Measurement AsRecorded(const core::Measurement& value) {
  const core::MeasurementKind kind = core::MeasurementKindOf(value);
  return Assemble(kind, {}, [&](SensorField field, FieldValues& out) {
    FieldValues exact;
    if (!ValuesOf(field, value, nullptr, exact)) return false;
    const SensorColumnGroup& group = GroupOf(kind, field);
    for (int i = 0; i < group.Count(); ++i) {
      out[static_cast<std::size_t>(i)] = AsWritten(exact[static_cast<std::size_t>(i)], group);
    }
    return true;
  });
}

bool SensorCsvColumns::IsReadKey(std::string_view key) const {
  for (const SensorColumnGroup& group : SensorColumnGroups(kind_)) {
    if (group.label || key.substr(0, group.prefix.size()) != group.prefix) continue;
    for (int i = 0; i < group.Count(); ++i) {
      if (group.Key(i) == key) return true;
    }
  }
  return false;
}

bool SensorCsvColumns::IsLabelKey(std::string_view key) const {
  for (const SensorColumnGroup& group : SensorColumnGroups(kind_)) {
    if (!group.label || key.substr(0, group.prefix.size()) != group.prefix) continue;
    for (int i = 0; i < group.Count(); ++i) {
      if (group.Key(i) == key) return true;
    }
  }
  return false;
}

SensorCsvColumns LocateSensorCsvColumns(const std::vector<std::string>& keys,
                                        const std::string& file) {
  SensorCsvColumns located;
  located.kind_ = KindOfHeader(keys, file);
  for (const SensorColumnGroup& group : SensorColumnGroups(located.kind_)) {
    std::vector<int> columns;
    for (int i = 0; i < group.Count(); ++i) {
      const auto it = std::find(keys.begin(), keys.end(), group.Key(i));
      columns.push_back(it == keys.end() ? -1 : static_cast<int>(it - keys.begin()));
    }
    // A label is never read as a whole (only conditions and faults, one column each):
    // what a header has of it is taken as it is.
    const auto found = std::count_if(columns.begin(), columns.end(), [](int c) { return c >= 0; });
    const bool whole_or_absent = found == 0 || found == std::ssize(columns);
    if ((found == 0 && Required(group.field)) || (!whole_or_absent && !group.label)) {
      throw PartialField(group, columns, file);
    }
    located.columns_[static_cast<std::size_t>(group.field)] = std::move(columns);
  }
  // The twist is whole or absent: velocity and angular rate together.
  if (located.kind_ == core::MeasurementKind::kPose &&
      located.Has(F::kVelocity) != located.Has(F::kAngularRate)) {
    const SensorField missing = located.Has(F::kVelocity) ? F::kAngularRate : F::kVelocity;
    throw PartialField(GroupOf(located.kind_, missing),
                       located.columns_[static_cast<std::size_t>(missing)], file);
  }
  return located;
}

core::Measurement ReadSensorCsvRow(const CsvReader& csv, const SensorCsvColumns& columns,
                                   const SensorCsvDefaults& defaults) {
  bool twist_empty = false;
  return Assemble(columns.kind(), defaults, [&](SensorField field, FieldValues& out) {
    if (!columns.Has(field)) return false;
    // Asked for after the pose and its covariance, as a row is read left to right.
    if (field == F::kVelocity) twist_empty = TwistIsEmpty(csv, columns);
    const bool twist = field == F::kVelocity || field == F::kAngularRate ||
                       field == F::kTwistCovariance;
    if (twist && twist_empty) return false;
    const std::span<const int> c = columns.Columns(field);
    for (std::size_t i = 0; i < c.size(); ++i) out[i] = csv.Number(c[i]);
    return true;
  });
}

}  // namespace tofu::replay
