// A pose stream's between-factor noise from its own white error and drift
// (estimator/pose_noise.h): the Jacobian of the relative motion against central
// differences, and the bound on a chain's joint covariance that independent factors with
// each factor's exact marginal covariance do not give.
#include "estimator/pose_noise.h"

#include <gtest/gtest.h>

#include <vector>

#include <Eigen/Eigenvalues>
#include <Eigen/QR>

#include "core/lie.h"
#include "core/random.h"

namespace tofu::estimator {
namespace {

using Matrix6 = Eigen::Matrix<double, 6, 6>;

Eigen::Isometry3d RandomPose(core::RandomStream& rng, double translation_m, double angle_rad) {
  Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
  T.linear() = core::ExpSO3(angle_rad * rng.Normal3());
  T.translation() = translation_m * rng.Normal3();
  return T;
}

// A white covariance [δθ_s; δp_A] with correlated blocks (a LiDAR odometry states one).
Matrix6 RandomWhite(core::RandomStream& rng, double rotation_std_rad, double position_std_m) {
  Matrix6 A;
  for (int r = 0; r < 6; ++r) {
    for (int c = 0; c < 6; ++c) A(r, c) = rng.Normal() * (r < 3 ? rotation_std_rad : position_std_m);
  }
  return A * A.transpose() / 6.0;
}

// The relative motion of I as PoseBetweenFactor measures it, its error against the
// unperturbed one as [p̂_IJ − p_IJ; Log(R_IJᵀ R̂_IJ)].
Eigen::Matrix<double, 6, 1> BetweenError(const Eigen::Isometry3d& T_As_i,
                                         const Eigen::Isometry3d& T_As_j,
                                         const Eigen::Isometry3d& T_Is,
                                         const Eigen::Matrix<double, 12, 1>& delta) {
  const auto perturbed = [](const Eigen::Isometry3d& T, const Eigen::Matrix<double, 6, 1>& d) {
    Eigen::Isometry3d P = T;
    P.linear() = T.linear() * core::ExpSO3(d.head<3>());
    P.translation() = T.translation() + d.tail<3>();
    return P;
  };
  const Eigen::Isometry3d T_IJ = T_Is * (T_As_i.inverse() * T_As_j) * T_Is.inverse();
  const Eigen::Isometry3d T_IJ_hat =
      T_Is * (perturbed(T_As_i, delta.head<6>()).inverse() * perturbed(T_As_j, delta.tail<6>())) *
      T_Is.inverse();
  Eigen::Matrix<double, 6, 1> e;
  e.head<3>() = T_IJ_hat.translation() - T_IJ.translation();
  e.tail<3>() = core::LogSO3(T_IJ.linear().transpose() * T_IJ_hat.linear());
  return e;
}

TEST(PoseBetweenJacobian, MatchesCentralDifferences) {
  core::RandomStream rng(31, "pose_noise_test");
  for (int trial = 0; trial < 20; ++trial) {
    const Eigen::Isometry3d T_As_i = RandomPose(rng, 3.0, 1.0);
    const Eigen::Isometry3d T_As_j = T_As_i * RandomPose(rng, 0.3, 0.3);
    const Eigen::Isometry3d T_Is = RandomPose(rng, 0.2, 1.0);
    const Eigen::Matrix<double, 6, 12> J = PoseBetweenJacobian(T_As_i, T_As_j, T_Is);
    constexpr double kStep = 1e-6;
    for (int c = 0; c < 12; ++c) {
      Eigen::Matrix<double, 12, 1> d = Eigen::Matrix<double, 12, 1>::Zero();
      d[c] = kStep;
      const Eigen::Matrix<double, 6, 1> numeric =
          (BetweenError(T_As_i, T_As_j, T_Is, d) - BetweenError(T_As_i, T_As_j, T_Is, -d)) /
          (2.0 * kStep);
      EXPECT_LT((J.col(c) - numeric).norm(), 1e-7) << "trial " << trial << " column " << c
                                                   << "\n" << J.col(c).transpose() << "\n"
                                                   << numeric.transpose();
    }
  }
}

// The drift adds σ² d per axis, d the distance travelled between the two poses.
TEST(PoseBetweenCovariance, DriftGrowsWithTheDistanceBetweenThePoses) {
  core::RandomStream rng(32, "pose_noise_test");
  const Eigen::Isometry3d T_As_i = RandomPose(rng, 3.0, 1.0);
  const Eigen::Isometry3d T_As_j = T_As_i * RandomPose(rng, 0.3, 0.3);
  const Eigen::Isometry3d T_Is = RandomPose(rng, 0.2, 1.0);
  const Matrix6 W = RandomWhite(rng, 1e-3, 2e-3);
  const Matrix6 white_only = PoseBetweenCovariance(T_As_i, W, T_As_j, W, T_Is, {0.02, 0.002}, 0.0);
  const Matrix6 with_drift = PoseBetweenCovariance(T_As_i, W, T_As_j, W, T_Is, {0.02, 0.002}, 0.5);
  Matrix6 expected = Matrix6::Zero();
  expected.topLeftCorner<3, 3>().diagonal().setConstant(0.02 * 0.02 * 0.5);
  expected.bottomRightCorner<3, 3>().diagonal().setConstant(0.002 * 0.002 * 0.5);
  EXPECT_LT((with_drift - white_only - expected).norm(), 1e-15);
}

// Four poses of one stream, three consecutive between factors. Their errors' joint
// covariance T (from the poses' white errors through the Jacobians, plus each interval's
// drift) is tridiagonal in blocks. The block-diagonal D of PoseBetweenCovariance dominates
// it (D − T ⪰ 0); the factors' exact marginals (no doubling) do not: fused as independent
// they are over-confident about the difference of consecutive displacements.
TEST(PoseBetweenCovariance, BoundsAChainsJointCovarianceWhereExactMarginalsDoNot) {
  core::RandomStream rng(33, "pose_noise_test");
  for (int trial = 0; trial < 20; ++trial) {
    const Eigen::Isometry3d T_Is = RandomPose(rng, 0.2, 1.0);
    std::vector<Eigen::Isometry3d> poses{RandomPose(rng, 3.0, 1.0)};
    std::vector<Matrix6> white;
    for (int k = 0; k < 4; ++k) {
      if (k > 0) poses.push_back(poses.back() * RandomPose(rng, 0.05, 0.05));
      white.push_back(RandomWhite(rng, 1e-3, 2e-3));
    }
    const PoseDriftRates drift{0.02, 0.002};
    Eigen::Matrix<double, 18, 24> G = Eigen::Matrix<double, 18, 24>::Zero();
    Eigen::Matrix<double, 24, 24> W_all = Eigen::Matrix<double, 24, 24>::Zero();
    Eigen::Matrix<double, 18, 18> bound = Eigen::Matrix<double, 18, 18>::Zero();
    Eigen::Matrix<double, 18, 18> marginals = Eigen::Matrix<double, 18, 18>::Zero();
    Eigen::Matrix<double, 18, 18> drift_part = Eigen::Matrix<double, 18, 18>::Zero();
    for (int k = 0; k < 4; ++k) W_all.block<6, 6>(6 * k, 6 * k) = white[k];
    for (int f = 0; f < 3; ++f) {
      const Eigen::Matrix<double, 6, 12> J = PoseBetweenJacobian(poses[f], poses[f + 1], T_Is);
      G.block<6, 12>(6 * f, 6 * f) = J;
      const double distance_m = (poses[f + 1].translation() - poses[f].translation()).norm();
      bound.block<6, 6>(6 * f, 6 * f) = PoseBetweenCovariance(
          poses[f], white[f], poses[f + 1], white[f + 1], T_Is, drift, distance_m);
      const Matrix6 drift_only = PoseBetweenCovariance(poses[f], Matrix6::Zero(), poses[f + 1],
                                                       Matrix6::Zero(), T_Is, drift, distance_m);
      drift_part.block<6, 6>(6 * f, 6 * f) = drift_only;
      marginals.block<6, 6>(6 * f, 6 * f) = J.leftCols<6>() * white[f] * J.leftCols<6>().transpose() +
                                            J.rightCols<6>() * white[f + 1] *
                                                J.rightCols<6>().transpose() +
                                            drift_only;
    }
    const Eigen::Matrix<double, 18, 18> truth = G * W_all * G.transpose() + drift_part;
    // The marginals are exact block by block ...
    for (int f = 0; f < 3; ++f) {
      EXPECT_LT((marginals.block<6, 6>(6 * f, 6 * f) - truth.block<6, 6>(6 * f, 6 * f)).norm(),
                1e-12 * truth.norm());
    }
    const double scale = truth.norm();
    const auto min_eigenvalue = [](const Eigen::Matrix<double, 18, 18>& M) {
      return Eigen::SelfAdjointEigenSolver<Eigen::Matrix<double, 18, 18>>(0.5 * (M + M.transpose()))
          .eigenvalues()
          .minCoeff();
    };
    // ... the bound dominates the joint covariance, the marginals do not.
    EXPECT_GE(min_eigenvalue(bound - truth), -1e-12 * scale) << "trial " << trial;
    EXPECT_LT(min_eigenvalue(marginals - truth), -1e-3 * scale) << "trial " << trial;
  }
}

// The directions a projector keeps get their marginal information (P Σ P)⁺; the
// conditional information P Σ⁻¹ P, what multiplying Σ⁻¹'s square root by P gives, exceeds
// it where Σ couples kept and dropped directions. With P = I both are Σ⁻¹.
TEST(ObservedSqrtInformation, KeepsTheMarginalInformationOfTheKeptDirections) {
  core::RandomStream rng(34, "pose_noise_test");
  for (int trial = 0; trial < 20; ++trial) {
    const Matrix6 covariance = RandomWhite(rng, 1e-2, 2e-2) + 1e-6 * Matrix6::Identity();
    Eigen::Matrix<double, 6, 4> basis;
    for (int c = 0; c < 4; ++c) basis.col(c) = Eigen::Matrix<double, 6, 1>::NullaryExpr([&] { return rng.Normal(); });
    const Eigen::HouseholderQR<Eigen::Matrix<double, 6, 4>> qr(basis);
    const Eigen::Matrix<double, 6, 4> Q = qr.householderQ() * Eigen::Matrix<double, 6, 4>::Identity();
    const Matrix6 P = Q * Q.transpose();
    const Matrix6 S = ObservedSqrtInformation(covariance, P);
    // (P Σ P)⁺ on the kept subspace: Q (Qᵀ Σ Q)⁻¹ Qᵀ.
    const Matrix6 marginal = Q * (Q.transpose() * covariance * Q).inverse() * Q.transpose();
    EXPECT_LT((S.transpose() * S - marginal).norm(), 1e-9 * marginal.norm()) << "trial " << trial;
    const Matrix6 conditional = P * covariance.inverse() * P;
    EXPECT_GT(Eigen::SelfAdjointEigenSolver<Matrix6>(conditional - marginal).eigenvalues().maxCoeff(),
              1e-6 * marginal.norm())
        << "trial " << trial;
    const Matrix6 all = ObservedSqrtInformation(covariance, Matrix6::Identity());
    EXPECT_LT((all.transpose() * all - covariance.inverse()).norm(), 1e-9 * covariance.inverse().norm());
  }
}

}  // namespace
}  // namespace tofu::estimator
