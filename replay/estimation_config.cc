#include "replay/estimation_config.h"

#include <algorithm>

#include "core/error.h"
#include "core/time.h"
#include "core/units.h"
#include "replay/recorded_log.h"
#include "replay/replay_method.h"

namespace tofu::replay {

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
      spec.pose_between_noise = config.pose_between_noise;
      // A white error the stream states nowhere would be the default identity covariance
      // of its samples: 1 m and 1 rad, a factor that constrains nothing.
      if (config.pose_between_noise == estimator::PoseBetweenNoise::kWhiteAndDrift &&
          stream != log.streams.end() && !stream->covariance_stated &&
          !(stream->position_noise_m && stream->rotation_noise_rad)) {
        throw core::InputError({}, "estimation.pose_between_noise",
                               "white_and_drift needs each pose stream's white noise, but '" +
                                   spec.name +
                                   "' states neither a covariance per sample nor "
                                   "position_noise_m and rotation_noise_deg in "
                                   "calibration.yaml; expected constant for it");
      }
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
