// `tofu search` (campaign/search.h): a failure region known analytically is found, by the
// control (random) and the guided optimiser (TPE); shrinking returns the smallest failing
// change; a search killed mid-way resumes with the result of an uninterrupted one; a bad
// spec is refused naming the key and the expected form; and, flown for real, a promoted
// failure fails under `tofu check`. The analytic problem is the one of
// tests/data/search/dropout_search.yaml: a VIO dropout at 20 Hz in a 6 s flight fails
// `sensors.vio.delivered_samples >= 90` when more than 1.5 s of it falls in the flight.

#include <sys/wait.h>

#include <gtest/gtest.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <csignal>
#include <map>
#include <filesystem>
#include <stdexcept>
#include <string>
#include <thread>
#include <vector>

#include <fmt/format.h>
#include <nlohmann/json.hpp>

#include "campaign/margin.h"
#include "campaign/search.h"
#include "campaign/search_spec.h"
#include "campaign/statistics.h"
#include "core/error.h"
#include "harness/scenario.h"
#include "tests/test_support.h"

namespace tofu {
namespace {

namespace fs = std::filesystem;
using campaign::FlightMargin;
using campaign::FlightRequest;
using campaign::Setting;

const fs::path kData = fs::path(TOFU_SOURCE_DIR) / "tests" / "data" / "search";

campaign::SearchSpec Spec(const std::string& text) {
  return campaign::ParseSearchSpec(text, "spec.yaml", kData);
}

std::string DropoutSpec(const std::string& optimizer, int budget, const std::string& extra = "") {
  return fmt::format(
      "name: dropout\nbase: dropout_base.yaml\n"
      "objective: {{expectations: [sensors.vio.delivered_samples]}}\n"
      "space:\n  faults:\n    - kinds: [{{kind: dropout, sensors: [vio]}}]\n"
      "      onset_s: [0, 5]\n      duration_s: [0.1, 3]\n"
      "budget: {{simulations: {}}}\noptimizer: {{name: {}, seed: 7}}\nconfirm: {{seeds: 3}}\n{}",
      budget, optimizer, extra);
}

// The flight's margin computed, not flown: 20 Hz samples over 6 s less those of the
// dropout's part within the flight, against min 90 (campaign/margin.h).
class AnalyticDropout : public campaign::FlightEvaluator {
 public:
  explicit AnalyticDropout(const campaign::SearchSpec& spec) : spec_(spec) {}
  std::vector<FlightMargin> Fly(const std::vector<FlightRequest>& requests) override {
    std::vector<FlightMargin> out;
    for (const FlightRequest& r : requests) {
      if (fail_after_ >= 0 && flown_ >= fail_after_) throw std::runtime_error("killed");
      ++flown_;
      double lost_s = 0.0;
      const campaign::FaultSetting& f = r.setting.faults.at(0);
      if (f.present) lost_s = std::min(f.onset_s + f.duration_s, 6.0) - f.onset_s;
      const double delivered = std::round(20.0 * (6.0 - lost_s));
      FlightMargin m;
      m.margin = campaign::ExpectationMargin(delivered, 90.0, std::nullopt);
      m.failing_metric = "sensors.vio.delivered_samples";
      m.outcome = m.margin < 0.0 ? "violated" : "passed";
      out.push_back(m);
    }
    return out;
  }
  int flown_ = 0;
  int fail_after_ = -1;  // throw at this many flights: a killed search

