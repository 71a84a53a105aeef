#pragma once
// Sim-internal: the motion of a mount frame s on the robot from the body's ground truth,
// shared by the sensor models. Rigid-body kinematics with the lever arm r = p_Bs and a
// second-order extrapolation over tau (to a sample time inside a physics step):
//   R_WB(tau) = R_WB Exp(omega tau + alpha tau^2 / 2),  p_WB(tau) = p + v tau + a tau^2 / 2,
//   p_Ws = p_WB + R_WB r,  v_Ws = v_WB + R_WB (omega x r),  R_Ws = R_WB R_Bs,
//   omega_s = R_Bs^T omega.

#include <Eigen/Core>
#include <Eigen/Geometry>

#include "core/measurement.h"
#include "sim/world.h"

namespace tofu::sim {

struct MountMotion {
  Eigen::Vector3d p_Ws = Eigen::Vector3d::Zero();
  Eigen::Matrix3d R_Ws = Eigen::Matrix3d::Identity();
  Eigen::Vector3d v_Ws_W = Eigen::Vector3d::Zero();
  Eigen::Vector3d omega_s_s = Eigen::Vector3d::Zero();
};

/// The mount T_Bs's motion tau_s seconds after the truth sample x.
MountMotion MountMotionAt(const TruthState& x, const Eigen::Isometry3d& T_Bs, double tau_s);

/// What a perfect odometry sensor with reference frame S (R_WS, p_WS in W) reports for the
/// mount motion `at`: pose of s in S and body twist of s in s, zero covariances.
core::PoseMeasurement TruePose(const MountMotion& at, const Eigen::Matrix3d& R_WS,
                               const Eigen::Vector3d& p_WS);

}  // namespace tofu::sim
