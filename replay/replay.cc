#include "replay/replay.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <fstream>
#include <limits>
#include <numeric>
#include <sstream>
#include <variant>

#include <fmt/format.h>
#include <nlohmann/json.hpp>

#include "core/error.h"
#include "core/units.h"
#include "estimator/velocity.h"
#include "interface/client.h"
#include "replay/api_convert.h"
#include "replay/builtin_estimator.h"
#include "replay/estimation_config.h"
#include "replay/file_io.h"
#include "replay/run_calibration.h"

namespace tofu::replay {
namespace {

double Percentile(std::vector<double> values, double fraction) {
  if (values.empty()) return 0.0;
  std::sort(values.begin(), values.end());
  const auto index = static_cast<std::size_t>(
      std::min<double>(values.size() - 1, std::ceil(fraction * values.size()) - 1));
  return values[index];
}


// estimate_<method>.csv, a row per output, written as it is formatted (an hour of
// outputs at 200 Hz is 130 MB of text).
void WriteEstimateCsv(const std::filesystem::path& file, const ReplayResult& result) {
  AtomicFileWriter csv(file);
  csv.Append(
      "#timestamp [ns],p_LI_x [m],p_LI_y [m],p_LI_z [m],q_LI_w [],q_LI_x [],q_LI_y [],"
      "q_LI_z [],v_L_x [m s^-1],v_L_y [m s^-1],v_L_z [m s^-1],b_a_x [m s^-2],b_a_y [m s^-2],"
      "b_a_z [m s^-2],b_g_x [rad s^-1],b_g_y [rad s^-1],b_g_z [rad s^-1],std_p_x [m],"
      "std_p_y [m],std_p_z [m],valid,fused\n");
  ForEachOutput(result, [&](const estimator::EstimatorOutput& o) {
    Eigen::Quaterniond q = o.state.q_LI.normalized();
    if (q.w() < 0) q.coeffs() *= -1.0;
    std::string fused;
    for (const std::string& f : o.fused) fused += (fused.empty() ? "" : "+") + f;
    std::string std_p = ",,";
    if (o.position_covariance_m2) {
      const Eigen::Matrix3d& P = *o.position_covariance_m2;
      std_p = fmt::format("{:.6f},{:.6f},{:.6f}", std::sqrt(P(0, 0)), std::sqrt(P(1, 1)),
                          std::sqrt(P(2, 2)));
    }
    csv.Format(
        "{},{:.6f},{:.6f},{:.6f},{:.9f},{:.9f},{:.9f},{:.9f},{:.6f},{:.6f},{:.6f},{:.6f},{:.6f},"
        "{:.6f},{:.7f},{:.7f},{:.7f},{},{},{}\n",
        o.t_ns, o.state.p_LI.x(), o.state.p_LI.y(), o.state.p_LI.z(), q.w(), q.x(), q.y(), q.z(),
        o.state.v_L_mps.x(), o.state.v_L_mps.y(), o.state.v_L_mps.z(), o.bias.accel_mps2.x(),
        o.bias.accel_mps2.y(), o.bias.accel_mps2.z(), o.bias.gyro_radps.x(),
        o.bias.gyro_radps.y(), o.bias.gyro_radps.z(), std_p, o.valid ? 1 : 0, fused);
  });
  csv.Commit();
}

// Per-sample errors with both trajectories in W (the estimate through the alignment), for
// plots: scripts/plot_estimate.py draws this file.
void WriteErrorsCsv(const std::filesystem::path& file, const TrajectoryErrors& errors,
                    const std::vector<PoseSample>& estimate, const std::vector<PoseSample>& truth) {
  AtomicFileWriter csv(file);
  csv.Append(
      "#timestamp [ns],position_error [m],rotation_error [deg],p_W_est_x [m],p_W_est_y [m],"
      "p_W_est_z [m],p_W_true_x [m],p_W_true_y [m],p_W_true_z [m]\n");
  std::size_t e = 0;
  std::size_t g = 0;
  for (std::size_t k = 0; k < errors.t_ns.size(); ++k) {
    const core::Time t = errors.t_ns[k];
    while (e + 1 < estimate.size() && estimate[e].t_ns < t) ++e;
    while (g + 1 < truth.size() && truth[g + 1].t_ns <= t) ++g;
    const Eigen::Vector3d p_est = errors.T_WL * estimate[e].p;
    Eigen::Vector3d p_true = truth[g].p;
    if (g + 1 < truth.size() && truth[g + 1].t_ns > truth[g].t_ns) {
      const double u = static_cast<double>(t - truth[g].t_ns) /
                       static_cast<double>(truth[g + 1].t_ns - truth[g].t_ns);
      p_true = (1 - u) * truth[g].p + u * truth[g + 1].p;
    }
    csv.Format("{},{:.6f},{:.4f},{:.6f},{:.6f},{:.6f},{:.6f},{:.6f},{:.6f}\n", t,
               errors.position_error_m[k], errors.rotation_error_deg[k], p_est.x(), p_est.y(),
               p_est.z(), p_true.x(), p_true.y(), p_true.z());
  }
  csv.Commit();
}

std::string SafeFileName(const std::string& method) {
  std::string out = method;
  for (char& c : out) {
    if (c == ':' || c == '+' || c == '/' || c == ' ') c = '_';
  }
  return out;
}

// Datasheet (and Kalibr at-rest) white-noise densities describe an IMU on a table; on a
// flying multicopter, rotor vibration, its aliasing and unmodelled scale and misalignment
// errors make the effective noise an order of magnitude larger (tofu's own IMU model adds
// ~0.16 m/s² RMS of rotor vibration, 5x its white noise at 400 Hz). Visual-inertial
// systems configure EuRoC's ADIS16448 accordingly (VINS-Mono: 40x and 24x the datasheet).
// 10x is what docs/RESULTS.md measured best on both tofu's runs and EuRoC V1_02;
// `tofu estimate --imu-noise-scale` overrides it.
constexpr double kInFlightImuNoiseScale = 10.0;

}  // namespace

std::string MethodFileStem(const std::string& method) { return SafeFileName(method); }

std::string DecisionRows(const ReplayResult& result) {
  const auto join = [](const std::vector<std::string>& names) {
    std::string out;
    for (const std::string& n : names) out += (out.empty() ? "" : "+") + n;
    return out;
  };
  std::string rows;
  for (const estimator::ConsensusRecord& r : result.consensus) {
    const estimator::ConsensusDecision& d = r.decision;
    rows += fmt::format("{},{},{},{},{},{}\n", r.t_ns, result.method.name, join(d.fused),
                        join(d.excluded), join(d.unavailable), d.reason);
  }
  return rows;
}

std::string ConsistencyMatrixCsv(const ReplayResult& result) {
  std::string csv = "#timestamp [ns],pair,metric,value\n";
  for (const estimator::ConsensusRecord& r : result.consensus) {
    for (const auto& [pair, value] : r.values) {
      csv += fmt::format("{},{},{},{}\n", r.window_end_ns, pair, estimator::MetricName(r.metric),
                         value ? fmt::format("{:.6g}", *value) : std::string());
    }
  }
  return csv;
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

std::vector<std::string> SensorNamesOf(const RecordedLog& log) {
  std::vector<std::string> names;
  for (const RecordedStream& s : log.streams) {
    if (s.kind != StreamKind::kImu) names.push_back(s.name);
  }
  return names;
}

}  // namespace

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
    if (s.kind == StreamKind::kImu) continue;
    estimator::SensorSpec spec;
    spec.name = s.name;
    spec.kind = s.kind == StreamKind::kPose ? estimator::SensorKind::kPose
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
    // A pose stream that states no noise, neither per sample nor in calibration.yaml (a
    // TUM file, a CSV without covariance columns), is weighted with its own scatter
    // against the IMU, measured from the data (multi_graph_estimator.h). A tofu run's
    // streams all carry covariances: they keep the stated or default weights.
    spec.between_noise_from_data = s.kind == StreamKind::kPose && !s.covariance_stated &&
                                   !s.position_noise_m && !s.rotation_noise_rad;
    specs.push_back(spec);
  }
  return specs;
}

