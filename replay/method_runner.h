#pragma once
// One method run through its estimator, a measurement at a time in arrival order
// (MethodRunner; Replay over a whole log), and what it produced (ReplayResult: outputs in
// memory or spilled, counters, alignments, decisions, a client's failure).

#include <cstddef>
#include <filesystem>
#include <functional>
#include <map>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include <Eigen/Geometry>

#include "estimator/alignment_graph.h"
#include "estimator/consensus_estimator.h"
#include "estimator/local_smoother.h"
#include "estimator/multi_graph_estimator.h"
#include "replay/estimation_config.h"
#include "replay/labels.h"
#include "replay/output_spill.h"
#include "replay/recorded_log.h"
#include "replay/replay_method.h"
#include "replay/trajectory_metrics.h"

namespace tofu::replay {

struct ReplayResult {
  ReplayMethod method;
  /// The outputs in memory, in the order produced; empty when they went to `spilled`
  /// (read both through ForEachOutput) or were released once written.
  std::vector<estimator::EstimatorOutput> outputs;
  /// A flight's outputs, on disk as they were produced (MethodRunner::SpillOutputsTo).
  std::shared_ptr<const OutputSpill> spilled;
  estimator::EstimatorCounters counters;
  estimator::LocalSmootherStats solver;
  std::map<std::string, estimator::AlignmentEstimate> alignment;  ///< at the end
  /// T_AL each sensor used at the end (known, frozen or estimated), when it had one.
  std::map<std::string, Eigen::Isometry3d> T_AL_used;
  /// kConsensus: every evaluation (decision, reason, matrix values).
  std::vector<estimator::ConsensusRecord> consensus;
  double wall_time_s = 0.0;
  double log_duration_s = 0.0;
  /// One local update per keyframe: the time an update may take on the robot.
  core::Time keyframe_period_ns = 0;
  /// The first measurement the method saw (any stream).
  std::optional<core::Time> first_measurement_ns;
  /// Every (re-)initialisation of the local graph (estimator::InitialisationRecord).
  std::vector<estimator::InitialisationRecord> initialisations;
  /// Pose sensors: the between-factor stds in use at the end, and where they came from.
  struct StreamNoise {
    double between_position_std_m = 0.0;
    double between_rotation_std_rad = 0.0;
    std::string source;  ///< "stated" (calibration/options) or "measured" (from the data)
  };
  std::map<std::string, StreamNoise> stream_noise;
  /// kClient: why the client failed (it stopped being fed then; what it produced before
  /// is kept), and its last standard-error lines.
  std::optional<std::string> failure;
  std::vector<std::string> failure_stderr_tail;
  /// kClient: the JSON object its ReportJson (the protocol's `finished.report`) gave.
  std::string client_report_json;
};

/// One method, fed one measurement at a time in arrival order: the same code replays a
/// recorded log (Replay) and runs inside a flight (the run loop's consumers), so an
/// in-loop estimate and `tofu estimate` on the recorded streams are the same numbers.
/// `log` describes the streams (ReadRecordedLog or DescribeRunStreams); its
/// measurements are not read.
class MethodRunner {
 public:
  /// A client method (kClient) is started here (its process launched, or its plug-in
  /// loaded, and given its setup with `texts`); a client that fails to start makes a
  /// runner whose result has `failure` set.
  MethodRunner(const RecordedLog& log, const ReplayMethod& method,
               const estimator::MultiGraphEstimatorOptions& options,
               const std::vector<estimator::SensorSpec>& sensors,
               const estimator::ConsensusEstimatorOptions& consensus = {},
               const ClientTexts& texts = {});
  ~MethodRunner();
  MethodRunner(MethodRunner&&) noexcept;
  MethodRunner& operator=(MethodRunner&&) noexcept;

  /// The next measurement in arrival order; returns how many outputs it produced. A
  /// process client's answers may lag (open loop streams ahead): Sync() waits for them.
  std::size_t Add(const core::StampedMeasurement& measurement, core::Time arrival_ns);
  /// Every output of the measurements added so far is in outputs() (a closed loop calls
  /// it before the controller reads the newest).
  void Sync();
  /// The client failed (kClient): the method is no longer fed.
  bool failed() const;
  /// Why, with the client's last standard-error lines ("" when it did not fail).
  std::string failure_text() const;
  /// A label the oracle learns while the run goes on (the run loop's condition
  /// transitions); the log's own labels (labels.csv) are known from the start. Other
  /// methods ignore labels.
  void AddLabel(const LabelEvent& label);
  /// The newest output, or null before the first.
  const estimator::EstimatorOutput* newest_output() const;
  /// Writes every output to an anonymous file in `dir` as it is produced instead of
  /// keeping it in memory (a flight's run directory: its memory then stays flat however
  /// long it flies). Before the first Add.
  void SpillOutputsTo(const std::filesystem::path& dir);
  /// The result; wall_time_s is the time spent inside Add. Ends a client (finish).
  ReplayResult Finish() &&;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

/// Runs one method over the whole log in arrival order. `progress` (may be null) is
/// called with the fraction done.
/// `consensus` configures kConsensus methods only.
ReplayResult Replay(const RecordedLog& log, const ReplayMethod& method,
                    const estimator::MultiGraphEstimatorOptions& options,
                    const std::vector<estimator::SensorSpec>& sensors,
                    const std::function<void(double)>& progress = nullptr,
                    const estimator::ConsensusEstimatorOptions& consensus = {},
                    const ClientTexts& texts = {});

/// How many outputs a result holds (in memory or spilled), and each of them in order.
std::size_t OutputCount(const ReplayResult& result);
void ForEachOutput(const ReplayResult& result,
                   const std::function<void(const estimator::EstimatorOutput&)>& visit);

/// The valid outputs as a trajectory of T_LI.
std::vector<PoseSample> OutputTrajectory(const ReplayResult& result);

/// A method none of whose sensors had a single sample accepted by the estimator (all
/// non-finite, out of order, ...): what was rejected, per sensor. nullopt otherwise and
/// for imu_only. `tofu estimate` exits 1 with it; a scenario fails its run.
std::optional<std::string> NothingToFuse(const ReplayResult& result, const std::string& imu_stream);

/// A failed client method's error with its last standard-error lines, for logs; "" when
/// the method did not fail.
std::string ClientFailureText(const ReplayResult& result);

}  // namespace tofu::replay
