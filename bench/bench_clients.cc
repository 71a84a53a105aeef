// What users' estimators cost the harness (issue 33, item 7; docs/BENCHMARKS.md):
//  - BM_ReplayThroughProtocol: paper_consensus_indoor's recorded streams replayed through
//    the process protocol to a C++ client that answers at once (this binary, re-run as
//    `--serve-echo`: one estimate per IMU sample), JSON and MessagePack: the protocol's own
//    cost as a real-time factor (goal >= 200x);
//  - BM_ClosedLoopThroughClient: a 60 s closed-loop flight flown on consensus in process,
//    on the same consensus behind the protocol (tofu-estimator-host, MessagePack) and
//    behind the plug-in API (libtofu_builtin_plugin.so): what the protocol adds to the
//    flight's wall time (goal <= 10 %) and the plug-in against the same code built in
//    (goal within 5 %);
//  - BM_PythonEkfClosedLoop: the Python ESKF example flying scenarios/clients/
//    python_ekf_wall.yaml's closed-loop flight (goal >= 10x real time).
// The clients' paths: beside this binary's build directory (TOFU_BUILD_DIR).

#include <unistd.h>

#include <cstring>
#include <filesystem>
#include <map>
#include <memory>
#include <string>
#include <vector>

#include <benchmark/benchmark.h>

#include "harness/run.h"
#include "harness/run_directory.h"
#include "harness/scenario.h"
#include "interface/estimator_client.h"
#include "interface/framing.h"
#include "replay/estimation_config.h"
#include "replay/recorded_log.h"
#include "replay/replay.h"

