#include "report/mcap_export.h"

#include <mujoco/mujoco.h>

#include <algorithm>
#include <cmath>
#include <map>
#include <optional>
#include <set>
#include <string_view>
#include <system_error>
#include <vector>

#include <fmt/format.h>
#include <nlohmann/json.hpp>

#include "core/error.h"
#include "core/file_io.h"
#include "renders/events.h"
#include "renders/run_data.h"
#include "replay/csv_reader.h"
#include "replay/run_format.h"
#include "report/json_text.h"
#include "report/mcap_schemas.h"
#include "sim/world.h"

namespace tofu::report {
namespace {

namespace fs = std::filesystem;
using replay::CsvTable;
using renders::RunData;
using renders::TimedPose;

constexpr const char* kWorldFrame = "world";
constexpr const char* kBodyFrame = "base_link";

std::uint64_t LogTime(core::Time t_ns) { return t_ns < 0 ? 0 : static_cast<std::uint64_t>(t_ns); }

// Foxglove's Log levels (foxglove.LogLevel).
enum LogLevel { kInfo = 2, kWarning = 3, kError = 4 };

// The channels of one export: a topic's id by name, created on first use with its schema.
class Channels {
 public:
  explicit Channels(McapWriter& writer) : writer_(writer) {}

  std::uint16_t Get(const std::string& topic, const std::string& schema_name) {
    const auto it = channels_.find(topic);
    if (it != channels_.end()) return it->second;
    auto schema = schemas_.find(schema_name);
    if (schema == schemas_.end()) {
      schema = schemas_.emplace(schema_name, writer_.AddSchema(schema_name, "jsonschema",
                                                               JsonSchemaText(schema_name)))
                   .first;
    }
    const std::uint16_t id = writer_.AddChannel(schema->second, topic, "json");
    channels_.emplace(topic, id);
    return id;
  }

  void Add(const std::string& topic, const std::string& schema_name, core::Time log_ns,
           core::Time publish_ns, const std::string& json) {
    writer_.AddMessage(Get(topic, schema_name), LogTime(log_ns), LogTime(publish_ns), json);
    ++counts_[topic];
  }

  const std::map<std::string, std::uint64_t>& counts() const { return counts_; }

