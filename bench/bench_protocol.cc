// Cost of the process protocol (docs/INTERFACE.md) per message, both encodings: tofu's
// side (encode a measurement, decode the estimates), a C++ client's side (decode the
// measurement, encode its estimates), nlohmann::json's value-building path for comparison,
// the four together in-process, and the whole trip through a real client process (this
// binary re-run as `--serve-estimator json|msgpack`, a trivial estimator behind
// interface::ServeEstimator).
//
// The goal: 120 s of streams (~50k messages) replayed at >= 200x real time through a
// trivial C++ client, i.e. about 12 us of wall time per message for everything, so the
// protocol's share must stay well under 10 us.
//
//   build/bench/bench_protocol [--benchmark_filter=Process]

#include <unistd.h>

#include <benchmark/benchmark.h>

#include <filesystem>
#include <string>
#include <string_view>
#include <vector>

#include <nlohmann/json.hpp>

#include "interface/client.h"
#include "interface/estimator_client.h"
#include "interface/framing.h"
#include "interface/protocol.h"

namespace {

using namespace tofu;
using interface::Encoding;

api::EstimatorSetup BenchSetup() {
  api::EstimatorSetup setup;
  setup.method = "external:bench";
  api::SensorInfo imu;
  imu.name = "imu";
  api::SensorInfo vio;
  vio.name = "vio";
  vio.kind = api::SensorKind::kPose;
  api::SensorInfo leica;
  leica.name = "leica";
  leica.kind = api::SensorKind::kPosition;
  setup.sensors = {imu, vio, leica};
  return setup;
}

// An IMU sample with the digits a simulated one has.
api::Measurement Imu(std::int64_t i) {
  api::Measurement m;
  m.t_ns = 1'000'000'000 + i * 2'500'000;
  m.arrival_ns = m.t_ns;
  m.imu.acc_I_mps2 = {0.012345678901234 + 1e-9 * static_cast<double>(i), -0.0234567890123, 9.8123456789};
  m.imu.gyro_I_radps = {0.00123456789012, -0.000234567890123, 0.0345678901234};
  return m;
}

// The run's mix: 18 IMU samples, one VIO pose with twist and covariances, one position.
api::Measurement StreamSample(std::int64_t i) {
  api::Measurement m = Imu(i);
  if (i % 20 == 7) {
    m.sensor = 1;
    m.kind = api::SensorKind::kPose;
    m.pose.T_Ss = {{1.23456789, -0.3456789, 2.0123456}, {0.99, 0.01, -0.02, 0.1}};
    for (std::size_t k = 0; k < 36; ++k) m.pose.covariance[k] = k % 7 == 0 ? 1e-4 : 1.234e-7;
    m.pose.has_twist = true;
    m.pose.v_s_mps = {0.5, -0.25, 0.125};
    m.pose.twist_covariance = m.pose.covariance;
  } else if (i % 20 == 13) {
    m.sensor = 2;
    m.kind = api::SensorKind::kPosition;
    m.position.p_Ss_m = {10.123456, -3.456789, 1.234567};
    m.position.covariance_m2 = {1e-6, 0, 0, 0, 1e-6, 0, 0, 0, 4e-6};
  }
  return m;
}

api::Estimate BenchEstimate(std::int64_t t_ns) {
  api::Estimate e;
  e.t_ns = t_ns;
  e.valid = e.initialized = true;
  e.T_LI = {{1.2345678901234, -2.345678901234, 0.98765432109876},
            {0.99875234, 0.0123456789, -0.0456789012, 0.0123456}};
  e.v_L_mps = {0.123456789, -0.0234567891, 0.00345678912};
  e.omega_I_radps = {0.00123456789012, -0.000234567890123, 0.0345678901234};
  e.bias_acc_mps2 = {0.01, -0.02, 0.03};
  e.bias_gyro_radps = {1e-4, -2e-4, 3e-4};
  e.position_covariance_m2 = api::Mat3{1e-4, 1e-6, 0, 1e-6, 1e-4, 0, 0, 0, 2e-4};
  return e;
}

// One estimate per IMU sample (as tofu's own methods answer), none for the other sensors.
class TrivialEstimator final : public api::Estimator {
 public:
  void Start(const api::EstimatorSetup&) override {}
  void Add(const api::Measurement& m, std::vector<api::Estimate>* out) override {
    if (m.kind == api::SensorKind::kImu) out->push_back(BenchEstimate(m.t_ns));
  }
};

Encoding EncodingOf(const benchmark::State& state) {
  return state.range(0) == 0 ? Encoding::kJson : Encoding::kMsgpack;
}

void Label(benchmark::State& state, std::size_t bytes) {
  state.SetLabel(std::string(interface::EncodingName(EncodingOf(state))) + ", " +
                 std::to_string(bytes) + " B");
  state.SetItemsProcessed(state.iterations());
}

// ---- tofu's side ----

void BM_EncodeMeasurement(benchmark::State& state) {
  const api::EstimatorSetup setup = BenchSetup();
  const api::Measurement m = Imu(12345);
  std::string out;
  for (auto _ : state) {
    out.clear();
    interface::AppendMeasurementFrame(12345, setup, m, EncodingOf(state), &out);
    benchmark::DoNotOptimize(out.data());
  }
  Label(state, out.size());
}
BENCHMARK(BM_EncodeMeasurement)->Arg(0)->Arg(1);

void BM_EncodeMeasurementViaNlohmannJson(benchmark::State& state) {
  const api::EstimatorSetup setup = BenchSetup();
  const api::Measurement m = Imu(12345);
  std::string out;
  for (auto _ : state) {
    out.clear();
    interface::AppendFrame(interface::MeasurementMessage(12345, setup, m), EncodingOf(state), &out);
    benchmark::DoNotOptimize(out.data());
  }
  Label(state, out.size());
}
BENCHMARK(BM_EncodeMeasurementViaNlohmannJson)->Arg(0)->Arg(1);

std::string EstimatesFrame(Encoding encoding) {
  const api::Estimate e = BenchEstimate(1'030'862'500);
  std::string frame;
  interface::AppendEstimatesFrame(12345, &e, 1, encoding, &frame);
  return frame;
}

void BM_DecodeEstimates(benchmark::State& state) {
  const std::string frame = EstimatesFrame(EncodingOf(state));
  interface::FrameReader reader(EncodingOf(state));
  std::vector<api::Estimate> estimates;
  for (auto _ : state) {
    reader.Feed(frame);
    estimates.clear();
    interface::DecodeEstimates(*reader.Next(), 12345, &estimates);
    benchmark::DoNotOptimize(estimates.data());
  }
  Label(state, frame.size());
}
BENCHMARK(BM_DecodeEstimates)->Arg(0)->Arg(1);

// ---- the client's side ----

void BM_DecodeMeasurement(benchmark::State& state) {
  const api::EstimatorSetup setup = BenchSetup();
  std::string frame;
  interface::AppendMeasurementFrame(12345, setup, Imu(12345), EncodingOf(state), &frame);
  interface::FrameReader reader(EncodingOf(state));
  for (auto _ : state) {
    reader.Feed(frame);
    std::int64_t seq = 0;
    const api::Measurement m = interface::DecodeMeasurement(*reader.Next(), setup, &seq);
    benchmark::DoNotOptimize(m.imu.acc_I_mps2.data());
  }
  Label(state, frame.size());
}
BENCHMARK(BM_DecodeMeasurement)->Arg(0)->Arg(1);

void BM_EncodeEstimates(benchmark::State& state) {
  const api::Estimate e = BenchEstimate(1'030'862'500);
  std::string out;
  for (auto _ : state) {
    out.clear();
    interface::AppendEstimatesFrame(12345, &e, 1, EncodingOf(state), &out);
    benchmark::DoNotOptimize(out.data());
  }
  Label(state, out.size());
}
BENCHMARK(BM_EncodeEstimates)->Arg(0)->Arg(1);

void BM_EncodeEstimatesViaNlohmannJson(benchmark::State& state) {
  const std::vector<api::Estimate> estimates = {BenchEstimate(1'030'862'500)};
  std::string out;
  for (auto _ : state) {
    out.clear();
    interface::AppendFrame(interface::EstimatesMessage(12345, estimates), EncodingOf(state), &out);
    benchmark::DoNotOptimize(out.data());
  }
  Label(state, out.size());
}
BENCHMARK(BM_EncodeEstimatesViaNlohmannJson)->Arg(0)->Arg(1);

// ---- all four, in one process: the protocol's cost without pipes or scheduling ----

void BM_RoundTripInProcess(benchmark::State& state) {
  const Encoding encoding = EncodingOf(state);
  const api::EstimatorSetup setup = BenchSetup();
  TrivialEstimator estimator;
  interface::FrameReader client_reader(encoding);
  interface::FrameReader tofu_reader(encoding);
  std::string to_client;
  std::string to_tofu;
  std::vector<api::Estimate> made;
  std::vector<api::Estimate> received;
  std::int64_t i = 0;
  for (auto _ : state) {
    to_client.clear();
    interface::AppendMeasurementFrame(i, setup, StreamSample(i), encoding, &to_client);
    client_reader.Feed(to_client);
    std::int64_t seq = 0;
    const api::Measurement m = interface::DecodeMeasurement(*client_reader.Next(), setup, &seq);
    made.clear();
    estimator.Add(m, &made);
    to_tofu.clear();
    interface::AppendEstimatesFrame(seq, made.data(), made.size(), encoding, &to_tofu);
    tofu_reader.Feed(to_tofu);
    received.clear();
    interface::DecodeEstimates(*tofu_reader.Next(), i, &received);
    benchmark::DoNotOptimize(received.data());
    ++i;
  }
  state.SetLabel(interface::EncodingName(encoding));
  state.SetItemsProcessed(state.iterations());
}
BENCHMARK(BM_RoundTripInProcess)->Arg(0)->Arg(1);

// ---- the whole trip through a client process ----

std::string SelfPath() { return std::filesystem::read_symlink("/proc/self/exe").string(); }

// Each iteration: 5000 samples of the run's mix through ProcessEstimator (256 in flight),
// then Drain. items/s is messages per second of wall time.
void BM_ProcessClient(benchmark::State& state) {
  const Encoding encoding = EncodingOf(state);
  interface::ProcessClientConfig config;
  config.name = "external:bench";
  config.command = {SelfPath(), "--serve-estimator", interface::EncodingName(encoding)};
  interface::ProcessEstimator estimator(config);
  estimator.Start(BenchSetup());
  constexpr std::int64_t kBatch = 5000;
  std::vector<api::Measurement> stream;
  std::vector<api::Estimate> out;
  std::int64_t i = 0;
  for (auto _ : state) {
    state.PauseTiming();
    stream.clear();
    for (std::int64_t k = 0; k < kBatch; ++k, ++i) stream.push_back(StreamSample(i));
    out.clear();
    state.ResumeTiming();
    for (const api::Measurement& m : stream) estimator.Add(m, &out);
    estimator.Drain(&out);
    benchmark::DoNotOptimize(out.data());
  }
  estimator.Finish(&out);
  state.SetLabel(interface::EncodingName(encoding));
  state.SetItemsProcessed(state.iterations() * kBatch);
}
BENCHMARK(BM_ProcessClient)->Arg(0)->Arg(1)->Unit(benchmark::kMillisecond)->UseRealTime();

}  // namespace

int main(int argc, char** argv) {
  if (argc == 3 && std::string_view(argv[1]) == "--serve-estimator") {
    TrivialEstimator estimator;
    return interface::ServeEstimator(estimator, STDIN_FILENO, STDOUT_FILENO,
                                     std::string_view(argv[2]) == "msgpack" ? Encoding::kMsgpack
                                                                            : Encoding::kJson);
  }
  benchmark::Initialize(&argc, argv);
  if (benchmark::ReportUnrecognizedArguments(argc, argv)) return 1;
  benchmark::RunSpecifiedBenchmarks();
  benchmark::Shutdown();
  return 0;
}
