#include "replay/labels.h"

#include <algorithm>
#include <string_view>

namespace tofu::replay {

void SensorHealth::Add(const LabelEvent& label) {
  Timeline& timeline = timelines_[label.sensor];
  // Keep the events in time order (stable: same-time events in the order given).
  const auto at = std::upper_bound(
      timeline.events.begin(), timeline.events.end(), label.t_ns,
      [](core::Time t, const LabelEvent& e) { return t < e.t_ns; });
  const std::size_t index = static_cast<std::size_t>(at - timeline.events.begin());
  timeline.events.insert(at, label);
  // Inserted among the events already applied: replay from the start at the next query.
  if (index < timeline.next) {
    timeline.next = 0;
    timeline.active.clear();
  }
}

SensorHealth::Timeline& SensorHealth::AdvanceTo(const std::string& sensor, core::Time t_ns) {
  Timeline& timeline = timelines_[sensor];
  if (t_ns < timeline.queried_ns) {
    timeline.next = 0;
    timeline.active.clear();
  }
  timeline.queried_ns = t_ns;
  while (timeline.next < timeline.events.size() && timeline.events[timeline.next].t_ns <= t_ns) {
    const LabelEvent& e = timeline.events[timeline.next++];
    int& count = timeline.active[e.source + ":" + e.label];
    count = e.active ? count + 1 : std::max(0, count - 1);
  }
  return timeline;
}

bool SensorHealth::Healthy(const std::string& sensor, core::Time t_ns) {
  const Timeline& timeline = AdvanceTo(sensor, t_ns);
  return std::none_of(timeline.active.begin(), timeline.active.end(),
                      [](const auto& entry) { return entry.second > 0; });
}

std::string SensorHealth::ActiveLabels(const std::string& sensor, core::Time t_ns) {
  std::string out;
  for (const auto& [label, active] : AdvanceTo(sensor, t_ns).active) {
    if (active <= 0) continue;
    if (!out.empty()) out += '+';
    out += std::string_view(label).substr(label.find(':') + 1);
  }
  return out;
}

}  // namespace tofu::replay
