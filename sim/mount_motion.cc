#include "sim/mount_motion.h"

#include "core/lie.h"

namespace tofu::sim {

MountMotion MountMotionAt(const TruthState& x, const Eigen::Isometry3d& T_Bs, double tau_s) {
  const Eigen::Vector3d omega_B = x.omega_WB_B + x.alpha_WB_B * tau_s;
  Eigen::Matrix3d R_WB = x.q_WB.toRotationMatrix();
  Eigen::Vector3d p_WB = x.p_WB;
  Eigen::Vector3d v_WB = x.v_WB_W;
  if (tau_s != 0.0) {
    R_WB = R_WB * core::ExpSO3(x.omega_WB_B * tau_s + 0.5 * x.alpha_WB_B * tau_s * tau_s);
    p_WB += x.v_WB_W * tau_s + 0.5 * x.a_WB_W * tau_s * tau_s;
    v_WB += x.a_WB_W * tau_s;
  }
  const Eigen::Vector3d r = T_Bs.translation();
  const Eigen::Matrix3d R_Bs = T_Bs.linear();
  MountMotion m;
  m.p_Ws = p_WB + R_WB * r;
  m.R_Ws = R_WB * R_Bs;
  m.v_Ws_W = v_WB + R_WB * omega_B.cross(r);
  m.omega_s_s = R_Bs.transpose() * omega_B;
  return m;
}

core::PoseMeasurement TruePose(const MountMotion& at, const Eigen::Matrix3d& R_WS,
                               const Eigen::Vector3d& p_WS) {
  core::PoseMeasurement truth;
  truth.p_Ss = R_WS.transpose() * (at.p_Ws - p_WS);
  truth.q_Ss = core::CanonicalQuat(Eigen::Quaterniond(R_WS.transpose() * at.R_Ws));
  truth.covariance.setZero();
  truth.has_twist = true;
  truth.v_s_s_mps = at.R_Ws.transpose() * at.v_Ws_W;
  truth.omega_s_s_radps = at.omega_s_s;
  truth.twist_covariance.setZero();
  return truth;
}

}  // namespace tofu::sim
