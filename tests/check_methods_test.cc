// `tofu check`'s method table (campaign/check_methods.h) on hand-made summaries: median
// (of an even count too) and worst per metric, nulls skipped, the ATE over the oracle's per
// seed, the method order of the scenario, the +inf of missed faults and of sensors never
// re-admitted (null in summary.json), and the exact CSV and markdown text; then the files
// WriteCheckMethods leaves in a check directory.

#include <gtest/gtest.h>

#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <limits>
#include <optional>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "campaign/check_command.h"
#include "campaign/check_methods.h"
#include "harness/scenario.h"
#include "tests/test_support.h"

namespace tofu {
namespace {

namespace fs = std::filesystem;
using campaign::AggregateMethodTables;
using campaign::AggregateScenarioMethods;
using campaign::MethodMetricSummary;
using campaign::MethodsCsv;
using campaign::MethodsMarkdown;
using campaign::MethodTableRow;
using campaign::ScenarioCheck;
using campaign::ScenarioMethodTable;
using campaign::SeedRun;
using nlohmann::json;

constexpr double kInf = std::numeric_limits<double>::infinity();

SeedRun FakeRun(uint64_t seed, json methods, double simulated_s = 90.0) {
  SeedRun r;
  r.seed = seed;
  r.exit_code = 0;
  r.summary = {{"simulated_s", simulated_s}, {"methods", std::move(methods)}};
  return r;
}

const MethodTableRow& Row(const ScenarioMethodTable& t, const std::string& method) {
  for (const MethodTableRow& row : t.methods) {
    if (row.method == method) return row;
  }
  ADD_FAILURE() << "no method " << method;
  static const MethodTableRow none;
  return none;
}

const MethodMetricSummary& Metric(const ScenarioMethodTable& t, const std::string& method,
                                  const std::string& metric) {
  const MethodMetricSummary* m = Row(t, method).Find(metric);
  if (m == nullptr) {
    ADD_FAILURE() << "no metric " << metric << " of " << method;
    static const MethodMetricSummary none;
    return none;
  }
  return *m;
}

std::vector<std::string> Methods(const ScenarioMethodTable& t) {
  std::vector<std::string> names;
  for (const MethodTableRow& row : t.methods) names.push_back(row.method);
  return names;
}

TEST(CheckMethods, MedianOfAnEvenCountAndWorstOverTheSeeds) {
  std::vector<SeedRun> runs;
  const double ates[] = {0.1, 0.4, 0.2, 0.3};
  const double valid[] = {1.0, 0.9, 0.95, 1.0};
  for (int i = 0; i < 4; ++i) {
    runs.push_back(FakeRun(i + 1, {{"naive", {{"ate_m", ates[i]}, {"valid_fraction", valid[i]},
                                          {"rotation_rmse_deg", 1.0 + i}}}}));
  }
  const ScenarioMethodTable t = AggregateScenarioMethods("s", {"naive"}, runs);
  EXPECT_EQ(t.scenario, "s");
  EXPECT_EQ(t.seeds, 4);
  const MethodMetricSummary& ate = Metric(t, "naive", "ate_m");
  EXPECT_EQ(ate.seeds, 4);
  EXPECT_NEAR(*ate.median, 0.25, 1e-12) << "even count: the mean of the middle two";
  EXPECT_DOUBLE_EQ(*ate.worst, 0.4);
  const MethodMetricSummary& rot = Metric(t, "naive", "rotation_rmse_deg");
  EXPECT_DOUBLE_EQ(*rot.median, 2.5);
  EXPECT_DOUBLE_EQ(*rot.worst, 4.0);
  const MethodMetricSummary& v = Metric(t, "naive", "valid_fraction");
  EXPECT_DOUBLE_EQ(*v.median, 0.975);
  EXPECT_DOUBLE_EQ(*v.worst, 0.9) << "valid_fraction: the worst seed is the smallest";
  // Every metric listed, in table order; no oracle, no ratio.
  ASSERT_EQ(Row(t, "naive").metrics.size(), campaign::kMethodTableMetrics.size());
  for (size_t i = 0; i < campaign::kMethodTableMetrics.size(); ++i) {
    EXPECT_EQ(Row(t, "naive").metrics[i].metric, campaign::kMethodTableMetrics[i]);
  }
  EXPECT_EQ(Row(t, "naive").Find("ate_over_oracle"), nullptr);
}

TEST(CheckMethods, OddCountMedianIsTheMiddleValue) {
  std::vector<SeedRun> runs = {FakeRun(1, {{"m", {{"ate_m", 3.0}}}}), FakeRun(2, {{"m", {{"ate_m", 1.0}}}}),
                               FakeRun(3, {{"m", {{"ate_m", 2.0}}}})};
  const ScenarioMethodTable t = AggregateScenarioMethods("s", {}, runs);
  EXPECT_DOUBLE_EQ(*Metric(t, "m", "ate_m").median, 2.0);
  EXPECT_DOUBLE_EQ(*Metric(t, "m", "ate_m").worst, 3.0);
}

TEST(CheckMethods, NullsMissingKeysAndBrokenRunsAreNoValue) {
  SeedRun broken;  // a run without a summary
  broken.seed = 4;
  broken.exit_code = 3;
  broken.error = "simulation failed";
  std::vector<SeedRun> runs = {
      FakeRun(1, {{"naive", {{"ate_m", 0.5}, {"nees_position_mean", nullptr}}}}),
      FakeRun(2, {{"naive", {{"ate_m", nullptr}, {"nees_position_mean", "x"}}}}),
      FakeRun(3, {{"naive", {{"nees_position_mean", std::nan("")}}}}), broken};
  const ScenarioMethodTable t = AggregateScenarioMethods("s", {"naive"}, runs);
  EXPECT_EQ(t.seeds, 4);
  const MethodMetricSummary& ate = Metric(t, "naive", "ate_m");
  EXPECT_EQ(ate.seeds, 1);
  EXPECT_DOUBLE_EQ(*ate.median, 0.5);
  EXPECT_DOUBLE_EQ(*ate.worst, 0.5);
  const MethodMetricSummary& nees = Metric(t, "naive", "nees_position_mean");
  EXPECT_EQ(nees.seeds, 0);
  EXPECT_FALSE(nees.median);
  EXPECT_FALSE(nees.worst);
  // A non-consensus method has no detection metrics: no value, not zero.
  EXPECT_EQ(Metric(t, "naive", "max_detection_delay_s").seeds, 0);
  EXPECT_EQ(Metric(t, "naive", "switches").seeds, 0);
}

TEST(CheckMethods, AteOverOracleIsTakenPerSeed) {
  // Per seed: 0.2/0.1 = 2, 0.3/0.3 = 1; seed 3 has no oracle ATE, seed 4 no consensus ATE.
  // The ratio of the medians (0.25 / 0.2 = 1.25) would be a different number.
  std::vector<SeedRun> runs = {
      FakeRun(1, {{"consensus", {{"ate_m", 0.2}}}, {"oracle", {{"ate_m", 0.1}}}}),
      FakeRun(2, {{"consensus", {{"ate_m", 0.3}}}, {"oracle", {{"ate_m", 0.3}}}}),
      FakeRun(3, {{"consensus", {{"ate_m", 5.0}}}, {"oracle", {{"ate_m", nullptr}}}}),
      FakeRun(4, {{"consensus", {{"ate_m", nullptr}}}, {"oracle", {{"ate_m", 0.2}}}}),
      FakeRun(5, {{"consensus", {{"ate_m", 0.1}}}, {"oracle", {{"ate_m", 0.0}}}})};
  const ScenarioMethodTable t = AggregateScenarioMethods("s", {"consensus", "oracle"}, runs);
  const MethodMetricSummary& ratio = Metric(t, "consensus", "ate_over_oracle");
  EXPECT_EQ(ratio.seeds, 2) << "only seeds where both have an ATE (and the oracle's > 0)";
  EXPECT_DOUBLE_EQ(*ratio.median, 1.5);
  EXPECT_DOUBLE_EQ(*ratio.worst, 2.0);
  const MethodMetricSummary& own = Metric(t, "oracle", "ate_over_oracle");
  EXPECT_EQ(own.seeds, 3);
  EXPECT_DOUBLE_EQ(*own.median, 1.0);
  // The ratio comes last, after the metrics of summary.json.
  EXPECT_EQ(Row(t, "consensus").metrics.back().metric, "ate_over_oracle");
}

TEST(CheckMethods, MethodsInTheScenarioOrderThenTheRestSorted) {
  // nlohmann's objects iterate sorted by key (consensus, naive, oracle, ...): the table
  // must follow estimation.methods instead, then list unconfigured methods by name.
  const json methods = {{"consensus", {{"ate_m", 0.1}}}, {"naive", {{"ate_m", 0.5}}},
                        {"oracle", {{"ate_m", 0.1}}},    {"zeta", {{"ate_m", 1.0}}},
                        {"alpha", {{"ate_m", 1.0}}},     {"single:vio@clean", {{"ate_m", 0.2}}}};
  const ScenarioMethodTable t = AggregateScenarioMethods(
      "s", {"single:vio@clean", "oracle", "naive", "consensus", "missing"}, {FakeRun(1, methods)});
  EXPECT_EQ(Methods(t), (std::vector<std::string>{"single:vio@clean", "oracle", "naive",
                                                  "consensus", "missing", "alpha", "zeta"}));
  EXPECT_EQ(Metric(t, "missing", "ate_m").seeds, 0) << "configured but never reported";
}

TEST(CheckMethods, MissedFaultsAndSensorsNeverReadmittedAreInfinite) {
  // summary.json writes +inf as null: the missed fault of seed 2 must not vanish from the
  // worst detection delay, nor the sensor of seed 3 that was never trusted again.
  const json detected_and_back = {{"sensor", "leica"}, {"fault", "jump"}, {"onset_s", 40.0},
                                  {"end_s", 52.0},     {"detected", true}, {"delay_s", 0.2},
                                  {"readmission_delay_s", 5.6}};
  json never_back = detected_and_back;
  never_back["readmission_delay_s"] = nullptr;
  json open_fault = detected_and_back;  // lasts to the end of the run: nothing to re-admit
  open_fault["end_s"] = 90.0;
  open_fault["readmission_delay_s"] = nullptr;
  std::vector<SeedRun> runs = {
      FakeRun(1, {{"consensus", {{"faults", 1}, {"faults_detected", 1},
                             {"max_detection_delay_s", 0.2}, {"max_readmission_delay_s", 5.6},
                             {"detections", {detected_and_back}}}}}),
      FakeRun(2, {{"consensus", {{"faults", 2}, {"faults_detected", 1},
                             {"max_detection_delay_s", nullptr}, {"max_readmission_delay_s", 4.0},
                             {"detections", {detected_and_back}}}}}),
      FakeRun(3, {{"consensus", {{"faults", 1}, {"faults_detected", 1},
                             {"max_detection_delay_s", 0.4},
                             {"max_readmission_delay_s", nullptr},
                             {"detections", {never_back}}}}}),
      FakeRun(4, {{"consensus", {{"faults", 1}, {"faults_detected", 1},
                             {"max_detection_delay_s", 0.3},
                             {"max_readmission_delay_s", nullptr},
                             {"detections", {open_fault}}}}}),
      // Detected everything, and yet a null delay (a malformed or hand-edited summary):
      // no value, no crash.
      FakeRun(5, {{"consensus", {{"faults", 1}, {"faults_detected", 1},
                             {"max_detection_delay_s", nullptr},
                             {"max_readmission_delay_s", nullptr}, {"detections", "garbage"}}}})};
  const ScenarioMethodTable t = AggregateScenarioMethods("s", {"consensus"}, runs);
  const MethodMetricSummary& detection = Metric(t, "consensus", "max_detection_delay_s");
  EXPECT_EQ(detection.seeds, 4);  // seeds 1-4
  EXPECT_TRUE(std::isinf(*detection.worst));
  EXPECT_NEAR(*detection.median, 0.35, 1e-12);  // 0.2 0.3 | 0.4 inf
  const MethodMetricSummary& readmission = Metric(t, "consensus", "max_readmission_delay_s");
  EXPECT_EQ(readmission.seeds, 3);  // seeds 1-3; seed 4's fault never ended
  EXPECT_DOUBLE_EQ(*readmission.median, 5.6);
  EXPECT_EQ(*readmission.worst, kInf);

  const std::string csv = MethodsCsv({t});
  EXPECT_CONTAINS(csv, "s,consensus,max_detection_delay_s,4,0.35,inf\n");
  EXPECT_CONTAINS(csv, "s,consensus,max_readmission_delay_s,3,5.6,inf\n");
  const std::string md = MethodsMarkdown({t});
  EXPECT_CONTAINS(md, "| missed (4 of 5 seeds) | never (3 of 5 seeds) |");
}

// Two scenarios: the CSV and markdown text exactly.
std::vector<ScenarioMethodTable> TwoScenarios() {
  std::vector<SeedRun> a = {
      FakeRun(1, {{"consensus", {{"ate_m", 0.02}, {"rotation_rmse_deg", 0.3},
                             {"position_step_max_m", 0.002},
                             {"nees_position_mean", 0.9}, {"nees_position_median", 0.7},
                             {"position_containment_95", 0.99}, {"max_detection_delay_s", 0.4},
                             {"max_readmission_delay_s", 5.6}, {"false_exclusion_fraction", 0.01},
                             {"switches", 5}, {"valid_fraction", 1.0}, {"faults", 2},
                             {"faults_detected", 2}}},
              {"oracle", {{"ate_m", 0.01}, {"valid_fraction", 1.0}}}}),
      FakeRun(2, {{"consensus", {{"ate_m", 0.04}, {"rotation_rmse_deg", 0.5},
                             {"position_step_max_m", 0.006},
                             {"nees_position_mean", 1.1}, {"nees_position_median", 0.9},
                             {"position_containment_95", 0.97}, {"max_detection_delay_s", 0.2},
                             {"max_readmission_delay_s", 1.1}, {"false_exclusion_fraction", 0.03},
                             {"switches", 3}, {"valid_fraction", 0.5}, {"faults", 2},
                             {"faults_detected", 2}}},
              {"oracle", {{"ate_m", 0.01}, {"valid_fraction", 1.0}}}})};
  std::vector<SeedRun> b = {FakeRun(7, {{"naive", {{"ate_m", 1.5}}}})};
  return {AggregateScenarioMethods("zz_first", {"oracle", "consensus"}, a),
          AggregateScenarioMethods("aa_second", {"naive"}, b)};
}

TEST(CheckMethods, CsvIsLongFormatWithAHeader) {
  const std::string csv = MethodsCsv(TwoScenarios());
  // The header line (tofu's CSV form: '#' and the columns), then the rows in table order.
  const std::string header = "#scenario,method,metric,seeds,median,worst\n";
  ASSERT_EQ(csv.substr(0, header.size()), header) << csv;
  const std::string rows = csv.substr(header.size());
  EXPECT_EQ(rows,
            "zz_first,oracle,ate_m,2,0.01,0.01\n"
            "zz_first,oracle,rotation_rmse_deg,0,,\n"
            "zz_first,oracle,position_step_max_m,0,,\n"
            "zz_first,oracle,nees_position_mean,0,,\n"
            "zz_first,oracle,nees_position_median,0,,\n"
            "zz_first,oracle,position_containment_95,0,,\n"
            "zz_first,oracle,max_detection_delay_s,0,,\n"
            "zz_first,oracle,max_readmission_delay_s,0,,\n"
            "zz_first,oracle,false_exclusion_fraction,0,,\n"
            "zz_first,oracle,switches,0,,\n"
            "zz_first,oracle,valid_fraction,2,1,1\n"
            "zz_first,oracle,ate_over_oracle,2,1,1\n"
            "zz_first,consensus,ate_m,2,0.03,0.04\n"
            "zz_first,consensus,rotation_rmse_deg,2,0.4,0.5\n"
            "zz_first,consensus,position_step_max_m,2,0.004,0.006\n"
            "zz_first,consensus,nees_position_mean,2,1,1.1\n"
            "zz_first,consensus,nees_position_median,2,0.8,0.9\n"
            "zz_first,consensus,position_containment_95,2,0.98,0.97\n"
            "zz_first,consensus,max_detection_delay_s,2,0.30000000000000004,0.4\n"
            "zz_first,consensus,max_readmission_delay_s,2,3.3499999999999996,5.6\n"
            "zz_first,consensus,false_exclusion_fraction,2,0.02,0.03\n"
            "zz_first,consensus,switches,2,4,5\n"
            "zz_first,consensus,valid_fraction,2,0.75,0.5\n"
            "zz_first,consensus,ate_over_oracle,2,3,4\n"
            "aa_second,naive,ate_m,1,1.5,1.5\n"
            "aa_second,naive,rotation_rmse_deg,0,,\n"
            "aa_second,naive,position_step_max_m,0,,\n"
            "aa_second,naive,nees_position_mean,0,,\n"
            "aa_second,naive,nees_position_median,0,,\n"
            "aa_second,naive,position_containment_95,0,,\n"
            "aa_second,naive,max_detection_delay_s,0,,\n"
            "aa_second,naive,max_readmission_delay_s,0,,\n"
            "aa_second,naive,false_exclusion_fraction,0,,\n"
            "aa_second,naive,switches,0,,\n"
            "aa_second,naive,valid_fraction,0,,\n");
}

TEST(CheckMethods, MarkdownHasATablePerScenarioInInputOrder) {
  const std::string md = MethodsMarkdown(TwoScenarios());
  const size_t first = md.find("\n## zz_first (2 seeds)\n");
  const size_t second = md.find("\n## aa_second (1 seed)\n");
  ASSERT_NE(first, std::string::npos) << md;
  ASSERT_NE(second, std::string::npos) << md;
  EXPECT_LT(first, second);
  EXPECT_CONTAINS(md,
                  "| method | ATE median / worst [m] | ATE/oracle median / worst | rotation RMSE "
                  "median [deg] | largest step worst [m] | NEES median | 95 % containment median "
                  "| max detection delay worst [s] | re-admission worst [s] | false exclusion "
                  "worst |\n"
                  "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|\n"
                  "| oracle | 0.01 / 0.01 | 1 / 1 | - | - | - | - | - | - | - |\n"
                  "| consensus | 0.03 / 0.04 | 3 / 4 | 0.4 | 0.006 | 0.8 | 0.98 | 0.4 | 5.6 | 0.03 |\n");
  EXPECT_CONTAINS(md, "| naive | 1.5 / 1.5 | - | - | - | - | - | - | - | - |\n");
}

TEST(CheckMethods, ScenariosWithoutMethodsAreLeftOut) {
  harness::Scenario with, without;
  with.name = "with";
  with.estimation.emplace();
  with.estimation->methods = {"oracle", "naive"};
  without.name = "without";
  ScenarioCheck a, b;
  a.runs = {FakeRun(1, {{"naive", {{"ate_m", 0.5}}}, {"oracle", {{"ate_m", 0.1}}}})};
  b.runs = {FakeRun(1, json::object())};
  const auto tables = AggregateMethodTables({without, with}, {b, a});
  ASSERT_EQ(tables.size(), 1u);
  EXPECT_EQ(tables[0].scenario, "with");
  EXPECT_EQ(Methods(tables[0]), (std::vector<std::string>{"oracle", "naive"}));
  EXPECT_DOUBLE_EQ(*Metric(tables[0], "naive", "ate_over_oracle").median, 5.0);
}

bool HaveMatplotlib() {
  return std::system("/usr/bin/python3 -c 'import matplotlib' >/dev/null 2>&1") == 0;
}

TEST(CheckMethods, WritesTheTableAndFigureOnlyWithAnEstimationBlock) {
  const fs::path dir = test::PerTestDirectory("tofu_check_methods_");
  fs::create_directories(dir);
  harness::Scenario scenario;
  scenario.name = "with";
  scenario.estimation.emplace();
  scenario.estimation->methods = {"oracle", "naive"};
  ScenarioCheck check;
  check.runs = {FakeRun(1, {{"naive", {{"ate_m", 0.5}}}, {"oracle", {{"ate_m", 0.1}}}}),
                FakeRun(2, {{"naive", {{"ate_m", 0.7}}}, {"oracle", {{"ate_m", 0.2}}}})};
  test::WriteFile(dir / "methods.png", "a figure of an earlier check");

  const auto md = campaign::WriteCheckMethods(dir, {scenario}, {check});
  ASSERT_TRUE(md.has_value());
  EXPECT_EQ(*md, dir / "methods.md");
  EXPECT_EQ(test::ReadFile(dir / "methods.md"), MethodsMarkdown(AggregateMethodTables({scenario}, {check})));
  EXPECT_CONTAINS(test::ReadFile(dir / "methods.csv"), "with,naive,ate_m,2,0.6,0.7\n");
  if (HaveMatplotlib()) {
    const std::string png = test::ReadFile(dir / "methods.png");
    EXPECT_EQ(png.substr(0, 8), "\x89PNG\r\n\x1a\n") << "methods.png is not the new figure";
  } else {
    EXPECT_FALSE(fs::exists(dir / "methods.png")) << "the earlier check's figure is left";
  }
  for (const auto& entry : fs::directory_iterator(dir)) {
    EXPECT_EQ(entry.path().filename().string().find(".tmp-"), std::string::npos)
        << "staging left behind: " << entry.path();
  }

  // A check without any estimation block writes none and removes what an earlier one left.
  harness::Scenario plain;
  plain.name = "plain";
  EXPECT_FALSE(campaign::WriteCheckMethods(dir, {plain}, {ScenarioCheck{}}).has_value());
  EXPECT_FALSE(fs::exists(dir / "methods.md"));
  EXPECT_FALSE(fs::exists(dir / "methods.csv"));
  EXPECT_FALSE(fs::exists(dir / "methods.png"));
  if (!HasFailure()) fs::remove_all(dir);
}

}  // namespace
}  // namespace tofu
