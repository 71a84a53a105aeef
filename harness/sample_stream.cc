#include "harness/sample_stream.h"

#include <tuple>
#include <utility>

namespace tofu::harness {

bool ArrivalQueue::Later::operator()(const Entry& a, const Entry& b) const {
  // std::priority_queue pops its greatest element: "later" sorts first.
  return std::tie(a.arrival_ns, a.rank, a.t_ns, a.sequence) >
         std::tie(b.arrival_ns, b.rank, b.t_ns, b.sequence);
}

ArrivalQueue::ArrivalQueue(std::vector<uint32_t> stream_rank)
    : stream_rank_(std::move(stream_rank)) {}

void ArrivalQueue::Push(std::size_t stream, const sim::SensorSample& sample) {
  heap_.push(Entry{sample.arrival_ns, stream_rank_.at(stream), sample.t_ns, next_sequence_++,
                   stream, sample});
}

void ArrivalQueue::Release(core::Time now_ns,
                           const std::function<void(const ArrivedSample&)>& consumer) {
  while (!heap_.empty() && heap_.top().arrival_ns <= now_ns) {
    const Entry& top = heap_.top();
    consumer(ArrivedSample{top.stream, &top.sample});
    heap_.pop();
  }
}

void ArrivalQueue::Flush(const std::function<void(const ArrivedSample&)>& consumer) {
  while (!heap_.empty()) {
    const Entry& top = heap_.top();
    consumer(ArrivedSample{top.stream, &top.sample});
    heap_.pop();
  }
}

}  // namespace tofu::harness
