#include "harness/metrics.h"

namespace tofu::harness {

const std::vector<MetricInfo>& MetricCatalog() {
  static const std::vector<MetricInfo> catalog = {
      {"tracking.position_rmse_m", "m", "RMS of |p_WB - p_ref| over the window", true},
      {"tracking.position_max_m", "m", "maximum of |p_WB - p_ref| over the window", true},
      {"tracking.attitude_rmse_deg", "deg", "RMS of the angle of R_ref^T R_WB", true},
      {"tracking.attitude_max_deg", "deg", "maximum angle of R_ref^T R_WB", true},
      {"tracking.final_position_error_m", "m", "|p_WB - p_ref| at the end of the run", false},
      {"collisions.count", "count", "contact events between robot and structure", false},
      {"structure.min_distance_m", "m",
       "smallest distance between robot collision geometry and structure (ground excluded)",
       false},
      {"allocation.saturation_fraction", "fraction",
       "fraction of controller updates whose allocation hit a thrust limit", true},
      {"approach.max_standoff_error_m", "m",
       "largest |tool-tip distance to surface - standoff| at the end of approach segments",
       false},
  };
  return catalog;
}

const MetricInfo* FindMetric(std::string_view name) {
  for (const MetricInfo& info : MetricCatalog()) {
    if (info.name == name) return &info;
  }
  return nullptr;
}

}  // namespace tofu::harness
