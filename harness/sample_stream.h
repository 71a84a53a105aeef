#pragma once
// The run's one arrival-ordered sample stream (docs/DESIGN.md, "Data flow of one run").
// Sensor models stamp each sample with its time of validity t_ns and its arrival
// arrival_ns = t_ns + latency (+ a scheduled delay); the run loop pushes every sample as
// it is produced and, after each physics step, releases to its consumers those that have
// arrived by the step's end, in the order (arrival, stream rank, t_ns, production order).
// That order is the one ReadRecordedLog gives a recorded run (stream rank = the stream's
// place among the streams sorted by name), so a consumer in the loop and a replay of the
// written run see the same sequence.
//
// A sample is released only once the clock has passed its arrival: a consumer acting at
// time t has seen exactly the samples with arrival_ns <= t (the causality the
// closed-loop test checks).

#include <cstdint>
#include <functional>
#include <queue>
#include <vector>

#include "core/time.h"
#include "sim/sensor.h"

namespace tofu::harness {

/// A released sample: which stream (index into the run's sensor list) and the sample.
struct ArrivedSample {
  std::size_t stream = 0;
  const sim::SensorSample* sample = nullptr;
};

class ArrivalQueue {
 public:
  /// `stream_rank[i]`: the place of stream i among the streams sorted by name.
  explicit ArrivalQueue(std::vector<uint32_t> stream_rank);

  /// A sample of stream `stream`, produced now. The queue keeps a copy.
  void Push(std::size_t stream, const sim::SensorSample& sample);
  /// Hands every sample with arrival_ns <= now_ns to `consumer`, in arrival order.
  void Release(core::Time now_ns, const std::function<void(const ArrivedSample&)>& consumer);
  /// Hands every remaining sample over (the end of the run: what was recorded, the
  /// recorded run's replay sees too).
  void Flush(const std::function<void(const ArrivedSample&)>& consumer);
  std::size_t pending() const { return heap_.size(); }

 private:
  struct Entry {
    core::Time arrival_ns;
    uint32_t rank;
    core::Time t_ns;
    uint64_t sequence;
    std::size_t stream;
    sim::SensorSample sample;
  };
  struct Later {
    bool operator()(const Entry& a, const Entry& b) const;
  };
  std::vector<uint32_t> stream_rank_;
  std::priority_queue<Entry, std::vector<Entry>, Later> heap_;
  uint64_t next_sequence_ = 0;
};

}  // namespace tofu::harness
