#pragma once
// How the estimation methods of a run are configured: a scenario's `estimation:` block as
// plain values (the YAML is read by harness/scenario.h), and what it makes of a recorded
// log's streams. Shared by the run loop (harness/) and `tofu estimate`
// (estimate_command.h), so an in-loop estimate and a replay of the recorded streams are
// configured alike.

#include <optional>
#include <span>
#include <string>
#include <string_view>
#include <vector>

#include "core/error.h"
#include "core/option_fields.h"
#include "core/units.h"
#include "estimator/consensus_estimator.h"
#include "estimator/consensus_selector.h"
#include "estimator/multi_graph_estimator.h"

namespace tofu::replay {

struct RecordedLog;

/// A named set of defaults for the whole `estimation:` block (`profile:`): a scenario
/// writes a key only where that option is what it is about.
///  - kPaper: the seed paper's configuration (Lanegger et al.), as tofu reproduces it;
///  - kRecommended: the best combination by measurement (scripts/measure_profiles.py on
///    the suite's recorded runs, chosen on seeds 1-5, reported on 6-10: docs/RESULTS.md,
///    "One recommended profile").
enum class EstimationProfile { kPaper, kRecommended };
/// Every profile, in the order the reference lists them.
inline constexpr EstimationProfile kEstimationProfiles[] = {EstimationProfile::kPaper,
                                                            EstimationProfile::kRecommended};
/// "paper", "recommended".
std::string_view EstimationProfileName(EstimationProfile profile);

/// `estimation.consensus` in a scenario (and the options of `consensus` methods). Its
/// keys, limits and documentation: Fields(); its defaults: a profile's
/// (EstimationConfig::Defaults), not the member initialisers below.
struct ConsensusConfig {
  /// The pairs' consistency metric: cm (the paper's Cramér-von Mises distance, m/s) or
  /// nis (normalised by the sensors' stated covariances, unitless; consistency.h).
  estimator::ConsistencyMetric metric = estimator::ConsistencyMetric::kCm;
  double threshold = 0.1;                 ///< below it a pair is consistent; CM paper: 0.1 m/s
  std::optional<double> leave_threshold;  ///< hysteresis; unset = paper
  double min_dwell_s = 0.0;               ///< 0 = paper
  /// `fuse`: pair_member (one sensor of the most consistent pair, the paper) or
  /// consistent_set (every sensor of the largest mutually consistent set).
  estimator::ConsensusPolicy policy = estimator::ConsensusPolicy::kPairMember;
  /// pair_member: give way to a preferred sensor that has recovered (false: the paper).
  bool return_to_priority = true;
  std::vector<std::string> priority;      ///< sensors, most preferred first
  double window_s = 1.0;                  ///< CM window
  double rate_hz = 10.0;                  ///< evaluations per second
  /// Beyond the paper: the window of the mean-difference test of each sensor pair (0: off;
  /// estimator/consensus_estimator.h, bias_window_ns), its false-alarm probability per
  /// evaluation and the floor of its mean's standard deviation (consistency.h
  /// MeanDifferenceOptions::floor_std_mps).
  double bias_window_s = 0.0;
  double bias_false_alarm = 1e-4;
  double bias_floor_mps = 0.001;

