#include "replay/replay_method.h"

#include <algorithm>
#include <cmath>
#include <sstream>
#include <variant>

#include <fmt/format.h>

#include "core/error.h"

namespace tofu::replay {

std::string MethodFileStem(const std::string& method) {
  std::string out = method;
  for (char& c : out) {
    if (c == ':' || c == '+' || c == '/' || c == ' ') c = '_';
  }
  return out;
}

namespace {

constexpr const char* kMethodForms =
    "single:<sensor>, fuse:<a>+<b>, imu_only, naive, oracle, consensus, "
    "consensus:pair_member, consensus:consistent_set, external:<client> or plugin:<client>, "
    "optionally with @clean";

// "external:<key>" or "plugin:<key>" against the scenario's clients: the parsed method, an
// error message, or nullopt when `body` is no client method.
std::optional<std::variant<ReplayMethod, std::string>> ParseClientMethod(
    ReplayMethod method, const std::string& body, const std::vector<ClientSpec>& clients) {
  const bool process = body.starts_with("external:");
  if (!process && !body.starts_with("plugin:")) return std::nullopt;
  const std::string key = body.substr(body.find(':') + 1);
  const ClientSpec::Kind kind = process ? ClientSpec::Kind::kProcess : ClientSpec::Kind::kPlugin;
  std::string known;
  for (const ClientSpec& c : clients) {
    if (c.kind == kind && c.key == key) {
      method.kind = ReplayMethod::Kind::kClient;
      method.client = c;
      return method;
    }
    if (c.kind == kind) known += (known.empty() ? "" : ", ") + c.key;
  }
  return fmt::format("method '{}': no {} client '{}' in the scenario's {} block (known: {})",
                     method.name, process ? "process" : "plug-in", key,
                     process ? "external:" : "plugins:", known.empty() ? "(none)" : known);
}

// The grammar of method names, against a list of sensor names and the scenario's clients;
// the parsed method or an error message.
std::variant<ReplayMethod, std::string> ParseMethod(const std::string& name,
                                                    const std::vector<std::string>& sensors,
                                                    const std::vector<ClientSpec>& clients) {
  ReplayMethod method;
  method.name = name;
  std::string body = name;
  const std::string kClean = "@clean";
  if (body.size() > kClean.size() && body.ends_with(kClean)) {
    method.clean_streams = true;
    body.resize(body.size() - kClean.size());
  }
  std::string known;
  for (const std::string& s : sensors) known += (known.empty() ? "" : ", ") + s;
  if (known.empty()) known = "(none)";
  std::optional<std::string> error;
  auto require = [&](const std::string& sensor) {
    if (std::find(sensors.begin(), sensors.end(), sensor) == sensors.end()) {
      error = fmt::format("method '{}': no sensor stream '{}' (known: {}); expected {}", name,
                          sensor, known, kMethodForms);
      return;
    }
    method.fused.push_back(sensor);
  };
  if (body == "imu_only") return method;
  if (auto client = ParseClientMethod(method, body, clients)) return std::move(*client);
  if (body == "naive") {
    method.kind = ReplayMethod::Kind::kNaive;
    method.fused = sensors;
    if (sensors.empty()) return fmt::format("method '{}': no sensor to fuse", name);
    return method;
  }
  if (body == "oracle") {
    method.kind = ReplayMethod::Kind::kOracle;
    method.fused = sensors;
    if (sensors.empty()) return fmt::format("method '{}': no sensor to fuse", name);
    return method;
  }
  if (body == "consensus" || body.starts_with("consensus:")) {
    method.kind = ReplayMethod::Kind::kConsensus;
    if (body != "consensus") {
      method.policy = estimator::ConsensusPolicyFromName(body.substr(10));
      if (!method.policy) {
        return fmt::format("method '{}': unknown consensus fusion '{}'; expected {}", name,
                           body.substr(10), kMethodForms);
      }
    }
    if (sensors.empty()) return fmt::format("method '{}': no sensor to choose from", name);
    return method;
  }
  if (body.starts_with("single:")) {
    require(body.substr(7));
    if (error) return *error;
    return method;
  }
  if (body.starts_with("fuse:")) {
    std::stringstream list(body.substr(5));
    std::string sensor;
    while (std::getline(list, sensor, '+')) require(sensor);
    if (error) return *error;
    if (!method.fused.empty()) return method;
  }
  return fmt::format("method '{}': expected {} (sensors: {})", name, kMethodForms, known);
}

}  // namespace

std::vector<std::string> SensorNamesOf(const RecordedLog& log) {
  std::vector<std::string> names;
  for (const RecordedStream& s : log.streams) {
    if (s.kind != core::MeasurementKind::kImu) names.push_back(s.name);
  }
  return names;
}

ReplayMethod ParseReplayMethod(const std::string& name, const RecordedLog& log,
                               const std::vector<ClientSpec>& clients) {
  auto parsed = ParseMethod(name, SensorNamesOf(log), clients);
  if (auto* error = std::get_if<std::string>(&parsed)) {
    throw core::InputError({log.directory.string()}, "--method", *error);
  }
  return std::get<ReplayMethod>(std::move(parsed));
}

std::optional<std::string> CheckMethodName(const std::string& name,
                                           const std::vector<std::string>& sensors,
                                           const std::vector<ClientSpec>& clients) {
  auto parsed = ParseMethod(name, sensors, clients);
  if (auto* error = std::get_if<std::string>(&parsed)) return *error;
  return std::nullopt;
}

estimator::MultiGraphEstimatorOptions DefaultEstimatorOptions(const RecordedLog& log) {
  estimator::MultiGraphEstimatorOptions options;
  if (log.imu_noise) {
    options.local.imu_noise.gyro_noise_density_radps_per_sqrthz =
        log.imu_noise->gyro_noise_density_radps_per_sqrthz;
    options.local.imu_noise.accel_noise_density_mps2_per_sqrthz =
        log.imu_noise->accel_noise_density_mps2_per_sqrthz;
    options.local.imu_noise.gyro_random_walk_radps2_per_sqrthz =
        log.imu_noise->gyro_random_walk_radps2_per_sqrthz;
    options.local.imu_noise.accel_random_walk_mps3_per_sqrthz =
        log.imu_noise->accel_random_walk_mps3_per_sqrthz;
  }
  options.local.imu_noise.gyro_noise_density_radps_per_sqrthz *= kInFlightImuNoiseScale;
  options.local.imu_noise.accel_noise_density_mps2_per_sqrthz *= kInFlightImuNoiseScale;
  options.local.imu_samples_are_interval_averages = log.imu_samples_are_interval_averages;
  // Replays are reproducible: no wall-time cap on the solver (it would make the result
  // depend on the machine); the iteration cap still holds.
  options.local.max_solver_time_s = 1e6;
  return options;
}

std::vector<estimator::SensorSpec> SensorSpecsOf(const RecordedLog& log) {
  std::vector<estimator::SensorSpec> specs;
  for (const RecordedStream& s : log.streams) {
    if (s.kind == core::MeasurementKind::kImu) continue;
    estimator::SensorSpec spec;
    spec.name = s.name;
    spec.kind = s.kind == core::MeasurementKind::kPose ? estimator::SensorKind::kPose
                                             : estimator::SensorKind::kPosition;
    spec.T_Is = s.T_Is;
    // Between-factor weights from the stated odometry noise: the white noise of both ends
    // plus the drift over the distance flown between keyframes (~5 cm at 1.5 m/s, 30 Hz).
    constexpr double kDistanceBetweenKeyframes_m = 0.05;
    if (s.position_noise_m) {
      const double drift = s.position_random_walk_m_per_sqrtm.value_or(0.0) *
                           std::sqrt(kDistanceBetweenKeyframes_m);
      spec.between_position_std_m =
          std::sqrt(2.0 * *s.position_noise_m * *s.position_noise_m + drift * drift);
    }
    if (s.rotation_noise_rad) spec.between_rotation_std_rad = std::sqrt(2.0) * *s.rotation_noise_rad;
    // The same noise as the stream's own model (estimator::PoseBetweenNoise::kWhiteAndDrift):
    // a white std not stated leaves the sample's stated covariance as its white error.
    spec.white_position_std_m = s.position_noise_m.value_or(0.0);
    spec.white_rotation_std_rad = s.rotation_noise_rad.value_or(0.0);
    spec.drift.position_random_walk_m_per_sqrtm = s.position_random_walk_m_per_sqrtm.value_or(0.0);
    spec.drift.rotation_random_walk_rad_per_sqrtm =
        s.rotation_random_walk_rad_per_sqrtm.value_or(0.0);
    // A pose stream that states no noise, neither per sample nor in calibration.yaml (a
    // TUM file, a CSV without covariance columns), is weighted with its own scatter
    // against the IMU, measured from the data (multi_graph_estimator.h). A tofu run's
    // streams all carry covariances: they keep the stated or default weights.
    spec.between_noise_from_data = s.kind == core::MeasurementKind::kPose && !s.covariance_stated &&
                                   !s.position_noise_m && !s.rotation_noise_rad;
    specs.push_back(spec);
  }
  return specs;
}

}  // namespace tofu::replay
