#include "renders/events.h"

#include <algorithm>
#include <cmath>
#include <map>
#include <set>
#include <tuple>

#include <fmt/format.h>

#include "core/error.h"

namespace tofu::renders {
namespace {

std::string SafeSlugPart(const std::string& text) {
  std::string out;
  for (const char c : text) {
    const bool keep = (c >= 'a' && c <= 'z') || (c >= 'A' && c <= 'Z') || (c >= '0' && c <= '9') ||
                      c == '_' || c == '-';
    out += keep ? c : '_';
  }
  return out.empty() ? std::string("none") : out;
}

std::string JoinPlus(const std::vector<std::string>& items) {
  std::string out;
  for (const std::string& s : items) out += (out.empty() ? "" : "+") + s;
  return out.empty() ? std::string("none") : out;
}

}  // namespace

const char* EventKindName(EventKind kind) {
  switch (kind) {
    case EventKind::kFaultOnset: return "fault_onset";
    case EventKind::kDetection: return "detection";
    case EventKind::kSensorSwitch: return "sensor_switch";
    case EventKind::kErrorAboveBound: return "error_above_bound";
    case EventKind::kCollision: return "collision";
  }
  return "event";
}

std::string RenderEvent::Slug() const {
  return fmt::format("{}_{}_{:07d}ms", EventKindName(kind), SafeSlugPart(subject),
                     t_ns / 1'000'000);
}

void EventOptions::Validate() const {
  if (!(error_bound_m > 0.0) || !std::isfinite(error_bound_m)) {
    throw core::InputError({"render options"}, "--error-bound",
                           fmt::format("expected a positive bound in metres, got {}", error_bound_m));
  }
  if (!(rearm_fraction > 0.0 && rearm_fraction <= 1.0)) {
    throw core::InputError({"render options"}, "rearm_fraction", "expected (0, 1]");
  }
}

std::vector<RenderEvent> FindEvents(const RunData& run, const EventOptions& options) {
  options.Validate();
  std::vector<RenderEvent> events;

  // Fault onsets: a scheduled fault becomes active.
  for (const LabelRow& l : run.labels) {
    if (l.source == "fault" && l.active) {
      events.push_back({l.t_ns, EventKind::kFaultOnset, l.sensor, l.sensor + " " + l.label});
    }
  }

  // Detections and switches, per method, from the consensus decisions.
  std::map<std::string, const DecisionRow*> previous;
  for (const DecisionRow& d : run.decisions) {
    const auto it = previous.find(d.method);
    if (it != previous.end()) {
      const DecisionRow& before = *it->second;
      for (const std::string& s : d.excluded) {
        if (std::find(before.excluded.begin(), before.excluded.end(), s) == before.excluded.end()) {
          events.push_back({d.t_ns, EventKind::kDetection, s,
                            fmt::format("{} excluded by {}{}", s, d.method,
                                        d.reason.empty() ? "" : " (" + d.reason + ")")});
        }
      }
      if (d.fused != before.fused) {
        events.push_back({d.t_ns, EventKind::kSensorSwitch, d.method,
                          fmt::format("{} fuses {} (was {})", d.method, JoinPlus(d.fused),
                                      JoinPlus(before.fused))});
      }
    }
    previous[d.method] = &d;
  }

  // Error above the bound: rising edges, re-armed once below bound * rearm_fraction.
  std::map<std::string, bool> above;
  std::vector<ErrorRow> errors = run.errors;
  std::stable_sort(errors.begin(), errors.end(),
                   [](const ErrorRow& a, const ErrorRow& b) { return a.t_ns < b.t_ns; });
  for (const ErrorRow& e : errors) {
    bool& is_above = above[e.method];
    if (!is_above && e.position_error_m > options.error_bound_m) {
      is_above = true;
      events.push_back({e.t_ns, EventKind::kErrorAboveBound, e.method,
                        fmt::format("{} position error {:.2f} m > {:.2f} m", e.method,
                                    e.position_error_m, options.error_bound_m)});
    } else if (is_above && e.position_error_m < options.error_bound_m * options.rearm_fraction) {
      is_above = false;
    }
  }

  for (const CollisionRow& c : run.collisions) {
    events.push_back({c.t_ns, EventKind::kCollision, c.structure_geom.empty() ? "structure" : c.structure_geom,
                      fmt::format("collision {} - {}", c.robot_geom, c.structure_geom)});
  }

  std::stable_sort(events.begin(), events.end(), [](const RenderEvent& a, const RenderEvent& b) {
    return std::tie(a.t_ns, a.kind, a.subject) < std::tie(b.t_ns, b.kind, b.subject);
  });
  // The earliest of each kind, then the earliest overall.
  std::map<EventKind, size_t> per_kind;
  std::vector<RenderEvent> kept;
  for (const RenderEvent& e : events) {
    if (per_kind[e.kind]++ >= options.max_per_kind) continue;
    if (kept.size() >= options.max_events) break;
    kept.push_back(e);
  }
  return kept;
}

}  // namespace tofu::renders
