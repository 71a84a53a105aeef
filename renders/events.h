#pragma once
// Failure events of a run, chosen automatically: fault onset (labels.csv), detection (a
// sensor entering `excluded` in decisions.csv), sensor switch (a change of `fused`),
// error above a bound (errors.csv or estimate_<method>_errors.csv), collision
// (summary.json). Each becomes a clip of +- 2 s and a keyframe PNG.

#include <string>
#include <vector>

#include "core/time.h"
#include "renders/run_data.h"

namespace tofu::renders {

enum class EventKind { kFaultOnset, kDetection, kSensorSwitch, kErrorAboveBound, kCollision };

/// "fault_onset", "detection", "sensor_switch", "error_above_bound", "collision".
const char* EventKindName(EventKind kind);

struct RenderEvent {
  core::Time t_ns = 0;
  EventKind kind = EventKind::kFaultOnset;
  std::string subject;  ///< the sensor (fault, detection), method (switch, error) or geom
  std::string detail;   ///< one line for the overlay: "vio divergence", "gnss excluded"
  /// File-name stem: "<kind>_<subject>_<t in ms>".
  std::string Slug() const;
};

struct EventOptions {
  double error_bound_m = 0.5;  ///< position error above this is an event (rising edge)
  /// A crossing needs the error to have been below bound * rearm_fraction before (at the
  /// start too: an estimate that never converged has no onset to show).
  double rearm_fraction = 0.8;
  /// Decisions and errors of a method within this long of its first row are its start-up
  /// (initialisation, first alignment), not failures [s].
  double settle_s = 5.0;
  /// An event of the same kind and subject within this long after a kept one is in the
  /// same clip: not another event (a flapping selection would flood the renders) [s].
  double merge_s = 4.0;
  /// Caps: at most this many of each kind and in total, chosen by priority (collision,
  /// fault onset, detection of a faulted sensor, error above the bound, false alarm,
  /// sensor switch), then time.
  size_t max_per_kind = 4;
  size_t max_events = 12;

  /// The options within their limits; otherwise false and *why = "<option>: <problem>".
  bool IsValid(std::string* why = nullptr) const;
};

/// The events of a run, in time order (ties: kind, then subject).
std::vector<RenderEvent> FindEvents(const RunData& run, const EventOptions& options = {});

}  // namespace tofu::renders
