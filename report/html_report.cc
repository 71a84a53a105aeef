#include "report/html_report.h"

#include <unistd.h>

#include <algorithm>
#include <cctype>
#include <cmath>
#include <cstdint>
#include <fstream>
#include <functional>
#include <map>
#include <optional>
#include <set>
#include <vector>

#include <fmt/format.h>
#include <nlohmann/json.hpp>
#include <yaml-cpp/yaml.h>

#include "core/error.h"
#include "core/file_io.h"
#include "harness/check_command.h"
#include "harness/run_directory.h"
#include "renders/run_data.h"
#include "replay/csv_reader.h"
#include "replay/file_io.h"
#include "report/html_report_assets.h"

namespace tofu::report {

namespace fs = std::filesystem;
using core::InputError;
using nlohmann::json;

// ---- text (public) ----

std::string HtmlEscape(std::string_view text) {
  std::string out;
  out.reserve(text.size() + text.size() / 8);
  for (const char ch : text) {
    switch (ch) {
      case '&':
        out += "&amp;";
        break;
      case '<':
        out += "&lt;";
        break;
      case '>':
        out += "&gt;";
        break;
      case '"':
        out += "&quot;";
        break;
      case '\'':
        out += "&#39;";
        break;
      case '\t':
      case '\n':
      case '\r':
        out += ch;
        break;
      default:
        // Other C0 controls are not allowed in HTML text; they carry nothing to show.
        if (static_cast<unsigned char>(ch) >= 0x20 && ch != 0x7f) out += ch;
    }
  }
  return out;
}

std::string Base64(std::string_view bytes) {
  static constexpr char kAlphabet[] =
      "ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
  std::string out;
  out.reserve((bytes.size() + 2) / 3 * 4);
  size_t i = 0;
  for (; i + 2 < bytes.size(); i += 3) {
    const uint32_t v = (static_cast<uint8_t>(bytes[i]) << 16) |
                       (static_cast<uint8_t>(bytes[i + 1]) << 8) |
                       static_cast<uint8_t>(bytes[i + 2]);
    out += kAlphabet[(v >> 18) & 63];
    out += kAlphabet[(v >> 12) & 63];
    out += kAlphabet[(v >> 6) & 63];
    out += kAlphabet[v & 63];
  }
  if (i + 1 == bytes.size()) {
    const uint32_t v = static_cast<uint8_t>(bytes[i]) << 16;
    out += kAlphabet[(v >> 18) & 63];
    out += kAlphabet[(v >> 12) & 63];
    out += "==";
  } else if (i + 2 == bytes.size()) {
    const uint32_t v =
        (static_cast<uint8_t>(bytes[i]) << 16) | (static_cast<uint8_t>(bytes[i + 1]) << 8);
    out += kAlphabet[(v >> 18) & 63];
    out += kAlphabet[(v >> 12) & 63];
    out += kAlphabet[(v >> 6) & 63];
    out += '=';
  }
  return out;
}

std::string ScriptSafeJson(const json& value) {
  const std::string text = value.dump(-1, ' ', false, json::error_handler_t::replace);
  std::string out;
  out.reserve(text.size());
  // '<', '>' and '&' can only occur inside JSON strings, where \u escapes mean the same.
  for (const char ch : text) {
    switch (ch) {
      case '<':
        out += "\\u003c";
        break;
      case '>':
        out += "\\u003e";
        break;
      case '&':
        out += "\\u0026";
        break;
      default:
        out += ch;
    }
  }
  return out;
}

namespace {

std::string E(std::string_view text) { return HtmlEscape(text); }

const char* const kRunForm =
    "a tofu run directory (what `tofu run SCENARIO --out DIR` writes: .tofu-run, scenario.yaml, "
    "summary.json)";
const char* const kCheckForm =
    "a check directory (what `tofu check --out DIR` writes: <scenario>/seed_<s>/ run "
    "directories)";

// A relative path as an href: every byte outside the unreserved set percent-encoded.
std::string Href(const fs::path& relative) {
  std::string out;
  for (const char ch : relative.generic_string()) {
    const unsigned char c = static_cast<unsigned char>(ch);
    if (std::isalnum(c) != 0 || ch == '-' || ch == '_' || ch == '.' || ch == '~' || ch == '/') {
      out += ch;
    } else {
      out += fmt::format("%{:02X}", c);
    }
  }
  return out;
}

// ---- numbers ----

std::string Number(double v) {
  if (!std::isfinite(v)) return "n/a";
  return fmt::format("{:.4g}", v);
}

// A field of a summary object for a table cell: numbers with 4 significant digits,
// booleans as yes/no, missing or null as a dash.
std::string Field(const json& object, const std::string& key) {
  if (!object.is_object()) return "–";
  const auto it = object.find(key);
  if (it == object.end() || it->is_null()) return "–";
  if (it->is_boolean()) return it->get<bool>() ? "yes" : "no";
  if (it->is_number()) return Number(it->get<double>());
  if (it->is_string()) return E(it->get<std::string>());
  return E(it->dump());
}

std::optional<double> OptionalNumber(const json& object, const std::string& key) {
  if (!object.is_object()) return std::nullopt;
  const auto it = object.find(key);
  if (it == object.end() || !it->is_number()) return std::nullopt;
  return it->get<double>();
}

std::string StringField(const json& object, const std::string& key) {
  if (!object.is_object()) return {};
  const auto it = object.find(key);
  return it != object.end() && it->is_string() ? it->get<std::string>() : std::string();
}

// Rounded for the page's data: the plot needs no more digits than a screen shows.
double Rounded(double v, int significant) {
  if (!std::isfinite(v) || v == 0.0) return v;
  const double scale = std::pow(10.0, significant - 1 - std::floor(std::log10(std::abs(v))));
  return std::round(v * scale) / scale;
}

// ---- reading ----

// The scenario.yaml of a run: the resolved scenario, read tolerantly (the page shows what
// is there; harness validated it when the run was made).
struct ScenarioFile {
  std::string text;
  YAML::Node root;
};

ScenarioFile ReadScenarioFile(const fs::path& path) {
  ScenarioFile file;
  file.text = core::ReadWholeFile(path, "scenario.yaml of a tofu run directory");
  try {
    file.root = YAML::Load(file.text);
  } catch (const YAML::Exception& e) {
    throw InputError({path.string(), e.mark.line + 1, e.mark.column + 1}, "", e.msg);
  }
  if (!file.root.IsMap()) {
    throw InputError({path.string(), 1, 1}, "", "expected a mapping (the resolved scenario)");
  }
  return file;
}

std::string YamlScalar(const YAML::Node& map, const std::string& key) {
  if (!map.IsMap()) return {};
  const YAML::Node node = map[key];
  return node && node.IsScalar() ? node.as<std::string>() : std::string();
}

bool IsRunDirectory(const fs::path& dir) {
  std::error_code ec;
  if (!fs::is_directory(dir, ec)) return false;
  return fs::exists(dir / harness::kRunMarkerFile, ec) ||
         (fs::is_regular_file(dir / "scenario.yaml", ec) &&
          fs::is_regular_file(dir / "summary.json", ec));
}

// "seed_<digits>" (or "seed_<digits>.log" when `log`): the seed, else nullopt.
std::optional<uint64_t> SeedOfName(std::string name, bool log) {
  if (log) {
    if (!name.ends_with(".log")) return std::nullopt;
    name.resize(name.size() - 4);
  }
  if (!name.starts_with("seed_") || name.size() == 5 || name.size() > 25) return std::nullopt;
  uint64_t seed = 0;
  for (size_t i = 5; i < name.size(); ++i) {
    if (name[i] < '0' || name[i] > '9') return std::nullopt;
    seed = seed * 10 + static_cast<uint64_t>(name[i] - '0');
  }
  return seed;
}

// The seeds a scenario folder of a check holds (a run directory or a log of one).
std::set<uint64_t> SeedsIn(const fs::path& scenario_dir) {
  std::set<uint64_t> seeds;
  std::error_code ec;
  if (!fs::is_directory(scenario_dir, ec) || fs::exists(scenario_dir / kReportMarkerFile, ec)) {
    return seeds;
  }
  for (const auto& entry : fs::directory_iterator(scenario_dir, ec)) {
    const std::string name = entry.path().filename().string();
    if (const auto s = SeedOfName(name, false); s && IsRunDirectory(entry.path())) seeds.insert(*s);
    if (const auto s = SeedOfName(name, true); s && entry.is_regular_file()) seeds.insert(*s);
  }
  return seeds;
}

std::vector<std::string> CheckScenarioFolders(const fs::path& check_dir) {
  std::vector<std::string> names;
  std::error_code ec;
  for (const auto& entry : fs::directory_iterator(check_dir, ec)) {
    if (entry.is_directory() && !SeedsIn(entry.path()).empty()) {
      names.push_back(entry.path().filename().string());
    }
  }
  std::sort(names.begin(), names.end());
  return names;
}

// The last lines of a log as it looks on a terminal (a progress bar redraws with '\r').
// A run's log tail as the page shows it: a line each, each ended.
std::string LogTailText(const fs::path& path, std::size_t max_lines) {
  std::string tail;
  for (const std::string& line : core::LogTail(path, max_lines)) tail += line + "\n";
  return tail;
}

// Everything one run page shows, read before anything is written.
struct RunInputs {
  fs::path dir;
  ScenarioFile scenario;
  json summary;
  renders::RunData data;
  struct Series {
    std::vector<double> t_s, value;
  };
  Series tracking;  ///< tracking.csv position_error: the ground-truth flight
  /// closed_loop/<method>/control.csv per flight: tracking error, structure distance.
  std::map<std::string, std::pair<Series, Series>> closed_loop;
};

RunInputs::Series ReadColumn(const replay::CsvTable& csv, const char* column) {
  RunInputs::Series out;
  const int t = csv.Require("timestamp");
  const int c = csv.Require(column);
  for (size_t r = 0; r < csv.rows(); ++r) {
    const double v = csv.Double(r, c, true);
    out.t_s.push_back(static_cast<double>(csv.Int(r, t)) * 1e-9);
    out.value.push_back(v);
  }
  return out;
}

RunInputs ReadRunInputs(const fs::path& dir) {
  if (!IsRunDirectory(dir)) {
    throw InputError({dir.string()}, "", fmt::format("not a run directory: expected {}", kRunForm));
  }
  RunInputs in;
  in.dir = dir;
  in.scenario = ReadScenarioFile(dir / "scenario.yaml");
  in.summary = renders::ReadRunJson(dir / "summary.json");
  if (!in.summary.is_object()) {
    throw InputError({(dir / "summary.json").string(), 1, 1}, "",
                     "expected a JSON object (the run's metrics and expectations)");
  }
  if (in.summary.contains("expectations") && !in.summary["expectations"].is_array()) {
    throw InputError({(dir / "summary.json").string()}, "expectations", "expected an array");
  }
  in.data = renders::ReadRunData(dir);
  if (fs::exists(dir / "tracking.csv")) {
    const replay::CsvTable csv(
        dir / "tracking.csv",
        "#timestamp [ns],p_ref_x [m],...,position_error [m],attitude_error [deg]");
    in.tracking = ReadColumn(csv, "position_error");
  }
  std::error_code ec;
  if (fs::is_directory(dir / "closed_loop", ec)) {
    for (const auto& entry : fs::directory_iterator(dir / "closed_loop")) {
      const fs::path control = entry.path() / "control.csv";
      if (!entry.is_directory() || !fs::exists(control)) continue;
      const replay::CsvTable csv(control,
                                  "#timestamp [ns],mode,...,tracking_error [m],"
                                  "estimate_error [m],structure_distance [m]");
      in.closed_loop[entry.path().filename().string()] = {ReadColumn(csv, "tracking_error"),
                                                          ReadColumn(csv, "structure_distance")};
    }
  }
  return in;
}

// ---- page pieces ----

// Where a page is written and how it links to what surrounds it.
struct PageContext {
  fs::path page_dir;      ///< the (staging) directory the page is written into
  std::string back_href;  ///< link to the check overview, or ""
  std::string log_href;   ///< link to the run's log, or ""
};

std::string PageHead(const std::string& title) {
  return fmt::format(
      "<!DOCTYPE html>\n<html lang=\"en\">\n<head>\n<meta charset=\"utf-8\">\n"
      "<meta name=\"viewport\" content=\"width=device-width, initial-scale=1\">\n"
      "<title>{}</title>\n<style>\n{}</style>\n</head>\n<body>\n",
      E(title), kReportCss);
}

std::string PageFoot(bool with_plots) {
  std::string out =
      "<footer>Written by <code>tofu report</code>. Self-contained: no network is used "
      "to view this page.</footer>\n";
  if (with_plots) out += fmt::format("<script>\n{}</script>\n", kPlotScript);
  return out + "</body>\n</html>\n";
}

std::string Badge(bool pass, std::string_view pass_text = "PASSED",
                  std::string_view fail_text = "FAILED") {
  return fmt::format("<span class=\"badge {}\">{}</span>", pass ? "pass" : "fail",
                     pass ? pass_text : fail_text);
}

// An image as a data URI (self-contained page) or, when large, a file copied into media/.
std::string ImageSource(const fs::path& file, const PageContext& ctx) {
  constexpr std::uintmax_t kInlineMaxBytes = 6u << 20;
  std::error_code ec;
  const std::uintmax_t size = fs::file_size(file, ec);
  if (!ec && size <= kInlineMaxBytes) {
    const std::string ext = file.extension().string();
    const char* mime = ext == ".gif" ? "image/gif" : ext == ".jpg" ? "image/jpeg" : "image/png";
    return fmt::format("data:{};base64,{}", mime, Base64(core::ReadWholeFile(file, "image")));
  }
  fs::create_directories(ctx.page_dir / "media");
  fs::copy_file(file, ctx.page_dir / "media" / file.filename(),
                fs::copy_options::overwrite_existing);
  return Href(fs::path("media") / file.filename());
}

std::string CopyMedia(const fs::path& file, const PageContext& ctx) {
  fs::create_directories(ctx.page_dir / "media");
  fs::copy_file(file, ctx.page_dir / "media" / file.filename(),
                fs::copy_options::overwrite_existing);
  return Href(fs::path("media") / file.filename());
}

std::string Section(const std::string& id, const std::string& title, const std::string& body) {
  return fmt::format("<section id=\"{}\">\n<h2>{}</h2>\n{}</section>\n", id, E(title), body);
}

// ---- run page sections ----

std::string ExpectationMetric(const json& e) {
  std::string metric = StringField(e, "metric");
  if (const std::string rel = StringField(e, "relative_to"); !rel.empty()) metric += " / " + rel;
  if (const auto w = e.find("window_s"); w != e.end() && w->is_array() && w->size() == 2 &&
                                         (*w)[0].is_number() && (*w)[1].is_number()) {
    metric += fmt::format(" [{:g}, {:g}] s", (*w)[0].get<double>(), (*w)[1].get<double>());
  }
  return metric;
}

std::string ExpectationsTable(const json& summary) {
  const auto it = summary.find("expectations");
  if (it == summary.end() || it->empty()) {
    return "<p class=\"muted\">The scenario has no <code>expect:</code> block.</p>\n";
  }
  int passed = 0;
  std::string rows;
  for (const json& e : *it) {
    const bool pass = e.is_object() && e.value("passed", false);
    passed += pass ? 1 : 0;
    rows += fmt::format(
        "<tr class=\"{}\"><td><code>{}</code></td><td class=\"num\">{}</td><td class=\"num\">{}"
        "</td><td class=\"num\">{}</td><td class=\"result\">{}</td><td "
        "class=\"where\">{}</td></tr>\n",
        pass ? "pass" : "fail", E(ExpectationMetric(e)), Field(e, "value"), Field(e, "min"),
        Field(e, "max"), pass ? "pass" : "FAIL", E(StringField(e, "where")));
  }
  return fmt::format(
      "<p>{} of {} expectations held.</p>\n<table class=\"expectations\">\n<thead><tr>"
      "<th>expectation</th><th>value</th><th>min</th><th>max</th><th>result</th><th>where</th>"
      "</tr></thead>\n<tbody>\n{}</tbody>\n</table>\n",
      passed, it->size(), rows);
}

std::string MethodsTable(const json& summary) {
  const auto it = summary.find("methods");
  if (it == summary.end() || !it->is_object() || it->empty()) return {};
  std::string rows, detections;
  for (const auto& [name, m] : it->items()) {
    std::string detected = "–";
    if (const auto f = OptionalNumber(m, "faults")) {
      detected = fmt::format("{}/{}", Field(m, "faults_detected"), Number(*f));
    }
    rows += fmt::format(
        "<tr><td><code>{}</code></td><td class=\"num\">{}</td><td class=\"num\">{}</td>"
        "<td class=\"num\">{}</td><td class=\"num\">{}</td><td class=\"num\">{}</td>"
        "<td class=\"num\">{}</td><td class=\"num\">{}</td><td class=\"num\">{}</td>"
        "<td class=\"num\">{}</td><td class=\"num\">{}</td></tr>\n",
        E(name), Field(m, "ate_m"), Field(m, "ate_max_m"), Field(m, "rotation_rmse_deg"),
        Field(m, "rpe_m"), Field(m, "nees_position_mean"), Field(m, "valid_fraction"), detected,
        Field(m, "max_detection_delay_s"), Field(m, "false_exclusion_fraction"),
        Field(m, "switches"));
    if (const auto d = m.find("detections"); m.is_object() && d != m.end() && d->is_array()) {
      for (const json& x : *d) {
        const bool found = x.is_object() && x.value("detected", false);
        detections += fmt::format(
            "<tr class=\"{}\"><td><code>{}</code></td><td>{}</td><td>{}</td><td class=\"num\">{}"
            "</td><td class=\"num\">{}</td><td class=\"result\">{}</td><td "
            "class=\"num\">{}</td></tr>\n",
            found ? "pass" : "fail", E(name), E(StringField(x, "sensor")),
            E(StringField(x, "fault")), Field(x, "onset_s"), Field(x, "end_s"),
            found ? "detected" : "MISSED", Field(x, "delay_s"));
      }
    }
  }
  std::string out = fmt::format(
      "<p>Every method ran inside the flight on the same samples; errors after SE(3) "
      "alignment to ground truth.</p>\n<table>\n<thead><tr><th>method</th><th>ATE [m]</th>"
      "<th>ATE max [m]</th><th>rot RMSE [deg]</th><th>RPE [m]</th><th>NEES mean</th>"
      "<th>valid</th><th>faults detected</th><th>max delay [s]</th><th>false excl.</th>"
      "<th>switches</th></tr></thead>\n<tbody>\n{}</tbody>\n</table>\n",
      rows);
  if (!detections.empty()) {
    out += fmt::format(
        "<h3>Fault detections</h3>\n<table>\n<thead><tr><th>method</th><th>sensor</th>"
        "<th>fault</th><th>onset [s]</th><th>end [s]</th><th>result</th><th>delay [s]</th></tr>"
        "</thead>\n<tbody>\n{}</tbody>\n</table>\n",
        detections);
  }
  return Section("methods", "Estimation methods", out);
}

std::string ClosedLoopTable(const json& summary) {
  const auto it = summary.find("closed_loop");
  if (it == summary.end() || !it->is_object() || it->empty()) return {};
  std::string rows, events;
  for (const auto& [name, f] : it->items()) {
    const auto hits = OptionalNumber(f, "collisions");
    const bool diverged = f.is_object() && f.value("diverged", false);
    const bool bad = (hits && *hits > 0) || diverged || !StringField(f, "failure").empty();
    rows += fmt::format(
        "<tr class=\"{}\"><td>flown on <code>{}</code></td><td class=\"num\">{}</td>"
        "<td class=\"num\">{}</td><td class=\"num\">{}</td><td class=\"num result\">{}</td>"
        "<td class=\"num\">{}</td><td class=\"num\">{}</td><td class=\"num\">{}</td><td>{}</td>"
        "<td class=\"num\">{}</td></tr>\n",
        bad ? "fail" : "pass", E(name), Field(f, "tracking_rmse_m"), Field(f, "tracking_max_m"),
        Field(f, "estimate_ate_m"), Field(f, "collisions"), Field(f, "min_structure_distance_m"),
        Field(f, "time_to_first_collision_s"), Field(f, "failsafe_events"), Field(f, "diverged"),
        Field(f, "handover_s"));
    if (const auto e = f.find("events"); f.is_object() && e != f.end() && e->is_array()) {
      for (const json& x : *e) {
        events += fmt::format(
            "<tr><td><code>{}</code></td><td class=\"num\">{}</td><td>{}</td><td>{}</td></tr>\n",
            E(name), Field(x, "t_s"), E(StringField(x, "event")), E(StringField(x, "detail")));
      }
    }
  }
  std::string out = fmt::format(
      "<p>The controller flew on each method's estimate; each flight is judged against "
      "ground truth.</p>\n<table>\n<thead><tr><th>flight</th><th>tracking RMSE [m]</th>"
      "<th>tracking max [m]</th><th>estimate ATE [m]</th><th>collisions</th>"
      "<th>min structure dist. [m]</th><th>first collision [s]</th><th>failsafe events</th>"
      "<th>diverged</th><th>handover [s]</th></tr></thead>\n<tbody>\n{}</tbody>\n</table>\n",
      rows);
  if (!events.empty()) {
    out += fmt::format(
        "<details><summary>Flight events</summary>\n<table>\n<thead><tr><th>flight</th>"
        "<th>t [s]</th><th>event</th><th>detail</th></tr></thead>\n<tbody>\n{}</tbody>\n"
        "</table>\n</details>\n",
        events);
  }
  return Section("closed-loop", "Closed-loop flights", out);
}

// ---- the interactive plots ----

struct PlotSeries {
  std::string name;
  std::string color;
  bool dashed = false;
  std::vector<double> t_s, value;
};

struct PlotBand {
  double t0_s = 0.0, t1_s = 0.0;
  std::string label;
};

struct PlotSpec {
  std::string id, title, caption, y_label, unit;
  bool y_from_zero = true;
  std::vector<PlotSeries> series;
  std::vector<PlotBand> bands;
};

// One colour per method on every plot of a page: consensus black as in the seed paper's
// figure (consensus.png), the others from a palette without the tables' pass green and
// fail red, in name order.
std::map<std::string, std::string> MethodColors(const RunInputs& in) {
  static const char* const kPalette[] = {"#ff7f0e", "#1f77b4", "#9467bd", "#17becf",
                                         "#8c564b", "#e377c2", "#bcbd22", "#7f7f7f"};
  std::set<std::string> names;
  for (const renders::ErrorRow& r : in.data.errors) names.insert(r.method);
  for (const auto& [method, flight] : in.closed_loop) names.insert(method);
  std::map<std::string, std::string> colors;
  size_t next = 0;
  for (const std::string& name : names) {
    colors[name] = name == "consensus" ? "#000000" : kPalette[next++ % std::size(kPalette)];
  }
  return colors;
}

bool HasValues(const std::vector<double>& values) {
  return std::any_of(values.begin(), values.end(), [](double v) { return std::isfinite(v); });
}

// At most `max_points` per series: one point per bucket, the largest value (an error's
// peak must survive), so a long run stays a small page and a fast plot.
void Decimate(PlotSeries& s, size_t max_points) {
  if (s.t_s.size() <= max_points) return;
  const size_t bucket = (s.t_s.size() + max_points - 1) / max_points;
  std::vector<double> t, v;
  for (size_t i = 0; i < s.t_s.size(); i += bucket) {
    size_t best = i;
    for (size_t k = i; k < std::min(i + bucket, s.t_s.size()); ++k) {
      if (std::isfinite(s.value[k]) &&
          (!std::isfinite(s.value[best]) || s.value[k] > s.value[best])) {
        best = k;
      }
    }
    t.push_back(s.t_s[best]);
    v.push_back(s.value[best]);
  }
  s.t_s = std::move(t);
  s.value = std::move(v);
}

// The gap beyond which the line breaks (the estimate was invalid there): 5x the median
// sample spacing.
double GapSeconds(const std::vector<double>& t_s) {
  if (t_s.size() < 3) return 1e9;
  std::vector<double> dt;
  for (size_t i = 1; i < t_s.size(); ++i) dt.push_back(t_s[i] - t_s[i - 1]);
  std::nth_element(dt.begin(), dt.begin() + static_cast<long>(dt.size() / 2), dt.end());
  return std::max(5.0 * dt[dt.size() / 2], 1e-3);
}

// Whether the y axis should start logarithmic: the series' typical (median) values are
// orders of magnitude apart (a diverged sensor at metres beside consensus at centimetres),
// so a linear axis would flatten the methods that matter onto zero.
bool WantsLogScale(const PlotSpec& spec) {
  double lo = INFINITY, hi = 0.0;
  for (const PlotSeries& s : spec.series) {
    std::vector<double> positive;
    for (const double v : s.value) {
      if (std::isfinite(v) && v > 0.0) positive.push_back(v);
    }
    if (positive.empty()) continue;
    std::nth_element(positive.begin(), positive.begin() + static_cast<long>(positive.size() / 2),
                     positive.end());
    lo = std::min(lo, positive[positive.size() / 2]);
    hi = std::max(hi, positive[positive.size() / 2]);
  }
  return spec.y_from_zero && std::isfinite(lo) && hi > 30.0 * lo;
}

std::string PlotHtml(PlotSpec spec) {
  const bool log_scale = WantsLogScale(spec);
  json data;
  data["title"] = spec.title;
  data["y_label"] = spec.y_label;
  data["unit"] = spec.unit;
  data["y_from_zero"] = spec.y_from_zero;
  data["series"] = json::array();
  std::string legend;
  for (size_t i = 0; i < spec.series.size(); ++i) {
    PlotSeries& s = spec.series[i];
    Decimate(s, 4000);
    json t = json::array(), v = json::array();
    for (size_t k = 0; k < s.t_s.size(); ++k) {
      t.push_back(Rounded(s.t_s[k], 7));
      // NaN has no JSON form: null, which the script treats as a gap.
      v.push_back(std::isfinite(s.value[k]) ? json(Rounded(s.value[k], 5)) : json(nullptr));
    }
    data["series"].push_back({{"name", s.name},
                              {"color", s.color},
                              {"dash", s.dashed},
                              {"gap_s", GapSeconds(s.t_s)},
                              {"t", t},
                              {"y", v}});
    legend += fmt::format(
        "<button type=\"button\" class=\"series\" data-i=\"{}\" title=\"show or hide\"><span "
        "class=\"swatch{}\" style=\"border-color:{}\"></span>{}</button>",
        i, s.dashed ? " dashed" : "", s.color, E(s.name));
  }
  data["bands"] = json::array();
  for (const PlotBand& b : spec.bands) {
    data["bands"].push_back({{"t0", b.t0_s}, {"t1", b.t1_s}, {"label", b.label}});
  }
  return fmt::format(
      "<div class=\"plot-block\">\n<h3>{}</h3>\n<p class=\"caption\">{}</p>\n"
      "<div class=\"tofu-plot\" id=\"plot-{}\">\n<div class=\"plot-bar\"><span class=\"legend\">{}"
      "</span><span class=\"plot-tools\"><label><input type=\"checkbox\" class=\"plot-log\"{}> log "
      "scale</label> <button type=\"button\" class=\"plot-reset\">reset "
      "zoom</button></span></div>\n"
      "<canvas class=\"plot-canvas\" aria-label=\"{}\"></canvas>\n<div class=\"plot-tip\"></div>\n"
      "<div class=\"plot-help\"><span class=\"plot-range\"></span> Hover for values; drag or "
      "wheel to zoom in time; double-click to reset.</div>\n"
      "<script type=\"application/json\" class=\"plot-data\">{}</script>\n</div>\n</div>\n",
      E(spec.title), spec.caption, E(spec.id), legend, log_scale ? " checked" : "", E(spec.title),
      ScriptSafeJson(data));
}

// Fault windows of labels.csv (source "fault"): shaded on the plots.
std::vector<PlotBand> FaultBands(const renders::RunData& data) {
  std::vector<PlotBand> bands;
  std::map<std::pair<std::string, std::string>, double> open;
  for (const renders::LabelRow& l : data.labels) {
    if (l.source != "fault") continue;
    const auto key = std::make_pair(l.sensor, l.label);
    const double t = static_cast<double>(l.t_ns) * 1e-9;
    if (l.active) {
      open.emplace(key, t);
    } else if (const auto it = open.find(key); it != open.end()) {
      bands.push_back({it->second, t, l.sensor + ": " + l.label});
      open.erase(it);
    }
  }
  const double end = data.groundtruth.empty() ? 0.0 : static_cast<double>(data.end_ns()) * 1e-9;
  for (const auto& [key, t0] : open) bands.push_back({t0, end, key.first + ": " + key.second});
  std::sort(bands.begin(), bands.end(),
            [](const PlotBand& a, const PlotBand& b) { return a.t0_s < b.t0_s; });
  return bands;
}

std::string PlotsSection(const RunInputs& in) {
  const std::vector<PlotBand> bands = FaultBands(in.data);
  const std::map<std::string, std::string> colors = MethodColors(in);
  const std::string shaded = bands.empty() ? "" : " Shaded: scheduled faults (labels.csv).";
  std::string out;
  if (!in.data.errors.empty()) {
    PlotSpec spec;
    spec.id = "position-error";
    spec.title = "Position error of each method";
    spec.caption =
        E("Every method's position error against ground truth after its SE(3) "
          "alignment (errors.csv, invalid estimates left out)." +
          shaded);
    spec.y_label = "position error [m]";
    spec.unit = "m";
    spec.bands = bands;
    std::map<std::string, PlotSeries> by_method;
    for (const renders::ErrorRow& r : in.data.errors) {
      PlotSeries& s = by_method[r.method];
      s.t_s.push_back(static_cast<double>(r.t_ns) * 1e-9);
      s.value.push_back(r.position_error_m);
    }
    for (auto& [name, s] : by_method) {
      s.name = name;
      s.color = colors.at(name);
      s.dashed = name.ends_with("@clean");
      // errors.csv interleaves methods by time; each series must be time-ordered.
      std::vector<size_t> order(s.t_s.size());
      for (size_t i = 0; i < order.size(); ++i) order[i] = i;
      std::stable_sort(order.begin(), order.end(),
                       [&](size_t a, size_t b) { return s.t_s[a] < s.t_s[b]; });
      PlotSeries sorted = s;
      for (size_t i = 0; i < order.size(); ++i) {
        sorted.t_s[i] = s.t_s[order[i]];
        sorted.value[i] = s.value[order[i]];
      }
      spec.series.push_back(std::move(sorted));
    }
    out += PlotHtml(std::move(spec));
  }
  {
    PlotSpec spec;
    spec.id = "tracking-error";
    spec.title = "Tracking error of the flight";
    spec.caption =
        E("True position against the reference: the ground-truth flight (tracking.csv)" +
          std::string(in.closed_loop.empty() ? "."
                                             : " and each closed-loop flight, flown on a method's "
                                               "estimate (closed_loop/<method>/control.csv).") +
          shaded);
    spec.y_label = "position off the reference [m]";
    spec.unit = "m";
    spec.bands = bands;
    if (!in.tracking.t_s.empty()) {
      spec.series.push_back(
          {"ground-truth flight", "#57606a", false, in.tracking.t_s, in.tracking.value});
    }
    for (const auto& [method, flight] : in.closed_loop) {
      spec.series.push_back(
          {"flown on " + method, colors.at(method), false, flight.first.t_s, flight.first.value});
    }
    if (!spec.series.empty()) out += PlotHtml(std::move(spec));
  }
  if (!in.closed_loop.empty()) {
    PlotSpec spec;
    spec.id = "structure-distance";
    spec.title = "Distance to the nearest structure";
    spec.caption =
        E("Each closed-loop flight's distance from the robot to the nearest structure "
          "within the distance horizon (closed_loop/<method>/control.csv); at or below "
          "zero the robot touches it." +
          shaded);
    spec.y_label = "distance to structure [m]";
    spec.unit = "m";
    spec.y_from_zero = false;
    spec.bands = bands;
    for (const auto& [method, flight] : in.closed_loop) {
      // Empty where the structure is beyond the distance horizon.
      if (!HasValues(flight.second.value)) continue;
      spec.series.push_back(
          {"flown on " + method, colors.at(method), false, flight.second.t_s, flight.second.value});
    }
    if (!spec.series.empty()) out += PlotHtml(std::move(spec));
  }
  if (out.empty()) return {};
  return Section("plots", "Errors over time", out);
}

// ---- figures, renders, sensors ----

std::string FigureCaption(const std::string& file) {
  if (file == "consensus.png") {
    return "consensus.png: the seed paper's figure of the run (scripts/plot_consensus.py): "
           "corruption per sensor, errors per method, what the consensus fused, consistency "
           "values.";
  }
  if (file == "closed_loop.png") {
    return "closed_loop.png: the closed-loop flights (scripts/plot_closed_loop.py): true paths, "
           "tracking and estimate errors, wall distance.";
  }
  return file;
}

std::string FiguresSection(const RunInputs& in, const PageContext& ctx) {
  std::vector<fs::path> pngs;
  for (const auto& entry : fs::directory_iterator(in.dir)) {
    if (entry.is_regular_file() && entry.path().extension() == ".png") pngs.push_back(entry.path());
  }
  if (pngs.empty()) return {};
  std::sort(pngs.begin(), pngs.end());
  std::string out;
  for (const fs::path& png : pngs) {
    const std::string name = png.filename().string();
    out += fmt::format("<figure><img src=\"{}\" alt=\"{}\"><figcaption>{}</figcaption></figure>\n",
                       ImageSource(png, ctx), E(name), E(FigureCaption(name)));
  }
  return Section("figures", "Figures", out);
}

std::string RendersSection(const RunInputs& in, const PageContext& ctx) {
  const fs::path dir = in.dir / "renders";
  std::error_code ec;
  if (!fs::is_directory(dir, ec)) return {};
  // The events of render.json in their order, else the files by name.
  struct Item {
    std::string caption;
    fs::path keyframe, clip;
  };
  std::vector<Item> items;
  std::set<fs::path> listed;
  std::string gl;
  if (fs::exists(dir / "render.json")) {
    const json meta = renders::ReadRunJson(dir / "render.json");
    gl = StringField(meta, "gl");
    if (const auto events = meta.find("events");
        meta.is_object() && events != meta.end() && events->is_array()) {
      for (const json& e : *events) {
        Item item;
        const auto t = OptionalNumber(e, "t_ns");
        item.caption = fmt::format("{}{}: {}", t ? fmt::format("{:.2f} s, ", *t * 1e-9) : "",
                                   StringField(e, "kind"), StringField(e, "detail"));
        if (const std::string k = StringField(e, "keyframe"); !k.empty() && fs::exists(dir / k)) {
          item.keyframe = dir / k;
        }
        if (const std::string c = StringField(e, "clip"); !c.empty() && fs::exists(dir / c)) {
          item.clip = dir / c;
        }
        listed.insert(item.keyframe);
        listed.insert(item.clip);
        items.push_back(std::move(item));
      }
    }
  }
  std::vector<fs::path> others;
  for (const auto& entry : fs::directory_iterator(dir)) {
    const std::string ext = entry.path().extension().string();
    if (entry.is_regular_file() && (ext == ".png" || ext == ".mp4" || ext == ".gif") &&
        !listed.contains(entry.path())) {
      others.push_back(entry.path());
    }
  }
  std::sort(others.begin(), others.end());
  for (const fs::path& p : others) {
    Item item;
    item.caption = p.filename().string();
    (p.extension() == ".mp4" ? item.clip : item.keyframe) = p;
    items.push_back(std::move(item));
  }
  if (items.empty()) return {};
  std::string out =
      fmt::format("<p>Off-screen renders of the run's failure events (renders/{}).</p>\n",
                  gl.empty() ? "" : E(", " + gl));
  out += "<div class=\"renders\">\n";
  for (const Item& item : items) {
    out += "<figure class=\"render\">";
    if (!item.keyframe.empty()) {
      out += fmt::format("<img src=\"{}\" alt=\"{}\">", ImageSource(item.keyframe, ctx),
                         E(item.keyframe.filename().string()));
    }
    if (!item.clip.empty()) {
      if (item.clip.extension() == ".gif") {
        out += fmt::format("<img src=\"{}\" alt=\"{}\">", ImageSource(item.clip, ctx),
                           E(item.clip.filename().string()));
      } else {
        const std::string src = CopyMedia(item.clip, ctx);
        out += fmt::format(
            "<video controls muted preload=\"metadata\" src=\"{}\"></video>"
            "<div class=\"muted\"><a href=\"{}\">{}</a></div>",
            src, src, E(item.clip.filename().string()));
      }
    }
    out += fmt::format("<figcaption>{}</figcaption></figure>\n", E(item.caption));
  }
  out += "</div>\n";
  return Section("renders", "Failure renders", out);
}

std::string SensorsSection(const RunInputs& in) {
  const auto it = in.summary.find("sensors");
  const std::vector<PlotBand> faults = FaultBands(in.data);
  if ((it == in.summary.end() || !it->is_object() || it->empty()) && faults.empty()) return {};
  std::string out;
  if (it != in.summary.end() && it->is_object() && !it->empty()) {
    std::string rows;
    for (const auto& [name, s] : it->items()) {
      std::string conditions;
      if (const auto c = s.find("condition_time_fraction");
          s.is_object() && c != s.end() && c->is_object()) {
        for (const auto& [condition, fraction] : c->items()) {
          if (!fraction.is_number()) continue;
          conditions += fmt::format("{}{} {:.1f}%", conditions.empty() ? "" : ", ", E(condition),
                                    100.0 * fraction.get<double>());
        }
      }
      rows += fmt::format(
          "<tr><td><code>{}</code></td><td>{}</td><td>{}</td><td class=\"num\">{}</td>"
          "<td class=\"num\">{}</td><td class=\"num\">{}</td><td>{}</td></tr>\n",
          E(name), Field(s, "type"), Field(s, "site"), Field(s, "samples"), Field(s, "delivered"),
          Field(s, "position_error_rms_m"), conditions.empty() ? "–" : conditions);
    }
    out += fmt::format(
        "<table>\n<thead><tr><th>sensor</th><th>type</th><th>mount</th><th>samples</th>"
        "<th>delivered</th><th>position error RMS [m]</th><th>conditions (time share)</th></tr>"
        "</thead>\n<tbody>\n{}</tbody>\n</table>\n",
        rows);
  }
  if (!faults.empty()) {
    std::string rows;
    for (const PlotBand& f : faults) {
      rows += fmt::format(
          "<tr><td>{}</td><td class=\"num\">{:.2f}</td><td class=\"num\">{:.2f}</td></tr>\n",
          E(f.label), f.t0_s, f.t1_s);
    }
    out += fmt::format(
        "<h3>Scheduled faults</h3>\n<table>\n<thead><tr><th>sensor: fault</th><th>from [s]</th>"
        "<th>to [s]</th></tr></thead>\n<tbody>\n{}</tbody>\n</table>\n",
        rows);
  }
  return Section("sensors", "Sensors", out);
}

std::string CollisionsSection(const json& summary) {
  const auto it = summary.find("collisions");
  if (it == summary.end() || !it->is_array() || it->empty()) return {};
  std::string rows;
  for (const json& c : *it) {
    rows += fmt::format(
        "<tr class=\"fail\"><td class=\"num\">{}</td><td "
        "class=\"num\">{}</td><td>{}</td><td>{}</td>"
        "<td class=\"num\">{}</td></tr>\n",
        Field(c, "start_s"), Field(c, "end_s"), Field(c, "robot_geom"), Field(c, "structure_geom"),
        Field(c, "max_penetration_m"));
  }
  return Section(
      "collisions", "Collisions (ground-truth flight)",
      fmt::format("<table>\n<thead><tr><th>start [s]</th><th>end [s]</th><th>robot geom</th>"
                  "<th>structure geom</th><th>max penetration [m]</th></tr></thead>\n"
                  "<tbody>\n{}</tbody>\n</table>\n",
                  rows));
}

std::string Joined(const std::vector<std::string>& items) {
  std::string out;
  for (const std::string& s : items) out += (out.empty() ? "" : "+") + s;
  return out.empty() ? "–" : out;
}

// decisions.csv holds a decision every 0.1 s; the page lists only the changes.
std::string DecisionsSection(const renders::RunData& data) {
  if (data.decisions.empty()) return {};
  std::string rows;
  std::map<std::string, std::string> last;
  size_t changes = 0;
  for (const renders::DecisionRow& d : data.decisions) {
    const std::string state =
        Joined(d.fused) + "|" + Joined(d.excluded) + "|" + Joined(d.unavailable);
    if (last[d.method] == state) continue;
    last[d.method] = state;
    if (++changes > 300) continue;
    rows += fmt::format(
        "<tr><td class=\"num\">{:.2f}</td><td><code>{}</code></td><td>{}</td><td>{}</td><td>{}</td>"
        "<td>{}</td></tr>\n",
        static_cast<double>(d.t_ns) * 1e-9, E(d.method), E(Joined(d.fused)), E(Joined(d.excluded)),
        E(Joined(d.unavailable)), E(d.reason));
  }
  return Section(
      "decisions", "Consensus decisions",
      fmt::format("<details><summary>{} changes of what was fused (decisions.csv){}</summary>\n"
                  "<table>\n<thead><tr><th>t [s]</th><th>method</th><th>fused</th>"
                  "<th>excluded</th><th>unavailable</th><th>reason</th></tr></thead>\n"
                  "<tbody>\n{}</tbody>\n</table>\n</details>\n",
                  changes, changes > 300 ? ", the first 300 listed" : "", rows));
}

std::string MetricsSection(const json& summary) {
  const auto it = summary.find("metrics");
  if (it == summary.end() || !it->is_object() || it->empty()) return {};
  std::string rows;
  for (const auto& [name, v] : it->items()) {
    rows += fmt::format("<tr><td><code>{}</code></td><td class=\"num\">{}</td></tr>\n", E(name),
                        v.is_number() ? Number(v.get<double>())
                        : v.is_null() ? "–"
                                      : E(v.dump()));
  }
  return Section(
      "metrics", "All metrics",
      fmt::format("<details><summary>{} metrics of summary.json (what <code>expect:</code> can "
                  "assert)</summary>\n<table>\n<thead><tr><th>metric</th><th>value</th></tr>"
                  "</thead>\n<tbody>\n{}</tbody>\n</table>\n</details>\n",
                  it->size(), rows));
}

// Links to the <section id=...><h2>...</h2> of a page body, in order: a long run page
// (tables, plots, figures, renders) is read by jumping.
std::string TableOfContents(const std::string& body) {
  const std::string open = "<section id=\"";
  std::string links;
  for (size_t p = body.find(open); p != std::string::npos; p = body.find(open, p + 1)) {
    const size_t id_end = body.find('"', p + open.size());
    const size_t h2 = body.find("<h2>", id_end);
    const size_t h2_end = body.find("</h2>", h2);
    if (id_end == std::string::npos || h2 == std::string::npos || h2_end == std::string::npos)
      break;
    // Both are already escaped where the section was made.
    links += fmt::format("<a href=\"#{}\">{}</a>",
                         body.substr(p + open.size(), id_end - p - open.size()),
                         body.substr(h2 + 4, h2_end - h2 - 4));
  }
  return links.empty() ? "" : "<nav class=\"toc\">" + links + "</nav>\n";
}

std::string RunPageHtml(const RunInputs& in, const PageContext& ctx) {
  const json& s = in.summary;
  const std::string name =
      !in.data.scenario_name.empty() ? in.data.scenario_name : StringField(s, "scenario");
  const std::string failure = StringField(s, "failure");
  const bool passed = s.value("passed", false);
  const auto seed = OptionalNumber(s, "seed");
  std::string page = PageHead(fmt::format("{} — tofu run report", name));

  std::string nav;
  if (!ctx.back_href.empty())
    nav += fmt::format("<a href=\"{}\">&larr; check overview</a>", ctx.back_href);
  if (!ctx.log_href.empty())
    nav += fmt::format("{}<a href=\"{}\">run log</a>", nav.empty() ? "" : " · ", ctx.log_href);
  // What was flown, in one line under the verdict.
  std::vector<std::string> facts;
  const auto fact = [&facts](std::string_view key, const std::string& value_html) {
    if (!value_html.empty() && value_html != "–")
      facts.push_back(fmt::format("{} <b>{}</b>", E(key), value_html));
  };
  fact("world", E(in.data.world));
  fact("robot", E(in.data.robot));
  fact("seed", seed ? Number(*seed) : "");
  fact("simulated", OptionalNumber(s, "simulated_s") ? Field(s, "simulated_s") + " s" : "");
  fact("faults scheduled", Field(s, "faults_scheduled"));
  if (const auto c = s.find("closest_structure");
      c != s.end() && OptionalNumber(*c, "distance_m")) {
    fact("closest structure",
         fmt::format("{} m at {} s", Field(*c, "distance_m"), Field(*c, "t_s")));
  }
  std::string fact_line;
  for (const std::string& f : facts) fact_line += (fact_line.empty() ? "" : " · ") + f;
  const std::string description = YamlScalar(in.scenario.root, "description");
  page += fmt::format(
      "<header class=\"top {}\">{}<h1>{} {}</h1>\n{}<div class=\"facts\">{}</div>\n"
      "<div class=\"sub\">tofu run directory {}</div>\n</header>\n<main>\n",
      passed ? "pass" : "fail", nav.empty() ? "" : "<nav>" + nav + "</nav>", E(name),
      Badge(passed, "PASSED", failure.empty() ? "FAILED" : "SIMULATION FAILED"),
      description.empty() ? "" : "<div class=\"description\">" + E(description) + "</div>\n",
      fact_line, E(fs::absolute(in.dir).lexically_normal().string()));

  std::string scenario;
  if (!failure.empty()) {
    scenario += fmt::format("<p class=\"failure\"><strong>Simulation failed:</strong> {}</p>\n",
                            E(failure));
  }
  scenario += fmt::format(
      "<details><summary>scenario.yaml (resolved: every default filled "
      "in)</summary>\n<pre>{}</pre>\n"
      "</details>\n",
      E(in.scenario.text));
  // The verdict's reasons first, then what happened over time, then the numbers.
  std::string body = Section("expectations", "Expectations", ExpectationsTable(s));
  const std::string plots = PlotsSection(in);
  body += plots;
  body += MethodsTable(s);
  body += ClosedLoopTable(s);
  body += FiguresSection(in, ctx);
  body += RendersSection(in, ctx);
  body += CollisionsSection(s);
  body += SensorsSection(in);
  body += DecisionsSection(in.data);
  body += MetricsSection(s);
  body += Section("scenario", "Scenario", scenario);
  page += TableOfContents(body) + body + "</main>\n";
  page += PageFoot(!plots.empty());
  return page;
}

void WriteRunPage(const RunInputs& in, const PageContext& ctx) {
  fs::create_directories(ctx.page_dir);
  replay::WriteFileAtomically(ctx.page_dir / "index.html", RunPageHtml(in, ctx));
}

// ---- the output directory ----

// Writes a report into a staging sibling of `out_dir` with `fill`, then swaps it in: old
// aside, new in, old gone. On any failure the staging directory is removed and an
// earlier report stays as it was.
void WriteReportDirectory(const fs::path& out_dir,
                          const std::function<void(const fs::path&)>& fill) {
  CheckReportOutputDirectory(out_dir);
  const fs::path out = fs::absolute(out_dir).lexically_normal();
  const fs::path target = out.filename().empty() ? out.parent_path() : out;
  const fs::path parent = target.parent_path();
  fs::create_directories(parent);
  const fs::path staging =
      parent / (target.filename().string() + fmt::format(".tmp-{}", ::getpid()));
  const fs::path old = parent / (target.filename().string() + fmt::format(".old-{}", ::getpid()));
  fs::remove_all(staging);
  try {
    fs::create_directories(staging);
    replay::WriteFileAtomically(staging / kReportMarkerFile,
                                 "a tofu report: `tofu report --out` replaces this directory\n");
    fill(staging);
    fs::remove_all(old);
    if (fs::exists(target)) fs::rename(target, old);
    fs::rename(staging, target);
    fs::remove_all(old);
  } catch (...) {
    std::error_code ignored;
    fs::remove_all(staging, ignored);
    throw;
  }
}

// ---- the check page ----

struct CheckRun {
  harness::SeedRun run;
  std::optional<ScenarioFile> scenario;  ///< its scenario.yaml (pass_fraction), when readable
  bool has_page = false;                 ///< its page was written
  std::string read_error;                ///< why the run has no page
  std::string log_tail;
};

struct CheckScenario {
  std::string name;
  std::vector<CheckRun> runs;
  harness::ScenarioCheck check;
};

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
      // As `tofu run` exits: 3 when the simulation failed, else 1 when an expectation (or
      // a closed-loop flight) failed.
      if (!failure.empty()) {
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
  std::vector<harness::SeedRun> runs;
  for (const CheckRun& r : sc.runs) runs.push_back(r.run);
  sc.check = harness::EvaluateScenarioCheck(ScenarioOfRuns(sc.name, sc.runs), std::move(runs));
}

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

std::string ScenarioResult(const harness::ScenarioCheck& c) {
  if (!c.runs_ok) return "<span class=\"badge fail\">ERROR</span>";
  return Badge(c.passed, "pass", "FAIL");
}

std::string CheckSummaryTable(const std::vector<CheckScenario>& scenarios) {
  std::string rows;
  for (const CheckScenario& sc : scenarios) {
    const harness::ScenarioCheck& c = sc.check;
    int held = 0;
    for (const auto& a : c.expectations) held += a.passed ? 1 : 0;
    std::string methods;
    for (const harness::MethodStats& m : c.methods) {
      methods += fmt::format(
          "<div><code>{}</code> {}{}</div>", E(m.method),
          m.ate_mean_m ? Number(*m.ate_mean_m) + " m" : "–",
          m.has_detections ? fmt::format(", {}/{} faults detected", m.faults_detected, m.faults)
                           : "");
    }
    for (const harness::ClosedLoopStats& f : c.closed_loop) {
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
  const harness::ScenarioCheck& c = sc.check;
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
std::string ExpectationRow(const harness::AggregatedExpectation& a) {
  std::string cells;
  for (const harness::SeedOutcome& o : a.seeds) {
    cells += fmt::format("<td class=\"cell num {}\">{} {}</td>", o.held ? "pass" : "fail",
                         o.value ? Number(*o.value) : "n/a", o.held ? "✔" : "✘");
  }
  return fmt::format(
      "<tr class=\"{}\"><td><code>{}</code><div class=\"where\">{}</div></td><td "
      "class=\"num\">{}/{}</td>{}"
      "<td class=\"result\">{}</td></tr>\n",
      a.passed ? "pass" : "fail", E(harness::ExpectationLabel(a.expectation)),
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
  for (const harness::AggregatedExpectation& a : sc.check.expectations) rows += ExpectationRow(a);
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
  const harness::ScenarioCheck& c = sc.check;
  if (c.methods.empty() && c.closed_loop.empty()) return "";
  std::string mrows;
  for (const harness::MethodStats& m : c.methods) {
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
  for (const harness::ClosedLoopStats& f : c.closed_loop) {
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
  const harness::ScenarioCheck& c = sc.check;
  std::string out =
      fmt::format("<section class=\"scenario\" id=\"scenario-{}\">\n<h2><code>{}</code> {}</h2>\n",
                  E(sc.name), E(sc.name), ScenarioResult(c));
  if (!c.source_file.empty()) out += fmt::format("<p class=\"muted\">{}</p>\n", E(c.source_file));
  out += ExpectationMatrix(sc);
  out += MethodsPerSeedTable(sc);
  out += RunFailureNotes(sc);
  return out + "</section>\n";
}

std::string CheckPageHtml(const fs::path& check_dir, const std::vector<CheckScenario>& scenarios) {
  size_t runs = 0, runs_passed = 0, scenarios_passed = 0;
  for (const CheckScenario& sc : scenarios) {
    runs += sc.runs.size();
    runs_passed += static_cast<size_t>(sc.check.seeds_passed);
    scenarios_passed += sc.check.passed ? 1 : 0;
  }
  const bool passed = scenarios_passed == scenarios.size();
  std::string page = PageHead("tofu check report");
  page += fmt::format(
      "<header class=\"top {}\"><h1>tofu check {}</h1>\n<div class=\"sub\">{} of {} scenarios "
      "passed · "
      "{} of {} runs passed every expectation · {}</div>\n</header>\n<main>\n",
      passed ? "pass" : "fail", Badge(passed), scenarios_passed, scenarios.size(), runs_passed,
      runs, E(fs::absolute(check_dir).lexically_normal().string()));
  page +=
      Section("overview", "Scenarios",
              "<p>One row per scenario over its seeds (an expectation passes when it held in at "
              "least <code>ceil(pass_fraction &times; seeds)</code> of them). Each seed links to "
              "its run's page.</p>\n" +
                  CheckSummaryTable(scenarios));
  for (const CheckScenario& sc : scenarios) page += ScenarioDetail(sc);
  page += "</main>\n" + PageFoot(false);
  return page;
}

}  // namespace

// ---- public ----

ReportInputKind DetectReportInput(const fs::path& input) {
  std::error_code ec;
  if (!fs::exists(input, ec)) {
    throw InputError({input.string()}, "",
                     fmt::format("no such directory: expected {} or {}", kRunForm, kCheckForm));
  }
  if (!fs::is_directory(input, ec)) {
    throw InputError({input.string()}, "",
                     fmt::format("not a directory: expected {} or {}", kRunForm, kCheckForm));
  }
  if (IsRunDirectory(input)) return ReportInputKind::kRun;
  if (!CheckScenarioFolders(input).empty()) return ReportInputKind::kCheck;
  throw InputError({input.string()}, "", fmt::format("neither {} nor {}", kRunForm, kCheckForm));
}

void CheckReportOutputDirectory(const fs::path& out_dir) {
  if (out_dir.empty()) throw InputError({"--out"}, "", "expected a directory, got ''");
  std::error_code ec;
  const fs::file_status status = fs::status(out_dir, ec);
  if (ec || !fs::exists(status)) return;
  if (!fs::is_directory(status)) {
    throw InputError({out_dir.string()}, "--out",
                     "exists and is not a directory: expected a new or empty directory, or an "
                     "earlier tofu report");
  }
  if (fs::is_empty(out_dir, ec)) return;
  if (!fs::exists(out_dir / kReportMarkerFile)) {
    throw InputError({out_dir.string()}, "--out",
                     fmt::format("holds files that are not a tofu report (no {}): refusing to "
                                 "replace it; choose a new or empty directory",
                                 kReportMarkerFile));
  }
}

fs::path WriteRunReport(const fs::path& run_dir, const fs::path& out_dir) {
  CheckReportOutputDirectory(out_dir);
  // Everything is read (and every malformed file found) before anything is written.
  const RunInputs inputs = ReadRunInputs(run_dir);
  WriteReportDirectory(out_dir, [&](const fs::path& staging) {
    WriteRunPage(inputs, PageContext{staging, "", ""});
  });
  return fs::absolute(out_dir).lexically_normal() / "index.html";
}

fs::path WriteCheckReport(const fs::path& check_dir, const fs::path& out_dir,
                          const std::vector<std::string>& only_scenarios) {
  CheckReportOutputDirectory(out_dir);
  if (DetectReportInput(check_dir) != ReportInputKind::kCheck) {
    throw InputError({check_dir.string()}, "",
                     fmt::format("not a check directory: expected {}", kCheckForm));
  }
  std::vector<std::string> names = CheckScenarioFolders(check_dir);
  if (!only_scenarios.empty()) {
    const std::set<std::string> wanted(only_scenarios.begin(), only_scenarios.end());
    std::erase_if(names, [&](const std::string& n) { return !wanted.contains(n); });
  }
  std::vector<CheckScenario> scenarios;
  for (const std::string& name : names) scenarios.push_back(ReadCheckScenario(check_dir, name));
  WriteReportDirectory(out_dir, [&](const fs::path& staging) {
    for (CheckScenario& sc : scenarios) WriteCheckPages(sc, staging);
    replay::WriteFileAtomically(staging / "index.html", CheckPageHtml(check_dir, scenarios));
  });
  return fs::absolute(out_dir).lexically_normal() / "index.html";
}

fs::path WriteReport(const fs::path& input, const fs::path& out_dir) {
  CheckReportOutputDirectory(out_dir);
  return DetectReportInput(input) == ReportInputKind::kRun ? WriteRunReport(input, out_dir)
                                                           : WriteCheckReport(input, out_dir);
}

}  // namespace tofu::report
