#include "renders/events.h"

#include <algorithm>
#include <cmath>
#include <map>
#include <set>
#include <tuple>

#include <fmt/format.h>

#include "core/error.h"
#include "renders/render_options.h"

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

bool EventOptions::IsValid(std::string* why) const {
  const auto fail = [why](const std::string& key, const std::string& message) {
    if (why != nullptr) *why = key + ": " + message;
    return false;
  };
  if (!(error_bound_m > 0.0) || !std::isfinite(error_bound_m)) {
    return fail("--error-bound",
                fmt::format("expected a positive bound in metres, got {}", error_bound_m));
  }
  if (!(rearm_fraction > 0.0 && rearm_fraction <= 1.0)) {
    return fail("rearm_fraction", "expected (0, 1]");
  }
  if (!(settle_s >= 0.0) || !std::isfinite(settle_s)) return fail("settle_s", "expected >= 0 s");
  if (!(merge_s >= 0.0) || !std::isfinite(merge_s)) return fail("merge_s", "expected >= 0 s");
  return true;
}

namespace {

// Fault onsets: a scheduled fault becomes active.
void AddFaultOnsets(const RunData& run, std::vector<RenderEvent>& events) {
  for (const LabelRow& l : run.labels) {
    if (l.source == "fault" && l.active) {
      events.push_back({l.t_ns, EventKind::kFaultOnset, l.sensor, l.sensor + " " + l.label});
    }
  }
}

// Detections and switches, per method, from the consensus decisions after start-up
// (`settle_ns` after a method's first decision).
void AddDetectionsAndSwitches(const RunData& run, core::Time settle_ns,
                              std::vector<RenderEvent>& events) {
  std::map<std::string, const DecisionRow*> previous;
  std::map<std::string, core::Time> first_decision;
  for (const DecisionRow& d : run.decisions) {
    first_decision.emplace(d.method, d.t_ns);
    const DecisionRow* before_ptr = previous[d.method];
    previous[d.method] = &d;
    if (before_ptr == nullptr || d.t_ns < first_decision[d.method] + settle_ns) continue;
    const DecisionRow& before = *before_ptr;
    for (const std::string& s : d.excluded) {
      if (std::find(before.excluded.begin(), before.excluded.end(), s) == before.excluded.end()) {
        const std::vector<std::string> faults = run.ActiveFaults(s, d.t_ns);
        const std::string verdict = faults.empty()
                                        ? std::string("false alarm: no fault active")
                                        : "fault " + JoinPlus(faults);
        events.push_back({d.t_ns, EventKind::kDetection, s,
                          fmt::format("{} excluded by {} ({}){}", s, d.method, verdict,
                                      d.reason.empty() ? "" : ": " + d.reason)});
      }
    }
    if (d.fused != before.fused) {
      events.push_back({d.t_ns, EventKind::kSensorSwitch, d.method,
                        fmt::format("{} fuses {} (was {})", d.method, JoinPlus(d.fused),
                                    JoinPlus(before.fused))});
    }
  }
}

// Error above the bound: rising edges of an armed method (below bound * rearm_fraction
// since start-up or since its last crossing).
void AddErrorsAboveBound(const RunData& run, const EventOptions& options, core::Time settle_ns,
                         std::vector<RenderEvent>& events) {
  std::vector<ErrorRow> errors = run.errors;
  std::stable_sort(errors.begin(), errors.end(),
                   [](const ErrorRow& a, const ErrorRow& b) { return a.t_ns < b.t_ns; });
  std::map<std::string, bool> armed;
  std::map<std::string, core::Time> first_error;
  for (const ErrorRow& e : errors) {
    first_error.emplace(e.method, e.t_ns);
    if (e.t_ns < first_error[e.method] + settle_ns) continue;
    bool& is_armed = armed[e.method];
    if (is_armed && e.position_error_m > options.error_bound_m) {
      is_armed = false;
      events.push_back({e.t_ns, EventKind::kErrorAboveBound, e.method,
                        fmt::format("{} position error {:.2f} m > {:.2f} m", e.method,
                                    e.position_error_m, options.error_bound_m)});
    } else if (!is_armed && e.position_error_m < options.error_bound_m * options.rearm_fraction) {
      is_armed = true;
    }
  }
}

void AddCollisions(const RunData& run, std::vector<RenderEvent>& events) {
  for (const CollisionRow& c : run.collisions) {
    events.push_back({c.t_ns, EventKind::kCollision,
                      c.structure_geom.empty() ? "structure" : c.structure_geom,
                      fmt::format("collision {} - {}", c.robot_geom, c.structure_geom)});
  }
}

bool EarlierEvent(const RenderEvent& a, const RenderEvent& b) {
  return std::tie(a.t_ns, a.kind, a.subject) < std::tie(b.t_ns, b.kind, b.subject);
}

// Which events tell most: collisions, fault onsets, detections of a faulted sensor,
// errors above the bound, false alarms, switches (0: most).
int EventPriority(const RunData& run, const RenderEvent& e) {
  switch (e.kind) {
    case EventKind::kCollision: return 0;
    case EventKind::kFaultOnset: return 1;
    case EventKind::kDetection: return run.ActiveFaults(e.subject, e.t_ns).empty() ? 4 : 2;
    case EventKind::kErrorAboveBound: return 3;
    case EventKind::kSensorSwitch: return 5;
  }
  return 6;
}

// Repeats within merge_s of a kept event of the same kind, subject and priority are in
// its clip (a false alarm does not swallow the detection of a fault that follows it).
// `events` in time order.
std::vector<RenderEvent> WithoutRepeats(const RunData& run, const std::vector<RenderEvent>& events,
                                        const EventOptions& options) {
  const core::Time merge_ns = core::SecondsToTime(options.merge_s);
  std::map<std::tuple<EventKind, std::string, int>, core::Time> last_kept;
  std::vector<RenderEvent> merged;
  for (const RenderEvent& e : events) {
    const auto key = std::make_tuple(e.kind, e.subject, EventPriority(run, e));
    const auto last = last_kept.find(key);
    if (last != last_kept.end() && e.t_ns - last->second <= merge_ns) continue;
    last_kept[key] = e.t_ns;
    merged.push_back(e);
  }
  return merged;
}

// Caps, per kind and in total, by priority then time; the result in time order.
std::vector<RenderEvent> MostTelling(const RunData& run, std::vector<RenderEvent> merged,
                                     const EventOptions& options) {
  std::stable_sort(merged.begin(), merged.end(), [&](const RenderEvent& a, const RenderEvent& b) {
    return EventPriority(run, a) < EventPriority(run, b);
  });
  std::map<EventKind, size_t> per_kind;
  std::vector<RenderEvent> kept;
  for (const RenderEvent& e : merged) {
    if (kept.size() >= options.max_events) break;
    if (per_kind[e.kind]++ >= options.max_per_kind) continue;
    kept.push_back(e);
  }
  std::stable_sort(kept.begin(), kept.end(), EarlierEvent);
  return kept;
}

}  // namespace

std::vector<RenderEvent> FindEvents(const RunData& run, const EventOptions& options) {
  RequireValidRenderOptions(options);
  const core::Time settle_ns = core::SecondsToTime(options.settle_s);
  std::vector<RenderEvent> events;
  AddFaultOnsets(run, events);
  AddDetectionsAndSwitches(run, settle_ns, events);
  AddErrorsAboveBound(run, options, settle_ns, events);
  AddCollisions(run, events);
  std::stable_sort(events.begin(), events.end(), EarlierEvent);
  // Caps keep the most telling first.
  return MostTelling(run, WithoutRepeats(run, events, options), options);
}

}  // namespace tofu::renders
