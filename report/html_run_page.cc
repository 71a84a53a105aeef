#include "report/html_run_page.h"

#include <algorithm>
#include <map>
#include <set>
#include <vector>

#include <fmt/format.h>
#include <nlohmann/json.hpp>

#include "replay/file_io.h"
#include "report/html_plots.h"

namespace tofu::report::html {

namespace fs = std::filesystem;
using nlohmann::json;

namespace {

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
    // A method whose client failed has no figures (null in summary.json): its row says so,
    // with the cause, rather than a row of dashes that reads as "nothing measured".
    const std::string failure = StringField(m, "failure");
    if (!failure.empty()) {
      rows += fmt::format(
          "<tr class=\"fail\"><td><code>{}</code></td><td class=\"result\" colspan=\"10\">"
          "FAILED: {}</td></tr>\n",
          E(name), E(failure.substr(0, failure.find('\n'))));
      continue;
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
  // summary.json's one place for what failed: the simulation, or a user's client.
  const bool client_failed = StringField(s, "failure_kind") == "client";
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
      Badge(passed, "PASSED",
            failure.empty() ? "FAILED" : client_failed ? "CLIENT FAILED" : "SIMULATION FAILED"),
      description.empty() ? "" : "<div class=\"description\">" + E(description) + "</div>\n",
      fact_line, E(fs::absolute(in.dir).lexically_normal().string()));

  std::string scenario;
  if (!failure.empty()) {
    scenario += fmt::format("<p class=\"failure\"><strong>{} failed:</strong> {}</p>\n",
                            client_failed ? "A client" : "Simulation", E(failure));
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

}  // namespace

void WriteRunPage(const RunInputs& in, const PageContext& ctx) {
  fs::create_directories(ctx.page_dir);
  replay::WriteFileAtomically(ctx.page_dir / "index.html", RunPageHtml(in, ctx));
}

}  // namespace tofu::report::html
