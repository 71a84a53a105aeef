#include "renders/overlay.h"

#include <algorithm>
#include <cmath>
#include <set>

#include <fmt/format.h>

#include "core/error.h"
#include "renders/scene_renderer.h"

namespace tofu::renders {
namespace {

std::string Join(const std::vector<std::string>& items, const char* separator) {
  std::string out;
  for (const std::string& s : items) out += (out.empty() ? "" : separator) + s;
  return out;
}

// Colour of a consistency value: green (consistent) through yellow to red; grey when
// unavailable. `badness` in [0, 1].
Rgba BadnessColor(double badness) {
  if (!std::isfinite(badness)) return {0.35f, 0.35f, 0.38f, 1.0f};
  const float u = static_cast<float>(std::clamp(badness, 0.0, 1.0));
  if (u < 0.5f) return {0.15f + 1.6f * u, 0.75f, 0.25f, 1.0f};
  return {0.95f, 0.75f - 1.2f * (u - 0.5f), 0.25f - 0.3f * (u - 0.5f), 1.0f};
}

}  // namespace

// Sensor marker colours (no magenta: that hue belongs to the first ghost).
Rgba SensorColor(size_t sensor_index) {
  static constexpr std::array<Rgba, 6> kPalette = {{{0.10f, 0.55f, 1.00f, 1.0f},
                                                    {1.00f, 0.60f, 0.05f, 1.0f},
                                                    {0.00f, 0.85f, 0.85f, 1.0f},
                                                    {0.95f, 0.90f, 0.10f, 1.0f},
                                                    {0.55f, 0.35f, 0.15f, 1.0f},
                                                    {0.60f, 0.95f, 0.50f, 1.0f}}};
  return kPalette[sensor_index % kPalette.size()];
}

Overlay::Overlay(const RunData& run, std::vector<const MethodEstimate*> ghosts,
                 const std::string& consistency_metric, const OverlayFrame& frame,
                 const mjrContext* context)
    : run_(run), ghosts_(std::move(ghosts)), frame_(frame), context_(context) {
  // Decisions: the consensus method's if there is one, else the first method's.
  std::set<std::string> decided;
  for (const DecisionRow& d : run_.decisions) decided.insert(d.method);
  if (!decided.empty()) {
    decision_method_ = decided.count("consensus") != 0 ? "consensus" : *decided.begin();
  }
  // Consistency: the decision method's file, else the first ghost's, else the run's.
  std::vector<std::string> candidates = {decision_method_};
  for (const MethodEstimate* g : ghosts_) candidates.push_back(g->method);
  candidates.push_back("");
  for (const auto& [method, rows] : run_.consistency) candidates.push_back(method);
  for (const std::string& c : candidates) {
    const auto it = run_.consistency.find(c);
    if (it != run_.consistency.end() && !it->second.empty()) {
      consistency_ = &it->second;
      break;
    }
  }
  if (consistency_ == nullptr) return;
  consistency_metric_ = consistency_metric;
  std::set<std::string> metrics;
  for (const ConsistencyRow& row : *consistency_) metrics.insert(row.metric);
  if (consistency_metric_.empty()) {
    consistency_metric_ = *metrics.begin();
  } else if (metrics.count(consistency_metric_) == 0) {
    throw core::InputError({run_.directory.string()}, "--metric",
                           fmt::format("no consistency metric '{}' in the run (metrics: {})",
                                       consistency_metric_,
                                       Join({metrics.begin(), metrics.end()}, ", ")));
  }
  // Low is good for MAE, KL and CvM: full red at the 95th percentile of the run.
  std::vector<double> values;
  std::set<std::string> names;
  for (const ConsistencyRow& row : *consistency_) {
    if (row.metric != consistency_metric_) continue;
    names.insert(row.a);
    names.insert(row.b);
    if (std::isfinite(row.value)) values.push_back(std::abs(row.value));
  }
  if (!values.empty()) {
    const size_t k = static_cast<size_t>(0.95 * static_cast<double>(values.size() - 1));
    std::nth_element(values.begin(), values.begin() + static_cast<std::ptrdiff_t>(k), values.end());
    consistency_scale_ = std::max(values[k], 1e-9);
  }
  const bool has_local = names.erase("local") != 0;
  matrix_names_.assign(names.begin(), names.end());
  if (has_local) matrix_names_.push_back("local");
  if (matrix_names_.size() > 8) matrix_names_.resize(8);
}

bool Overlay::LowIsGood() const { return consistency_metric_ != "pcc"; }

double Overlay::Badness(double value) const {
  if (!std::isfinite(value)) return value;
  if (!LowIsGood()) return 1.0 - value;  // correlation 1: consistent; <= 0: not at all
  return std::abs(value) / consistency_scale_;
}

const DecisionRow* Overlay::DecisionAt(core::Time t_ns) const {
  const DecisionRow* found = nullptr;
  for (const DecisionRow& d : run_.decisions) {
    if (d.t_ns > t_ns) break;
    if (d.method == decision_method_) found = &d;
  }
  return found;
}

// Latest value of each pair of the shown metric at t.
std::map<std::pair<std::string, std::string>, double> Overlay::ConsistencyAt(
    core::Time t_ns) const {
  std::map<std::pair<std::string, std::string>, double> values;
  if (consistency_ == nullptr) return values;
  for (const ConsistencyRow& row : *consistency_) {
    if (row.t_ns > t_ns) continue;
    if (row.metric != consistency_metric_) continue;
    values[{row.a, row.b}] = row.value;
  }
  return values;
}

void Overlay::DrawText(core::Time t_ns, const std::string& camera_name,
                       const std::string& caption) const {
  std::string titles;
  std::string values;
  int lines = 0;
  const int max_lines = MaxOverlayLines();
  const auto line = [&](const std::string& title, const std::string& value) {
    if (lines++ >= max_lines) return;
    titles += (titles.empty() ? "" : "\n") + title;
    values += (values.empty() ? "" : "\n") + value;
  };
  line("time", fmt::format("{:.2f} s  ({})", core::TimeToSeconds(t_ns), camera_name));
  // Long values (a decision's reason) are cut to the frame's width.
  const size_t max_chars =
      static_cast<size_t>(std::max(16, (frame_.width_px - 110 * frame_.font_scale / 100) /
                                           (8 * frame_.font_scale / 100)));
  const auto fit = [max_chars](const std::string& text) {
    return text.size() <= max_chars ? text : text.substr(0, max_chars - 3) + "...";
  };
  if (!caption.empty()) line("event", fit(caption));
  if (const DecisionRow* d = DecisionAt(t_ns)) {
    line("fused", fmt::format("{} ({})", d->fused.empty() ? "none" : Join(d->fused, "+"),
                              decision_method_));
    line("excluded", d->excluded.empty() ? "none" : Join(d->excluded, "+"));
    if (!d->unavailable.empty()) line("unavailable", Join(d->unavailable, "+"));
  } else if (!ghosts_.empty()) {
    const MethodEstimate& g = *ghosts_.front();
    const auto it = std::upper_bound(
        g.T_WB.begin(), g.T_WB.end(), t_ns,
        [](core::Time t, const TimedPose& p) { return t < p.t_ns; });
    if (it != g.T_WB.begin()) {
      const std::string& fused = g.fused[static_cast<size_t>(it - g.T_WB.begin()) - 1];
      line("fused", fmt::format("{} ({})", fused.empty() ? "none" : fused, g.method));
    }
  }
  // Scheduled faults, then the conditions the scene causes (occlusion, degeneracy, ...).
  for (const char* source : {"fault", "condition"}) {
    std::string text;
    for (const SensorTrack& s : run_.sensors) {
      const std::vector<std::string> active = run_.ActiveLabels(s.name, source, t_ns);
      if (!active.empty()) text += (text.empty() ? "" : ", ") + s.name + ": " + Join(active, "|");
    }
    if (!text.empty()) line(std::string(source) + "s", fit(text));
  }
  // The inset shows the values when drawn; else one line of them.
  const auto values_at = ConsistencyAt(t_ns);
  if (!values_at.empty() && !(frame_.heatmap && matrix_names_.size() >= 2)) {
    std::string text;
    int shown = 0;
    for (const auto& [pair, value] : values_at) {
      if (shown++ == 4) {
        text += " ...";
        break;
      }
      text += fmt::format("{}{}-{} {}", text.empty() ? "" : ", ", pair.first, pair.second,
                          std::isfinite(value) ? fmt::format("{:.2f}", value) : "n/a");
    }
    line(consistency_metric_, text);
  }
  const mjrRect viewport = {0, 0, frame_.width_px, frame_.height_px};
  mjr_overlay(mjFONT_NORMAL, mjGRID_TOPLEFT, viewport, titles.c_str(), values.c_str(), context_);
}

// Lines of the text overlay that fit in the upper half of the frame (small frames keep
// the first, most important ones).
int Overlay::MaxOverlayLines() const {
  const int line_px = 23 * frame_.font_scale / 100;
  return std::max(2, frame_.height_px / 2 / line_px);
}

int Overlay::TextHeight() const { return 18 * frame_.font_scale / 100; }

// Legend along the bottom: each ghost's and each sensor's colour, wrapping to a second
// row when the frame is narrow.
void Overlay::DrawLegend() const {
  const int h = TextHeight();
  const int char_w = 8 * frame_.font_scale / 100;
  int x = 4;
  int y = 4;
  const auto entry = [&](const std::string& text, const Rgba& bg, const Rgba& fg) {
    const int w = static_cast<int>(text.size()) * char_w + 10;
    if (x + w > frame_.width_px && x > 4) {
      x = 4;
      y += h + 4;
    }
    if (x + w > frame_.width_px || y + h > frame_.height_px / 3) return;
    mjr_label({x, y, w, h}, mjFONT_NORMAL, text.c_str(), bg[0], bg[1], bg[2], 0.85f, fg[0], fg[1],
              fg[2], context_);
    x += w + 4;
  };
  const Rgba dark = {0.05f, 0.05f, 0.05f, 1.0f};
  for (size_t k = 0; k < ghosts_.size(); ++k) {
    const std::array<float, 3> c = GhostColor(k);
    entry(ghosts_[k]->method, {c[0], c[1], c[2], 1.0f}, dark);
  }
  for (size_t k = 0; k < run_.sensors.size(); ++k) {
    entry(run_.sensors[k].name, SensorColor(k), dark);
  }
}

// Consistency-matrix inset, top right: one cell per pair, coloured by consistency.
void Overlay::DrawHeatmap(core::Time t_ns) const {
  if (consistency_ == nullptr || matrix_names_.size() < 2) return;
  const auto values = ConsistencyAt(t_ns);
  const int n = static_cast<int>(matrix_names_.size());
  const int cell = std::max(18, std::min(frame_.height_px / 16, 40)) * frame_.font_scale / 100;
  const int header_w = 5 * 8 * frame_.font_scale / 100 + 8;
  const int width = header_w + n * cell;
  const int height = TextHeight() + cell + n * cell;
  const int left = frame_.width_px - width - 6;
  const int top = frame_.height_px - 6;  // GL y grows upwards
  if (left < 0 || height + 12 > frame_.height_px) return;
  mjr_rectangle({left - 3, top - height - 3, width + 6, height + 6}, 0.0f, 0.0f, 0.0f, 0.55f);
  const std::string title =
      fmt::format("{} {}", consistency_metric_, LowIsGood() ? "(low=ok)" : "(1=ok)");
  mjr_label({left, top - TextHeight(), width, TextHeight()}, mjFONT_NORMAL, title.c_str(), 0.0f,
            0.0f, 0.0f, 0.0f, 1.0f, 1.0f, 1.0f, context_);
  const int grid_top = top - TextHeight();
  const auto short_name = [](const std::string& s) { return s.substr(0, 5); };
  for (int c = 0; c < n; ++c) {
    mjr_label({left + header_w + c * cell, grid_top - cell, cell, cell}, mjFONT_NORMAL,
              short_name(matrix_names_[c]).substr(0, std::max(1, cell / 8)).c_str(), 0.0f, 0.0f,
              0.0f, 0.0f, 0.9f, 0.9f, 0.9f, context_);
  }
  for (int r = 0; r < n; ++r) {
    const int y = grid_top - cell - (r + 1) * cell;
    mjr_label({left, y, header_w, cell}, mjFONT_NORMAL, short_name(matrix_names_[r]).c_str(), 0.0f,
              0.0f, 0.0f, 0.0f, 0.9f, 0.9f, 0.9f, context_);
    for (int c = 0; c < n; ++c) {
      const mjrRect rect = {left + header_w + c * cell + 1, y + 1, cell - 2, cell - 2};
      if (r == c) {
        mjr_rectangle(rect, 0.12f, 0.12f, 0.12f, 1.0f);
        continue;
      }
      auto it = values.find({matrix_names_[r], matrix_names_[c]});
      if (it == values.end()) it = values.find({matrix_names_[c], matrix_names_[r]});
      if (it == values.end()) {
        mjr_rectangle(rect, 0.22f, 0.22f, 0.24f, 1.0f);
        continue;
      }
      const Rgba color = BadnessColor(Badness(it->second));
      const std::string text =
          cell >= 30 && std::isfinite(it->second) ? fmt::format("{:.2g}", it->second) : "";
      mjr_label(rect, mjFONT_NORMAL, text.c_str(), color[0], color[1], color[2], 1.0f, 0.0f,
                0.0f, 0.0f, context_);
    }
  }
}

}  // namespace tofu::renders
