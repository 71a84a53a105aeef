#include "report/html_plots.h"

#include <algorithm>
#include <cmath>
#include <map>
#include <set>
#include <utility>

#include <fmt/format.h>
#include <nlohmann/json.hpp>

#include "report/html_page.h"
#include "report/html_report.h"

namespace tofu::report::html {

using nlohmann::json;

namespace {

struct PlotSeries {
  std::string name;
  std::string color;
  bool dashed = false;
  std::vector<double> t_s, value;
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

}  // namespace

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

namespace {

// What every plot of a run page shares: the method colours and the fault bands.
struct PlotContext {
  std::map<std::string, std::string> colors;
  std::vector<PlotBand> bands;
  std::string shaded;  ///< the caption's note on the bands ("" without faults)
};

// Every method's position error against ground truth (errors.csv).
std::string PositionErrorPlot(const RunInputs& in, const PlotContext& plot) {
  if (in.data.errors.empty()) return {};
  PlotSpec spec;
  spec.id = "position-error";
  spec.title = "Position error of each method";
  spec.caption =
      E("Every method's position error against ground truth after its SE(3) "
        "alignment (errors.csv, invalid estimates left out)." +
        plot.shaded);
  spec.y_label = "position error [m]";
  spec.unit = "m";
  spec.bands = plot.bands;
  std::map<std::string, PlotSeries> by_method;
  for (const renders::ErrorRow& r : in.data.errors) {
    PlotSeries& s = by_method[r.method];
    s.t_s.push_back(static_cast<double>(r.t_ns) * 1e-9);
    s.value.push_back(r.position_error_m);
  }
  for (auto& [name, s] : by_method) {
    s.name = name;
    s.color = plot.colors.at(name);
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
  return PlotHtml(std::move(spec));
}

// The ground-truth flight's and each closed-loop flight's tracking error.
std::string TrackingErrorPlot(const RunInputs& in, const PlotContext& plot) {
  PlotSpec spec;
  spec.id = "tracking-error";
  spec.title = "Tracking error of the flight";
  spec.caption =
      E("True position against the reference: the ground-truth flight (tracking.csv)" +
        std::string(in.closed_loop.empty() ? "."
                                           : " and each closed-loop flight, flown on a method's "
                                             "estimate (closed_loop/<method>/control.csv).") +
        plot.shaded);
  spec.y_label = "position off the reference [m]";
  spec.unit = "m";
  spec.bands = plot.bands;
  if (!in.tracking.t_s.empty()) {
    spec.series.push_back(
        {"ground-truth flight", "#57606a", false, in.tracking.t_s, in.tracking.value});
  }
  for (const auto& [method, flight] : in.closed_loop) {
    spec.series.push_back(
        {"flown on " + method, plot.colors.at(method), false, flight.first.t_s, flight.first.value});
  }
  return spec.series.empty() ? std::string() : PlotHtml(std::move(spec));
}

// Each closed-loop flight's distance to the nearest structure.
std::string StructureDistancePlot(const RunInputs& in, const PlotContext& plot) {
  if (in.closed_loop.empty()) return {};
  PlotSpec spec;
  spec.id = "structure-distance";
  spec.title = "Distance to the nearest structure";
  spec.caption =
      E("Each closed-loop flight's distance from the robot to the nearest structure "
        "within the distance horizon (closed_loop/<method>/control.csv); at or below "
        "zero the robot touches it." +
        plot.shaded);
  spec.y_label = "distance to structure [m]";
  spec.unit = "m";
  spec.y_from_zero = false;
  spec.bands = plot.bands;
  for (const auto& [method, flight] : in.closed_loop) {
    // Empty where the structure is beyond the distance horizon.
    if (!HasValues(flight.second.value)) continue;
    spec.series.push_back(
        {"flown on " + method, plot.colors.at(method), false, flight.second.t_s, flight.second.value});
  }
  return spec.series.empty() ? std::string() : PlotHtml(std::move(spec));
}

}  // namespace

std::string PlotsSection(const RunInputs& in) {
  PlotContext plot;
  plot.bands = FaultBands(in.data);
  plot.colors = MethodColors(in);
  plot.shaded = plot.bands.empty() ? "" : " Shaded: scheduled faults (labels.csv).";
  const std::string out =
      PositionErrorPlot(in, plot) + TrackingErrorPlot(in, plot) + StructureDistancePlot(in, plot);
  if (out.empty()) return {};
  return Section("plots", "Errors over time", out);
}

}  // namespace tofu::report::html
