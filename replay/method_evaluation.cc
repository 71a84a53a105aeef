#include "replay/method_evaluation.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <utility>

#include <Eigen/Cholesky>

#include "core/units.h"
#include "replay/json_field.h"
#include "replay/method_runner.h"
#include "replay/recorded_log.h"
#include "replay/stream_comparison.h"

namespace tofu::replay {
namespace {

// Ground-truth position of I at t, linearly interpolated; nullopt outside or across a gap.
std::optional<Eigen::Vector3d> TruthPositionAt(const std::vector<PoseSample>& truth, core::Time t) {
  const auto it = std::lower_bound(truth.begin(), truth.end(), t,
                                   [](const PoseSample& g, core::Time tt) { return g.t_ns < tt; });
  if (it == truth.end()) return std::nullopt;
  if (it->t_ns == t) return it->p;
  if (it == truth.begin()) return std::nullopt;
  const PoseSample& a = *std::prev(it);
  const PoseSample& b = *it;
  if (b.t_ns - a.t_ns > 50'000'000) return std::nullopt;
  const double u = static_cast<double>(t - a.t_ns) / static_cast<double>(b.t_ns - a.t_ns);
  return (1.0 - u) * a.p + u * b.p;
}

double TiltErrorDeg(const Eigen::Quaterniond& q_LI, const Eigen::Quaterniond& q_WI) {
  const Eigen::Vector3d down_I_est = q_LI.conjugate() * -Eigen::Vector3d::UnitZ();
  const Eigen::Vector3d down_I_true = q_WI.conjugate() * -Eigen::Vector3d::UnitZ();
  return core::DegFromRad(
      std::atan2(down_I_est.cross(down_I_true).norm(), down_I_est.dot(down_I_true)));
}

// The ground truth nearest in time (200 Hz and more: within half a period).
const PoseSample* TruthAt(const std::vector<PoseSample>& truth, core::Time t_ns) {
  if (truth.empty()) return nullptr;
  auto it = std::lower_bound(truth.begin(), truth.end(), t_ns,
                             [](const PoseSample& g, core::Time t) { return g.t_ns < t; });
  if (it == truth.end()) return &truth.back();
  if (it != truth.begin() && t_ns - std::prev(it)->t_ns < it->t_ns - t_ns) --it;
  return &*it;
}

// The estimated gravity direction against the true one, over the valid outputs: roll and
// pitch error, free of the yaw and origin that an SE(3) alignment hides (L and W are both
// gravity-aligned, so no alignment is needed). What an IMU-aided estimate must get right.
std::optional<TiltError> ScoreTilt(const RecordedLog& log, const ReplayResult& result) {
  if (log.ground_truth.empty()) return std::nullopt;
  double sum_sq = 0.0;
  TiltError tilt;
  std::size_t n = 0;
  ForEachOutput(result, [&](const estimator::EstimatorOutput& o) {
    if (!o.valid) return;
    const PoseSample* g = TruthAt(log.ground_truth, o.t_ns);
    if (g == nullptr) return;
    tilt.final_deg = TiltErrorDeg(o.state.q_LI, g->q);
    sum_sq += tilt.final_deg * tilt.final_deg;
    tilt.max_deg = std::max(tilt.max_deg, tilt.final_deg);
    ++n;
  });
  if (n == 0) return std::nullopt;
  tilt.rms_deg = std::sqrt(sum_sq / n);
  return tilt;
}

// The estimated IMU biases against the ground truth's: RMS over the valid outputs and at
// the last one.
std::optional<BiasError> ScoreBias(const RecordedLog& log, const ReplayResult& result) {
  if (log.ground_truth.empty() || log.ground_truth_biases.size() != log.ground_truth.size()) {
    return std::nullopt;
  }
  double gyro_sum_sq = 0.0, accel_sum_sq = 0.0;
  std::size_t n = 0;
  estimator::ImuBias last;
  const GroundTruthBias* last_truth = nullptr;
  ForEachOutput(result, [&](const estimator::EstimatorOutput& o) {
    if (!o.valid) return;
    const PoseSample* g = TruthAt(log.ground_truth, o.t_ns);
    if (g == nullptr) return;
    const GroundTruthBias& b = log.ground_truth_biases[g - log.ground_truth.data()];
    gyro_sum_sq += (o.bias.gyro_radps - b.b_g_radps).squaredNorm();
    accel_sum_sq += (o.bias.accel_mps2 - b.b_a_mps2).squaredNorm();
    ++n;
    last = o.bias;
    last_truth = &b;
  });
  if (n == 0) return std::nullopt;
  BiasError e;
  e.gyro_rms_radps = std::sqrt(gyro_sum_sq / n);
  e.accel_rms_mps2 = std::sqrt(accel_sum_sq / n);
  e.gyro_final_radps = last.gyro_radps;
  e.gyro_true_final_radps = last_truth->b_g_radps;
  e.accel_final_mps2 = last.accel_mps2;
  e.accel_true_final_mps2 = last_truth->b_a_mps2;
  return e;
}

// The best pose stream the method fused, alone on the same span: what fusion must beat.
std::optional<InputCheck> CheckAgainstInputs(const RecordedLog& log, const ReplayResult& result,
                                             const std::vector<PoseSample>& trajectory,
                                             const TrajectoryErrors& errors) {
  if (log.ground_truth.empty() || trajectory.empty()) return std::nullopt;
  std::optional<InputCheck> best;
  for (const RecordedStream& stream : log.streams) {
    if (stream.kind != core::MeasurementKind::kPose) continue;
    const bool fused_by_method =
        result.method.kind == ReplayMethod::Kind::kConsensus ||
        std::find(result.method.fused.begin(), result.method.fused.end(), stream.name) !=
            result.method.fused.end();
    if (!fused_by_method) continue;
    const std::vector<PoseSample> raw =
        RawPoseTrajectory(log, stream, trajectory.front().t_ns, trajectory.back().t_ns);
    if (raw.size() <= 10) continue;
    const TrajectoryErrors raw_errors = EvaluateTrajectory(raw, log.ground_truth);
    if (best && best->input_ate_m <= raw_errors.ate_position_rmse_m) continue;
    InputCheck check;
    check.input = "raw:" + stream.name;
    check.input_ate_m = raw_errors.ate_position_rmse_m;
    check.input_rotation_deg = raw_errors.rotation_rmse_deg;
    best = check;
  }
  if (!best) return std::nullopt;
  best->worse_in_position = errors.ate_position_rmse_m > best->input_ate_m;
  best->worse_in_rotation = errors.rotation_rmse_deg > best->input_rotation_deg;
  best->ate_m = errors.ate_position_rmse_m;
  best->rotation_deg = errors.rotation_rmse_deg;
  return best;
}

// The NEES of each matched sample's reported position covariance, in L (NaN where there
// is none): e_L = R_LW (T_WL p_LI - p_WI).
std::vector<double> PositionNees(const RecordedLog& log, const ReplayResult& result,
                                 const TrajectoryErrors& t) {
  std::vector<double> nees(t.t_ns.size(), std::numeric_limits<double>::quiet_NaN());
  const Eigen::Matrix3d R_LW = t.T_WL.linear().transpose();
  std::size_t k = 0;  // next of the matched samples (t.t_ns)
  ForEachOutput(result, [&](const estimator::EstimatorOutput& o) {
    if (!o.valid) return;
    while (k < t.t_ns.size() && t.t_ns[k] < o.t_ns) ++k;
    if (k == t.t_ns.size() || t.t_ns[k] != o.t_ns) return;  // no ground truth there
    if (!o.position_covariance_m2) return;
    const auto p_WI = TruthPositionAt(log.ground_truth, o.t_ns);
    if (!p_WI) return;
    const Eigen::Vector3d e_L = R_LW * (t.T_WL * o.state.p_LI - *p_WI);
    const Eigen::LDLT<Eigen::Matrix3d> ldlt(*o.position_covariance_m2);
    if (ldlt.info() == Eigen::Success && ldlt.isPositive()) nees[k] = e_L.dot(ldlt.solve(e_L));
  });
  return nees;
}

void SetTrajectoryScores(const TrajectoryErrors& t, const std::vector<double>& nees,
                         MethodEvaluation& e) {
  e.ate_m = t.ate_position_rmse_m;
  e.ate_max_m = t.ate_position_max_m;
  e.rotation_rmse_deg = t.rotation_rmse_deg;
  if (t.rpe_pairs > 0) {
    e.rpe_m = t.rpe_translation_rmse_m;
    e.rpe_deg = t.rpe_rotation_rmse_deg;
  }
  if (t.step_pairs > 0) {
    e.position_step_max_m = t.position_step_max_m;
    e.position_step_max_t_s = core::TimeToSeconds(t.position_step_max_t_ns);
  }
  double nees_sum = 0.0;
  std::vector<double> values;
  for (const double v : nees) {
    if (std::isnan(v)) continue;
    nees_sum += v;
    values.push_back(v);
  }
  e.nees_samples = values.size();
  if (values.empty()) return;
  e.nees_position_mean = nees_sum / static_cast<double>(e.nees_samples);
  const auto inside = std::count_if(values.begin(), values.end(),
                                    [](double v) { return v <= kChiSquare3Dof95; });
  e.position_containment_95 = static_cast<double>(inside) / static_cast<double>(values.size());
  e.nees_position_median = Median(std::move(values));
}

}  // namespace

std::optional<double> FaultDetection::delay_s() const {
  if (!detected_ns) return std::nullopt;
  return core::TimeToSeconds(*detected_ns - onset_ns);
}

std::optional<double> FaultDetection::readmission_delay_s() const {
  if (!detected_ns || !ends_in_run) return std::nullopt;
  if (!readmitted_ns) return std::numeric_limits<double>::infinity();
  return core::TimeToSeconds(*readmitted_ns - end_ns);
}

std::optional<double> MethodEvaluation::max_readmission_delay_s() const {
  std::optional<double> worst;
  for (const FaultDetection& d : detections) {
    if (const auto delay = d.readmission_delay_s()) worst = std::max(worst.value_or(*delay), *delay);
  }
  return worst;
}

int MethodEvaluation::missed_faults() const {
  int missed = 0;
  for (const FaultDetection& d : detections) missed += d.detected_ns ? 0 : 1;
  return missed;
}

std::optional<double> MethodEvaluation::max_detection_delay_s(const std::string& kind) const {
  std::optional<double> worst;
  for (const FaultDetection& d : detections) {
    if (!kind.empty() && d.fault != kind) continue;
    const double delay = d.delay_s().value_or(std::numeric_limits<double>::infinity());
    worst = std::max(worst.value_or(delay), delay);
  }
  return worst;
}

double MethodEvaluation::false_exclusion_fraction() const {
  double worst = 0.0;
  for (const auto& [sensor, seconds] : false_exclusion_s) worst = std::max(worst, seconds);
  return run_duration_s > 0.0 ? worst / run_duration_s : 0.0;
}

ConsensusScores ScoreConsensusDecisions(const std::vector<estimator::ConsensusRecord>& decisions,
                                        const std::vector<LabelEvent>& labels,
                                        core::Time run_end_ns,
                                        const std::vector<std::string>& sensors) {
  const std::vector<LabelInterval> intervals = MergedLabelIntervals(labels, run_end_ns);
  std::vector<LabelInterval> faults, conditions;
  for (const LabelInterval& i : intervals) (i.source == "fault" ? faults : conditions).push_back(i);
  const auto active_at = [](const std::vector<LabelInterval>& windows, const std::string& sensor,
                            core::Time t) {
    return std::any_of(windows.begin(), windows.end(), [&](const LabelInterval& w) {
      return w.sensor == sensor && w.start_ns <= t && t < w.end_ns;
    });
  };

  ConsensusScores scores;
  std::optional<std::vector<std::string>> previous_fused;
  bool fused_once = false;
  for (std::size_t r = 0; r < decisions.size(); ++r) {
    const estimator::ConsensusRecord& rec = decisions[r];
    const estimator::ConsensusDecision& d = rec.decision;
    // Switches: changes of the fused set once something was fused.
    if (fused_once && previous_fused && *previous_fused != d.fused) ++scores.switches;
    if (!d.fused.empty()) fused_once = true;
    previous_fused = d.fused;
    // False exclusions: excluded while no fault and no condition was active.
    const core::Time next = r + 1 < decisions.size() ? decisions[r + 1].t_ns
                                                     : std::max(rec.t_ns, run_end_ns);
    for (const std::string& s : d.excluded) {
      if (active_at(faults, s, rec.t_ns) || active_at(conditions, s, rec.t_ns)) continue;
      scores.false_exclusion_s[s] += core::TimeToSeconds(next - rec.t_ns);
    }
  }
  // Detection: the first decision excluding the sensor, from the onset until 1 s after
  // the fault ended (a decision lags its window by the evaluation delay). A dropout is no
  // data, not wrong data: nothing to detect.
  for (const LabelInterval& f : faults) {
    if (f.label == "dropout") continue;
    FaultDetection det;
    det.sensor = f.sensor;
    det.fault = f.label;
    det.onset_ns = f.start_ns;
    det.end_ns = f.end_ns;
    det.ends_in_run = !f.open;
    const auto listed = [&](const std::vector<std::string>& names) {
      return std::find(names.begin(), names.end(), f.sensor) != names.end();
    };
    for (const estimator::ConsensusRecord& rec : decisions) {
      if (rec.t_ns < f.start_ns) continue;
      if (rec.t_ns > f.end_ns + 1'000'000'000) break;
      if (listed(rec.decision.excluded)) {
        det.detected_ns = rec.t_ns;
        break;
      }
    }
    // Re-admission: eligible again, for good, once the fault is over (issue 16: within
    // the alignment window, and a few seconds at the median).
    if (det.detected_ns && det.ends_in_run) {
      std::optional<core::Time> since;
      for (const estimator::ConsensusRecord& rec : decisions) {
        if (rec.t_ns < f.end_ns) continue;
        if (!listed(rec.decision.eligible)) {
          since.reset();
          continue;
        }
        if (!since) since = rec.t_ns;
        if (rec.t_ns - *since >= 1'000'000'000) break;
      }
      det.readmitted_ns = since;
    }
    scores.detections.push_back(det);
  }
  for (const std::string& s : sensors) scores.false_exclusion_s.emplace(s, 0.0);
  return scores;
}

std::vector<estimator::ConsensusRecord> RestatedAtFaultOnsets(
    std::vector<estimator::ConsensusRecord> records, const std::vector<LabelEvent>& labels) {
  std::vector<estimator::ConsensusRecord> onsets;
  for (const LabelEvent& label : labels) {
    if (label.source != "fault" || !label.active) continue;
    const auto after = std::upper_bound(
        records.begin(), records.end(), label.t_ns,
        [](core::Time t, const estimator::ConsensusRecord& r) { return t < r.t_ns; });
    if (after == records.begin()) continue;  // nothing decided yet
    estimator::ConsensusRecord restated = *std::prev(after);
    restated.t_ns = label.t_ns;
    restated.window_end_ns = label.t_ns;
    restated.decision.t_ns = label.t_ns;
    restated.decision.changed = false;
    onsets.push_back(std::move(restated));
  }
  records.insert(records.end(), onsets.begin(), onsets.end());
  std::stable_sort(records.begin(), records.end(),
                   [](const auto& a, const auto& b) { return a.t_ns < b.t_ns; });
  return records;
}


MethodScores ScoreMethod(const RecordedLog& log, const ReplayResult& result,
                         const ScoringContext& context) {
  MethodScores s;
  MethodEvaluation& e = s.evaluation;
  const ReplayMethod& method = result.method;
  e.method = method.name;
  e.outputs = OutputCount(result);
  e.run_duration_s = context.run_duration_s;
  e.wall_time_s = result.wall_time_s;
  if (result.failure) e.failure = ClientFailureText(result);
  s.trajectory = OutputTrajectory(result);
  e.valid_fraction = e.outputs == 0 ? 0.0
                                    : static_cast<double>(s.trajectory.size()) /
                                          static_cast<double>(e.outputs);
  for (const estimator::InitialisationRecord& r : result.initialisations) {
    const PoseSample* g = TruthAt(log.ground_truth, r.t_ns);
    s.initialisation_tilt_error_deg.push_back(
        g ? std::optional<double>(TiltErrorDeg(r.state.q_LI, g->q)) : std::nullopt);
  }
  s.tilt = ScoreTilt(log, result);
  s.bias = ScoreBias(log, result);
  if (!log.ground_truth.empty() && s.trajectory.size() > 10) {
    s.errors = EvaluateTrajectory(s.trajectory, log.ground_truth);
    s.input_check = CheckAgainstInputs(log, result, s.trajectory, *s.errors);
    s.nees = PositionNees(log, result, *s.errors);
    SetTrajectoryScores(*s.errors, s.nees, e);
  }

  // Consensus, and a client that says which sensors it fuses: detection, re-admission,
  // false exclusions and switches.
  static const std::vector<LabelEvent> kNoLabels;
  const std::vector<LabelEvent>& labels = context.labels ? *context.labels : kNoLabels;
  const core::Time run_end_ns = core::SecondsToTime(context.run_duration_s);
  const bool client_selects =
      method.kind == ReplayMethod::Kind::kClient && !result.consensus.empty();
  if (client_selects || method.kind == ReplayMethod::Kind::kConsensus) {
    e.consensus = true;
    // Faults as intervals per (sensor, kind), overlapping ones merged (labels.h).
    ConsensusScores scores = ScoreConsensusDecisions(
        client_selects ? RestatedAtFaultOnsets(result.consensus, labels) : result.consensus,
        labels, run_end_ns, context.sensors);
    e.switches = scores.switches;
    e.detections = std::move(scores.detections);
    e.false_exclusion_s = std::move(scores.false_exclusion_s);
  }
  if (method.kind == ReplayMethod::Kind::kConsensus) e.threshold = context.consensus_threshold;
  return s;
}

std::vector<RawStreamScore> ScoreRawStreams(const RecordedLog& log, core::Time from_ns,
                                            core::Time to_ns) {
  std::vector<RawStreamScore> scores;
  if (log.ground_truth.empty() || from_ns > to_ns) return scores;
  for (const RecordedStream& stream : log.streams) {
    if (stream.kind != core::MeasurementKind::kPose) continue;
    std::vector<PoseSample> raw = RawPoseTrajectory(log, stream, from_ns, to_ns);
    if (raw.size() <= 10) continue;
    TrajectoryErrors errors = EvaluateTrajectory(raw, log.ground_truth);
    scores.push_back({stream.name, std::move(raw), std::move(errors)});
  }
  return scores;
}

nlohmann::json FailedFiguresJson(nlohmann::json figures, const std::string& failure) {
  nlohmann::json failed = nlohmann::json::object();
  nlohmann::json partial = nlohmann::json::object();
  for (auto& [key, value] : figures.items()) {
    // What the figures are of, not figures: kept.
    if (key == "ate_alignment" || key == "corridor_m" || key == "digests") {
      failed[key] = value;
      continue;
    }
    failed[key] = nullptr;
    partial[key] = std::move(value);
  }
  failed["failure"] = failure;
  failed["partial"] = std::move(partial);
  return failed;
}

nlohmann::json MethodEvaluationJson(const MethodEvaluation& m) {
  nlohmann::json j = {{"ate_alignment", "se3"},
                      {"ate_m", NumberOrNull(m.ate_m)},
                      {"ate_max_m", NumberOrNull(m.ate_max_m)},
                      {"rotation_rmse_deg", NumberOrNull(m.rotation_rmse_deg)},
                      {"rpe_m", NumberOrNull(m.rpe_m)},
                      {"rpe_deg", NumberOrNull(m.rpe_deg)},
                      {"position_step_max_m", NumberOrNull(m.position_step_max_m)},
                      {"position_step_max_t_s", NumberOrNull(m.position_step_max_t_s)},
                      {"nees_position_mean", NumberOrNull(m.nees_position_mean)},
                      {"nees_position_median", NumberOrNull(m.nees_position_median)},
                      {"position_containment_95", NumberOrNull(m.position_containment_95)},
                      {"nees_samples", m.nees_samples},
                      {"outputs", m.outputs},
                      {"valid_fraction", m.valid_fraction}};
  if (m.consensus) {
    j["threshold"] = NumberOrNull(m.threshold);
    j["switches"] = m.switches;
    j["faults"] = m.detections.size();
    j["faults_detected"] = m.detections.size() - static_cast<std::size_t>(m.missed_faults());
    j["max_detection_delay_s"] = NumberOrNull(m.max_detection_delay_s());
    j["max_readmission_delay_s"] = NumberOrNull(m.max_readmission_delay_s());
    j["false_exclusion_fraction"] = m.false_exclusion_fraction();
    nlohmann::json false_exclusions = nlohmann::json::object();
    for (const auto& [sensor, seconds] : m.false_exclusion_s) false_exclusions[sensor] = seconds;
    j["false_exclusion_s"] = false_exclusions;
    nlohmann::json detections = nlohmann::json::array();
    for (const FaultDetection& d : m.detections) {
      detections.push_back({{"sensor", d.sensor},
                            {"fault", d.fault},
                            {"onset_s", core::TimeToSeconds(d.onset_ns)},
                            {"end_s", core::TimeToSeconds(d.end_ns)},
                            {"detected", d.detected_ns.has_value()},
                            {"delay_s", NumberOrNull(d.delay_s())},
                            {"readmission_delay_s", NumberOrNull(d.readmission_delay_s())}});
    }
    j["detections"] = detections;
  }
  if (m.failure) j = FailedFiguresJson(std::move(j), *m.failure);
  return j;
}

}  // namespace tofu::replay
