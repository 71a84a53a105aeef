// The drifting odometry frame VIO and LiDAR odometry share (sim/odometry_frame.h): S is
// latched at boot only where the options leave it unset; with no error the measured pose
// is the true one; the error enters as R_hat = R_err R_Ss, p_hat = p_Ss + dp_S, and the
// path is integrated with the drifted attitude.
#include "sim/odometry_frame.h"

#include <gtest/gtest.h>

#include <cmath>

#include "core/lie.h"

namespace tofu::sim {
namespace {

MountMotion Motion(const Eigen::Vector3d& p_Ws, const Eigen::Vector3d& rotation_vector) {
  MountMotion m;
  m.p_Ws = p_Ws;
  m.R_Ws = core::ExpSO3(rotation_vector);
  m.v_Ws_W = Eigen::Vector3d(0.5, -0.2, 0.1);
  m.omega_s_s = Eigen::Vector3d(0.01, 0.02, -0.3);
  return m;
}

TEST(DriftingOdometryFrame, BootLatchesOnlyTheUnsetPartsOnce) {
  const MountMotion boot = Motion({1, 2, 3}, {0.1, -0.2, 0.3});
  DriftingOdometryFrame unset(std::nullopt, std::nullopt);
  EXPECT_TRUE(unset.Boot(boot));
  EXPECT_TRUE(unset.T_WS().translation().isApprox(boot.p_Ws));
  EXPECT_TRUE(unset.T_WS().linear().isApprox(boot.R_Ws));
  EXPECT_FALSE(unset.Boot(Motion({9, 9, 9}, {0, 0, 1})));  // later steps change nothing
  EXPECT_TRUE(unset.T_WS().translation().isApprox(boot.p_Ws));

  const Eigen::Quaterniond q_WS(Eigen::AngleAxisd(0.7, Eigen::Vector3d::UnitZ()));
  DriftingOdometryFrame attitude_set(std::nullopt, q_WS);
  EXPECT_TRUE(attitude_set.T_WS().linear().isApprox(q_WS.toRotationMatrix()));  // known now
  attitude_set.Boot(boot);
  EXPECT_TRUE(attitude_set.T_WS().translation().isApprox(boot.p_Ws));
  EXPECT_TRUE(attitude_set.T_WS().linear().isApprox(q_WS.toRotationMatrix()));

  DriftingOdometryFrame position_set(Eigen::Vector3d(-1, 0, 4), std::nullopt);
  position_set.Boot(boot);
  EXPECT_TRUE(position_set.T_WS().translation().isApprox(Eigen::Vector3d(-1, 0, 4)));
  EXPECT_TRUE(position_set.T_WS().linear().isApprox(boot.R_Ws));
}

TEST(DriftingOdometryFrame, WithoutErrorTheMeasuredPoseIsTheTruth) {
  DriftingOdometryFrame frame(std::nullopt, std::nullopt);
  frame.Boot(Motion({1, 2, 3}, {0.1, -0.2, 0.3}));
  const MountMotion at = Motion({2, 1, 3.5}, {0.2, 0.1, -0.4});
  const core::PoseMeasurement truth = frame.TruePose(at);
  const core::PoseMeasurement measured =
      frame.Measured(at, truth, std::nullopt, std::nullopt, std::nullopt);
  EXPECT_EQ(measured.p_Ss, truth.p_Ss);
  EXPECT_LT(measured.q_Ss.angularDistance(truth.q_Ss), 1e-12);
  EXPECT_EQ(measured.v_s_s_mps, truth.v_s_s_mps);
  EXPECT_EQ(measured.omega_s_s_radps, truth.omega_s_s_radps);
  EXPECT_TRUE(measured.has_twist);
}

TEST(DriftingOdometryFrame, TheErrorEntersAsTheModelStates) {
  DriftingOdometryFrame frame(Eigen::Vector3d::Zero(), Eigen::Quaterniond::Identity());
  const Eigen::Vector3d dtheta_S(0.0, 0.0, 0.05);
  frame.RotateError(dtheta_S);
  frame.AddPositionError(Eigen::Vector3d(0.1, 0.0, 0.0));
  // A 2 m step along x with a yaw error of 0.05 rad: dp += (R_err - I) step.
  frame.IntegratePath(Eigen::Vector3d(2.0, 0.0, 0.0));
  const Eigen::Matrix3d R_err = core::ExpSO3(dtheta_S);
  EXPECT_TRUE(frame.R_err().isApprox(R_err));
  const Eigen::Vector3d dp_S =
      Eigen::Vector3d(0.1, 0.0, 0.0) + (R_err - Eigen::Matrix3d::Identity()) * Eigen::Vector3d(2, 0, 0);

  const MountMotion at = Motion({2, 0, 0}, {0.0, 0.0, 0.2});
  const core::PoseMeasurement truth = frame.TruePose(at);
  const Eigen::Vector3d velocity_error_S(0.0, 0.3, 0.0);
  const Eigen::Vector3d rotation_noise_s(0.01, 0.0, 0.0);
  const core::PoseMeasurement measured =
      frame.Measured(at, truth, Eigen::Vector3d(0, 0, 0.02), rotation_noise_s, velocity_error_S);
  EXPECT_TRUE(measured.p_Ss.isApprox(truth.p_Ss + dp_S + Eigen::Vector3d(0, 0, 0.02)));
  const Eigen::Matrix3d R_hat = R_err * truth.q_Ss.toRotationMatrix();
  EXPECT_TRUE(measured.q_Ss.toRotationMatrix().isApprox(R_hat * core::ExpSO3(rotation_noise_s)));
  EXPECT_TRUE(measured.v_s_s_mps.isApprox(truth.v_s_s_mps + R_hat.transpose() * velocity_error_S));
}

}  // namespace
}  // namespace tofu::sim
