#pragma once
// Evaluation of a run: the metrics of the catalogue (metrics.h) computed from a
// RunRecord, the scenario's expectations checked against them, and the summary.json
// document. Deterministic: no wall-clock figure enters the summary.

#include <map>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include <nlohmann/json.hpp>

#include "harness/run.h"

namespace tofu::harness {

struct ExpectationResult {
  Expectation expectation;
  std::optional<double> value;  ///< nullopt: undefined (e.g. no samples in the window)
  bool passed = false;
};

struct Evaluation {
  std::vector<ExpectationResult> expectations;
  bool passed = false;  ///< every expectation held and the simulation did not fail
  /// A user's estimator or controller failed (a method of the run, or the flight of a
  /// closed-loop one): `tofu run` exits 3, as for a failed simulation.
  std::vector<std::string> client_failures;
  nlohmann::json summary;
};

/// Value of a catalogue metric over the record; `window_s` restricts windowable metrics
/// to samples with from <= t <= to. nullopt when undefined. Throws std::invalid_argument
/// for a name not in the catalogue.
std::optional<double> MetricValue(const RunRecord& record, const std::string& metric,
                                  const std::optional<std::pair<double, double>>& window_s);

Evaluation Evaluate(const RunRecord& record);

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
std::vector<LabelInterval> PairedLabelIntervals(const std::vector<replay::LabelEvent>& labels,
                                                core::Time end_ns);

/// The time each (sensor, label, source) was active, as disjoint intervals: overlapping
/// or touching activations merged (faults 8-14 s and 10-16 s are active 8-16 s), which is
/// what the sensor's samples were labelled with and what a fault detector had to notice.
/// Faults are scored on these (EvaluateEstimation): one detection per interval, and no
/// exclusion inside one is a false exclusion. Sorted by (start, sensor, label).
std::vector<LabelInterval> MergedLabelIntervals(const std::vector<replay::LabelEvent>& labels,
                                                core::Time end_ns);

/// What a consensus method's decisions score against the run's labels.
struct ConsensusScores {
  int switches = 0;  ///< changes of the fused set once something was fused
  /// Per fault interval (MergedLabelIntervals) except dropouts, by onset.
  std::vector<FaultDetection> detections;
  /// Per sensor of `sensors` (and any other excluded one): seconds excluded while none of
  /// its fault or condition intervals was active.
  std::map<std::string, double> false_exclusion_s;
};
ConsensusScores ScoreConsensusDecisions(const std::vector<estimator::ConsensusRecord>& decisions,
                                        const std::vector<replay::LabelEvent>& labels,
                                        core::Time run_end_ns,
                                        const std::vector<std::string>& sensors);

/// The judgement of a closed-loop flight (RunRecord::closed_loop) against ground truth;
/// the `closed_loop.<method>.*` metrics.
struct ClosedLoopMetrics {
  std::optional<double> tracking_rmse_m;  ///< true |p_WB - p_ref|, whole flight
  std::optional<double> tracking_max_m;
  std::optional<double> estimate_ate_m;   ///< the controller's estimate vs truth, after handover
  std::size_t collisions = 0;
  std::optional<double> min_structure_distance_m;  ///< the distance horizon when nothing nearer
  std::optional<double> time_to_first_collision_s;
  std::size_t failsafe_events = 0;
  bool diverged = false;  ///< tracking_max_m above control.corridor_m
  std::optional<double> handover_s;
};
ClosedLoopMetrics ComputeClosedLoopMetrics(const RunRecord& flight);
/// The metrics and the pilot's events as summary.json holds them.
nlohmann::json ClosedLoopJson(const RunRecord& flight);

}  // namespace tofu::harness
