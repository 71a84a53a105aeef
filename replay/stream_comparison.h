#pragma once
// A sensor stream on its own against what a method made of it: its pose stream as a
// trajectory of the IMU frame (the reference a fused method is compared with), and the
// consistency of its velocity with the local estimate over time.

#include <optional>
#include <string>
#include <vector>

#include "core/time.h"
#include "estimator/consistency.h"
#include "replay/method_runner.h"
#include "replay/recorded_log.h"
#include "replay/trajectory_metrics.h"

namespace tofu::replay {

/// Body velocity of each sensor's mount from its own stream and from the local estimate
/// (v_s = R_Isᵀ (R_LIᵀ v_L + ω_I × p_Is)), compared with a consistency metric over a
/// sliding window at `rate_hz`. Pose streams are differentiated in their own frame A and
/// rotated by their own attitude; position streams need R_As, taken from the local
/// estimate and the estimator's final T_AL.
struct LocalConsistencySeries {
  std::string sensor;
  std::vector<core::Time> t_ns;
  std::vector<std::optional<double>> value;
};
std::vector<LocalConsistencySeries> LocalConsistency(
    const RecordedLog& log, const ReplayResult& result, estimator::ConsistencyMetric metric,
    const estimator::ConsistencyOptions& options, double rate_hz);

/// A pose stream on its own as a trajectory of the IMU frame, T_AI = T_As T_Is⁻¹, within
/// [from_ns, to_ns]: the reference fused methods are compared with.
std::vector<PoseSample> RawPoseTrajectory(const RecordedLog& log, const RecordedStream& stream,
                                          core::Time from_ns, core::Time to_ns);

}  // namespace tofu::replay