 private:
  const campaign::SearchSpec& spec_;
};

double LostSeconds(const Setting& s) {
  const campaign::FaultSetting& f = s.faults.at(0);
  return std::min(f.onset_s + f.duration_s, 6.0) - f.onset_s;
}

TEST(SearchMargin, IsSignedAndNormalisedByTheBound) {
  EXPECT_DOUBLE_EQ(campaign::ExpectationMargin(0.5, std::nullopt, 1.0), 0.5);
  EXPECT_DOUBLE_EQ(campaign::ExpectationMargin(1.5, std::nullopt, 1.0), -0.5);
  EXPECT_DOUBLE_EQ(campaign::ExpectationMargin(60.0, 90.0, std::nullopt), -1.0 / 3.0);
  EXPECT_DOUBLE_EQ(campaign::ExpectationMargin(2.0, std::nullopt, 0.0), -2.0);  // a count: its own unit
  EXPECT_DOUBLE_EQ(campaign::ExpectationMargin(1.0, 1.0, 1.0), 0.0);           // on the bound: holds
  EXPECT_DOUBLE_EQ(campaign::ExpectationMargin(3.0, 2.0, 4.0), 0.25);           // the nearer bound
}

TEST(SearchMargin, AFlightWithoutMarginIsAFailureFound) {
  campaign::SeedRun run;
  run.error = "simulation failed (exit 3)";
  const FlightMargin crashed = campaign::MarginOfRun(run, {"x"});
  EXPECT_TRUE(std::isinf(crashed.margin) && crashed.margin < 0.0);
  EXPECT_EQ(crashed.outcome, "simulation failed");

  campaign::SeedRun client;
  client.summary = nlohmann::json::parse(R"({"expectations": [{"metric": "x", "min": null, "max": 1.0,
                                             "value": 0.5, "passed": true}]})");
  client.client_failure = "method external:ekf failed: exited with status 1";
  const FlightMargin failed = campaign::MarginOfRun(client, {"x"});
  EXPECT_TRUE(std::isinf(failed.margin) && failed.margin < 0.0);
  EXPECT_EQ(failed.outcome, "client failed");
  EXPECT_NE(failed.cause.find("external:ekf"), std::string::npos);
}

TEST(SearchStatistics, ClopperPearsonMatchesScipy) {
  // scipy.stats.binomtest(k, n).proportion_ci(0.95, method="exact")
  const campaign::Interval a = campaign::ClopperPearsonInterval(3, 5, 0.95);
  EXPECT_NEAR(a.low, 0.1466328, 1e-6);
  EXPECT_NEAR(a.high, 0.9472550, 1e-6);
  const campaign::Interval none = campaign::ClopperPearsonInterval(0, 10, 0.95);
  EXPECT_EQ(none.low, 0.0);
  EXPECT_NEAR(none.high, 0.3084971, 1e-6);
  const campaign::Interval all = campaign::ClopperPearsonInterval(5, 5, 0.95);
  EXPECT_NEAR(all.low, 0.4781762, 1e-6);
  EXPECT_EQ(all.high, 1.0);
}

// The interval's coverage, counted exactly (binomial probabilities of every outcome whose
// interval holds p): Clopper-Pearson never covers less than its level, at any p and n.
TEST(SearchStatistics, ClopperPearsonCoversAtLeastItsLevel) {
  for (const int n : {2, 3, 5, 10, 20}) {
    std::vector<campaign::Interval> intervals;
    for (int k = 0; k <= n; ++k) intervals.push_back(campaign::ClopperPearsonInterval(k, n, 0.95));
    for (double p = 0.005; p < 1.0; p += 0.01) {
      double coverage = 0.0;
      for (int k = 0; k <= n; ++k) {
        if (intervals[k].low <= p && p <= intervals[k].high) {
          coverage += std::exp(std::lgamma(n + 1.0) - std::lgamma(k + 1.0) - std::lgamma(n - k + 1.0) +
                               k * std::log(p) + (n - k) * std::log1p(-p));
        }
      }
      EXPECT_GE(coverage, 0.95 - 1e-9) << "n " << n << ", p " << p;
    }
  }
}

class SearchAnalytic : public ::testing::TestWithParam<std::string> {};