namespace {

namespace fs = std::filesystem;
using tofu::harness::Scenario;

std::string g_self;  // this binary, for the echo client

// The cheapest estimator there is: the IMU sample's time, nothing computed.
class EchoEstimator final : public tofu::api::Estimator {
 public:
  void Start(const tofu::api::EstimatorSetup&) override {}
  void Add(const tofu::api::Measurement& m, std::vector<tofu::api::Estimate>* out) override {
    if (m.kind != tofu::api::SensorKind::kImu) return;
    tofu::api::Estimate e;
    e.t_ns = m.t_ns;
    e.valid = true;
    e.initialized = true;
    e.omega_I_radps = m.imu.gyro_I_radps;
    out->push_back(e);
  }
};

fs::path SourceDir() { return fs::path(TOFU_SOURCE_DIR); }
fs::path BuildDir() { return fs::path(TOFU_BUILD_DIR); }

const tofu::replay::RecordedLog& PaperLog() {
  static std::unique_ptr<tofu::replay::RecordedLog> log;
  static const fs::path dir =
      fs::temp_directory_path() / ("tofu_bench_clients_" + std::to_string(::getpid()));
  if (!log) {
    const Scenario scenario =
        tofu::harness::LoadScenario((SourceDir() / "scenarios/paper_consensus_indoor.yaml").string());
    tofu::harness::SimulateOptions options;
    Scenario flown = scenario;
    flown.estimation.reset();  // the streams only
    const tofu::harness::RunRecord record = tofu::harness::Simulate(flown, options);
    fs::remove_all(dir);
    fs::create_directories(dir.parent_path());
    tofu::harness::WriteRunDirectory(record, tofu::harness::Evaluate(record), dir.string());
    log = std::make_unique<tofu::replay::RecordedLog>(tofu::replay::ReadRecordedLog(dir));
    std::atexit([] {
      std::error_code ignored;
      fs::remove_all(dir, ignored);
    });
  }
  return *log;
}

tofu::replay::ClientSpec Process(const std::string& key, std::vector<std::string> command,
                                 const std::string& config = "{}") {
  tofu::replay::ClientSpec c;
  c.kind = tofu::replay::ClientSpec::Kind::kProcess;
  c.key = key;
  c.command = std::move(command);
  c.working_dir = fs::current_path().string();
  c.config_json = config;
  return c;
}

void BM_ReplayThroughProtocol(benchmark::State& state) {
  const bool msgpack = state.range(0) == 1;
  const tofu::replay::RecordedLog& log = PaperLog();
  const std::vector<tofu::replay::ClientSpec> clients = {
      Process("echo", {g_self, "--serve-echo", msgpack ? "msgpack" : "json"})};
  const tofu::replay::ReplayMethod method =
      tofu::replay::ParseReplayMethod("external:echo", log, clients);
  const tofu::replay::EstimationSetup setup = tofu::replay::MakeEstimationSetup(log, {});
  double log_s = 0.0;
  for (auto _ : state) {
    const tofu::replay::ReplayResult result =
        tofu::replay::Replay(log, method, setup.estimator, setup.sensors, nullptr, setup.consensus,
                             {log.calibration_yaml, "", 9.81});
    if (result.failure) {
      state.SkipWithError(result.failure->c_str());
      return;
    }
    benchmark::DoNotOptimize(result.outputs.data());
    log_s += result.log_duration_s;
  }
  state.counters["real_time_factor"] = benchmark::Counter(log_s, benchmark::Counter::kIsRate);
  state.counters["messages"] = static_cast<double>(log.measurements.size());
}
BENCHMARK(BM_ReplayThroughProtocol)->ArgName("msgpack")->Arg(0)->Arg(1)
    ->Unit(benchmark::kMillisecond)->UseRealTime()->Iterations(3);

// Flies `scenario` once per iteration; the real-time factor as a counter.
void FlyAndCount(benchmark::State& state, const Scenario& scenario,
                 const tofu::harness::SimulateOptions& options) {
  double simulated_s = 0.0;
  for (auto _ : state) {
    const tofu::harness::RunRecord record = tofu::harness::Simulate(scenario, options);
    if (record.failure) {
      state.SkipWithError(record.failure->c_str());
      return;
    }
    benchmark::DoNotOptimize(record.groundtruth.data());
    simulated_s += static_cast<double>(record.physics_steps) / scenario.physics.rate_hz;
  }
  state.counters["real_time_factor"] = benchmark::Counter(simulated_s, benchmark::Counter::kIsRate);
}

// 60 s of the paper's sensors and its VIO divergence, flown on `method`.
void BM_ClosedLoopThroughClient(benchmark::State& state) {
  static const char* kMethods[] = {"consensus", "external:host", "plugin:builtin"};
  const std::string method = kMethods[state.range(0)];
  Scenario scenario =
      tofu::harness::LoadScenario((SourceDir() / "scenarios/closed_loop_vio_divergence_wall.yaml").string());
  tofu::replay::ClientSpec plugin;
  plugin.kind = tofu::replay::ClientSpec::Kind::kPlugin;
  plugin.key = "builtin";
  plugin.library = (BuildDir() / "libtofu_builtin_plugin.so").string();
  plugin.config_json = R"({"method": "consensus"})";
  scenario.clients = {Process("host", {(BuildDir() / "tofu-estimator-host").string(), "--encoding",
                                       "msgpack"},
                              R"({"method": "consensus"})"),
                      plugin};
  scenario.estimation->clients = scenario.clients;
  scenario.estimation->methods = {"consensus", "external:host", "plugin:builtin"};
  tofu::harness::SimulateOptions options;
  options.fly_on = method;
  FlyAndCount(state, scenario, options);
}
BENCHMARK(BM_ClosedLoopThroughClient)->ArgName("consensus_host_plugin")->Arg(0)->Arg(1)->Arg(2)
    ->Unit(benchmark::kMillisecond)->UseRealTime()->Iterations(1)->Repetitions(3);

void BM_PythonEkfClosedLoop(benchmark::State& state) {
  const Scenario scenario = tofu::harness::LoadScenario(
      (SourceDir() / "scenarios/clients/python_ekf_wall.yaml").string());
  tofu::harness::SimulateOptions options;
  options.fly_on = "external:python_ekf";
  FlyAndCount(state, scenario, options);
}
BENCHMARK(BM_PythonEkfClosedLoop)->Unit(benchmark::kMillisecond)->UseRealTime()->Iterations(1)
    ->Repetitions(3);

}  // namespace

int main(int argc, char** argv) {
  g_self = fs::absolute(argv[0]).string();
  if (argc == 3 && std::strcmp(argv[1], "--serve-echo") == 0) {
    EchoEstimator echo;
    return tofu::interface::ServeEstimator(echo, STDIN_FILENO, STDOUT_FILENO,
                                           std::strcmp(argv[2], "msgpack") == 0
                                               ? tofu::interface::Encoding::kMsgpack
                                               : tofu::interface::Encoding::kJson);
  }
  benchmark::Initialize(&argc, argv);
  if (benchmark::ReportUnrecognizedArguments(argc, argv)) return 1;
  benchmark::RunSpecifiedBenchmarks();
  benchmark::Shutdown();
  return 0;
}
