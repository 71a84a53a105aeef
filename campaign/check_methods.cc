#include "campaign/check_methods.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <map>
#include <set>
#include <system_error>

#include <fmt/format.h>

#include "harness/run_directory.h"
#include "harness/yaml_reader.h"
#include "replay/file_io.h"

namespace tofu::campaign {

using replay::StagingPath;
using replay::WriteFileAtomically;

const std::vector<std::string> kMethodTableMetrics = {
    "ate_m",
    "rotation_rmse_deg",
    "position_step_max_m",
    "nees_position_mean",
    "nees_position_median",
    "position_containment_95",
    "max_detection_delay_s",
    "max_readmission_delay_s",
    "false_exclusion_fraction",
    "switches",
    "valid_fraction",
};

namespace {

namespace fs = std::filesystem;
using nlohmann::json;
using core::FormatDouble;

constexpr const char* kOracle = "oracle";
constexpr const char* kAteOverOracle = "ate_over_oracle";
constexpr double kInf = std::numeric_limits<double>::infinity();

// A number of a JSON object; nullopt when missing, not a number or NaN (JSON has no NaN;
// only a hand-made document can hold one).
std::optional<double> Number(const json& object, const char* key) {
  const auto it = object.find(key);
  if (it == object.end() || !it->is_number()) return std::nullopt;
  const double value = it->get<double>();
  if (std::isnan(value)) return std::nullopt;
  return value;
}

// Whether a fault of `method` was detected, ended before the run did and was never
// re-admitted: its readmission_delay_s was +inf, which summary.json writes as null.
bool NeverReadmitted(const json& method, const json& summary) {
  const auto detections = method.find("detections");
  const std::optional<double> run_end_s = Number(summary, "simulated_s");
  if (detections == method.end() || !detections->is_array() || !run_end_s) return false;
  for (const json& d : *detections) {
    if (!d.is_object()) continue;
    const auto detected = d.find("detected");
    const auto delay = d.find("readmission_delay_s");
    const std::optional<double> end_s = Number(d, "end_s");
    if (detected != d.end() && detected->is_boolean() && detected->get<bool>() && end_s &&
        *end_s < *run_end_s - 1e-6 && delay != d.end() && delay->is_null()) {
      return true;
    }
  }
  return false;
}

// One seed's value of a metric of a method (`summary`: the run's whole summary.json).
std::optional<double> MetricValue(const json& method, const json& summary,
                                  const std::string& metric) {
  if (!method.is_object()) return std::nullopt;
  std::optional<double> value = Number(method, metric.c_str());
  if (value) return value;
  const auto raw = method.find(metric);
  if (raw == method.end() || !raw->is_null()) return std::nullopt;
  if (metric == "max_detection_delay_s") {
    // The largest delay is +inf exactly when a fault was missed.
    const std::optional<double> faults = Number(method, "faults");
    const std::optional<double> detected = Number(method, "faults_detected");
    if (faults && detected && *detected < *faults) return kInf;
  } else if (metric == "max_readmission_delay_s") {
    if (NeverReadmitted(method, summary)) return kInf;
  }
  return std::nullopt;
}

MethodMetricSummary Summarise(const std::string& metric, std::vector<double> values) {
  MethodMetricSummary s;
  s.metric = metric;
  s.seeds = static_cast<int>(values.size());
  if (values.empty()) return s;
  std::sort(values.begin(), values.end());
  const size_t n = values.size();
  // Values are finite or +inf: the mean of the middle two is +inf when one of them is.
  s.median = n % 2 == 1 ? values[n / 2] : 0.5 * (values[n / 2 - 1] + values[n / 2]);
  // Fractions where less is worse: valid outputs, and containment (a covariance that
  // holds the truth less often than it says is the dangerous one).
  const bool lower_is_worse = metric == "valid_fraction" || metric == "position_containment_95";
  s.worst = lower_is_worse ? values.front() : values.back();
  return s;
}

// The `methods` object of a run's summary, nullptr when it has none.
const json* MethodsOf(const SeedRun& run) {
  if (!run.summary.is_object()) return nullptr;
  const auto it = run.summary.find("methods");
  return it != run.summary.end() && it->is_object() ? &*it : nullptr;
}

// ---- text ----

std::string CsvNumber(const std::optional<double>& v) {
  if (!v) return "";
  if (std::isinf(*v)) return *v > 0 ? "inf" : "-inf";
  return FormatDouble(*v);
}

// Names are identifiers in practice; anything a CSV reader would split is quoted.
std::string CsvField(const std::string& text) {
  if (text.find_first_of(",\"\r\n") == std::string::npos) return text;
  std::string quoted = "\"";
  for (const char c : text) quoted += c == '"' ? std::string("\"\"") : std::string(1, c);
  return quoted + "\"";
}

std::string MdText(const std::string& text) {
  std::string out;
  for (const char c : text) {
    if (c == '|') out += '\\';
    out += c == '\n' ? ' ' : c;
  }
  return out;
}

// A figure in the table: 4 significant digits; +inf as `inf_text`.
std::string MdNumber(double v, const char* inf_text) {
  if (std::isinf(v)) return inf_text;
  return fmt::format("{:.4g}", v);
}

// "median / worst", "-" without a value, and how many seeds had one when not all did.
std::string MdCell(const MethodMetricSummary* s, int seeds, bool median, bool worst,
                   const char* inf_text = "inf") {
  if (s == nullptr || s->seeds == 0) return "-";
  std::string text;
  if (median) text += MdNumber(*s->median, inf_text);
  if (median && worst) text += " / ";
  if (worst) text += MdNumber(*s->worst, inf_text);
  if (s->seeds < seeds) text += fmt::format(" ({} of {} seeds)", s->seeds, seeds);
  return text;
}

}  // namespace

const MethodMetricSummary* MethodTableRow::Find(const std::string& metric) const {
  for (const MethodMetricSummary& m : metrics) {
    if (m.metric == metric) return &m;
  }
  return nullptr;
}

ScenarioMethodTable AggregateScenarioMethods(const std::string& scenario,
                                             const std::vector<std::string>& method_order,
                                             const std::vector<SeedRun>& runs) {
  ScenarioMethodTable table;
  table.scenario = scenario;
  table.seeds = static_cast<int>(runs.size());

  // The methods: the configured order first, then what else the summaries hold (sorted:
  // nlohmann's objects are).
  std::vector<std::string> names;
  std::set<std::string> seen;
  for (const std::string& m : method_order) {
    if (seen.insert(m).second) names.push_back(m);
  }
  for (const SeedRun& r : runs) {
    if (const json* methods = MethodsOf(r)) {
      for (const auto& [name, value] : methods->items()) {
        if (seen.insert(name).second) names.push_back(name);
      }
    }
  }
  const bool has_oracle = seen.contains(kOracle);

  for (const std::string& name : names) {
    MethodTableRow row;
    row.method = name;
    std::map<std::string, std::vector<double>> values;
    std::vector<double> ratios;
    for (const SeedRun& r : runs) {
      const json* methods = MethodsOf(r);
      if (methods == nullptr) continue;
      const auto method = methods->find(name);
      if (method == methods->end()) continue;
      if (const auto failure = method->find("failure"); failure != method->end() && failure->is_string()) {
        if (row.failed_seeds++ == 0) {
          const std::string text = failure->get<std::string>();
          row.failure = text.substr(0, text.find('\n'));
        }
      }
      for (const std::string& metric : kMethodTableMetrics) {
        if (const auto v = MetricValue(*method, r.summary, metric)) values[metric].push_back(*v);
      }
      // ATE over the oracle's in the same seed: both finite, the oracle's positive.
      const auto oracle_method = methods->find(kOracle);
      if (oracle_method == methods->end()) continue;
      const std::optional<double> ate = MetricValue(*method, r.summary, "ate_m");
      const std::optional<double> oracle = MetricValue(*oracle_method, r.summary, "ate_m");
      if (ate && oracle && std::isfinite(*ate) && std::isfinite(*oracle) && *oracle > 0.0) {
        ratios.push_back(*ate / *oracle);
      }
    }
    for (const std::string& metric : kMethodTableMetrics) {
      row.metrics.push_back(Summarise(metric, values[metric]));
    }
    if (has_oracle) row.metrics.push_back(Summarise(kAteOverOracle, ratios));
    table.methods.push_back(std::move(row));
  }
  return table;
}

std::vector<ScenarioMethodTable> AggregateMethodTables(const std::vector<harness::Scenario>& scenarios,
                                                       const std::vector<ScenarioCheck>& checks) {
  std::vector<ScenarioMethodTable> tables;
  for (size_t i = 0; i < scenarios.size() && i < checks.size(); ++i) {
    const harness::Scenario& s = scenarios[i];
    ScenarioMethodTable table = AggregateScenarioMethods(
        s.name, s.estimation ? s.estimation->methods : std::vector<std::string>{},
        checks[i].runs);
    if (!table.methods.empty()) tables.push_back(std::move(table));
  }
  return tables;
}

std::string MethodsCsv(const std::vector<ScenarioMethodTable>& tables) {
  // One header line, as every CSV of tofu (errors.csv, decisions.csv): the columns; the
  // units are in the metric names (README.md, "tofu check").
  std::string out = "#scenario,method,metric,seeds,median,worst\n";
  for (const ScenarioMethodTable& t : tables) {
    for (const MethodTableRow& row : t.methods) {
      for (const MethodMetricSummary& m : row.metrics) {
        out += fmt::format("{},{},{},{},{},{}\n", CsvField(t.scenario), CsvField(row.method),
                           m.metric, m.seeds, CsvNumber(m.median), CsvNumber(m.worst));
      }
      if (row.failed_seeds > 0) {
        out += fmt::format("{},{},failed_seeds,{},{},{}\n", CsvField(t.scenario),
                           CsvField(row.method), t.seeds, row.failed_seeds, row.failed_seeds);
      }
    }
  }
  return out;
}

std::string MethodsMarkdown(const std::vector<ScenarioMethodTable>& tables) {
  std::string out =
      "# Estimation methods over the seeds\n\n"
      "Median and worst seed of each metric (summary.json `methods`); \"-\": no seed has a "
      "value; \"(k of N seeds)\": only k seeds have one. ATE/oracle: ATE over the oracle's "
      "ATE in the same seed. Largest step: the largest change of the position error between "
      "consecutive outputs (a jump of the estimate). Worst detection delay \"missed\": a fault was not detected; "
      "worst re-admission \"never\": a sensor was not trusted again after its fault.\n";
  for (const ScenarioMethodTable& t : tables) {
    out += fmt::format("\n## {} ({} seed{})\n\n", MdText(t.scenario), t.seeds,
                       t.seeds == 1 ? "" : "s");
    out +=
        "| method | ATE median / worst [m] | ATE/oracle median / worst | rotation RMSE median "
        "[deg] | largest step worst [m] | NEES median | 95 % containment median | max detection "
        "delay worst [s] | re-admission worst [s] | false exclusion worst |\n"
        "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|\n";
    for (const MethodTableRow& row : t.methods) {
      out += fmt::format(
          "| {} | {} | {} | {} | {} | {} | {} | {} | {} | {} |\n",
          row.failed_seeds == 0
              ? MdText(row.method)
              : fmt::format("{} **FAILED in {} of {} seeds: {}**", MdText(row.method),
                            row.failed_seeds, t.seeds, MdText(row.failure)),
          MdCell(row.Find("ate_m"), t.seeds, true, true),
          MdCell(row.Find(kAteOverOracle), t.seeds, true, true),
          MdCell(row.Find("rotation_rmse_deg"), t.seeds, true, false),
          MdCell(row.Find("position_step_max_m"), t.seeds, false, true),
          MdCell(row.Find("nees_position_median"), t.seeds, true, false),
          MdCell(row.Find("position_containment_95"), t.seeds, true, false),
          MdCell(row.Find("max_detection_delay_s"), t.seeds, false, true, "missed"),
          MdCell(row.Find("max_readmission_delay_s"), t.seeds, false, true, "never"),
          MdCell(row.Find("false_exclusion_fraction"), t.seeds, false, true));
    }
  }
  return out;
}

std::optional<fs::path> WriteCheckMethods(const fs::path& out_dir,
                                          const std::vector<harness::Scenario>& scenarios,
                                          const std::vector<ScenarioCheck>& checks) {
  const fs::path csv = out_dir / "methods.csv";
  const fs::path md = out_dir / "methods.md";
  const fs::path png = out_dir / "methods.png";
  // An earlier check's figure would pass for this one's if the plot fails.
  std::error_code ignored;
  fs::remove(png, ignored);
  const bool estimation = std::any_of(scenarios.begin(), scenarios.end(),
                                      [](const harness::Scenario& s) { return s.estimation.has_value(); });
  if (!estimation) {
    fs::remove(csv, ignored);
    fs::remove(md, ignored);
    return std::nullopt;
  }
  const std::vector<ScenarioMethodTable> tables = AggregateMethodTables(scenarios, checks);
  WriteFileAtomically(csv, MethodsCsv(tables), "--out");
  WriteFileAtomically(md, MethodsMarkdown(tables), "--out");

  // Drawn into a staging sibling renamed into place: no half-drawn methods.png.
  const fs::path script = fs::path(TOFU_SCRIPTS_DIR) / "plot_check_methods.py";
  const fs::path staging = StagingPath(png);
  bool drawn = false;
  try {
    drawn = fs::exists(script) &&
            harness::RunQuietly({script.string(), out_dir.string(), "--out", staging.string()}) == 0;
  } catch (...) {  // interrupted (interrupt.h): the script was stopped mid-drawing
    fs::remove(staging, ignored);
    throw;
  }
  if (drawn) {
    fs::rename(staging, png, ignored);
    drawn = !ignored;
  }
  fs::remove(staging, ignored);
  if (!drawn) {
    fmt::print(stderr, "tofu: warning: no {} ({} failed; needs python3-matplotlib)\n",
               png.string(), script.string());
  }
  return md;
}

}  // namespace tofu::campaign
