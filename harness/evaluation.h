#pragma once
// Evaluation of a run: the metrics of the catalogue (metrics.h) computed from a
// RunRecord, the scenario's expectations checked against them, and the summary.json
// document. Deterministic: no wall-clock figure enters the summary.

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
  nlohmann::json summary;
};

/// Value of a catalogue metric over the record; `window_s` restricts windowable metrics
/// to samples with from <= t <= to. nullopt when undefined. Throws std::invalid_argument
/// for a name not in the catalogue.
std::optional<double> MetricValue(const RunRecord& record, const std::string& metric,
                                  const std::optional<std::pair<double, double>>& window_s);

Evaluation Evaluate(const RunRecord& record);

}  // namespace tofu::harness
