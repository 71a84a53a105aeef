#include "harness/in_loop_methods.h"

#include <algorithm>
#include <condition_variable>
#include <deque>
#include <exception>
#include <mutex>
#include <optional>
#include <thread>
#include <utility>
#include <variant>

#include "core/error.h"
#include "harness/run.h"
#include "harness/run_directory.h"
#include "replay/recorded_log.h"
#include "replay/replay_method.h"
#include "replay/run_format.h"

namespace tofu::harness {
namespace {

// Items per batch handed to the workers, and batches a worker may have waiting before the
// flight waits for it. A batch is a few tenths of a second of flight with the full sensor
// suite: the hand-over (a lock and a wake-up) is paid per batch, not per sample, and the
// flight never runs more than a few seconds of data ahead of the slowest worker, which
// bounds the memory the queues hold.
constexpr std::size_t kBatchItems = 512;
constexpr std::size_t kMaxWaitingBatches = 8;

}  // namespace

// One entry of the sequence every method sees: a released sample (of the delivered or
// the clean streams) or a label, in the order the flight produced them.
struct InLoopMethods::Item {
  struct Sample {
    bool clean = false;
    core::StampedMeasurement measurement;
    core::Time arrival_ns = 0;
  };
  std::variant<Sample, replay::LabelEvent> entry;
};

// tofu's own methods off the caller's thread: the batches every method still needs, and
// per method how far it got. A worker takes one batch of one method at a time: the method
// furthest behind that no other worker is running. So a method's batches go through it in
// order, one thread at a time (the pool's mutex hands its state from one to the next), and
// the cores stay busy however unequal the methods' costs are.
struct InLoopMethods::Pool {
  struct Method {
    std::size_t runner = 0;      // index into runners_
    std::size_t next_batch = 0;  // the first batch it has not run
    bool running = false;        // a worker has it now
    std::exception_ptr error;    // after a failure it runs nothing more
  };
  std::vector<Method> methods;
  std::vector<std::thread> threads;
  std::mutex mutex;
  std::condition_variable changed;
  std::deque<std::shared_ptr<const std::vector<Item>>> batches;  // from first_batch on
  std::size_t first_batch = 0;  // index of batches.front()
  std::size_t batch_count = 0;  // batches queued so far
  bool closing = false;         // nothing more will be queued

