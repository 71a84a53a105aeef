#pragma once
// Ground-truth labels of a run (labels.csv): when each condition of a sensor (occluded,
// degenerate, no_fix, ...) and each scheduled fault (divergence, jump, ...) starts and
// ends. Written by the run loop, read back by `tofu estimate`, scored by the evaluation
// and used by the `oracle` method, which fuses exactly the sensors the labels call
// healthy.

#include <cstddef>
#include <map>
#include <string>
#include <vector>

#include "core/time.h"

namespace tofu::replay {

/// A label transition: a condition or a scheduled fault of a sensor starts or ends.
struct LabelEvent {
  core::Time t_ns = 0;
  std::string sensor;
  std::string label;   ///< condition name ("occluded") or fault kind ("divergence")
  std::string source;  ///< "condition" or "fault"
  bool active = false;
};

/// Which sensors the labels call healthy at a time: no fault and no condition active.
/// Labels may be added while queries go on (the run loop learns conditions as it flies):
/// a label must not be added for a time before a query already answered for its sensor
/// (it would change that answer); queries of one sensor are cheapest in time order.
class SensorHealth {
 public:
  void Add(const LabelEvent& label);
  /// No label of `sensor` active at t_ns (a transition at t_ns counts from t_ns on).
  bool Healthy(const std::string& sensor, core::Time t_ns);
  /// The labels of `sensor` active at t_ns, comma-free, "+"-joined (empty when healthy).
  std::string ActiveLabels(const std::string& sensor, core::Time t_ns);

 private:
  struct Timeline {
    std::vector<LabelEvent> events;  // by time, stable
    std::size_t next = 0;            // events before `next` are applied to `active`
    core::Time queried_ns = 0;
    // "source:label" -> starts minus ends so far: overlapping faults of one kind (a
    // start, a start, an end, an end) stay active until the last one ends.
    std::map<std::string, int> active;
  };
  Timeline& AdvanceTo(const std::string& sensor, core::Time t_ns);
  std::map<std::string, Timeline> timelines_;
};

/// A label's activity on one sensor: active in [start_ns, end_ns).
struct LabelInterval {
  std::string sensor;
  std::string label;   ///< fault kind ("divergence") or condition name ("occluded")
  std::string source;  ///< "fault" or "condition"
  core::Time start_ns = 0;
  core::Time end_ns = 0;
  bool open = false;  ///< still active at the end: end_ns is the end given
};

/// Each activation of a label as its own interval. Two scheduled faults of one kind on one
/// sensor may overlap, and their transitions then read start, start, end, end: each start
/// is closed by the next end of its (sensor, label, source), first in first out, so every
/// fault keeps its own interval (the corpus's event table: one row per fault). Starts
/// never ended close at `end_ns`, marked open. Order: closed intervals by their end
/// transition, then the open ones by (sensor, label, source) and start.
std::vector<LabelInterval> PairedLabelIntervals(const std::vector<LabelEvent>& labels,
                                                core::Time end_ns);

/// The time each (sensor, label, source) was active, as disjoint intervals: overlapping
/// or touching activations merged (faults 8-14 s and 10-16 s are active 8-16 s), which is
/// what the sensor's samples were labelled with and what a fault detector had to notice.
/// Faults are scored on these (method_evaluation.h): one detection per interval, and no
/// exclusion inside one is a false exclusion. Sorted by (start, sensor, label).
std::vector<LabelInterval> MergedLabelIntervals(const std::vector<LabelEvent>& labels,
                                                core::Time end_ns);

}  // namespace tofu::replay
