// MCAP export speed (`tofu export`, report/mcap_export.cc): wall and CPU time to write a
// 120 s run directory as one MCAP file, zstd-compressed and stored. Results go to
// docs/BENCHMARKS.md ("MCAP export"); the goal is under 2 s on one core.
//
//   taskset -c 1 build/bench/bench_export --benchmark_repetitions=3
//
// The run: $TOFU_BENCH_RUN_DIR if set (any tofu run directory), else
// scenarios/paper_consensus_indoor.yaml flown here once (120 s, four estimation methods,
// consensus decisions and consistency values: every topic but the closed-loop ones).

#include <unistd.h>

#include <cstdlib>
#include <filesystem>

#include <benchmark/benchmark.h>
#include <fmt/format.h>

#include "harness/run.h"
#include "harness/run_directory.h"
#include "harness/scenario.h"
#include "report/mcap_export.h"

namespace {

namespace fs = std::filesystem;

const fs::path& RunDir() {
  static const fs::path dir = [] {
    if (const char* env = std::getenv("TOFU_BENCH_RUN_DIR")) return fs::path(env);
    const fs::path out = fs::temp_directory_path() / fmt::format("tofu_bench_export_{}", ::getpid());
    const tofu::harness::Scenario scenario =
        tofu::harness::LoadScenario(TOFU_SOURCE_DIR "/scenarios/paper_consensus_indoor.yaml");
    tofu::harness::RunRecord record = tofu::harness::Simulate(scenario, {});
    tofu::harness::WriteRun(record, out.string(), {});
    return out;
  }();
  return dir;
}

void Export(benchmark::State& state, tofu::report::McapCompression compression) {
  const fs::path run = RunDir();
  const fs::path mcap = fs::temp_directory_path() / fmt::format("tofu_bench_export_{}.mcap", ::getpid());
  tofu::report::McapExportOptions options;
  options.compression = compression;
  tofu::report::McapExportResult result;
  for (auto _ : state) result = tofu::report::ExportRunToMcap(run, mcap, options);
  std::uintmax_t csv_bytes = 0;
  for (const auto& entry : fs::recursive_directory_iterator(run)) {
    if (entry.is_regular_file() && entry.path().extension() == ".csv") csv_bytes += entry.file_size();
  }
  state.counters["messages"] = static_cast<double>(result.messages);
  state.counters["mcap_MB"] = static_cast<double>(result.bytes) / 1e6;
  state.counters["csv_MB"] = static_cast<double>(csv_bytes) / 1e6;
  state.counters["msg_per_s"] =
      benchmark::Counter(static_cast<double>(result.messages), benchmark::Counter::kIsIterationInvariantRate);
  fs::remove(mcap);
}

void BM_ExportZstd(benchmark::State& state) { Export(state, tofu::report::McapCompression::kZstd); }
void BM_ExportStored(benchmark::State& state) { Export(state, tofu::report::McapCompression::kNone); }

BENCHMARK(BM_ExportZstd)->Unit(benchmark::kMillisecond)->Iterations(3);
BENCHMARK(BM_ExportStored)->Unit(benchmark::kMillisecond)->Iterations(3);

}  // namespace

BENCHMARK_MAIN();