namespace {

// A client's estimates are checked before they are recorded (the protocol's decoder checks
// their form; a plug-in's come as structs): finite numbers, a non-zero quaternion, time
// that does not go backwards. Returns the problem, or an empty string.
std::string ClientEstimateProblem(const api::Estimate& e, std::optional<core::Time> previous_ns) {
  const auto finite = [](const auto& values) {
    return std::all_of(values.begin(), values.end(), [](double v) { return std::isfinite(v); });
  };
  if (previous_ns && e.t_ns < *previous_ns) {
    return fmt::format("t_ns {} is earlier than the previous estimate's {}: expected "
                       "non-decreasing times", e.t_ns, *previous_ns);
  }
  if (!finite(e.T_LI.p_m)) return "p_LI_m: expected 3 finite numbers";
  if (!finite(e.T_LI.q_wxyz)) return "q_LI_wxyz: expected 4 finite numbers";
  const double q_norm2 = e.T_LI.q_wxyz[0] * e.T_LI.q_wxyz[0] + e.T_LI.q_wxyz[1] * e.T_LI.q_wxyz[1] +
                         e.T_LI.q_wxyz[2] * e.T_LI.q_wxyz[2] + e.T_LI.q_wxyz[3] * e.T_LI.q_wxyz[3];
  if (!(q_norm2 > 1e-12)) return "q_LI_wxyz: expected a non-zero quaternion";
  if (!finite(e.v_L_mps)) return "v_L_mps: expected 3 finite numbers";
  if (!finite(e.omega_I_radps)) return "omega_I_radps: expected 3 finite numbers";
  if (!finite(e.bias_acc_mps2) || !finite(e.bias_gyro_radps)) return "bias: expected finite numbers";
  if (e.position_covariance_m2 && !finite(*e.position_covariance_m2)) {
    return "position_covariance_m2: expected 9 finite numbers";
  }
  return {};
}

// A client method's estimator: its process or its plug-in, started with its setup.
std::unique_ptr<api::Estimator> StartClient(const RecordedLog& log, const ReplayMethod& method,
                                            const ClientTexts& texts) {
  const ClientSpec& spec = *method.client;
  api::EstimatorSetup setup = ApiSetupOf(log, texts.gravity_mps2);
  setup.method = method.name;
  setup.config_json = spec.config_json;
  setup.calibration_yaml = CalibrationWithoutTruth(texts.calibration_yaml, "calibration.yaml");
  setup.estimation_yaml = texts.estimation_yaml;
  std::unique_ptr<api::Estimator> estimator;
  if (spec.kind == ClientSpec::Kind::kProcess) {
    interface::ProcessClientConfig config;
    config.name = method.name;
    config.command = spec.command;
    config.working_dir = spec.working_dir;
    config.timeout_s = spec.timeout_s;
    estimator = std::make_unique<interface::ProcessEstimator>(std::move(config));
  } else {
    estimator = interface::PluginLibrary::Open(spec.library)->CreateEstimator(spec.key);
  }
  estimator->Start(setup);
  return estimator;
}

}  // namespace

