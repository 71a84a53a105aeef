// `tofu check` as CI meets it: exit codes (0 every expectation held, 1 one failed, 2 bad
// input before anything runs), JUnit XML that a real parser (pugixml) reads with the right
// suites, cases and failures, expectations aggregated over seeds with pass_fraction, and
// renders listed as Jenkins attachments. Scenarios are short hovers written to a temp dir.

#include <sys/wait.h>
#include <unistd.h>

#include <gtest/gtest.h>
#include <pugixml.hpp>

#include <algorithm>
#include <chrono>
#include <csignal>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <optional>
#include <set>
#include <string>
#include <utility>
#include <vector>

#include <fmt/format.h>
#include <nlohmann/json.hpp>

#include "core/error.h"
#include "campaign/check_command.h"
#include "harness/scenario.h"
#include "harness/yaml_reader.h"
#include "tests/test_support.h"

namespace tofu {
namespace {

namespace fs = std::filesystem;
using test::ReadFile;
using test::WriteFile;
using test::Quote;
using campaign::AggregateExpectation;
using campaign::CheckJUnitXml;
using campaign::EvaluateScenarioCheck;
using campaign::RequiredPasses;
using campaign::SeedOutcome;
using campaign::SeedRun;


// A 3 s hover in the indoor arena with light gusts (so that seeds differ) and the given
// expect: entries (YAML flow maps, one per line).
std::string HoverScenario(const std::string& name, const std::vector<std::string>& expect) {
  std::string yaml = "name: " + name +
                     "\n"
                     "world: indoor_arena\n"
                     "duration_s: 3\n"
                     "seed: 1\n"
                     "trajectory:\n"
                     "  start: {position_m: [0, 0, 1.5]}\n"
                     "  segments:\n"
                     "    - hover: {duration_s: 3}\n"
                     "wind:\n"
                     "  gust_std_mps: 0.3\n"
                     "expect:\n";
  for (const std::string& e : expect) yaml += "  - " + e + "\n";
  return yaml;
}

using Result = test::CommandResult;

class CheckCommandTest : public ::testing::Test {
 protected:
  void SetUp() override {
    root_ = test::PerTestDirectory("tofu_check_test_");
    scenarios_ = root_ / "scenarios";
    out_ = root_ / "out";
    junit_ = root_ / "junit.xml";
    fs::create_directories(scenarios_);
  }
  void TearDown() override {
    if (!HasFailure()) fs::remove_all(root_);
  }

  // Runs `tofu check <args> --out out_ --junit junit_`, capturing stdout and stderr.
  Result Check(const std::string& args) {
    const fs::path out = root_ / "stdout.txt";
    const fs::path err = root_ / "stderr.txt";
    const std::string command = Quote(TOFU_BINARY) + " check " + args + " --out " +
                                Quote(out_.string()) + " --junit " + Quote(junit_.string()) +
                                " >" + Quote(out.string()) + " 2>" + Quote(err.string());
    const int status = std::system(command.c_str());
    Result r;
    EXPECT_TRUE(WIFEXITED(status)) << command;
    r.exit_code = WIFEXITED(status) ? WEXITSTATUS(status) : -1;
    r.out = ReadFile(out);
    r.err = ReadFile(err);
    return r;
  }

  // The JUnit file, parsed; fails the test if it does not parse.
  pugi::xml_document JUnit() {
    pugi::xml_document doc;
    const pugi::xml_parse_result parsed = doc.load_file(junit_.c_str());
    EXPECT_TRUE(parsed) << junit_ << ": " << parsed.description();
    return doc;
  }