TEST_P(SearchAnalytic, FindsTheKnownRegionAndShrinksToItsEdge) {
  const campaign::SearchSpec spec = Spec(DropoutSpec(GetParam(), 40));
  AnalyticDropout flights(spec);
  const auto proposer = campaign::MakeProposer(spec, fs::path(TOFU_SOURCE_DIR) / "scripts");
  const campaign::SearchOutcome out = campaign::RunSearch(spec, flights, *proposer);
  ASSERT_EQ(out.evaluations.size(), 40u);
  // Every evaluation's verdict is the analytic one: fails exactly when > 1.5 s is lost.
  for (const campaign::SearchEvaluation& e : out.evaluations) {
    EXPECT_EQ(e.margin.margin < 0.0, std::round(20.0 * (6.0 - LostSeconds(e.setting))) < 90.0) << e.id;
  }
  ASSERT_FALSE(out.failures.empty());
  ASSERT_TRUE(out.failures.front().confirmed);
  ASSERT_TRUE(out.simulations_to_first_confirmed.has_value());
  for (const campaign::FoundFailure& f : out.failures) {
    if (!f.confirmed) continue;
    EXPECT_EQ(f.confirm_failures, 3);
    // Removing the dropout passes, so it stays; its duration comes down to the smallest
    // that fails: more than 1.5 s lost, within a bisection step (4 steps of the found one).
    ASSERT_TRUE(f.shrunk.faults[0].present) << f.id;
    const double lost = LostSeconds(f.shrunk);
    EXPECT_GT(lost, 1.5) << f.id;
    EXPECT_LE(lost, 1.5 + LostSeconds(f.found) / 16.0 + 0.05) << f.id;
    EXPECT_LT(f.shrunk_margin.margin, 0.0);
    EXPECT_GE(f.shrunk_margin.margin, f.found_margin.margin);
  }
}

INSTANTIATE_TEST_SUITE_P(Optimizers, SearchAnalytic, ::testing::Values("random", "tpe"));

TEST(Search, TheSameSpecProposesTheSamePoints) {
  for (const std::string optimizer : {"random", "tpe"}) {
    const campaign::SearchSpec spec = Spec(DropoutSpec(optimizer, 12));
    AnalyticDropout a(spec), b(spec);
    const auto pa = campaign::MakeProposer(spec, fs::path(TOFU_SOURCE_DIR) / "scripts");
    const auto pb = campaign::MakeProposer(spec, fs::path(TOFU_SOURCE_DIR) / "scripts");
    const auto oa = campaign::RunSearch(spec, a, *pa);
    const auto ob = campaign::RunSearch(spec, b, *pb);
    ASSERT_EQ(oa.evaluations.size(), ob.evaluations.size());
    for (std::size_t i = 0; i < oa.evaluations.size(); ++i) {
      EXPECT_EQ(oa.evaluations[i].unit, ob.evaluations[i].unit) << optimizer << " " << i;
    }
  }
}

TEST(Search, AKilledSearchResumesWithTheSameResult) {
  const fs::path dir = test::PerTestDirectory("tofu_search_resume_");
  fs::create_directories(dir);
  for (const std::string optimizer : {"random", "tpe"}) {
    const campaign::SearchSpec spec = Spec(DropoutSpec(optimizer, 16));
    const fs::path scripts = fs::path(TOFU_SOURCE_DIR) / "scripts";

    AnalyticDropout whole(spec);
    const auto p0 = campaign::MakeProposer(spec, scripts);
    const campaign::SearchOutcome expected = campaign::RunSearch(spec, whole, *p0);

    const fs::path journal = dir / (optimizer + ".jsonl");
    AnalyticDropout killed(spec);
    killed.fail_after_ = 9;  // mid-batch: the batch's first flight is flown, not journaled
    {
      campaign::JournaledEvaluator journaled(spec, killed, journal);
      const auto p1 = campaign::MakeProposer(spec, scripts);
      EXPECT_THROW(campaign::RunSearch(spec, journaled, *p1), std::runtime_error);
    }
    // A kill while the journal was written leaves a torn line: dropped on resume.
    { std::ofstream(journal, std::ios::app) << R"({"id": "e0000)"; }

    AnalyticDropout resumed(spec);
    campaign::JournaledEvaluator journaled(spec, resumed, journal);
    const auto p2 = campaign::MakeProposer(spec, scripts);
    const campaign::SearchOutcome got = campaign::RunSearch(spec, journaled, *p2);
    // What the killed search journaled is not flown again; the rest is, once.
    EXPECT_GE(journaled.reused(), 8u) << optimizer;
    EXPECT_EQ(static_cast<int>(journaled.flown() + journaled.reused()), whole.flown_) << optimizer;
    ASSERT_EQ(got.evaluations.size(), expected.evaluations.size());
    for (std::size_t i = 0; i < got.evaluations.size(); ++i) {
      EXPECT_EQ(got.evaluations[i].unit, expected.evaluations[i].unit) << optimizer << " " << i;
      EXPECT_EQ(got.evaluations[i].margin.margin, expected.evaluations[i].margin.margin);
    }
    ASSERT_EQ(got.failures.size(), expected.failures.size());
    for (std::size_t i = 0; i < got.failures.size(); ++i) {
      EXPECT_EQ(got.failures[i].id, expected.failures[i].id);
      EXPECT_EQ(got.failures[i].shrunk, expected.failures[i].shrunk);
    }
  }
  fs::remove_all(dir);
}

