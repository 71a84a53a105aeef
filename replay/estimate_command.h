#pragma once
// `tofu estimate`: a recorded log's methods replayed, scored and written, with a table.

#include <filesystem>
#include <functional>
#include <optional>
#include <string>
#include <vector>

#include "replay/estimation_config.h"

namespace tofu::replay {

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
  std::optional<bool> between_position_in_reference;
  /// Factor from the at-rest (calibration or datasheet) IMU white-noise densities to the
  /// in-flight ones the estimator uses (default 10, see DefaultEstimatorOptions).
  std::optional<double> imu_noise_scale;
  /// Reads the `estimation:` block of a tofu run directory's scenario.yaml (the
  /// harness's scenario reader; nullopt when the scenario has none), so the methods are
  /// configured as in the flight. Unset: scenario.yaml is not read.
  std::function<std::optional<EstimationConfig>(const std::filesystem::path& scenario_yaml)>
      read_estimation_config;
  /// Applies `--set KEY=VALUE` to the estimation configuration (the run's scenario's, or
  /// the default profile's for a real log): the harness's reader of the estimation keys
  /// (harness::ApplyEstimationSettings). May be empty.
  std::function<void(EstimationConfig* config)> apply_settings;
  /// Progress of each method (the CLI draws a bar); may be empty.
  std::function<void(const std::string& method, double fraction)> progress;
};
int RunEstimateCommand(const EstimateCommandOptions& options);

}  // namespace tofu::replay