  fs::path root_, scenarios_, out_, junit_;
};

pugi::xml_node Suite(const pugi::xml_document& doc, const std::string& name) {
  return doc.child("testsuites").find_child_by_attribute("testsuite", "name", name.c_str());
}

size_t Count(const pugi::xml_node& node, const char* xpath) {
  return node.select_nodes(xpath).size();
}

// ---- the CLI end to end ----

TEST_F(CheckCommandTest, PassingScenariosExitZeroWithCleanJUnit) {
  WriteFile(scenarios_ / "b_hover.yaml",
            HoverScenario("b_hover", {"{metric: collisions.count, max: 0}",
                                      "{metric: tracking.position_max_m, max: 0.5, "
                                      "window_s: [1, 3], pass_fraction: 1}"}));
  WriteFile(scenarios_ / "a_hover.yaml",
            HoverScenario("a_hover", {"{metric: collisions.count, max: 0}"}));
  WriteFile(scenarios_ / "notes.txt", "not a scenario");
  const Result r = Check(Quote(scenarios_.string()) + " --jobs 2");
  ASSERT_EQ(r.exit_code, 0) << r.out << r.err;

  const pugi::xml_document doc = JUnit();
  const pugi::xml_node suites = doc.child("testsuites");
  EXPECT_EQ(Count(suites, "testsuite"), 2u);
  // Suites in sorted file order; each has its expectations plus the "run" case.
  EXPECT_STREQ(suites.first_child().attribute("name").value(), "a_hover");
  EXPECT_EQ(Suite(doc, "a_hover").attribute("tests").as_int(), 2);
  EXPECT_EQ(Count(Suite(doc, "a_hover"), "testcase"), 2u);
  EXPECT_EQ(Suite(doc, "b_hover").attribute("tests").as_int(), 3);
  EXPECT_EQ(Count(Suite(doc, "b_hover"), "testcase"), 3u);
  EXPECT_TRUE(Suite(doc, "b_hover")
                  .find_child_by_attribute("testcase", "name",
                                           "tracking.position_max_m [1, 3] s <= 0.5"));
  EXPECT_EQ(Count(suites, "//failure"), 0u);
  EXPECT_EQ(suites.attribute("failures").as_int(), 0);
  EXPECT_EQ(suites.attribute("tests").as_int(), 5);

  // One run directory per scenario and seed, with the log beside it.
  EXPECT_TRUE(fs::is_regular_file(out_ / "a_hover" / "seed_1" / "summary.json"));
  EXPECT_TRUE(fs::is_regular_file(out_ / "b_hover" / "seed_1.log"));
  EXPECT_CONTAINS(r.out, "a_hover");
  EXPECT_CONTAINS(r.out, "pass");
  // No estimation block, no method table.
  EXPECT_FALSE(fs::exists(out_ / "methods.md"));
  EXPECT_FALSE(fs::exists(out_ / "methods.csv"));
  EXPECT_EQ(r.out.find("method table"), std::string::npos) << r.out;
}

TEST_F(CheckCommandTest, EstimationMethodsAreTabulatedOverTheSeeds) {
  // Methods listed out of name order: the table keeps the scenario's order.
  std::string yaml = HoverScenario("est_hover", {"{metric: collisions.count, max: 0}"});
  yaml += "sensors:\n  imu: {}\n  vio: {}\n"
          "estimation:\n  methods: [oracle, naive, \"single:vio\"]\n";
  WriteFile(scenarios_ / "b_est_hover.yaml", yaml);
  WriteFile(scenarios_ / "a_plain.yaml",
            HoverScenario("a_plain", {"{metric: collisions.count, max: 0}"}));
  const Result r = Check(Quote(scenarios_.string()) + " --seeds 2 --jobs 2");
  ASSERT_EQ(r.exit_code, 0) << r.out << r.err;
  EXPECT_CONTAINS(r.out, "method table: " + (out_ / "methods.md").string() + "\n");

  const std::string md = ReadFile(out_ / "methods.md");
  EXPECT_CONTAINS(md, "## est_hover (2 seeds)");
  EXPECT_EQ(md.find("a_plain"), std::string::npos) << "a scenario without methods: " << md;
  const size_t oracle = md.find("\n| oracle | ");
  const size_t naive = md.find("\n| naive | ");
  const size_t single = md.find("\n| single:vio | ");
  ASSERT_NE(oracle, std::string::npos) << md;
  EXPECT_LT(oracle, naive) << md;
  EXPECT_LT(naive, single) << md;
  // Each seed's ATE from its summary.json: the CSV's median and worst are theirs.
  std::vector<double> ates;
  for (const uint64_t seed : {1, 2}) {
    const auto summary = nlohmann::json::parse(
        ReadFile(out_ / "est_hover" / fmt::format("seed_{}", seed) / "summary.json"));
    ates.push_back(summary["methods"]["naive"]["ate_m"].get<double>());
  }
  const std::string csv = ReadFile(out_ / "methods.csv");
  EXPECT_EQ(csv.rfind("#scenario,method,metric,seeds,median,worst\n", 0), 0u) << csv;
  EXPECT_CONTAINS(csv, fmt::format("est_hover,naive,ate_m,2,{},{}\n",
                                   core::FormatDouble(0.5 * (ates[0] + ates[1])),
                                   core::FormatDouble(std::max(ates[0], ates[1]))));
  EXPECT_CONTAINS(csv, "est_hover,oracle,ate_over_oracle,2,1,1\n");
}

TEST_F(CheckCommandTest, ImpossibleExpectationExitsOneWithFailureNamingTheMetric) {
  const fs::path file = scenarios_ / "impossible.yaml";
  WriteFile(file, HoverScenario("impossible", {"{metric: collisions.count, max: 0}",
                                               "{metric: collisions.count, min: 1}"}));
  const Result r = Check(Quote(file.string()) + " --jobs 1");
  ASSERT_EQ(r.exit_code, 1) << r.out << r.err;
  EXPECT_CONTAINS(r.out, "collisions.count >= 1");
  EXPECT_CONTAINS(r.out, file.string() + ":13");

  const pugi::xml_document doc = JUnit();
  const pugi::xml_node suite = Suite(doc, "impossible");
  EXPECT_EQ(suite.attribute("failures").as_int(), 1);
  const pugi::xpath_node_set failures = doc.select_nodes("//failure");
  ASSERT_EQ(failures.size(), 1u);
  const pugi::xml_node testcase = failures.first().node().parent();
  EXPECT_STREQ(testcase.attribute("name").value(), "collisions.count >= 1");
  EXPECT_EQ(testcase.attribute("line").as_int(), 13);
  EXPECT_CONTAINS(failures.first().node().attribute("message").value(), "collisions.count");
  EXPECT_CONTAINS(failures.first().node().attribute("message").value(), "held in 0 of 1 seeds");
  EXPECT_CONTAINS(failures.first().node().text().get(), "seed 1: 0 (not held)");
  // The run itself worked.
  EXPECT_FALSE(suite.find_child_by_attribute("testcase", "name", "run").child("failure"));
}

TEST_F(CheckCommandTest, SeedsAggregateWithPassFraction) {
  // First learn how the metric spreads over seeds 1..3 (gusts differ per seed) ...
  const std::string metric = "tracking.position_max_m";
  const fs::path file = scenarios_ / "gusty.yaml";
  WriteFile(file, HoverScenario("gusty", {"{metric: " + metric + ", min: 0}"}));
  ASSERT_EQ(Check(Quote(file.string()) + " --seeds 3 --jobs 2").exit_code, 0);
  std::vector<double> values;
  for (int seed = 1; seed <= 3; ++seed) {
    const nlohmann::json summary = nlohmann::json::parse(
        ReadFile(out_ / "gusty" / ("seed_" + std::to_string(seed)) / "summary.json"));
    EXPECT_EQ(summary["seed"].get<int>(), seed);
    values.push_back(summary["expectations"][0]["value"].get<double>());
  }
  std::vector<double> sorted = values;
  std::sort(sorted.begin(), sorted.end());
  ASSERT_LT(sorted[0], sorted[1]);
  ASSERT_LT(sorted[1], sorted[2]) << "seeds must differ for this test to mean anything";

  // ... then bound it between the middle and the largest value: it holds in exactly 2 of
  // the 3 seeds.
  const std::string bound =
      "{metric: " + metric + ", max: " + fmt::format("{:.17g}", (sorted[1] + sorted[2]) / 2);
  WriteFile(file, HoverScenario("gusty", {bound + ", pass_fraction: 0.6}",
                                          bound + ", pass_fraction: 1}", bound + "}"}));
  const Result r = Check(Quote(file.string()) + " --seeds 3 --jobs 2");
  EXPECT_EQ(r.exit_code, 1) << r.out << r.err;
  const pugi::xml_document doc = JUnit();
  const pugi::xml_node suite = Suite(doc, "gusty");
  EXPECT_STREQ(suite.child("properties")
                   .find_child_by_attribute("property", "name", "seeds")
                   .attribute("value")
                   .value(),
               "1,2,3");
  const pugi::xpath_node_set cases = suite.select_nodes("testcase[@name!='run']");
  ASSERT_EQ(cases.size(), 3u);
  EXPECT_FALSE(cases[0].node().child("failure")) << "0.6 of 3 seeds needs 2, and 2 held";
  ASSERT_TRUE(cases[1].node().child("failure"));
  ASSERT_TRUE(cases[2].node().child("failure")) << "pass_fraction defaults to 1";
  const std::string message = cases[1].node().child("failure").attribute("message").value();
  EXPECT_CONTAINS(message, "held in 2 of 3 seeds, needs 3");
  for (int seed = 1; seed <= 3; ++seed) EXPECT_CONTAINS(message, "seed " + std::to_string(seed));
  EXPECT_EQ(suite.attribute("failures").as_int(), 2);
}

TEST_F(CheckCommandTest, MalformedExpectationIsBadInputBeforeAnythingRuns) {
  WriteFile(scenarios_ / "good.yaml",
            HoverScenario("good", {"{metric: collisions.count, max: 0}"}));
  struct Case {
    std::string entry;
    std::string says;
  };
  const std::vector<Case> cases = {
      {"{metric: collisions.cuont, max: 0}", "unknown metric 'collisions.cuont'"},
      {"{metric: collisions.count, max: 0, pass_fraction: 1.5}", "pass_fraction"},
      {"{metric: collisions.count, max: 0, pass_fraction: 0}", "in (0, 1]"},
      {"{metric: collisions.count, max: 0, pass_fraction: most}", "pass_fraction"},
  };
  for (const Case& c : cases) {
    SCOPED_TRACE(c.entry);
    const fs::path bad = scenarios_ / "zz_bad.yaml";
    WriteFile(bad, HoverScenario("zz_bad", {"{metric: collisions.count, max: 0}", c.entry}));
    const Result r = Check(Quote(scenarios_.string()) + " --jobs 2");
    EXPECT_EQ(r.exit_code, 2) << r.out << r.err;
    EXPECT_CONTAINS(r.err, bad.string() + ":13:");
    EXPECT_CONTAINS(r.err, c.says);
    EXPECT_FALSE(fs::exists(out_)) << "nothing may run on bad input";
    EXPECT_FALSE(fs::exists(junit_));
  }
  // Bad paths and options are bad input too.
  EXPECT_EQ(Check(Quote((scenarios_ / "missing.yaml").string())).exit_code, 2);
  fs::remove(scenarios_ / "zz_bad.yaml");
  EXPECT_EQ(Check(Quote(scenarios_.string()) + " --seeds 0").exit_code, 2);
  EXPECT_FALSE(fs::exists(out_));
}

TEST_F(CheckCommandTest, DuplicateScenarioNamesAreBadInput) {
  WriteFile(scenarios_ / "one.yaml", HoverScenario("same", {"{metric: collisions.count, max: 0}"}));
  WriteFile(scenarios_ / "two.yaml", HoverScenario("same", {"{metric: collisions.count, max: 0}"}));
  const Result r = Check(Quote(scenarios_.string()));
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_CONTAINS(r.err, "scenario name 'same'");
  EXPECT_FALSE(fs::exists(out_));
}

// A scenario whose world model is missing passed `tofu check`'s validation and failed in
// every run (issue 19, finding 8): now it is bad input before anything runs.
TEST_F(CheckCommandTest, AMissingWorldModelIsBadInputBeforeAnythingRuns) {
  std::string text = HoverScenario("lost", {"{metric: collisions.count, max: 0}"});
  text.replace(text.find("indoor_arena"), std::string("indoor_arena").size(), "lost_world");
  const fs::path file = scenarios_ / "lost.yaml";
  WriteFile(file, text);
  const Result r = Check(Quote(file.string()));
  EXPECT_EQ(r.exit_code, 2) << r.out << r.err;
  EXPECT_CONTAINS(r.err, file.string() + ":2:");
  EXPECT_CONTAINS(r.err, "key 'world'");
  EXPECT_CONTAINS(r.err, "lost_world.xml");
  EXPECT_FALSE(fs::exists(out_)) << "nothing may run on bad input";
}

// SIGTERM to `tofu check` while one run writes its staging directory and another flies
// (issue 19, finding 7): before, the check died and its runs went on writing in the
// background. Now it forwards the signal, waits for every run to remove its staging
// directory and stop, writes no JUnit and exits 143.
TEST_F(CheckCommandTest, SigtermStopsEveryRunWaitsForThemAndLeavesNoStaging) {
  // Hovers with sensors: a minute (~2 s of flight, then ~0.5 s writing its staging
  // directory, when the signal comes) and an hour (still flying then).
  for (const auto& [name, duration] : {std::pair<std::string, std::string>{"minute", "60"},
                                       std::pair<std::string, std::string>{"hour", "3600"}}) {
    std::string text = HoverScenario(name, {"{metric: collisions.count, max: 0}"});
    text.replace(text.find("duration_s: 3\n"), std::string("duration_s: 3\n").size(),
                 "duration_s: " + duration + "\nsensors:\n  imu: {}\n  vio: {}\n  lio: {type: lidar_odometry}\n");
    WriteFile(scenarios_ / (name + ".yaml"), text);
  }
  test::ChildProcess check({TOFU_BINARY, "check", scenarios_.string(), "--jobs", "2", "--out",
                            out_.string(), "--junit", junit_.string()},
                           root_, root_ / "check.log");
  std::vector<pid_t> runs;
  ASSERT_TRUE(test::WaitUntil(
      [&] {
        runs = test::ChildrenOf(check.pid());
        return runs.size() == 2 || check.Exited();
      },
      std::chrono::minutes(2)))
      << ReadFile(root_ / "check.log");
  const auto staging_of_the_minute = [&] {
    std::error_code ec;
    for (const auto& entry : fs::directory_iterator(out_ / "minute", ec)) {
      if (entry.path().filename().string().starts_with("seed_1.tmp-")) return true;
    }
    return false;
  };
  ASSERT_TRUE(test::WaitUntil([&] { return staging_of_the_minute() || check.Exited(); },
                              std::chrono::minutes(5)));
  ASSERT_FALSE(check.Exited()) << ReadFile(root_ / "check.log");
  ASSERT_EQ(::kill(check.pid(), SIGTERM), 0);
  const std::optional<int> status = check.Wait(std::chrono::minutes(2));
  std::vector<pid_t> outlived;
  for (const pid_t run : runs) {
    if (test::ProcessExists(run)) outlived.push_back(run);
  }
  // Whatever happened, no run of this test outlives it.
  for (const pid_t run : outlived) ::kill(run, SIGKILL);
  ASSERT_TRUE(status.has_value()) << "check still running 2 min after SIGTERM";
  EXPECT_TRUE(WIFEXITED(*status)) << "ended by signal " << WTERMSIG(*status)
                                  << " instead of exiting after stopping its runs";
  if (WIFEXITED(*status)) {
    EXPECT_EQ(WEXITSTATUS(*status), 128 + SIGTERM);
  }
  EXPECT_TRUE(outlived.empty()) << outlived.size() << " runs outlived the check";
  // Nothing staged is left, nothing looks like a complete run, no JUnit of a partial check.
  for (const auto& entry : fs::recursive_directory_iterator(root_)) {
    EXPECT_EQ(entry.path().filename().string().find(".tmp-"), std::string::npos) << entry.path();
    EXPECT_NE(entry.path().filename().string(), ".tofu-run") << entry.path();
  }
  EXPECT_FALSE(fs::exists(junit_));
  EXPECT_CONTAINS(ReadFile(root_ / "check.log"), "interrupted by SIGTERM");
  // Each run was given the signal and cleaned up (rather than being killed).
  for (const char* name : {"minute", "hour"}) {
    EXPECT_CONTAINS(ReadFile(out_ / name / "seed_1.log"), "interrupted by SIGTERM");
  }
}

// A stand-in for `tofu run` (RunCheckCommand's tofu_binary): a shell script given
// `run SCENARIO --seed S --out DIR --quiet --force`, so that failures that a real scenario cannot
// produce on demand (a crashed simulation, renders) are checked end to end.
fs::path FakeTofu(const fs::path& dir, const std::string& body) {
  const fs::path script = dir / "fake_tofu.sh";
  WriteFile(script, "#!/bin/sh\nseed=\"$4\"\nout=\"$6\"\n" + body);
  fs::permissions(script, fs::perms::owner_all);
  return script;
}

TEST_F(CheckCommandTest, FailedSimulationExitsThreeAndFailsTheRunCase) {
  const fs::path file = scenarios_ / "crash.yaml";
  WriteFile(file, HoverScenario("crash", {"{metric: collisions.count, max: 0}"}));
  campaign::CheckCommandOptions options;
  options.inputs = {file.string()};
  options.seeds = 2;
  options.out_dir = out_.string();
  options.junit_path = junit_.string();
  options.quiet = true;
  // Seed 2 crashes (exit 3, no run directory); seed 1 is killed by a signal.
  options.tofu_binary = FakeTofu(root_,
                                 "if [ \"$seed\" = 2 ]; then\n"
                                 "  echo 'tofu: error: MuJoCo bad state (simulated)' >&2; exit 3\n"
                                 "fi\n"
                                 "kill -KILL $$\n")
                            .string();
  EXPECT_EQ(campaign::RunCheckCommand(options), 3);
  const pugi::xml_document doc = JUnit();
  const pugi::xml_node run = Suite(doc, "crash").find_child_by_attribute("testcase", "name", "run");
  ASSERT_TRUE(run.child("failure"));
  EXPECT_STREQ(run.child("failure").attribute("message").value(), "2 of 2 runs failed");
  const std::string text = run.child("failure").text().get();
  EXPECT_CONTAINS(text, "seed 2: simulation failed (exit 3):\ntofu: error: MuJoCo bad state");
  EXPECT_CONTAINS(text, "seed 1: killed by signal 9");
  EXPECT_CONTAINS(text, (out_ / "crash" / "seed_2.log").string());
  // Its expectation did not hold in a seed without a summary.
  EXPECT_TRUE(Suite(doc, "crash")
                  .find_child_by_attribute("testcase", "name", "collisions.count <= 0")
                  .child("failure"));
}

TEST_F(CheckCommandTest, RendersOfFailingRunsAreAttached) {
  const fs::path file = scenarios_ / "rendered.yaml";
  WriteFile(file, HoverScenario("rendered", {"{metric: collisions.count, max: 0}"}));
  campaign::CheckCommandOptions options;
  options.inputs = {file.string()};
  options.out_dir = out_.string();
  options.junit_path = junit_.string();
  options.quiet = true;
  // A run whose expectation failed and that rendered the failure event.
  options.tofu_binary = FakeTofu(
      root_,
      "mkdir -p \"$out/renders\"\n"
      "echo png > \"$out/renders/collision_000.png\"\n"
      "echo mp4 > \"$out/renders/collision.mp4\"\n"
      "echo '{\"expectations\": [{\"metric\": \"collisions.count\", \"value\": 1, "
      "\"passed\": false}], \"passed\": false}' > \"$out/summary.json\"\n"
      "exit 1\n").string();
  EXPECT_EQ(campaign::RunCheckCommand(options), 1);
  const pugi::xml_document doc = JUnit();
  const pugi::xml_node failed =
      Suite(doc, "rendered").find_child_by_attribute("testcase", "name", "collisions.count <= 0");
  ASSERT_TRUE(failed.child("failure"));
  const std::string renders = (out_ / "rendered" / "seed_1" / "renders").string();
  EXPECT_CONTAINS(failed.child("system-out").text().get(),
                  "[[ATTACHMENT|" + renders + "/collision.mp4]]\n[[ATTACHMENT|" + renders +
                      "/collision_000.png]]\n");
  EXPECT_FALSE(Suite(doc, "rendered")
                   .find_child_by_attribute("testcase", "name", "run")
                   .child("failure"));
}

// ---- aggregation and JUnit as units ----

TEST(CheckAggregation, RequiredPassesIsCeilingOfFractionTimesSeeds) {
  EXPECT_EQ(RequiredPasses(1.0, 1), 1);
  EXPECT_EQ(RequiredPasses(0.01, 1), 1);  // one seed: it must hold
  EXPECT_EQ(RequiredPasses(0.9, 10), 9);
  EXPECT_EQ(RequiredPasses(0.7, 10), 7);  // 0.7 * 10 = 7.000000000000001 in doubles
  EXPECT_EQ(RequiredPasses(0.71, 10), 8);
  EXPECT_EQ(RequiredPasses(0.5, 3), 2);
  EXPECT_EQ(RequiredPasses(1.0 / 3.0, 3), 1);
  EXPECT_EQ(RequiredPasses(0.34, 3), 2);
  EXPECT_EQ(RequiredPasses(1.0, 3), 3);
}

harness::Expectation MaxExpectation(double max, double pass_fraction) {
  harness::Expectation e;
  e.metric = "tracking.position_max_m";
  e.max = max;
  e.pass_fraction = pass_fraction;
  e.location = {"s.yaml", 7, 5};
  return e;
}

TEST(CheckAggregation, ExpectationPassesWhenItHeldInEnoughSeeds) {
  const std::vector<SeedOutcome> two_of_three = {{1, 0.1, true, ""}, {2, 0.3, false, ""}, {3, 0.2, true, ""}};
  const auto a = AggregateExpectation(MaxExpectation(0.25, 0.6), two_of_three);
  EXPECT_EQ(a.held, 2);
  EXPECT_EQ(a.required, 2);
  EXPECT_TRUE(a.passed);
  const auto b = AggregateExpectation(MaxExpectation(0.25, 0.7), two_of_three);
  EXPECT_EQ(b.required, 3);
  EXPECT_FALSE(b.passed);
  EXPECT_FALSE(AggregateExpectation(MaxExpectation(0.25, 0.5), {}).passed) << "no seeds, no pass";
}

// A run as `tofu run` leaves it: its expectation results and, optionally, methods.
SeedRun FakeRun(uint64_t seed, int exit_code, std::optional<double> value, bool held,
                nlohmann::json methods = nullptr) {
  SeedRun r;
  r.seed = seed;
  r.exit_code = exit_code;
  r.run_dir = "/nonexistent/seed_" + std::to_string(seed);
  r.summary = {{"expectations",
                {{{"metric", "tracking.position_max_m"},
                  {"value", value ? nlohmann::json(*value) : nlohmann::json(nullptr)},
                  {"passed", held}}}}};
  if (!methods.is_null()) r.summary["methods"] = methods;
  return r;
}

TEST(CheckAggregation, ScenarioCheckReadsSummariesAndMethods) {
  harness::Scenario scenario;
  scenario.name = "s";
  scenario.expect = {MaxExpectation(0.25, 0.6)};
  const nlohmann::json m1 = {{"consensus", {{"ate_m", 0.1}, {"faults", 2}, {"faults_detected", 1}}},
                             {"naive", {{"ate_m", 0.5}}}};
  const nlohmann::json m2 = {{"consensus", {{"ate_m", 0.3}, {"faults", 2}, {"faults_detected", 2}}},
                             {"naive", {{"ate_m", nullptr}}}};
  std::vector<SeedRun> runs = {FakeRun(1, 0, 0.1, true, m1), FakeRun(2, 1, 0.3, false, m2),
                               FakeRun(3, 0, 0.2, true)};
  const campaign::ScenarioCheck c = EvaluateScenarioCheck(scenario, runs);
  ASSERT_EQ(c.expectations.size(), 1u);
  EXPECT_EQ(c.expectations[0].held, 2);
  EXPECT_TRUE(c.expectations[0].passed);
  EXPECT_EQ(c.seeds_passed, 2);
  EXPECT_TRUE(c.runs_ok);
  EXPECT_TRUE(c.passed);
  ASSERT_EQ(c.methods.size(), 2u);
  EXPECT_EQ(c.methods[0].method, "consensus");
  EXPECT_NEAR(*c.methods[0].ate_mean_m, 0.2, 1e-12);
  EXPECT_EQ(c.methods[0].faults, 4);
  EXPECT_EQ(c.methods[0].faults_detected, 3);
  EXPECT_EQ(c.methods[1].method, "naive");
  EXPECT_NEAR(*c.methods[1].ate_mean_m, 0.5, 1e-12);
  EXPECT_FALSE(c.methods[1].has_detections);

  // A simulation failure: its seed does not count as held and the scenario fails.
  runs[2].exit_code = core::kExitSimulationError;
  runs[2].error = "simulation failed (exit 3)";
  runs[2].summary = nullptr;
  const campaign::ScenarioCheck failed = EvaluateScenarioCheck(scenario, runs);
  EXPECT_EQ(failed.expectations[0].held, 1);
  EXPECT_FALSE(failed.runs_ok);
  EXPECT_FALSE(failed.passed);

  // A summary whose expectations do not line up with the scenario's is not trusted.
  runs[0].summary["expectations"][0]["metric"] = "collisions.count";
  EXPECT_EQ(EvaluateScenarioCheck(scenario, runs).expectations[0].held, 0);
}

TEST(CheckAggregation, ClosedLoopFlightsAreAggregatedOverTheSeeds) {
  harness::Scenario scenario;
  scenario.name = "s";
  scenario.expect = {MaxExpectation(0.25, 0.6)};
  std::vector<SeedRun> runs = {FakeRun(1, 0, 0.1, true), FakeRun(2, 0, 0.1, true)};
  runs[0].summary["closed_loop"] = {
      {"consensus", {{"tracking_rmse_m", 0.02}, {"collisions", 0}, {"failsafe_events", 0}}},
      {"naive", {{"tracking_rmse_m", 0.8}, {"collisions", 1}, {"failsafe_events", 0}}}};
  runs[1].summary["closed_loop"] = {
      {"consensus", {{"tracking_rmse_m", 0.04}, {"collisions", 0}, {"failsafe_events", 1}}},
      {"naive", {{"tracking_rmse_m", nullptr}, {"collisions", 2}, {"failsafe_events", 0}}}};
  const campaign::ScenarioCheck c = EvaluateScenarioCheck(scenario, runs);
  ASSERT_EQ(c.closed_loop.size(), 2u);
  EXPECT_EQ(c.closed_loop[0].method, "consensus");
  EXPECT_NEAR(*c.closed_loop[0].tracking_rmse_mean_m, 0.03, 1e-12);
  EXPECT_EQ(c.closed_loop[0].failsafe_events, 1);
  EXPECT_EQ(c.closed_loop[1].method, "naive");
  EXPECT_NEAR(*c.closed_loop[1].tracking_rmse_mean_m, 0.8, 1e-12);  // seed 2 had none
  EXPECT_EQ(c.closed_loop[1].collisions, 3);
  EXPECT_EQ(c.closed_loop[1].seeds, 2);
}

TEST(CheckJUnit, EscapesTextAndAttachesRendersOfFailedSeeds) {
  const fs::path root = fs::path(::testing::TempDir()) /
                        ("tofu_check_junit_" + std::to_string(::getpid()));
  fs::remove_all(root);
  fs::create_directories(root / "seed_2" / "renders" / "event_0");
  WriteFile(root / "seed_2" / "renders" / "event_0" / "frame & <1>.png", "png");
  WriteFile(root / "seed_2" / "renders" / "collision.mp4", "mp4");
  WriteFile(root / "seed_2" / "renders" / "notes.txt", "not a render");

  harness::Scenario scenario;
  scenario.name = "s";
  scenario.source_file = "dir/\"quoted\" & s.yaml";
  scenario.expect = {MaxExpectation(0.25, 1.0)};
  scenario.expect[0].location.file = scenario.source_file;
  std::vector<SeedRun> runs = {FakeRun(1, 0, 0.1, true), FakeRun(2, 1, 0.3, false)};
  runs[1].run_dir = (root / "seed_2").string();
  runs[1].wall_time_s = 1.5;
  const std::string xml = CheckJUnitXml({EvaluateScenarioCheck(scenario, runs)});

  pugi::xml_document doc;
  ASSERT_TRUE(doc.load_string(xml.c_str())) << xml;
  const pugi::xml_node suite = doc.child("testsuites").child("testsuite");
  EXPECT_STREQ(suite.attribute("file").value(), "dir/\"quoted\" & s.yaml");
  EXPECT_EQ(suite.attribute("tests").as_int(), 2);
  EXPECT_EQ(suite.attribute("failures").as_int(), 1);
  const pugi::xml_node failed = suite.find_child_by_attribute(
      "testcase", "name", "tracking.position_max_m <= 0.25");
  ASSERT_TRUE(failed.child("failure")) << xml;
  const std::string out = failed.child("system-out").text().get();
  const std::string renders = (root / "seed_2" / "renders").string();
  EXPECT_CONTAINS(out, "[[ATTACHMENT|" + renders + "/collision.mp4]]\n[[ATTACHMENT|" + renders +
                           "/event_0/frame & <1>.png]]");
  EXPECT_EQ(out.find("notes.txt"), std::string::npos);
  EXPECT_EQ(out.find("seed 1"), std::string::npos) << "seed 1 held: nothing to attach";
  EXPECT_CONTAINS(failed.child("failure").text().get(), "seed 2: 0.3 (not held)");
  EXPECT_DOUBLE_EQ(suite.attribute("time").as_double(), 1.5);

  // Characters XML cannot hold do not break the document.
  EXPECT_EQ(campaign::XmlEscape("a\x01<b>\n", true), "a?&lt;b&gt;&#10;");
  EXPECT_EQ(campaign::XmlEscape("'\"&\t\n", false), "&apos;&quot;&amp;\t\n");
  fs::remove_all(root);
}

}  // namespace
}  // namespace tofu