struct MethodRunner::Impl {
  ReplayMethod method;
  std::vector<std::string> stream_names;  // api sensor index -> name (the log's order)
  std::vector<std::string> sensor_names;  // the non-IMU streams
  std::unique_ptr<api::Estimator> estimator;
  BuiltinEstimator* builtin = nullptr;               // tofu's own (diagnostics, labels)
  interface::ProcessEstimator* process = nullptr;   // a process client (Sync)
  ReplayResult result;
  std::optional<core::Time> first_t_ns;
  core::Time last_t_ns = 0;
  std::vector<estimator::SensorSpec> specs;  // as given (what was stated)
  std::chrono::steady_clock::duration busy{};
  std::vector<api::Estimate> estimates;  // scratch
  std::optional<core::Time> last_estimate_ns;
  std::shared_ptr<OutputSpill> spill;  // SpillOutputsTo
  std::optional<estimator::EstimatorOutput> newest;  // of a spilled method

  void Keep(estimator::EstimatorOutput output) {
    if (spill == nullptr) {
      result.outputs.push_back(std::move(output));
      return;
    }
    spill->Append(output);
    newest = std::move(output);
  }

  std::size_t IndexOf(const std::string& sensor) const {
    for (std::size_t i = 0; i < stream_names.size(); ++i) {
      if (stream_names[i] == sensor) return i;
    }
    throw std::invalid_argument(fmt::format("method {}: measurement of unknown stream '{}'",
                                            method.name, sensor));
  }

  // The first failure is the one reported (what the client said after it is moot).
  void Fail(const std::string& why, std::vector<std::string> stderr_tail) {
    if (result.failure) return;
    result.failure = why;
    result.failure_stderr_tail = std::move(stderr_tail);
    estimator.reset();  // ends a process client now (no process left behind)
    process = nullptr;
  }

  // Runs `call` on a client, turning its errors into the method's failure.
  template <typename Call>
  void Guarded(Call&& call) {
    if (builtin != nullptr) {
      call();
      return;
    }
    try {
      call();
    } catch (const interface::ClientError& e) {
      Fail(e.what(), e.stderr_tail());
    } catch (const std::exception& e) {
      Fail(fmt::format("{}: {}", method.name, e.what()), {});
    }
  }

  // The estimates collected in `estimates` into the result (checked for a client).
  void Record() {
    for (api::Estimate& e : estimates) {
      if (result.failure) break;
      if (builtin == nullptr) {
        if (const std::string problem = ClientEstimateProblem(e, last_estimate_ns); !problem.empty()) {
          Fail(fmt::format("{}: estimate at t_ns {}: {}", method.name, e.t_ns, problem),
               process != nullptr ? process->End() : std::vector<std::string>{});
          break;
        }
        last_estimate_ns = e.t_ns;
      }
      Keep(FromApiEstimate(std::move(e)));
    }
    estimates.clear();
  }
};

MethodRunner::MethodRunner(const RecordedLog& log, const ReplayMethod& method,
                           const estimator::MultiGraphEstimatorOptions& options,
                           const std::vector<estimator::SensorSpec>& sensors,
                           const estimator::ConsensusEstimatorOptions& consensus_options,
                           const ClientTexts& texts)
    : impl_(std::make_unique<Impl>()) {
  Impl& m = *impl_;
  m.method = method;
  for (const RecordedStream& s : log.streams) {
    m.stream_names.push_back(s.name);
    if (s.kind != StreamKind::kImu) m.sensor_names.push_back(s.name);
  }
  m.specs = sensors;
  m.result.method = method;
  m.result.keyframe_period_ns = core::PeriodFromRate(options.local.keyframe_rate_hz);
  if (method.kind != ReplayMethod::Kind::kClient) {
    auto builtin = std::make_unique<BuiltinEstimator>(
        log, method, EstimationSetup{options, sensors, consensus_options});
    // Told what any estimator is told (the mission survey among it).
    api::EstimatorSetup setup = ApiSetupOf(log, texts.gravity_mps2);
    setup.method = method.name;
    builtin->Start(setup);
    m.builtin = builtin.get();
    m.estimator = std::move(builtin);
    for (const LabelEvent& label : log.labels) AddLabel(label);
    return;
  }
  m.Guarded([&] {
    m.estimator = StartClient(log, method, texts);
    m.process = dynamic_cast<interface::ProcessEstimator*>(m.estimator.get());
  });
}

MethodRunner::~MethodRunner() = default;
MethodRunner::MethodRunner(MethodRunner&&) noexcept = default;
MethodRunner& MethodRunner::operator=(MethodRunner&&) noexcept = default;

std::size_t MethodRunner::Add(const core::StampedMeasurement& measurement, core::Time arrival_ns) {
  Impl& m = *impl_;
  if (!m.estimator) return 0;  // a failed client
  const auto start = std::chrono::steady_clock::now();
  const std::size_t before = OutputCount(m.result);
  if (!m.first_t_ns || measurement.t_ns < *m.first_t_ns) m.first_t_ns = measurement.t_ns;
  m.last_t_ns = std::max(m.last_t_ns, measurement.t_ns);
  const api::Measurement sample =
      ToApiMeasurement(measurement, arrival_ns, m.IndexOf(measurement.sensor));
  m.Guarded([&] { m.estimator->Add(sample, &m.estimates); });
  m.Record();
  if (m.builtin != nullptr) {
    for (estimator::ConsensusRecord& r : m.builtin->TakeConsensusRecords()) {
      m.result.consensus.push_back(std::move(r));
    }
  }
  m.busy += std::chrono::steady_clock::now() - start;
  return OutputCount(m.result) - before;
}

void MethodRunner::Sync() {
  Impl& m = *impl_;
  if (m.process == nullptr) return;
  const auto start = std::chrono::steady_clock::now();
  m.Guarded([&] { m.process->Drain(&m.estimates); });
  m.Record();
  m.busy += std::chrono::steady_clock::now() - start;
}

bool MethodRunner::failed() const { return impl_->result.failure.has_value(); }

std::string MethodRunner::failure_text() const { return ClientFailureText(impl_->result); }

void MethodRunner::AddLabel(const LabelEvent& label) {
  // The un-faulted streams (@clean) have no scheduled fault; their conditions still hold.
  if (impl_->method.clean_streams && label.source == "fault") return;
  if (impl_->builtin != nullptr) impl_->builtin->AddLabel(label);
}