// The shipped problems (searches/, the benchmark of docs/RESULTS.md) load, and their bases
// load their models: a change of the scenario format cannot leave them behind unnoticed.
TEST(SearchSpec, TheShippedProblemsLoad) {
  int problems = 0;
  for (const auto& entry : fs::directory_iterator(fs::path(TOFU_SOURCE_DIR) / "searches")) {
    if (entry.path().extension() != ".yaml") continue;
    ++problems;
    try {
      const campaign::SearchSpec spec = campaign::LoadSearchSpec(entry.path());
      harness::CheckScenarioModels(spec.base);
      EXPECT_TRUE(spec.stop_at_first) << entry.path();  // the benchmark counts to the first failure
    } catch (const core::InputError& e) {
      ADD_FAILURE() << e.what();
    }
  }
  EXPECT_GE(problems, 3);
}

// Each bad spec: exit 2's message names the key and the expected form.
struct BadSpec {
  std::string what;
  std::string text;
  std::vector<std::string> said;
};

TEST(SearchSpec, BadSpecsNameTheKeyAndTheExpectedForm) {
  const std::string space = "space:\n  faults:\n    - kinds: [{kind: dropout, sensors: [vio]}]\n"
                            "      onset_s: [0, 5]\n      duration_s: [0.1, 3]\n";
  const std::string head = "name: s\nbase: dropout_base.yaml\n";
  const std::string objective = "objective: {expectations: [sensors.vio.delivered_samples]}\n";
  const std::string budget = "budget: {simulations: 4}\n";
  const std::vector<BadSpec> cases = {
      {"unknown parameter", head + objective + "space:\n  wind_speed: [0, 1]\n" + budget,
       {"space.wind_speed", "unknown key"}},
      {"unknown set key", head + objective + "space:\n  set: {trajectory.speed_mps: [0.5, 1]}\n" + budget,
       {"space.set.trajectory.speed_mps", "not a key the base scenario takes", "unknown key 'speed_mps'"}},
      {"set key past a list's end", head + objective + "space:\n  set:\n    trajectory.segments[3].hover.duration_s: [1, 2]\n" + budget,
       {"trajectory.segments[3].hover.duration_s", "names no key of the base scenario"}},
      {"empty range", head + objective +
                          "space:\n  faults:\n    - kinds: [{kind: dropout, sensors: [vio]}]\n"
                          "      onset_s: [2, 2]\n      duration_s: [0.1, 3]\n" + budget,
       {"onset_s", "empty range", "lo < hi"}},
      {"objective names no expectation", head + "objective: {expectations: [methods.consensus.ate_m]}\n" + space + budget,
       {"objective.expectations", "names no expectation of the base", "sensors.vio.delivered_samples"}},
      {"budget of 0", head + objective + space + "budget: {simulations: 0}\n",
       {"budget.simulations", "[1, 1000000]"}},
      {"batch of 0", head + objective + space + "budget: {simulations: 4, batch: 0}\n",
       {"budget.batch", "[1, 256]"}},
      {"unknown optimizer", head + objective + space + budget + "optimizer: {name: cmaes}\n",
       {"optimizer.name", "random, tpe"}},
      {"sensor the base lacks", head + objective +
                                    "space:\n  faults:\n    - kinds: [{kind: dropout, sensors: [lidar]}]\n"
                                    "      onset_s: [0, 5]\n      duration_s: [0.1, 3]\n" + budget,
       {"sensors", "'lidar'"}},
      {"onset past the flight", head + objective +
                                    "space:\n  faults:\n    - kinds: [{kind: dropout, sensors: [vio]}]\n"
                                    "      onset_s: [0, 8]\n      duration_s: [0.1, 3]\n" + budget,
       {"onset_s", "hi < 6"}},
  };
  for (const BadSpec& c : cases) {
    try {
      Spec(c.text);
      ADD_FAILURE() << c.what << ": accepted";
    } catch (const core::InputError& e) {
      const std::string message = e.what();
      EXPECT_NE(message.find("spec.yaml:"), std::string::npos) << c.what << ": " << message;
      for (const std::string& s : c.said) EXPECT_NE(message.find(s), std::string::npos) << c.what << ": " << message;
    }
  }
}

