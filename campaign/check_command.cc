#include "campaign/check_command.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <map>
#include <set>

#include <fmt/format.h>
#include <fmt/ranges.h>

#include "core/cores.h"
#include "core/error.h"
#include "core/file_io.h"
#include "core/version.h"
#include "campaign/cell_record.h"
#include "campaign/check_methods.h"
#include "campaign/check_shards.h"
#include "campaign/compare.h"
#include "harness/yaml_reader.h"
#include "replay/file_io.h"

namespace tofu::campaign {

using replay::WriteFileAtomically;

namespace {

namespace fs = std::filesystem;
using core::InputError;
using core::FormatDouble;

// ---- running ----

// One run to do and, once done, what came of it.
struct Job : RunRequest {
  uint64_t cell = 0;  // in the check's grid (check_shards.h)
  size_t scenario_index = 0;
};

// ---- reporting ----

std::string FormatValue(const std::optional<double>& v) {
  return v ? fmt::format("{:.4g}", *v) : std::string("n/a");
}

std::string Where(const harness::Expectation& e) {
  return fmt::format("{}:{}", e.location.file, e.location.line);
}

std::string SeedValues(const AggregatedExpectation& a, std::string_view separator) {
  std::string text;
  for (const SeedOutcome& s : a.seeds) {
    if (!text.empty()) text += separator;
    if (!s.not_measurable.empty()) {
      text += fmt::format("seed {}: not measurable, {} (not held)", s.seed, s.not_measurable);
      continue;
    }
    text += fmt::format("seed {}: {} ({})", s.seed, FormatValue(s.value),
                        s.held ? "held" : "not held");
  }
  return text;
}

std::string AggregateMessage(const AggregatedExpectation& a) {
  return fmt::format("held in {} of {} seeds, needs {} (pass_fraction {})", a.held,
                     a.seeds.size(), a.required, FormatDouble(a.expectation.pass_fraction));
}

void PrintTable(const std::vector<ScenarioCheck>& checks) {
  struct Row {
    std::string scenario, seeds, method, ate, detections, result;
  };
  std::vector<Row> rows;
  for (const ScenarioCheck& c : checks) {
    const std::string seeds = fmt::format("{}/{}", c.seeds_passed, c.runs.size());
    // A failed client is its own row's verdict; the other rows say the scenario's.
    const bool expectations_held =
        std::all_of(c.expectations.begin(), c.expectations.end(),
                    [](const AggregatedExpectation& a) { return a.passed; });
    const std::string result = !c.runs_ok ? "ERROR" : expectations_held ? "pass" : "FAIL";
    const auto failed = [&](int failed_seeds, const std::string& failure) {
      return fmt::format("FAILED in {}/{} seeds: {}", failed_seeds, c.runs.size(), failure);
    };
    if (c.methods.empty()) rows.push_back({c.name, seeds, "-", "-", "-", result});
    for (const MethodStats& m : c.methods) {
      if (m.failed_seeds > 0) {
        rows.push_back({c.name, seeds, m.method, "FAILED", "-", failed(m.failed_seeds, m.failure)});
        continue;
      }
      rows.push_back({c.name, seeds, m.method,
                      m.ate_mean_m ? fmt::format("{:.4f}", *m.ate_mean_m) : std::string("-"),
                      m.has_detections ? fmt::format("{}/{}", m.faults_detected, m.faults)
                                       : std::string("-"),
                      result});
    }
    // Closed-loop flights: the true tracking RMSE in the ATE column, and the collisions.
    for (const ClosedLoopStats& f : c.closed_loop) {
      if (f.failed_seeds > 0) {
        rows.push_back({c.name, seeds, "flown on " + f.method, "FAILED", "-",
                        failed(f.failed_seeds, f.failure)});
        continue;
      }
      rows.push_back({c.name, seeds, "flown on " + f.method,
                      f.tracking_rmse_mean_m ? fmt::format("trk {:.4f}", *f.tracking_rmse_mean_m)
                                             : std::string("-"),
                      fmt::format("{} hits", f.collisions), result});
    }
  }
  Row header{"scenario", "seeds ok", "method", "ATE [m]", "detected", "result"};
  size_t w[5] = {header.scenario.size(), header.seeds.size(), header.method.size(),
                 header.ate.size(), header.detections.size()};
  for (const Row& r : rows) {
    w[0] = std::max(w[0], r.scenario.size());
    w[1] = std::max(w[1], r.seeds.size());
    w[2] = std::max(w[2], r.method.size());
    w[3] = std::max(w[3], r.ate.size());
    w[4] = std::max(w[4], r.detections.size());
  }
  rows.insert(rows.begin(), header);
  for (const Row& r : rows) {
    fmt::print("{:<{}}  {:>{}}  {:<{}}  {:>{}}  {:>{}}  {}\n", r.scenario, w[0], r.seeds, w[1],
               r.method, w[2], r.ate, w[3], r.detections, w[4], r.result);
  }
}

void PrintFailures(const std::vector<ScenarioCheck>& checks) {
  bool header = false;
  for (const ScenarioCheck& c : checks) {
    for (const AggregatedExpectation& a : c.expectations) {
      if (a.passed) continue;
      if (!header) fmt::print("failed expectations:\n");
      header = true;
      fmt::print("  {}: {}: {} at {}\n    {}\n", c.name, ExpectationLabel(a.expectation),
                 AggregateMessage(a), Where(a.expectation), SeedValues(a, "; "));
    }
  }
  header = false;
  for (const ScenarioCheck& c : checks) {
    for (const SeedRun& r : c.runs) {
      if (r.client_failure.empty()) continue;
      if (!header) fmt::print("failed clients:\n");
      header = true;
      fmt::print("  {} seed {}: {}\n    log: {}\n", c.name, r.seed, r.client_failure, r.log_path);
    }
  }
  header = false;
  for (const ScenarioCheck& c : checks) {
    for (const SeedRun& r : c.runs) {
      if (r.error.empty()) continue;
      if (!header) fmt::print("failed runs:\n");
      header = true;
      std::string error = r.error;
      for (size_t p = 0; (p = error.find('\n', p)) != std::string::npos; p += 5) {
        error.replace(p, 1, "\n    ");
      }
      fmt::print("  {} seed {}: {}\n    log: {}\n", c.name, r.seed, error, r.log_path);
    }
  }
}

// Every *.png and *.mp4 under <run_dir>/renders/, sorted.
std::vector<std::string> Renders(const std::string& run_dir) {
  std::vector<std::string> files;
  const fs::path renders = fs::path(run_dir) / "renders";
  std::error_code ec;
  if (!fs::is_directory(renders, ec)) return files;
  for (auto it = fs::recursive_directory_iterator(renders, ec);
       !ec && it != fs::recursive_directory_iterator(); it.increment(ec)) {
    const std::string ext = it->path().extension().string();
    if (it->is_regular_file(ec) && (ext == ".png" || ext == ".mp4")) {
      files.push_back(fs::absolute(it->path()).lexically_normal().string());
    }
  }
  std::sort(files.begin(), files.end());
  return files;
}

// <system-out> of a failing test case: the run directories of the seeds it failed in and
// their renders in the Jenkins JUnit-attachments form.
std::string FailureSystemOut(const ScenarioCheck& c, const std::set<uint64_t>& failed_seeds) {
  std::string out;
  for (const SeedRun& r : c.runs) {
    if (!failed_seeds.contains(r.seed)) continue;
    out += fmt::format("seed {}: run directory {}\n", r.seed, r.run_dir);
    for (const std::string& file : Renders(r.run_dir)) {
      out += fmt::format("[[ATTACHMENT|{}]]\n", file);
    }
  }
  return out;
}


// ---- validation ----

void ValidateOptions(const CheckCommandOptions& options) {
  if (options.seeds < 1) {
    throw InputError({"--seeds"}, "",
                     fmt::format("expected an integer >= 1, got {}", options.seeds));
  }
  if (options.jobs < 0) {
    throw InputError({"--jobs"}, "",
                     fmt::format("expected an integer >= 1 (0: number of cores), got {}",
                                 options.jobs));
  }
  if (options.out_dir.empty()) throw InputError({"--out"}, "", "expected a directory, got ''");
  std::error_code ec;
  if (fs::exists(options.out_dir, ec) && !fs::is_directory(options.out_dir, ec)) {
    throw InputError({options.out_dir}, "--out", "exists and is not a directory");
  }
  const bool sharded = !options.shard.origin.empty();
  if (sharded && !options.merge_dirs.empty()) {
    throw InputError({}, options.shard.origin,
                     "a merge (--merge) runs no shard: leave out --shard, and merge every shard");
  }
  if (sharded && options.junit_path) {
    throw InputError({}, "--junit",
                     fmt::format("shard {}/{} (from {}) writes no JUnit: give --junit to the merge "
                                 "(tofu check ... --merge DIR...), which has every seed",
                                 options.shard.index, options.shard.count, options.shard.origin));
  }
  if (sharded && options.baseline_path) {
    throw InputError({}, "--baseline",
                     fmt::format("shard {}/{} (from {}) compares nothing: give --baseline to the "
                                 "merge (tofu check ... --merge DIR...), which has every seed",
                                 options.shard.index, options.shard.count, options.shard.origin));
  }
  if (options.baseline_path && options.baseline_path->empty()) {
    throw InputError({"--baseline"}, "", "expected a baseline file or a check directory, got ''");
  }
  if (options.junit_path) {
    if (options.junit_path->empty()) throw InputError({"--junit"}, "", "expected a file, got ''");
    if (fs::is_directory(*options.junit_path, ec)) {
      throw InputError({*options.junit_path}, "--junit", "is a directory, expected a file path");
    }
  }
}

// Loads every scenario; prints every problem (not only the first) and returns false if
// there was one.
bool LoadAll(const std::vector<std::string>& paths, std::vector<harness::Scenario>& scenarios) {
  bool ok = true;
  std::map<std::string, std::string> file_of_name;
  for (const std::string& path : paths) {
    try {
      harness::Scenario scenario = harness::LoadScenario(path);
      // What `tofu validate` checks: the models too, so a run never fails on them.
      harness::CheckScenarioModels(scenario);
      CheckScenarioMinimalEffects(scenario);
      // Run directories are named after scenarios: two files may not share a name.
      const auto [it, inserted] = file_of_name.emplace(scenario.name, path);
      if (!inserted) {
        throw InputError({path}, "name",
                         fmt::format("scenario name '{}' is also the name of {}; run "
                                     "directories are named after scenarios",
                                     scenario.name, it->second));
      }
      scenarios.push_back(std::move(scenario));
    } catch (const InputError& e) {
      fmt::print(stderr, "tofu: error: {}\n", e.what());
      ok = false;
    }
  }
  return ok;
}

}  // namespace

// ---- public helpers ----

std::vector<std::string> ExpandScenarioInputs(const std::vector<std::string>& inputs) {
  std::vector<std::string> files;
  std::set<fs::path> seen;
  const auto add = [&](const fs::path& file) {
    std::error_code ec;
    const fs::path key = fs::weakly_canonical(file, ec);
    if (seen.insert(ec ? file : key).second) files.push_back(file.string());
  };
  for (const std::string& input : inputs) {
    std::error_code ec;
    const fs::file_status status = fs::status(input, ec);
    if (!fs::exists(status)) {
      throw InputError({input}, "", "no such file or directory (expected a scenario YAML file "
                                    "or a directory of them)");
    }
    if (!fs::is_directory(status)) {
      add(input);
      continue;
    }
    std::vector<fs::path> found;
    for (const auto& entry : fs::directory_iterator(input)) {
      if (entry.path().extension() == ".yaml" && entry.is_regular_file()) {
        found.push_back(entry.path());
      }
    }
    if (found.empty()) throw InputError({input}, "", "directory has no *.yaml scenario files");
    std::sort(found.begin(), found.end());
    for (const fs::path& f : found) add(f);
  }
  return files;
}

int RequiredPasses(double pass_fraction, int seeds) {
  // pass_fraction * seeds carries the rounding error of the decimal fraction (0.7 * 10 =
  // 7.000000000000001); a tolerance far below 1/seeds keeps ceil from counting it.
  const int required = static_cast<int>(std::ceil(pass_fraction * seeds - 1e-9));
  return std::clamp(required, 1, std::max(seeds, 1));
}

AggregatedExpectation AggregateExpectation(const harness::Expectation& expectation,
                                           std::vector<SeedOutcome> seeds) {
  AggregatedExpectation a;
  a.expectation = expectation;
  a.seeds = std::move(seeds);
  a.held = static_cast<int>(
      std::count_if(a.seeds.begin(), a.seeds.end(), [](const SeedOutcome& s) { return s.held; }));
  a.required = RequiredPasses(expectation.pass_fraction, static_cast<int>(a.seeds.size()));
  a.passed = !a.seeds.empty() && a.held >= a.required;
  return a;
}

namespace {

// Each seed's outcome of expectation `index` of the scenario (`e`), from its summary.json.
std::vector<SeedOutcome> SeedOutcomes(const std::vector<SeedRun>& runs, size_t index,
                                      const harness::Expectation& e) {
  std::vector<SeedOutcome> outcomes;
  for (const SeedRun& r : runs) {
    SeedOutcome o;
    o.seed = r.seed;
    const nlohmann::json* entry = nullptr;
    if (r.summary.is_object() && r.summary.contains("expectations") &&
        r.summary["expectations"].is_array() && index < r.summary["expectations"].size()) {
      entry = &r.summary["expectations"][index];
    }
    // Position and metric name must agree: anything else is not this expectation.
    if (entry != nullptr && entry->is_object() && entry->value("metric", "") == e.metric) {
      const auto value = entry->find("value");
      if (value != entry->end() && value->is_number()) o.value = value->get<double>();
      const auto passed = entry->find("passed");
      o.held = passed != entry->end() && passed->is_boolean() && passed->get<bool>();
      const auto why = entry->find("not_measurable");
      if (why != entry->end() && why->is_string()) o.not_measurable = why->get<std::string>();
    }
    outcomes.push_back(o);
  }
  return outcomes;
}

// Counts a method's or flight's failure in one seed (its summary entry's `failure`).
void NoteFailure(const nlohmann::json& entry, int& failed_seeds, std::string& first) {
  const auto failure = entry.find("failure");
  if (failure == entry.end() || !failure->is_string()) return;
  ++failed_seeds;
  if (first.empty()) {
    const std::string text = failure->get<std::string>();
    first = text.substr(0, text.find('\n'));
  }
}

// The estimation methods over the seeds (mean ATE, faults detected), by method name.
std::vector<MethodStats> MethodStatsOverSeeds(const std::vector<SeedRun>& runs) {
  std::map<std::string, MethodStats> methods;
  std::map<std::string, double> ate_sum;
  for (const SeedRun& r : runs) {
    if (!r.summary.is_object() || !r.summary.contains("methods") ||
        !r.summary["methods"].is_object()) {
      continue;
    }
    for (const auto& [name, m] : r.summary["methods"].items()) {
      MethodStats& stats = methods[name];
      stats.method = name;
      if (!m.is_object()) continue;
      NoteFailure(m, stats.failed_seeds, stats.failure);
      if (const auto ate = m.find("ate_m"); ate != m.end() && ate->is_number()) {
        ate_sum[name] += ate->get<double>();
        ++stats.seeds_with_ate;
      }
      if (const auto faults = m.find("faults"); faults != m.end() && faults->is_number()) {
        stats.faults += faults->get<int>();
        stats.has_detections = true;
        const auto detected = m.find("faults_detected");
        if (detected != m.end() && detected->is_number()) {
          stats.faults_detected += detected->get<int>();
        }
      }
    }
  }
  std::vector<MethodStats> out;
  for (auto& [name, stats] : methods) {
    if (stats.seeds_with_ate > 0) stats.ate_mean_m = ate_sum[name] / stats.seeds_with_ate;
    out.push_back(stats);
  }
  return out;
}

// The closed-loop flights over the seeds (mean tracking error, collisions, failsafe
// events), by method name.
std::vector<ClosedLoopStats> ClosedLoopStatsOverSeeds(const std::vector<SeedRun>& runs) {
  std::map<std::string, ClosedLoopStats> flights;
  std::map<std::string, std::pair<double, int>> tracking_sum;
  for (const SeedRun& r : runs) {
    if (!r.summary.is_object() || !r.summary.contains("closed_loop") ||
        !r.summary["closed_loop"].is_object()) {
      continue;
    }
    for (const auto& [name, f] : r.summary["closed_loop"].items()) {
      ClosedLoopStats& stats = flights[name];
      stats.method = name;
      ++stats.seeds;
      if (!f.is_object()) continue;
      NoteFailure(f, stats.failed_seeds, stats.failure);
      if (const auto t = f.find("tracking_rmse_m"); t != f.end() && t->is_number()) {
        tracking_sum[name].first += t->get<double>();
        ++tracking_sum[name].second;
      }
      if (const auto n = f.find("collisions"); n != f.end() && n->is_number()) {
        stats.collisions += n->get<int>();
      }
      if (const auto n = f.find("failsafe_events"); n != f.end() && n->is_number()) {
        stats.failsafe_events += n->get<int>();
      }
    }
  }
  std::vector<ClosedLoopStats> out;
  for (auto& [name, stats] : flights) {
    const auto& [sum, count] = tracking_sum[name];
    if (count > 0) stats.tracking_rmse_mean_m = sum / count;
    out.push_back(stats);
  }
  return out;
}

}  // namespace

ScenarioCheck EvaluateScenarioCheck(const harness::Scenario& scenario, std::vector<SeedRun> runs) {
  ScenarioCheck c;
  c.name = scenario.name;
  c.source_file = scenario.source_file;
  c.runs = std::move(runs);

  for (size_t i = 0; i < scenario.expect.size(); ++i) {
    const harness::Expectation& e = scenario.expect[i];
    c.expectations.push_back(AggregateExpectation(e, SeedOutcomes(c.runs, i, e)));
  }
  for (const SeedRun& r : c.runs) {
    if (r.error.empty() && r.exit_code == core::kExitOk) ++c.seeds_passed;
    if (!r.error.empty()) c.runs_ok = false;
    if (!r.client_failure.empty()) c.clients_ok = false;
  }
  c.methods = MethodStatsOverSeeds(c.runs);
  c.closed_loop = ClosedLoopStatsOverSeeds(c.runs);

  c.passed = c.runs_ok && c.clients_ok && !c.runs.empty() &&
             std::all_of(c.expectations.begin(), c.expectations.end(),
                         [](const AggregatedExpectation& a) { return a.passed; });
  return c;
}

std::string ExpectationLabel(const harness::Expectation& e) {
  std::string label = e.metric;
  if (e.relative_to) label += " / " + *e.relative_to;
  if (e.window_s) {
    label += fmt::format(" [{}, {}] s", FormatDouble(e.window_s->first),
                         FormatDouble(e.window_s->second));
  }
  if (e.min && e.max) {
    label += fmt::format(" in [{}, {}]", FormatDouble(*e.min), FormatDouble(*e.max));
  } else if (e.min) {
    label += " >= " + FormatDouble(*e.min);
  } else if (e.max) {
    label += " <= " + FormatDouble(*e.max);
  }
  return label;
}

std::string XmlEscape(std::string_view text, bool attribute) {
  std::string out;
  out.reserve(text.size());
  for (const char ch : text) {
    switch (ch) {
      case '&': out += "&amp;"; break;
      case '<': out += "&lt;"; break;
      case '>': out += "&gt;"; break;
      case '"': out += "&quot;"; break;
      case '\'': out += "&apos;"; break;
      case '\n': out += attribute ? "&#10;" : "\n"; break;
      case '\r': out += "&#13;"; break;  // a literal one would be normalised away
      case '\t': out += attribute ? "&#9;" : "\t"; break;
      default:
        // XML 1.0 has no way to hold the other C0 control characters, not even escaped.
        out += static_cast<unsigned char>(ch) < 0x20 || ch == 0x7f ? '?' : ch;
    }
  }
  return out;
}

namespace {

std::string XmlAttribute(std::string_view s) { return XmlEscape(s, true); }
std::string XmlText(std::string_view s) { return XmlEscape(s, false); }

// The runs themselves: fail when one exited with bad input or a failed simulation.
// Counts a failure into `failures`.
std::string RunTestCase(const ScenarioCheck& c, double time_s, int& failures) {
  std::set<uint64_t> broken;
  std::string run_errors;
  for (const SeedRun& r : c.runs) {
    if (r.error.empty()) continue;
    broken.insert(r.seed);
    run_errors += fmt::format("seed {}: {}\nlog: {}\n", r.seed, r.error, r.log_path);
  }
  std::string testcase =
      fmt::format("    <testcase name=\"run\" classname=\"{}\" file=\"{}\" time=\"{:.3f}\"",
                  XmlAttribute(c.name), XmlAttribute(c.source_file), time_s);
  if (broken.empty()) return testcase + "/>\n";
  ++failures;
  return testcase + fmt::format(
      ">\n      <failure message=\"{}\" type=\"run\">{}</failure>\n"
      "      <system-out>{}</system-out>\n    </testcase>\n",
      XmlAttribute(fmt::format("{} of {} runs failed", broken.size(), c.runs.size())),
      XmlText(run_errors), XmlText(FailureSystemOut(c, broken)));
}

// One test case per method or closed-loop flight that failed in some seed: the client's
// failure is its own, whatever the expectations say. Counts failures into `failures`.
std::string ClientTestCases(const ScenarioCheck& c, int& failures) {
  std::string cases;
  const auto add = [&](const std::string& name, int failed_seeds, const std::string& failure,
                       const std::string& key) {
    std::string seeds;
    std::string detail;
    for (const SeedRun& r : c.runs) {
      const auto* entry = r.summary.is_object() && r.summary.contains(key) &&
                                  r.summary[key].is_object() && r.summary[key].contains(name)
                              ? &r.summary[key][name]
                              : nullptr;
      if (entry == nullptr || !entry->is_object() || !entry->contains("failure") ||
          !(*entry)["failure"].is_string()) {
        continue;
      }
      seeds += fmt::format("{}{}", seeds.empty() ? "" : ", ", r.seed);
      detail += fmt::format("seed {}: {}\nlog: {}\n", r.seed, (*entry)["failure"].get<std::string>(),
                            r.log_path);
    }
    ++failures;
    const std::string label = key == "methods" ? "method " + name : "closed-loop flight on " + name;
    cases += fmt::format(
        "    <testcase name=\"{}\" classname=\"{}\" file=\"{}\" time=\"0\">\n"
        "      <failure message=\"{}\" type=\"client\">{}</failure>\n    </testcase>\n",
        XmlAttribute(label), XmlAttribute(c.name), XmlAttribute(c.source_file),
        XmlAttribute(fmt::format("{} failed in {} of {} seeds ({}): {}", label, failed_seeds,
                                 c.runs.size(), seeds, failure)),
        XmlText(detail));
  };
  for (const MethodStats& m : c.methods) {
    if (m.failed_seeds > 0) add(m.method, m.failed_seeds, m.failure, "methods");
  }
  for (const ClosedLoopStats& f : c.closed_loop) {
    if (f.failed_seeds > 0) add(f.method, f.failed_seeds, f.failure, "closed_loop");
  }
  return cases;
}

// Compared with a baseline: fails when a cell of the scenario regressed, with each
// regressed cell's figures. Counts a failure into `failures`.
std::string BaselineTestCase(const ScenarioCheck& c, int& failures) {
  if (!c.baseline_regressions && c.baseline_error.empty()) return {};
  std::string testcase =
      fmt::format("    <testcase name=\"compared with the baseline\" classname=\"{}\" file=\"{}\" "
                  "time=\"0\"",
                  XmlAttribute(c.name), XmlAttribute(c.source_file));
  if (!c.baseline_error.empty()) {
    ++failures;
    return testcase + fmt::format(
        ">\n      <failure message=\"{}\" type=\"baseline\"/>\n    </testcase>\n",
        XmlAttribute("not compared with the baseline: " + c.baseline_error));
  }
  const std::vector<std::string>& regressed = *c.baseline_regressions;
  if (regressed.empty()) return testcase + "/>\n";
  ++failures;
  std::string lines;
  for (const std::string& r : regressed) lines += r + "\n";
  return testcase + fmt::format(
      ">\n      <failure message=\"{}\" type=\"regression\">{}</failure>\n    </testcase>\n",
      XmlAttribute(fmt::format("{} regressed against the baseline: {}", regressed.size() == 1
                                                                         ? "1 cell"
                                                                         : fmt::format("{} cells", regressed.size()),
                               regressed.front())),
      XmlText(lines));
}

int ClientTestCaseCount(const ScenarioCheck& c) {
  int n = 0;
  for (const MethodStats& m : c.methods) n += m.failed_seeds > 0 ? 1 : 0;
  for (const ClosedLoopStats& f : c.closed_loop) n += f.failed_seeds > 0 ? 1 : 0;
  return n;
}

// One test case per expectation, aggregated over the seeds. Names are unique within a
// suite (a repeated label gets its source line). Counts failures into `failures`.
std::string ExpectationTestCases(const ScenarioCheck& c, int& failures) {
  std::string cases;
  std::map<std::string, int> label_count;
  for (const AggregatedExpectation& a : c.expectations) {
    ++label_count[ExpectationLabel(a.expectation)];
  }
  for (const AggregatedExpectation& a : c.expectations) {
    std::string name = ExpectationLabel(a.expectation);
    if (label_count[name] > 1) name += fmt::format(" (line {})", a.expectation.location.line);
    cases += fmt::format(
        "    <testcase name=\"{}\" classname=\"{}\" file=\"{}\" line=\"{}\" time=\"0\"",
        XmlAttribute(name), XmlAttribute(c.name), XmlAttribute(a.expectation.location.file),
        a.expectation.location.line);
    if (a.passed) {
      cases += "/>\n";
      continue;
    }
    ++failures;
    std::set<uint64_t> failed_seeds;
    for (const SeedOutcome& s : a.seeds) {
      if (!s.held) failed_seeds.insert(s.seed);
    }
    cases += fmt::format(
        ">\n      <failure message=\"{}\" type=\"expectation\">{}\n{}\nat {}</failure>\n"
        "      <system-out>{}</system-out>\n    </testcase>\n",
        XmlAttribute(fmt::format("{}: {}: {}", ExpectationLabel(a.expectation), AggregateMessage(a),
                                 SeedValues(a, "; "))),
        XmlText(AggregateMessage(a)), XmlText(SeedValues(a, "\n")), XmlText(Where(a.expectation)),
        XmlText(FailureSystemOut(c, failed_seeds)));
  }
  return cases;
}

// The <property> lines of the methods' and closed-loop flights' figures over the seeds.
std::string StatsProperties(const ScenarioCheck& c) {
  std::string properties;
  for (const MethodStats& m : c.methods) {
    if (m.ate_mean_m) {
      properties += fmt::format("      <property name=\"{}\" value=\"{}\"/>\n",
                                XmlAttribute(m.method + ".ate_mean_m"), FormatDouble(*m.ate_mean_m));
    }
    if (m.has_detections) {
      properties += fmt::format("      <property name=\"{}\" value=\"{}/{}\"/>\n",
                                XmlAttribute(m.method + ".faults_detected"), m.faults_detected,
                                m.faults);
    }
  }
  for (const ClosedLoopStats& f : c.closed_loop) {
    if (f.tracking_rmse_mean_m) {
      properties += fmt::format("      <property name=\"{}\" value=\"{}\"/>\n",
                                XmlAttribute("closed_loop." + f.method + ".tracking_rmse_mean_m"),
                                FormatDouble(*f.tracking_rmse_mean_m));
    }
    properties += fmt::format("      <property name=\"{}\" value=\"{}\"/>\n",
                              XmlAttribute("closed_loop." + f.method + ".collisions"), f.collisions);
    properties += fmt::format("      <property name=\"{}\" value=\"{}\"/>\n",
                              XmlAttribute("closed_loop." + f.method + ".failsafe_events"),
                              f.failsafe_events);
  }
  return properties;
}

}  // namespace

std::string CheckJUnitXml(const std::vector<ScenarioCheck>& checks) {
  int total_tests = 0, total_failures = 0;
  double total_time = 0.0;
  std::string suites;
  for (const ScenarioCheck& c : checks) {
    double time = 0.0;
    for (const SeedRun& r : c.runs) time += r.wall_time_s;
    int failures = 0;
    std::string cases = RunTestCase(c, time, failures);
    cases += ClientTestCases(c, failures);
    cases += BaselineTestCase(c, failures);
    cases += ExpectationTestCases(c, failures);

    const int tests = 1 + ClientTestCaseCount(c) +
                      (c.baseline_regressions || !c.baseline_error.empty() ? 1 : 0) +
                      static_cast<int>(c.expectations.size());
    std::string seeds;
    for (const SeedRun& r : c.runs) seeds += fmt::format("{}{}", seeds.empty() ? "" : ",", r.seed);
    suites += fmt::format(
        "  <testsuite name=\"{}\" tests=\"{}\" failures=\"{}\" errors=\"0\" skipped=\"0\" "
        "time=\"{:.3f}\" file=\"{}\">\n"
        "    <properties>\n"
        "      <property name=\"seeds\" value=\"{}\"/>\n"
        "      <property name=\"seeds_passed\" value=\"{}\"/>\n",
        XmlAttribute(c.name), tests, failures, time, XmlAttribute(c.source_file), seeds,
        c.seeds_passed);
    suites += StatsProperties(c);
    suites += "    </properties>\n" + cases + "  </testsuite>\n";
    total_tests += tests;
    total_failures += failures;
    total_time += time;
  }
  return fmt::format(
      "<?xml version=\"1.0\" encoding=\"UTF-8\"?>\n"
      "<testsuites name=\"tofu check\" tests=\"{}\" failures=\"{}\" errors=\"0\" "
      "time=\"{:.3f}\">\n{}</testsuites>\n",
      total_tests, total_failures, total_time, suites);
}

// ---- the command ----

namespace {

// The runs of the grid that `shard` owns (all of it without one), longest simulated
// scenarios first. Nothing is touched on disk.
std::vector<Job> PlanRuns(const std::vector<harness::Scenario>& scenarios, const CheckGrid& grid,
                          const harness::Shard& shard, const fs::path& out) {
  std::vector<Job> queue;
  for (uint64_t cell = 0; cell < grid.Cells(); ++cell) {
    if (!shard.Owns(cell)) continue;
    Job job;
    job.cell = cell;
    job.scenario_index = cell / static_cast<uint64_t>(grid.seeds);
    job.scenario_path = scenarios[job.scenario_index].source_file;
    job.label = grid.scenarios[job.scenario_index].name;
    job.run.seed = grid.SeedOf(cell);
    job.run.run_dir = grid.RunDirectory(out, cell).string();
    job.run.log_path = job.run.run_dir + ".log";
    queue.push_back(std::move(job));
  }
  // Longest simulated scenarios first: the suite ends sooner when its longest run does not
  // start last (stable, so seeds keep their order; the report does not depend on it).
  std::stable_sort(queue.begin(), queue.end(), [&](const Job& a, const Job& b) {
    return scenarios[a.scenario_index].duration_s > scenarios[b.scenario_index].duration_s;
  });
  return queue;
}

// Each scenario's folder under `out` made, with what an earlier check left of the runs
// this process will make removed: every seed on one machine (stale seeds beyond --seeds
// are not taken for this check's), a shard's own seeds only (other shards may be writing
// beside it; the merge removes the rest). Shard records that would describe other runs
// go too.
void PrepareRunFolders(const CheckGrid& grid, const harness::Shard& shard, const fs::path& out) {
  for (size_t i = 0; i < grid.scenarios.size(); ++i) {
    const CheckGrid::Entry& e = grid.scenarios[i];
    const uint64_t first_cell = i * static_cast<uint64_t>(grid.seeds);
    RemoveStaleRuns(out / e.name, [&](uint64_t seed) {
      if (shard.origin.empty()) return true;
      const bool in_grid =
          seed >= e.first_seed && seed - e.first_seed < static_cast<uint64_t>(grid.seeds);
      return in_grid && shard.Owns(first_cell + (seed - e.first_seed));
    });
    fs::create_directories(out / e.name);
  }
  RemoveShardRecords(out, shard);
}

// A shard's end: its record, which the merge needs to take its runs as one machine's.
int FinishShard(const CheckCommandOptions& options, const CheckGrid& grid,
                const std::vector<Job>& queue, const fs::path& out) {
  std::map<uint64_t, RecordedRun> runs;
  for (const Job& job : queue) {
    runs[job.cell] = {job.run.exit_code, job.run.error, job.run.wall_time_s};
  }
  try {
    WriteShardRecord(out, options.shard, grid, runs);
  } catch (const core::IoError& e) {
    fmt::print(stderr, "tofu: error: {}\n", e.what());
    return core::kExitIoError;
  }
  if (!options.quiet) {
    fmt::print("shard {}/{}: {} runs recorded in {}; the check's verdict is the merge's "
               "(tofu check ... --merge)\n",
               options.shard.index, options.shard.count, queue.size(),
               (out / ShardRecordName(options.shard)).string());
  }
  return core::kExitOk;
}

// The merge in place of the pool: every run of the grid as the shards recorded it, its
// files gathered under `out`. False (said why) when the shards do not make up the grid.
bool TakeShardRuns(const CheckCommandOptions& options, const CheckGrid& grid,
                   std::vector<Job>& queue, const fs::path& out) {
  std::map<uint64_t, RecordedRun> runs;
  try {
    runs = MergeShards(options.merge_dirs, grid, out);
  } catch (const InputError& e) {
    fmt::print(stderr, "tofu: error: {}\n", e.what());
    return false;
  }
  for (Job& job : queue) {
    const RecordedRun& r = runs.at(job.cell);
    job.run.exit_code = r.exit_code;
    job.run.error = r.error;
    job.run.wall_time_s = r.wall_time_s;
  }
  if (!options.quiet) {
    fmt::print(stderr, "tofu check: merged {} shard directories: {} scenarios x {} seeds = {} "
                       "runs -> {}\n",
               options.merge_dirs.size(), grid.scenarios.size(), grid.seeds, queue.size(),
               out.string());
  }
  return true;
}

// What went wrong over all runs of the check.
struct CheckFailures {
  bool bad_input = false;
  bool io_failed = false;
  bool simulation_failed = false;
  bool client_failed = false;
  bool expectation_failed = false;
};

// Aggregate per scenario, in input order, runs in seed order.
std::vector<ScenarioCheck> CheckScenarios(const std::vector<harness::Scenario>& scenarios,
                                          std::vector<Job>& queue, CheckFailures& failures) {
  std::vector<std::vector<SeedRun>> runs(scenarios.size());
  for (Job& job : queue) {
    ReadSummary(job.run);
    runs[job.scenario_index].push_back(std::move(job.run));
  }
  std::vector<ScenarioCheck> checks;
  for (size_t i = 0; i < scenarios.size(); ++i) {
    checks.push_back(EvaluateScenarioCheck(scenarios[i], std::move(runs[i])));
    const ScenarioCheck& c = checks.back();
    for (const SeedRun& r : c.runs) {
      failures.bad_input = failures.bad_input || r.exit_code == core::kExitBadInput;
      failures.io_failed = failures.io_failed || r.exit_code == core::kExitIoError;
      failures.simulation_failed = failures.simulation_failed || !r.error.empty();
      failures.client_failed = failures.client_failed || !r.client_failure.empty();
    }
    failures.expectation_failed = failures.expectation_failed || !c.passed;
  }
  return checks;
}

// <out>/check.json: the grid and every run's exit status, with the tofu that ran them:
// what `tofu compare` reads a check directory by (campaign/cell_record.h).
void WriteCheckRecord(const fs::path& out, const CheckGrid& grid,
                      const std::vector<harness::Scenario>& loaded,
                      const std::vector<ScenarioCheck>& checks) {
  nlohmann::json scenarios = nlohmann::json::array();
  for (size_t i = 0; i < grid.scenarios.size(); ++i) {
    const CheckGrid::Entry& e = grid.scenarios[i];
    nlohmann::json entry = {{"name", e.name}, {"fnv1a64", e.fnv1a64}, {"first_seed", e.first_seed}};
    if (!loaded[i].compare_minimal_effects.empty()) {
      entry["minimal_effects"] = loaded[i].compare_minimal_effects;
    }
    scenarios.push_back(std::move(entry));
  }
  nlohmann::json runs = nlohmann::json::array();
  for (const ScenarioCheck& c : checks) {
    for (const SeedRun& r : c.runs) {
      runs.push_back({{"scenario", c.name},
                      {"seed", r.seed},
                      {"exit_code", r.exit_code},
                      {"error", r.error},
                      {"client_failure", r.client_failure},
                      {"wall_time_s", r.wall_time_s}});
    }
  }
  const nlohmann::json record = {{"format", kCheckRecordFormat},
                                 {"version", 1},
                                 {"tofu_version", core::TofuVersion()},
                                 {"tofu_commit", core::TofuCommit()},
                                 {"seeds", grid.seeds},
                                 {"scenarios", scenarios},
                                 {"runs", runs}};
  WriteFileAtomically(out / kCheckRecordFile, record.dump(1) + "\n", "--out");
}

// The campaign the grid will be: its cells with no values yet, for matching a baseline
// to the grid before anything runs.
CampaignRecord PlannedCampaign(const CheckGrid& grid, const fs::path& out) {
  CampaignRecord planned;
  planned.source = out;
  planned.tofu_version = core::TofuVersion();
  planned.tofu_commit = core::TofuCommit();
  planned.metric_versions = CurrentMetricVersions();
  for (uint64_t cell = 0; cell < grid.Cells(); ++cell) {
    CellRecord record;
    record.scenario = grid.ScenarioOf(cell).name;
    record.seed = grid.SeedOf(cell);
    record.scenario_hash = grid.ScenarioOf(cell).fnv1a64;
    planned.cells.push_back(std::move(record));
  }
  return planned;
}

// The baseline of --baseline, matched to the grid: another grid, scenario file, tofu or
// metric definition is bad input before anything runs.
CampaignRecord ReadMatchingBaseline(const std::string& path, const CheckGrid& grid,
                                    const fs::path& out) {
  CampaignRecord baseline = ReadCampaign(path);
  CompareCampaigns(baseline, PlannedCampaign(grid, out), CompareOptions{});
  return baseline;
}

// The check against its baseline: <out>/compare.md and compare.json, and each scenario's
// regressed cells. Returns false (printed) when the finished check cannot be compared.
bool CompareWithBaseline(const CampaignRecord& baseline, const fs::path& out,
                         std::vector<ScenarioCheck>& checks, bool quiet, bool& regressed) {
  Comparison comparison;
  try {
    comparison = CompareCampaigns(baseline, ReadCheckDirectory(out), CompareOptions{});
  } catch (const InputError& e) {
    fmt::print(stderr, "tofu: error: --baseline: {}\n", e.what());
    for (ScenarioCheck& c : checks) c.baseline_error = e.what();
    return false;
  }
  WriteFileAtomically(out / kCompareMarkdownFile, ComparisonMarkdown(comparison), "--out");
  WriteFileAtomically(out / kCompareJsonFile, ComparisonJson(comparison).dump(1) + "\n", "--out");
  for (ScenarioCheck& c : checks) c.baseline_regressions.emplace();
  for (const CellComparison& cell : comparison.cells) {
    if (cell.verdict != Verdict::kRegressed) continue;
    regressed = true;
    for (ScenarioCheck& c : checks) {
      if (c.name == cell.scenario) c.baseline_regressions->push_back(CellFigures(cell));
    }
  }
  if (!quiet || regressed) {
    fmt::print("compared with the baseline {}: {} cells, {} regressed, {} improved, {} "
               "inconclusive, {} unchanged (tofu compare; {})\n",
               baseline.source.string(), comparison.cells.size(),
               comparison.Count(Verdict::kRegressed), comparison.Count(Verdict::kImproved),
               comparison.Count(Verdict::kInconclusive), comparison.Count(Verdict::kUnchanged),
               (out / kCompareMarkdownFile).string());
    for (const ScenarioCheck& c : checks) {
      for (const std::string& line : *c.baseline_regressions) {
        fmt::print("  REGRESSED {}: {}\n", c.name, line);
      }
    }
  }
  return true;
}

// After the runs (or the merge): the table, the JUnit and the method tables of the whole
// grid, the check's record, the comparison with the baseline, and the check's exit code.
int ReportCheck(const CheckCommandOptions& options, const std::vector<harness::Scenario>& scenarios,
                const CheckGrid& grid, std::vector<Job>& queue, const fs::path& out,
                const std::optional<CampaignRecord>& baseline) {
  CheckFailures failures;
  std::vector<ScenarioCheck> checks = CheckScenarios(scenarios, queue, failures);
  bool regressed = false;
  // An earlier check's comparison is never taken for this one's.
  std::error_code ignored;
  fs::remove(out / kCompareMarkdownFile, ignored);
  fs::remove(out / kCompareJsonFile, ignored);
  try {
    WriteCheckRecord(out, grid, scenarios, checks);
    if (!options.quiet) PrintTable(checks);
    if (baseline && !CompareWithBaseline(*baseline, out, checks, options.quiet, regressed)) {
      failures.bad_input = true;
    }
  } catch (const core::IoError& e) {
    fmt::print(stderr, "tofu: error: {}\n", e.what());
    return core::kExitIoError;
  }

  PrintFailures(checks);
  if (options.junit_path) {
    try {
      WriteFileAtomically(*options.junit_path, CheckJUnitXml(checks), "--junit");
    } catch (const core::IoError& e) {
      fmt::print(stderr, "tofu: error: {}\n", e.what());
      return core::kExitIoError;
    }
    if (!options.quiet) fmt::print("JUnit XML: {}\n", *options.junit_path);
  }
  try {  // <out>/methods.csv, .md, .png: the estimation methods over the seeds
    const auto table = WriteCheckMethods(out, scenarios, checks);
    if (table && !options.quiet) fmt::print("method table: {}\n", table->string());
  } catch (const core::IoError& e) {
    fmt::print(stderr, "tofu: error: {}\n", e.what());
    return core::kExitIoError;
  }
  // One code per run of the check, the most fundamental cause first: the user's input,
  // the machine's storage, the simulation, then the expectations.
  if (failures.bad_input) return core::kExitBadInput;
  if (failures.io_failed) return core::kExitIoError;
  if (failures.simulation_failed) return core::kExitSimulationError;
  if (failures.client_failed) return core::kExitClientFailed;
  return failures.expectation_failed || regressed ? core::kExitExpectationFailed : core::kExitOk;
}

}  // namespace

void CheckScenarioMinimalEffects(const harness::Scenario& scenario) {
  RequireKnownMinimalEffects(
      scenario.compare_minimal_effects,
      [&](const std::string& name) {
        const auto it = scenario.key_locations.find("compare.minimal_effects." + name);
        return it != scenario.key_locations.end() ? it->second
                                                  : core::SourceLocation{scenario.source_file, 0, 0};
      },
      "compare.minimal_effects.");
}

int RunCheckCommand(const CheckCommandOptions& options) {
  // Everything that can be wrong with the input is found before anything runs or is
  // written.
  std::vector<harness::Scenario> scenarios;
  CheckGrid grid;
  std::optional<CampaignRecord> baseline;
  const fs::path out = fs::absolute(options.out_dir).lexically_normal();
  try {
    ValidateOptions(options);
    const std::vector<std::string> paths =
        ExpandScenarioInputs(options.inputs.empty() ? std::vector<std::string>{"scenarios"}
                                                    : options.inputs);
    if (!LoadAll(paths, scenarios)) return core::kExitBadInput;
    grid = MakeCheckGrid(scenarios, options.seeds);
    if (options.baseline_path) baseline = ReadMatchingBaseline(*options.baseline_path, grid, out);
  } catch (const InputError& e) {
    fmt::print(stderr, "tofu: error: {}\n", e.what());
    return core::kExitBadInput;
  }

  std::vector<Job> queue = PlanRuns(scenarios, grid, options.shard, out);
  if (!options.merge_dirs.empty()) {
    if (!TakeShardRuns(options, grid, queue, out)) return core::kExitBadInput;
    return ReportCheck(options, scenarios, grid, queue, out, baseline);
  }
  PrepareRunFolders(grid, options.shard, out);
  const std::string binary = options.tofu_binary.empty() ? SelfExecutable() : options.tofu_binary;
  int jobs = options.jobs;
  if (jobs == 0) jobs = core::UsableCores();
  if (!options.quiet) {
    const std::string part =
        options.shard.origin.empty()
            ? std::string()
            : fmt::format("shard {}/{} (from {}) of ", options.shard.index, options.shard.count,
                          options.shard.origin);
    fmt::print(stderr, "tofu check: {}{} scenarios x {} seeds: {} runs, {} at a time -> {}\n",
               part, scenarios.size(), options.seeds, queue.size(), jobs, out.string());
  }
  std::vector<RunRequest*> requests;
  for (Job& job : queue) requests.push_back(&job);
  RunPool(binary, requests, jobs, options.quiet, "check");
  if (!options.shard.origin.empty()) return FinishShard(options, grid, queue, out);
  return ReportCheck(options, scenarios, grid, queue, out, baseline);
}

}  // namespace tofu::campaign
