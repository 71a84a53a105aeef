#include "sim/sensor.h"

namespace tofu::sim {

const std::array<Condition, 13>& AllConditions() {
  static const std::array<Condition, 13> all = {
      kOccluded,    kLockLost,   kSearching, kFeatureStarved, kMotionBlur,
      kTrackerReset, kDegenerate, kFewReturns, kNoFix,        kSingleFix,
      kFloatFix,    kMultipath,  kSaturated};
  return all;
}

std::string_view ConditionName(Condition condition) {
  switch (condition) {
    case kOccluded: return "occluded";
    case kLockLost: return "lock_lost";
    case kSearching: return "searching";
    case kFeatureStarved: return "feature_starved";
    case kMotionBlur: return "motion_blur";
    case kTrackerReset: return "tracker_reset";
    case kDegenerate: return "degenerate";
    case kFewReturns: return "few_returns";
    case kNoFix: return "no_fix";
    case kSingleFix: return "single_fix";
    case kFloatFix: return "float_fix";
    case kMultipath: return "multipath";
    case kSaturated: return "saturated";
    case kConditionNone: return "none";
  }
  return "unknown";
}

}  // namespace tofu::sim