const estimator::EstimatorOutput* MethodRunner::newest_output() const {
  const Impl& m = *impl_;
  if (m.spill != nullptr) return m.newest ? &*m.newest : nullptr;
  return m.result.outputs.empty() ? nullptr : &m.result.outputs.back();
}

void MethodRunner::SpillOutputsTo(const std::filesystem::path& dir) {
  Impl& m = *impl_;
  if (OutputCount(m.result) > 0) throw std::logic_error("SpillOutputsTo after the first output");
  m.spill = std::make_shared<OutputSpill>(dir);
  m.result.spilled = m.spill;
}

namespace {

// A client that reports which sensors it fuses is scored as consensus is (detection,
// re-admission, false exclusion, switches): its fused sets become decisions, one at each
// change; every other sensor is excluded meanwhile.
std::vector<estimator::ConsensusRecord> DecisionsFromFusedSets(
    const ReplayResult& result, const std::vector<std::string>& sensors) {
  std::vector<estimator::ConsensusRecord> records;
  std::optional<std::vector<std::string>> previous;
  ForEachOutput(result, [&](const estimator::EstimatorOutput& o) {
    if (!o.initialized || (previous && *previous == o.fused)) return;
    estimator::ConsensusRecord r;
    r.t_ns = o.t_ns;
    r.window_end_ns = o.t_ns;
    r.decision.t_ns = o.t_ns;
    r.decision.fused = o.fused;
    r.decision.eligible = o.fused;
    for (const std::string& s : sensors) {
      if (std::find(o.fused.begin(), o.fused.end(), s) == o.fused.end()) {
        r.decision.excluded.push_back(s);
      }
    }
    r.decision.reason = "reported by the client";
    r.decision.changed = previous.has_value();
    previous = o.fused;
    records.push_back(std::move(r));
  });
  return records;
}

}  // namespace

ReplayResult MethodRunner::Finish() && {
  Impl& m = *impl_;
  if (m.builtin == nullptr && m.estimator) {
    const auto start = std::chrono::steady_clock::now();
    m.Guarded([&] {
      m.estimator->Finish(&m.estimates);
      m.result.client_report_json = m.estimator->ReportJson();
    });
    m.Record();
    m.estimator.reset();
    m.busy += std::chrono::steady_clock::now() - start;
  }
  ReplayResult result = std::move(m.result);
  result.wall_time_s = std::chrono::duration<double>(m.busy).count();
  if (m.first_t_ns) result.log_duration_s = core::TimeToSeconds(m.last_t_ns - *m.first_t_ns);
  result.first_measurement_ns = m.first_t_ns;
  if (m.builtin == nullptr) {
    bool reports_fused = false;
    ForEachOutput(result, [&](const estimator::EstimatorOutput& o) { reports_fused |= !o.fused.empty(); });
    if (reports_fused) result.consensus = DecisionsFromFusedSets(result, m.sensor_names);
    return result;
  }
  const estimator::MultiGraphEstimator& estimator = m.builtin->estimator();
  result.initialisations = estimator.initialisations();
  for (const estimator::SensorSpec& spec : m.specs) {
    const auto used = estimator.BetweenNoiseOf(spec.name);
    if (!used) continue;
    result.stream_noise[spec.name] = {
        used->position_std_m, used->rotation_std_rad,
        used->measured_at_ns ? "measured" : spec.between_noise_from_data ? "default" : "stated"};
  }
  result.counters = estimator.counters();
  result.solver = estimator.local().stats();
  for (const std::string& name : m.stream_names) {
    if (const estimator::AlignmentGraph* g = estimator.AlignmentGraphOf(name)) {
      result.alignment[name] = g->estimate();
    }
    if (const auto T_AL = estimator.AlignmentOf(name)) result.T_AL_used[name] = *T_AL;
  }
  return result;
}

ReplayResult Replay(const RecordedLog& log, const ReplayMethod& method,
                    const estimator::MultiGraphEstimatorOptions& options,
                    const std::vector<estimator::SensorSpec>& sensors,
                    const std::function<void(double)>& progress,
                    const estimator::ConsensusEstimatorOptions& consensus_options,
                    const ClientTexts& texts) {
  MethodRunner runner(log, method, options, sensors, consensus_options, texts);
  const std::size_t n = log.measurements.size();
  for (std::size_t i = 0; i < n; ++i) {
    runner.Add(log.measurements[i], log.arrival_ns[i]);
    if (progress && (i % 4096 == 0 || i + 1 == n)) progress(static_cast<double>(i + 1) / n);
  }
  return std::move(runner).Finish();
}

std::size_t OutputCount(const ReplayResult& result) {
  return result.spilled != nullptr ? result.spilled->size() : result.outputs.size();
}

void ForEachOutput(const ReplayResult& result,
                   const std::function<void(const estimator::EstimatorOutput&)>& visit) {
  if (result.spilled != nullptr) {
    result.spilled->ForEach(visit);
    return;
  }
  for (const estimator::EstimatorOutput& o : result.outputs) visit(o);
}

std::vector<PoseSample> OutputTrajectory(const ReplayResult& result) {
  std::vector<PoseSample> trajectory;
  trajectory.reserve(OutputCount(result));  // not grown by doubling: an hour is 46 MB
  ForEachOutput(result, [&](const estimator::EstimatorOutput& o) {
    if (o.valid) trajectory.push_back(PoseSample{o.t_ns, o.state.p_LI, o.state.q_LI.normalized()});
  });
  return trajectory;
}

