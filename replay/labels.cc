#include "replay/labels.h"

#include <algorithm>
#include <deque>
#include <map>
#include <tuple>
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

std::vector<LabelInterval> PairedLabelIntervals(const std::vector<LabelEvent>& labels,
                                                core::Time end_ns) {
  std::map<std::tuple<std::string, std::string, std::string>, std::deque<core::Time>> started;
  std::vector<LabelInterval> intervals;
  for (const LabelEvent& l : labels) {
    const auto key = std::make_tuple(l.sensor, l.label, l.source);
    if (l.active) {
      started[key].push_back(l.t_ns);
    } else if (const auto it = started.find(key); it != started.end() && !it->second.empty()) {
      intervals.push_back({l.sensor, l.label, l.source, it->second.front(), l.t_ns, false});
      it->second.pop_front();
    }
  }
  for (const auto& [key, onsets] : started) {
    for (const core::Time onset : onsets) {
      intervals.push_back({std::get<0>(key), std::get<1>(key), std::get<2>(key), onset, end_ns, true});
    }
  }
  return intervals;
}

std::vector<LabelInterval> MergedLabelIntervals(const std::vector<LabelEvent>& labels,
                                                core::Time end_ns) {
  std::vector<LabelInterval> paired = PairedLabelIntervals(labels, end_ns);
  const auto key = [](const LabelInterval& i) {
    return std::tie(i.sensor, i.label, i.source, i.start_ns, i.end_ns);
  };
  std::sort(paired.begin(), paired.end(),
            [&](const LabelInterval& a, const LabelInterval& b) { return key(a) < key(b); });
  std::vector<LabelInterval> merged;
  for (const LabelInterval& i : paired) {
    LabelInterval* last = merged.empty() ? nullptr : &merged.back();
    if (last != nullptr && last->sensor == i.sensor && last->label == i.label &&
        last->source == i.source && i.start_ns <= last->end_ns) {
      if (i.end_ns > last->end_ns) {
        last->end_ns = i.end_ns;
        last->open = i.open;
      } else if (i.end_ns == last->end_ns) {
        last->open = last->open || i.open;
      }
      continue;
    }
    merged.push_back(i);
  }
  std::sort(merged.begin(), merged.end(), [](const LabelInterval& a, const LabelInterval& b) {
    return std::tie(a.start_ns, a.sensor, a.label, a.source) <
           std::tie(b.start_ns, b.sensor, b.label, b.source);
  });
  return merged;
}

}  // namespace tofu::replay
