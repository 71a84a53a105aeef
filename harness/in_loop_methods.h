#pragma once
// The estimation methods a flight runs in its loop: each fed, in arrival order, the
// samples as the run directory will record them (replay::AsRecorded), configured from the
// calibration the run will write (DescribeRunStreams), so that `tofu estimate` on the
// written run reproduces them. Set up at the flight's first release (run.cc), once the
// models have latched their reference frames.
//
// Each method is a sequential computation over one input sequence (samples and labels in
// arrival order) and shares nothing with the others, so tofu's own methods can run on
// worker threads beside the flight without changing a bit of their output: the flight
// queues batches of that sequence, and a worker takes one batch of one method at a time
// (the method furthest behind that no other worker has), so that each method runs through
// every batch in order, on one thread at a time. Clients stay on the flight's thread (a
// process client is already asynchronous; a plug-in need not be thread-safe), and so does
// the method a closed-loop flight flies on (the controller needs its every answer at once).

#include <cstddef>
#include <filesystem>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "harness/sample_stream.h"
#include "replay/estimation_config.h"
#include "replay/labels.h"
#include "replay/method_runner.h"

namespace tofu::harness {

struct RunRecord;     // run.h
struct SensorStream;  // run.h

class InLoopMethods {
 public:
  /// `threads` > 1: tofu's own methods run on min(threads, their number) worker threads;
  /// 1: every method runs on the caller's thread. `flying`: the first method is flown on
  /// (closed loop) and stays on the caller's thread.
  InLoopMethods(std::vector<std::string> names, const replay::EstimationConfig& config,
                int threads, bool flying);
  ~InLoopMethods();  ///< stops and joins the workers (a flight that ended by an exception)
  InLoopMethods(const InLoopMethods&) = delete;
  InLoopMethods& operator=(const InLoopMethods&) = delete;

  bool empty() const { return names_.empty(); }
  bool any_clean() const { return any_clean_; }
  bool started() const { return !runners_.empty() || names_.empty(); }

  /// Starts the methods (clients are launched here) and their workers. `spill_dir`: where
  /// the methods' outputs go as they are produced (a run directory), else memory.
  void Start(const RunRecord& record, const std::optional<std::filesystem::path>& spill_dir);
  /// The scheduled faults as labels, known before the flight (the oracle's); given to the
  /// methods when they start.
  void SetFaultSchedule(std::vector<replay::LabelEvent> schedule);
  /// A condition transition the run just recorded.
  void AddLabel(const replay::LabelEvent& label);
  /// The next released sample of `streams[a.stream]`, delivered or clean.
  void Feed(bool clean_stream, const std::vector<SensorStream>& streams, const ArrivedSample& a);

  /// The flying method (closed loop): every answer of what was released so far, before
  /// the controller reads its newest output. Throws SimulationError when it failed: a
  /// flight on a failed estimator has nothing to fly on.
  const replay::MethodRunner& SyncFlying();

  /// Every method's result, in the order of `names`, once the workers have run through
  /// everything fed. Rethrows what a worker's method threw.
  std::vector<replay::ReplayResult> Finish();

 private:
  struct Item;
  struct Pool;
  void Dispatch();
  void StopWorkers();
  void RunWorker();
  void Take(Item item);
  void Apply(const Item& item, std::size_t runner);

  std::vector<std::string> names_;
  replay::EstimationConfig config_;
  int threads_ = 1;
  bool flying_ = false;
  bool any_clean_ = false;
  std::vector<bool> clean_;
  std::vector<replay::MethodRunner> runners_;
  std::vector<std::size_t> on_caller_;  ///< runners_ that run on the caller's thread
  std::vector<replay::LabelEvent> schedule_;
  std::unique_ptr<Pool> pool_;  ///< tofu's own methods on worker threads, if any
  std::shared_ptr<std::vector<Item>> pending_;  ///< the batch being filled for the workers
};

}  // namespace tofu::harness
