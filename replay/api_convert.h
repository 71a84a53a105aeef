#pragma once
// tofu's own types <-> the public api's (include/tofu/api.h), one place. Every conversion
// copies doubles as they are (no normalisation, no rounding), so a built-in method that
// goes through the api, in process, through a plug-in or through the protocol, gives
// the same bits as before.

#include <string>

#include <Eigen/Geometry>

#include "core/measurement.h"
#include "estimator/multi_graph_estimator.h"
#include "tofu/api.h"

namespace tofu::replay {

struct RecordedLog;

api::Pose ToApiPose(const Eigen::Isometry3d& T_AB);
Eigen::Isometry3d FromApiPose(const api::Pose& T_AB);
api::Vec3 ToApi(const Eigen::Vector3d& v);
Eigen::Vector3d FromApi(const api::Vec3& v);
/// (w, x, y, z), as stored: no normalisation.
api::Quat ToApi(const Eigen::Quaterniond& q);
Eigen::Quaterniond FromApi(const api::Quat& q);

api::SensorKind ToApi(core::MeasurementKind kind);
core::MeasurementKind FromApi(api::SensorKind kind);

api::Measurement ToApiMeasurement(const core::StampedMeasurement& measurement,
                                  core::Time arrival_ns, std::size_t sensor_index);
/// `sensor`: the name of the stream measurement.sensor indexes.
core::StampedMeasurement FromApiMeasurement(const api::Measurement& measurement,
                                            const std::string& sensor);

/// Moves the fused list (an output is made once and converted once).
api::Estimate ToApiEstimate(estimator::EstimatorOutput&& output);
estimator::EstimatorOutput FromApiEstimate(api::Estimate&& estimate);

/// The setup every method of `log` is given: its streams in the log's order (sorted by
/// name) with their nominal mounts in I; the IMU's index. Texts and config are the
/// caller's.
api::EstimatorSetup ApiSetupOf(const RecordedLog& log, double gravity_mps2);

}  // namespace tofu::replay