// ---- flown for real: `tofu search` and `tofu check` as processes ----

// tofu, run in the test's directory.
test::CommandResult Tofu(const std::string& args, const fs::path& dir) { return test::RunTofu(args, dir); }

// `tofu search SPEC --out <dir>/out --promote <dir>/promoted`, then `tofu check` of what it
// promoted.
test::CommandResult SearchAndPromote(const std::string& spec, const fs::path& dir) {
  return Tofu(fmt::format("search {} --out {} --jobs 2 --no-renders --promote {}", test::Quote(spec),
                          test::Quote((dir / "out").string()), test::Quote((dir / "promoted").string())),
              dir);
}
test::CommandResult CheckPromoted(const fs::path& dir) {
  return Tofu(fmt::format("check {} --out {} --quiet", test::Quote((dir / "promoted").string()),
                          test::Quote((dir / "check").string())),
              dir);
}

TEST(SearchCommand, APromotedFailureFailsUnderCheck) {
  const fs::path dir = test::PerTestDirectory("tofu_search_promote_");
  fs::create_directories(dir);
  const std::string spec = (kData / "dropout_search.yaml").string();
  const test::CommandResult search = SearchAndPromote(spec, dir);
  ASSERT_EQ(search.exit_code, 1) << search.err;
  const nlohmann::json result = nlohmann::json::parse(test::ReadFile(dir / "out" / "search.json"));
  ASSERT_FALSE(result["failures"].empty());
  EXPECT_TRUE(result["failures"][0]["confirmed"].get<bool>());
  // Flown, the shrunk dropout is the smallest that fails: just over 1.5 s lost.
  const nlohmann::json& fault = result["failures"][0]["shrunk"]["faults"][0];
  const double lost = std::min(fault["onset_s"].get<double>() + fault["duration_s"].get<double>(), 6.0) -
                      fault["onset_s"].get<double>();
  EXPECT_GT(lost, 1.45);
  EXPECT_LT(lost, 1.8);
  EXPECT_TRUE(fs::exists(dir / "out" / "failures" / "f1" / "scenario.yaml"));

  // tofu report of the search: the margins, the failures ranked, each one's flight page.
  const test::CommandResult report = Tofu(fmt::format("report {} --out {}", test::Quote((dir / "out").string()),
                                                      test::Quote((dir / "report").string())),
                                          dir);
  ASSERT_EQ(report.exit_code, 0) << report.err;
  const std::string page = test::ReadFile(dir / "report" / "index.html");
  EXPECT_NE(page.find("CONFIRMED FAILURE"), std::string::npos);
  EXPECT_NE(page.find("<svg class=\"margins\""), std::string::npos);
  EXPECT_NE(page.find("sensors.vio.delivered_samples"), std::string::npos);
  EXPECT_TRUE(fs::exists(dir / "report" / "failures" / "f1" / "index.html"));

  std::vector<fs::path> promoted;
  for (const auto& e : fs::directory_iterator(dir / "promoted")) promoted.push_back(e.path());
  ASSERT_FALSE(promoted.empty());
  const test::CommandResult check = CheckPromoted(dir);
  EXPECT_EQ(check.exit_code, 1) << check.out << check.err;
  EXPECT_NE(check.out.find("sensors.vio.delivered_samples"), std::string::npos) << check.out;

  // ...and as episodes of a failure corpus: a spec that includes the promoted directory
  // flies them after its sampled episodes, and the corpus verifies.
  test::WriteFile(dir / "corpus.yaml",
                  "name: hard_cases\nseed: 3\nepisodes: 1\nduration_s: 6\n"
                  "worlds: [{world: indoor_arena, center_m: [0, 0]}]\n"
                  "trajectory: {families: [circle], speed_mps: 0.5, size_m: 1.0, height_m: 1.5, tilt_deg: 0}\n"
                  "sensors: {imu: {}, vio: {rate_hz: 20}}\ninclude: [promoted]\n");
  const std::string corpus = test::Quote((dir / "corpus").string());
  const test::CommandResult generate =
      Tofu(fmt::format("corpus generate {} --out {} --quiet", test::Quote((dir / "corpus.yaml").string()), corpus), dir);
  ASSERT_EQ(generate.exit_code, 0) << generate.err;
  const test::CommandResult verify = Tofu(fmt::format("corpus verify {}", corpus), dir);
  ASSERT_EQ(verify.exit_code, 0) << verify.out << verify.err;
  const std::string manifest = test::ReadFile(dir / "corpus" / "manifest.csv");
  EXPECT_NE(manifest.find("hard_cases_e000001,1,indoor_arena,included"), std::string::npos) << manifest;
  EXPECT_TRUE(fs::exists(dir / "corpus" / "included" / "promoted"));

  // Resumed in the same --out: nothing flown again, the same result.
  const std::string before = test::ReadFile(dir / "out" / "search.json");
  const test::CommandResult again = Tofu(fmt::format("search {} --out {} --jobs 2 --no-renders", test::Quote(spec),
                                                     test::Quote((dir / "out").string())),
                                         dir);
  EXPECT_EQ(again.exit_code, 1) << again.err;
  EXPECT_NE(again.err.find("0 flights flown"), std::string::npos) << again.err;
  EXPECT_EQ(test::ReadFile(dir / "out" / "search.json"), before);

  // Another spec in the same --out: refused before anything flies.
  const fs::path other = dir / "other.yaml";
  test::WriteFile(other, test::ReadFile(spec) + "\nstop_at_first: true\n");
  fs::copy_file(kData / "dropout_base.yaml", dir / "dropout_base.yaml");
  const test::CommandResult refused = Tofu(fmt::format("search {} --out {}", test::Quote(other.string()),
                                                       test::Quote((dir / "out").string())),
                                           dir);
  EXPECT_EQ(refused.exit_code, 2);
  EXPECT_NE(refused.err.find("holds a search of another spec"), std::string::npos) << refused.err;
  fs::remove_all(dir);
}

