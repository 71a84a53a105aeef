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

void AddTwistWhiteNoise(double velocity_noise_mps, double angular_rate_noise_radps,
                        core::RandomStream& stream, core::PoseMeasurement* measured) {
  if (velocity_noise_mps > 0.0) measured->v_s_s_mps += velocity_noise_mps * stream.Normal3();
  if (angular_rate_noise_radps > 0.0) {
    measured->omega_s_s_radps += angular_rate_noise_radps * stream.Normal3();
  }
}

}  // namespace tofu::sim
