#pragma once
// Replay of recorded streams (a tofu run directory or a real robot's log, see
// recorded_log.h) through the multi-graph estimator, one method at a time, and the
// evaluation of what it produced: trajectory errors against the ground truth and the
// consistency of each sensor's velocity with the local estimate (seed paper Sec. 2.1).
// Used by `tofu estimate RUN_DIR` and by the run loop (harness/run.h).

#include <filesystem>
#include <functional>
#include <map>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "estimator/alignment_graph.h"
#include "estimator/consensus_estimator.h"
#include "estimator/consistency.h"
#include "estimator/local_smoother.h"
#include "estimator/multi_graph_estimator.h"
#include "replay/estimation_config.h"
#include "replay/labels.h"
#include "replay/method_evaluation.h"
#include "replay/output_spill.h"
#include "replay/recorded_log.h"
#include "replay/trajectory_metrics.h"

namespace tofu::replay {

/// What a method fuses. Names:
///  - "single:<sensor>": one sensor all the time; "fuse:<a>+<b>": several all the time;
///  - "imu_only": nothing (IMU propagation from the first state);
///  - "naive": every sensor all the time, with the true frame transforms T_AL (the seed
///    paper's naive baseline, given "the ground truth transform between the Leica and
///    local frame");
///  - "consensus": the sensors chosen online by consensus (estimator/consensus_estimator.h),
///    fusing as the scenario's `consensus: {fuse: ...}` says; "consensus:pair_member" and
///    "consensus:consistent_set" choose that explicitly (both can run in one flight);
///  - "oracle": at every sample, exactly the sensors the ground-truth labels call healthy
///    (no fault, no condition active: replay/labels.h), with the estimated alignments as
///    consensus has them: the upper bound of any selection. A log without labels.csv (a
///    real log) has no label, so the oracle fuses everything there.
/// A suffix "@clean" runs the method on the un-faulted streams (sensors/clean/): the
/// paper's reference is "single:vio@clean".
///  - "external:<name>", "plugin:<name>": a user's estimator, a process speaking the
///    protocol of docs/INTERFACE.md or a C++ plug-in, as the scenario's `external:` or
///    `plugins:` entry <name> says (EstimationConfig::clients).
struct ReplayMethod {
  enum class Kind { kFixed, kNaive, kConsensus, kOracle, kClient };
  std::string name;
  Kind kind = Kind::kFixed;
  std::optional<ClientSpec> client;  ///< kClient
  std::vector<std::string> fused;  ///< kFixed, kNaive and kOracle: the sensors it may fuse
  bool clean_streams = false;      ///< "@clean"
  /// kConsensus: the fusion rule when the name states one (else the scenario's).
  std::optional<estimator::ConsensusPolicy> policy;
};

/// Parses a method name against the log's streams; throws core::InputError naming the
/// method, the unknown sensor and the known ones.
/// `clients`: the scenario's users' estimators (external:/plugin: names).
ReplayMethod ParseReplayMethod(const std::string& name, const RecordedLog& log,
                               const std::vector<ClientSpec>& clients = {});
/// The same check against a list of sensor names (a scenario's, before any run): returns
/// an error message, or nullopt when the name is a valid method for these sensors.
std::optional<std::string> CheckMethodName(const std::string& name,
                                           const std::vector<std::string>& sensors,
                                           const std::vector<ClientSpec>& clients = {});

/// Estimator options for a log: IMU noise from its calibration when known (else the
/// ADIS16448 datasheet), inflated 10x for flight (rotor vibration), the IMU sample
/// convention of its layout (tofu's simulated IMU averages over each interval; a real
/// log's samples are instantaneous).
estimator::MultiGraphEstimatorOptions DefaultEstimatorOptions(const RecordedLog& log);
/// Sensor specifications (kinds, mounts) of the log's non-IMU streams.
std::vector<estimator::SensorSpec> SensorSpecsOf(const RecordedLog& log);

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

/// Body velocity of each sensor's mount from its own stream and from the local estimate
/// (v_s = R_Isᵀ (R_LIᵀ v_L + ω_I × p_Is)), compared with a consistency metric over a
/// sliding window at `rate_hz`. Pose streams are differentiated in their own frame A and
/// rotated by their own attitude; position streams need R_As, taken from the local
/// estimate and the estimator's final T_AL.
struct LocalConsistencySeries {
  std::string sensor;
  std::vector<core::Time> t_ns;
  std::vector<std::optional<double>> value;
};
std::vector<LocalConsistencySeries> LocalConsistency(
    const RecordedLog& log, const ReplayResult& result, estimator::ConsistencyMetric metric,
    const estimator::ConsistencyOptions& options, double rate_hz);

/// A pose stream on its own as a trajectory of the IMU frame, T_AI = T_As T_Is⁻¹, within
/// [from_ns, to_ns]: the reference fused methods are compared with.
std::vector<PoseSample> RawPoseTrajectory(const RecordedLog& log, const RecordedStream& stream,
                                          core::Time from_ns, core::Time to_ns);

/// A method none of whose sensors had a single sample accepted by the estimator (all
/// non-finite, out of order, ...): what was rejected, per sensor. nullopt otherwise and
/// for imu_only. `tofu estimate` exits 1 with it; a scenario fails its run.
std::optional<std::string> NothingToFuse(const ReplayResult& result, const std::string& imu_stream);

/// A failed client method's error with its last standard-error lines, for logs; "" when
/// the method did not fail.
std::string ClientFailureText(const ReplayResult& result);

/// The solver's cost WriteMethodResult wrote to timing_estimate_<method>.json.
struct MethodFiles {
  double solve_mean_ms = 0.0;
  double solve_p99_ms = 0.0;
  double update_budget_ms = 0.0;  ///< the keyframe period
};
/// Writes one method's estimate_<method>.csv/.tum/.json (with T_WL, the alignment of L
/// to W, and the scores when scored), estimate_<method>_errors.csv and
/// timing_estimate_<method>.json into out_dir; ':' and '+' in the method name become '_'
/// in file names. Computes nothing it writes but the timing: `scores` is ScoreMethod's.
MethodFiles WriteMethodResult(const RecordedLog& log, const ReplayResult& result,
                              const MethodScores& scores, const std::filesystem::path& out_dir);
/// decisions.csv: the header, and the rows of one consensus method (every evaluation:
/// t_ns, method, fused, excluded, unavailable, reason; sensor lists joined with '+').
inline constexpr const char* kDecisionsCsvHeader =
    "#timestamp [ns],method,fused,excluded,unavailable,reason\n";
std::string DecisionRows(const ReplayResult& result);
/// consistency_<method>.csv of a consensus method: t_ns (end of the window), pair ("a-b",
/// "a-local"), metric, value (empty when unavailable).
std::string ConsistencyMatrixCsv(const ReplayResult& result);

/// A method name as used in file names.
std::string MethodFileStem(const std::string& method);

/// `tofu estimate` as a function: reads the log, runs every method, writes
/// estimate_<method>.csv/.tum and estimate_<method>.json into out_dir (default: the log's
/// directory), prints a table. Returns the process exit code.
struct EstimateCommandOptions {
  std::filesystem::path log_dir;
  std::optional<std::filesystem::path> out_dir;
  std::vector<std::string> methods;  ///< empty: single:<s> for every non-IMU stream
  bool use_clean_streams = false;
  bool quiet = false;
  /// Overrides of the estimator's defaults (unset: keep them).
  std::optional<double> window_s;
  std::optional<double> keyframe_rate_hz;
  std::optional<double> between_position_std_m;
  std::optional<double> between_rotation_std_rad;
  std::optional<double> huber_delta;
  std::optional<bool> between_position_in_reference;
  /// Factor from the at-rest (calibration or datasheet) IMU white-noise densities to the
  /// in-flight ones the estimator uses (default 10, see DefaultEstimatorOptions).
  std::optional<double> imu_noise_scale;
  /// `consensus` methods: the CM threshold (default 0.1, the paper's).
  std::optional<double> consensus_threshold;
  /// Reads the `estimation:` block of a tofu run directory's scenario.yaml (the
  /// harness's scenario reader; nullopt when the scenario has none), so the methods are
  /// configured as in the flight. Unset: scenario.yaml is not read.
  std::function<std::optional<EstimationConfig>(const std::filesystem::path& scenario_yaml)>
      read_estimation_config;
  /// Progress of each method (the CLI draws a bar); may be empty.
  std::function<void(const std::string& method, double fraction)> progress;
};
int RunEstimateCommand(const EstimateCommandOptions& options);

}  // namespace tofu::replay