TEST(SearchCommand, AUsersEstimatorThatCrashesIsAFailureFoundWithItsStderr) {
  const fs::path dir = test::PerTestDirectory("tofu_search_client_");
  fs::create_directories(dir);
  const std::string spec = (kData / "client_search.yaml").string();
  const test::CommandResult search = SearchAndPromote(spec, dir);
  ASSERT_EQ(search.exit_code, 1) << search.err;
  const nlohmann::json result = nlohmann::json::parse(test::ReadFile(dir / "out" / "search.json"));
  ASSERT_FALSE(result["failures"].empty());
  const nlohmann::json& f = result["failures"][0];
  EXPECT_EQ(f["expectation"], "client failed");
  EXPECT_TRUE(f["confirmed"].get<bool>());
  EXPECT_TRUE(f["found_margin"]["margin"].is_null());
  const std::string cause = f["found_margin"]["cause"].get<std::string>();
  EXPECT_NE(cause.find("external:gap_intolerant"), std::string::npos) << cause;
  EXPECT_NE(cause.find("gap_intolerant: no vio for"), std::string::npos) << cause;  // its stderr
  // The shrunk dropout still silences VIO for more than 1.2 s, and not much more.
  const nlohmann::json& fault = f["shrunk"]["faults"][0];
  EXPECT_GT(fault["duration_s"].get<double>(), 1.1);
  EXPECT_LT(fault["duration_s"].get<double>(), 1.4);
  // Promoted, the crash fails the check (a client failed: exit 5).
  EXPECT_NE(test::ReadFile(dir / "out" / "flights" / (f["shrunk_flight"].get<std::string>() + ".yaml"))
                .find("external:gap_intolerant"),
            std::string::npos);
  const test::CommandResult check = CheckPromoted(dir);
  EXPECT_EQ(check.exit_code, 5) << check.out << check.err;
  fs::remove_all(dir);
}

