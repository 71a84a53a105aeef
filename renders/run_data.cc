#include "renders/run_data.h"

#include <algorithm>
#include <cmath>
#include <fstream>
#include <sstream>

#include <fmt/format.h>
#include <nlohmann/json.hpp>
#include <yaml-cpp/yaml.h>

#include "core/error.h"
#include "core/file_io.h"
#include "replay/csv_reader.h"
#include "replay/run_format.h"
#include "replay/yaml_fields.h"

namespace tofu::renders {
namespace {

namespace fs = std::filesystem;
using core::InputError;
using replay::CsvTable;

// ---- text ----

std::vector<std::string> SplitPlus(std::string_view text) {
  std::vector<std::string> out;
  size_t start = 0;
  while (start <= text.size() && !text.empty()) {
    const size_t plus = text.find('+', start);
    const std::string_view item =
        text.substr(start, plus == std::string_view::npos ? std::string_view::npos : plus - start);
    if (!item.empty()) out.emplace_back(item);
    if (plus == std::string_view::npos) break;
    start = plus + 1;
  }
  return out;
}

std::string SafeFileName(const std::string& method) {
  std::string out = method;
  for (char& c : out) {
    if (c == ':' || c == '+' || c == '/' || c == ' ') c = '_';
  }
  return out;
}

bool EndsWith(const std::string& s, const std::string& suffix) {
  return s.size() >= suffix.size() && s.compare(s.size() - suffix.size(), suffix.size(), suffix) == 0;
}

Eigen::Quaterniond ReadQuaternion(const CsvTable& csv, size_t row, const int (&cols)[4]) {
  Eigen::Quaterniond q(csv.Double(row, cols[0]), csv.Double(row, cols[1]),
                       csv.Double(row, cols[2]), csv.Double(row, cols[3]));
  if (!(q.norm() > 1e-9)) return Eigen::Quaterniond::Identity();
  return q.normalized();
}

// ---- the files ----

void ReadScenario(RunData& run) {
  const fs::path path = run.directory / "scenario.yaml";
  if (!fs::is_regular_file(path)) {
    throw InputError({path.string()}, "", "missing: expected the file of a tofu run directory");
  }
  const std::string file = path.string();
  const YAML::Node root = replay::LoadYamlText(
      core::ReadWholeFile(path, "scenario.yaml", core::kMaxConfigFileBytes), file);
  if (!root.IsMap()) {
    throw replay::YamlError(file, root.Mark(), "", "expected a mapping (the resolved scenario)");
  }
  run.scenario_name = replay::YamlString(root["name"], file, "name");
  run.world = replay::YamlString(root["world"], file, "world");
  if (root["robot"]) run.robot = replay::YamlString(root["robot"], file, "robot");
}

void ReadGroundTruth(RunData& run) {
  const CsvTable csv(run.directory / "groundtruth.csv",
                     "#timestamp [ns],p_WB_x [m],p_WB_y [m],p_WB_z [m],q_WB_w [],q_WB_x [],"
                     "q_WB_y [],q_WB_z [],...");
  const int t = csv.Require("timestamp");
  const int p[3] = {csv.Require("p_WB_x"), csv.Require("p_WB_y"), csv.Require("p_WB_z")};
  const int q[4] = {csv.Require("q_WB_w"), csv.Require("q_WB_x"), csv.Require("q_WB_y"),
                    csv.Require("q_WB_z")};
  run.groundtruth.reserve(csv.rows());
  for (size_t r = 0; r < csv.rows(); ++r) {
    TimedPose pose;
    pose.t_ns = csv.Int(r, t);
    if (!run.groundtruth.empty() && pose.t_ns <= run.groundtruth.back().t_ns) {
      throw InputError({csv.file(), csv.Line(r), 1}, "",
                       "timestamps must increase strictly (ground truth is written in order)");
    }
    pose.p_W = Eigen::Vector3d(csv.Double(r, p[0]), csv.Double(r, p[1]), csv.Double(r, p[2]));
    pose.q_W = ReadQuaternion(csv, r, q);
    run.groundtruth.push_back(pose);
  }
  if (run.groundtruth.empty()) {
    throw InputError({csv.file(), 2, 0}, "", "no ground-truth rows: nothing to render");
  }
}

// calibration.yaml through the one reader of the run-directory schema: mounts and the
// IMU's nominal mount now, the sensors' geometry when a layer asks for it.
void ReadCalibration(RunData& run) {
  const fs::path path = run.directory / "calibration.yaml";
  if (!fs::is_regular_file(path)) {
    throw InputError({path.string()}, "", "missing: expected the file of a tofu run directory");
  }
  run.calibration = replay::ReadRunCalibration(path);
  run.mounts = run.calibration.mounts;
  // The estimates are of the IMU frame I: its nominal mount (what the estimator is given).
  bool imu_found = false;
  for (const auto& [name, c] : run.calibration.sensors) {
    if (replay::MeasurementKindOfSensorType(c.type) != core::MeasurementKind::kImu || !c.T_Bs) continue;
    run.T_BI = *c.T_Bs;
    imu_found = true;
    break;
  }
  if (!imu_found && run.mounts.count("imu") != 0) run.T_BI = run.mounts.at("imu");
}

void ReadSensors(RunData& run) {
  const replay::RunCalibration& calibration = run.calibration;
  for (const fs::path& file : SensorCsvFiles(run.directory)) {
    const std::string name = file.stem().string();
    const auto cal = calibration.sensors.find(name);
    if (cal == calibration.sensors.end()) {
      run.notes.push_back(fmt::format("sensors/{}.csv: not in calibration.yaml, not drawn", name));
      continue;
    }
    // An IMU has nothing to place in W (and an hour of it is not worth reading).
    if (replay::MeasurementKindOfSensorType(cal->second.type) == core::MeasurementKind::kImu) continue;
    const CsvTable csv(file, std::string(replay::kSensorCsvForm));
    SensorTrack track;
    track.name = name;
    track.type = cal->second.type;
    track.site = cal->second.site;
    track.true_T_WS = cal->second.true_T_WS.value_or(Eigen::Isometry3d::Identity());
    const replay::SensorCsvColumns columns = replay::LocateSensorCsvColumns(csv.keys(), csv.file());
    using replay::SensorField;
    const int t = columns.Column(SensorField::kTimestamp);
    const int p[3] = {columns.Column(SensorField::kPosition, 0),
                      columns.Column(SensorField::kPosition, 1),
                      columns.Column(SensorField::kPosition, 2)};
    const int conditions = columns.Column(SensorField::kConditions);
    const int faults = columns.Column(SensorField::kFaults);
    for (size_t r = 0; r < csv.rows(); ++r) {
      const Eigen::Vector3d p_Ss(csv.Double(r, p[0]), csv.Double(r, p[1]), csv.Double(r, p[2]));
      if (!p_Ss.allFinite()) continue;  // a faulted NaN sample: nothing to place
      track.t_ns.push_back(csv.Int(r, t));
      track.p_W.push_back(track.true_T_WS * p_Ss);
      track.conditions.emplace_back(conditions >= 0 ? csv.Text(r, conditions) : "");
      track.faults.emplace_back(faults >= 0 ? csv.Text(r, faults) : "");
    }
    run.sensors.push_back(std::move(track));
  }
}

void ReadLabels(RunData& run) {
  const fs::path path = run.directory / "labels.csv";
  if (!fs::exists(path)) return;
  const CsvTable csv(path, "#timestamp [ns],sensor,label,source,active");
  const int t = csv.Require("timestamp");
  const int sensor = csv.Require("sensor");
  const int label = csv.Require("label");
  const int source = csv.Require("source");
  const int active = csv.Require("active");
  for (size_t r = 0; r < csv.rows(); ++r) {
    LabelRow row;
    row.t_ns = csv.Int(r, t);
    row.sensor = csv.Text(r, sensor);
    row.label = csv.Text(r, label);
    row.source = csv.Text(r, source);
    const int64_t a = csv.Int(r, active);
    if (a != 0 && a != 1) {
      throw InputError({csv.file(), csv.Line(r), 0}, "", "column 'active': expected 0 or 1");
    }
    row.active = a == 1;
    run.labels.push_back(row);
  }
  std::stable_sort(run.labels.begin(), run.labels.end(),
                   [](const LabelRow& a, const LabelRow& b) { return a.t_ns < b.t_ns; });
}

void ReadSummary(RunData& run) {
  const fs::path path = run.directory / "summary.json";
  if (!fs::exists(path)) return;
  const nlohmann::json j = ReadRunJson(path);
  if (!j.contains("collisions")) return;
  const nlohmann::json& list = j["collisions"];
  if (!list.is_array()) throw InputError({path.string()}, "collisions", "expected an array");
  for (size_t i = 0; i < list.size(); ++i) {
    const nlohmann::json& c = list[i];
    const std::string key = fmt::format("collisions[{}]", i);
    if (!c.is_object() || !c.contains("start_s") || !c["start_s"].is_number()) {
      throw InputError({path.string()}, key, "expected {start_s: number, ...}");
    }
    CollisionRow row;
    row.t_ns = core::SecondsToTime(c["start_s"].get<double>());
    if (c.contains("robot_geom") && c["robot_geom"].is_string()) row.robot_geom = c["robot_geom"];
    if (c.contains("structure_geom") && c["structure_geom"].is_string()) {
      row.structure_geom = c["structure_geom"];
    }
    run.collisions.push_back(row);
  }
}

// T_WL of an estimate json ({"T_WL": {"p_m": [...], "q_wxyz": [...]}}), if there.
std::optional<Eigen::Isometry3d> JsonPose(const fs::path& path, const nlohmann::json& j,
                                          const std::string& key) {
  if (!j.contains(key)) return std::nullopt;
  const nlohmann::json& pose = j[key];
  const bool ok = pose.is_object() && pose.contains("p_m") && pose.contains("q_wxyz") &&
                  pose["p_m"].is_array() && pose["p_m"].size() == 3 &&
                  pose["q_wxyz"].is_array() && pose["q_wxyz"].size() == 4;
  if (!ok) throw InputError({path.string()}, key, "expected {p_m: [x,y,z], q_wxyz: [w,x,y,z]}");
  for (const auto& v : pose["p_m"]) {
    if (!v.is_number()) throw InputError({path.string()}, key + ".p_m", "expected numbers");
  }
  for (const auto& v : pose["q_wxyz"]) {
    if (!v.is_number()) throw InputError({path.string()}, key + ".q_wxyz", "expected numbers");
  }
  Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
  T.translation() = Eigen::Vector3d(pose["p_m"][0], pose["p_m"][1], pose["p_m"][2]);
  const Eigen::Quaterniond q(pose["q_wxyz"][0], pose["q_wxyz"][1], pose["q_wxyz"][2],
                             pose["q_wxyz"][3]);
  if (q.norm() < 1e-9) throw InputError({path.string()}, key + ".q_wxyz", "expected a unit quaternion");
  T.linear() = q.normalized().toRotationMatrix();
  return T;
}

void ReadErrorsFile(RunData& run, const fs::path& path, const std::string& method_of_file) {
  const CsvTable csv(path, method_of_file.empty()
                               ? "#timestamp [ns],method,position_error [m],rotation_error [deg],"
                                 "valid,nees"
                               : "#timestamp [ns],position_error [m],rotation_error [deg],...");
  const int t = csv.Require("timestamp");
  const int method = method_of_file.empty() ? csv.Require("method") : -1;
  const int position = csv.Require("position_error");
  const int rotation = csv.Find("rotation_error");
  const int valid = csv.Find("valid");
  for (size_t r = 0; r < csv.rows(); ++r) {
    if (valid >= 0 && csv.Text(r, valid) == "0") continue;
    ErrorRow row;
    row.t_ns = csv.Int(r, t);
    row.method = method >= 0 ? std::string(csv.Text(r, method)) : method_of_file;
    row.position_error_m = csv.Double(r, position, true);
    row.rotation_error_deg = rotation >= 0 ? csv.Double(r, rotation, true) : 0.0;
    if (std::isfinite(row.position_error_m)) run.errors.push_back(row);
  }
}

void ReadEstimates(RunData& run) {
  std::vector<fs::path> files;
  for (const auto& entry : fs::directory_iterator(run.directory)) {
    const std::string name = entry.path().filename().string();
    if (entry.is_regular_file() && name.rfind("estimate_", 0) == 0 && EndsWith(name, ".csv") &&
        !EndsWith(name, "_errors.csv")) {
      files.push_back(entry.path());
    }
  }
  std::sort(files.begin(), files.end());
  const bool errors_csv = fs::exists(run.directory / "errors.csv");
  for (const fs::path& file : files) {
    const std::string stem = file.stem().string();
    MethodEstimate estimate;
    estimate.method = stem.substr(std::string("estimate_").size());
    const fs::path json_path = run.directory / (stem + ".json");
    std::optional<Eigen::Isometry3d> T_WL;
    if (fs::exists(json_path)) {
      const nlohmann::json j = ReadRunJson(json_path);
      if (j.contains("method") && j["method"].is_string()) estimate.method = j["method"];
      T_WL = JsonPose(json_path, j, "T_WL");
    }
    const CsvTable csv(file, "#timestamp [ns],p_LI_x [m],p_LI_y [m],p_LI_z [m],q_LI_w [],"
                             "q_LI_x [],q_LI_y [],q_LI_z [],...,valid,fused");
    const int t = csv.Require("timestamp");
    const int p[3] = {csv.Require("p_LI_x"), csv.Require("p_LI_y"), csv.Require("p_LI_z")};
    const int q[4] = {csv.Require("q_LI_w"), csv.Require("q_LI_x"), csv.Require("q_LI_y"),
                      csv.Require("q_LI_z")};
    const int valid = csv.Find("valid");
    const int fused = csv.Find("fused");
    std::vector<TimedPose> T_LI;
    for (size_t r = 0; r < csv.rows(); ++r) {
      if (valid >= 0 && csv.Text(r, valid) != "1") continue;
      TimedPose pose;
      pose.t_ns = csv.Int(r, t);
      pose.p_W = Eigen::Vector3d(csv.Double(r, p[0]), csv.Double(r, p[1]), csv.Double(r, p[2]));
      pose.q_W = ReadQuaternion(csv, r, q);
      if (!pose.p_W.allFinite()) continue;
      if (!T_LI.empty() && pose.t_ns <= T_LI.back().t_ns) continue;
      T_LI.push_back(pose);
      estimate.fused.emplace_back(fused >= 0 ? csv.Text(r, fused) : "");
    }
    if (T_LI.empty()) {
      run.notes.push_back(fmt::format("{}: no valid estimate, no ghost", file.filename().string()));
      continue;
    }
    // L -> W: the evaluation's alignment when the json has it, else the first valid
    // estimate against ground truth (the estimator starts in L = its first pose).
    if (T_WL) {
      estimate.T_WL = *T_WL;
      estimate.alignment_source = fmt::format("T_WL of {}", json_path.filename().string());
    } else {
      const Eigen::Isometry3d T_WB0 = InterpolatePose(run.groundtruth, T_LI.front().t_ns).T_W();
      const Eigen::Isometry3d T_LI0 = T_LI.front().T_W();
      estimate.T_WL = T_WB0 * run.T_BI * T_LI0.inverse();
      estimate.alignment_source = "first valid sample against ground truth";
    }
    const Eigen::Isometry3d T_IB = run.T_BI.inverse();
    for (const TimedPose& pose : T_LI) {
      const Eigen::Isometry3d T_WB = estimate.T_WL * pose.T_W() * T_IB;
      TimedPose ghost;
      ghost.t_ns = pose.t_ns;
      ghost.p_W = T_WB.translation();
      ghost.q_W = Eigen::Quaterniond(T_WB.linear()).normalized();
      estimate.T_WB.push_back(ghost);
    }
    if (!errors_csv) {
      const fs::path errors = run.directory / (stem + "_errors.csv");
      if (fs::exists(errors)) ReadErrorsFile(run, errors, estimate.method);
    }
    run.notes.push_back(fmt::format("ghost '{}': {} poses, L->W from {}", estimate.method,
                                    estimate.T_WB.size(), estimate.alignment_source));
    run.estimates.push_back(std::move(estimate));
  }
  std::sort(run.estimates.begin(), run.estimates.end(),
            [](const MethodEstimate& a, const MethodEstimate& b) { return a.method < b.method; });
  if (errors_csv) ReadErrorsFile(run, run.directory / "errors.csv", "");
}

// Closed-loop flights (closed_loop/<method>/, a run directory each): each flight's TRUE
// path becomes a ghost "flown on <method>" beside the ground-truth flight's robot, and its
// collisions are the run's events, so a render of the critical moment shows every
// method's robot where it really was.
void ReadClosedLoopFlights(RunData& run) {
  const std::vector<fs::path> flights = ClosedLoopFlightDirs(run.directory);
  for (const fs::path& dir : flights) {
    RunData flight;
    flight.directory = dir;
    ReadGroundTruth(flight);
    ReadSummary(flight);
    const std::string label = "flown on " + dir.filename().string();
    MethodEstimate ghost;
    ghost.method = label;
    ghost.T_WB = std::move(flight.groundtruth);
    ghost.fused.assign(ghost.T_WB.size(), "");
    ghost.alignment_source = "the true path of closed_loop/" + dir.filename().string();
    run.notes.push_back(fmt::format("ghost '{}': {} true poses of the closed-loop flight",
                                    label, ghost.T_WB.size()));
    run.estimates.push_back(std::move(ghost));
    for (CollisionRow c : flight.collisions) {
      c.robot_geom = "(" + label + ") " + c.robot_geom;
      run.collisions.push_back(std::move(c));
    }
  }
  std::sort(run.collisions.begin(), run.collisions.end(),
            [](const CollisionRow& a, const CollisionRow& b) { return a.t_ns < b.t_ns; });
}

void ReadDecisions(RunData& run) {
  const fs::path path = run.directory / "decisions.csv";
  if (!fs::exists(path)) return;
  const CsvTable csv(path, "#timestamp [ns],method,fused,excluded,unavailable,reason",
                     replay::CsvOptions{.last_column_takes_rest = true});
  const int t = csv.Require("timestamp");
  const int method = csv.Require("method");
  const int fused = csv.Require("fused");
  const int excluded = csv.Require("excluded");
  const int unavailable = csv.Find("unavailable");
  const int reason = csv.Find("reason");
  for (size_t r = 0; r < csv.rows(); ++r) {
    DecisionRow row;
    row.t_ns = csv.Int(r, t);
    row.method = csv.Text(r, method);
    row.fused = SplitPlus(csv.Text(r, fused));
    row.excluded = SplitPlus(csv.Text(r, excluded));
    if (unavailable >= 0) row.unavailable = SplitPlus(csv.Text(r, unavailable));
    if (reason >= 0) row.reason = csv.Text(r, reason);
    run.decisions.push_back(std::move(row));
  }
  std::stable_sort(run.decisions.begin(), run.decisions.end(),
                   [](const DecisionRow& a, const DecisionRow& b) { return a.t_ns < b.t_ns; });
}

void ReadConsistencyFile(RunData& run, const fs::path& path, const std::string& method) {
  const CsvTable csv(path, "#timestamp [ns],pair,metric,value");
  const int t = csv.Require("timestamp");
  const int pair = csv.Require("pair");
  const int metric = csv.Require("metric");
  const int value = csv.Require("value");
  std::vector<ConsistencyRow>& rows = run.consistency[method];
  for (size_t r = 0; r < csv.rows(); ++r) {
    ConsistencyRow row;
    row.t_ns = csv.Int(r, t);
    const std::string_view text = csv.Text(r, pair);
    const size_t dash = text.find('-');
    if (dash == std::string_view::npos || dash == 0 || dash + 1 == text.size()) {
      throw InputError({csv.file(), csv.Line(r), 0}, "",
                       fmt::format("column 'pair': expected 'a-b', got '{}'", text));
    }
    row.a = text.substr(0, dash);
    row.b = text.substr(dash + 1);
    row.metric = csv.Text(r, metric);
    row.value = csv.Double(r, value, true);
    rows.push_back(std::move(row));
  }
}

void ReadConsistency(RunData& run) {
  std::vector<fs::path> files;
  for (const auto& entry : fs::directory_iterator(run.directory)) {
    const std::string name = entry.path().filename().string();
    if (entry.is_regular_file() && name.rfind("consistency", 0) == 0 && EndsWith(name, ".csv")) {
      files.push_back(entry.path());
    }
  }
  std::sort(files.begin(), files.end());
  for (const fs::path& file : files) {
    const std::string stem = file.stem().string();
    std::string method;
    if (stem != "consistency") {
      if (stem.rfind("consistency_", 0) != 0) continue;
      method = stem.substr(std::string("consistency_").size());
      // The file name is the method's safe form; name it as the estimate does.
      for (const MethodEstimate& e : run.estimates) {
        if (SafeFileName(e.method) == method) method = e.method;
      }
    }
    ReadConsistencyFile(run, file, method);
  }
}

}  // namespace

Eigen::Isometry3d TimedPose::T_W() const {
  Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
  T.linear() = q_W.toRotationMatrix();
  T.translation() = p_W;
  return T;
}

TimedPose InterpolatePose(const std::vector<TimedPose>& poses, core::Time t_ns) {
  if (t_ns <= poses.front().t_ns) return poses.front();
  if (t_ns >= poses.back().t_ns) return poses.back();
  const auto after = std::lower_bound(
      poses.begin(), poses.end(), t_ns,
      [](const TimedPose& p, core::Time t) { return p.t_ns < t; });
  const TimedPose& b = *after;
  if (b.t_ns == t_ns) return b;
  const TimedPose& a = *(after - 1);
  const double u = static_cast<double>(t_ns - a.t_ns) / static_cast<double>(b.t_ns - a.t_ns);
  TimedPose out;
  out.t_ns = t_ns;
  out.p_W = (1.0 - u) * a.p_W + u * b.p_W;
  out.q_W = a.q_W.slerp(u, b.q_W).normalized();
  return out;
}

const SensorTrack* RunData::FindSensor(const std::string& name) const {
  for (const SensorTrack& s : sensors) {
    if (s.name == name) return &s;
  }
  return nullptr;
}

bool RunData::LabelActive(const std::string& sensor, const std::string& label,
                          core::Time t_ns) const {
  bool active = false;
  for (const LabelRow& row : labels) {
    if (row.t_ns > t_ns) break;
    if (row.sensor == sensor && row.label == label) active = row.active;
  }
  return active;
}

std::vector<std::string> RunData::ActiveLabels(const std::string& sensor, const std::string& source,
                                               core::Time t_ns) const {
  std::map<std::string, bool> state;
  for (const LabelRow& row : labels) {
    if (row.t_ns > t_ns) break;
    if (row.sensor == sensor && row.source == source) state[row.label] = row.active;
  }
  std::vector<std::string> active;
  for (const auto& [label, on] : state) {
    if (on) active.push_back(label);
  }
  return active;
}

nlohmann::json ReadRunJson(const fs::path& path) {
  const std::string text = core::ReadWholeFile(path, "JSON file of a tofu run directory");
  try {
    return nlohmann::json::parse(text);
  } catch (const nlohmann::json::parse_error& e) {
    // nlohmann reports a byte offset; name the place as line:column like every reader.
    int line = 1;
    int column = 1;
    for (size_t i = 0; i + 1 < e.byte && i < text.size(); ++i) {
      if (text[i] == '\n') {
        ++line;
        column = 1;
      } else {
        ++column;
      }
    }
    throw InputError({path.string(), line, column}, "", fmt::format("malformed JSON: {}", e.what()));
  }
}

std::vector<fs::path> SensorCsvFiles(const fs::path& run_dir) {
  std::vector<fs::path> files;
  const fs::path folder = run_dir / "sensors";
  if (!fs::is_directory(folder)) return files;
  for (const auto& entry : fs::directory_iterator(folder)) {
    if (entry.is_regular_file() && entry.path().extension() == ".csv") files.push_back(entry.path());
  }
  std::sort(files.begin(), files.end());
  return files;
}

std::vector<fs::path> ClosedLoopFlightDirs(const fs::path& run_dir) {
  std::vector<fs::path> flights;
  const fs::path folder = run_dir / "closed_loop";
  if (!fs::is_directory(folder)) return flights;
  for (const auto& entry : fs::directory_iterator(folder)) {
    if (entry.is_directory() && fs::exists(entry.path() / "groundtruth.csv")) flights.push_back(entry.path());
  }
  std::sort(flights.begin(), flights.end());
  return flights;
}

std::vector<LidarGeometry> LidarGeometries(const RunData& run) {
  std::vector<LidarGeometry> lidars;
  for (const auto& [name, c] : run.calibration.sensors) {
    if (const std::optional<core::LidarBeamPattern> beams = run.calibration.LidarBeams(name)) {
      lidars.push_back({c.site, *beams});
    }
  }
  return lidars;
}

std::vector<SkyGeometry> SkyGeometries(const RunData& run) {
  std::vector<SkyGeometry> skies;
  for (const auto& [name, c] : run.calibration.sensors) {
    if (replay::SensorModelOfName(c.type) != replay::SensorModel::kGnss) continue;
    if (c.sky_directions_S.empty()) {
      throw InputError({run.calibration.file}, "sensors." + name + ".sky_directions_S",
                       "missing: this run directory predates the GNSS sky in calibration.yaml; "
                       "run the scenario again to draw its sky");
    }
    SkyGeometry sky;
    sky.site = c.site;
    sky.T_WS = c.true_T_WS.value_or(Eigen::Isometry3d::Identity());
    sky.directions_S = c.sky_directions_S;
    sky.ray_length_m =
        run.calibration.OptionNumber(name, "sky_ray_length_m").value_or(sky.ray_length_m);
    skies.push_back(std::move(sky));
  }
  return skies;
}

RunData ReadRunData(const fs::path& directory) {
  if (!fs::is_directory(directory)) {
    throw InputError({directory.string()}, "",
                     "not a directory: expected a tofu run directory (`tofu run SCENARIO --out "
                     "DIR` writes one)");
  }
  RunData run;
  run.directory = directory;
  ReadScenario(run);
  ReadGroundTruth(run);
  ReadCalibration(run);
  ReadSensors(run);
  ReadLabels(run);
  ReadSummary(run);
  ReadEstimates(run);
  ReadClosedLoopFlights(run);
  ReadDecisions(run);
  ReadConsistency(run);
  return run;
}

}  // namespace tofu::renders
