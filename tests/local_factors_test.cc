// Cost functions of the local fixed-lag smoother (estimator/local_factors.h): the pose
// manifold's Plus/Minus and their Jacobians, every factor's analytic Jacobian against
// central differences in the tangent space (large rotations, relative rotations near π,
// biases away from the linearisation point), Ceres's GradientChecker with the manifolds,
// zero residuals at exact states, and the non-finite guards.

#include "estimator/local_factors.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <limits>
#include <memory>
#include <numbers>
#include <stdexcept>
#include <string>
#include <vector>

#include <ceres/gradient_checker.h>

#include "core/lie.h"
#include "core/random.h"

namespace tofu::estimator {
namespace {

using Pose = std::array<double, kPoseSize>;
using SpeedBias = std::array<double, kSpeedBiasSize>;
const Eigen::Vector3d kGravity_L(0.0, 0.0, -9.81);

// ---- random states ----

class Sampler {
 public:
  explicit Sampler(const std::string& name) : random_(7, name) {}

  Eigen::Vector3d Vector(double scale) {
    return scale * Eigen::Vector3d(random_.Normal(), random_.Normal(), random_.Normal());
  }
  Eigen::Vector3d UnitVector() { return Vector(1.0).normalized(); }
  double Uniform(double lo, double hi) { return random_.Uniform(lo, hi); }
  // A rotation by an angle in [lo, hi] about a random axis.
  Eigen::Quaterniond Rotation(double lo_rad, double hi_rad) {
    return core::ExpQuat(Uniform(lo_rad, hi_rad) * UnitVector());
  }
  // Upper-triangular square-root information with a positive, spread diagonal.
  template <int N>
  Eigen::Matrix<double, N, N> SqrtInformation(double scale) {
    Eigen::Matrix<double, N, N> S = Eigen::Matrix<double, N, N>::Zero();
    for (int r = 0; r < N; ++r) {
      S(r, r) = scale * Uniform(0.5, 2.0);
      for (int c = r + 1; c < N; ++c) S(r, c) = scale * Uniform(-0.3, 0.3);
    }
    return S;
  }

