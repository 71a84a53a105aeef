#pragma once
// Helpers shared by the tests that drive a pose sensor model (VIO, LiDAR odometry)
// directly: a world, body poses, a kinematic truth with a constant twist, stepping a model
// through it, and the measured-vs-true errors of its samples.

#include <array>
#include <functional>
#include <numbers>
#include <string>
#include <variant>
#include <vector>

#include <Eigen/Geometry>

#include "core/lie.h"
#include "core/measurement.h"
#include "core/time.h"
#include "sim/sensor.h"
#include "sim/world.h"

namespace tofu::sim::test {

inline World MakeWorld(const std::string& name) {
  WorldOptions options;
  options.world = name;
  return World(options);
}

inline Waypoint Pose(const Eigen::Vector3d& p_WB, double yaw_deg = 0.0) {
  return Waypoint{p_WB, Eigen::Quaterniond(
                            Eigen::AngleAxisd(yaw_deg * std::numbers::pi / 180.0, Eigen::Vector3d::UnitZ()))};
}

// Pose of a mount site for the body at `body` (T_WB T_Bs).
inline Eigen::Isometry3d SitePose(const World& world, const Waypoint& body, const std::string& site) {
  const MountSite* mount = world.robot().FindSite(site);
  Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
  T.linear() = (body.q_WB * mount->q_Bs).toRotationMatrix();
  T.translation() = body.p_WB + body.q_WB * mount->p_Bs;
  return T;
}

// Constant twist of B from a start pose: p = p0 + v t, R = R0 Exp(omega_B t).
inline TruthState ConstantTwist(const Waypoint& start, const Eigen::Vector3d& v_W,
                         const Eigen::Vector3d& omega_B, core::Time t_ns) {
  const double t = core::TimeToSeconds(t_ns);
  TruthState x;
  x.t_ns = t_ns;
  x.p_WB = start.p_WB + v_W * t;
  x.q_WB = (start.q_WB * core::ExpQuat(omega_B * t)).normalized();
  x.v_WB_W = v_W;
  x.omega_WB_B = omega_B;
  return x;
}

// Steps `model` from t = 0 for duration_s with the truth of `truth_at`; the world must
// have been Reset to the start pose. Returns the samples.
inline std::vector<SensorSample> Drive(SensorModel& model, const World& world,
                                const std::function<TruthState(core::Time)>& truth_at,
                                double duration_s) {
  std::vector<SensorSample> samples;
  const std::array<double, kArmCount * kRotorsPerArm> thrust{};
  const core::Time end_ns = core::SecondsToTime(duration_s);
  for (core::Time t = 0; t < end_ns; t += world.timestep_ns()) {
    const TruthState x = truth_at(t);
    model.Step(SensorInput{x, world, thrust}, &samples);
  }
  return samples;
}

inline const core::PoseMeasurement& Measured(const SensorSample& s) {
  return std::get<core::PoseMeasurement>(s.measured);
}
inline const core::PoseMeasurement& Truth(const SensorSample& s) {
  return std::get<core::PoseMeasurement>(s.truth);
}
inline Eigen::Vector3d PositionError_S(const SensorSample& s) {
  return Measured(s).p_Ss - Truth(s).p_Ss;
}
// Left rotation error in S: Log(R_meas R_true^T).
inline Eigen::Vector3d RotationError_S(const SensorSample& s) {
  return core::LogQuat(Measured(s).q_Ss * Truth(s).q_Ss.conjugate());
}

}  // namespace tofu::sim::test