std::vector<LocalConsistencySeries> LocalConsistency(
    const RecordedLog& log, const ReplayResult& result, estimator::ConsistencyMetric metric,
    const estimator::ConsistencyOptions& options, double rate_hz) {
  std::vector<LocalConsistencySeries> out;
  // Looks outputs up by time: the in-memory ones (`tofu estimate`'s), not a flight's spill.
  if (result.spilled != nullptr) throw std::logic_error("LocalConsistency: outputs were spilled");
  if (result.outputs.empty()) return out;
  for (const RecordedStream& stream : log.streams) {
    if (stream.kind == StreamKind::kImu) continue;
    // The stream's samples, in time order of validity.
    std::vector<core::Time> t;
    std::vector<Eigen::Vector3d> p_A;
    std::vector<Eigen::Quaterniond> q_As;
    for (const core::StampedMeasurement& m : log.measurements) {
      if (m.sensor != stream.name) continue;
      if (const auto* pose = std::get_if<core::PoseMeasurement>(&m.value)) {
        t.push_back(m.t_ns);
        p_A.push_back(pose->p_Ss);
        q_As.push_back(pose->q_Ss);
      } else if (const auto* position = std::get_if<core::PositionMeasurement>(&m.value)) {
        t.push_back(m.t_ns);
        p_A.push_back(position->p_Ss);
      }
    }
    std::vector<std::size_t> order(t.size());
    std::iota(order.begin(), order.end(), 0);
    std::stable_sort(order.begin(), order.end(), [&](auto a, auto b) { return t[a] < t[b]; });
    std::vector<core::Time> t_sorted;
    std::vector<Eigen::Vector3d> p_sorted;
    std::vector<Eigen::Quaterniond> q_sorted;
    for (std::size_t k : order) {
      t_sorted.push_back(t[k]);
      p_sorted.push_back(p_A[k]);
      if (!q_As.empty()) q_sorted.push_back(q_As[k]);
    }
    // The fit needs neighbours on both sides of every sample: a half window of at least
    // 1.5 sample periods (estimator/velocity.h), e.g. 150 ms for a 10 Hz visual stream.
    estimator::DifferentiationOptions diff;
    if (t_sorted.size() >= 3) {
      std::vector<core::Time> spacing;
      for (std::size_t k = 1; k < t_sorted.size(); ++k) spacing.push_back(t_sorted[k] - t_sorted[k - 1]);
      std::nth_element(spacing.begin(), spacing.begin() + spacing.size() / 2, spacing.end());
      const core::Time period_ns = spacing[spacing.size() / 2];
      diff.half_window_ns = std::max(diff.half_window_ns, period_ns * 3 / 2 + period_ns / 10);
      diff.max_gap_ns = std::max(diff.max_gap_ns, 3 * period_ns);
    }
    const estimator::VelocitySeries v_A = estimator::DifferentiatePositions(t_sorted, p_sorted, diff);

    // Local estimate at the mount, in s, at the output times.
    estimator::VelocitySeries local;
    const Eigen::Matrix3d R_Is = stream.T_Is.linear();
    const Eigen::Vector3d p_Is = stream.T_Is.translation();
    for (const estimator::EstimatorOutput& o : result.outputs) {
      if (!o.valid) continue;
      const Eigen::Matrix3d R_LI = o.state.q_LI.toRotationMatrix();
      local.t_ns.push_back(o.t_ns);
      local.v_mps.push_back(R_Is.transpose() *
                            (R_LI.transpose() * o.state.v_L_mps + o.omega_I_radps.cross(p_Is)));
    }
    if (local.t_ns.size() < 2) continue;

    // The sensor's velocity in s: rotated by its own attitude (pose streams), or by the
    // local attitude and the final alignment (position streams).
    estimator::VelocitySeries sensor;
    const auto alignment = result.alignment.find(stream.name);
    for (std::size_t k = 0; k < v_A.t_ns.size(); ++k) {
      const core::Time tk = v_A.t_ns[k];
      Eigen::Matrix3d R_As;
      if (!q_sorted.empty()) {
        const auto it = std::lower_bound(t_sorted.begin(), t_sorted.end(), tk);
        R_As = q_sorted[static_cast<std::size_t>(it - t_sorted.begin())].normalized().toRotationMatrix();
      } else {
        if (alignment == result.alignment.end() || !alignment->second.valid) break;
        const auto it = std::lower_bound(local.t_ns.begin(), local.t_ns.end(), tk);
        if (it == local.t_ns.end()) break;
        const estimator::EstimatorOutput* o = nullptr;
        for (const estimator::EstimatorOutput& out_k : result.outputs) {
          if (out_k.valid && out_k.t_ns == *it) { o = &out_k; break; }
        }
        if (o == nullptr) continue;
        R_As = alignment->second.T_AL.linear() * o->state.q_LI.toRotationMatrix() * R_Is;
      }
      sensor.t_ns.push_back(tk);
      sensor.v_mps.push_back(R_As.transpose() * v_A.v_mps[k]);
    }
    if (sensor.t_ns.size() < 2) continue;

    LocalConsistencySeries series;
    series.sensor = stream.name;
    const core::Time period = core::PeriodFromRate(rate_hz);
    const core::Time t0 = std::max(sensor.t_ns.front(), local.t_ns.front()) + options.window_ns;
    const core::Time t1 = std::min(sensor.t_ns.back(), local.t_ns.back());
    for (core::Time te = t0; te <= t1; te += period) {
      series.t_ns.push_back(te);
      series.value.push_back(estimator::WindowConsistency(sensor, local, te, metric, options));
    }
    out.push_back(std::move(series));
  }
  return out;
}