 private:
  core::RandomStream random_;
};

Pose MakePose(const Eigen::Vector3d& p_LI, const Eigen::Quaterniond& q_LI) {
  const Eigen::Quaterniond q = q_LI.normalized();
  return {p_LI.x(), p_LI.y(), p_LI.z(), q.x(), q.y(), q.z(), q.w()};
}

Eigen::Quaterniond QuatOf(const Pose& pose) {
  return Eigen::Quaterniond(pose[6], pose[3], pose[4], pose[5]);
}

Eigen::Vector3d PositionOf(const Pose& pose) { return Eigen::Vector3d(pose[0], pose[1], pose[2]); }

SpeedBias MakeSpeedBias(const Eigen::Vector3d& v, const Eigen::Vector3d& b_a,
                        const Eigen::Vector3d& b_g) {
  return {v.x(), v.y(), v.z(), b_a.x(), b_a.y(), b_a.z(), b_g.x(), b_g.y(), b_g.z()};
}

// ---- Jacobian checks ----

// Central differences of the residual in the tangent space of block `b`: each tangent
// coordinate perturbed by ±h through the block's Plus (Euclidean when manifold is null).
Eigen::MatrixXd NumericTangentJacobian(const ceres::CostFunction& cost,
                                       const std::vector<const double*>& blocks,
                                       const std::vector<const ceres::Manifold*>& manifolds,
                                       size_t b, double h = 1e-6) {
  const int ambient = cost.parameter_block_sizes()[b];
  const int tangent = manifolds[b] != nullptr ? manifolds[b]->TangentSize() : ambient;
  Eigen::MatrixXd J(cost.num_residuals(), tangent);
  for (int k = 0; k < tangent; ++k) {
    Eigen::VectorXd residual[2];
    for (int side = 0; side < 2; ++side) {
      Eigen::VectorXd delta = Eigen::VectorXd::Zero(tangent);
      delta[k] = side == 0 ? h : -h;
      std::vector<double> x(ambient);
      if (manifolds[b] != nullptr) {
        EXPECT_TRUE(manifolds[b]->Plus(blocks[b], delta.data(), x.data()));
      } else {
        for (int a = 0; a < ambient; ++a) x[a] = blocks[b][a] + delta[a];
      }
      std::vector<const double*> perturbed = blocks;
      perturbed[b] = x.data();
      EXPECT_TRUE(EvaluateTangent(cost, perturbed, manifolds, &residual[side], nullptr));
    }
    J.col(k) = (residual[0] - residual[1]) / (2.0 * h);
  }
  return J;
}

// Analytic tangent Jacobians (EvaluateTangent) against central differences, row by row:
// the whitening gives the rows very different scales, so each row of [J_0 ... J_n] is
// compared relative to its own norm. Returns the largest relative row error.
double ExpectTangentJacobiansMatch(const ceres::CostFunction& cost,
                                   const std::vector<const double*>& blocks,
                                   const std::vector<const ceres::Manifold*>& manifolds,
                                   const std::string& what, double tolerance = 1e-5) {
  Eigen::VectorXd residual;
  std::vector<Eigen::MatrixXd> analytic;
  EXPECT_TRUE(EvaluateTangent(cost, blocks, manifolds, &residual, &analytic)) << what;
  if (analytic.size() != blocks.size()) return std::numeric_limits<double>::infinity();
  std::vector<Eigen::MatrixXd> numeric;
  for (size_t b = 0; b < blocks.size(); ++b) {
    numeric.push_back(NumericTangentJacobian(cost, blocks, manifolds, b));
    EXPECT_EQ(analytic[b].rows(), numeric[b].rows());
    EXPECT_EQ(analytic[b].cols(), numeric[b].cols());
  }
  double worst = 0.0;
  for (int r = 0; r < cost.num_residuals(); ++r) {
    double row_norm2 = 0.0;
    double diff_norm2 = 0.0;
    for (size_t b = 0; b < blocks.size(); ++b) {
      row_norm2 += numeric[b].row(r).squaredNorm();
      diff_norm2 += (analytic[b].row(r) - numeric[b].row(r)).squaredNorm();
    }
    const double relative = std::sqrt(diff_norm2) / std::max(std::sqrt(row_norm2), 1e-12);
    worst = std::max(worst, relative);
    EXPECT_LT(relative, tolerance) << what << ": residual row " << r;
    if (relative >= tolerance) {
      for (size_t b = 0; b < blocks.size(); ++b) {
        ADD_FAILURE() << what << " row " << r << " block " << b << "\nanalytic "
                      << analytic[b].row(r) << "\nnumeric  " << numeric[b].row(r);
      }
    }
  }
  return worst;
}

// Ceres's own check: its numeric ambient Jacobian (Ridders) and ours, both multiplied by
// the manifolds' PlusJacobians. Ridders' default first step (1e-2 relative, 5e-3 on a
// quaternion coefficient) is too coarse where Log is strongly curved (residual rotation of
// 3 rad) and gives garbage there; 1e-4 is within 3e-10 of the exact derivative.
void ExpectGradientCheckerPasses(const ceres::CostFunction& cost,
                                 const std::vector<const double*>& blocks,
                                 const std::vector<const ceres::Manifold*>& manifolds,
                                 const std::string& what) {
  ceres::NumericDiffOptions options;
  options.ridders_relative_initial_step_size = 1e-4;
  ceres::GradientChecker checker(&cost, &manifolds, options);
  ceres::GradientChecker::ProbeResults results;
  const bool ok = checker.Probe(blocks.data(), 1e-5, &results);
  EXPECT_TRUE(ok) << what << ": max relative error " << results.maximum_relative_error << "\n"
                  << results.error_log;
  std::printf("%s: GradientChecker max relative error %.2e\n", what.c_str(),
              results.maximum_relative_error);
}

// ---- the pose manifold ----

TEST(PoseManifold, PlusMinusRoundTrip) {
  Sampler sample("manifold_round_trip");
  const PoseManifold manifold;
  for (int trial = 0; trial < 20; ++trial) {
    const Pose x = MakePose(sample.Vector(3.0), sample.Rotation(2.0, 3.1));
    Eigen::Matrix<double, 6, 1> delta;
    delta << sample.Vector(1.0), sample.Uniform(0.1, 3.0) * sample.UnitVector();
    Pose y;
    ASSERT_TRUE(manifold.Plus(x.data(), delta.data(), y.data()));
    EXPECT_NEAR(QuatOf(y).norm(), 1.0, 1e-14);
    // Plus is p + δp and q ⊗ Exp(δθ).
    EXPECT_LT((PositionOf(y) - PositionOf(x) - delta.head<3>()).norm(), 1e-12);
    EXPECT_LT(QuatOf(y).angularDistance(QuatOf(x) * core::ExpQuat(delta.tail<3>())), 1e-12);
    Eigen::Matrix<double, 6, 1> back;
    ASSERT_TRUE(manifold.Minus(y.data(), x.data(), back.data()));
    EXPECT_LT((back - delta).norm(), 1e-10) << "trial " << trial;
    // And the other way: x ⊞ (y ⊟ x) = y.
    const Pose z = MakePose(sample.Vector(3.0), sample.Rotation(0.0, 3.1));
    ASSERT_TRUE(manifold.Minus(z.data(), x.data(), back.data()));
    Pose x_plus;
    ASSERT_TRUE(manifold.Plus(x.data(), back.data(), x_plus.data()));
    EXPECT_LT((PositionOf(x_plus) - PositionOf(z)).norm(), 1e-12);
    EXPECT_LT(QuatOf(x_plus).angularDistance(QuatOf(z)), 1e-10);
  }
}

TEST(PoseManifold, JacobiansMatchNumericDerivativesAndLiftIsTheInverse) {
  Sampler sample("manifold_jacobians");
  const PoseManifold manifold;
  const double h = 1e-6;
  for (int trial = 0; trial < 10; ++trial) {
    // Include quaternions with w < 0 (the same rotation, the other sign).
    Eigen::Quaterniond q = sample.Rotation(0.5, 3.1);
    if (trial % 2 == 1) q.coeffs() = -q.coeffs();
    const Pose x = MakePose(sample.Vector(2.0), q);

    Eigen::Matrix<double, 7, 6, Eigen::RowMajor> plus_jacobian;
    ASSERT_TRUE(manifold.PlusJacobian(x.data(), plus_jacobian.data()));
    Eigen::Matrix<double, 7, 6> plus_numeric;
    for (int k = 0; k < 6; ++k) {
      Eigen::Matrix<double, 6, 1> delta = Eigen::Matrix<double, 6, 1>::Zero();
      Pose xp;
      Pose xm;
      delta[k] = h;
      manifold.Plus(x.data(), delta.data(), xp.data());
      delta[k] = -h;
      manifold.Plus(x.data(), delta.data(), xm.data());
      for (int a = 0; a < 7; ++a) plus_numeric(a, k) = (xp[a] - xm[a]) / (2 * h);
    }
    EXPECT_LT((plus_jacobian - plus_numeric).norm(), 1e-8) << "PlusJacobian, trial " << trial;

    // MinusJacobian: ∂Minus(y, x)/∂y at y = x, in all 7 ambient directions.
    Eigen::Matrix<double, 6, 7, Eigen::RowMajor> minus_jacobian;
    ASSERT_TRUE(manifold.MinusJacobian(x.data(), minus_jacobian.data()));
    Eigen::Matrix<double, 6, 7> minus_numeric;
    for (int a = 0; a < 7; ++a) {
      Pose yp = x;
      Pose ym = x;
      yp[a] += h;
      ym[a] -= h;
      Eigen::Matrix<double, 6, 1> dp;
      Eigen::Matrix<double, 6, 1> dm;
      manifold.Minus(yp.data(), x.data(), dp.data());
      manifold.Minus(ym.data(), x.data(), dm.data());
      minus_numeric.col(a) = (dp - dm) / (2 * h);
    }
    EXPECT_LT((minus_jacobian - minus_numeric).norm(), 1e-8) << "MinusJacobian, trial " << trial;

    const Eigen::Matrix<double, 6, 7> lift = PoseLiftJacobian(x.data());
    EXPECT_LT((lift * plus_jacobian - Eigen::Matrix<double, 6, 6>::Identity()).norm(), 1e-14);
    EXPECT_LT((lift - minus_jacobian).norm(), 1e-14);
  }
}

// ---- IMU factor ----

struct ImuFixture {
  ImuBias bias_linearisation;
  ImuPreintegration preintegration{ImuBias{}, ImuNoiseParams{}};
};

// 100 samples at 200 Hz (0.5 s) with rates ~2.5 rad/s (ΔR̃ turns > 1 rad) and a
// specific force around 1 g, integrated at a non-zero linearisation bias.
ImuFixture MakePreintegration(Sampler& sample) {
  ImuFixture f;
  f.bias_linearisation.accel_mps2 = Eigen::Vector3d(0.15, -0.1, 0.12);
  f.bias_linearisation.gyro_radps = Eigen::Vector3d(0.03, 0.02, -0.04);
  f.preintegration = ImuPreintegration(f.bias_linearisation, ImuNoiseParams{});
  const Eigen::Vector3d omega = Eigen::Vector3d(1.0, -2.0, 1.2);
  for (int k = 0; k < 100; ++k) {
    const Eigen::Vector3d accel = Eigen::Vector3d(0.5, -0.3, 9.81) + sample.Vector(1.0);
    const Eigen::Vector3d gyro = omega + sample.Vector(0.3);
    f.preintegration.Integrate(accel, gyro, 0.005);
  }
  return f;
}

// Bias of a state: |b_a| ~ 0.2, |b_g| ~ 0.05, away from the linearisation point.
ImuBias StateBias(const ImuBias& linearisation) {
  ImuBias b = linearisation;
  b.accel_mps2 += Eigen::Vector3d(0.04, 0.05, -0.03);
  b.gyro_radps += Eigen::Vector3d(-0.01, 0.015, 0.008);
  return b;
}

TEST(ImuFactor, TangentJacobiansMatchNumericDifferentiation) {
  Sampler sample("imu_factor_jacobians");
  const PoseManifold pose_manifold;
  const std::vector<const ceres::Manifold*> manifolds = {&pose_manifold, nullptr, &pose_manifold,
                                                         nullptr};
  for (int trial = 0; trial < 6; ++trial) {
    const ImuFixture f = MakePreintegration(sample);
    ASSERT_GT(core::LogSO3(f.preintegration.delta_R()).norm(), 1.0);
    const ImuFactor factor(f.preintegration, kGravity_L);
    const ImuBias b_i = StateBias(f.bias_linearisation);
    const NavState state_i{sample.Rotation(2.0, 3.0), sample.Vector(5.0), sample.Vector(2.0)};
    NavState state_j = f.preintegration.Predict(state_i, b_i, kGravity_L);
    // Even trials: near the solution (small residuals, the small-angle branches); odd
    // trials: far from it, with the rotation residual at 3 rad (near π).
    if (trial % 2 == 0) {
      state_j.q_LI = state_j.q_LI * core::ExpQuat(sample.Vector(0.01));
      state_j.p_LI += sample.Vector(0.01);
      state_j.v_L_mps += sample.Vector(0.01);
    } else {
      state_j.q_LI = state_j.q_LI * core::ExpQuat(3.0 * sample.UnitVector());
      state_j.p_LI += sample.Vector(1.0);
      state_j.v_L_mps += sample.Vector(1.0);
    }
    const Pose pose_i = MakePose(state_i.p_LI, state_i.q_LI);
    const Pose pose_j = MakePose(state_j.p_LI, state_j.q_LI);
    const SpeedBias sb_i = MakeSpeedBias(state_i.v_L_mps, b_i.accel_mps2, b_i.gyro_radps);
    const SpeedBias sb_j = MakeSpeedBias(state_j.v_L_mps, b_i.accel_mps2 + sample.Vector(0.01),
                                         b_i.gyro_radps + sample.Vector(0.001));
    const std::vector<const double*> blocks = {pose_i.data(), sb_i.data(), pose_j.data(),
                                               sb_j.data()};
    if (trial % 2 == 1) {
      Eigen::VectorXd residual;
      ASSERT_TRUE(EvaluateTangent(factor, blocks, manifolds, &residual, nullptr));
      // Un-whiten to read r_ΔR: S is lower triangular, so S^{-1} r recovers it.
      const Eigen::VectorXd r =
          factor.sqrt_information().triangularView<Eigen::Lower>().solve(residual);
      EXPECT_NEAR(r.head<3>().norm(), 3.0, 1e-9);
    }
    const double worst = ExpectTangentJacobiansMatch(factor, blocks, manifolds,
                                                     "ImuFactor trial " + std::to_string(trial));
    std::printf("ImuFactor trial %d: worst relative row error %.2e\n", trial, worst);
    if (trial < 2) {
      ExpectGradientCheckerPasses(factor, blocks, manifolds,
                                  "ImuFactor trial " + std::to_string(trial));
    }
  }
}

// A known motion with a closed-form IMU signal: constant body rate ω (R(t) = R0 Exp(ω t))
// and constant acceleration a_L, so the mean specific force over [t, t + T] is
// (1/T) ∫ Exp(−ω s) ds R(t)ᵀ (a_L − g). The factor between the true states vanishes up
// to the integration's discretisation error: rotating the mean specific force with the
// midpoint attitude misses Δv by (ωT)²/24 |f| T per step (the product of Exp(ωT/2) and
// the mean of Exp(−ωs) is I + [ω]x² T²/24), i.e. 0.3 s · (2.0 · 0.0025)²/24 · 12 m/s² =
// 4e-6 m/s and ~6e-7 m here; the rotation is exact for a constant rate.
TEST(ImuFactor, ResidualVanishesAtTheTrueStates) {
  const Eigen::Matrix3d R0 = core::ExpSO3(Eigen::Vector3d(2.0, -1.0, 0.5));  // 2.3 rad
  const Eigen::Vector3d omega(0.8, -1.5, 1.1);
  const Eigen::Vector3d a_L(1.5, -0.7, 2.0);
  const Eigen::Vector3d p0(1.0, 2.0, 3.0);
  const Eigen::Vector3d v0(0.5, -1.0, 0.3);
  ImuBias bias;
  bias.accel_mps2 = Eigen::Vector3d(0.2, -0.1, 0.05);
  bias.gyro_radps = Eigen::Vector3d(0.04, -0.03, 0.02);
  const auto state_at = [&](double t) {
    return NavState{Eigen::Quaterniond(R0 * core::ExpSO3(omega * t)),
                    p0 + v0 * t + 0.5 * a_L * t * t, v0 + a_L * t};
  };
  // ∫_0^T Exp(−ω s) ds = T I − (1 − cos wT)/w² [ω]x + (T − sin(wT)/w)/w² [ω]x².
  const double T = 1.0 / 400.0;
  const double w = omega.norm();
  const Eigen::Matrix3d W = core::Hat(omega);
  const Eigen::Matrix3d integral = T * Eigen::Matrix3d::Identity() -
                                   (1.0 - std::cos(w * T)) / (w * w) * W +
                                   (T - std::sin(w * T) / w) / (w * w) * W * W;
  ImuPreintegration pre(bias, ImuNoiseParams{});
  const int count = 120;  // 0.3 s
  for (int k = 0; k < count; ++k) {
    const Eigen::Matrix3d R_k = state_at(k * T).q_LI.toRotationMatrix();
    const Eigen::Vector3d accel = integral * R_k.transpose() * (a_L - kGravity_L) / T;
    pre.Integrate(accel + bias.accel_mps2, omega + bias.gyro_radps, T);
  }
  const NavState s_i = state_at(0.0);
  const NavState s_j = state_at(count * T);
  const Pose pose_i = MakePose(s_i.p_LI, s_i.q_LI);
  const Pose pose_j = MakePose(s_j.p_LI, s_j.q_LI);
  const SpeedBias sb_i = MakeSpeedBias(s_i.v_L_mps, bias.accel_mps2, bias.gyro_radps);
  const SpeedBias sb_j = MakeSpeedBias(s_j.v_L_mps, bias.accel_mps2, bias.gyro_radps);
  const ImuFactor factor(pre, kGravity_L);
  Eigen::VectorXd residual;
  ASSERT_TRUE(EvaluateTangent(factor, {pose_i.data(), sb_i.data(), pose_j.data(), sb_j.data()}, {},
                              &residual, nullptr));
  const Eigen::VectorXd r =
      factor.sqrt_information().triangularView<Eigen::Lower>().solve(residual);
  std::printf("true states: |r_R| %.2e rad, |r_v| %.2e m/s, |r_p| %.2e m, whitened %.2e\n",
              r.head<3>().norm(), r.segment<3>(3).norm(), r.tail<3>().norm(), residual.norm());
  EXPECT_LT(r.head<3>().norm(), 1e-10);
  EXPECT_LT(r.segment<3>(3).norm(), 1e-5);
  EXPECT_LT(r.tail<3>().norm(), 2e-6);
  EXPECT_LT(residual.norm(), 0.1);  // far inside the noise (χ²₉ ~ 9)

  // Predict() at a bias away from the linearisation point gives a state at which the
  // factor, evaluated with that bias, is exactly zero (same eq. 44 correction).
  ImuBias other = StateBias(bias);
  const NavState s_pred = pre.Predict(s_i, other, kGravity_L);
  const SpeedBias sb_i_other = MakeSpeedBias(s_i.v_L_mps, other.accel_mps2, other.gyro_radps);
  const Pose pose_pred = MakePose(s_pred.p_LI, s_pred.q_LI);
  const SpeedBias sb_pred = MakeSpeedBias(s_pred.v_L_mps, other.accel_mps2, other.gyro_radps);
  ASSERT_TRUE(EvaluateTangent(factor,
                              {pose_i.data(), sb_i_other.data(), pose_pred.data(), sb_pred.data()},
                              {}, &residual, nullptr));
  EXPECT_LT(residual.norm(), 1e-6);
}

TEST(ImuFactor, RejectsEmptyPreintegrationAndNonFiniteStates) {
  ImuPreintegration empty(ImuBias{}, ImuNoiseParams{});
  EXPECT_THROW(ImuFactor(empty, kGravity_L), std::invalid_argument);
  ImuPreintegration noiseless(ImuBias{}, ImuNoiseParams{0.0, 0.0, 0.0, 0.0});
  for (int k = 0; k < 10; ++k) {
    noiseless.Integrate(Eigen::Vector3d(0, 0, 9.81), Eigen::Vector3d(0.1, 0, 0), 0.005);
  }
  EXPECT_THROW(ImuFactor(noiseless, kGravity_L), std::invalid_argument);

  Sampler sample("imu_factor_nan");
  const ImuFixture f = MakePreintegration(sample);
  const ImuFactor factor(f.preintegration, kGravity_L);
  Pose pose_i = MakePose(Eigen::Vector3d::Zero(), Eigen::Quaterniond::Identity());
  const Pose pose_j = pose_i;
  SpeedBias sb =
      MakeSpeedBias(Eigen::Vector3d::Zero(), Eigen::Vector3d::Zero(), Eigen::Vector3d::Zero());
  Eigen::VectorXd residual;
  EXPECT_TRUE(EvaluateTangent(factor, {pose_i.data(), sb.data(), pose_j.data(), sb.data()}, {},
                              &residual, nullptr));
  pose_i[4] = std::numeric_limits<double>::quiet_NaN();
  EXPECT_FALSE(EvaluateTangent(factor, {pose_i.data(), sb.data(), pose_j.data(), sb.data()}, {},
                               &residual, nullptr));
  pose_i[4] = 0.0;
  sb[7] = std::numeric_limits<double>::infinity();
  EXPECT_FALSE(EvaluateTangent(factor, {pose_i.data(), sb.data(), pose_j.data(), sb.data()}, {},
                               &residual, nullptr));
}

// The smoother splits samples at keyframe times, so an interval may hold a single, even a
// partial, sample: its covariance is positive definite (continuous-time noise within the
// step) and the whitening is exact (Sᵀ S Σ = I).
TEST(ImuFactor, SingleShortSampleGivesAWellConditionedFactor) {
  for (const double dt : {2.5e-3, 1e-4, 1e-6}) {
    ImuPreintegration pre(ImuBias{}, ImuNoiseParams{});
    pre.Integrate(Eigen::Vector3d(0.3, 0.1, 9.81), Eigen::Vector3d(0.5, 0.2, 0.1), dt);
    std::unique_ptr<ImuFactor> factor;
    ASSERT_NO_THROW(factor = std::make_unique<ImuFactor>(pre, kGravity_L)) << dt;
    const Eigen::Matrix<double, 9, 9> SS =
        factor->sqrt_information().transpose() * factor->sqrt_information() * pre.covariance();
    EXPECT_LT((SS - Eigen::Matrix<double, 9, 9>::Identity()).norm(), 1e-6) << dt;
  }
}

// ---- bias random walk ----

TEST(BiasRandomWalkFactor, WhitensByTheDiscretisedRandomWalkAndJacobiansMatch) {
  const ImuNoiseParams noise;
  const double dt = 0.1;
  const BiasRandomWalkFactor factor(dt, noise);
  Sampler sample("bias_random_walk");
  const SpeedBias sb_i = MakeSpeedBias(sample.Vector(1.0), sample.Vector(0.2), sample.Vector(0.05));
  SpeedBias sb_j = sb_i;
  Eigen::VectorXd residual;
  ASSERT_TRUE(EvaluateTangent(factor, {sb_i.data(), sb_j.data()}, {}, &residual, nullptr));
  EXPECT_LT(residual.norm(), 1e-15);  // equal biases (velocities may differ)
  sb_j[0] += 1.0;
  sb_j[3] += 0.01;   // b_a x
  sb_j[8] += 0.001;  // b_g z
  ASSERT_TRUE(EvaluateTangent(factor, {sb_i.data(), sb_j.data()}, {}, &residual, nullptr));
  const double sigma_ba = noise.accel_random_walk_mps3_per_sqrthz * std::sqrt(dt);
  const double sigma_bg = noise.gyro_random_walk_radps2_per_sqrthz * std::sqrt(dt);
  EXPECT_NEAR(residual[0], 0.01 / sigma_ba, 1e-9);
  EXPECT_NEAR(residual[5], 0.001 / sigma_bg, 1e-9);
  EXPECT_NEAR(residual.norm(), std::hypot(0.01 / sigma_ba, 0.001 / sigma_bg), 1e-9);

  const std::vector<const ceres::Manifold*> manifolds = {nullptr, nullptr};
  ExpectTangentJacobiansMatch(factor, {sb_i.data(), sb_j.data()}, manifolds, "BiasRandomWalk");
  EXPECT_THROW(BiasRandomWalkFactor(0.0, noise), std::invalid_argument);
}

// ---- pose between (seed paper eq. 2) ----

TEST(PoseBetweenFactor, ZeroAtTheMeasuredRelativePoseAndJacobiansMatch) {
  Sampler sample("pose_between");
  const PoseManifold pose_manifold;
  const std::vector<const ceres::Manifold*> manifolds = {&pose_manifold, &pose_manifold};
  for (int trial = 0; trial < 6; ++trial) {
    const Eigen::Quaterniond q_i = sample.Rotation(2.0, 3.0);
    const Eigen::Vector3d p_i = sample.Vector(5.0);
    Eigen::Isometry3d T_IJ = Eigen::Isometry3d::Identity();
    T_IJ.linear() = sample.Rotation(2.0, 3.0).toRotationMatrix();
    T_IJ.translation() = sample.Vector(2.0);
    const Eigen::Matrix<double, 6, 6> S = sample.SqrtInformation<6>(10.0);
    const PoseBetweenFactor factor(T_IJ, S);

    // Exact: T_j = T_i T_IJ.
    const Eigen::Quaterniond q_j_exact = q_i * Eigen::Quaterniond(T_IJ.linear());
    const Eigen::Vector3d p_j_exact = p_i + q_i * T_IJ.translation();
    const Pose pose_i = MakePose(p_i, q_i);
    Pose pose_j = MakePose(p_j_exact, q_j_exact);
    Eigen::VectorXd residual;
    ASSERT_TRUE(
        EvaluateTangent(factor, {pose_i.data(), pose_j.data()}, manifolds, &residual, nullptr));
    EXPECT_LT(residual.norm(), 1e-10);

    // Away from it: relative rotation error 3 rad on odd trials (near π), small on even.
    const double angle = trial % 2 == 1 ? 3.0 : 0.05;
    pose_j = MakePose(p_j_exact + sample.Vector(0.5),
                      q_j_exact * core::ExpQuat(angle * sample.UnitVector()));
    ASSERT_TRUE(
        EvaluateTangent(factor, {pose_i.data(), pose_j.data()}, manifolds, &residual, nullptr));
    const Eigen::VectorXd r = S.triangularView<Eigen::Upper>().solve(residual);
    EXPECT_NEAR(r.tail<3>().norm(), angle, 1e-9);
    const std::string what = "PoseBetween trial " + std::to_string(trial);
    ExpectTangentJacobiansMatch(factor, {pose_i.data(), pose_j.data()}, manifolds, what);
    if (trial < 2)
      ExpectGradientCheckerPasses(factor, {pose_i.data(), pose_j.data()}, manifolds, what);
  }
}

// The translation residual is expressed in I_i: an anisotropic information along I_i's x
// axis weights the error along that body axis, whatever the attitude.
TEST(PoseBetweenFactor, TranslationResidualIsInTheFrameOfPoseI) {
  const Eigen::Quaterniond q_i(Eigen::AngleAxisd(std::numbers::pi / 2, Eigen::Vector3d::UnitZ()));
  const Pose pose_i = MakePose(Eigen::Vector3d::Zero(), q_i);
  // p_j displaced by 1 m along L's y, which is I_i's x axis.
  const Pose pose_j = MakePose(Eigen::Vector3d(0, 1, 0), q_i);
  Eigen::Matrix<double, 6, 6> S = Eigen::Matrix<double, 6, 6>::Identity();
  S(0, 0) = 100.0;
  const PoseBetweenFactor factor(Eigen::Isometry3d::Identity(), S);
  Eigen::VectorXd residual;
  ASSERT_TRUE(EvaluateTangent(factor, {pose_i.data(), pose_j.data()}, {}, &residual, nullptr));
  EXPECT_NEAR(residual[0], 100.0, 1e-12);
  EXPECT_NEAR(residual.tail<5>().norm(), 0.0, 1e-12);
}

// ---- position between (seed paper eq. 3) ----

TEST(PositionBetweenFactor, ZeroAtTheMeasuredDisplacementAndJacobiansMatch) {
  Sampler sample("position_between");
  const PoseManifold pose_manifold;
  const std::vector<const ceres::Manifold*> manifolds = {&pose_manifold, &pose_manifold};
  for (int trial = 0; trial < 6; ++trial) {
    const Eigen::Vector3d p_Is = sample.Vector(0.3);
    const Eigen::Matrix3d R_LA = sample.Rotation(2.0, 3.0).toRotationMatrix();
    const Eigen::Quaterniond q_i = sample.Rotation(2.0, 3.0);
    // Relative rotation near π on odd trials.
    const Eigen::Quaterniond q_j =
        q_i * core::ExpQuat((trial % 2 == 1 ? 3.0 : 0.5) * sample.UnitVector());
    const Eigen::Vector3d p_i = sample.Vector(5.0);
    const Eigen::Vector3d p_j = sample.Vector(5.0);
    // The sensor's mount point moved by Δ in L, measured in A: Δp_A = R_LAᵀ Δ.
    const Eigen::Vector3d displacement_L = (p_j + q_j * p_Is) - (p_i + q_i * p_Is);
    const Eigen::Matrix3d S = sample.SqrtInformation<3>(50.0);
    const PositionBetweenFactor exact(p_Is, R_LA, R_LA.transpose() * displacement_L, S);
    const Pose pose_i = MakePose(p_i, q_i);
    const Pose pose_j = MakePose(p_j, q_j);
    Eigen::VectorXd residual;
    ASSERT_TRUE(
        EvaluateTangent(exact, {pose_i.data(), pose_j.data()}, manifolds, &residual, nullptr));
    EXPECT_LT(residual.norm(), 1e-10);

    const PositionBetweenFactor factor(p_Is, R_LA, sample.Vector(2.0), S);
    const std::string what = "PositionBetween trial " + std::to_string(trial);
    ExpectTangentJacobiansMatch(factor, {pose_i.data(), pose_j.data()}, manifolds, what);
    if (trial < 2)
      ExpectGradientCheckerPasses(factor, {pose_i.data(), pose_j.data()}, manifolds, what);
  }
}

// ---- position in L through the frozen T_AL (beyond the paper) ----

TEST(PositionInLocalFactor, ZeroAtTheMeasuredPositionAndJacobiansMatch) {
  Sampler sample("position_in_local");
  const PoseManifold pose_manifold;
  const std::vector<const ceres::Manifold*> manifolds = {&pose_manifold};
  for (int trial = 0; trial < 6; ++trial) {
    const Eigen::Vector3d p_Is = sample.Vector(0.3);
    const Eigen::Quaterniond q = sample.Rotation(2.0, 3.0);
    const Eigen::Vector3d p = sample.Vector(5.0);
    const Eigen::Matrix3d S = sample.SqrtInformation<3>(50.0);
    const Pose pose = MakePose(p, q);
    const PositionInLocalFactor exact(p_Is, p + q * p_Is, S);
    Eigen::VectorXd residual;
    ASSERT_TRUE(EvaluateTangent(exact, {pose.data()}, manifolds, &residual, nullptr));
    EXPECT_LT(residual.norm(), 1e-10);
    // The residual is S times the position error of the mount point in L.
    const Eigen::Vector3d offset = sample.Vector(0.5);
    const PositionInLocalFactor off(p_Is, p + q * p_Is - offset, S);
    ASSERT_TRUE(EvaluateTangent(off, {pose.data()}, manifolds, &residual, nullptr));
    EXPECT_LT((residual - S * offset).norm(), 1e-9);

    const PositionInLocalFactor factor(p_Is, sample.Vector(5.0), S);
    const std::string what = "PositionInLocal trial " + std::to_string(trial);
    ExpectTangentJacobiansMatch(factor, {pose.data()}, manifolds, what);
    if (trial < 2) ExpectGradientCheckerPasses(factor, {pose.data()}, manifolds, what);
  }
}

TEST(PositionWithOffsetFactor, ZeroAtTheMeasuredPositionAndJacobiansMatch) {
  Sampler sample("position_with_offset");
  const PoseManifold pose_manifold;
  const std::vector<const ceres::Manifold*> manifolds = {&pose_manifold, nullptr};
  for (int trial = 0; trial < 6; ++trial) {
    const Eigen::Vector3d p_Is = sample.Vector(0.3);
    const Eigen::Quaterniond q = sample.Rotation(2.0, 3.0);
    const Eigen::Vector3d p = sample.Vector(5.0);
    const Eigen::Matrix3d S = sample.SqrtInformation<3>(50.0);
    const Pose pose = MakePose(p, q);
    Eigen::Vector3d o_L = sample.Vector(2.0);
    // Measured at the mount point less the offset: zero residual.
    const PositionWithOffsetFactor exact(p_Is, p + q * p_Is - o_L, S);
    Eigen::VectorXd residual;
    ASSERT_TRUE(EvaluateTangent(exact, {pose.data(), o_L.data()}, manifolds, &residual, nullptr));
    EXPECT_LT(residual.norm(), 1e-10);
    // Moving the offset by d moves the residual by −S d, whatever the pose.
    const Eigen::Vector3d d = sample.Vector(0.5);
    Eigen::Vector3d moved = o_L + d;
    ASSERT_TRUE(EvaluateTangent(exact, {pose.data(), moved.data()}, manifolds, &residual, nullptr));
    EXPECT_LT((residual + S * d).norm(), 1e-9);

    const PositionWithOffsetFactor factor(p_Is, sample.Vector(5.0), S);
    const std::string what = "PositionWithOffset trial " + std::to_string(trial);
    ExpectTangentJacobiansMatch(factor, {pose.data(), o_L.data()}, manifolds, what);
    if (trial < 2) {
      ExpectGradientCheckerPasses(factor, {pose.data(), o_L.data()}, manifolds, what);
    }
  }
}

// ---- priors ----

TEST(PosePriorFactor, IsTheManifoldMinusAndJacobiansMatch) {
  Sampler sample("pose_prior");
  const PoseManifold pose_manifold;
  const std::vector<const ceres::Manifold*> manifolds = {&pose_manifold};
  for (int trial = 0; trial < 6; ++trial) {
    const Pose prior = MakePose(sample.Vector(3.0), sample.Rotation(2.0, 3.0));
    const Eigen::Matrix<double, 6, 6> S = sample.SqrtInformation<6>(5.0);
    const PosePriorFactor factor(prior.data(), S);
    const PosePriorFactor same(PositionOf(prior), QuatOf(prior), S);
    Eigen::VectorXd residual;
    ASSERT_TRUE(EvaluateTangent(factor, {prior.data()}, manifolds, &residual, nullptr));
    EXPECT_LT(residual.norm(), 1e-12);

    Eigen::Matrix<double, 6, 1> delta;
    delta << sample.Vector(1.0), (trial % 2 == 1 ? 3.0 : 0.1) * sample.UnitVector();
    Pose x;
    pose_manifold.Plus(prior.data(), delta.data(), x.data());
    ASSERT_TRUE(EvaluateTangent(factor, {x.data()}, manifolds, &residual, nullptr));
    EXPECT_LT((residual - S * delta).norm(), 1e-9 * (S * delta).norm());  // S (x ⊟ x0)
    Eigen::VectorXd residual_same;
    ASSERT_TRUE(EvaluateTangent(same, {x.data()}, manifolds, &residual_same, nullptr));
    EXPECT_LT((residual - residual_same).norm(), 1e-12);
    ExpectTangentJacobiansMatch(factor, {x.data()}, manifolds,
                                "PosePrior trial " + std::to_string(trial));
  }
}

TEST(SpeedBiasPriorFactor, IsTheWhitenedDifferenceAndJacobiansMatch) {
  Sampler sample("speed_bias_prior");
  const SpeedBias prior =
      MakeSpeedBias(sample.Vector(1.0), sample.Vector(0.2), sample.Vector(0.05));
  const Eigen::Matrix<double, 9, 9> S = sample.SqrtInformation<9>(3.0);
  const SpeedBiasPriorFactor factor(prior.data(), S);
  const SpeedBias x = MakeSpeedBias(sample.Vector(1.0), sample.Vector(0.2), sample.Vector(0.05));
  Eigen::VectorXd residual;
  ASSERT_TRUE(EvaluateTangent(factor, {prior.data()}, {}, &residual, nullptr));
  EXPECT_LT(residual.norm(), 1e-15);
  ASSERT_TRUE(EvaluateTangent(factor, {x.data()}, {}, &residual, nullptr));
  const Eigen::Map<const Eigen::Matrix<double, 9, 1>> xv(x.data());
  const Eigen::Map<const Eigen::Matrix<double, 9, 1>> pv(prior.data());
  EXPECT_LT((residual - S * (xv - pv)).norm(), 1e-12);
  ExpectTangentJacobiansMatch(factor, {x.data()}, {nullptr}, "SpeedBiasPrior");
}

// ---- non-finite input ----

TEST(LocalFactors, NonFiniteInputIsRejected) {
  const double nan = std::numeric_limits<double>::quiet_NaN();
  const Pose good = MakePose(Eigen::Vector3d(1, 2, 3), Eigen::Quaterniond::Identity());
  Pose bad = good;
  bad[1] = nan;
  SpeedBias sb_good{};
  SpeedBias sb_bad{};
  sb_bad[4] = nan;
  Eigen::VectorXd r;
  const PoseBetweenFactor between(Eigen::Isometry3d::Identity(),
                                  Eigen::Matrix<double, 6, 6>::Identity());
  EXPECT_FALSE(EvaluateTangent(between, {good.data(), bad.data()}, {}, &r, nullptr));
  const PositionBetweenFactor position(Eigen::Vector3d(0.1, 0, 0), Eigen::Matrix3d::Identity(),
                                       Eigen::Vector3d::Zero(), Eigen::Matrix3d::Identity());
  EXPECT_FALSE(EvaluateTangent(position, {bad.data(), good.data()}, {}, &r, nullptr));
  const PosePriorFactor pose_prior(good.data(), Eigen::Matrix<double, 6, 6>::Identity());
  EXPECT_FALSE(EvaluateTangent(pose_prior, {bad.data()}, {}, &r, nullptr));
  const SpeedBiasPriorFactor sb_prior(sb_good.data(), Eigen::Matrix<double, 9, 9>::Identity());
  EXPECT_FALSE(EvaluateTangent(sb_prior, {sb_bad.data()}, {}, &r, nullptr));
  const BiasRandomWalkFactor walk(0.1, ImuNoiseParams{});
  EXPECT_FALSE(EvaluateTangent(walk, {sb_good.data(), sb_bad.data()}, {}, &r, nullptr));
  // A zero quaternion cannot be normalised.
  Pose zero_q = good;
  zero_q[3] = zero_q[4] = zero_q[5] = zero_q[6] = 0.0;
  EXPECT_FALSE(EvaluateTangent(pose_prior, {zero_q.data()}, {}, &r, nullptr));
  // And the good inputs evaluate.
  EXPECT_TRUE(EvaluateTangent(between, {good.data(), good.data()}, {}, &r, nullptr));
  EXPECT_TRUE(EvaluateTangent(sb_prior, {sb_good.data()}, {}, &r, nullptr));
}

}  // namespace
}  // namespace tofu::estimator
