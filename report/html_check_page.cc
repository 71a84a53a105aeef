#include "report/html_check_page.h"

#include <algorithm>
#include <cmath>

#include <fmt/format.h>
#include <nlohmann/json.hpp>

#include "campaign/cell_record.h"
#include "campaign/compare.h"
#include "core/error.h"
#include "renders/run_data.h"
#include "report/html_page.h"
#include "report/html_run_page.h"

namespace tofu::report::html {

namespace fs = std::filesystem;
using core::InputError;
using nlohmann::json;

namespace {

// "file:line" of summary.json's `where` as a location.
core::SourceLocation ParseWhere(const std::string& where) {
  core::SourceLocation location;
  const size_t colon = where.rfind(':');
  if (colon == std::string::npos) {
    location.file = where;
    return location;
  }
  location.file = where.substr(0, colon);
  try {
    location.line = std::stoi(where.substr(colon + 1));
  } catch (const std::exception&) {
    location.file = where;
  }
  return location;
}

// The scenario's expectations as `tofu check` aggregated them: bounds and places from a
// run's summary.json, pass_fraction from its resolved scenario.yaml.
harness::Scenario ScenarioOfRuns(const std::string& name, const std::vector<CheckRun>& runs) {
  harness::Scenario scenario;
  scenario.name = name;
  for (const CheckRun& r : runs) {
    if (!r.scenario || !r.run.summary.is_object()) continue;
    const json& list = r.run.summary.value("expectations", json::array());
    const YAML::Node expect = r.scenario->root["expect"];
    for (size_t i = 0; i < list.size(); ++i) {
      const json& e = list[i];
      harness::Expectation x;
      x.metric = StringField(e, "metric");
      x.min = OptionalNumber(e, "min");
      x.max = OptionalNumber(e, "max");
      if (const std::string rel = StringField(e, "relative_to"); !rel.empty()) x.relative_to = rel;
      if (const auto w = e.find("window_s"); e.is_object() && w != e.end() && w->is_array() &&
                                             w->size() == 2 && (*w)[0].is_number() &&
                                             (*w)[1].is_number()) {
        x.window_s = std::make_pair((*w)[0].get<double>(), (*w)[1].get<double>());
      }
      x.location = ParseWhere(StringField(e, "where"));
      if (expect && expect.IsSequence() && i < expect.size() && expect[i].IsMap() &&
          expect[i]["pass_fraction"]) {
        try {
          x.pass_fraction = expect[i]["pass_fraction"].as<double>();
        } catch (const YAML::Exception&) {
          // A resolved scenario always has a number here; keep the default (every seed).
        }
      }
      scenario.expect.push_back(std::move(x));
    }
    if (!scenario.expect.empty()) scenario.source_file = scenario.expect.front().location.file;
    break;
  }
  return scenario;
}

}  // namespace

// The runs of one scenario folder, their summaries read (a check may hold thousands of
// runs: their pages are written one at a time, WriteCheckPages).
CheckScenario ReadCheckScenario(const fs::path& check_dir, const std::string& name) {
  CheckScenario sc;
  sc.name = name;
  const fs::path dir = check_dir / name;
  for (const uint64_t seed : SeedsIn(dir)) {
    CheckRun r;
    r.run.seed = seed;
    r.run.run_dir = (dir / fmt::format("seed_{}", seed)).string();
    r.run.log_path = (dir / fmt::format("seed_{}.log", seed)).string();
    r.log_tail = LogTailText(r.run.log_path, 12);
    if (!IsRunDirectory(r.run.run_dir)) {
      r.run.exit_code = core::kExitBadInput;
      r.run.error = "no run directory: the run was refused or did not start (see its log)";
      sc.runs.push_back(std::move(r));
      continue;
    }
    try {
      r.run.summary = renders::ReadRunJson(fs::path(r.run.run_dir) / "summary.json");
      if (!r.run.summary.is_object()) {
        throw InputError({(fs::path(r.run.run_dir) / "summary.json").string(), 1, 1}, "",
                         "expected a JSON object");
      }
      r.scenario = ReadScenarioFile(fs::path(r.run.run_dir) / "scenario.yaml");
      const std::string failure = StringField(r.run.summary, "failure");
      // As `tofu run` exits: 3 when the simulation failed, 5 when a user's client did, else
      // 1 when an expectation (or a closed-loop flight) failed.
      if (!failure.empty() && StringField(r.run.summary, "failure_kind") == "client") {
        r.run.exit_code = core::kExitClientFailed;
        r.run.client_failure = failure;
      } else if (!failure.empty()) {
        r.run.exit_code = core::kExitSimulationError;
        r.run.error = "simulation failed: " + failure;
      } else {
        r.run.exit_code =
            r.run.summary.value("passed", false) ? core::kExitOk : core::kExitExpectationFailed;
      }
    } catch (const InputError& e) {
      r.read_error = e.what();
      r.run.exit_code = core::kExitSimulationError;
      r.run.error = std::string("unreadable run directory: ") + e.what();
    }
    sc.runs.push_back(std::move(r));
  }
  return sc;
}

// Writes each run's page (and log) under <staging>/<scenario>/seed_<s>/, reading one run
// at a time; a run whose files are malformed gets no page but a red row saying why. Then
// aggregates the scenario as `tofu check` does.
void WriteCheckPages(CheckScenario& sc, const fs::path& staging) {
  for (CheckRun& r : sc.runs) {
    const fs::path seed_dir = staging / sc.name / fmt::format("seed_{}", r.run.seed);
    std::string log_href;
    if (fs::is_regular_file(r.run.log_path)) {
      fs::create_directories(seed_dir);
      fs::copy_file(r.run.log_path, seed_dir / "run.log", fs::copy_options::overwrite_existing);
      log_href = "run.log";
    }
    if (!r.read_error.empty() || !IsRunDirectory(r.run.run_dir)) continue;
    try {
      const RunInputs inputs = ReadRunInputs(r.run.run_dir);
      WriteRunPage(inputs, PageContext{seed_dir, "../../index.html", log_href});
      r.has_page = true;
    } catch (const InputError& e) {
      r.read_error = e.what();
      r.run.exit_code = core::kExitSimulationError;
      r.run.error = std::string("unreadable run directory: ") + e.what();
    }
  }
  std::vector<campaign::SeedRun> runs;
  for (const CheckRun& r : sc.runs) runs.push_back(r.run);
  sc.check = campaign::EvaluateScenarioCheck(ScenarioOfRuns(sc.name, sc.runs), std::move(runs));
}

namespace {

fs::path RunPagePath(const std::string& scenario, uint64_t seed) {
  return fs::path(scenario) / fmt::format("seed_{}", seed) / "index.html";
}

std::string RunVerdict(const CheckRun& r) {
  if (!r.read_error.empty()) return "unreadable";
  switch (r.run.exit_code) {
    case core::kExitOk:
      return "passed";
    case core::kExitExpectationFailed:
      return "expectation failed";
    case core::kExitBadInput:
      return "no run";
    default:
      return "simulation failed";
  }
}

std::string SeedLink(const CheckScenario& sc, const CheckRun& r) {
  if (r.has_page) {
    return fmt::format("<a href=\"{}\">seed {}</a>", Href(RunPagePath(sc.name, r.run.seed)),
                       r.run.seed);
  }
  return fmt::format("seed {}", r.run.seed);
}

std::string ScenarioResult(const campaign::ScenarioCheck& c) {
  if (!c.runs_ok) return "<span class=\"badge fail\">ERROR</span>";
  return Badge(c.passed, "pass", "FAIL");
}

std::string CheckSummaryTable(const std::vector<CheckScenario>& scenarios) {
  std::string rows;
  for (const CheckScenario& sc : scenarios) {
    const campaign::ScenarioCheck& c = sc.check;
    int held = 0;
    for (const auto& a : c.expectations) held += a.passed ? 1 : 0;
    std::string methods;
    for (const campaign::MethodStats& m : c.methods) {
      methods += fmt::format(
          "<div><code>{}</code> {}{}</div>", E(m.method),
          m.ate_mean_m ? Number(*m.ate_mean_m) + " m" : "–",
          m.has_detections ? fmt::format(", {}/{} faults detected", m.faults_detected, m.faults)
                           : "");
    }
    for (const campaign::ClosedLoopStats& f : c.closed_loop) {
      methods += fmt::format("<div>flown on <code>{}</code>: trk {}, {} hits</div>", E(f.method),
                             f.tracking_rmse_mean_m ? Number(*f.tracking_rmse_mean_m) + " m" : "–",
                             f.collisions);
    }
    std::string seeds;
    for (const CheckRun& r : sc.runs) {
      const bool ok = r.run.error.empty() && r.run.exit_code == core::kExitOk;
      seeds +=
          fmt::format("<span class=\"chip {}\">{}</span> ", ok ? "pass" : "fail", SeedLink(sc, r));
    }
    const bool ok = c.passed;
    rows += fmt::format(
        "<tr class=\"{}\"><td><a href=\"#scenario-{}\"><code>{}</code></a></td><td "
        "class=\"result\">{}</td>"
        "<td class=\"num\">{}/{}</td><td class=\"num\">{}/{}</td><td>{}</td><td>{}</td></tr>\n",
        ok ? "pass" : "fail", E(sc.name), E(sc.name), ScenarioResult(c), c.seeds_passed,
        c.runs.size(), held, c.expectations.size(), methods.empty() ? "–" : methods, seeds);
  }
  return fmt::format(
      "<table class=\"overview\">\n<thead><tr><th>scenario</th><th>result</th><th>seeds passed</th>"
      "<th>expectations held</th><th>methods: mean ATE over the "
      "seeds</th><th>runs</th></tr></thead>\n"
      "<tbody>\n{}</tbody>\n</table>\n",
      rows);
}

// The matrix's first row: how each seed's run went.
std::string RunRow(const CheckScenario& sc) {
  const campaign::ScenarioCheck& c = sc.check;
  std::string cells;
  for (const CheckRun& r : sc.runs) {
    // A run that worked but failed an expectation is no error of the run: neutral here,
    // red in the expectation's row.
    const char* style = !r.run.error.empty() || r.run.exit_code == core::kExitBadInput ? "fail"
                        : r.run.exit_code == core::kExitOk                             ? "pass"
                                                           : "neutral";
    cells += fmt::format("<td class=\"cell {}\">{}</td>", style, E(RunVerdict(r)));
  }
  return fmt::format(
      "<tr class=\"{}\"><td>run</td><td class=\"num\">–</td>{}<td "
      "class=\"result\">{}</td></tr>\n",
      c.runs_ok ? "pass" : "fail", cells, c.runs_ok ? "ok" : "ERROR");
}

// A row of the matrix: the expectation's value in each seed, and its verdict over them.
std::string ExpectationRow(const campaign::AggregatedExpectation& a) {
  std::string cells;
  for (const campaign::SeedOutcome& o : a.seeds) {
    cells += fmt::format("<td class=\"cell num {}\">{} {}</td>", o.held ? "pass" : "fail",
                         o.value ? Number(*o.value) : "n/a", o.held ? "✔" : "✘");
  }
  return fmt::format(
      "<tr class=\"{}\"><td><code>{}</code><div class=\"where\">{}</div></td><td "
      "class=\"num\">{}/{}</td>{}"
      "<td class=\"result\">{}</td></tr>\n",
      a.passed ? "pass" : "fail", E(campaign::ExpectationLabel(a.expectation)),
      E(fmt::format("{}:{}", a.expectation.location.file, a.expectation.location.line)),
      a.required, a.seeds.size(), cells,
      a.passed ? fmt::format("held {}/{}", a.held, a.seeds.size())
               : fmt::format("FAIL {}/{}", a.held, a.seeds.size()));
}

// The matrix: expectations by seeds.
std::string ExpectationMatrix(const CheckScenario& sc) {
  std::string head;
  for (const CheckRun& r : sc.runs) head += fmt::format("<th>{}</th>", SeedLink(sc, r));
  std::string rows = RunRow(sc);
  for (const campaign::AggregatedExpectation& a : sc.check.expectations) rows += ExpectationRow(a);
  return fmt::format(
      "<table "
      "class=\"matrix\">\n<thead><tr><th>expectation</th><th>needs</th>{}<th>result</th></tr></"
      "thead>\n"
      "<tbody>\n{}</tbody>\n</table>\n",
      head, rows);
}

// Methods per seed (ATE) and closed-loop flights per seed (tracking RMSE); none without
// either.
std::string MethodsPerSeedTable(const CheckScenario& sc) {
  const campaign::ScenarioCheck& c = sc.check;
  if (c.methods.empty() && c.closed_loop.empty()) return "";
  std::string mrows;
  for (const campaign::MethodStats& m : c.methods) {
    std::string cells;
    for (const CheckRun& r : sc.runs) {
      const json methods = r.run.summary.is_object()
                               ? r.run.summary.value("methods", json::object())
                               : json::object();
      cells += fmt::format("<td class=\"num\">{}</td>",
                           Field(methods.value(m.method, json::object()), "ate_m"));
    }
    mrows += fmt::format(
        "<tr><td><code>{}</code></td>{}<td class=\"num\">{}</td><td class=\"num\">{}</td></tr>\n",
        E(m.method), cells, m.ate_mean_m ? Number(*m.ate_mean_m) : "–",
        m.has_detections ? fmt::format("{}/{}", m.faults_detected, m.faults) : "–");
  }
  for (const campaign::ClosedLoopStats& f : c.closed_loop) {
    std::string cells;
    for (const CheckRun& r : sc.runs) {
      const json flights = r.run.summary.is_object()
                               ? r.run.summary.value("closed_loop", json::object())
                               : json::object();
      cells += fmt::format("<td class=\"num\">{}</td>",
                           Field(flights.value(f.method, json::object()), "tracking_rmse_m"));
    }
    mrows += fmt::format(
        "<tr class=\"{}\"><td>flown on <code>{}</code> (tracking RMSE)</td>{}<td "
        "class=\"num\">{}</td>"
        "<td class=\"num\">{} hits, {} failsafe</td></tr>\n",
        f.collisions > 0 ? "fail" : "", E(f.method), cells,
        f.tracking_rmse_mean_m ? Number(*f.tracking_rmse_mean_m) : "–", f.collisions,
        f.failsafe_events);
  }
  std::string mhead;
  for (const CheckRun& r : sc.runs) mhead += fmt::format("<th>seed {}</th>", r.run.seed);
  return fmt::format(
      "<h3>Methods [m]</h3>\n<table>\n<thead><tr><th>method "
      "(ATE)</th>{}<th>mean</th><th>detected / "
      "collisions</th></tr></thead>\n<tbody>\n{}</tbody>\n</table>\n",
      mhead, mrows);
}

// Why runs failed.
std::string RunFailureNotes(const CheckScenario& sc) {
  std::string out;
  for (const CheckRun& r : sc.runs) {
    if (r.run.error.empty()) continue;
    out += fmt::format("<div class=\"failure\"><strong>seed {}:</strong> {}", r.run.seed,
                       E(r.run.error));
    if (fs::is_regular_file(r.run.log_path)) {
      out += fmt::format(" (<a href=\"{}\">log</a>)",
                         Href(fs::path(sc.name) / fmt::format("seed_{}", r.run.seed) / "run.log"));
    }
    if (!r.log_tail.empty()) out += fmt::format("<pre>{}</pre>", E(r.log_tail));
    out += "</div>\n";
  }
  return out;
}

std::string ScenarioDetail(const CheckScenario& sc) {
  const campaign::ScenarioCheck& c = sc.check;
  std::string out =
      fmt::format("<section class=\"scenario\" id=\"scenario-{}\">\n<h2><code>{}</code> {}</h2>\n",
                  E(sc.name), E(sc.name), ScenarioResult(c));
  if (!c.source_file.empty()) out += fmt::format("<p class=\"muted\">{}</p>\n", E(c.source_file));
  out += ExpectationMatrix(sc);
  out += MethodsPerSeedTable(sc);
  out += RunFailureNotes(sc);
  return out + "</section>\n";
}


// ---- the comparison with a baseline (<check>/compare.json of tofu check --baseline) ----

// A cell's per-seed pairs as a slope chart: the base on the left, the new on the right,
// one line per seed; a log axis for an error's scale (a ratio metric). Events (0/1) as the
// counts on each side.
std::string SlopeChart(const json& cell) {
  const bool ratio = cell.value("kind", "") == "ratio";
  std::vector<std::pair<double, double>> pairs;
  std::vector<double> all;
  for (const json& s : cell.value("seeds", json::array())) {
    if (!s.is_object() || !s.value("base", json()).is_number() ||
        !s.value("new", json()).is_number()) {
      continue;
    }
    const double b = s.at("base").get<double>(), n = s.at("new").get<double>();
    if (ratio && (b <= 0.0 || n <= 0.0)) continue;
    pairs.emplace_back(b, n);
    all.push_back(b);
    all.push_back(n);
  }
  if (pairs.empty()) return "<span class=\"muted\">no pairs</span>";
  const auto scale = [&](double v) { return ratio ? std::log(v) : v; };
  double lo = scale(*std::min_element(all.begin(), all.end()));
  double hi = scale(*std::max_element(all.begin(), all.end()));
  if (hi - lo < 1e-12) {
    lo -= 1.0;
    hi += 1.0;
  }
  constexpr double kWidth = 180, kHeight = 96, kLeft = 40, kRight = 140, kTop = 8, kBottom = 84;
  const auto y = [&](double v) { return kBottom - (scale(v) - lo) / (hi - lo) * (kBottom - kTop); };
  const std::string verdict = cell.value("verdict", "");
  const char* color = verdict == "regressed" ? "#cf222e" : verdict == "improved" ? "#1a7f37"
                      : verdict == "unchanged" ? "#0969da" : "#6e7781";
  std::string svg = fmt::format(
      "<svg class=\"slope\" width=\"{}\" height=\"{}\" viewBox=\"0 0 {} {}\" role=\"img\">"
      "<line x1=\"{}\" y1=\"{}\" x2=\"{}\" y2=\"{}\" stroke=\"#d0d7de\"/>"
      "<line x1=\"{}\" y1=\"{}\" x2=\"{}\" y2=\"{}\" stroke=\"#d0d7de\"/>",
      kWidth, kHeight, kWidth, kHeight, kLeft, kTop, kLeft, kBottom, kRight, kTop, kRight, kBottom);
  for (const auto& [b, n] : pairs) {
    svg += fmt::format(
        "<line x1=\"{}\" y1=\"{:.1f}\" x2=\"{}\" y2=\"{:.1f}\" stroke=\"{}\" stroke-opacity=\"0.7\"/>"
        "<circle cx=\"{}\" cy=\"{:.1f}\" r=\"2.2\" fill=\"{}\"/><circle cx=\"{}\" cy=\"{:.1f}\" "
        "r=\"2.2\" fill=\"{}\"/>",
        kLeft, y(b), kRight, y(n), color, kLeft, y(b), color, kRight, y(n), color);
  }
  const double top = ratio ? std::exp(hi) : hi, bottom = ratio ? std::exp(lo) : lo;
  svg += fmt::format(
      "<text x=\"{}\" y=\"{}\" font-size=\"9\" text-anchor=\"end\">{:.3g}</text>"
      "<text x=\"{}\" y=\"{}\" font-size=\"9\" text-anchor=\"end\">{:.3g}</text>"
      "<text x=\"{}\" y=\"{}\" font-size=\"9\" text-anchor=\"middle\">base</text>"
      "<text x=\"{}\" y=\"{}\" font-size=\"9\" text-anchor=\"middle\">new</text></svg>",
      kLeft - 4, kTop + 6, top, kLeft - 4, kBottom, bottom, kLeft, kHeight - 1, kRight, kHeight - 1);
  return svg;
}

std::string EffectOf(const json& cell) {
  const std::string kind = cell.value("kind", "");
  if (kind == "event") {
    return fmt::format("{} &rarr; {} of {} seeds", cell.value("base_events", 0),
                       cell.value("new_events", 0), cell.value("new_count", 0));
  }
  const json interval = cell.value("interval", json());
  if (!cell.value("effect", json()).is_number() || !interval.is_array() || interval.size() != 2 ||
      !interval[0].is_number() || !interval[1].is_number()) {
    return "-";
  }
  const double effect = cell.at("effect").get<double>();
  const double low = interval[0].get<double>(), high = interval[1].get<double>();
  if (kind == "ratio") return fmt::format("&times;{:.3f} [{:.3f}, {:.3f}]", effect, low, high);
  return fmt::format("{:+.4g} [{:+.4g}, {:+.4g}] {}", effect, low, high, E(cell.value("unit", "")));
}

// Reads <check>/compare.json; null when the check was not compared with a baseline.
json ReadComparison(const fs::path& check_dir) {
  const fs::path file = check_dir / campaign::kCompareJsonFile;
  if (!fs::exists(file)) return nullptr;
  const json comparison = campaign::ReadJsonRecord(file);
  if (!comparison.is_object() || comparison.value("format", "") != campaign::kCompareJsonFormat ||
      !comparison.contains("cells") || !comparison.at("cells").is_array()) {
    throw InputError({file.string()}, "format",
                     "expected the JSON of tofu compare (\"format\": \"tofu compare\", cells)");
  }
  return comparison;
}

int Regressed(const json& comparison) {
  if (comparison.is_null()) return 0;
  int n = 0;
  for (const json& c : comparison.at("cells")) n += c.value("verdict", "") == "regressed" ? 1 : 0;
  return n;
}

// The section: the summary, then every cell that is not unchanged (regressed first) with
// its per-seed pairs drawn; when every cell is unchanged, the ATE cells' pairs.
std::string ComparisonSection(const json& comparison) {
  if (comparison.is_null()) return {};
  std::vector<const json*> shown;
  const auto rank = [](const json* c) {
    const std::string v = c->value("verdict", "");
    return v == "regressed" ? 0 : v == "improved" ? 1 : v == "inconclusive" ? 2 : 3;
  };
  for (const json& c : comparison.at("cells")) {
    if (c.value("verdict", "") != "unchanged") shown.push_back(&c);
  }
  const bool all_unchanged = shown.empty();
  if (all_unchanged) {
    for (const json& c : comparison.at("cells")) {
      if (c.value("metric", "") == "methods.<method>.ate_m") shown.push_back(&c);
    }
  }
  std::stable_sort(shown.begin(), shown.end(),
                   [&](const json* a, const json* b) { return rank(a) < rank(b); });
  const json counts = comparison.value("counts", json::object());
  std::string body = fmt::format(
      "<p>Base <code>{}</code> &rarr; new <code>{}</code>: {} cells, <strong>{} regressed</strong>, "
      "{} improved, {} inconclusive, {} unchanged (false-discovery rate {} by {}). {}</p>\n",
      E(comparison.value("base", "")), E(comparison.value("new", "")), comparison.at("cells").size(),
      counts.value("regressed", 0), counts.value("improved", 0), counts.value("inconclusive", 0),
      counts.value("unchanged", 0), comparison.value("fdr", 0.0),
      E(comparison.value("fdr_procedure", "")),
      all_unchanged ? "Every cell is unchanged; the pairs of each method's ATE are drawn."
                    : "Every cell that is not unchanged, with each seed's pair drawn.");
  body += "<table><tr><th>verdict</th><th>scenario</th><th>method</th><th>metric</th>"
          "<th>pairing</th><th>effect [CI]</th><th>p adj</th><th>seeds</th></tr>\n";
  for (const json* c : shown) {
    const std::string verdict = c->value("verdict", "");
    const std::string metric = c->value("metric", "");
    const bool expectation = metric == "run.expectation.<label>";
    body += fmt::format(
        "<tr class=\"{}\"><td class=\"result\">{}</td><td><code>{}</code></td><td>{}</td>"
        "<td>{}</td><td>{}</td><td class=\"num\">{}</td><td class=\"num\">{}</td><td>{}</td></tr>\n",
        verdict == "regressed" ? "fail" : verdict == "improved" ? "pass" : "", E(verdict),
        E(c->value("scenario", "")), expectation ? "-" : E(c->value("subject", "")),
        expectation ? "expectation " + E(c->value("subject", "")) : E(metric), E(c->value("pairing", "")),
        EffectOf(*c),
        c->value("note", "").empty() ? fmt::format("{:.3g}", c->value("p_adjusted", 1.0))
                                     : E(c->value("note", "")),
        SlopeChart(*c));
  }
  body += "</table>\n";
  return Section("baseline", "Compared with the baseline", body);
}

}  // namespace

std::string CheckPageHtml(const fs::path& check_dir, const std::vector<CheckScenario>& scenarios) {
  size_t runs = 0, runs_passed = 0, scenarios_passed = 0;
  for (const CheckScenario& sc : scenarios) {
    runs += sc.runs.size();
    runs_passed += static_cast<size_t>(sc.check.seeds_passed);
    scenarios_passed += sc.check.passed ? 1 : 0;
  }
  const json comparison = ReadComparison(check_dir);
  const int regressed = Regressed(comparison);
  const bool passed = scenarios_passed == scenarios.size() && regressed == 0;
  std::string page = PageHead("tofu check report");
  page += fmt::format(
      "<header class=\"top {}\"><h1>tofu check {}</h1>\n<div class=\"sub\">{} of {} scenarios "
      "passed · "
      "{} of {} runs passed every expectation{} · {}</div>\n</header>\n<main>\n",
      passed ? "pass" : "fail", Badge(passed), scenarios_passed, scenarios.size(), runs_passed,
      runs,
      comparison.is_null() ? std::string()
                           : fmt::format(" · {} {} against the baseline", regressed,
                                         regressed == 1 ? "cell regressed" : "cells regressed"),
      E(fs::absolute(check_dir).lexically_normal().string()));
  page +=
      Section("overview", "Scenarios",
              "<p>One row per scenario over its seeds (an expectation passes when it held in at "
              "least <code>ceil(pass_fraction &times; seeds)</code> of them). Each seed links to "
              "its run's page.</p>\n" +
                  CheckSummaryTable(scenarios));
  page += ComparisonSection(comparison);
  for (const CheckScenario& sc : scenarios) page += ScenarioDetail(sc);
  page += "</main>\n" + PageFoot(false);
  return page;
}

}  // namespace tofu::report::html