TEST(SearchCommand, ABadSpecIsExit2NamingTheKeyWithNothingFlown) {
  const fs::path dir = test::PerTestDirectory("tofu_search_bad_");
  fs::create_directories(dir);
  fs::copy_file(kData / "dropout_base.yaml", dir / "dropout_base.yaml");
  test::WriteFile(dir / "bad.yaml", "name: bad\nbase: dropout_base.yaml\n"
                                    "objective: {expectations: [sensors.vio.delivered_samples]}\n"
                                    "space: {seed: [1, 5]}\nbudget: {simulations: 0}\n");
  const test::CommandResult bad = Tofu(fmt::format("search {} --out {}", test::Quote((dir / "bad.yaml").string()),
                                                   test::Quote((dir / "out").string())),
                                       dir);
  EXPECT_EQ(bad.exit_code, 2);
  EXPECT_NE(bad.err.find("bad.yaml:5:"), std::string::npos) << bad.err;
  EXPECT_NE(bad.err.find("budget.simulations"), std::string::npos) << bad.err;
  EXPECT_NE(bad.err.find("expected a whole number in [1, 1000000]"), std::string::npos) << bad.err;
  EXPECT_FALSE(fs::exists(dir / "out"));
  fs::remove_all(dir);
}

TEST(SearchCommand, ShardsMergeIntoOneSearch) {
  const fs::path dir = test::PerTestDirectory("tofu_search_shards_");
  fs::create_directories(dir);
  const std::string spec = (kData / "dropout_search.yaml").string();
  const std::string out = test::Quote((dir / "out").string());
  // The merge refuses while a shard has not flown, naming it.
  ASSERT_LE(Tofu(fmt::format("search {} --out {} --shard 0/2 --jobs 2 --no-renders --quiet", test::Quote(spec), out),
                 dir).exit_code, 1);
  const test::CommandResult early = Tofu(fmt::format("search {} --out {} --merge", test::Quote(spec), out), dir);
  EXPECT_EQ(early.exit_code, 2);
  EXPECT_NE(early.err.find("shard 1 of 2 is missing"), std::string::npos) << early.err;
  ASSERT_LE(Tofu(fmt::format("search {} --out {} --shard 1/2 --jobs 2 --no-renders --quiet", test::Quote(spec), out),
                 dir).exit_code, 1);
  const test::CommandResult merge = Tofu(fmt::format("search {} --out {} --merge --quiet", test::Quote(spec), out), dir);
  ASSERT_LE(merge.exit_code, 1) << merge.err;

  const auto read = [&](const fs::path& p) { return nlohmann::json::parse(test::ReadFile(p)); };
  const nlohmann::json s0 = read(dir / "out" / "shard_0000_of_0002" / "search.json");
  const nlohmann::json s1 = read(dir / "out" / "shard_0001_of_0002" / "search.json");
  const nlohmann::json merged = read(dir / "out" / "search.json");
  // Each shard: half the budget, its optimiser seeded apart.
  EXPECT_EQ(s0["budget"], 4);
  EXPECT_EQ(s1["optimizer_seed"].get<int>(), s0["optimizer_seed"].get<int>() + 1);
  EXPECT_EQ(merged["shards"], 2);
  EXPECT_EQ(merged["evaluations"].size(), s0["evaluations"].size() + s1["evaluations"].size());
  EXPECT_EQ(merged["evaluations"][0]["id"], "shard_0000_of_0002/e000000");
  // No two merged failures of one expectation lie within the dedupe distance.
  EXPECT_LE(merged["failures"].size(), s0["failures"].size() + s1["failures"].size());
  for (const nlohmann::json& f : merged["failures"]) {
    if (f["confirmed"].get<bool>()) {
      EXPECT_TRUE(fs::is_directory(dir / "out" / f["run_dir"].get<std::string>())) << f["run_dir"];
    }
  }
  EXPECT_EQ(merge.exit_code, merged["failures"].empty() ? 0 : 1);
  fs::remove_all(dir);
}

