#include "estimator/consistency.h"

namespace tofu::estimator {

std::string_view MetricName(ConsistencyMetric metric) {
  switch (metric) {
    case ConsistencyMetric::kMae: return "mae";
    case ConsistencyMetric::kPcc: return "pcc";
    case ConsistencyMetric::kKl: return "kl";
    case ConsistencyMetric::kCm: return "cm";
  }
  return "unknown";
}

std::optional<ConsistencyMetric> MetricFromName(std::string_view name) {
  for (const ConsistencyMetric m : {ConsistencyMetric::kMae, ConsistencyMetric::kPcc,
                                    ConsistencyMetric::kKl, ConsistencyMetric::kCm}) {
    if (MetricName(m) == name) return m;
  }
  return std::nullopt;
}

}  // namespace tofu::estimator
