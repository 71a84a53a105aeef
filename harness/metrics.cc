#include "harness/metrics.h"

#include "sim/faults.h"
#include "sim/sensor.h"

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
      {"sensors.<sensor>.delivered_samples", "count",
       "samples the stream delivered (after scheduled faults)", true},
      {"sensors.<sensor>.condition.<condition>", "fraction",
       "fraction of the time the condition (e.g. occluded, no_fix, degenerate) was active; "
       "a+b: any of them (e.g. single_fix+no_fix: GNSS without RTK)",
       true},
      {"sensors.<sensor>.position_error_rms_m", "m",
       "RMS of the true position error of the delivered samples (pose and position sensors)",
       true},
      // Estimation methods (`estimation:`), harness/estimation.h.
      {"methods.<method>.ate_m", "m",
       "position ATE: RMS of the position error after an SE(3) alignment of the whole estimate",
       false},
      {"methods.<method>.ate_max_m", "m", "largest position error under the same alignment", false},
      {"methods.<method>.rotation_rmse_deg", "deg", "RMS rotation error under the same alignment",
       false},
      {"methods.<method>.rpe_m", "m", "RMS relative position error over 1 s", false},
      {"methods.<method>.position_step_max_m", "m",
       "continuity: the largest change of the aligned position error between consecutive "
       "outputs (a step of the estimate the true motion does not explain)",
       false},
      {"methods.<method>.nees_position_mean", "",
       "mean NEES of the reported position covariance (3 when consistent)", false},
      {"methods.<method>.nees_position_median", "",
       "median NEES of the reported position covariance (2.37 when consistent)", false},
      {"methods.<method>.position_containment_95", "fraction",
       "samples whose true position is inside the reported covariance's 95 % ellipsoid "
       "(NEES <= 7.81; 0.95 when consistent)",
       false},
      {"methods.<method>.valid_fraction", "fraction", "valid outputs / outputs", false},
      {"methods.<method>.switches", "count", "changes of the fused set (consensus)", false},
      {"methods.<method>.missed_faults", "count",
       "scheduled faults (dropouts aside) never excluded by the method (consensus)", false},
      {"methods.<method>.max_detection_delay_s", "s",
       "largest delay from fault onset to the sensor's exclusion; inf when one was missed",
       false},
      {"methods.<method>.detection_delay_s.<fault>", "s",
       "largest detection delay over the faults of one kind; inf when one was missed", false},
      {"methods.<method>.max_readmission_delay_s", "s",
       "largest delay from the end of a detected fault until the sensor is trusted again "
       "(available, not excluded); inf when it never is",
       false},
      {"methods.<method>.false_exclusion_fraction", "fraction",
       "largest time a sensor was excluded with no fault or condition active, over the run",
       false},
      // Closed-loop flights (`control: {state_source: estimate}`), harness/closed_loop.h:
      // the robot flew on the method's estimate; judged against ground truth.
      {"closed_loop.<method>.tracking_rmse_m", "m",
       "RMS of the true |p_WB - p_ref| of the flight flown on the method (over the window)", true},
      {"closed_loop.<method>.tracking_max_m", "m",
       "largest true |p_WB - p_ref| of that flight (over the window)", true},
      {"closed_loop.<method>.estimate_ate_m", "m",
       "RMS of |p_WB estimated - p_WB true| as the controller saw it, after the handover",
       false},
      {"closed_loop.<method>.collisions", "count", "contact events of that flight", false},
      {"closed_loop.<method>.min_structure_distance_m", "m",
       "smallest distance to structure (ground excluded) in that flight", false},
      {"closed_loop.<method>.time_to_first_collision_s", "s",
       "time of the first contact; undefined when none", false},
      {"closed_loop.<method>.failsafe_events", "count", "failsafe activations in that flight",
       false},
      {"closed_loop.<method>.diverged", "bool",
       "1 when the true position left the reference by more than control.corridor_m", false},
      {"closed_loop.<method>.handover_s", "s", "when the controller began flying on the estimate",
       false},
  };
  return catalog;
}

namespace {

bool IsIdentifier(std::string_view s) {
  if (s.empty()) return false;
  for (const char c : s) {
    if (!((c >= 'a' && c <= 'z') || (c >= '0' && c <= '9') || c == '_')) return false;
  }
  return true;
}

// Method names (replay/replay.h): single:vio@clean, fuse:vio+leica, consensus, ...
bool IsMethodName(std::string_view s) {
  if (s.empty()) return false;
  for (const char c : s) {
    if (!((c >= 'a' && c <= 'z') || (c >= '0' && c <= '9') || c == '_' || c == ':' || c == '@' ||
          c == '+')) {
      return false;
    }
  }
  return true;
}

bool IsFaultName(std::string_view s) { return sim::FaultKindFromName(s).has_value(); }

bool IsConditionName(std::string_view s) {
  for (const sim::Condition c : sim::AllConditions()) {
    if (sim::ConditionName(c) == s) return true;
  }
  return false;
}

// "a+b+c": a union of condition names, each known.
bool IsConditionUnion(std::string_view s) {
  size_t begin = 0;
  while (true) {
    const size_t plus = s.find('+', begin);
    if (!IsConditionName(s.substr(begin, plus == std::string_view::npos ? plus : plus - begin))) {
      return false;
    }
    if (plus == std::string_view::npos) return true;
    begin = plus + 1;
  }
}

std::vector<std::string_view> SplitDots(std::string_view s) {
  std::vector<std::string_view> parts;
  size_t begin = 0;
  while (true) {
    const size_t dot = s.find('.', begin);
    parts.push_back(s.substr(begin, dot == std::string_view::npos ? dot : dot - begin));
    if (dot == std::string_view::npos) return parts;
    begin = dot + 1;
  }
}

}  // namespace

std::optional<std::pair<const MetricInfo*, MetricArguments>> MatchMetric(std::string_view name) {
  const std::vector<std::string_view> parts = SplitDots(name);
  for (const MetricInfo& info : MetricCatalog()) {
    const std::vector<std::string_view> pattern = SplitDots(info.name);
    if (pattern.size() != parts.size()) continue;
    MetricArguments args;
    bool match = true;
    for (size_t i = 0; i < parts.size() && match; ++i) {
      if (pattern[i] == "<sensor>") {
        match = IsIdentifier(parts[i]);
        args.sensor = parts[i];
      } else if (pattern[i] == "<method>") {
        match = IsMethodName(parts[i]);
        args.method = parts[i];
      } else if (pattern[i] == "<fault>") {
        match = IsFaultName(parts[i]);
        args.fault = parts[i];
      } else if (pattern[i] == "<condition>") {
        match = IsConditionUnion(parts[i]);
        args.condition = parts[i];
      } else {
        match = pattern[i] == parts[i];
      }
    }
    if (match) return std::make_pair(&info, args);
  }
  return std::nullopt;
}

const MetricInfo* FindMetric(std::string_view name) {
  const auto match = MatchMetric(name);
  return match ? match->first : nullptr;
}

}  // namespace tofu::harness
