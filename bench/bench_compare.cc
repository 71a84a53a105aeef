// `tofu compare` on a grid of the size issue 52 names: 19 scenarios x 10 seeds with 8
// methods and every comparable metric (3 continuous per method beside the events, and 5
// expectations per scenario). Target: the whole comparison, both baseline files read,
// the verdicts, the table, the markdown and the JSON, in at most 1 s on one core.
//
//   build/bench/bench_compare --benchmark_repetitions=3
//
// BM_CompareCheckDirectories reads check directories instead, as `tofu compare A B` does:
// from a real check (TOFU_BENCH_CHECK set to a `tofu check --out` directory, e.g. the
// suite's of scripts/results.py, runs/results/suite) it makes a check directory of 19
// scenarios x 10 seeds by cycling the real scenarios' summary.json files under new names,
// and compares it with itself. Skipped without TOFU_BENCH_CHECK.

#include <unistd.h>

#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <random>
#include <string>

#include <benchmark/benchmark.h>
#include <fmt/format.h>
#include <nlohmann/json.hpp>

#include "campaign/cell_record.h"
#include "campaign/compare.h"

namespace {

namespace fs = std::filesystem;
using tofu::campaign::CampaignRecord;
using tofu::campaign::CellRecord;

constexpr int kScenarios = 19;
constexpr int kSeeds = 10;
constexpr int kMethods = 8;
constexpr int kExpectations = 5;

// A campaign with every metric filled: per method ATE, rotation RMSE, RPE, the position
// step, detection and re-admission delays, false exclusions, valid fraction and the
// method's events; per run its expectations. `drift` scales the second campaign's ATE.
CampaignRecord Campaign(double drift, uint64_t own_seed) {
  CampaignRecord c;
  c.source = fmt::format("synthetic_{}", own_seed);
  c.tofu_version = "0.1.0";
  c.tofu_commit = "bench";
  c.metric_versions = tofu::campaign::CurrentMetricVersions();
  std::mt19937_64 own(own_seed);
  std::normal_distribution<double> normal;
  for (int s = 0; s < kScenarios; ++s) {
    for (int k = 1; k <= kSeeds; ++k) {
      std::mt19937_64 world(static_cast<uint64_t>(s * 1009 + k));
      CellRecord cell;
      cell.scenario = fmt::format("scenario_{:02}", s);
      cell.seed = static_cast<uint64_t>(k);
      cell.scenario_hash = fmt::format("{:016x}", s * 7919);
      cell.exit_code = 0;
      cell.digests = {fmt::format("{:016x}", k * 104729), fmt::format("{:016x}", k * 1299709)};
      cell.events["run.failed"] = false;
      for (int m = 0; m < kMethods; ++m) {
        const std::string p = fmt::format("methods.method_{}.", m);
        const double seed_effect = 0.3 * normal(world);
        const double own_noise = 0.02 * normal(own);
        cell.values[p + "ate_m"] = 0.05 * (m == 0 ? drift : 1.0) * std::exp(seed_effect + own_noise);
        cell.values[p + "rotation_rmse_deg"] = 0.4 * std::exp(seed_effect + own_noise);
        cell.values[p + "rpe_m"] = 0.01 * std::exp(seed_effect + own_noise);
        cell.values[p + "position_step_max_m"] = 0.02 * std::exp(seed_effect + own_noise);
        cell.values[p + "max_detection_delay_s"] = 0.3 + 0.05 * std::abs(normal(world));
        cell.values[p + "max_readmission_delay_s"] = 1.5 + 0.2 * std::abs(normal(world));
        cell.values[p + "false_exclusion_fraction"] = 0.01 * std::abs(normal(world));
        cell.values[p + "valid_fraction"] = 0.99;
        for (const char* event : {"failed", "missed_fault", "never_readmitted"}) {
          cell.events[p + event] = false;
        }
      }
      for (int e = 0; e < kExpectations; ++e) {
        cell.events[fmt::format("run.expectation.methods.method_{}.ate_m", e)] = false;
      }
      c.cells.push_back(std::move(cell));
    }
  }
  return c;
}

void WriteFile(const fs::path& path, const std::string& text) {
  std::ofstream(path) << text;
}

void Compare(const CampaignRecord& base, const CampaignRecord& now, benchmark::State& state) {
  const tofu::campaign::Comparison comparison =
      tofu::campaign::CompareCampaigns(base, now, tofu::campaign::CompareOptions{});
  const std::string table = tofu::campaign::ComparisonTable(comparison);
  const std::string markdown = tofu::campaign::ComparisonMarkdown(comparison);
  const std::string json = tofu::campaign::ComparisonJson(comparison).dump(1);
  benchmark::DoNotOptimize(table.size() + markdown.size() + json.size());
  state.counters["cells"] = static_cast<double>(comparison.cells.size());
}

// Two baseline files of the grid (the second with method_0 10 % worse), read and compared.
void BM_CompareBaselines(benchmark::State& state) {
  const fs::path dir = fs::temp_directory_path() / fmt::format("bench_compare_{}", ::getpid());
  fs::create_directories(dir);
  WriteFile(dir / "base.json", tofu::campaign::BaselineJson(Campaign(1.0, 1)));
  WriteFile(dir / "new.json", tofu::campaign::BaselineJson(Campaign(1.1, 2)));
  for (auto _ : state) {
    const CampaignRecord base = tofu::campaign::ReadBaselineFile(dir / "base.json");
    const CampaignRecord now = tofu::campaign::ReadBaselineFile(dir / "new.json");
    Compare(base, now, state);
  }
  fs::remove_all(dir);
}
BENCHMARK(BM_CompareBaselines)->Unit(benchmark::kMillisecond)->UseRealTime();

// The grid's check directory made of a real check's summaries: scenario i of kScenarios
// is the real check's scenario i % (its count), seeds 1..kSeeds (cycled over its seeds).
fs::path MakeCheckDirectory(const fs::path& real) {
  const auto record = nlohmann::json::parse(std::ifstream(real / "check.json"));
  const auto& scenarios = record.at("scenarios");
  const int real_seeds = record.at("seeds").get<int>();
  const fs::path dir = fs::temp_directory_path() / fmt::format("bench_compare_check_{}", ::getpid());
  fs::remove_all(dir);
  nlohmann::json names = nlohmann::json::array(), runs = nlohmann::json::array();
  for (int s = 0; s < kScenarios; ++s) {
    const auto& source = scenarios.at(static_cast<size_t>(s) % scenarios.size());
    const std::string name = fmt::format("scenario_{:02}", s);
    names.push_back({{"name", name}, {"fnv1a64", fmt::format("{:016x}", s)}, {"first_seed", 1}});
    for (int k = 1; k <= kSeeds; ++k) {
      const int real_seed = source.at("first_seed").get<int>() + (k - 1) % real_seeds;
      const fs::path to = dir / name / fmt::format("seed_{}", k);
      fs::create_directories(to);
      fs::copy_file(real / source.at("name").get<std::string>() / fmt::format("seed_{}", real_seed) /
                        "summary.json",
                    to / "summary.json");
      runs.push_back({{"scenario", name}, {"seed", k}, {"exit_code", 0}, {"error", ""},
                      {"client_failure", ""}, {"wall_time_s", 1.0}});
    }
  }
  nlohmann::json check = record;
  check["seeds"] = kSeeds;
  check["scenarios"] = names;
  check["runs"] = runs;
  std::ofstream(dir / "check.json") << check.dump(1);
  return dir;
}

// That check directory compared with itself, every summary.json read twice.
void BM_CompareCheckDirectories(benchmark::State& state) {
  const char* real = std::getenv("TOFU_BENCH_CHECK");
  if (real == nullptr) {
    state.SkipWithError("set TOFU_BENCH_CHECK to a tofu check --out directory");
    return;
  }
  const fs::path dir = MakeCheckDirectory(real);
  for (auto _ : state) {
    const CampaignRecord base = tofu::campaign::ReadCheckDirectory(dir);
    const CampaignRecord now = tofu::campaign::ReadCheckDirectory(dir);
    Compare(base, now, state);
  }
  fs::remove_all(dir);
}
BENCHMARK(BM_CompareCheckDirectories)->Unit(benchmark::kMillisecond)->UseRealTime();

}  // namespace

BENCHMARK_MAIN();