namespace {

// How and when the local graph started, and, with ground truth, how wrong its gravity
// direction was.
nlohmann::ordered_json InitialisationJson(const ReplayResult& result, const MethodScores& scores) {
  nlohmann::ordered_json list = nlohmann::ordered_json::array();
  for (std::size_t i = 0; i < result.initialisations.size(); ++i) {
    const estimator::InitialisationRecord& r = result.initialisations[i];
    nlohmann::ordered_json e;
    e["t_ns"] = r.t_ns;
    if (result.first_measurement_ns) {
      e["after_first_sample_s"] = core::TimeToSeconds(r.t_ns - *result.first_measurement_ns);
    }
    e["method"] = estimator::InitialisationMethodName(r.method);
    e["sensor"] = r.sensor;
    e["after_imu_gap"] = r.after_imu_gap;
    if (r.method == estimator::InitialisationRecord::Method::kVisualInertial) {
      e["window_s"] = r.window_s;
      e["gravity_direction_std_deg"] = core::DegFromRad(r.gravity_direction_std_rad);
      e["relative_position_std_m"] = r.relative_position_std_m;
      e["relative_rotation_std_deg"] = core::DegFromRad(r.relative_rotation_std_rad);
    }
    if (const std::optional<double>& error_deg = scores.initialisation_tilt_error_deg[i]) {
      e["gravity_direction_error_deg"] = *error_deg;
    }
    list.push_back(e);
  }
  return list;
}

nlohmann::ordered_json TiltErrorJson(const TiltError& tilt) {
  return {{"rms_deg", tilt.rms_deg}, {"max_deg", tilt.max_deg}, {"final_deg", tilt.final_deg}};
}

nlohmann::ordered_json BiasErrorJson(const BiasError& bias) {
  const auto vec = [](const Eigen::Vector3d& v) { return std::vector<double>{v.x(), v.y(), v.z()}; };
  return {{"gyro_rms_radps", bias.gyro_rms_radps},
          {"accel_rms_mps2", bias.accel_rms_mps2},
          {"gyro_final_radps", vec(bias.gyro_final_radps)},
          {"gyro_true_final_radps", vec(bias.gyro_true_final_radps)},
          {"accel_final_mps2", vec(bias.accel_final_mps2)},
          {"accel_true_final_mps2", vec(bias.accel_true_final_mps2)}};
}

}  // namespace

namespace {

// The ATE block of estimate_<method>.json and of a raw stream's JSON.
nlohmann::ordered_json AteJson(const TrajectoryErrors& errors) {
  return {{"alignment", "se3"},
          {"matched", errors.matched},
          {"position_rmse_m", errors.ate_position_rmse_m},
          {"position_max_m", errors.ate_position_max_m},
          {"rotation_rmse_deg", errors.rotation_rmse_deg},
          {"rpe_delta_s", errors.rpe_delta_s},
          {"rpe_translation_rmse_m", errors.rpe_translation_rmse_m},
          {"rpe_rotation_rmse_deg", errors.rpe_rotation_rmse_deg}};
}

nlohmann::ordered_json PoseJson(const Eigen::Isometry3d& T, const char* p_key, const char* q_key) {
  const Eigen::Quaterniond q(T.linear());
  const Eigen::Vector3d p = T.translation();
  return {{p_key, {p.x(), p.y(), p.z()}}, {q_key, {q.w(), q.x(), q.y(), q.z()}}};
}

// What the estimator did with its input: per-stream counters, the solver's, the frame
// alignments (and the T_AL each sensor was fused with at the end: known, frozen at fusion
// start, or the alignment graph's usable estimate).
void AddEstimatorState(const ReplayResult& result, nlohmann::ordered_json& j) {
  nlohmann::ordered_json streams;
  for (const auto& [name, c] : result.counters.streams) {
    streams[name] = {{"accepted", c.accepted},
                     {"rejected_non_finite", c.rejected_non_finite},
                     {"rejected_out_of_order", c.rejected_out_of_order},
                     {"rejected_duplicate", c.rejected_duplicate},
                     {"rejected_time_out_of_range", c.rejected_time_out_of_range},
                     {"not_fused_unaligned", c.not_fused_unaligned}};
  }
  j["streams"] = streams;
  j["solver"] = {{"solves", result.solver.solves},
                 {"iterations", result.solver.iterations},
                 {"keyframes", result.solver.keyframes},
                 {"late_keyframes", result.solver.late_keyframes},
                 {"too_old_measurements", result.solver.too_old_measurements},
                 {"iteration_cap_hits", result.solver.iteration_cap_hits},
                 {"time_cap_hits", result.solver.time_cap_hits},
                 {"bad_solves", result.solver.bad_solves},
                 {"marginalisation_failures", result.solver.marginalisation_failures},
                 {"reinitialisations", result.counters.reinitialisations},
                 {"restarts_after_gap", result.counters.restarts_after_gap}};
  nlohmann::ordered_json alignment;
  for (const auto& [name, a] : result.alignment) {
    nlohmann::ordered_json entry = {{"valid", a.valid}};
    entry.update(PoseJson(a.T_AL, "p_AL_m", "q_AL_wxyz"));
    entry.update(nlohmann::ordered_json{{"observable_rotation_dofs", a.observable_rotation_dofs},
                                        {"yaw_observable", a.yaw_observable},
                                        {"rms_residual_m", a.rms_residual_m},
                                        {"pairs", a.pairs}});
    alignment[name] = entry;
  }
  j["alignment"] = alignment;
  nlohmann::ordered_json used;
  for (const auto& [name, T_AL] : result.T_AL_used) used[name] = PoseJson(T_AL, "p_AL_m", "q_AL_wxyz");
  j["T_AL_used"] = used;
}

// A client method: its name, its failure, and its own report (a JSON object; one that is
// not stays out).
void AddClient(const ReplayResult& result, nlohmann::ordered_json& j) {
  j["client"] = result.method.client->Name();
  if (result.failure) {
    j["failure"] = *result.failure;
    j["failure_stderr_tail"] = result.failure_stderr_tail;
  }
  const auto report = nlohmann::ordered_json::parse(result.client_report_json, nullptr, false);
  if (!report.is_discarded() && report.is_object() && !report.empty()) {
    j["client_report"] = report;
  }
}

// timing_<stem>.json: the wall clock, and whether the method could run on the robot (each
// local update, one per keyframe, within the keyframe period; keeping up with its input).
MethodFiles WriteTimingJson(const ReplayResult& result, const std::filesystem::path& file) {
  MethodFiles files;
  const std::vector<double>& solve_s = result.solver.solve_time_s;
  files.solve_mean_ms =
      solve_s.empty() ? 0.0
                      : 1e3 * std::accumulate(solve_s.begin(), solve_s.end(), 0.0) / solve_s.size();
  files.solve_p99_ms = 1e3 * Percentile(solve_s, 0.99);
  nlohmann::ordered_json timing = {
      {"wall_time_s", result.wall_time_s},
      {"real_time_factor", result.wall_time_s > 0 ? result.log_duration_s / result.wall_time_s : 0.0},
      {"solve_mean_ms", files.solve_mean_ms},
      {"solve_p50_ms", 1e3 * Percentile(solve_s, 0.5)},
      {"solve_p99_ms", files.solve_p99_ms}};
  files.update_budget_ms = 1e3 * core::TimeToSeconds(result.keyframe_period_ns);
  timing["realtime_budget"] = {
      {"update_budget_ms", files.update_budget_ms},
      {"update_p99_within_budget",
       files.update_budget_ms > 0 && files.solve_p99_ms <= files.update_budget_ms},
      {"keeps_up_with_input", result.wall_time_s < result.log_duration_s},
      {"note", "wall-clock on the machine that ran it: the update's p99 against the keyframe "
               "period (one local update per keyframe), and total time against data time"}};
  WriteFileAtomically(file, timing.dump(2) + "\n");
  return files;
}

}  // namespace

