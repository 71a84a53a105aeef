#include "replay/estimate_command.h"

#include <algorithm>
#include <limits>

#include <fmt/format.h>

#include "core/error.h"
#include "replay/file_io.h"
#include "replay/method_evaluation.h"
#include "replay/method_runner.h"
#include "replay/method_writers.h"
#include "replay/replay_method.h"

namespace tofu::replay {

namespace {

// `--method` as given, or by default each non-IMU stream alone.
std::vector<ReplayMethod> MethodsToReplay(const EstimateCommandOptions& options,
                                          const RecordedLog& log,
                                          const std::vector<ClientSpec>& clients) {
  std::vector<ReplayMethod> methods;
  if (options.methods.empty()) {
    for (const RecordedStream& s : log.streams) {
      if (s.kind != core::MeasurementKind::kImu) methods.push_back(ParseReplayMethod("single:" + s.name, log));
    }
  } else {
    for (const std::string& m : options.methods) methods.push_back(ParseReplayMethod(m, log, clients));
  }
  return methods;
}

// A tofu run directory says how its methods were configured (its scenario's
// estimation: block): the same configuration reproduces what ran in the flight.
EstimationConfig RunEstimationConfig(const EstimateCommandOptions& options) {
  EstimationConfig run_config = EstimationConfig::Defaults(EstimationConfig::kDefaultProfile);
  if (const std::filesystem::path scenario = options.log_dir / "scenario.yaml";
      options.read_estimation_config && std::filesystem::is_regular_file(scenario)) {
    if (const std::optional<EstimationConfig> config = options.read_estimation_config(scenario)) {
      run_config = *config;
      run_config.methods.clear();
      if (!options.quiet) {
        fmt::print("note: estimator configured from {} (its estimation: block)\n",
                   scenario.string());
      }
    }
  }
  if (options.apply_settings) options.apply_settings(&run_config);
  return run_config;
}

estimator::MultiGraphEstimatorOptions WithEstimatorOverrides(
    estimator::MultiGraphEstimatorOptions estimator_options, const EstimateCommandOptions& options) {
  if (options.window_s) estimator_options.local.window_ns = core::SecondsToTime(*options.window_s);
  if (options.keyframe_rate_hz) estimator_options.local.keyframe_rate_hz = *options.keyframe_rate_hz;
  if (options.imu_noise_scale) {
    const double k = *options.imu_noise_scale / kInFlightImuNoiseScale;
    estimator_options.local.imu_noise.gyro_noise_density_radps_per_sqrthz *= k;
    estimator_options.local.imu_noise.accel_noise_density_mps2_per_sqrthz *= k;
  }
  return estimator_options;
}

std::vector<estimator::SensorSpec> WithBetweenFactorOverrides(
    std::vector<estimator::SensorSpec> specs, const EstimateCommandOptions& options) {
  for (estimator::SensorSpec& spec : specs) {
    const bool overridden = options.between_position_std_m || options.between_rotation_std_rad ||
                            options.between_position_in_reference;
    if (overridden && spec.pose_between_noise == estimator::PoseBetweenNoise::kWhiteAndDrift) {
      throw core::InputError(
          {}, "--between-position-std, --between-rotation-std, --position-in-reference",
          "the run's scenario weights '" + spec.name +
              "' by its own noise (estimation.pose_between_noise: white_and_drift), which "
              "constant between stds do not apply to; expected none of these options, or "
              "--set pose_between_noise=constant with them");
    }
    if (options.between_position_std_m) spec.between_position_std_m = *options.between_position_std_m;
    if (options.between_rotation_std_rad) spec.between_rotation_std_rad = *options.between_rotation_std_rad;
    if (options.between_position_std_m || options.between_rotation_std_rad) {
      spec.between_noise_from_data = false;
    }
    if (options.between_position_in_reference) {
      spec.between_position_in_reference = *options.between_position_in_reference;
    }
  }
  return specs;
}

// Methods with @clean replay the un-faulted streams of the same run.
std::optional<RecordedLog> ReadCleanLogIfAsked(const EstimateCommandOptions& options,
                                               const std::vector<ReplayMethod>& methods) {
  std::optional<RecordedLog> clean_log;
  for (const ReplayMethod& m : methods) {
    if (m.clean_streams && !options.use_clean_streams && !clean_log) {
      RecordedLogOptions clean_read;
      clean_read.use_clean_streams = true;
      clean_log = ReadRecordedLog(options.log_dir, clean_read);
    }
  }
  return clean_log;
}

void PrintClientFailure(const ReplayResult& result) {
  fmt::print(stderr, "error: {}\n", ClientFailureText(result));
}

void WarnIfWorseThanInput(const ReplayMethod& method, const MethodScores& scores) {
  if (const std::optional<InputCheck>& c = scores.input_check;
      c && (c->worse_in_position || c->worse_in_rotation)) {
    fmt::print(stderr,
               "warning: {} is worse than its input {} on the same span (ATE {:.4f} m vs "
               "{:.4f} m, rotation {:.3f} deg vs {:.3f} deg)\n",
               method.name, c->input, c->ate_m, c->input_ate_m, c->rotation_deg,
               c->input_rotation_deg);
  }
}

void PrintMethodRow(const ReplayMethod& method, const ReplayResult& result,
                    const MethodScores& scores, const MethodFiles& files) {
  const std::vector<PoseSample>& trajectory = scores.trajectory;
  const std::optional<TrajectoryErrors>& errors = scores.errors;
  fmt::print("{:<28} {:>9} {:>9} {:>9} {:>9} {:>8.0f} {:>10.3f} {:>10.3f}\n", method.name,
             errors ? fmt::format("{:.4f}", errors->ate_position_rmse_m) : "n/a",
             errors ? fmt::format("{:.3f}", errors->rotation_rmse_deg) : "n/a",
             errors ? fmt::format("{:.4f}", errors->rpe_translation_rmse_m) : "n/a",
             fmt::format("{}/{}", trajectory.size(), OutputCount(result)),
             result.wall_time_s > 0 ? result.log_duration_s / result.wall_time_s : 0.0,
             files.solve_mean_ms, files.solve_p99_ms);
}

// Each pose stream on its own over the span the methods covered (ScoreRawStreams).
void WriteRawStreamBaselines(const RecordedLog& log, core::Time first_output_ns,
                             core::Time last_output_ns, const std::filesystem::path& out_dir,
                             bool quiet) {
  for (const RawStreamScore& raw : ScoreRawStreams(log, first_output_ns, last_output_ns)) {
    WriteRawStreamResult(log, raw, out_dir);
    if (!quiet) {
      fmt::print("{:<28} {:>9.4f} {:>9.3f} {:>9.4f}   (the stream alone, same span)\n",
                 "raw:" + raw.stream, raw.errors.ate_position_rmse_m, raw.errors.rotation_rmse_deg,
                 raw.errors.rpe_translation_rmse_m);
    }
  }
}

}  // namespace

int RunEstimateCommand(const EstimateCommandOptions& options) {
  RecordedLogOptions read;
  read.use_clean_streams = options.use_clean_streams;
  const RecordedLog log = ReadRecordedLog(options.log_dir, read);
  const EstimationConfig run_config = RunEstimationConfig(options);
  const std::vector<ReplayMethod> methods = MethodsToReplay(options, log, run_config.clients);
  const EstimationSetup setup = MakeEstimationSetup(log, run_config);
  const ClientTexts texts{log.calibration_yaml, run_config.resolved_yaml};
  const estimator::MultiGraphEstimatorOptions estimator_options =
      WithEstimatorOverrides(setup.estimator, options);
  const std::optional<RecordedLog> clean_log = ReadCleanLogIfAsked(options, methods);
  const auto log_for = [&](const ReplayMethod& m) -> const RecordedLog& {
    return m.clean_streams && clean_log ? *clean_log : log;
  };
  const std::vector<estimator::SensorSpec> specs = WithBetweenFactorOverrides(setup.sensors, options);
  if (!options.quiet) {
    for (const std::string& note : log.notes) fmt::print("note: {}\n", note);
    fmt::print("{:<28} {:>9} {:>9} {:>9} {:>9} {:>8} {:>10} {:>10}\n", "method", "ATE [m]",
               "rot [deg]", "RPE1s [m]", "valid", "x RT", "solve [ms]", "p99 [ms]");
  }
  const estimator::ConsensusEstimatorOptions& consensus_options = setup.consensus;
  RequireValidOptions(estimator_options, consensus_options,
                      {"tofu estimate (--window, --keyframe-rate, --imu-noise-scale)"}, "");
  const std::filesystem::path out_dir = options.out_dir.value_or(options.log_dir);
  std::filesystem::create_directories(out_dir);
  ConsensusFiles consensus_files(out_dir);
  core::Time first_output_ns = std::numeric_limits<core::Time>::max();
  core::Time last_output_ns = std::numeric_limits<core::Time>::min();
  bool failed = false;
  bool failed_client = false;  // a user's estimator failed: exit 3, as a failed flight
  // The same scores as a run's (labels.csv of a run directory: detection and false
  // exclusions too), of which the files below show what `tofu estimate` always showed.
  ScoringContext scoring;
  // The run ends with its last sample (a tofu run starts at t = 0, as its labels do).
  for (const core::StampedMeasurement& m : log.measurements) {
    scoring.run_duration_s = std::max(scoring.run_duration_s, core::TimeToSeconds(m.t_ns));
  }
  for (const estimator::SensorSpec& s : specs) scoring.sensors.push_back(s.name);
  scoring.consensus_threshold = consensus_options.selection.threshold;
  // Every method's figures in summary.json's schema (MethodEvaluationJson): what a run's
  // scoring of the same outputs gives, so a configuration can be measured on recorded runs.
  nlohmann::json evaluation = {{"methods", nlohmann::json::object()},
                               {"estimation", run_config.resolved_yaml}};
  for (const ReplayMethod& method : methods) {
    std::function<void(double)> progress;
    if (options.progress) progress = [&](double f) { options.progress(method.name, f); };
    const ReplayResult result = Replay(log_for(method), method, estimator_options, specs,
                                       progress, consensus_options, texts);
    const RecordedLog& method_log = log_for(method);
    scoring.labels = &method_log.labels;
    const MethodScores scores = ScoreMethod(method_log, result, scoring);
    const MethodFiles files = WriteMethodResult(method_log, result, scores, out_dir);
    evaluation["methods"][method.name] = MethodEvaluationJson(scores.evaluation);
    if (result.failure) {
      PrintClientFailure(result);
      failed_client = true;
    }
    consensus_files.Add(result);
    if (!scores.trajectory.empty()) {
      first_output_ns = std::min(first_output_ns, scores.trajectory.front().t_ns);
      last_output_ns = std::max(last_output_ns, scores.trajectory.back().t_ns);
    }
    WarnIfWorseThanInput(method, scores);
    if (const std::optional<std::string> starved = NothingToFuse(result, log_for(method).imu_stream)) {
      fmt::print(stderr, "error: {}\n", *starved);
      failed = true;
    }
    if (!options.quiet) PrintMethodRow(method, result, scores, files);
  }
  consensus_files.Commit();
  WriteFileAtomically(out_dir / "evaluation.json", evaluation.dump(2) + "\n");
  WriteRawStreamBaselines(log, first_output_ns, last_output_ns, out_dir, options.quiet);
  if (failed_client) return core::kExitSimulationError;
  return failed ? 1 : 0;
}

}  // namespace tofu::replay
