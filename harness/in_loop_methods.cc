#include "harness/in_loop_methods.h"

#include <algorithm>
#include <condition_variable>
#include <deque>
#include <exception>
#include <mutex>
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

struct InLoopMethods::Worker {
  std::vector<std::size_t> runners;  // indices into runners_, run in this order
  std::thread thread;
  std::mutex mutex;
  std::condition_variable changed;
  std::deque<std::shared_ptr<const std::vector<Item>>> batches;
  bool closing = false;  // nothing more will be queued
  std::exception_ptr error;
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
  // Methods dealt to the workers in turn (paper_consensus_indoor's four over two cores:
  // consensus with single:vio@clean, naive with single:vio).
  const std::size_t worker_count = std::min<std::size_t>(threadable.size(), threads_);
  for (std::size_t w = 0; w < worker_count; ++w) workers_.push_back(std::make_unique<Worker>());
  for (std::size_t k = 0; k < threadable.size(); ++k) {
    workers_[k % worker_count]->runners.push_back(threadable[k]);
  }
  for (const std::unique_ptr<Worker>& worker : workers_) {
    worker->thread = std::thread([this, w = worker.get()] { RunWorker(*w); });
  }
  if (!workers_.empty()) pending_ = std::make_shared<std::vector<Item>>();
  // The labels known so far: the fault schedule, and the conditions of the first step.
  for (const replay::LabelEvent& label : schedule_) AddLabel(label);
  for (const replay::LabelEvent& label : record.labels) AddLabel(label);
}

// A worker's loop: every batch in order through each of its methods, until the flight
// closes the queue and it is empty. After a failure the worker keeps taking batches (the
// flight must not wait on it) but runs nothing more: Finish reports the failure.
void InLoopMethods::RunWorker(Worker& worker) {
  for (;;) {
    std::shared_ptr<const std::vector<Item>> batch;
    {
      std::unique_lock lock(worker.mutex);
      worker.changed.wait(lock, [&] { return worker.closing || !worker.batches.empty(); });
      if (worker.batches.empty()) return;  // closing, and everything is done
      batch = std::move(worker.batches.front());
      worker.batches.pop_front();
    }
    worker.changed.notify_all();  // room for the flight's next batch
    if (worker.error) continue;
    try {
      for (const Item& item : *batch) Apply(item, worker.runners);
    } catch (...) {
      worker.error = std::current_exception();
    }
  }
}

// One item of the sequence to the methods `runners` (indices into runners_).
void InLoopMethods::Apply(const Item& item, const std::vector<std::size_t>& runners) {
  for (const std::size_t r : runners) {
    if (const auto* s = std::get_if<Item::Sample>(&item.entry)) {
      if (clean_[r] == s->clean) runners_[r].Add(s->measurement, s->arrival_ns);
    } else {
      runners_[r].AddLabel(std::get<replay::LabelEvent>(item.entry));
    }
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
  Apply(item, on_caller_);
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
  for (const std::unique_ptr<Worker>& worker : workers_) {
    {
      std::unique_lock lock(worker->mutex);
      worker->changed.wait(lock, [&] { return worker->batches.size() < kMaxWaitingBatches; });
      worker->batches.push_back(batch);
    }
    worker->changed.notify_all();
  }
}

void InLoopMethods::StopWorkers() {
  for (const std::unique_ptr<Worker>& worker : workers_) {
    {
      std::lock_guard lock(worker->mutex);
      worker->closing = true;
    }
    worker->changed.notify_all();
  }
  for (const std::unique_ptr<Worker>& worker : workers_) {
    if (worker->thread.joinable()) worker->thread.join();
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
  for (const std::unique_ptr<Worker>& worker : workers_) {
    if (worker->error) std::rethrow_exception(worker->error);
  }
  std::vector<replay::ReplayResult> results;
  for (replay::MethodRunner& r : runners_) results.push_back(std::move(r).Finish());
  return results;
}

}  // namespace tofu::harness