 private:
  McapWriter& writer_;
  std::map<std::string, std::uint16_t> schemas_;
  std::map<std::string, std::uint16_t> channels_;
  std::map<std::string, std::uint64_t> counts_;
};

std::string PoseInFrame(core::Time t_ns, const char* frame, const Eigen::Vector3d& p,
                        const Eigen::Quaterniond& q) {
  JsonText j;
  j.Begin();
  j.Time("timestamp", t_ns);
  j.String("frame_id", frame);
  j.Pose("pose", p, q);
  j.End();
  return j.str();
}

std::string LogMessage(core::Time t_ns, int level, const std::string& message,
                       const std::string& name, const std::string& file, int line) {
  JsonText j;
  j.Begin();
  j.Time("timestamp", t_ns);
  j.Int("level", level);
  j.String("message", message);
  j.String("name", name);
  j.String("file", file);
  j.Int("line", std::max(0, line));
  j.End();
  return j.str();
}

// '|'-joined labels as a JSON array of strings.
std::vector<std::string> SplitLabels(std::string_view text, char separator = '|') {
  std::vector<std::string> out;
  std::size_t start = 0;
  while (start <= text.size() && !text.empty()) {
    const std::size_t end = text.find(separator, start);
    const std::string_view item = text.substr(start, end == std::string_view::npos ? end : end - start);
    if (!item.empty()) out.emplace_back(item);
    if (end == std::string_view::npos) break;
    start = end + 1;
  }
  return out;
}

// ---- ground truth ----

void ExportGroundTruth(const RunData& run, Channels& out) {
  for (const TimedPose& T_WB : run.groundtruth) {
    JsonText tf;
    tf.Begin();
    tf.Time("timestamp", T_WB.t_ns);
    tf.String("parent_frame_id", kWorldFrame);
    tf.String("child_frame_id", kBodyFrame);
    tf.Vector("translation", T_WB.p_W);
    tf.Quaternion("rotation", T_WB.q_W);
    tf.End();
    out.Add("/tf", "foxglove.FrameTransform", T_WB.t_ns, T_WB.t_ns, tf.str());
    out.Add("/groundtruth", "foxglove.PoseInFrame", T_WB.t_ns, T_WB.t_ns,
            PoseInFrame(T_WB.t_ns, kWorldFrame, T_WB.p_W, T_WB.q_W));
  }
}

// ---- sensor streams: every row as written, and its measurement mapped into W ----

using replay::SensorCsvColumns;
using replay::SensorField;

// The columns of a field (-1: missing): a covariance is N(N+1)/2 of them, its upper
// triangle (replay/run_format.h).
std::vector<int> FieldColumns(const SensorCsvColumns& c, SensorField field, int count) {
  std::vector<int> columns;
  for (int i = 0; i < count; ++i) columns.push_back(c.Has(field) ? c.Column(field, i) : -1);
  return columns;
}

// The full row-major matrix of an upper triangle (the convention of ROS and Foxglove
// covariances; a missing or empty column is null).
template <int N>
std::vector<double> FullCovariance(const CsvTable& csv, std::size_t row, const std::vector<int>& columns) {
  std::vector<double> c(N * N, std::nan(""));
  std::size_t i = 0;
  for (int r = 0; r < N; ++r) {
    for (int k = r; k < N; ++k, ++i) {
      const double v = columns[i] >= 0 ? csv.Double(row, columns[i], true) : std::nan("");
      c[r * N + k] = c[k * N + r] = v;
    }
  }
  return c;
}

core::Time ArrivalNs(const CsvTable& csv, const SensorCsvColumns& c, std::size_t r) {
  const core::Time t_ns = csv.Int(r, c.Column(SensorField::kTimestamp));
  return c.Has(SensorField::kArrival) ? csv.Int(r, c.Column(SensorField::kArrival)) : t_ns;
}

void AddSensorRowFields(JsonText& j, const CsvTable& csv, const SensorCsvColumns& c, std::size_t r) {
  const int conditions = c.Column(SensorField::kConditions);
  const int faults = c.Column(SensorField::kFaults);
  j.Time("timestamp", csv.Int(r, c.Column(SensorField::kTimestamp)));
  j.Time("arrival", ArrivalNs(csv, c, r));
  j.Strings("conditions", SplitLabels(conditions >= 0 ? csv.Text(r, conditions) : ""));
  j.Strings("faults", SplitLabels(faults >= 0 ? csv.Text(r, faults) : ""));
}

Eigen::Vector3d ReadVector(const CsvTable& csv, std::size_t r, const std::vector<int>& columns) {
  return {csv.Double(r, columns[0]), csv.Double(r, columns[1]), csv.Double(r, columns[2])};
}

void ExportImuSamples(const CsvTable& csv, const SensorCsvColumns& c, const std::string& topic,
                      Channels& out) {
  const std::vector<int> w = FieldColumns(c, SensorField::kGyro, 3);
  const std::vector<int> a = FieldColumns(c, SensorField::kAccel, 3);
  for (std::size_t r = 0; r < csv.rows(); ++r) {
    JsonText j;
    j.Begin();
    AddSensorRowFields(j, csv, c, r);
    j.Vector("angular_velocity_radps", ReadVector(csv, r, w));
    j.Vector("linear_acceleration_mps2", ReadVector(csv, r, a));
    j.End();
    out.Add(topic, "tofu.ImuSample", csv.Int(r, c.Column(SensorField::kTimestamp)),
            ArrivalNs(csv, c, r), j.str());
  }
}

// The measured twist of a pose row, when the row has one.
void AddTwist(JsonText& j, const CsvTable& csv, const SensorCsvColumns& c, std::size_t r) {
  const std::vector<int> v = FieldColumns(c, SensorField::kVelocity, 3);
  if (v[0] < 0 || csv.Text(r, v[0]).empty()) return;
  j.Vector("linear_velocity_mps", ReadVector(csv, r, v));
  j.Vector("angular_velocity_radps",
           ReadVector(csv, r, FieldColumns(c, SensorField::kAngularRate, 3)));
  j.Numbers("twist_covariance",
            FullCovariance<6>(csv, r, FieldColumns(c, SensorField::kTwistCovariance, 21)));
}

// A pose or position stream: each row as measured (in the sensor's reference frame), and
// mapped into W.
void ExportMeasurements(const RunData& run, const std::string& name, const CsvTable& csv,
                        const SensorCsvColumns& c, const std::string& topic, Channels& out) {
  const renders::SensorTrack* track = run.FindSensor(name);
  const Eigen::Isometry3d T_WS = track ? track->true_T_WS : Eigen::Isometry3d::Identity();
  const std::vector<int> p = FieldColumns(c, SensorField::kPosition, 3);
  const bool is_pose = c.kind() == core::MeasurementKind::kPose;
  const std::vector<int> q = FieldColumns(c, SensorField::kQuaternion, 4);
  const std::string frame = name + "_reference";
  const std::vector<int> cov_pose = FieldColumns(c, SensorField::kPoseCovariance, 21);
  const std::vector<int> cov_p = FieldColumns(c, SensorField::kPositionCovariance, 6);
  for (std::size_t r = 0; r < csv.rows(); ++r) {
    const core::Time t_ns = csv.Int(r, c.Column(SensorField::kTimestamp));
    const core::Time arrival_ns = ArrivalNs(csv, c, r);
    const Eigen::Vector3d p_Ss = ReadVector(csv, r, p);
    Eigen::Quaterniond q_Ss = Eigen::Quaterniond::Identity();
    JsonText j;
    j.Begin();
    AddSensorRowFields(j, csv, c, r);
    j.String("frame_id", frame);
    if (is_pose) {
      q_Ss = Eigen::Quaterniond(csv.Double(r, q[0]), csv.Double(r, q[1]), csv.Double(r, q[2]),
                                csv.Double(r, q[3]));
      j.Pose("pose", p_Ss, q_Ss);
      j.Numbers("covariance", FullCovariance<6>(csv, r, cov_pose));
      AddTwist(j, csv, c, r);
    } else {
      j.Vector("position", p_Ss);
      j.Numbers("covariance", FullCovariance<3>(csv, r, cov_p));
    }
    j.End();
    out.Add(topic, is_pose ? "tofu.PoseMeasurement" : "tofu.PositionMeasurement", t_ns,
            arrival_ns, j.str());

    // In W through the sensor's true reference frame (calibration.yaml true_T_WS), as
    // the renderer places it; a NaN sample (a fault) has no place.
    if (!p_Ss.allFinite() || (is_pose && !q_Ss.coeffs().allFinite())) continue;
    const Eigen::Vector3d p_W = T_WS * p_Ss;
    const Eigen::Quaterniond q_W =
        is_pose ? Eigen::Quaterniond(T_WS.linear() * q_Ss.normalized().toRotationMatrix())
                : Eigen::Quaterniond::Identity();
    out.Add(topic + "/world", "foxglove.PoseInFrame", t_ns, arrival_ns,
            PoseInFrame(t_ns, kWorldFrame, p_W, q_W.normalized()));
  }
}

void ExportSensors(const RunData& run, Channels& out) {
  for (const fs::path& file : renders::SensorCsvFiles(run.directory)) {
    const std::string name = file.stem().string();
    const std::string topic = "/sensors/" + name;
    const CsvTable csv(file, std::string(replay::kSensorCsvForm));
    const SensorCsvColumns columns = replay::LocateSensorCsvColumns(csv.keys(), csv.file());
    if (columns.kind() == core::MeasurementKind::kImu) {
      ExportImuSamples(csv, columns, topic, out);
    } else {
      ExportMeasurements(run, name, csv, columns, topic, out);
    }
  }
}

// ---- estimates, errors, decisions, consistency ----

// The estimate_<method>.csv files of a run directory (not their _errors.csv), by name.
std::vector<fs::path> EstimateCsvFiles(const fs::path& directory) {
  std::vector<fs::path> files;
  for (const auto& entry : fs::directory_iterator(directory)) {
    const std::string name = entry.path().filename().string();
    if (entry.is_regular_file() && name.rfind("estimate_", 0) == 0 && name.ends_with(".csv") &&
        !name.ends_with("_errors.csv")) {
      files.push_back(entry.path());
    }
  }
  std::sort(files.begin(), files.end());
  return files;
}

// The method's name as its .json beside the CSV gives it, else the file's stem.
std::string EstimateMethodName(const RunData& run, const fs::path& file) {
  const std::string stem = file.stem().string();
  std::string method = stem.substr(std::string("estimate_").size());
  const fs::path json_path = run.directory / (stem + ".json");
  if (fs::exists(json_path)) {
    const nlohmann::json j = renders::ReadRunJson(json_path);
    if (j.is_object() && j.contains("method") && j["method"].is_string()) method = j["method"];
  }
  return method;
}

void ExportEstimateFile(const RunData& run, const fs::path& file, Channels& out) {
  const std::string method = EstimateMethodName(run, file);
  const CsvTable csv(file, "#timestamp [ns],p_LI_x [m],...,valid,fused");
  const int t = csv.Require("timestamp");
  const auto columns = [&](std::initializer_list<const char*> keys) {
    std::vector<int> c;
    for (const char* k : keys) c.push_back(csv.Require(k));
    return c;
  };
  const std::vector<int> p = columns({"p_LI_x", "p_LI_y", "p_LI_z"});
  const std::vector<int> q = columns({"q_LI_w", "q_LI_x", "q_LI_y", "q_LI_z"});
  const std::vector<int> v = columns({"v_L_x", "v_L_y", "v_L_z"});
  const std::vector<int> ba = columns({"b_a_x", "b_a_y", "b_a_z"});
  const std::vector<int> bg = columns({"b_g_x", "b_g_y", "b_g_z"});
  const std::vector<int> sp = columns({"std_p_x", "std_p_y", "std_p_z"});
  const int valid = csv.Require("valid");
  const int fused = csv.Find("fused");
  const auto vec = [&](std::size_t r, const std::vector<int>& c) {
    return Eigen::Vector3d(csv.Double(r, c[0], true), csv.Double(r, c[1], true),
                           csv.Double(r, c[2], true));
  };
  const std::string topic = "/estimates/" + method;
  for (std::size_t r = 0; r < csv.rows(); ++r) {
    const core::Time t_ns = csv.Int(r, t);
    JsonText j;
    j.Begin();
    j.Time("timestamp", t_ns);
    j.String("frame_id", "L");
    j.Pose("pose", vec(r, p),
           Eigen::Quaterniond(csv.Double(r, q[0]), csv.Double(r, q[1]), csv.Double(r, q[2]),
                              csv.Double(r, q[3])));
    j.Vector("velocity_mps", vec(r, v));
    j.Vector("accel_bias_mps2", vec(r, ba));
    j.Vector("gyro_bias_radps", vec(r, bg));
    j.Vector("position_std_m", vec(r, sp));
    j.Bool("valid", csv.Text(r, valid) == "1");
    j.Strings("fused", SplitLabels(fused >= 0 ? csv.Text(r, fused) : "", '+'));
    j.End();
    out.Add(topic, "tofu.Estimate", t_ns, t_ns, j.str());
  }
  // T_WB of the valid rows, as the renderer's ghost (the evaluation's alignment T_WL).
  const auto estimate = std::find_if(run.estimates.begin(), run.estimates.end(),
                                     [&](const renders::MethodEstimate& e) { return e.method == method; });
  if (estimate == run.estimates.end()) return;
  for (const TimedPose& T_WB : estimate->T_WB) {
    out.Add(topic + "/world", "foxglove.PoseInFrame", T_WB.t_ns, T_WB.t_ns,
            PoseInFrame(T_WB.t_ns, kWorldFrame, T_WB.p_W, T_WB.q_W));
  }
}

void ExportErrors(const RunData& run, Channels& out) {
  for (const renders::ErrorRow& e : run.errors) {
    JsonText j;
    j.Begin();
    j.Time("timestamp", e.t_ns);
    j.Number("position_error_m", e.position_error_m);
    j.Number("rotation_error_deg", e.rotation_error_deg);
    j.End();
    out.Add("/errors/" + e.method, "tofu.EstimateError", e.t_ns, e.t_ns, j.str());
  }
}

void ExportDecisions(const RunData& run, Channels& out) {
  for (const renders::DecisionRow& d : run.decisions) {
    JsonText j;
    j.Begin();
    j.Time("timestamp", d.t_ns);
    j.String("method", d.method);
    j.Strings("fused", d.fused);
    j.Strings("excluded", d.excluded);
    j.Strings("unavailable", d.unavailable);
    j.String("reason", d.reason);
    j.End();
    out.Add("/consensus/decisions", "tofu.ConsensusDecision", d.t_ns, d.t_ns, j.str());
  }
}

// One matrix per evaluation: the rows of one time stamp.
void ExportConsistency(const RunData& run, Channels& out) {
  for (const auto& [method, rows] : run.consistency) {
    const std::string topic = "/consensus/consistency/" + (method.empty() ? "run" : method);
    std::size_t i = 0;
    while (i < rows.size()) {
      const core::Time t_ns = rows[i].t_ns;
      JsonText j;
      j.Begin();
      j.Time("timestamp", t_ns);
      j.Key("entries");
      j.BeginArray();
      for (; i < rows.size() && rows[i].t_ns == t_ns; ++i) {
        j.Begin();
        j.String("a", rows[i].a);
        j.String("b", rows[i].b);
        j.String("metric", rows[i].metric);
        j.Number("value", rows[i].value);
        j.End();
      }
      j.EndArray();
      j.End();
      out.Add(topic, "tofu.ConsistencyMatrix", t_ns, t_ns, j.str());
    }
  }
}

void ExportEstimates(const RunData& run, Channels& out) {
  for (const fs::path& file : EstimateCsvFiles(run.directory)) ExportEstimateFile(run, file, out);
  ExportErrors(run, out);
  ExportDecisions(run, out);
  ExportConsistency(run, out);
}

// ---- labels, failure events, closed-loop flights ----

void ExportLabelsAndEvents(const RunData& run, Channels& out) {
  for (std::size_t i = 0; i < run.labels.size(); ++i) {
    const renders::LabelRow& l = run.labels[i];
    const bool fault = l.source == "fault";
    const int level = l.active ? (fault ? kError : kWarning) : kInfo;
    out.Add("/labels", "foxglove.Log", l.t_ns, l.t_ns,
            LogMessage(l.t_ns, level,
                       fmt::format("{} {} {} {}", l.sensor, l.source, l.label,
                                   l.active ? "starts" : "ends"),
                       l.sensor, "labels.csv", static_cast<int>(i) + 2));
  }
  for (const renders::RenderEvent& e : renders::FindEvents(run)) {
    const bool severe = e.kind == renders::EventKind::kCollision ||
                        e.kind == renders::EventKind::kFaultOnset;
    out.Add("/events", "foxglove.Log", e.t_ns, e.t_ns,
            LogMessage(e.t_ns, severe ? kError : kWarning,
                       fmt::format("{}: {}", renders::EventKindName(e.kind), e.detail), e.subject,
                       "", 0));
  }

  for (const fs::path& dir : renders::ClosedLoopFlightDirs(run.directory)) {
    const std::string stem = dir.filename().string();
    const auto ghost = std::find_if(run.estimates.begin(), run.estimates.end(),
                                    [&](const renders::MethodEstimate& e) {
                                      return e.method == "flown on " + stem;
                                    });
    if (ghost != run.estimates.end()) {
      for (const TimedPose& T_WB : ghost->T_WB) {
        out.Add("/closed_loop/" + stem + "/groundtruth", "foxglove.PoseInFrame", T_WB.t_ns,
                T_WB.t_ns, PoseInFrame(T_WB.t_ns, kWorldFrame, T_WB.p_W, T_WB.q_W));
      }
    }
    const fs::path events = dir / "events.csv";
    if (!fs::exists(events)) continue;
    const CsvTable csv(events, "#timestamp [ns],event,detail",
                       replay::CsvOptions{.last_column_takes_rest = true});
    const int t = csv.Require("timestamp");
    const int event = csv.Require("event");
    const int detail = csv.Find("detail");
    for (std::size_t r = 0; r < csv.rows(); ++r) {
      const std::string kind(csv.Text(r, event));
      const core::Time t_ns = csv.Int(r, t);
      const std::string text(detail >= 0 ? csv.Text(r, detail) : "");
      out.Add("/closed_loop/" + stem + "/events", "foxglove.Log", t_ns, t_ns,
              LogMessage(t_ns, kind.rfind("failsafe", 0) == 0 ? kWarning : kInfo,
                         text.empty() ? kind : kind + ": " + text, "flown on " + stem,
                         "closed_loop/" + stem + "/events.csv", csv.Line(r)));
    }
  }
}

// ---- the scene: the world's geoms in W and the robot's in base_link ----

struct Primitive {
  Eigen::Vector3d p;
  Eigen::Quaterniond q;
  std::array<float, 4> rgba;
};

// The primitives of one scene entity, each a JSON array of foxglove primitives.
struct ScenePrimitives {
  JsonText cubes, cylinders, spheres;
};

// Geom `type` of half-sizes `size` (MuJoCo's) at p, q, as the primitives that draw it.
void AddGeom(ScenePrimitives& lists, int type, const mjtNum* size, const Eigen::Vector3d& p,
             const Eigen::Quaterniond& q, const std::array<float, 4>& rgba) {
  const auto primitive = [&](JsonText& list, const Eigen::Vector3d& at, const Eigen::Vector3d& extent,
                             bool cylinder) {
    list.Begin();
    list.Pose("pose", at, q);
    list.Vector("size", extent);
    if (cylinder) {
      list.Number("bottom_scale", 1.0);
      list.Number("top_scale", 1.0);
    }
    list.Color("color", rgba);
    list.End();
  };
  switch (type) {
    case mjGEOM_PLANE: {
      // A plane of size 0 is infinite; draw 40 m of it.
      const double sx = size[0] > 0 ? 2.0 * size[0] : 40.0;
      const double sy = size[1] > 0 ? 2.0 * size[1] : 40.0;
      primitive(lists.cubes, p - q * Eigen::Vector3d(0, 0, 0.005), {sx, sy, 0.01}, false);
      break;
    }
    case mjGEOM_BOX:
      primitive(lists.cubes, p, 2.0 * Eigen::Vector3d(size[0], size[1], size[2]), false);
      break;
    case mjGEOM_SPHERE:
      primitive(lists.spheres, p, Eigen::Vector3d::Constant(2.0 * size[0]), false);
      break;
    case mjGEOM_ELLIPSOID:
      primitive(lists.spheres, p, 2.0 * Eigen::Vector3d(size[0], size[1], size[2]), false);
      break;
    case mjGEOM_CYLINDER:
      primitive(lists.cylinders, p, {2.0 * size[0], 2.0 * size[0], 2.0 * size[1]}, true);
      break;
    case mjGEOM_CAPSULE: {
      // A cylinder and its two hemispherical caps (as spheres).
      primitive(lists.cylinders, p, {2.0 * size[0], 2.0 * size[0], 2.0 * size[1]}, true);
      const Eigen::Vector3d axis = q * Eigen::Vector3d(0, 0, size[1]);
      primitive(lists.spheres, p + axis, Eigen::Vector3d::Constant(2.0 * size[0]), false);
      primitive(lists.spheres, p - axis, Eigen::Vector3d::Constant(2.0 * size[0]), false);
      break;
    }
    default:
      break;  // meshes and height fields: none in tofu's models
  }
}

// The visible geoms of the model at its initial state: the world's in W, the robot's (the
// tree of `robot_body`, -1: none) in its base frame B0 (p_WB0, q_WB0).
void CollectGeoms(const mjModel* m, const mjData* d, int robot_body, const Eigen::Vector3d& p_WB0,
                  const Eigen::Quaterniond& q_WB0, ScenePrimitives& world, ScenePrimitives& robot) {
  for (JsonText* j : {&world.cubes, &world.cylinders, &world.spheres, &robot.cubes,
                      &robot.cylinders, &robot.spheres}) {
    j->BeginArray();
  }
  for (int g = 0; g < m->ngeom; ++g) {
    // MuJoCo's viewer shows groups 0-2 by default; the robot's collision proxies (group 2)
    // are hidden and its visuals (3) shown, as models/robots/omav.xml asks of renders.
    const int group = m->geom_group[g];
    const bool is_robot = robot_body >= 0 && m->body_rootid[m->geom_bodyid[g]] == robot_body;
    if (group == 2 || group > 4) continue;
    std::array<float, 4> rgba;
    const int material = m->geom_matid[g];
    const float* c = material >= 0 ? m->mat_rgba + 4 * material : m->geom_rgba + 4 * g;
    std::copy(c, c + 4, rgba.begin());
    if (rgba[3] <= 0.0f) continue;
    const Eigen::Vector3d p_W(d->geom_xpos[3 * g], d->geom_xpos[3 * g + 1], d->geom_xpos[3 * g + 2]);
    Eigen::Matrix3d R_W;
    for (int r = 0; r < 3; ++r) {
      for (int k = 0; k < 3; ++k) R_W(r, k) = d->geom_xmat[9 * g + 3 * r + k];
    }
    Eigen::Vector3d p = p_W;
    Eigen::Quaterniond q(R_W);
    if (is_robot) {
      p = q_WB0.conjugate() * (p_W - p_WB0);
      q = q_WB0.conjugate() * q;
    }
    AddGeom(is_robot ? robot : world, m->geom_type[g], m->geom_size + 3 * g, p, q, rgba);
  }
  for (JsonText* j : {&world.cubes, &world.cylinders, &world.spheres, &robot.cubes,
                      &robot.cylinders, &robot.spheres}) {
    j->EndArray();
  }
}

// A foxglove SceneEntity drawing `primitives` in `frame`, from t0 on.
void AddSceneEntity(JsonText& j, core::Time t0, const char* id, const char* frame,
                    const ScenePrimitives& primitives) {
  j.Begin();
  j.Time("timestamp", t0);
  j.String("frame_id", frame);
  j.String("id", id);
  j.Time("lifetime", 0);  // forever
  j.Bool("frame_locked", std::string_view(frame) != kWorldFrame);
  j.Raw("metadata", "[]");
  j.Raw("arrows", "[]");
  j.Raw("cubes", primitives.cubes.str());
  j.Raw("spheres", primitives.spheres.str());
  j.Raw("cylinders", primitives.cylinders.str());
  j.Raw("lines", "[]");
  j.Raw("triangles", "[]");
  j.Raw("texts", "[]");
  j.Raw("models", "[]");
  j.End();
}

void ExportScene(const RunData& run, Channels& out) {
  sim::WorldOptions options;
  options.world = run.world;
  options.robot = run.robot;
  const sim::World world(options);
  const mjModel* m = world.model();
  mjData* d = mj_makeData(m);
  mj_forward(m, d);
  const int root_joint = mj_name2id(m, mjOBJ_JOINT, "root");
  const int robot_body = root_joint >= 0 ? m->body_rootid[m->jnt_bodyid[root_joint]] : -1;
  const Eigen::Vector3d p_WB0(d->xpos[3 * std::max(robot_body, 0)], d->xpos[3 * std::max(robot_body, 0) + 1],
                              d->xpos[3 * std::max(robot_body, 0) + 2]);
  const mjtNum* xq = d->xquat + 4 * std::max(robot_body, 0);
  const Eigen::Quaterniond q_WB0(xq[0], xq[1], xq[2], xq[3]);

  ScenePrimitives world_primitives, robot_primitives;
  CollectGeoms(m, d, robot_body, p_WB0, q_WB0, world_primitives, robot_primitives);
  mj_deleteData(d);

  const core::Time t0 = run.start_ns();
  JsonText scene;
  scene.Begin();
  scene.Raw("deletions", "[]");
  scene.Key("entities");
  scene.BeginArray();
  AddSceneEntity(scene, t0, "world", kWorldFrame, world_primitives);
  AddSceneEntity(scene, t0, "robot", kBodyFrame, robot_primitives);
  scene.EndArray();
  scene.End();
  out.Add("/scene", "foxglove.SceneUpdate", t0, t0, scene.str());
}


}  // namespace

McapExportResult ExportRunToMcap(const fs::path& run_dir, const fs::path& mcap_file,
                                 const McapExportOptions& options) {
  const RunData run = renders::ReadRunData(run_dir);
  if (mcap_file.has_parent_path() && !fs::is_directory(mcap_file.parent_path())) {
    throw core::IoError(fmt::format("cannot write {}: {} is not a directory", mcap_file.string(),
                                    mcap_file.parent_path().string()));
  }
  const fs::path partial = mcap_file.string() + ".partial";
  McapExportResult result;
  try {
    McapWriterOptions writer_options;
    writer_options.compression = options.compression;
    McapWriter writer(partial, writer_options);
    Channels channels(writer);
    ExportScene(run, channels);
    ExportGroundTruth(run, channels);
    ExportSensors(run, channels);
    ExportEstimates(run, channels);
    ExportLabelsAndEvents(run, channels);
    writer.AddMetadata("scenario", {{"name", run.scenario_name},
                                    {"world", run.world},
                                    {"robot", run.robot},
                                    {"scenario.yaml", core::ReadWholeFile(run_dir / "scenario.yaml", "scenario file")}});
    writer.AddMetadata("tofu", {{"version", TOFU_VERSION_STRING},
                                {"run", fs::absolute(run_dir).lexically_normal().filename().string()}});
    writer.Close();
    result.messages_per_topic = channels.counts();
    result.messages = writer.statistics().message_count;
  } catch (...) {
    std::error_code ignored;
    fs::remove(partial, ignored);
    throw;
  }
  std::error_code ec;
  fs::rename(partial, mcap_file, ec);
  if (ec) {
    fs::remove(partial, ec);
    throw core::IoError(fmt::format("cannot write {}: {}", mcap_file.string(), ec.message()));
  }
  result.bytes = fs::file_size(mcap_file);
  return result;
}

}  // namespace tofu::report
