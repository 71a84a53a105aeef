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

}  // namespace tofu::replay
