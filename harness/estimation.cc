#include "harness/estimation.h"

#include <algorithm>
#include <cmath>
#include <fstream>
#include <limits>
#include <set>

#include <fmt/format.h>

#include "core/error.h"
#include "harness/evaluation.h"
#include "harness/sensor_suite.h"
#include "replay/file_io.h"
#include "replay/recorded_log.h"
#include "replay/replay.h"
#include "replay/trajectory_metrics.h"

namespace tofu::harness {

using replay::ConsistencyMatrixCsv;
using replay::DecisionRows;
using replay::kDecisionsCsvHeader;
using replay::LabelEvent;
using replay::MethodFiles;
using replay::PoseSample;
using replay::MethodFileStem;
using replay::ReadRecordedLog;
using replay::RecordedLog;
using replay::RecordedLogOptions;
using replay::ReplayMethod;
using replay::ReplayResult;
using replay::SensorSpecsOf;
using replay::TrajectoryErrors;
using replay::WriteFileAtomically;
using replay::WriteMethodResult;

namespace {

namespace fs = std::filesystem;



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

// A client's decisions are its fused set at each change (replay's DecisionsFromFusedSets):
// a sensor it had already stopped fusing when a fault began has no decision in the fault's
// interval. The decision in force at each fault onset is stated again there, so that such
// a sensor counts as excluded from the onset (delay 0), as sampling its fused set would.
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

// The 95 % quantile of χ² with 3 degrees of freedom: the NEES bound of the position
// covariance's 95 % ellipsoid.
constexpr double kChiSquare3Dof95 = 7.814727903251178;

// Decimation of errors.csv: one row per 50 ms of estimate time.
constexpr core::Time kErrorRowPeriodNs = 50'000'000;

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

std::vector<MethodEvaluation> EvaluateEstimation(const fs::path& run_dir,
                                                 const replay::EstimationConfig& config,
                                                 const std::vector<LabelEvent>& labels,
                                                 double run_duration_s,
                                                 std::vector<ReplayResult>& results) {
  // The streams' descriptions and the ground truth: the samples went through the
  // estimators in the loop (results), not through this reader.
  RecordedLogOptions read;
  read.read_measurements = false;
  const RecordedLog log = ReadRecordedLog(run_dir, read);
  const std::vector<estimator::SensorSpec> specs = SensorSpecsOf(log);
  const core::Time run_end_ns = core::SecondsToTime(run_duration_s);
  std::vector<std::string> sensor_names;
  for (const estimator::SensorSpec& s : specs) sensor_names.push_back(s.name);

  // errors.csv: every method's rows, written as they are formatted (a row per output with
  // a covariance: an hour of two methods would be 90 MB of text held).
  replay::AtomicFileWriter errors_csv(run_dir / "errors.csv");
  errors_csv.Append("#timestamp [ns],method,position_error [m],rotation_error [deg],valid,nees\n");
  std::string decisions_csv = kDecisionsCsvHeader;
  bool any_consensus = false;
  std::vector<MethodEvaluation> evaluations;
  for (ReplayResult& result : results) {
    const ReplayMethod& method = result.method;
    MethodEvaluation e;
    e.outputs = replay::OutputCount(result);
    if (result.failure) e.failure = replay::ClientFailureText(result);
    MethodFiles files = replay::WriteMethodResult(log, result, run_dir);
    const std::size_t valid_outputs = files.trajectory.size();
    std::vector<PoseSample>().swap(files.trajectory);  // the outputs are read again below

    e.method = method.name;
    e.run_duration_s = run_duration_s;
    e.wall_time_s = result.wall_time_s;
    e.valid_fraction = e.outputs == 0 ? 0.0
                                      : static_cast<double>(valid_outputs) /
                                            static_cast<double>(e.outputs);
    if (files.errors) {
      const TrajectoryErrors& t = *files.errors;
      e.ate_m = t.ate_position_rmse_m;
      e.ate_max_m = t.ate_position_max_m;
      e.rotation_rmse_deg = t.rotation_rmse_deg;
      if (t.rpe_pairs > 0) {
        e.rpe_m = t.rpe_translation_rmse_m;
        e.rpe_deg = t.rpe_rotation_rmse_deg;
      }
      // errors.csv rows and the NEES of the reported position covariance, in L.
      const Eigen::Matrix3d R_LW = t.T_WL.linear().transpose();
      double nees_sum = 0.0;
      std::vector<double> nees_values;
      std::size_t k = 0;  // next of the matched samples (t.t_ns)
      std::optional<core::Time> last_row;
      replay::ForEachOutput(result, [&](const estimator::EstimatorOutput& o) {
        if (!o.valid) return;
        while (k < t.t_ns.size() && t.t_ns[k] < o.t_ns) ++k;
        if (k == t.t_ns.size()) return;
        if (t.t_ns[k] != o.t_ns) return;  // no ground truth there
        std::optional<double> nees;
        if (o.position_covariance_m2) {
          if (const auto p_WI = TruthPositionAt(log.ground_truth, o.t_ns)) {
            const Eigen::Vector3d e_L = R_LW * (t.T_WL * o.state.p_LI - *p_WI);
            const Eigen::Matrix3d& P = *o.position_covariance_m2;
            const Eigen::LDLT<Eigen::Matrix3d> ldlt(P);
            if (ldlt.info() == Eigen::Success && ldlt.isPositive()) {
              nees = e_L.dot(ldlt.solve(e_L));
              nees_sum += *nees;
              nees_values.push_back(*nees);
              ++e.nees_samples;
            }
          }
        }
        if (nees || !last_row || o.t_ns - *last_row >= kErrorRowPeriodNs) {
          last_row = o.t_ns;
          errors_csv.Format("{},{},{:.6f},{:.4f},1,{}\n", o.t_ns, method.name,
                            t.position_error_m[k], t.rotation_error_deg[k],
                            nees ? fmt::format("{:.4g}", *nees) : std::string());
        }
      });
      if (e.nees_samples > 0) {
        e.nees_position_mean = nees_sum / static_cast<double>(e.nees_samples);
        const auto inside = std::count_if(nees_values.begin(), nees_values.end(),
                                          [](double v) { return v <= kChiSquare3Dof95; });
        e.position_containment_95 =
            static_cast<double>(inside) / static_cast<double>(nees_values.size());
        e.nees_position_median = replay::Median(std::move(nees_values));
      }
    }

    // Consensus, and a client that says which sensors it fuses: detection, re-admission,
    // false exclusions and switches.
    const bool client_selects = method.kind == ReplayMethod::Kind::kClient && !result.consensus.empty();
    if (client_selects) {
      e.consensus = true;
      ConsensusScores scores = ScoreConsensusDecisions(
          RestatedAtFaultOnsets(result.consensus, labels), labels, run_end_ns, sensor_names);
      e.switches = scores.switches;
      e.detections = std::move(scores.detections);
      e.false_exclusion_s = std::move(scores.false_exclusion_s);
    }
    if (method.kind == ReplayMethod::Kind::kConsensus) {
      any_consensus = true;
      e.consensus = true;
      e.threshold = config.consensus.threshold;
      decisions_csv += DecisionRows(result);
      // Faults as intervals per (sensor, kind), overlapping ones merged (evaluation.h).
      ConsensusScores scores =
          ScoreConsensusDecisions(result.consensus, labels, run_end_ns, sensor_names);
      e.switches = scores.switches;
      e.detections = std::move(scores.detections);
      e.false_exclusion_s = std::move(scores.false_exclusion_s);
      WriteFileAtomically(run_dir / ("consistency_" + MethodFileStem(method.name) + ".csv"),
                          ConsistencyMatrixCsv(result));
    }
    // Done with the outputs: an in-memory method's are freed, a spilled one's file closes.
    std::vector<estimator::EstimatorOutput>().swap(result.outputs);
    result.spilled.reset();
    evaluations.push_back(std::move(e));
  }
  errors_csv.Commit();
  if (any_consensus) WriteFileAtomically(run_dir / "decisions.csv", decisions_csv);
  return evaluations;
}

}  // namespace tofu::harness
