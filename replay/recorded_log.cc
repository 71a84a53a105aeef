#include "replay/recorded_log.h"

#include <algorithm>
#include <array>
#include <cerrno>
#include <charconv>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstring>
#include <map>
#include <string_view>
#include <system_error>
#include <utility>
#include <variant>

#include <fmt/format.h>
#include <fmt/ranges.h>
#include <yaml-cpp/yaml.h>

#include "core/error.h"
#include "core/file_io.h"
#include "core/units.h"
#include "replay/csv_reader.h"
#include "replay/run_calibration.h"
#include "replay/trajectory_metrics.h"
#include "replay/yaml_fields.h"

namespace tofu::replay {
namespace {

namespace fs = std::filesystem;
using core::InputError;
using core::Time;

// ---- text and CSV ----

// Columns of a 3-vector "<prefix>x,<prefix>y,<prefix>z" (or w first for quaternions).
template <size_t N>
std::array<int, N> RequireAll(const CsvReader& csv, std::string_view prefix,
                              std::string_view suffixes, std::string_view what) {
  std::array<int, N> columns{};
  for (size_t i = 0; i < N; ++i) {
    columns[i] = csv.Require(fmt::format("{}{}", prefix, suffixes[i]), what);
  }
  return columns;
}

// Where the rows of a stream go while reading.
struct Sink {
  std::vector<core::StampedMeasurement>* measurements;
  std::vector<Time>* arrival_ns;
};

// What ReadSensorCsv found.
struct SensorCsvContents {
  core::MeasurementKind kind = core::MeasurementKind::kImu;
  size_t rows = 0;
  bool covariance_stated = true;  ///< false: no covariance columns, the default used
};

// Notes on what ReadSensorCsv assumed and on the columns it left unread.
void NoteSensorCsv(const CsvReader& csv, const SensorCsvColumns& columns, const std::string& name,
                   bool defaulted_covariance, bool defaulted_twist_covariance,
                   std::vector<std::string>& notes) {
  if (!columns.Has(SensorField::kArrival)) {
    notes.push_back(fmt::format("{}: no arrival column, arrival = t", name));
  }
  if (defaulted_covariance) {
    notes.push_back(fmt::format("{}: no covariance columns, the default covariance is used", name));
  }
  if (defaulted_twist_covariance) {
    notes.push_back(fmt::format("{}: twist without cov_twist_* columns, identity assumed", name));
  }
  std::vector<std::string> labels;
  std::vector<std::string> unknown;
  for (const std::string& key : csv.keys()) {
    if (columns.IsReadKey(key)) continue;
    (columns.IsLabelKey(key) ? labels : unknown).push_back(key);
  }
  if (!labels.empty()) {
    notes.push_back(fmt::format("{}: ground-truth label columns not read ({} columns: err_*, "
                                "conditions, faults)",
                                name, labels.size()));
  }
  if (!unknown.empty()) {
    notes.push_back(fmt::format("{}: unknown columns ignored: {}", name, fmt::join(unknown, ", ")));
  }
}

// One sensors/<name>.csv (or EuRoC imu0/data.csv): its kind from the header, every row
// into `sink`. Returns the kind and the row count; notes what it ignored.
SensorCsvContents ReadSensorCsv(const fs::path& path, const std::string& name,
                                const RecordedLogOptions& options, Sink sink,
                                std::vector<std::string>& notes) {
  CsvReader csv(path, std::string(kSensorCsvForm));
  const SensorCsvColumns columns = LocateSensorCsvColumns(csv.keys(), csv.name());
  const int t_col = columns.Column(SensorField::kTimestamp);
  const int arrival_col = columns.Column(SensorField::kArrival);
  const SensorCsvDefaults defaults{options.default_pose_covariance,
                                   options.default_position_covariance};
  const size_t reserve = options.read_measurements ? csv.RowsUpperBound() : 0;
  sink.measurements->reserve(sink.measurements->size() + reserve);
  sink.arrival_ns->reserve(sink.arrival_ns->size() + reserve);
  size_t rows = 0;
  bool twist_read = false;
  while (options.read_measurements && csv.Next()) {
    const Time t = csv.Integer(t_col);
    core::Measurement value = ReadSensorCsvRow(csv, columns, defaults);
    if (const auto* pose = std::get_if<core::PoseMeasurement>(&value)) twist_read |= pose->has_twist;
    const Time arrival = arrival_col >= 0 ? csv.Integer(arrival_col) : t;
    sink.measurements->push_back({name, t, std::move(value)});
    sink.arrival_ns->push_back(arrival);
    ++rows;
  }

  const core::MeasurementKind kind = columns.kind();
  const SensorField covariance =
      kind == core::MeasurementKind::kPose ? SensorField::kPoseCovariance : SensorField::kPositionCovariance;
  const bool defaulted_covariance = kind != core::MeasurementKind::kImu && rows > 0 && !columns.Has(covariance);
  const bool defaulted_twist_covariance = twist_read && !columns.Has(SensorField::kTwistCovariance);
  NoteSensorCsv(csv, columns, name, defaulted_covariance, defaulted_twist_covariance, notes);
  return {kind, rows, !defaulted_covariance};
}

// Ground truth CSV: T_WX from the columns <p>_x.. and <q>_w.., composed with T_XI, into
// log.ground_truth (and its biases when the file has both triples).
void ReadGroundTruthCsv(const fs::path& path, std::string_view p_prefix, std::string_view q_prefix,
                        const Eigen::Isometry3d& T_XI, RecordedLog& log) {
  CsvReader csv(path, fmt::format("#timestamp [ns],{}x [m],{}y [m],{}z [m],{}w [],{}x [],{}y [],"
                                "{}z [],...",
                                p_prefix, p_prefix, p_prefix, q_prefix, q_prefix, q_prefix,
                                q_prefix));
  const int t_col = csv.Require("timestamp", "time in ns");
  const auto p = RequireAll<3>(csv, p_prefix, "xyz", "ground-truth position in m");
  const auto q = RequireAll<4>(csv, q_prefix, "wxyz", "ground-truth attitude, Hamilton");
  const Eigen::Quaterniond q_XI(T_XI.linear());
  const bool identity = T_XI.isApprox(Eigen::Isometry3d::Identity(), 0.0);
  // Bias columns (EuRoC's estimate of the IMU biases) when all three of a kind are there.
  const auto optional_triple = [&](std::string_view prefix) -> std::optional<std::array<int, 3>> {
    std::array<int, 3> cols{};
    for (int i = 0; i < 3; ++i) {
      cols[i] = csv.Find(fmt::format("{}{}", prefix, "xyz"[i]));
      if (cols[i] < 0) return std::nullopt;
    }
    return cols;
  };
  const std::optional<std::array<int, 3>> b_g = optional_triple("b_w_RS_S_");
  const std::optional<std::array<int, 3>> b_a = optional_triple("b_a_RS_S_");
  const auto triple = [&](const std::array<int, 3>& cols) {
    return Eigen::Vector3d(csv.Number(cols[0]), csv.Number(cols[1]), csv.Number(cols[2]));
  };
  std::vector<PoseSample>& out = log.ground_truth;
  out.clear();
  out.reserve(csv.RowsUpperBound());
  log.ground_truth_biases.clear();
  if (b_g && b_a) log.ground_truth_biases.reserve(csv.RowsUpperBound());
  while (csv.Next()) {
    PoseSample g;
    g.t_ns = csv.Integer(t_col);
    if (b_g && b_a) log.ground_truth_biases.push_back({triple(*b_g), triple(*b_a)});
    const Eigen::Vector3d p_WX(csv.Number(p[0]), csv.Number(p[1]), csv.Number(p[2]));
    const Eigen::Quaterniond q_WX =
        QuaternionAsRead(csv.Number(q[0]), csv.Number(q[1]), csv.Number(q[2]), csv.Number(q[3]));
    if (identity) {
      g.p = p_WX;
      g.q = q_WX;
    } else {
      g.p = p_WX + q_WX * T_XI.translation();
      g.q = (q_WX * q_XI).normalized();
    }
    if (g.q.w() < 0.0) g.q.coeffs() *= -1.0;
    out.push_back(g);
  }
}

// labels.csv of a run directory (harness/run_directory.cc LabelsCsv).
std::vector<LabelEvent> ReadLabelsCsv(const fs::path& path) {
  CsvReader csv(path, "#timestamp [ns],sensor,label,source,active");
  const int t_col = csv.Require("timestamp", "time in ns");
  const int sensor_col = csv.Require("sensor", "the sensor's name");
  const int label_col = csv.Require("label", "a condition or fault kind");
  const int source_col = csv.Require("source", "condition or fault");
  const int active_col = csv.Require("active", "1 (starts) or 0 (ends)");
  std::vector<LabelEvent> out;
  out.reserve(csv.RowsUpperBound());
  while (csv.Next()) {
    LabelEvent e;
    e.t_ns = csv.Integer(t_col);
    e.sensor = std::string(csv.Text(sensor_col));
    e.label = std::string(csv.Text(label_col));
    e.source = std::string(csv.Text(source_col));
    if (e.sensor.empty() || e.label.empty()) {
      throw csv.Error(e.sensor.empty() ? sensor_col : label_col, "expected a name, got nothing");
    }
    if (e.source != "condition" && e.source != "fault") {
      throw csv.Error(source_col, fmt::format("expected condition or fault, got {}",
                                              CsvQuoted(e.source)));
    }
    const std::string_view active = csv.Text(active_col);
    if (active != "0" && active != "1") {
      throw csv.Error(active_col, fmt::format("expected 1 or 0, got {}", CsvQuoted(active)));
    }
    e.active = active == "1";
    if (!out.empty() && e.t_ns < out.back().t_ns) {
      throw csv.Error(t_col, fmt::format("timestamps must not decrease ({} after {})", e.t_ns,
                                         out.back().t_ns));
    }
    out.push_back(std::move(e));
  }
  return out;
}

// ---- calibration.yaml ----

// The four IMU noise densities from sensors.<imu>.options; nullopt (and a note) if absent.
std::optional<RecordedImuNoise> ReadImuNoise(const RunCalibration& cal, const std::string& imu,
                                             std::vector<std::string>& notes) {
  const auto it = cal.sensors.find(imu);
  if (it == cal.sensors.end() || !it->second.has_options) {
    notes.push_back(fmt::format("IMU noise densities: none (no sensors.{}.options in "
                                "calibration.yaml)",
                                imu));
    return std::nullopt;
  }
  RecordedImuNoise noise;
  const std::array<std::pair<const char*, double*>, 4> keys = {
      {{"gyro_noise_density_radps_per_sqrthz", &noise.gyro_noise_density_radps_per_sqrthz},
       {"accel_noise_density_mps2_per_sqrthz", &noise.accel_noise_density_mps2_per_sqrthz},
       {"gyro_random_walk_radps2_per_sqrthz", &noise.gyro_random_walk_radps2_per_sqrthz},
       {"accel_random_walk_mps3_per_sqrthz", &noise.accel_random_walk_mps3_per_sqrthz}}};
  std::vector<std::string> missing;
  for (const auto& [key, out] : keys) {
    const std::optional<double> v = cal.OptionNumber(imu, key);
    if (!v) {
      missing.emplace_back(key);
      continue;
    }
    *out = *v;
  }
  if (!missing.empty()) {
    notes.push_back(fmt::format("IMU noise densities: none (sensors.{}.options lacks {})", imu,
                                fmt::join(missing, ", ")));
    return std::nullopt;
  }
  notes.push_back(fmt::format("IMU noise densities from calibration.yaml sensors.{}.options", imu));
  return noise;
}

// EuRoC's own calibration of its IMU (the ASL dataset format, mav0/imu0/sensor.yaml, as
// Kalibr writes it): the four noise densities and the IMU's mount T_BS in the body frame
// (a 4x4 row-major matrix under T_BS.data). nullopt when the file does not exist.
struct EurocImuCalibration {
  RecordedImuNoise noise;
  Eigen::Isometry3d T_BI = Eigen::Isometry3d::Identity();
};

std::optional<EurocImuCalibration> ReadEurocImuSensorYaml(const fs::path& path) {
  std::error_code ec;
  if (!fs::is_regular_file(path, ec)) return std::nullopt;
  const std::string file = path.string();
  const YAML::Node root =
      LoadYamlText(core::ReadWholeFile(path, "EuRoC sensor.yaml", core::kMaxConfigFileBytes), file);
  if (!root.IsMap()) throw YamlError(file, root.Mark(), "", "expected a map (EuRoC sensor.yaml)");
  EurocImuCalibration out;
  const std::array<std::pair<const char*, double*>, 4> keys = {
      {{"gyroscope_noise_density", &out.noise.gyro_noise_density_radps_per_sqrthz},
       {"accelerometer_noise_density", &out.noise.accel_noise_density_mps2_per_sqrthz},
       {"gyroscope_random_walk", &out.noise.gyro_random_walk_radps2_per_sqrthz},
       {"accelerometer_random_walk", &out.noise.accel_random_walk_mps3_per_sqrthz}}};
  for (const auto& [key, value] : keys) {
    const YAML::Node v = root[key];
    if (!v) {
      throw YamlError(file, root.Mark(), key,
                      "missing: an EuRoC IMU sensor.yaml states gyroscope_noise_density, "
                      "gyroscope_random_walk, accelerometer_noise_density and "
                      "accelerometer_random_walk (SI units per sqrt(Hz))");
    }
    *value = YamlNumber(v, file, key);
    if (!(std::isfinite(*value) && *value > 0.0)) {
      throw YamlError(file, v.Mark(), key, fmt::format("expected a positive number, got {}", *value));
    }
  }
  if (const YAML::Node T = root["T_BS"]) {
    const YAML::Node data = T.IsMap() ? T["data"] : YAML::Node();
    if (!data || !data.IsSequence() || data.size() != 16) {
      throw YamlError(file, T.Mark(), "T_BS.data", "expected 16 numbers (a 4x4 row-major matrix)");
    }
    Eigen::Matrix4d M;
    for (int i = 0; i < 16; ++i) {
      M(i / 4, i % 4) = YamlNumber(data[i], file, fmt::format("T_BS.data[{}]", i));
    }
    const Eigen::Matrix3d R = M.topLeftCorner<3, 3>();
    // Kalibr prints 8-10 digits: orthonormal to that, not to machine precision.
    if (!M.allFinite() || (R.transpose() * R - Eigen::Matrix3d::Identity()).norm() > 1e-5 ||
        R.determinant() < 0.0 || M.row(3) != Eigen::RowVector4d(0, 0, 0, 1)) {
      throw YamlError(file, data.Mark(), "T_BS.data",
                      "expected a rigid transform: an orthonormal rotation with determinant "
                      "+1 and a last row 0 0 0 1");
    }
    out.T_BI.linear() = Eigen::Quaterniond(R).normalized().toRotationMatrix();
    out.T_BI.translation() = M.topRightCorner<3, 1>();
  }
  return out;
}

// Mounts (T_Is = T_BI^-1 T_Bs, nominal), odometry noise, true reference frames and
// IMU noise of the log's streams from its calibration; returns the true IMU mount
// T_BI (the ground truth's B-to-I step).
Eigen::Isometry3d ApplyCalibration(const RunCalibration& cal, RecordedLog& log) {
  Eigen::Isometry3d T_BI = Eigen::Isometry3d::Identity();
  Eigen::Isometry3d T_BI_true = Eigen::Isometry3d::Identity();
  if (!cal.present) {
    log.notes.push_back("no calibration.yaml: identity mounts");
  } else {
    const auto imu = cal.sensors.find(log.imu_stream);
    if (!log.imu_stream.empty() && imu != cal.sensors.end() && imu->second.T_Bs) {
      T_BI = *imu->second.T_Bs;
      T_BI_true = imu->second.true_T_Bs ? *imu->second.true_T_Bs : T_BI;
    } else {
      log.notes.push_back("calibration.yaml: no IMU mount, T_B_I = identity");
    }
    for (RecordedStream& s : log.streams) {
      const auto it = cal.sensors.find(s.name);
      if (it != cal.sensors.end()) s.true_T_WS = it->second.true_T_WS;
      if (const auto surveyed = cal.T_MS.find(s.name); surveyed != cal.T_MS.end()) {
        s.T_MS = surveyed->second;
      }
      if (it == cal.sensors.end() || !it->second.T_Bs) {
        log.notes.push_back(fmt::format("{}: no mount in calibration.yaml, T_I_s = identity",
                                        s.name));
        continue;
      }
      s.T_Is = T_BI.inverse() * *it->second.T_Bs;
    }
    for (RecordedStream& s : log.streams) {
      if (const auto v = cal.OptionNumber(s.name, "position_noise_m")) s.position_noise_m = *v;
      if (const auto v = cal.OptionNumber(s.name, "rotation_noise_deg")) {
        s.rotation_noise_rad = core::RadFromDeg(*v);
      }
      if (const auto v = cal.OptionNumber(s.name, "position_random_walk_m_per_sqrtm")) {
        s.position_random_walk_m_per_sqrtm = *v;
      }
      for (const char* key : {"rotation_random_walk_deg_per_sqrtm", "yaw_random_walk_deg_per_sqrtm",
                              "tilt_random_walk_deg_per_sqrtm"}) {
        if (const auto v = cal.OptionNumber(s.name, key)) {
          s.rotation_random_walk_rad_per_sqrtm =
              std::max(s.rotation_random_walk_rad_per_sqrtm.value_or(0.0), core::RadFromDeg(*v));
        }
      }
      // The degeneracy test λ σ_r² < threshold as a std: σ_r / √threshold.
      const auto range_noise_m = cal.OptionNumber(s.name, "range_noise_m");
      const auto std_at = [&](const char* threshold_key) -> std::optional<double> {
        const auto threshold = cal.OptionNumber(s.name, threshold_key);
        if (!range_noise_m || !threshold || !(*range_noise_m > 0.0) || !(*threshold > 0.0)) {
          return std::nullopt;
        }
        return *range_noise_m / std::sqrt(*threshold);
      };
      s.unobserved_position_std_m = std_at("degenerate_translation_threshold");
      s.unobserved_rotation_std_rad = std_at("degenerate_rotation_threshold_m2");
    }
    log.notes.push_back("mounts: T_I_s = T_B_I^-1 T_B_s from calibration.yaml");
    // The nominal mount: the launch pad is what the operator states, through what the
    // flight stack is told of the IMU.
    if (cal.T_MB_launch) log.T_MI_launch = *cal.T_MB_launch * T_BI;
  }
  if (!log.imu_stream.empty()) {
    if (cal.present) {
      log.imu_noise = ReadImuNoise(cal, log.imu_stream, log.notes);
    } else {
      log.notes.push_back("IMU noise densities: none (no calibration.yaml)");
    }
  }

  return T_BI_true;
}

// The IMU frame I: the only IMU stream, else the one named "imu", else the first by
// name. False (and a note) when the log has none.
bool ChooseImuStream(RecordedLog& log) {
  std::vector<const RecordedStream*> imus;
  for (const RecordedStream& s : log.streams) {
    if (s.kind == core::MeasurementKind::kImu) imus.push_back(&s);
  }
  if (imus.empty()) {
    log.notes.push_back("no IMU stream");
    return false;
  }
  const auto named = std::find_if(imus.begin(), imus.end(),
                                  [](const RecordedStream* s) { return s->name == "imu"; });
  log.imu_stream = (named != imus.end() ? *named : imus.front())->name;
  if (imus.size() > 1) {
    log.notes.push_back(fmt::format("{} IMU streams; '{}' is the IMU frame I", imus.size(),
                                    log.imu_stream));
  }
  return true;
}

// ---- assembling the log ----

// A stream to read: its name, file and how to read it.
struct Source {
  std::string name;
  fs::path file;
  bool tum = false;
};

bool IsReservedTum(const std::string& stem) {
  return stem == "groundtruth" || stem.rfind("estimate_", 0) == 0;
}

// Sorts measurements (and arrival_ns) by (arrival, stream rank, t, read order) in place.
void SortByArrival(RecordedLog& log, const std::vector<size_t>& stream_end) {
  const size_t n = log.measurements.size();
  struct Key {
    Time arrival;
    uint32_t rank;
    Time t;
    uint32_t index;
  };
  std::vector<Key> keys(n);
  uint32_t rank = 0;
  for (size_t i = 0; i < n; ++i) {
    while (rank < stream_end.size() && i >= stream_end[rank]) ++rank;
    keys[i] = {log.arrival_ns[i], rank, log.measurements[i].t_ns, static_cast<uint32_t>(i)};
  }
  std::sort(keys.begin(), keys.end(), [](const Key& a, const Key& b) {
    if (a.arrival != b.arrival) return a.arrival < b.arrival;
    if (a.rank != b.rank) return a.rank < b.rank;
    if (a.t != b.t) return a.t < b.t;
    return a.index < b.index;
  });
  // Apply the permutation (destination k takes source keys[k].index) cycle by cycle, so
  // that the large measurement vector is never copied.
  std::vector<Time> arrival(n);
  for (size_t k = 0; k < n; ++k) arrival[k] = log.arrival_ns[keys[k].index];
  log.arrival_ns = std::move(arrival);
  std::vector<bool> done(n, false);
  for (size_t start = 0; start < n; ++start) {
    if (done[start] || keys[start].index == start) {
      done[start] = true;
      continue;
    }
    core::StampedMeasurement held = std::move(log.measurements[start]);
    size_t k = start;
    while (true) {
      done[k] = true;
      const size_t source = keys[k].index;
      if (source == start) {
        log.measurements[k] = std::move(held);
        break;
      }
      log.measurements[k] = std::move(log.measurements[source]);
      k = source;
    }
  }
}

// Where a log's streams and ground truth are: a tofu run directory (sensors/*.csv) or an
// EuRoC-style log (mav0/imu0/data.csv, *.tum).
struct LogLayout {
  bool run_directory = false;
  std::vector<Source> sources;  // by name
  fs::path ground_truth_file;
};

LogLayout FindLayout(const fs::path& directory, const RecordedLogOptions& options,
                     std::vector<std::string>& notes) {
  std::error_code ec;
  LogLayout layout;
  layout.run_directory = fs::is_directory(directory / "sensors", ec);
  std::vector<Source>& sources = layout.sources;
  if (layout.run_directory) {
    const fs::path folder =
        options.use_clean_streams ? directory / "sensors" / "clean" : directory / "sensors";
    if (!fs::is_directory(folder, ec)) {
      throw InputError({folder.string()}, "",
                       "no such folder: use_clean_streams needs sensors/clean/<name>.csv");
    }
    for (const auto& entry : fs::directory_iterator(folder)) {
      if (entry.is_regular_file() && entry.path().extension() == ".csv") {
        sources.push_back({entry.path().stem().string(), entry.path(), false});
      }
    }
    notes.push_back(fmt::format("layout: tofu run directory, streams from {}",
                                options.use_clean_streams ? "sensors/clean/*.csv (un-faulted)"
                                                          : "sensors/*.csv"));
    layout.ground_truth_file = directory / "groundtruth.csv";
  } else {
    const fs::path imu = directory / "mav0" / "imu0" / "data.csv";
    if (fs::is_regular_file(imu, ec)) sources.push_back({"imu", imu, false});
    for (const auto& entry : fs::directory_iterator(directory)) {
      if (!entry.is_regular_file() || entry.path().extension() != ".tum") continue;
      const std::string stem = entry.path().stem().string();
      if (IsReservedTum(stem)) {
        notes.push_back(fmt::format("{}: not read (a tofu output, not a sensor stream)",
                                    entry.path().filename().string()));
        continue;
      }
      sources.push_back({stem, entry.path(), true});
    }
    notes.push_back("layout: EuRoC-style log (mav0/imu0/data.csv as 'imu', *.tum as pose "
                    "streams)");
    layout.ground_truth_file = directory / "mav0" / "state_groundtruth_estimate0" / "data.csv";
  }
  std::sort(sources.begin(), sources.end(),
            [](const Source& a, const Source& b) { return a.name < b.name; });
  for (size_t i = 1; i < sources.size(); ++i) {
    if (sources[i].name == sources[i - 1].name) {
      throw InputError({sources[i].file.string()}, "",
                       fmt::format("stream name '{}' is also used by {}", sources[i].name,
                                   sources[i - 1].file.string()));
    }
  }
  if (sources.empty() && options.require_imu) {
    throw InputError({directory.string()}, "",
                     "no IMU stream found: expected sensors/<name>.csv (tofu run directory) or "
                     "mav0/imu0/data.csv (EuRoC)");
  }
  return layout;
}

// Every stream, in name order, into log.streams and log.measurements; returns where each
// stream's measurements end (SortByArrival merges them).
std::vector<size_t> ReadStreams(const fs::path& directory, const std::vector<Source>& sources,
                                const RecordedLogOptions& options, RecordedLog& log) {
  std::vector<size_t> stream_end;
  const Sink sink{&log.measurements, &log.arrival_ns};
  for (const Source& source : sources) {
    RecordedStream stream;
    stream.name = source.name;
    stream.file = source.file;
    if (source.tum) {
      const std::vector<PoseSample> poses = ReadTumTrajectory(source.file);
      log.measurements.reserve(log.measurements.size() + poses.size());
      log.arrival_ns.reserve(log.arrival_ns.size() + poses.size());
      for (const PoseSample& s : poses) {
        core::PoseMeasurement m;
        m.p_Ss = s.p;
        m.q_Ss = s.q;
        m.covariance = options.default_pose_covariance;
        log.measurements.push_back({source.name, s.t_ns, std::move(m)});
        log.arrival_ns.push_back(s.t_ns);
      }
      stream.kind = core::MeasurementKind::kPose;
      stream.rows = poses.size();
      stream.covariance_stated = false;
      log.notes.push_back(fmt::format("{}: TUM pose stream, arrival = t, default covariance",
                                      source.name));
    } else {
      const SensorCsvContents contents =
          ReadSensorCsv(source.file, source.name, options, sink, log.notes);
      stream.kind = contents.kind;
      stream.rows = contents.rows;
      stream.covariance_stated = contents.covariance_stated;
    }
    log.notes.push_back(fmt::format("{}: {} stream, {} rows from {}", stream.name,
                                    core::MeasurementKindName(stream.kind), stream.rows,
                                    fs::relative(stream.file, directory).string()));
    log.streams.push_back(std::move(stream));
    stream_end.push_back(log.measurements.size());
  }
  return stream_end;
}

// EuRoC's own IMU calibration (mav0/imu0/sensor.yaml): its noise densities unless
// calibration.yaml (the user's) states them; its mount when there is no calibration.yaml.
// EuRoC's body frame is the one its ground truth and (taken here) the pose streams are of.
void ApplyEurocImuCalibration(const fs::path& directory, bool calibration_present,
                              Eigen::Isometry3d& T_BI_true, RecordedLog& log) {
  const fs::path sensor_yaml = directory / "mav0" / "imu0" / "sensor.yaml";
  const std::optional<EurocImuCalibration> euroc = ReadEurocImuSensorYaml(sensor_yaml);
  if (!euroc) return;
  if (!log.imu_noise) {
    log.imu_noise = euroc->noise;
    log.notes.push_back("IMU noise densities from mav0/imu0/sensor.yaml");
  }
  if (calibration_present) return;
  T_BI_true = euroc->T_BI;
  for (RecordedStream& stream : log.streams) {
    if (stream.name != log.imu_stream) stream.T_Is = euroc->T_BI.inverse();
  }
  log.notes.push_back("mounts: T_B_I from mav0/imu0/sensor.yaml T_BS, other streams of the body");
}

// Ground truth of the IMU frame (T_WB x the true IMU mount), and a run's labels.
void ReadGroundTruthAndLabels(const fs::path& directory, const LogLayout& layout,
                              const Eigen::Isometry3d& T_BI_true, RecordedLog& log) {
  std::error_code ec;
  if (fs::is_regular_file(layout.ground_truth_file, ec)) {
    if (layout.run_directory) {
      ReadGroundTruthCsv(layout.ground_truth_file, "p_WB_", "q_WB_", T_BI_true, log);
      log.notes.push_back("ground truth: groundtruth.csv (T_WB) x T_B_I (true IMU mount)");
    } else {
      ReadGroundTruthCsv(layout.ground_truth_file, "p_RS_R_", "q_RS_", T_BI_true, log);
      log.notes.push_back("ground truth: mav0/state_groundtruth_estimate0/data.csv (T_WB) x T_B_I");
    }
  } else {
    log.notes.push_back(fmt::format("no ground truth ({} not found)",
                                    fs::relative(layout.ground_truth_file, directory).string()));
  }
  if (layout.run_directory) {
    const fs::path labels_file = directory / "labels.csv";
    if (fs::is_regular_file(labels_file, ec)) {
      log.labels = ReadLabelsCsv(labels_file);
      log.notes.push_back(fmt::format("labels: labels.csv ({} transitions)", log.labels.size()));
    }
  }
}

}  // namespace

RecordedLog ReadRecordedLog(const fs::path& directory, const RecordedLogOptions& options) {
  std::error_code ec;
  if (!fs::exists(directory, ec)) {
    throw InputError({directory.string()}, "",
                     "no such directory, expected a tofu run directory (sensors/*.csv) or an "
                     "EuRoC-style log (mav0/imu0/data.csv, *.tum)");
  }
  if (!fs::is_directory(directory, ec)) {
    throw InputError({directory.string()}, "",
                     "not a directory, expected a tofu run directory or an EuRoC-style log");
  }
  RecordedLog log;
  log.directory = directory;
  const LogLayout layout = FindLayout(directory, options, log.notes);
  const std::vector<size_t> stream_end = ReadStreams(directory, layout.sources, options, log);

  // The IMU: the only IMU stream, else the one named "imu", else the first by name.
  if (!ChooseImuStream(log) && options.require_imu) {
    throw InputError({directory.string()}, "",
                     fmt::format("no IMU stream found among {} stream(s): expected a CSV "
                                 "with columns w_RS_S_x/y/z, a_RS_S_x/y/z ({})",
                                 log.streams.size(),
                                 layout.run_directory ? "sensors/<name>.csv"
                                                      : "mav0/imu0/data.csv"));
  }
  log.imu_samples_are_interval_averages = layout.run_directory;

  // Mounts: T_Is = T_BI^-1 T_Bs (nominal mounts).
  RunCalibration calibration;
  if (const fs::path cal_path = directory / "calibration.yaml"; fs::is_regular_file(cal_path)) {
    log.calibration_yaml =
        core::ReadWholeFile(cal_path, "calibration file", core::kMaxConfigFileBytes);
    calibration = ParseRunCalibration(log.calibration_yaml, cal_path.string());
  }
  Eigen::Isometry3d T_BI_true = ApplyCalibration(calibration, log);
  if (!layout.run_directory && !log.imu_stream.empty()) {
    ApplyEurocImuCalibration(directory, calibration.present, T_BI_true, log);
  }
  ReadGroundTruthAndLabels(directory, layout, T_BI_true, log);
  SortByArrival(log, stream_end);
  return log;
}

RecordedLog DescribeRunStreams(std::vector<std::pair<std::string, core::MeasurementKind>> streams,
                               const std::string& calibration_yaml,
                               const fs::path& directory) {
  RecordedLog log;
  log.directory = directory;
  std::sort(streams.begin(), streams.end());
  for (const auto& [name, kind] : streams) {
    RecordedStream stream;
    stream.name = name;
    stream.kind = kind;
    stream.file = directory / "sensors" / (name + ".csv");
    log.streams.push_back(std::move(stream));
  }
  ChooseImuStream(log);
  log.imu_samples_are_interval_averages = true;
  const fs::path cal_path = directory / "calibration.yaml";
  ApplyCalibration(ParseRunCalibration(calibration_yaml, cal_path.string()), log);
  log.calibration_yaml = calibration_yaml;
  return log;
}

}  // namespace tofu::replay
