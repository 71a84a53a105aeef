#include "replay/method_runner.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <stdexcept>

#include <fmt/format.h>

#include "interface/client.h"
#include "replay/api_convert.h"
#include "replay/builtin_estimator.h"
#include "replay/run_calibration.h"

namespace tofu::replay {

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

  // The estimates collected in `estimates` into the result (checked for a client). Those
  // of the call in which a client failed are kept too: tofu reads a client's answers in
  // order and fails it only once none is left before the failing one (its exit, its
  // malformed message, its timeout), so what it answered before failing is the same on
  // every run, however far tofu's pipelining had got.
  void Record() {
    for (api::Estimate& e : estimates) {
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
    if (s.kind != core::MeasurementKind::kImu) m.sensor_names.push_back(s.name);
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

std::string ClientFailureText(const ReplayResult& result) {
  if (!result.failure) return {};
  return interface::ClientFailureWithStderr(*result.failure, result.method.name,
                                            result.failure_stderr_tail);
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

}  // namespace tofu::replay
