#include "harness/estimation.h"

#include <algorithm>
#include <cmath>
#include <fstream>
#include <future>
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

using replay::LabelEvent;
using replay::PoseSample;
using replay::ReadRecordedLog;
using replay::RecordedLog;
using replay::RecordedLogOptions;
using replay::ReplayMethod;
using replay::ReplayResult;
using replay::SensorSpecsOf;
using replay::TrajectoryErrors;
using replay::WriteMethodResult;

namespace {

namespace fs = std::filesystem;



// Decimation of errors.csv: one row per 50 ms of estimate time, and every sample with a
// NEES.
constexpr core::Time kErrorRowPeriodNs = 50'000'000;

void AppendErrorRows(const std::string& method, const TrajectoryErrors& t,
                     const std::vector<double>& nees, replay::AtomicFileWriter& errors_csv) {
  std::optional<core::Time> last_row;
  for (std::size_t k = 0; k < t.t_ns.size(); ++k) {
    const bool has_nees = !std::isnan(nees[k]);
    if (!has_nees && last_row && t.t_ns[k] - *last_row < kErrorRowPeriodNs) continue;
    last_row = t.t_ns[k];
    errors_csv.Format("{},{},{:.6f},{:.4f},1,{}\n", t.t_ns[k], method, t.position_error_m[k],
                      t.rotation_error_deg[k],
                      has_nees ? fmt::format("{:.4g}", nees[k]) : std::string());
  }
}

}  // namespace

std::vector<MethodEvaluation> EvaluateEstimation(const fs::path& run_dir,
                                                 const replay::EstimationConfig& config,
                                                 const std::vector<LabelEvent>& labels,
                                                 double run_duration_s,
                                                 std::vector<ReplayResult>& results,
                                                 int threads) {
  // The streams' descriptions and the ground truth: the samples went through the
  // estimators in the loop (results), not through this reader.
  RecordedLogOptions read;
  read.read_measurements = false;
  const RecordedLog log = ReadRecordedLog(run_dir, read);
  replay::ScoringContext scoring;
  scoring.labels = &labels;
  scoring.run_duration_s = run_duration_s;
  for (const estimator::SensorSpec& s : SensorSpecsOf(log)) scoring.sensors.push_back(s.name);
  scoring.consensus_threshold = config.consensus.threshold;

  // errors.csv: every method's rows, written as they are formatted (a row per output with
  // a covariance: an hour of two methods would be 90 MB of text held).
  replay::AtomicFileWriter errors_csv(run_dir / "errors.csv");
  errors_csv.Append("#timestamp [ns],method,position_error [m],rotation_error [deg],valid,nees\n");
  replay::ConsensusFiles consensus_files(run_dir);
  std::vector<MethodEvaluation> evaluations;
  const std::size_t at_once =
      run_duration_s <= kScoreSideBySideMaxS ? static_cast<std::size_t>(std::max(1, threads)) : 1;
  for (std::size_t first = 0; first < results.size(); first += at_once) {
    const std::size_t end = std::min(results.size(), first + at_once);
    // Scored and their own files written side by side; the shared files (errors.csv, the
    // consensus files) then take them in the methods' order.
    std::vector<replay::MethodScores> scores(end - first);
    {
      std::vector<std::future<void>> scoring_methods;
      for (std::size_t i = first; i < end; ++i) {
        scoring_methods.push_back(std::async(
            at_once > 1 ? std::launch::async : std::launch::deferred, [&, i] {
              scores[i - first] = replay::ScoreMethod(log, results[i], scoring);
              WriteMethodResult(log, results[i], scores[i - first], run_dir);
            }));
      }
      // get() rethrows a method's failure; the futures still running are waited for as
      // they go out of scope.
      for (std::future<void>& scored : scoring_methods) scored.get();
    }
    for (std::size_t i = first; i < end; ++i) {
      ReplayResult& result = results[i];
      const replay::MethodScores& method_scores = scores[i - first];
      if (const std::optional<TrajectoryErrors>& t = method_scores.errors) {
        AppendErrorRows(result.method.name, *t, method_scores.nees, errors_csv);
      }
      consensus_files.Add(result);
      // Done with the outputs: an in-memory method's are freed, a spilled one's file closes.
      std::vector<estimator::EstimatorOutput>().swap(result.outputs);
      result.spilled.reset();
      evaluations.push_back(std::move(scores[i - first].evaluation));
    }
  }
  errors_csv.Commit();
  consensus_files.Commit();
  return evaluations;
}

}  // namespace tofu::harness
