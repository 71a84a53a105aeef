#pragma once
// `tofu check`'s method table (issue 16): every estimation method of every scenario,
// aggregated over the check's seeds from each run's summary.json `methods` (median and
// worst seed per metric, and the ATE relative to the oracle's in the same seed), written
// as <out>/methods.csv (long format), <out>/methods.md (one markdown table per scenario)
// and drawn as <out>/methods.png by scripts/plot_check_methods.py.

#include <filesystem>
#include <optional>
#include <string>
#include <vector>

#include "campaign/check_command.h"
#include "harness/scenario.h"

namespace tofu::campaign {

/// One metric of one method over the seeds.
struct MethodMetricSummary {
  std::string metric;  ///< kMethodTableMetrics entry or "ate_over_oracle"
  int seeds = 0;       ///< seeds with a value
  std::optional<double> median;  ///< of those values (mean of the middle two for an even count)
  /// The worst of those values: the largest, the smallest for valid_fraction. +inf stands
  /// for a missed fault (max_detection_delay_s) or a sensor never re-admitted
  /// (max_readmission_delay_s).
  std::optional<double> worst;
};

/// One method of one scenario: every metric of kMethodTableMetrics, in that order, then
/// "ate_over_oracle" when the scenario has a method named "oracle".
struct MethodTableRow {
  std::string method;
  std::vector<MethodMetricSummary> metrics;
  /// Seeds in which the method (a user's client) failed: none of its figures counts there
  /// (summary.json has them null), and the row says so with the first seed's `failure`.
  int failed_seeds = 0;
  std::string failure;
  /// The entry of `metric`, nullptr when there is none.
  const MethodMetricSummary* Find(const std::string& metric) const;
};

/// One scenario's methods over its seeds.
struct ScenarioMethodTable {
  std::string scenario;
  int seeds = 0;  ///< runs of the scenario (with or without a summary)
  /// In the order of the scenario's `estimation.methods`, then any other method its
  /// summaries hold, sorted by name.
  std::vector<MethodTableRow> methods;
};

/// The per-method metrics of summary.json that the table aggregates, in table order.
/// summary.json stores +inf as null: a null max_detection_delay_s of a method with
/// faults > faults_detected is read as +inf (a missed fault), a null
/// max_readmission_delay_s as +inf when one of its `detections` was detected, ended
/// before the run did (end_s < simulated_s) and has a null readmission_delay_s (never
/// re-admitted); any other null, a missing key or a NaN is "no value" for that seed.
extern const std::vector<std::string> kMethodTableMetrics;

/// One scenario's table from its runs (in seed order; each SeedRun::summary is the parsed
/// summary.json, null when missing). `method_order`: the scenario's estimation.methods.
ScenarioMethodTable AggregateScenarioMethods(const std::string& scenario,
                                             const std::vector<std::string>& method_order,
                                             const std::vector<SeedRun>& runs);

/// The tables of a check: `checks[i]` holds the runs of `scenarios[i]` (same order and
/// size). Scenarios with no method (no estimation block and none in the summaries) are
/// left out.
std::vector<ScenarioMethodTable> AggregateMethodTables(const std::vector<harness::Scenario>& scenarios,
                                                       const std::vector<ScenarioCheck>& checks);

/// methods.csv: the header line "#scenario,method,metric,seeds,median,worst" (the form of
/// every tofu CSV), then a row per scenario, method and metric in table order (every
/// metric, also those no seed has: seeds 0), and for a method that failed in some seed a
/// row "failed_seeds" (seeds: the runs; median and worst: the seeds it failed in); units are in the metric names (_m, _deg, _s;
/// the others have none). A value is the shortest decimal text that reads back exactly,
/// "inf" for +inf, empty for none.
std::string MethodsCsv(const std::vector<ScenarioMethodTable>& tables);

/// methods.md: a heading and a markdown table per scenario, one row per method.
std::string MethodsMarkdown(const std::vector<ScenarioMethodTable>& tables);

/// What `tofu check` does after its runs: when at least one scenario has an estimation
/// block, writes <out_dir>/methods.csv and methods.md (atomically) and draws methods.png
/// with scripts/plot_check_methods.py (a missing python3 or matplotlib is a warning on
/// stderr, never a failure; a methods.png of an earlier check is removed first) and
/// returns the path of methods.md. Otherwise removes the three files an earlier check
/// may have left in <out_dir> (they would describe other runs) and returns nullopt.
/// Throws core::IoError when a file cannot be written.
std::optional<std::filesystem::path> WriteCheckMethods(const std::filesystem::path& out_dir,
                                                       const std::vector<harness::Scenario>& scenarios,
                                                       const std::vector<ScenarioCheck>& checks);

}  // namespace tofu::campaign
