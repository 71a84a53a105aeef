#include "replay/method_writers.h"

#include <algorithm>
#include <cmath>
#include <numeric>
#include <vector>

#include <fmt/format.h>
#include <nlohmann/json.hpp>

#include "core/units.h"
#include "estimator/consistency.h"
#include "replay/file_io.h"

namespace tofu::replay {
namespace {

double Percentile(std::vector<double> values, double fraction) {
  if (values.empty()) return 0.0;
  std::sort(values.begin(), values.end());
  const auto index = static_cast<std::size_t>(
      std::min<double>(values.size() - 1, std::ceil(fraction * values.size()) - 1));
  return values[index];
}


// estimate_<method>.csv, a row per output, written as it is formatted (an hour of
// outputs at 200 Hz is 130 MB of text).
void WriteEstimateCsv(const std::filesystem::path& file, const ReplayResult& result) {
  AtomicFileWriter csv(file);
  csv.Append(
      "#timestamp [ns],p_LI_x [m],p_LI_y [m],p_LI_z [m],q_LI_w [],q_LI_x [],q_LI_y [],"
      "q_LI_z [],v_L_x [m s^-1],v_L_y [m s^-1],v_L_z [m s^-1],b_a_x [m s^-2],b_a_y [m s^-2],"
      "b_a_z [m s^-2],b_g_x [rad s^-1],b_g_y [rad s^-1],b_g_z [rad s^-1],std_p_x [m],"
      "std_p_y [m],std_p_z [m],valid,fused\n");
  ForEachOutput(result, [&](const estimator::EstimatorOutput& o) {
    Eigen::Quaterniond q = o.state.q_LI.normalized();
    if (q.w() < 0) q.coeffs() *= -1.0;
    std::string fused;
    for (const std::string& f : o.fused) fused += (fused.empty() ? "" : "+") + f;
    std::string std_p = ",,";
    if (o.position_covariance_m2) {
      const Eigen::Matrix3d& P = *o.position_covariance_m2;
      std_p = fmt::format("{:.6f},{:.6f},{:.6f}", std::sqrt(P(0, 0)), std::sqrt(P(1, 1)),
                          std::sqrt(P(2, 2)));
    }
    csv.Format(
        "{},{:.6f},{:.6f},{:.6f},{:.9f},{:.9f},{:.9f},{:.9f},{:.6f},{:.6f},{:.6f},{:.6f},{:.6f},"
        "{:.6f},{:.7f},{:.7f},{:.7f},{},{},{}\n",
        o.t_ns, o.state.p_LI.x(), o.state.p_LI.y(), o.state.p_LI.z(), q.w(), q.x(), q.y(), q.z(),
        o.state.v_L_mps.x(), o.state.v_L_mps.y(), o.state.v_L_mps.z(), o.bias.accel_mps2.x(),
        o.bias.accel_mps2.y(), o.bias.accel_mps2.z(), o.bias.gyro_radps.x(),
        o.bias.gyro_radps.y(), o.bias.gyro_radps.z(), std_p, o.valid ? 1 : 0, fused);
  });
  csv.Commit();
}

// Per-sample errors with both trajectories in W (the estimate through the alignment), for
// plots: scripts/plot_estimate.py draws this file.
void WriteErrorsCsv(const std::filesystem::path& file, const TrajectoryErrors& errors,
                    const std::vector<PoseSample>& estimate, const std::vector<PoseSample>& truth) {
  AtomicFileWriter csv(file);
  csv.Append(
      "#timestamp [ns],position_error [m],rotation_error [deg],p_W_est_x [m],p_W_est_y [m],"
      "p_W_est_z [m],p_W_true_x [m],p_W_true_y [m],p_W_true_z [m]\n");
  std::size_t e = 0;
  std::size_t g = 0;
  for (std::size_t k = 0; k < errors.t_ns.size(); ++k) {
    const core::Time t = errors.t_ns[k];
    while (e + 1 < estimate.size() && estimate[e].t_ns < t) ++e;
    while (g + 1 < truth.size() && truth[g + 1].t_ns <= t) ++g;
    const Eigen::Vector3d p_est = errors.T_WL * estimate[e].p;
    Eigen::Vector3d p_true = truth[g].p;
    if (g + 1 < truth.size() && truth[g + 1].t_ns > truth[g].t_ns) {
      const double u = static_cast<double>(t - truth[g].t_ns) /
                       static_cast<double>(truth[g + 1].t_ns - truth[g].t_ns);
      p_true = (1 - u) * truth[g].p + u * truth[g + 1].p;
    }
    csv.Format("{},{:.6f},{:.4f},{:.6f},{:.6f},{:.6f},{:.6f},{:.6f},{:.6f}\n", t,
               errors.position_error_m[k], errors.rotation_error_deg[k], p_est.x(), p_est.y(),
               p_est.z(), p_true.x(), p_true.y(), p_true.z());
  }
  csv.Commit();
}

}  // namespace

std::string DecisionRows(const ReplayResult& result) {
  const auto join = [](const std::vector<std::string>& names) {
    std::string out;
    for (const std::string& n : names) out += (out.empty() ? "" : "+") + n;
    return out;
  };
  std::string rows;
  for (const estimator::ConsensusRecord& r : result.consensus) {
    const estimator::ConsensusDecision& d = r.decision;
    rows += fmt::format("{},{},{},{},{},{}\n", r.t_ns, result.method.name, join(d.fused),
                        join(d.excluded), join(d.unavailable), d.reason);
  }
  return rows;
}

std::string ConsistencyMatrixCsv(const ReplayResult& result) {
  std::string csv = "#timestamp [ns],pair,metric,value\n";
  for (const estimator::ConsensusRecord& r : result.consensus) {
    for (const auto& [pair, value] : r.values) {
      csv += fmt::format("{},{},{},{}\n", r.window_end_ns, pair, estimator::MetricName(r.metric),
                         value ? fmt::format("{:.6g}", *value) : std::string());
    }
  }
  return csv;
}

std::string BiasTestCsv(const ReplayResult& result) {
  std::string csv = "#timestamp [ns],pair,chi2\n";
  for (const estimator::ConsensusRecord& r : result.consensus) {
    for (const auto& [pair, chi2] : r.bias_chi2) {
      csv += fmt::format("{},{},{}\n", r.window_end_ns, pair,
                         chi2 ? fmt::format("{:.6g}", *chi2) : std::string());
    }
  }
  return csv;
}

ConsensusFiles::ConsensusFiles(std::filesystem::path out_dir) : out_dir_(std::move(out_dir)) {}

void ConsensusFiles::Add(const ReplayResult& result) {
  if (result.method.kind != ReplayMethod::Kind::kConsensus) return;
  any_consensus_ = true;
  decisions_csv_ += DecisionRows(result);
  WriteFileAtomically(out_dir_ / ("consistency_" + MethodFileStem(result.method.name) + ".csv"),
                      ConsistencyMatrixCsv(result));
  const bool bias_test = std::any_of(result.consensus.begin(), result.consensus.end(),
                                     [](const auto& r) { return !r.bias_chi2.empty(); });
  if (bias_test) {
    WriteFileAtomically(out_dir_ / ("bias_" + MethodFileStem(result.method.name) + ".csv"),
                        BiasTestCsv(result));
  }
}

void ConsensusFiles::Commit() const {
  if (any_consensus_) WriteFileAtomically(out_dir_ / "decisions.csv", decisions_csv_);
}

namespace {

// How and when the local graph started, and, with ground truth, how wrong its gravity
// direction was.
nlohmann::ordered_json InitialisationJson(const ReplayResult& result, const MethodScores& scores) {
  nlohmann::ordered_json list = nlohmann::ordered_json::array();
  for (std::size_t i = 0; i < result.initialisations.size(); ++i) {
    const estimator::InitialisationRecord& r = result.initialisations[i];
    nlohmann::ordered_json e;
    e["t_ns"] = r.t_ns;
    if (result.first_measurement_ns) {
      e["after_first_sample_s"] = core::TimeToSeconds(r.t_ns - *result.first_measurement_ns);
    }
    e["method"] = estimator::InitialisationMethodName(r.method);
    e["sensor"] = r.sensor;
    e["after_imu_gap"] = r.after_imu_gap;
    if (r.method == estimator::InitialisationRecord::Method::kVisualInertial) {
      e["window_s"] = r.window_s;
      e["gravity_direction_std_deg"] = core::DegFromRad(r.gravity_direction_std_rad);
      e["relative_position_std_m"] = r.relative_position_std_m;
      e["relative_rotation_std_deg"] = core::DegFromRad(r.relative_rotation_std_rad);
    }
    if (const std::optional<double>& error_deg = scores.initialisation_tilt_error_deg[i]) {
      e["gravity_direction_error_deg"] = *error_deg;
    }
    list.push_back(e);
  }
  return list;
}

nlohmann::ordered_json TiltErrorJson(const TiltError& tilt) {
  return {{"rms_deg", tilt.rms_deg}, {"max_deg", tilt.max_deg}, {"final_deg", tilt.final_deg}};
}

nlohmann::ordered_json BiasErrorJson(const BiasError& bias) {
  const auto vec = [](const Eigen::Vector3d& v) { return std::vector<double>{v.x(), v.y(), v.z()}; };
  return {{"gyro_rms_radps", bias.gyro_rms_radps},
          {"accel_rms_mps2", bias.accel_rms_mps2},
          {"gyro_final_radps", vec(bias.gyro_final_radps)},
          {"gyro_true_final_radps", vec(bias.gyro_true_final_radps)},
          {"accel_final_mps2", vec(bias.accel_final_mps2)},
          {"accel_true_final_mps2", vec(bias.accel_true_final_mps2)}};
}


// The ATE block of estimate_<method>.json and of a raw stream's JSON.
nlohmann::ordered_json AteJson(const TrajectoryErrors& errors) {
  return {{"alignment", "se3"},
          {"matched", errors.matched},
          {"position_rmse_m", errors.ate_position_rmse_m},
          {"position_max_m", errors.ate_position_max_m},
          {"rotation_rmse_deg", errors.rotation_rmse_deg},
          {"rpe_delta_s", errors.rpe_delta_s},
          {"rpe_translation_rmse_m", errors.rpe_translation_rmse_m},
          {"rpe_rotation_rmse_deg", errors.rpe_rotation_rmse_deg},
          {"position_step_max_m", errors.position_step_max_m},
          {"position_step_max_t_s", core::TimeToSeconds(errors.position_step_max_t_ns)}};
}

nlohmann::ordered_json PoseJson(const Eigen::Isometry3d& T, const char* p_key, const char* q_key) {
  const Eigen::Quaterniond q(T.linear());
  const Eigen::Vector3d p = T.translation();
  return {{p_key, {p.x(), p.y(), p.z()}}, {q_key, {q.w(), q.x(), q.y(), q.z()}}};
}

// What the estimator did with its input: per-stream counters, the solver's, the frame
// alignments (and the T_AL each sensor was fused with at the end: known, frozen at fusion
// start, or the alignment graph's usable estimate).
void AddEstimatorState(const ReplayResult& result, nlohmann::ordered_json& j) {
  nlohmann::ordered_json streams;
  for (const auto& [name, c] : result.counters.streams) {
    streams[name] = {{"accepted", c.accepted},
                     {"rejected_non_finite", c.rejected_non_finite},
                     {"rejected_out_of_order", c.rejected_out_of_order},
                     {"rejected_duplicate", c.rejected_duplicate},
                     {"rejected_time_out_of_range", c.rejected_time_out_of_range},
                     {"not_fused_unaligned", c.not_fused_unaligned}};
  }
  j["streams"] = streams;
  j["solver"] = {{"solves", result.solver.solves},
                 {"iterations", result.solver.iterations},
                 {"keyframes", result.solver.keyframes},
                 {"late_keyframes", result.solver.late_keyframes},
                 {"too_old_measurements", result.solver.too_old_measurements},
                 {"iteration_cap_hits", result.solver.iteration_cap_hits},
                 {"time_cap_hits", result.solver.time_cap_hits},
                 {"bad_solves", result.solver.bad_solves},
                 {"marginalisation_failures", result.solver.marginalisation_failures},
                 {"reinitialisations", result.counters.reinitialisations},
                 {"restarts_after_gap", result.counters.restarts_after_gap}};
  nlohmann::ordered_json alignment;
  for (const auto& [name, a] : result.alignment) {
    nlohmann::ordered_json entry = {{"valid", a.valid}};
    entry.update(PoseJson(a.T_AL, "p_AL_m", "q_AL_wxyz"));
    entry.update(nlohmann::ordered_json{{"observable_rotation_dofs", a.observable_rotation_dofs},
                                        {"yaw_observable", a.yaw_observable},
                                        {"rms_residual_m", a.rms_residual_m},
                                        {"pairs", a.pairs}});
    alignment[name] = entry;
  }
  j["alignment"] = alignment;
  nlohmann::ordered_json used;
  for (const auto& [name, T_AL] : result.T_AL_used) used[name] = PoseJson(T_AL, "p_AL_m", "q_AL_wxyz");
  j["T_AL_used"] = used;
}

// A client method: its name, its failure, and its own report (a JSON object; one that is
// not stays out).
void AddClient(const ReplayResult& result, nlohmann::ordered_json& j) {
  j["client"] = result.method.client->Name();
  if (result.failure) {
    j["failure"] = *result.failure;
    j["failure_stderr_tail"] = result.failure_stderr_tail;
  }
  const auto report = nlohmann::ordered_json::parse(result.client_report_json, nullptr, false);
  if (!report.is_discarded() && report.is_object() && !report.empty()) {
    j["client_report"] = report;
  }
}

// timing_<stem>.json: the wall clock, and whether the method could run on the robot (each
// local update, one per keyframe, within the keyframe period; keeping up with its input).
MethodFiles WriteTimingJson(const ReplayResult& result, const std::filesystem::path& file) {
  MethodFiles files;
  const std::vector<double>& solve_s = result.solver.solve_time_s;
  files.solve_mean_ms =
      solve_s.empty() ? 0.0
                      : 1e3 * std::accumulate(solve_s.begin(), solve_s.end(), 0.0) / solve_s.size();
  files.solve_p99_ms = 1e3 * Percentile(solve_s, 0.99);
  nlohmann::ordered_json timing = {
      {"wall_time_s", result.wall_time_s},
      {"real_time_factor", result.wall_time_s > 0 ? result.log_duration_s / result.wall_time_s : 0.0},
      {"solve_mean_ms", files.solve_mean_ms},
      {"solve_p50_ms", 1e3 * Percentile(solve_s, 0.5)},
      {"solve_p99_ms", files.solve_p99_ms}};
  files.update_budget_ms = 1e3 * core::TimeToSeconds(result.keyframe_period_ns);
  timing["realtime_budget"] = {
      {"update_budget_ms", files.update_budget_ms},
      {"update_p99_within_budget",
       files.update_budget_ms > 0 && files.solve_p99_ms <= files.update_budget_ms},
      {"keeps_up_with_input", result.wall_time_s < result.log_duration_s},
      {"note", "wall-clock on the machine that ran it: the update's p99 against the keyframe "
               "period (one local update per keyframe), and total time against data time"}};
  WriteFileAtomically(file, timing.dump(2) + "\n");
  return files;
}

}  // namespace

MethodFiles WriteMethodResult(const RecordedLog& log, const ReplayResult& result,
                              const MethodScores& scores, const std::filesystem::path& out_dir) {
  const std::string stem = "estimate_" + MethodFileStem(result.method.name);
  WriteEstimateCsv(out_dir / (stem + ".csv"), result);
  const std::vector<PoseSample>& trajectory = scores.trajectory;
  WriteTumTrajectory(out_dir / (stem + ".tum"), trajectory);

  nlohmann::ordered_json j;
  j["method"] = result.method.name;
  j["fused"] = result.method.fused;
  j["outputs"] = OutputCount(result);
  j["valid_outputs"] = trajectory.size();
  if (const std::optional<TrajectoryErrors>& errors = scores.errors) {
    WriteErrorsCsv(out_dir / (stem + "_errors.csv"), *errors, trajectory, log.ground_truth);
    j["ate"] = AteJson(*errors);
    // The alignment of L to W, so that renders can place the estimate in the world.
    j["T_WL"] = PoseJson(errors->T_WL, "p_m", "q_wxyz");
  }
  AddEstimatorState(result, j);
  j["initialisation"] = InitialisationJson(result, scores);
  nlohmann::ordered_json noise = nlohmann::ordered_json::object();
  for (const auto& [name, n] : result.stream_noise) {
    noise[name] = {{"between_position_std_m", n.between_position_std_m},
                   {"between_rotation_std_deg", core::DegFromRad(n.between_rotation_std_rad)},
                   {"source", n.source}};
  }
  j["stream_noise"] = noise;
  j["imu_gaps"] = {{"count", result.counters.imu_gaps},
                   {"total_s", result.counters.imu_gap_total_s},
                   {"restarts_after_gap", result.counters.restarts_after_gap}};
  if (scores.tilt) j["tilt_error"] = TiltErrorJson(*scores.tilt);
  if (scores.bias) j["bias_error"] = BiasErrorJson(*scores.bias);
  if (const std::optional<InputCheck>& c = scores.input_check) {
    j["input_check"] = {{"input", c->input},
                        {"input_ate_m", c->input_ate_m},
                        {"input_rotation_rmse_deg", c->input_rotation_deg},
                        {"ate_m", c->ate_m},
                        {"rotation_rmse_deg", c->rotation_deg},
                        {"worse_than_input", c->worse_in_position || c->worse_in_rotation}};
  }
  if (result.method.client) AddClient(result, j);
  WriteFileAtomically(out_dir / (stem + ".json"), j.dump(2) + "\n");
  return WriteTimingJson(result, out_dir / ("timing_" + stem + ".json"));
}

void WriteRawStreamResult(const RecordedLog& log, const RawStreamScore& raw,
                          const std::filesystem::path& out_dir) {
  const std::string stem = "estimate_raw_" + MethodFileStem(raw.stream);
  WriteErrorsCsv(out_dir / (stem + "_errors.csv"), raw.errors, raw.trajectory, log.ground_truth);
  nlohmann::ordered_json j;
  j["method"] = "raw:" + raw.stream;
  j["ate"] = AteJson(raw.errors);
  WriteFileAtomically(out_dir / (stem + ".json"), j.dump(2) + "\n");
}

}  // namespace tofu::replay