  // Under the mutex: the method a free worker should run next, if any.
  std::optional<std::size_t> NextMethod() const {
    std::optional<std::size_t> next;
    for (std::size_t m = 0; m < methods.size(); ++m) {
      if (methods[m].running || methods[m].next_batch == batch_count) continue;
      if (!next || methods[m].next_batch < methods[*next].next_batch) next = m;
    }
    return next;
  }
  // Under the mutex: how many batches the slowest method has still to run.
  std::size_t Backlog() const {
    std::size_t slowest = batch_count;
    for (const Method& method : methods) slowest = std::min(slowest, method.next_batch);
    return batch_count - slowest;
  }
};

InLoopMethods::InLoopMethods(std::vector<std::string> names, const replay::EstimationConfig& config,
                             int threads, bool flying)
    : names_(std::move(names)), config_(config), threads_(std::max(1, threads)), flying_(flying) {
  for (const std::string& name : names_) any_clean_ |= name.ends_with("@clean");
}

InLoopMethods::~InLoopMethods() { StopWorkers(); }

void InLoopMethods::Start(const RunRecord& record,
                          const std::optional<std::filesystem::path>& spill_dir) {
  std::vector<std::pair<std::string, core::MeasurementKind>> kinds;
  for (const SensorStream& s : record.sensors) kinds.emplace_back(s.name, s.kind);
  const std::string calibration_yaml = CalibrationYamlText(record);
  const replay::RecordedLog log = replay::DescribeRunStreams(kinds, calibration_yaml, "");
  const replay::EstimationSetup setup = replay::MakeEstimationSetup(log, config_);
  const replay::ClientTexts texts{calibration_yaml, config_.resolved_yaml};
  std::vector<std::size_t> threadable;
  for (std::size_t i = 0; i < names_.size(); ++i) {
    const replay::ReplayMethod method = replay::ParseReplayMethod(names_[i], log, config_.clients);
    clean_.push_back(method.clean_streams);
    runners_.emplace_back(log, method, setup.estimator, setup.sensors, setup.consensus, texts);
    if (spill_dir) runners_.back().SpillOutputsTo(*spill_dir);
    const bool flown = flying_ && i == 0;
    if (threads_ > 1 && !flown && method.kind != replay::ReplayMethod::Kind::kClient) {
      threadable.push_back(i);
    } else {
      on_caller_.push_back(i);
    }
  }
  if (!threadable.empty()) {
    pool_ = std::make_unique<Pool>();
    for (const std::size_t r : threadable) pool_->methods.emplace_back().runner = r;
    const std::size_t worker_count = std::min<std::size_t>(threadable.size(), threads_);
    for (std::size_t w = 0; w < worker_count; ++w) {
      pool_->threads.emplace_back([this] { RunWorker(); });
    }
    pending_ = std::make_shared<std::vector<Item>>();
  }
  // The labels known so far: the fault schedule, and the conditions of the first step.
  for (const replay::LabelEvent& label : schedule_) AddLabel(label);
  for (const replay::LabelEvent& label : record.labels) AddLabel(label);
}

// A worker's loop: one batch of one method at a time (Pool), until the flight has closed
// the queue and no method has a batch left that no other worker is running. After a
// failure a method takes its batches (the flight must not wait on it) but runs nothing
// more: Finish reports the failure.
void InLoopMethods::RunWorker() {
  Pool& pool = *pool_;
  for (;;) {
    std::size_t m = 0;
    std::shared_ptr<const std::vector<Item>> batch;
    {
      std::unique_lock lock(pool.mutex);
      std::optional<std::size_t> next;
      pool.changed.wait(lock, [&] { return (next = pool.NextMethod()) || pool.closing; });
      if (!next) return;  // closing, and what is left is another worker's
      m = *next;
      pool.methods[m].running = true;
      batch = pool.batches[pool.methods[m].next_batch - pool.first_batch];
    }
    Pool::Method& method = pool.methods[m];
    if (!method.error) {
      try {
        for (const Item& item : *batch) Apply(item, method.runner);
      } catch (...) {
        method.error = std::current_exception();
      }
    }
    {
      std::lock_guard lock(pool.mutex);
      method.running = false;
      ++method.next_batch;
      while (pool.first_batch < pool.batch_count - pool.Backlog()) {
        pool.batches.pop_front();
        ++pool.first_batch;
      }
    }
    pool.changed.notify_all();  // the method for another worker, room for the flight
  }
}

// One item of the sequence to the method runners_[r].
void InLoopMethods::Apply(const Item& item, std::size_t r) {
  if (const auto* s = std::get_if<Item::Sample>(&item.entry)) {
    if (clean_[r] == s->clean) runners_[r].Add(s->measurement, s->arrival_ns);
  } else {
    runners_[r].AddLabel(std::get<replay::LabelEvent>(item.entry));
  }
}

void InLoopMethods::SetFaultSchedule(std::vector<replay::LabelEvent> schedule) {
  schedule_ = std::move(schedule);
}

void InLoopMethods::AddLabel(const replay::LabelEvent& label) { Take(Item{label}); }

void InLoopMethods::Feed(bool clean_stream, const std::vector<SensorStream>& streams,
                         const ArrivedSample& a) {
  Take(Item{Item::Sample{clean_stream,
                         {streams[a.stream].name, a.sample->t_ns, replay::AsRecorded(a.sample->measured)},
                         a.sample->arrival_ns}});
}

// The next item of the sequence: to the methods on this thread now, to the workers' batch.
void InLoopMethods::Take(Item item) {
  for (const std::size_t r : on_caller_) Apply(item, r);
  if (pending_) {
    pending_->push_back(std::move(item));
    if (pending_->size() >= kBatchItems) Dispatch();
  }
}

void InLoopMethods::Dispatch() {
  if (!pending_ || pending_->empty()) return;
  std::shared_ptr<const std::vector<Item>> batch = std::move(pending_);
  pending_ = std::make_shared<std::vector<Item>>();
  pending_->reserve(kBatchItems);
  Pool& pool = *pool_;
  {
    std::unique_lock lock(pool.mutex);
    pool.changed.wait(lock, [&] { return pool.Backlog() < kMaxWaitingBatches; });
    pool.batches.push_back(std::move(batch));
    ++pool.batch_count;
  }
  pool.changed.notify_all();
}

void InLoopMethods::StopWorkers() {
  if (!pool_) return;
  {
    std::lock_guard lock(pool_->mutex);
    pool_->closing = true;
  }
  pool_->changed.notify_all();
  for (std::thread& thread : pool_->threads) {
    if (thread.joinable()) thread.join();
  }
}

const replay::MethodRunner& InLoopMethods::SyncFlying() {
  replay::MethodRunner& flying = runners_[0];
  flying.Sync();
  if (flying.failed()) throw core::SimulationError(flying.failure_text());
  return flying;
}

std::vector<replay::ReplayResult> InLoopMethods::Finish() {
  Dispatch();
  StopWorkers();
  if (pool_) {
    for (const Pool::Method& method : pool_->methods) {
      if (method.error) std::rethrow_exception(method.error);
    }
  }
  std::vector<replay::ReplayResult> results;
  for (replay::MethodRunner& r : runners_) results.push_back(std::move(r).Finish());
  return results;
}

}  // namespace tofu::harness
