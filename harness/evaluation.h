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
  /// Why the metric has no value to judge: the method or closed-loop flight it names
  /// failed, or the simulation did. Such an expectation fails.
  std::optional<std::string> not_measurable;
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
/// Why a closed-loop flight failed: the simulation's failure, else its flying method's
/// (a client that failed during or at the end of the flight); nullopt for a sound flight.
std::optional<std::string> ClosedLoopFlightFailure(const RunRecord& flight);
/// The metrics and the pilot's events as summary.json holds them.
nlohmann::json ClosedLoopJson(const RunRecord& flight);

}  // namespace tofu::harness
