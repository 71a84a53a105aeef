#include "replay/estimation_config.h"

#include <algorithm>

#include <fmt/format.h>

#include "core/error.h"
#include "core/time.h"
#include "core/units.h"
#include "replay/recorded_log.h"
#include "replay/replay_method.h"

namespace tofu::replay {

namespace {

using estimator::ConsistencyMetric;

constexpr core::ChoiceName kProfileChoices[] = {
    {"paper", static_cast<int>(EstimationProfile::kPaper)},
    {"recommended", static_cast<int>(EstimationProfile::kRecommended)}};
// nis needs the streams' stated covariances, which only the consensus has; the paper's
// other metrics (mae, pcc, kl) are `tofu consistency`'s, not a selection's.
constexpr core::ChoiceName kMetricChoices[] = {
    {"cm", static_cast<int>(ConsistencyMetric::kCm)},
    {"nis", static_cast<int>(ConsistencyMetric::kNis)}};
constexpr core::ChoiceName kPolicyChoices[] = {
    {"pair_member", static_cast<int>(estimator::ConsensusPolicy::kPairMember)},
    {"consistent_set", static_cast<int>(estimator::ConsensusPolicy::kConsistentSet)}};
constexpr core::ChoiceName kPositionFactorChoices[] = {
    {"between", static_cast<int>(estimator::PositionFactors::kBetween)},
    {"absolute", static_cast<int>(estimator::PositionFactors::kAbsolute)},
    {"offset", static_cast<int>(estimator::PositionFactors::kOffset)}};
constexpr core::ChoiceName kDegenerateChoices[] = {{"fused", 0}, {"left_out", 1}};
constexpr core::ChoiceName kPoseNoiseChoices[] = {
    {"constant", static_cast<int>(estimator::PoseBetweenNoise::kConstant)},
    {"white_and_drift", static_cast<int>(estimator::PoseBetweenNoise::kWhiteAndDrift)}};

}  // namespace

std::string_view EstimationProfileName(EstimationProfile profile) {
  // The words of the `profile` field (the table's first), so a profile is named once.
  return core::ChoiceWord(EstimationConfig::Fields().front().format, static_cast<int>(profile));
}

core::NumberRule ThresholdRule(ConsistencyMetric metric) {
  // cm: the paper's 0.1 m/s sits well inside; above 2 m/s no fault of the suite would be
  // seen. nis: below 1 (the statistic's mean for consistent streams) healthy pairs fail.
  return metric == ConsistencyMetric::kNis ? core::NumberRule::Between(1.0, 100.0, "")
                                           : core::NumberRule::Between(1e-6, 2.0, "m/s");
}

std::span<const core::OptionField<ConsensusConfig>> ConsensusConfig::Fields() {
  using F = core::OptionField<ConsensusConfig>;
  using R = core::NumberRule;
  using C = ConsensusConfig;
  static const F kFields[] = {
      F::Choice<&C::metric>("metric", kMetricChoices)
          .Doc("the pairs' consistency metric: cm, the paper's Cramér-von Mises distance of "
               "body velocities (m/s), or nis, the difference normalised by the sensors' "
               "stated covariances (unitless, 1 for consistent streams)"),
      F::Number("threshold", &C::threshold, R::Positive("m/s for cm, unitless for nis"))
          .Doc("a pair below it is consistent; in the metric's unit (cm: at most 2 m/s; nis: "
               "at least 1); a block naming a metric without it gets its profile's threshold "
               "for that metric"),
      F::OptionalNumber("leave_threshold", &C::leave_threshold,
                        R::Positive("m/s for cm, unitless for nis"))
          .Doc("hysteresis: a fused pair stays consistent below this (>= threshold); unset: "
               "the threshold"),
      F::Number("min_dwell_s", &C::min_dwell_s, R::Between(0.0, 3600.0, "s"))
          .Doc("least time between two changes of the fused set"),
      F::Choice<&C::policy>("fuse", kPolicyChoices)
          .Doc("pair_member: one sensor of the most consistent pair (the paper); "
               "consistent_set: every sensor of the largest mutually consistent set"),
      F::Flag("return_to_priority", &C::return_to_priority)
          .Doc("pair_member: give way to a preferred sensor (priority) once it is consistent "
               "again"),
      F::Number("window_s", &C::window_s, R::Between(0.1, 60.0, "s"))
          .Doc("the consistency metric's sliding window"),
      F::Number("rate_hz", &C::rate_hz, R::Between(0.5, 100.0, "Hz"))
          .Doc("consistency evaluations per second"),
      F::Number("bias_window_s", &C::bias_window_s, R::Between(0.0, 600.0, "s"))
          .Doc("window of each pair's mean-difference test, which sees slow drifts the "
               "window metric does not (0: off; else at least 0.5 s)"),
      F::Number("bias_false_alarm", &C::bias_false_alarm, R::Between(1e-12, 0.5, ""))
          .Doc("the mean-difference test's false-alarm probability per evaluation"),
      F::Number("bias_floor_mps", &C::bias_floor_mps, R::Between(0.0, 1.0, "m/s"))
          .Doc("floor of the standard deviation of the mean difference"),
  };
  return kFields;
}

bool ConsensusConfig::IsValid(std::string* why) const {
  if (!core::CheckOptionFields<ConsensusConfig>(*this, Fields(), why)) return false;
  const core::NumberRule rule = ThresholdRule(metric);
  const std::string metric_name(estimator::MetricName(metric));
  const auto fail = [&](const std::string& text) {
    if (why != nullptr) *why = text;
    return false;
  };
  if (!rule.Accepts(threshold)) {
    return fail(fmt::format("threshold: expected a number{} for metric {}, got {}",
                            rule.Describe(), metric_name, core::FormatDouble(threshold)));
  }
  if (leave_threshold && (!rule.Accepts(*leave_threshold) || *leave_threshold < threshold)) {
    return fail(fmt::format("leave_threshold: expected a number{} for metric {}, at least "
                            "threshold ({}), got {}",
                            rule.Describe(), metric_name, core::FormatDouble(threshold),
                            core::FormatDouble(*leave_threshold)));
  }
  if (bias_window_s > 0.0 && bias_window_s < 0.5) {
    return fail(fmt::format("bias_window_s: expected 0 (off) or at least 0.5 (s), got {}",
                            core::FormatDouble(bias_window_s)));
  }
  return true;
}

std::span<const core::OptionField<EstimationConfig>> EstimationConfig::Fields() {
  using F = core::OptionField<EstimationConfig>;
  using R = core::NumberRule;
  using E = EstimationConfig;
  static const F kFields[] = {
      F::Choice<&E::profile>("profile", kProfileChoices)
          .Doc("the defaults of every other key: paper (the seed paper's configuration) or "
               "recommended (the best combination by measurement, docs/RESULTS.md)"),
      F::Number("huber_delta", &E::huber_delta, R::Between(0.0, 100.0, "sigma"))
          .Doc("Huber loss on the between factors, in standard deviations (0: off, the "
               "paper)"),
      F::Choice<&E::position_factors>("position_factors", kPositionFactorChoices)
          .Doc("how position sensors constrain the local graph: between (displacements, the "
               "paper's eq. 3), absolute (through the frozen T_AL) or offset (up to an offset "
               "per chain the graph estimates)"),
      F::Choice<&E::leave_out_degenerate_directions>("degenerate_directions",
                                                     kDegenerateChoices)
          .Doc("a LiDAR odometry's degenerate directions: fused (the paper) or left_out of "
               "its between factors"),
      F::Choice<&E::pose_between_noise>("pose_between_noise", kPoseNoiseChoices)
          .Doc("weights of pose sensors' between factors: constant (the paper's ω) or "
               "white_and_drift (white error at both ends and drift over the distance; a stream "
               "that states no white error keeps constant)"),
      F::Number("alignment_level_prior_deg", &E::alignment_level_prior_deg,
                R::Between(0.0, 10.0, "deg"))
          .Doc("> 0: position sensors' alignments hold R_AL's tilt to this std (both frames "
               "levelled); 0: every rotation from the pairs (the paper)"),
  };
  return kFields;
}

bool EstimationConfig::IsValid(std::string* why) const {
  if (!core::CheckOptionFields<EstimationConfig>(*this, Fields(), why)) return false;
  if (!consensus.IsValid(why)) {
    if (why != nullptr) *why = "consensus." + *why;
    return false;
  }
  return true;
}

EstimationConfig EstimationConfig::Defaults(EstimationProfile profile) {
  EstimationConfig config;  // the paper's: the member initialisers
  config.profile = profile;
  if (profile == EstimationProfile::kRecommended) {
    // The choice of scripts/measure_profiles.py (docs/RESULTS.md, "One recommended
    // profile"; ctest EstimationProfile.RecommendedIsTheMeasuredChoice holds these to it).
    config.consensus.threshold = DefaultThreshold(profile, config.consensus.metric);
    config.huber_delta = 3.0;
    config.pose_between_noise = estimator::PoseBetweenNoise::kWhiteAndDrift;
    config.consensus.bias_window_s = 10.0;
  }
  return config;
}

double EstimationConfig::DefaultThreshold(EstimationProfile profile, ConsistencyMetric metric) {
  // nis's 3 was not chosen again for `recommended` (the selection kept cm).
  if (metric == ConsistencyMetric::kNis) return 3.0;
  return profile == EstimationProfile::kRecommended ? 0.3 : 0.1;
}

estimator::ConsensusOptions SelectionOptions(const ConsensusConfig& config) {
  estimator::ConsensusOptions options;
  options.threshold = config.threshold;
  options.leave_threshold = config.leave_threshold;
  options.min_dwell_ns = core::SecondsToTime(config.min_dwell_s);
  options.policy = config.policy;
  options.return_to_priority = config.return_to_priority;
  options.priority = config.priority;
  return options;
}

void RequireValidOptions(const estimator::MultiGraphEstimatorOptions& estimator,
                         const estimator::ConsensusEstimatorOptions& consensus,
                         const core::SourceLocation& where, const std::string& key_path) {
  std::string why;
  if (!estimator.IsValid(&why)) {
    throw core::InputError(where, key_path, "the estimator's options are invalid: " + why);
  }
  if (!consensus.IsValid(&why)) {
    throw core::InputError(where, key_path, "the consensus options are invalid: " + why);
  }
}

EstimationSetup MakeEstimationSetup(const RecordedLog& log, const EstimationConfig& config) {
  EstimationSetup setup;
  setup.estimator = DefaultEstimatorOptions(log);
  setup.estimator.local.huber_delta = config.huber_delta;
  setup.estimator.alignment.level_prior_std_rad =
      core::RadFromDeg(config.alignment_level_prior_deg);
  setup.sensors = SensorSpecsOf(log);
  for (estimator::SensorSpec& spec : setup.sensors) {
    spec.position_factors = config.position_factors;
    const auto stream = std::find_if(log.streams.begin(), log.streams.end(),
                                     [&](const RecordedStream& s) { return s.name == spec.name; });
    if (spec.kind == estimator::SensorKind::kPose) {
      // A stream that states its white error nowhere (a TUM file: no covariance per sample,
      // no noise in calibration.yaml) would be weighted by its samples' default identity
      // covariance, 1 m and 1 rad: a factor that constrains nothing. It keeps the constant
      // weights of its stated (or nominal) between stds instead.
      const bool white_stated =
          stream == log.streams.end() || stream->covariance_stated ||
          (stream->position_noise_m && stream->rotation_noise_rad);
      spec.pose_between_noise = white_stated ? config.pose_between_noise
                                             : estimator::PoseBetweenNoise::kConstant;
    }
    if (!config.leave_out_degenerate_directions) continue;
    if (stream == log.streams.end() || spec.kind != estimator::SensorKind::kPose) continue;
    spec.unobserved_position_std_m = stream->unobserved_position_std_m.value_or(0.0);
    spec.unobserved_rotation_std_rad = stream->unobserved_rotation_std_rad.value_or(0.0);
  }
  setup.consensus.selection = SelectionOptions(config.consensus);
  setup.consensus.consistency.metric = config.consensus.metric;
  setup.consensus.consistency.consistency.window_ns =
      core::SecondsToTime(config.consensus.window_s);
  setup.consensus.consistency.history_ns =
      setup.consensus.consistency.consistency.window_ns + 2'000'000'000;
  setup.consensus.evaluation_period_ns = core::PeriodFromRate(config.consensus.rate_hz);
  setup.consensus.bias_window_ns = core::SecondsToTime(config.consensus.bias_window_s);
  setup.consensus.bias_min_span_ns =
      std::min(setup.consensus.bias_min_span_ns, setup.consensus.bias_window_ns);
  setup.consensus.bias_false_alarm = config.consensus.bias_false_alarm;
  setup.consensus.bias.floor_std_mps = config.consensus.bias_floor_mps;
  RequireValidOptions(setup.estimator, setup.consensus, {}, "estimation");
  return setup;
}

}  // namespace tofu::replay
