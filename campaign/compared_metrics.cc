#include "campaign/compared_metrics.h"

namespace tofu::campaign {

std::string ComparedMetric::Pattern() const {
  if (scope == "run") return "run." + key + (key == "expectation" ? ".<label>" : "");
  return scope + ".<method>." + key;
}

const std::vector<ComparedMetric>& ComparedMetrics() {
  // Minimal effects: what a user would act on. 5 % of an error's scale is below the
  // seed-to-seed spread of one flight and above the numerical noise of a paired one; the
  // delays and fractions are the goals' own resolution (docs/RESULTS.md).
  static const std::vector<ComparedMetric> metrics = {
      {"ate_m", "methods", EffectKind::kRatio, false, 0.05, "m", 1,
       "position RMSE after SE(3) alignment"},
      {"rotation_rmse_deg", "methods", EffectKind::kRatio, false, 0.05, "deg", 1,
       "rotation RMSE after alignment"},
      {"rpe_m", "methods", EffectKind::kRatio, false, 0.05, "m", 1, "relative position error"},
      {"position_step_max_m", "methods", EffectKind::kRatio, false, 0.10, "m", 1,
       "largest jump of the position error between outputs"},
      {"max_detection_delay_s", "methods", EffectKind::kDifference, false, 0.2, "s", 1,
       "worst detection delay of a detected fault"},
      {"max_readmission_delay_s", "methods", EffectKind::kDifference, false, 0.5, "s", 1,
       "worst re-admission delay of a re-admitted sensor"},
      {"false_exclusion_fraction", "methods", EffectKind::kDifference, false, 0.005, "", 1,
       "share of healthy sensor time excluded"},
      {"valid_fraction", "methods", EffectKind::kDifference, true, 0.01, "", 1,
       "share of outputs that are valid"},
      {"failed", "methods", EffectKind::kEvent, false, 0.0, "", 1, "the method's client failed"},
      {"missed_fault", "methods", EffectKind::kEvent, false, 0.0, "", 1,
       "a scheduled fault was never detected"},
      {"never_readmitted", "methods", EffectKind::kEvent, false, 0.0, "", 1,
       "a sensor was never trusted again after its fault ended"},
      {"tracking_rmse_m", "closed_loop", EffectKind::kRatio, false, 0.05, "m", 1,
       "true tracking RMSE of the flight on the method"},
      {"tracking_max_m", "closed_loop", EffectKind::kRatio, false, 0.10, "m", 1,
       "largest true tracking error"},
      {"min_structure_distance_m", "closed_loop", EffectKind::kDifference, true, 0.02, "m", 1,
       "closest approach to a structure"},
      {"failed", "closed_loop", EffectKind::kEvent, false, 0.0, "", 1,
       "the flight's estimator or controller failed"},
      {"collided", "closed_loop", EffectKind::kEvent, false, 0.0, "", 1, "the robot hit a structure"},
      {"diverged", "closed_loop", EffectKind::kEvent, false, 0.0, "", 1,
       "the tracking error left the control corridor"},
      {"failsafe", "closed_loop", EffectKind::kEvent, false, 0.0, "", 1,
       "the pilot fell back to its failsafe"},
      {"failed", "run", EffectKind::kEvent, false, 0.0, "", 1,
       "the run failed (bad input, simulation, output) or has no summary"},
      {"expectation", "run", EffectKind::kEvent, false, 0.0, "", 1,
       "the scenario's expectation did not hold"},
  };
  return metrics;
}

const ComparedMetric* FindComparedMetric(std::string_view pattern) {
  for (const ComparedMetric& m : ComparedMetrics()) {
    if (m.Pattern() == pattern) return &m;
  }
  return nullptr;
}

std::optional<ConcreteMetric> MatchComparedMetric(std::string_view name) {
  for (const ComparedMetric& m : ComparedMetrics()) {
    const std::string prefix = m.scope + ".";
    if (!name.starts_with(prefix)) continue;
    if (m.scope == "run") {
      if (m.key == "expectation" && name.starts_with("run.expectation.") &&
          name.size() > std::string_view("run.expectation.").size()) {
        return ConcreteMetric{&m, std::string(name.substr(16))};
      }
      if (name == "run." + m.key) return ConcreteMetric{&m, ""};
      continue;
    }
    // <scope>.<method>.<key>: a method's name may hold dots, the key holds none.
    const std::string suffix = "." + m.key;
    if (name.size() > prefix.size() + suffix.size() && name.ends_with(suffix)) {
      return ConcreteMetric{
          &m, std::string(name.substr(prefix.size(), name.size() - prefix.size() - suffix.size()))};
    }
  }
  return std::nullopt;
}

}  // namespace tofu::campaign
