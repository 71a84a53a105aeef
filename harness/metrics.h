#pragma once
// The catalogue of summary metrics a scenario's `expect:` block may assert on. One
// place: the scenario validator rejects names not listed here, the evaluator computes
// exactly these.

#include <string>
#include <string_view>
#include <vector>

namespace tofu::harness {

struct MetricInfo {
  std::string name;         ///< dotted name, e.g. "tracking.position_rmse_m"
  std::string unit;         ///< "m", "deg", "count", "fraction"
  std::string description;
  bool windowable = false;  ///< may be restricted to a time window (`window_s`)
};

/// Every metric known to the evaluator, in a stable order.
const std::vector<MetricInfo>& MetricCatalog();

/// The catalogue entry of `name`, or nullptr.
const MetricInfo* FindMetric(std::string_view name);

}  // namespace tofu::harness
