#pragma once
// The catalogue of summary metrics a scenario's `expect:` block may assert on. One
// place: the scenario validator rejects names not listed here, the evaluator computes
// exactly these.

#include <string>
#include <optional>
#include <string_view>
#include <utility>
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

/// The catalogue entry of `name`, or nullptr. Catalogue names may hold placeholders:
/// `<sensor>` matches a stream name ([a-z0-9_]+) and `<condition>` a condition name
/// (sim::ConditionName), e.g. "sensors.leica.condition.occluded"; `<method>` an
/// estimation method ("methods.single:vio@clean.ate_m") and `<fault>` a fault kind.
const MetricInfo* FindMetric(std::string_view name);

/// The placeholders of a metric name filled in by FindMetric's match.
struct MetricArguments {
  std::string sensor;     ///< empty unless the metric is per sensor
  std::string condition;  ///< empty unless the metric is per condition
  std::string method;     ///< empty unless the metric is per estimation method
  std::string fault;      ///< empty unless the metric is per fault kind
};

/// Splits a concrete metric name ("sensors.gnss.condition.no_fix") into its catalogue
/// entry and arguments; nullopt if it matches no entry.
std::optional<std::pair<const MetricInfo*, MetricArguments>> MatchMetric(std::string_view name);

}  // namespace tofu::harness