// A search flight flies only what its objective reads (ScenarioScope::kObjective); the
// objective's values must be those of the whole scenario, bit for bit.
TEST(SearchFlights, FlyOnlyWhatTheObjectiveReadsWithTheWholeScenariosValues) {
  const fs::path dir = test::PerTestDirectory("tofu_search_scope_");
  fs::create_directories(dir);
  const auto spec_for = [](const std::string& metric) {
    return Spec(fmt::format("name: scope\nbase: closed_loop_base.yaml\nobjective: {{expectations: [{}]}}\n"
                            "space: {{seed: [1, 9]}}\nbudget: {{simulations: 1}}\n",
                            metric));
  };
  const auto values = [&](const std::string& yaml, const std::string& name) {
    test::WriteFile(dir / (name + ".yaml"), yaml);
    const test::CommandResult run =
        Tofu(fmt::format("run {} --out {} --quiet --no-plots", test::Quote((dir / (name + ".yaml")).string()),
                         test::Quote((dir / name).string())),
             dir);
    EXPECT_LE(run.exit_code, 1) << run.err;
    std::map<std::string, double> v;
    const nlohmann::json summary = nlohmann::json::parse(test::ReadFile(dir / name / "summary.json"));
    for (const nlohmann::json& e : summary["expectations"]) {
      v[e["metric"].get<std::string>()] = e["value"].get<double>();
    }
    return v;
  };
  const campaign::SearchSpec whole_spec = spec_for("collisions.count");
  Setting s = campaign::BaseSetting(whole_spec);
  const std::map<std::string, double> whole = values(campaign::ScenarioYaml(whole_spec, s, "whole"), "whole");
  ASSERT_EQ(whole.size(), 4u);
  for (const std::string metric : {"closed_loop.naive.tracking_rmse_m", "methods.naive.ate_m", "collisions.count"}) {
    const campaign::SearchSpec spec = spec_for(metric);
    const std::string yaml = campaign::ScenarioYaml(spec, s, "scoped", {}, campaign::ScenarioScope::kObjective);
    const harness::Scenario scoped = harness::ParseScenario(yaml, "scoped.yaml");
    ASSERT_EQ(scoped.expect.size(), 1u) << metric;
    if (metric == "closed_loop.naive.tracking_rmse_m") {  // relative_to the consensus flight
      EXPECT_EQ(scoped.control->methods, (std::vector<std::string>{"consensus", "naive"}));
    } else if (metric == "methods.naive.ate_m") {
      EXPECT_FALSE(scoped.control.has_value());
      ASSERT_TRUE(scoped.estimation.has_value());
      EXPECT_EQ(scoped.estimation->methods.size(), 1u);
    } else {
      EXPECT_FALSE(scoped.estimation.has_value());
    }
    const std::map<std::string, double> got = values(yaml, "scoped_" + std::to_string(scoped.expect.size()) + metric);
    ASSERT_EQ(got.count(metric), 1u);
    EXPECT_EQ(got.at(metric), whole.at(metric)) << metric;
  }
  fs::remove_all(dir);
}

TEST(SearchCommand, ATerminatedSearchResumesWithTheSameResult) {
  const fs::path dir = test::PerTestDirectory("tofu_search_kill_");
  fs::create_directories(dir);
  const std::string spec = (kData / "dropout_search.yaml").string();
  const test::CommandResult whole = Tofu(fmt::format("search {} --out {} --jobs 2 --no-renders --quiet",
                                                     test::Quote(spec), test::Quote((dir / "whole").string())),
                                         dir);
  ASSERT_EQ(whole.exit_code, 1) << whole.err;

  const fs::path out = dir / "killed";
  test::ChildProcess search({TOFU_BINARY, "search", spec, "--out", out.string(), "--jobs", "2", "--no-renders"},
                            dir, dir / "killed.log");
  // Stopped (as Slurm stops a job) once some flights are journaled.
  const auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(60);
  while (std::chrono::steady_clock::now() < deadline) {
    std::error_code ec;
    if (fs::file_size(out / "evaluations.jsonl", ec) > 300 && !ec) break;
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
  }
  ::kill(search.pid(), SIGTERM);
  ASSERT_TRUE(search.Wait(std::chrono::seconds(60)).has_value());
  EXPECT_FALSE(fs::exists(out / "search.json"));

  const test::CommandResult resumed = Tofu(fmt::format("search {} --out {} --jobs 2 --no-renders",
                                                       test::Quote(spec), test::Quote(out.string())),
                                           dir);
  ASSERT_EQ(resumed.exit_code, 1) << resumed.err;
  EXPECT_EQ(test::ReadFile(out / "search.json"), test::ReadFile(dir / "whole" / "search.json"));
  EXPECT_EQ(test::ReadFile(out / "failures.md"), test::ReadFile(dir / "whole" / "failures.md"));
  fs::remove_all(dir);
}

}  // namespace
}  // namespace tofu
