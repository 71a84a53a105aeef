#include "corpus/episode_writer.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <tuple>

#include <fmt/format.h>

#include "harness/evaluation.h"
#include "harness/scenario.h"
#include "replay/labels.h"
#include "sim/faults.h"
#include "sim/sensor.h"

namespace tofu::corpus {
namespace {

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

void Append(std::vector<double>& out, const Eigen::Vector3d& v) { out.insert(out.end(), {v.x(), v.y(), v.z()}); }
void Append(std::vector<double>& out, const Eigen::Quaterniond& q) { out.insert(out.end(), {q.w(), q.x(), q.y(), q.z()}); }

template <int N>
void AppendUpper(std::vector<double>& out, const Eigen::Matrix<double, N, N>& c) {
  for (int r = 0; r < N; ++r) {
    for (int k = r; k < N; ++k) out.push_back(c(r, k));
  }
}

template <int N>
std::string UpperColumns(const std::string& prefix) {
  std::string out;
  for (int r = 0; r < N; ++r) {
    for (int k = r; k < N; ++k) out += fmt::format("{}{}{}{}", out.empty() ? "" : ",", prefix, r, k);
  }
  return out;
}

std::string Join(const std::vector<std::string>& items, const char* separator = ",") {
  std::string out;
  for (const std::string& s : items) out += (out.empty() ? "" : separator) + s;
  return out;
}

// Bit i set for each of `names` found at position i of `order`.
std::uint32_t Mask(const std::vector<std::string>& names, const std::vector<std::string>& order) {
  std::uint32_t mask = 0;
  for (const std::string& n : names) {
    const auto it = std::find(order.begin(), order.end(), n);
    if (it != order.end() && it - order.begin() < 32) mask |= 1u << (it - order.begin());
  }
  return mask;
}

std::string BitNames(bool faults) {
  std::vector<std::string> names;
  if (faults) {
    for (const sim::FaultKind k : sim::AllFaultKinds()) names.emplace_back(sim::FaultKindName(k));
  } else {
    for (const sim::Condition c : sim::AllConditions()) names.emplace_back(sim::ConditionName(c));
  }
  return Join(names);
}

void WriteGroundTruth(const Hdf5Group& group, const std::vector<sim::TruthState>& truth) {
  std::vector<std::int64_t> t;
  std::vector<double> p, q, v, w;
  for (const sim::TruthState& s : truth) {
    t.push_back(s.t_ns);
    Append(p, s.p_WB);
    Append(q, s.q_WB);
    Append(v, s.v_WB_W);
    Append(w, s.omega_WB_B);
  }
  group.WriteInt64("t_ns", t);
  group.WriteDouble("p_WB_m", p, 3);
  group.WriteDouble("q_WB_wxyz", q, 4);
  group.WriteDouble("v_WB_W_mps", v, 3);
  group.WriteDouble("omega_WB_B_radps", w, 3);
}

void WriteSensor(const Hdf5Group& group, const harness::SensorStream& stream) {
  std::vector<std::int64_t> t, arrival;
  std::vector<double> values, covariance;
  std::vector<std::uint32_t> faults, conditions;
  std::vector<std::uint8_t> anomaly;
  std::string value_columns, covariance_columns;
  std::size_t value_width = 0, covariance_width = 0;
  for (std::size_t i = 0; i < stream.delivered.size(); ++i) {
    const sim::SensorSample& s = stream.delivered[i];
    t.push_back(s.t_ns);
    arrival.push_back(s.arrival_ns);
    const std::uint32_t fault_bits = i < stream.delivered_faults.size() ? stream.delivered_faults[i] : 0u;
    faults.push_back(fault_bits);
    conditions.push_back(s.conditions);
    anomaly.push_back(fault_bits != 0 || s.conditions != 0 ? 1 : 0);
    if (const auto* imu = std::get_if<core::ImuMeasurement>(&s.measured)) {
      Append(values, imu->gyro_I_radps);
      Append(values, imu->acc_I_mps2);
      value_columns = "w_x,w_y,w_z [rad/s],a_x,a_y,a_z [m/s^2] (in the IMU frame)";
      value_width = 6;
    } else if (const auto* pose = std::get_if<core::PoseMeasurement>(&s.measured)) {
      Append(values, pose->p_Ss);
      Append(values, pose->q_Ss);
      Append(values, pose->has_twist ? pose->v_s_s_mps : Eigen::Vector3d::Constant(kNaN));
      Append(values, pose->has_twist ? pose->omega_s_s_radps : Eigen::Vector3d::Constant(kNaN));
      AppendUpper<6>(covariance, pose->covariance);
      AppendUpper<6>(covariance, pose->has_twist ? pose->twist_covariance
                                              : Eigen::Matrix<double, 6, 6>::Constant(kNaN).eval());
      value_columns = "p_Ss_x,p_Ss_y,p_Ss_z [m],q_Ss_w,q_Ss_x,q_Ss_y,q_Ss_z,v_s_x,v_s_y,v_s_z [m/s],"
                      "omega_s_x,omega_s_y,omega_s_z [rad/s] (NaN twist: none reported)";
      covariance_columns = UpperColumns<6>("pose_") + "," + UpperColumns<6>("twist_") +
                           " (upper triangles, row-major; pose: [dtheta rad; dp m], twist: [v; omega])";
      value_width = 13;
      covariance_width = 42;
    } else if (const auto* position = std::get_if<core::PositionMeasurement>(&s.measured)) {
      Append(values, position->p_Ss);
      AppendUpper<3>(covariance, position->covariance);
      value_columns = "p_Ss_x,p_Ss_y,p_Ss_z [m]";
      covariance_columns = UpperColumns<3>("p_") + " (upper triangle, row-major, m^2)";
      value_width = 3;
      covariance_width = 6;
    }
  }
  group.SetAttribute("type", stream.type);
  group.SetAttribute("site", stream.site);
  group.WriteInt64("t_ns", t);
  group.WriteInt64("arrival_ns", arrival);
  group.WriteDouble("values", values, value_width == 0 ? 1 : value_width);
  group.SetDatasetAttribute("values", "columns", value_columns);
  if (covariance_width > 0) {
    group.WriteDouble("covariance", covariance, covariance_width);
    group.SetDatasetAttribute("covariance", "columns", covariance_columns);
  }
  group.WriteUInt32("fault_mask", faults);
  group.SetDatasetAttribute("fault_mask", "bits", BitNames(true));
  group.WriteUInt32("condition_mask", conditions);
  group.SetDatasetAttribute("condition_mask", "bits", BitNames(false));
  group.WriteUInt8("anomaly", anomaly);
  group.SetDatasetAttribute("anomaly", "meaning", "1: a scheduled fault or a physical condition is active");
}

// The fault-event table: each label of labels.csv from its start to its end (or the
// episode's end), with its cause, severity (scheduled: the plan's magnitude) and the
// flight phase (trajectory segment) at onset.
struct FaultEvent {
  std::string sensor, label, cause, phase;
  core::Time onset_ns = 0, offset_ns = 0;
  bool open = false;
  double severity = kNaN;
};

std::vector<FaultEvent> FaultEvents(const harness::RunRecord& record, const EpisodePlan& plan) {
  const core::Time end_ns = record.groundtruth.empty() ? 0 : record.groundtruth.back().t_ns;
  std::vector<FaultEvent> events;
  const auto phase_at = [&](core::Time t) {
    for (const sim::SegmentInfo& s : record.segments) {
      if (t >= s.start_ns && t < s.end_ns) return s.kind;
    }
    return std::string("end");
  };
  const auto close = [&](const std::string& sensor, const std::string& label, const std::string& source,
                         core::Time onset, core::Time offset, bool open) {
    FaultEvent e;
    e.sensor = sensor;
    e.label = label;
    e.cause = source == "fault" ? "scheduled" : "physical";
    e.onset_ns = onset;
    e.offset_ns = offset;
    e.open = open;
    e.phase = phase_at(onset);
    if (source == "fault") {
      // The first sample in a fault's window carries its label, so the fault is the one of
      // this sensor and kind that started last at or before the onset.
      core::Time best_start = -1;
      for (const PlannedFault& f : plan.faults) {
        const core::Time start = static_cast<core::Time>(std::llround(f.start_s * 1e9));
        const bool sized = f.kind != sim::FaultKind::kDropout && f.kind != sim::FaultKind::kFreeze;
        if (f.sensor == sensor && sim::FaultKindName(f.kind) == label && start <= onset && start > best_start) {
          best_start = start;
          e.severity = sized ? f.magnitude : kNaN;
        }
      }
    }
    events.push_back(e);
  };
  // Two scheduled faults of one kind on one sensor may overlap: their labels then read
  // start, start, end, end. Each start is its own event, closed by the next end in order
  // (first in, first out), so every fault keeps its row and its severity. The pairing is
  // the evaluation's (harness/evaluation.h), which scores the merged intervals.
  for (const replay::LabelInterval& i : replay::PairedLabelIntervals(record.labels, end_ns)) {
    close(i.sensor, i.label, i.source, i.start_ns, i.end_ns, i.open);
  }
  std::stable_sort(events.begin(), events.end(), [](const FaultEvent& a, const FaultEvent& b) {
    return std::tie(a.onset_ns, a.sensor, a.label) < std::tie(b.onset_ns, b.sensor, b.label);
  });
  return events;
}

void WriteEvents(const Hdf5Group& group, const std::vector<FaultEvent>& events) {
  std::vector<std::string> sensor, label, cause, phase;
  std::vector<std::int64_t> onset, offset;
  std::vector<std::uint8_t> open;
  std::vector<double> severity;
  for (const FaultEvent& e : events) {
    sensor.push_back(e.sensor);
    label.push_back(e.label);
    cause.push_back(e.cause);
    phase.push_back(e.phase);
    onset.push_back(e.onset_ns);
    offset.push_back(e.offset_ns);
    open.push_back(e.open ? 1 : 0);
    severity.push_back(e.severity);
  }
  group.WriteStrings("sensor", sensor);
  group.WriteStrings("kind", label);
  group.WriteStrings("cause", cause);
  group.WriteStrings("phase", phase);
  group.WriteInt64("onset_ns", onset);
  group.WriteInt64("offset_ns", offset);
  group.WriteUInt8("open", open);
  group.WriteDouble("severity", severity);
}

void WriteMethod(const Hdf5Group& group, const replay::ReplayResult& result,
                 const std::vector<std::string>& sensors) {
  std::vector<std::int64_t> t;
  std::vector<double> p, q, v, ba, bg, std_p;
  std::vector<std::uint8_t> valid;
  std::vector<std::uint32_t> fused;
  replay::ForEachOutput(result, [&](const estimator::EstimatorOutput& o) {
    t.push_back(o.t_ns);
    Append(p, o.state.p_LI);
    Append(q, o.state.q_LI);
    Append(v, o.state.v_L_mps);
    Append(ba, o.bias.accel_mps2);
    Append(bg, o.bias.gyro_radps);
    if (o.position_covariance_m2) {
      Append(std_p, o.position_covariance_m2->diagonal().cwiseSqrt());
    } else {
      Append(std_p, Eigen::Vector3d::Constant(kNaN));
    }
    valid.push_back(o.valid ? 1 : 0);
    fused.push_back(Mask(o.fused, sensors));
  });
  group.SetAttribute("method", result.method.name);
  group.WriteInt64("t_ns", t);
  group.WriteDouble("p_LI_m", p, 3);
  group.WriteDouble("q_LI_wxyz", q, 4);
  group.WriteDouble("v_L_mps", v, 3);
  group.WriteDouble("accel_bias_mps2", ba, 3);
  group.WriteDouble("gyro_bias_radps", bg, 3);
  group.WriteDouble("position_std_m", std_p, 3);
  group.WriteUInt8("valid", valid);
  group.WriteUInt32("fused_mask", fused);
  group.SetDatasetAttribute("fused_mask", "bits", Join(sensors));
  if (result.consensus.empty()) return;

  // Predictions: what consensus decided and the values behind it.
  const Hdf5Group decisions = group.CreateGroup("decisions");
  std::vector<std::int64_t> dt, ct;
  std::vector<std::uint32_t> df, de, du;
  std::vector<std::string> reason, pair;
  std::vector<double> value;
  for (const estimator::ConsensusRecord& r : result.consensus) {
    dt.push_back(r.t_ns);
    df.push_back(Mask(r.decision.fused, sensors));
    de.push_back(Mask(r.decision.excluded, sensors));
    du.push_back(Mask(r.decision.unavailable, sensors));
    reason.push_back(r.decision.reason);
    for (const auto& [name, metric_value] : r.values) {
      ct.push_back(r.t_ns);
      pair.push_back(name);
      value.push_back(metric_value.value_or(kNaN));
    }
  }
  decisions.WriteInt64("t_ns", dt);
  decisions.WriteUInt32("fused_mask", df);
  decisions.WriteUInt32("excluded_mask", de);
  decisions.WriteUInt32("unavailable_mask", du);
  decisions.WriteStrings("reason", reason);
  for (const char* d : {"fused_mask", "excluded_mask", "unavailable_mask"}) decisions.SetDatasetAttribute(d, "bits", Join(sensors));
  const Hdf5Group consistency = group.CreateGroup("consistency");
  consistency.WriteInt64("t_ns", ct);
  consistency.WriteStrings("pair", pair);
  consistency.WriteDouble("value", value);
}

std::string Hex(std::uint64_t h) { return fmt::format("{:016x}", h); }

}  // namespace

ManifestRow WriteEpisode(const Hdf5Group& parent, const EpisodePlan& plan,
                         const harness::RunRecord& record, const nlohmann::json& summary) {
  const Hdf5Group episode = parent.CreateGroup(plan.id);
  std::vector<std::string> sensors;
  for (const harness::SensorStream& s : record.sensors) sensors.push_back(s.name);

  WriteGroundTruth(episode.CreateGroup("groundtruth"), record.groundtruth);
  const Hdf5Group sensor_group = episode.CreateGroup("sensors");
  std::size_t samples = 0;
  for (const harness::SensorStream& s : record.sensors) {
    WriteSensor(sensor_group.CreateGroup(s.name), s);
    samples += s.delivered.size();
  }
  const std::vector<FaultEvent> events = FaultEvents(record, plan);
  WriteEvents(episode.CreateGroup("events"), events);
  const Hdf5Group methods = episode.CreateGroup("methods");
  for (const replay::ReplayResult& r : record.in_loop) {
    // A method's name may hold ':' and '@' ("single:vio@clean"); the group is its file-safe
    // form, the attribute `method` the name.
    std::string safe = r.method.name;
    std::replace_if(safe.begin(), safe.end(), [](char c) { return c == ':' || c == '/' || c == '+' || c == ' '; }, '_');
    WriteMethod(methods.CreateGroup(safe), r, sensors);
  }
  if (!record.closed_loop_flights.empty()) {
    const Hdf5Group flights = episode.CreateGroup("closed_loop");
    for (const harness::RunRecord& flight : record.closed_loop_flights) {
      if (!flight.closed_loop) continue;
      std::string safe = flight.closed_loop->method;
      std::replace_if(safe.begin(), safe.end(), [](char c) { return c == ':' || c == '/' || c == '+' || c == ' '; }, '_');
      const Hdf5Group g = flights.CreateGroup(safe);
      g.SetAttribute("method", flight.closed_loop->method);
      WriteGroundTruth(g.CreateGroup("groundtruth"), flight.groundtruth);
      g.SetAttribute("collisions", static_cast<std::int64_t>(flight.collisions.size()));
    }
  }

  ManifestRow row;
  row.index = plan.index;
  row.id = plan.id;
  row.scenario_seed = plan.scenario_seed;
  row.world = plan.world;
  row.family = plan.family;
  row.duration_s = record.scenario.duration_s;
  for (const FaultEvent& e : events) (e.cause == "scheduled" ? row.scheduled_faults : row.physical_events) += 1;
  row.samples = samples;
  row.collisions = record.collisions.size();
  if (summary.contains("methods") && summary["methods"].is_object()) {
    for (const auto& [method, scores] : summary["methods"].items()) {
      row.ate_m[method] = scores.contains("ate_m") && scores["ate_m"].is_number() ? scores["ate_m"].get<double>() : kNaN;
    }
  }
  row.content_hash = Hex(episode.ContentHash());

  episode.SetAttribute("index", static_cast<std::int64_t>(plan.index));
  episode.SetAttribute("id", plan.id);
  episode.SetAttribute("scenario_yaml", plan.scenario_yaml);
  episode.SetAttribute("resolved_scenario_yaml", harness::ResolvedScenarioYaml(record.scenario));
  episode.SetAttribute("scenario_seed", std::to_string(plan.scenario_seed));
  episode.SetAttribute("world", plan.world);
  episode.SetAttribute("family", plan.family);
  episode.SetAttribute("duration_s", row.duration_s);
  episode.SetAttribute("sensors", Join(sensors));
  episode.SetAttribute("manifest", ManifestJson(row).dump());
  episode.SetAttribute("content_hash", row.content_hash);
  return row;
}

ManifestRow ReadManifestRow(const Hdf5Group& episode) {
  const nlohmann::json j = nlohmann::json::parse(episode.StringAttribute("manifest"));
  ManifestRow row;
  row.index = j.at("index").get<std::uint64_t>();
  row.id = j.at("id").get<std::string>();
  row.scenario_seed = std::stoull(j.at("scenario_seed").get<std::string>());
  row.world = j.at("world").get<std::string>();
  row.family = j.at("family").get<std::string>();
  row.duration_s = j.at("duration_s").get<double>();
  row.scheduled_faults = j.at("scheduled_faults").get<std::size_t>();
  row.physical_events = j.at("physical_events").get<std::size_t>();
  row.samples = j.at("samples").get<std::size_t>();
  row.collisions = j.at("collisions").get<std::size_t>();
  for (const auto& [m, v] : j.at("ate_m").items()) row.ate_m[m] = v.is_number() ? v.get<double>() : kNaN;
  row.content_hash = j.at("content_hash").get<std::string>();
  return row;
}

nlohmann::ordered_json ManifestJson(const ManifestRow& row) {
  nlohmann::ordered_json ate = nlohmann::ordered_json::object();
  for (const auto& [m, v] : row.ate_m) ate[m] = std::isfinite(v) ? nlohmann::ordered_json(v) : nlohmann::ordered_json();
  nlohmann::ordered_json j = {{"index", row.index},
                              {"id", row.id},
                              {"scenario_seed", std::to_string(row.scenario_seed)},
                              {"world", row.world},
                              {"family", row.family},
                              {"duration_s", row.duration_s},
                              {"scheduled_faults", row.scheduled_faults},
                              {"physical_events", row.physical_events},
                              {"samples", row.samples},
                              {"collisions", row.collisions},
                              {"ate_m", ate},
                              {"content_hash", row.content_hash}};
  if (!row.shard.empty()) j["shard"] = row.shard;
  return j;
}

std::string ManifestCsvHeader(const std::vector<std::string>& methods) {
  std::string h = "index,id,scenario_seed,world,family,duration_s,scheduled_faults,physical_events,samples,collisions";
  for (const std::string& m : methods) h += ",ate_m_" + m;
  return h + ",content_hash,shard\n";
}

std::string ManifestCsvRow(const ManifestRow& row, const std::vector<std::string>& methods) {
  std::string line = fmt::format("{},{},{},{},{},{},{},{},{},{}", row.index, row.id, row.scenario_seed, row.world,
                                 row.family, row.duration_s, row.scheduled_faults, row.physical_events,
                                 row.samples, row.collisions);
  for (const std::string& m : methods) {
    const auto it = row.ate_m.find(m);
    line += it != row.ate_m.end() && std::isfinite(it->second) ? fmt::format(",{:.6f}", it->second) : ",";
  }
  return line + fmt::format(",{},{}\n", row.content_hash, row.shard);
}

}  // namespace tofu::corpus