MethodFiles WriteMethodResult(const RecordedLog& log, const ReplayResult& result,
                              const MethodScores& scores, const std::filesystem::path& out_dir) {
  const std::string stem = "estimate_" + SafeFileName(result.method.name);
  WriteEstimateCsv(out_dir / (stem + ".csv"), result);
  const std::vector<PoseSample>& trajectory = scores.trajectory;
  WriteTumTrajectory(out_dir / (stem + ".tum"), trajectory);

  nlohmann::ordered_json j;
  j["method"] = result.method.name;
  j["fused"] = result.method.fused;
  j["outputs"] = OutputCount(result);
  j["valid_outputs"] = trajectory.size();
  if (const std::optional<TrajectoryErrors>& errors = scores.errors) {
    WriteErrorsCsv(out_dir / (stem + "_errors.csv"), *errors, trajectory, log.ground_truth);
    j["ate"] = AteJson(*errors);
    // The alignment of L to W, so that renders can place the estimate in the world.
    j["T_WL"] = PoseJson(errors->T_WL, "p_m", "q_wxyz");
  }
  AddEstimatorState(result, j);
  j["initialisation"] = InitialisationJson(result, scores);
  nlohmann::ordered_json noise = nlohmann::ordered_json::object();
  for (const auto& [name, n] : result.stream_noise) {
    noise[name] = {{"between_position_std_m", n.between_position_std_m},
                   {"between_rotation_std_deg", core::DegFromRad(n.between_rotation_std_rad)},
                   {"source", n.source}};
  }
  j["stream_noise"] = noise;
  j["imu_gaps"] = {{"count", result.counters.imu_gaps},
                   {"total_s", result.counters.imu_gap_total_s},
                   {"restarts_after_gap", result.counters.restarts_after_gap}};
  if (scores.tilt) j["tilt_error"] = TiltErrorJson(*scores.tilt);
  if (scores.bias) j["bias_error"] = BiasErrorJson(*scores.bias);
  if (const std::optional<InputCheck>& c = scores.input_check) {
    j["input_check"] = {{"input", c->input},
                        {"input_ate_m", c->input_ate_m},
                        {"input_rotation_rmse_deg", c->input_rotation_deg},
                        {"ate_m", c->ate_m},
                        {"rotation_rmse_deg", c->rotation_deg},
                        {"worse_than_input", c->worse_in_position || c->worse_in_rotation}};
  }
  if (result.method.client) AddClient(result, j);
  WriteFileAtomically(out_dir / (stem + ".json"), j.dump(2) + "\n");
  return WriteTimingJson(result, out_dir / ("timing_" + stem + ".json"));
}

