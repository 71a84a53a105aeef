// `tofu compare` (campaign/compare.h): the verdicts on synthetic campaigns whose truth is
// known by construction (A/A, an injected regression, unpaired seed sets), their false
// verdict rate over many cells, the refusals of campaigns that cannot be compared, and the
// command on real checks (the pairing read from the runs' digests).

#include <sys/wait.h>

#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <random>
#include <string>

#include <fmt/format.h>
#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include "campaign/compare.h"
#include "core/error.h"
#include "tests/test_support.h"

namespace tofu::campaign {
namespace {

namespace fs = std::filesystem;

// A campaign of `scenarios` x `seeds` cells of one method "m": its ATE is
// base_ate * scale * exp(N(0, spread)) with a seed effect shared by every campaign made with
// the same `world_seed` (the seed's samples), plus N(0, noise) of its own (`own_seed`).
CampaignRecord Synthetic(int scenarios, int seeds, double scale, double spread, double noise,
                         uint64_t world_seed, uint64_t own_seed, uint64_t first_seed = 1) {
  CampaignRecord c;
  c.source = "synthetic";
  c.tofu_version = "0.1.0";
  c.tofu_commit = "test";
  for (const ComparedMetric& m : ComparedMetrics()) c.metric_versions[m.Pattern()] = m.version;
  std::mt19937_64 own(own_seed);
  std::normal_distribution<double> normal;
  for (int s = 0; s < scenarios; ++s) {
    for (int k = 0; k < seeds; ++k) {
      const uint64_t seed = first_seed + k;
      std::mt19937_64 world(world_seed * 1000003 + s * 1009 + seed);
      CellRecord cell;
      cell.scenario = fmt::format("s{}", s);
      cell.seed = seed;
      cell.scenario_hash = fmt::format("h{}", s);
      cell.exit_code = 0;
      cell.digests = {fmt::format("samples-{}", world_seed * 7 + seed),
                      fmt::format("streams-{}", world_seed * 7 + seed)};
      const double seed_effect = spread * normal(world);
      cell.values["methods.m.ate_m"] = 0.05 * scale * std::exp(seed_effect + noise * normal(own));
      cell.events["methods.m.failed"] = false;
      cell.events["run.failed"] = false;
      c.cells.push_back(cell);
    }
  }
  return c;
}

const CellComparison& Cell(const Comparison& c, const std::string& scenario, const std::string& metric) {
  for (const CellComparison& cell : c.cells) {
    if (cell.scenario == scenario && cell.metric->Pattern() == metric) return cell;
  }
  throw std::runtime_error("no cell " + scenario + " " + metric);
}

TEST(Compare, ACampaignAgainstItselfIsUnchangedEverywhere) {
  const CampaignRecord a = Synthetic(5, 5, 1.0, 0.3, 0.0, 1, 1);
  const Comparison c = CompareCampaigns(a, a, {});
  ASSERT_FALSE(c.cells.empty());
  for (const CellComparison& cell : c.cells) {
    EXPECT_EQ(cell.verdict, Verdict::kUnchanged) << cell.scenario << " " << cell.base_name;
    EXPECT_EQ(cell.pairing, Pairing::kIdenticalSamples);
  }
  EXPECT_EQ(Cell(c, "s0", "methods.<method>.ate_m").note, "identical values");
  EXPECT_DOUBLE_EQ(*Cell(c, "s0", "methods.<method>.ate_m").effect, 1.0);
}

TEST(Compare, AnInjectedRegressionIsFoundWhereItIsAndNowhereElse) {
  // The same seeds' samples (world 1) with 1 % noise of each build's own; scenario s2 is
  // 20 % worse in the new build.
  CampaignRecord base = Synthetic(4, 10, 1.0, 0.3, 0.01, 1, 11);
  CampaignRecord now = Synthetic(4, 10, 1.0, 0.3, 0.01, 1, 12);
  for (CellRecord& cell : now.cells) {
    if (cell.scenario == "s2") cell.values["methods.m.ate_m"] *= 1.2;
  }
  const Comparison c = CompareCampaigns(base, now, {});
  const CellComparison& hit = Cell(c, "s2", "methods.<method>.ate_m");
  EXPECT_EQ(hit.verdict, Verdict::kRegressed);
  EXPECT_NEAR(*hit.effect, 1.2, 0.02);
  EXPECT_LT(hit.interval->low, 1.25);
  EXPECT_GT(hit.interval->high, 1.15);
  for (const std::string s : {"s0", "s1", "s3"}) {
    EXPECT_EQ(Cell(c, s, "methods.<method>.ate_m").verdict, Verdict::kUnchanged) << s;
  }
  // The same change made 20 % better is an improvement.
  const Comparison back = CompareCampaigns(now, base, {});
  EXPECT_EQ(Cell(back, "s2", "methods.<method>.ate_m").verdict, Verdict::kImproved);
}

// A scenario's own minimal effect (its `compare: {minimal_effects}`) wins over the table's,
// and the command line's over both.
TEST(Compare, AScenarioSetsItsOwnMinimalEffectAndTheCommandLineWins) {
  const CampaignRecord base = Synthetic(2, 10, 1.0, 0.3, 0.0, 1, 1);
  CampaignRecord now = Synthetic(2, 10, 1.2, 0.3, 0.0, 1, 1);
  now.minimal_effects["s1"] = {{"methods.<method>.ate_m", 0.5}};
  const Comparison own = CompareCampaigns(base, now, {});
  EXPECT_EQ(Cell(own, "s0", "methods.<method>.ate_m").verdict, Verdict::kRegressed);
  EXPECT_DOUBLE_EQ(Cell(own, "s1", "methods.<method>.ate_m").minimal_effect, 0.5);
  EXPECT_NE(Cell(own, "s1", "methods.<method>.ate_m").verdict, Verdict::kRegressed);
  CompareOptions options;
  options.minimal_effects["methods.m.ate_m"] = 0.05;
  const Comparison overridden = CompareCampaigns(base, now, options);
  EXPECT_DOUBLE_EQ(Cell(overridden, "s1", "methods.<method>.ate_m").minimal_effect, 0.05);
  EXPECT_EQ(Cell(overridden, "s1", "methods.<method>.ate_m").verdict, Verdict::kRegressed);
}

TEST(Compare, AChangeBelowTheMinimalEffectIsNotAVerdict) {
  CampaignRecord base = Synthetic(1, 10, 1.0, 0.3, 0.001, 1, 21);
  CampaignRecord now = Synthetic(1, 10, 1.0, 0.3, 0.001, 1, 22);
  for (CellRecord& cell : now.cells) cell.values["methods.m.ate_m"] *= 1.02;  // 2 % < 5 %
  EXPECT_EQ(Cell(CompareCampaigns(base, now, {}), "s0", "methods.<method>.ate_m").verdict,
            Verdict::kUnchanged);
  CompareOptions strict;
  strict.minimal_effects["methods.<method>.ate_m"] = 0.01;
  EXPECT_EQ(Cell(CompareCampaigns(base, now, strict), "s0", "methods.<method>.ate_m").verdict,
            Verdict::kRegressed);
}

TEST(Compare, PairingMakesASmallChangeVisibleThatUnpairedSeedsCannot) {
  // 30 % seed-to-seed spread, 1 % of the build's own: a 10 % regression over 8 seeds.
  CampaignRecord base = Synthetic(1, 8, 1.0, 0.3, 0.01, 1, 31);
  CampaignRecord now = Synthetic(1, 8, 1.1, 0.3, 0.01, 1, 32);
  const Comparison paired = CompareCampaigns(base, now, {});
  EXPECT_EQ(Cell(paired, "s0", "methods.<method>.ate_m").verdict, Verdict::kRegressed);
  CompareOptions unpaired;
  unpaired.unpaired = true;
  CampaignRecord other = Synthetic(1, 8, 1.1, 0.3, 0.01, 2, 32, 101);  // other seeds
  const Comparison apart = CompareCampaigns(base, other, unpaired);
  const CellComparison& cell = Cell(apart, "s0", "methods.<method>.ate_m");
  EXPECT_EQ(cell.pairing, Pairing::kUnpaired);
  EXPECT_EQ(cell.verdict, Verdict::kInconclusive);
}

// Over A/A comparisons on disjoint seed sets (200 cells, independent), the share of
// improved/regressed verdicts stays below the false-discovery rate: under the global null
// every discovery is false, and Benjamini-Hochberg then bounds the chance of any at q.
TEST(Compare, FalseVerdictsOverDisjointSeedSetsStayBelowTheRate) {
  int false_verdicts = 0;
  int cells = 0;
  for (int trial = 0; trial < 20; ++trial) {
    const CampaignRecord a = Synthetic(10, 10, 1.0, 0.3, 0.0, 100 + trial, 1, 1);
    const CampaignRecord b = Synthetic(10, 10, 1.0, 0.3, 0.0, 200 + trial, 2, 11);
    CompareOptions options;
    options.unpaired = true;
    const Comparison c = CompareCampaigns(a, b, options);
    for (const CellComparison& cell : c.cells) {
      if (cell.metric->kind == EffectKind::kEvent) continue;
      ++cells;
      false_verdicts += cell.verdict == Verdict::kRegressed || cell.verdict == Verdict::kImproved;
    }
  }
  ASSERT_EQ(cells, 200);
  // 0.05 of 200 cells is 10; the family-wise bound makes the expected count far lower.
  EXPECT_LE(false_verdicts, 10) << false_verdicts << " false verdicts in " << cells << " cells";
}

TEST(Compare, PairedEventsUseMcNemarAndNeverDropAFailure) {
  CampaignRecord base = Synthetic(1, 10, 1.0, 0.3, 0.0, 1, 1);
  CampaignRecord now = base;
  for (CellRecord& cell : now.cells) {
    // The new build's client fails in every seed: its values are gone, its failure is not.
    cell.values.erase("methods.m.ate_m");
    cell.events["methods.m.failed"] = true;
  }
  const Comparison c = CompareCampaigns(base, now, {});
  const CellComparison& failed = Cell(c, "s0", "methods.<method>.failed");
  EXPECT_EQ(failed.new_only, 10);
  EXPECT_NEAR(failed.p_regressed, std::pow(0.5, 10), 1e-15);
  EXPECT_EQ(failed.verdict, Verdict::kRegressed);
  EXPECT_EQ(Cell(c, "s0", "methods.<method>.ate_m").verdict, Verdict::kInconclusive);
}

// One failed run (no summary, so no digests and no values) leaves the other seeds paired:
// its failure is a paired event, the metric is tested over the seeds that have both.
TEST(Compare, AFailedRunDoesNotUnpairTheOtherSeeds) {
  const CampaignRecord base = Synthetic(1, 8, 1.0, 0.3, 0.0, 1, 1);
  CampaignRecord now = Synthetic(1, 8, 1.0, 0.3, 0.0, 1, 1);
  CellRecord& failed = now.cells[3];
  failed.error = "exit 3: the simulation failed";
  failed.exit_code = 3;
  failed.values.clear();
  failed.digests = {};
  failed.events = {{"run.failed", true}};
  const Comparison c = CompareCampaigns(base, now, {});
  const CellComparison& ate = Cell(c, "s0", "methods.<method>.ate_m");
  EXPECT_EQ(ate.pairing, Pairing::kIdenticalSamples);
  EXPECT_EQ(ate.pairs, 7);
  const CellComparison& run = Cell(c, "s0", "run.failed");
  EXPECT_EQ(run.new_only, 1);
  EXPECT_EQ(run.base_only, 0);
}

TEST(Compare, RefusesWhatCannotBeComparedNamingTheCell) {
  const CampaignRecord a = Synthetic(2, 3, 1.0, 0.3, 0.0, 1, 1);
  const auto refused = [&](CampaignRecord b, const std::string& fragment) {
    try {
      CompareCampaigns(a, b, {});
      ADD_FAILURE() << "compared, expected a refusal naming " << fragment;
    } catch (const core::InputError& e) {
      EXPECT_NE(std::string(e.what()).find(fragment), std::string::npos) << e.what();
    }
  };
  CampaignRecord b = a;
  b.tofu_version = "0.2.0";
  refused(b, "tofu 0.2.0");
  b = a;
  b.metric_versions["methods.<method>.ate_m"] = 2;
  refused(b, "methods.<method>.ate_m");
  b = a;
  for (CellRecord& cell : b.cells) {
    if (cell.scenario == "s1") cell.scenario_hash = "changed";
  }
  refused(b, "s1");
  b = a;
  b.cells.pop_back();
  refused(b, "[1, 2] in the new");
  b = a;
  for (CellRecord& cell : b.cells) cell.scenario = cell.scenario == "s1" ? "s9" : cell.scenario;
  refused(b, "s1");
  CompareOptions options;
  options.minimal_effects["methods.<method>.no_such_metric"] = 0.1;
  EXPECT_THROW(CompareCampaigns(a, a, options), core::InputError);
  // A yes/no outcome has no size: no minimal effect for it.
  CompareOptions event;
  event.minimal_effects["methods.m.failed"] = 0.1;
  EXPECT_THROW(CompareCampaigns(a, a, event), core::InputError);
}

// ---- the command on real checks ----

struct Result {
  int exit_code = -1;
  std::string out;
};

Result Tofu(const std::string& args, const fs::path& cwd) {
  const std::string command = "cd " + test::Quote(cwd.string()) + " && " + test::Quote(TOFU_BINARY) +
                              " " + args + " >out.txt 2>&1";
  const int status = std::system(command.c_str());
  return {WIFEXITED(status) ? WEXITSTATUS(status) : -1, test::ReadFile(cwd / "out.txt")};
}

// A short flight with a VIO that diverges: naive fusion (every sensor, true frames) is far
// worse than consensus on the same samples. Eight seeds: a two-sided exact rank test over n
// pairs cannot go below 2 / 2^n (0.0625 at five seeds), and the grid's correction asks for
// more.
constexpr const char* kScenario = R"(
name: compare_short
world: indoor_arena
duration_s: 12
seed: 1
trajectory:
  start: {position_m: [0, 0, 1.5]}
  limits: {max_speed_mps: 1.0, max_acceleration_mps2: 1.5}
  segments:
    - hover: {duration_s: 1}
    - figure_eight: {center_m: [0, 0, 1.5], half_length_m: 2.0, half_width_m: 1.2, speed_mps: 1.0, laps: 1}
sensors:
  imu: {}
  vio: {}
  lio: {type: lidar_odometry}
  leica: {type: total_station}
faults:
  - {sensor: vio, kind: divergence, start_s: 4, end_s: 12, axis: [1, 0.5, 0], initial_velocity_mps: 0.3, time_constant_s: 4}
estimation:
  methods: [consensus, naive]
  consensus: {threshold: 0.3, priority: [leica, lio, vio]}
  huber_delta: 3
)";

TEST(CompareCommand, AChecksOwnRunsAreUnchangedAndNaiveFusionIsWorseThanConsensus) {
  const fs::path work = test::PerTestDirectory("compare_command_");
  fs::create_directories(work);
  test::WriteFile(work / "s.yaml", kScenario);
  const Result check = Tofu("check s.yaml --seeds 8 --jobs 2 --out A --quiet", work);
  ASSERT_EQ(check.exit_code, 0) << check.out;
  ASSERT_TRUE(fs::exists(work / "A" / "check.json"));

  // A/A: a check against itself.
  const Result same = Tofu("compare A A --json same.json --markdown same.md", work);
  EXPECT_EQ(same.exit_code, 0) << same.out;
  const auto j = nlohmann::json::parse(test::ReadFile(work / "same.json"));
  ASSERT_GT(j["cells"].size(), 5u);
  for (const auto& cell : j["cells"]) {
    EXPECT_EQ(cell["verdict"], "unchanged") << cell.dump();
    EXPECT_EQ(cell["pairing"], "identical samples") << cell.dump();
  }

  // Two methods of one check saw the same samples: naive is the regression.
  const Result methods = Tofu("compare A --methods consensus naive --json m.json", work);
  EXPECT_EQ(methods.exit_code, 1) << methods.out;
  const auto m = nlohmann::json::parse(test::ReadFile(work / "m.json"));
  bool found = false;
  for (const auto& cell : m["cells"]) {
    if (cell["metric"] != "methods.<method>.ate_m") continue;
    found = true;
    EXPECT_EQ(cell["verdict"], "regressed") << cell.dump();
    EXPECT_EQ(cell["pairing"], "identical samples");
    EXPECT_GT(cell["effect"].get<double>(), 2.0) << cell.dump();
  }
  EXPECT_TRUE(found) << m.dump();

  // A baseline file of the check compares as the check does; refusals write nothing.
  EXPECT_EQ(Tofu("baseline A --out base.json", work).exit_code, 0);
  EXPECT_EQ(Tofu("compare base.json A", work).exit_code, 0);
  const Result refused = Tofu("compare A --methods consensus no_such --json x.json", work);
  EXPECT_EQ(refused.exit_code, 2) << refused.out;
  EXPECT_NE(refused.out.find("no_such"), std::string::npos) << refused.out;
  EXPECT_FALSE(fs::exists(work / "x.json"));
  std::string text = test::ReadFile(work / "base.json");
  const std::string version = "\"tofu_version\": \"";
  text.replace(text.find(version) + version.size(), 1, "9");
  test::WriteFile(work / "other.json", text);
  const Result other = Tofu("compare other.json A --json y.json", work);
  EXPECT_EQ(other.exit_code, 2) << other.out;
  EXPECT_NE(other.out.find("re-record the baseline"), std::string::npos) << other.out;
  EXPECT_FALSE(fs::exists(work / "y.json"));

  // tofu check --baseline: the same tofu on the same seeds is unchanged, and its JUnit
  // holds a passing case "compared with the baseline".
  const Result same_check = Tofu("check s.yaml --seeds 8 --jobs 2 --out B --quiet --baseline "
                                 "base.json --junit B/junit.xml", work);
  EXPECT_EQ(same_check.exit_code, 0) << same_check.out;
  const std::string junit = test::ReadFile(work / "B" / "junit.xml");
  EXPECT_NE(junit.find("<testcase name=\"compared with the baseline\" classname=\"compare_short\" "
                       "file=\"s.yaml\" time=\"0\"/>"),
            std::string::npos) << junit;
  EXPECT_TRUE(fs::exists(work / "B" / "compare.md"));
  // A baseline whose consensus was 30 % better: the check regressed, its JUnit case fails
  // with the figures, the check exits 1.
  auto better = nlohmann::json::parse(test::ReadFile(work / "base.json"));
  for (auto& cell : better["cells"]) {
    auto& ate_m = cell["values"]["methods.consensus.ate_m"];
    ate_m = ate_m.get<double>() * 0.7;
  }
  test::WriteFile(work / "better.json", better.dump(1));
  const Result regressed = Tofu("check s.yaml --seeds 8 --jobs 2 --out C --quiet --baseline "
                                "better.json --junit C/junit.xml", work);
  EXPECT_EQ(regressed.exit_code, 1) << regressed.out;
  EXPECT_NE(regressed.out.find("REGRESSED compare_short: methods.consensus.ate_m x1.429"),
            std::string::npos) << regressed.out;
  const std::string failed_junit = test::ReadFile(work / "C" / "junit.xml");
  EXPECT_NE(failed_junit.find("<failure message=\"1 cell regressed against the baseline: "
                              "methods.consensus.ate_m x1.429"),
            std::string::npos) << failed_junit;
  EXPECT_NE(failed_junit.find("type=\"regression\""), std::string::npos);
  // Its report fails too, and draws the regressed cell's pairs.
  ASSERT_EQ(Tofu("report C --out C_report", work).exit_code, 0);
  const std::string page = test::ReadFile(work / "C_report" / "index.html");
  EXPECT_NE(page.find("1 cell regressed against the baseline"), std::string::npos);
  EXPECT_NE(page.find("<h1>tofu check <span class=\"badge fail\">"), std::string::npos);
  EXPECT_NE(page.find("Compared with the baseline"), std::string::npos);
  EXPECT_NE(page.find("<svg class=\"slope\""), std::string::npos);
  // A scenario's own minimal effects travel through check.json and the baseline file, and
  // one naming no comparable metric is refused by validate, run and check.
  std::string lenient = kScenario;
  lenient += "compare:\n  minimal_effects: {methods.<method>.ate_m: 0.5}\n";
  test::WriteFile(work / "lenient.yaml", lenient);
  ASSERT_EQ(Tofu("check lenient.yaml --seeds 8 --jobs 2 --out L --quiet", work).exit_code, 0);
  ASSERT_EQ(Tofu("baseline L --out lenient.json", work).exit_code, 0);
  const auto lenient_baseline = nlohmann::json::parse(test::ReadFile(work / "lenient.json"));
  EXPECT_EQ(lenient_baseline["minimal_effects"]["compare_short"]["methods.<method>.ate_m"], 0.5);
  std::string wrong = kScenario;
  wrong += "compare:\n  minimal_effects: {methods.<method>.no_such_m: 0.5}\n";
  test::WriteFile(work / "wrong.yaml", wrong);
  for (const std::string command : {"validate wrong.yaml", "run wrong.yaml --out W --quiet",
                                    "check wrong.yaml --out W --quiet"}) {
    const Result r = Tofu(command, work);
    EXPECT_EQ(r.exit_code, 2) << command << ": " << r.out;
    EXPECT_NE(r.out.find("wrong.yaml:"), std::string::npos) << r.out;
    EXPECT_NE(r.out.find("compare.minimal_effects.methods.<method>.no_such_m"), std::string::npos)
        << r.out;
  }
  EXPECT_FALSE(fs::exists(work / "W"));
  // Another grid (6 seeds of a baseline of 8): bad input before anything runs.
  const Result other_grid = Tofu("check s.yaml --seeds 6 --out D --quiet --baseline base.json", work);
  EXPECT_EQ(other_grid.exit_code, 2) << other_grid.out;
  EXPECT_NE(other_grid.out.find("compare_short"), std::string::npos) << other_grid.out;
  EXPECT_FALSE(fs::exists(work / "D"));
  fs::remove_all(work);
}

}  // namespace
}  // namespace tofu::campaign