  /// Every key of the block but `priority` (a list of the scenario's sensors, read where
  /// the sensors are known), in the order the writer writes them.
  static std::span<const core::OptionField<ConsensusConfig>> Fields();
  /// The table's limits and the rules between fields: the threshold on its metric's
  /// scale (ThresholdRule), leave_threshold >= threshold, a bias window of 0 or >= 0.5 s.
  bool IsValid(std::string* why = nullptr) const;
};

/// The limits of a consensus threshold for `metric`, in its unit: cm's is a velocity
/// distance in m/s, nis's a normalised one (1 on average for consistent streams).
core::NumberRule ThresholdRule(estimator::ConsistencyMetric metric);

/// A user's estimator (or controller) a scenario names: `external: {<key>: {command: [...],
/// config: {...}, timeout_s: 10}}` (a process speaking docs/INTERFACE.md's protocol) or
/// `plugins: {<key>: {library: ..., config: {...}}}` (a C++ plug-in, include/tofu/plugin.h).
struct ClientSpec {
  enum class Kind { kProcess, kPlugin };
  Kind kind = Kind::kProcess;
  std::string key;                     ///< the scenario's key
  std::vector<std::string> command;    ///< kProcess: argv
  std::string working_dir;             ///< kProcess: where it runs (absolute)
  double timeout_s = 10.0;             ///< kProcess: deadline of each answer
  std::string library;                 ///< kPlugin: the shared library (absolute)
  std::string config_json = "{}";      ///< the `config:` map as JSON text
  /// "external:<key>" or "plugin:<key>": the method (or controller) name.
  std::string Name() const { return (kind == Kind::kProcess ? "external:" : "plugin:") + key; }
};

/// What a client is told besides its streams (api::EstimatorSetup's texts).
struct ClientTexts {
  std::string calibration_yaml;  ///< the run's calibration.yaml
  std::string estimation_yaml;   ///< the scenario's resolved estimation: block
  double gravity_mps2 = core::kWorldGravity_mps2;
};

/// `estimation:` in a scenario. Its keys: Fields() and ConsensusConfig::Fields(), plus
/// `methods` and `consensus.priority`; its defaults: Defaults(profile).
struct EstimationConfig {
  EstimationProfile profile = EstimationProfile::kPaper;
  /// Method names (replay/replay_method.h ParseReplayMethod): consensus,
  /// consensus:pair_member, consensus:consistent_set, oracle, naive, single:<sensor>,
  /// fuse:<a>+<b>, imu_only, each optionally with @clean.
  std::vector<std::string> methods;
  ConsensusConfig consensus;
  /// Huber loss on the between factors, in standard deviations (0: off, as the paper).
  /// A faulty sensor is fused until consensus notices it (a few evaluations): without a
  /// robust loss, metre-level outliers in that time can wreck the local graph.
  double huber_delta = 0.0;
  /// How position sensors (total station, GNSS) constrain the local graph: "between"
  /// (displacements, the paper's eq. 3), "absolute" (each position in L through the
  /// frozen T_AL) or "offset" (each position in L up to an offset per chain that the
  /// graph estimates); estimator::PositionFactors.
  estimator::PositionFactors position_factors = estimator::PositionFactors::kBetween;
  /// Whether a LiDAR odometry's between factors leave out the directions its own
  /// information calls degenerate (`degenerate_directions: left_out`; RecordedStream's
  /// unobserved stds) or fuse every direction (`fused`, the paper).
  bool leave_out_degenerate_directions = false;
  /// How pose sensors' between factors are weighted: "constant" (one std per factor from
  /// the stated noise and a nominal 5 cm between keyframes, the paper's ω) or
  /// "white_and_drift" (each pose's white error and the drift over the distance between
  /// the keyframes, with the ends' correlation bounded; estimator::PoseBetweenNoise).
  estimator::PoseBetweenNoise pose_between_noise = estimator::PoseBetweenNoise::kConstant;
  /// > 0: a position sensor's frame and L are both levelled, and its alignment holds
  /// R_AL's tilt to this std (deg, as the scenario's `alignment_level_prior_deg` states
  /// it; AlignmentGraphOptions::level_prior_std_rad); 0: every rotation of T_AL from the
  /// pairs (the paper).
  double alignment_level_prior_deg = 0.0;
  /// The scenario's users' estimators (`external:` and `plugins:`), which methods
  /// "external:<key>" and "plugin:<key>" name.
  std::vector<ClientSpec> clients;
  /// This block as the resolved scenario writes it (what a client's setup carries).
  std::string resolved_yaml;

  /// The profile a block without `profile:` gets.
  static constexpr EstimationProfile kDefaultProfile = EstimationProfile::kRecommended;
  /// A profile's values of every option (no methods, no clients).
  static EstimationConfig Defaults(EstimationProfile profile);
  /// The threshold a profile gives `metric` when a block names the metric without one:
  /// each metric has its own scale.
  static double DefaultThreshold(EstimationProfile profile, estimator::ConsistencyMetric metric);
  /// The block's own keys but `methods` and `consensus` (the writer's order; `profile`
  /// first, read before the others).
  static std::span<const core::OptionField<EstimationConfig>> Fields();
  /// Both tables' limits and rules (consensus keys as "consensus.<key>: ...").
  bool IsValid(std::string* why = nullptr) const;
};

/// What every method of a run is configured with, from the streams' description (the
/// run directory's calibration, ReadRecordedLog or DescribeRunStreams) and the scenario's
/// `estimation:` block: in the loop and in `tofu estimate` alike.
struct EstimationSetup {
  estimator::MultiGraphEstimatorOptions estimator;
  std::vector<estimator::SensorSpec> sensors;
  estimator::ConsensusEstimatorOptions consensus;
};
/// Throws core::InputError when the options are outside their limits
/// (MultiGraphEstimatorOptions::IsValid, ConsensusEstimatorOptions::IsValid). Checked where
/// user values become options (a scenario's estimation: block, `tofu estimate` flags), so a
/// bad value is bad input (exit 2) before anything is written, not an estimator's
/// std::invalid_argument halfway through a run. `where` and `key_path` name where the
/// values came from.
void RequireValidOptions(const estimator::MultiGraphEstimatorOptions& estimator,
                         const estimator::ConsensusEstimatorOptions& consensus,
                         const core::SourceLocation& where, const std::string& key_path);

/// Validated (RequireValidOptions, key path "estimation").
EstimationSetup MakeEstimationSetup(const RecordedLog& log, const EstimationConfig& config);

/// The options of the consensus estimator from a scenario's configuration.
estimator::ConsensusOptions SelectionOptions(const ConsensusConfig& config);

}  // namespace tofu::replay