namespace {

// `--method` as given, or by default each non-IMU stream alone.
std::vector<ReplayMethod> MethodsToReplay(const EstimateCommandOptions& options,
                                          const RecordedLog& log,
                                          const std::vector<ClientSpec>& clients) {
  std::vector<ReplayMethod> methods;
  if (options.methods.empty()) {
    for (const RecordedStream& s : log.streams) {
      if (s.kind != StreamKind::kImu) methods.push_back(ParseReplayMethod("single:" + s.name, log));
    }
  } else {
    for (const std::string& m : options.methods) methods.push_back(ParseReplayMethod(m, log, clients));
  }
  return methods;
}

// A tofu run directory says how its methods were configured (its scenario's
// estimation: block): the same configuration reproduces what ran in the flight.
EstimationConfig RunEstimationConfig(const EstimateCommandOptions& options) {
  EstimationConfig run_config;
  if (const std::filesystem::path scenario = options.log_dir / "scenario.yaml";
      options.read_estimation_config && std::filesystem::is_regular_file(scenario)) {
    if (const std::optional<EstimationConfig> config = options.read_estimation_config(scenario)) {
      run_config = *config;
      run_config.methods.clear();
      if (!options.quiet) {
        fmt::print("note: estimator configured from {} (estimation: consensus, huber_delta)\n",
                   scenario.string());
      }
    }
  }
  return run_config;
}

estimator::MultiGraphEstimatorOptions WithEstimatorOverrides(
    estimator::MultiGraphEstimatorOptions estimator_options, const EstimateCommandOptions& options) {
  if (options.window_s) estimator_options.local.window_ns = core::SecondsToTime(*options.window_s);
  if (options.keyframe_rate_hz) estimator_options.local.keyframe_rate_hz = *options.keyframe_rate_hz;
  if (options.huber_delta) estimator_options.local.huber_delta = *options.huber_delta;
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
    const TrajectoryErrors& errors = raw.errors;
    const std::string stem = "estimate_raw_" + SafeFileName(raw.stream);
    WriteErrorsCsv(out_dir / (stem + "_errors.csv"), errors, raw.trajectory, log.ground_truth);
    nlohmann::ordered_json j;
    j["method"] = "raw:" + raw.stream;
    j["ate"] = AteJson(errors);
    WriteFileAtomically(out_dir / (stem + ".json"), j.dump(2) + "\n");
    if (!quiet) {
      fmt::print("{:<28} {:>9.4f} {:>9.3f} {:>9.4f}   (the stream alone, same span)\n",
                 "raw:" + raw.stream, errors.ate_position_rmse_m, errors.rotation_rmse_deg,
                 errors.rpe_translation_rmse_m);
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
  std::string decisions_csv = kDecisionsCsvHeader;
  estimator::ConsensusEstimatorOptions consensus_options = setup.consensus;
  if (options.consensus_threshold) consensus_options.selection.threshold = *options.consensus_threshold;
  RequireValidOptions(estimator_options, consensus_options,
                      {"tofu estimate (--window, --keyframe-rate, --huber, --imu-noise-scale, "
                       "--consensus-threshold)"},
                      "");
  const std::filesystem::path out_dir = options.out_dir.value_or(options.log_dir);
  std::filesystem::create_directories(out_dir);
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
  for (const ReplayMethod& method : methods) {
    std::function<void(double)> progress;
    if (options.progress) progress = [&](double f) { options.progress(method.name, f); };
    const ReplayResult result = Replay(log_for(method), method, estimator_options, specs,
                                       progress, consensus_options, texts);
    const RecordedLog& method_log = log_for(method);
    scoring.labels = &method_log.labels;
    const MethodScores scores = ScoreMethod(method_log, result, scoring);
    const MethodFiles files = WriteMethodResult(method_log, result, scores, out_dir);
    if (result.failure) {
      PrintClientFailure(result);
      failed_client = true;
    }
    if (method.kind == ReplayMethod::Kind::kConsensus) {
      decisions_csv += DecisionRows(result);
      WriteFileAtomically(out_dir / ("consistency_" + MethodFileStem(method.name) + ".csv"),
                          ConsistencyMatrixCsv(result));
    }
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
  if (decisions_csv != kDecisionsCsvHeader) WriteFileAtomically(out_dir / "decisions.csv", decisions_csv);
  WriteRawStreamBaselines(log, first_output_ns, last_output_ns, out_dir, options.quiet);
  if (failed_client) return core::kExitSimulationError;
  return failed ? 1 : 0;
}

std::string ClientFailureText(const ReplayResult& result) {
  if (!result.failure) return {};
  std::string text = *result.failure;
  if (!result.failure_stderr_tail.empty()) {
    text += fmt::format("\n  last lines of {}'s standard error:", result.method.name);
    for (const std::string& line : result.failure_stderr_tail) text += "\n    " + line;
  }
  return text;
}

std::optional<std::string> NothingToFuse(const ReplayResult& result,
                                         const std::string& imu_stream) {
  // The sensors the method would fuse: its list, or for consensus every non-IMU stream.
  std::vector<std::string> candidates = result.method.fused;
  if (result.method.kind == ReplayMethod::Kind::kConsensus) {
    candidates.clear();
    for (const auto& [name, c] : result.counters.streams) {
      if (name != imu_stream) candidates.push_back(name);
    }
  }
  if (candidates.empty()) return std::nullopt;  // imu_only fuses nothing by design
  std::string rejected;
  for (const std::string& name : candidates) {
    const auto it = result.counters.streams.find(name);
    if (it == result.counters.streams.end()) continue;
    const estimator::StreamGateCounters& c = it->second;
    if (c.accepted > 0) return std::nullopt;
    rejected += fmt::format("{}{}: {} non-finite, {} out of order, {} duplicate, {} out of range",
                            rejected.empty() ? "" : "; ", name, c.rejected_non_finite,
                            c.rejected_out_of_order, c.rejected_duplicate,
                            c.rejected_time_out_of_range);
  }
  return fmt::format("method {}: no sample of any sensor it would fuse was accepted ({})",
                     result.method.name, rejected);
}

std::vector<PoseSample> RawPoseTrajectory(const RecordedLog& log, const RecordedStream& stream,
                                          core::Time from_ns, core::Time to_ns) {
  std::vector<PoseSample> raw;
  const Eigen::Isometry3d T_sI = stream.T_Is.inverse();
  for (const core::StampedMeasurement& m : log.measurements) {
    if (m.sensor != stream.name || m.t_ns < from_ns || m.t_ns > to_ns) continue;
    const auto* pose = std::get_if<core::PoseMeasurement>(&m.value);
    if (pose == nullptr || !pose->p_Ss.allFinite() || !pose->q_Ss.coeffs().allFinite()) continue;
    Eigen::Isometry3d T_As = Eigen::Isometry3d::Identity();
    T_As.linear() = pose->q_Ss.normalized().toRotationMatrix();
    T_As.translation() = pose->p_Ss;
    const Eigen::Isometry3d T_AI = T_As * T_sI;
    raw.push_back({m.t_ns, T_AI.translation(), Eigen::Quaterniond(T_AI.linear())});
  }
  std::stable_sort(raw.begin(), raw.end(),
                   [](const PoseSample& a, const PoseSample& b) { return a.t_ns < b.t_ns; });
  return raw;
}

}  // namespace tofu::replay
