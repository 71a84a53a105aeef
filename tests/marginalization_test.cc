// Marginalisation into a linear Gaussian prior (estimator/marginalization.h):
//  - on a linear problem the prior is the exact Schur complement (JᵀJ = H*, Jᵀr0 = b*, by
//    hand) and the reduced problem (remaining factors + prior) has the batch solution;
//  - on a nonlinear pose problem marginalised at its optimum, the reduced problem keeps
//    the optimum and the kept blocks' marginal covariance;
//  - LinearPriorFactor's Jacobians against central differences in the tangent space,
//    away from the linearisation point (rotation ~1 rad), for Euclidean, PoseManifold and
//    a generic Ceres manifold block;
//  - directions without information are dropped (fewer rows, finite), and a non-finite
//    factor makes Marginalize return false with the prior untouched.
// Deterministic: own mt19937_64 + Box-Muller, fixed seeds.

#include "estimator/marginalization.h"

#include <gtest/gtest.h>

#include <cmath>
#include <cstdint>
#include <limits>
#include <memory>
#include <random>
#include <vector>

#include <Eigen/Dense>
#include <ceres/ceres.h>

#include "core/lie.h"
#include "estimator/imu_preintegration.h"
#include "estimator/local_factors.h"
#include "tests/ceres_test_support.h"

namespace tofu::estimator {
namespace {

// ---- deterministic randomness ----

class Rng {
 public:
  explicit Rng(std::uint64_t seed) : engine_(seed) {}
  // Uniform in [0, 1) from the top 53 bits (platform independent, unlike the std
  // distributions).
  double Uniform() { return static_cast<double>(engine_() >> 11) * 0x1.0p-53; }
  double Uniform(double lo, double hi) { return lo + (hi - lo) * Uniform(); }
  double Normal() {
    if (has_spare_) {
      has_spare_ = false;
      return spare_;
    }
    const double u1 = 1.0 - Uniform();  // (0, 1]
    const double u2 = Uniform();
    const double radius = std::sqrt(-2.0 * std::log(u1));
    spare_ = radius * std::sin(2.0 * M_PI * u2);
    has_spare_ = true;
    return radius * std::cos(2.0 * M_PI * u2);
  }
  Eigen::VectorXd Vector(int n, double scale = 1.0) {
    Eigen::VectorXd v(n);
    for (int k = 0; k < n; ++k) v[k] = scale * Normal();
    return v;
  }
  Eigen::MatrixXd Matrix(int rows, int cols, double scale = 1.0) {
    Eigen::MatrixXd m(rows, cols);
    for (int c = 0; c < cols; ++c) {
      for (int r = 0; r < rows; ++r) m(r, c) = scale * Normal();
    }
    return m;
  }

 private:
  std::mt19937_64 engine_;
  bool has_spare_ = false;
  double spare_ = 0.0;
};

// ---- a linear cost r = c + Σ_k A_k x_k ----

class LinearCost final : public ceres::CostFunction {
 public:
  LinearCost(std::vector<Eigen::MatrixXd> A, Eigen::VectorXd c) : A_(std::move(A)), c_(std::move(c)) {
    set_num_residuals(static_cast<int>(c_.size()));
    for (const Eigen::MatrixXd& a : A_) {
      mutable_parameter_block_sizes()->push_back(static_cast<int>(a.cols()));
    }
  }
  bool Evaluate(double const* const* parameters, double* residuals,
                double** jacobians) const override {
    Eigen::Map<Eigen::VectorXd> r(residuals, c_.size());
    r = c_;
    for (std::size_t k = 0; k < A_.size(); ++k) {
      r += A_[k] * Eigen::Map<const Eigen::VectorXd>(parameters[k], A_[k].cols());
      if (jacobians != nullptr && jacobians[k] != nullptr) {
        Eigen::Map<Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>>(
            jacobians[k], A_[k].rows(), A_[k].cols()) = A_[k];
      }
    }
    if (poison_) r[0] = std::numeric_limits<double>::quiet_NaN();
    return true;
  }
  void Poison() { poison_ = true; }
  const std::vector<Eigen::MatrixXd>& A() const { return A_; }

 private:
  std::vector<Eigen::MatrixXd> A_;
  Eigen::VectorXd c_;
  bool poison_ = false;
};

MarginalBlock Euclidean(Eigen::VectorXd& x) {
  return MarginalBlock{x.data(), static_cast<int>(x.size()), static_cast<int>(x.size()), nullptr};
}

// Dense least squares over stacked linear factors: returns the Gauss-Newton system of the
// whole problem at x (all blocks Euclidean) in the column layout given by `offsets`.
struct DenseSystem {
  Eigen::MatrixXd H;
  Eigen::VectorXd b;
};

ceres::Solver::Options TightSolver() { return test::ReferenceCeresOptions(); }

ceres::Problem::Options NoOwnership() {
  ceres::Problem::Options o;
  o.cost_function_ownership = ceres::DO_NOT_TAKE_OWNERSHIP;
  o.loss_function_ownership = ceres::DO_NOT_TAKE_OWNERSHIP;
  o.manifold_ownership = ceres::DO_NOT_TAKE_OWNERSHIP;
  return o;
}

// ---- linear problem: exact Schur complement and batch solution ----

TEST(Marginalization, LinearProblemPriorIsExactSchurComplementAndKeepsBatchSolution) {
  Rng rng(11);
  // Blocks: x1 (3, marginalised), x2 (3), x3 (2), at arbitrary current values.
  Eigen::VectorXd x1 = rng.Vector(3), x2 = rng.Vector(3), x3 = rng.Vector(2);
  // f1: prior-like on x1; f2: x1-x2; f3: x1-x3; f4: x2-x3 (not touching x1).
  LinearCost f1({rng.Matrix(3, 3) + 3 * Eigen::MatrixXd::Identity(3, 3)}, rng.Vector(3));
  LinearCost f2({rng.Matrix(4, 3), rng.Matrix(4, 3)}, rng.Vector(4));
  LinearCost f3({rng.Matrix(2, 3), rng.Matrix(2, 2)}, rng.Vector(2));
  LinearCost f4({rng.Matrix(3, 3), rng.Matrix(3, 2)}, rng.Vector(3));

  std::vector<MarginalFactor> touching = {
      {&f1, nullptr, {Euclidean(x1)}},
      {&f2, nullptr, {Euclidean(x1), Euclidean(x2)}},
      {&f3, nullptr, {Euclidean(x1), Euclidean(x3)}},
  };
  LinearPrior prior;
  ASSERT_TRUE(Marginalize(touching, {x1.data()}, &prior));
  ASSERT_EQ(prior.blocks.size(), 2u);
  EXPECT_EQ(prior.blocks[0].data, x2.data());  // first-seen order
  EXPECT_EQ(prior.blocks[1].data, x3.data());
  EXPECT_EQ(prior.J.rows(), 5);  // H* is full rank here (7 rows of f2, f3 on 5 columns)
  EXPECT_EQ(prior.J.cols(), 5);
  EXPECT_TRUE(prior.x0[0].isApprox(x2));
  EXPECT_TRUE(prior.x0[1].isApprox(x3));

  // By hand: stacked Jacobian over [x1 | x2 | x3] and residual at the current values.
  Eigen::MatrixXd J = Eigen::MatrixXd::Zero(9, 8);
  Eigen::VectorXd r(9);
  auto residual_of = [](const LinearCost& f, std::vector<const double*> xs) {
    Eigen::VectorXd out(f.num_residuals());
    std::vector<const double*> p = xs;
    f.Evaluate(p.data(), out.data(), nullptr);
    return out;
  };
  J.block(0, 0, 3, 3) = f1.A()[0];
  J.block(3, 0, 4, 3) = f2.A()[0];
  J.block(3, 3, 4, 3) = f2.A()[1];
  J.block(7, 0, 2, 3) = f3.A()[0];
  J.block(7, 6, 2, 2) = f3.A()[1];
  r << residual_of(f1, {x1.data()}), residual_of(f2, {x1.data(), x2.data()}),
      residual_of(f3, {x1.data(), x3.data()});
  const Eigen::MatrixXd H = J.transpose() * J;
  const Eigen::VectorXd b = J.transpose() * r;
  const Eigen::MatrixXd Hmm_inv = H.topLeftCorner(3, 3).inverse();
  const Eigen::MatrixXd H_star =
      H.bottomRightCorner(5, 5) - H.bottomLeftCorner(5, 3) * Hmm_inv * H.topRightCorner(3, 5);
  const Eigen::VectorXd b_star = b.tail(5) - H.bottomLeftCorner(5, 3) * Hmm_inv * b.head(3);
  const Eigen::MatrixXd JtJ = prior.J.transpose() * prior.J;
  const Eigen::VectorXd Jtr = prior.J.transpose() * prior.r0;
  EXPECT_LT((JtJ - H_star).norm(), 1e-10 * H_star.norm()) << JtJ << "\n\n" << H_star;
  EXPECT_LT((Jtr - b_star).norm(), 1e-10 * std::max(1.0, b_star.norm()));
  // The constant of the quadratic is not needed by the optimiser; r0 is the minimum-norm
  // one consistent with b*.

  // Batch solution of f1..f4 (linear least squares) vs f4 + prior solved by Ceres.
  Eigen::MatrixXd Jall = Eigen::MatrixXd::Zero(12, 8);
  Eigen::VectorXd rall(12);
  Jall.topRows(9) = J;
  Jall.block(9, 3, 3, 3) = f4.A()[0];
  Jall.block(9, 6, 3, 2) = f4.A()[1];
  rall << r, residual_of(f4, {x2.data(), x3.data()});
  const Eigen::VectorXd dx = -(Jall.transpose() * Jall).ldlt().solve(Jall.transpose() * rall);
  const Eigen::VectorXd x2_batch = x2 + dx.segment(3, 3);
  const Eigen::VectorXd x3_batch = x3 + dx.segment(6, 2);

  LinearPriorFactor prior_factor(prior);
  Eigen::VectorXd y2 = x2 + rng.Vector(3, 0.5), y3 = x3 + rng.Vector(2, 0.5);  // other start
  ceres::Problem problem(NoOwnership());
  problem.AddResidualBlock(&f4, nullptr, y2.data(), y3.data());
  problem.AddResidualBlock(&prior_factor, nullptr, y2.data(), y3.data());
  ceres::Solver::Summary summary;
  ceres::Solve(TightSolver(), &problem, &summary);
  ASSERT_TRUE(summary.IsSolutionUsable());
  EXPECT_LT((y2 - x2_batch).norm(), 1e-8) << y2.transpose() << " vs " << x2_batch.transpose();
  EXPECT_LT((y3 - x3_batch).norm(), 1e-8) << y3.transpose() << " vs " << x3_batch.transpose();
}

// The project's own linear factors (SpeedBiasPriorFactor, BiasRandomWalkFactor) on
// speed-bias blocks: the random walk carries no velocity information, so marginalising
// sb1 out of {prior(sb1), walk(sb1, sb2)} leaves a rank-6 prior on sb2 (the 3 velocity
// directions dropped, not turned into a huge or NaN prior), equal to the exact marginal.
TEST(Marginalization, DirectionsWithoutInformationAreDropped) {
  Rng rng(12);
  ImuNoiseParams noise;
  Eigen::VectorXd sb1 = rng.Vector(9, 0.1), sb2 = rng.Vector(9, 0.1);
  Eigen::Matrix<double, 9, 1> sb_prior = rng.Vector(9, 0.1);
  Eigen::Matrix<double, 9, 9> S = Eigen::Matrix<double, 9, 9>::Zero();
  for (int k = 0; k < 9; ++k) S(k, k) = 1.0 / (0.05 + 0.05 * k);
  SpeedBiasPriorFactor prior_factor(sb_prior, S);
  // The walk's information (1/(σ_bg² dt) ≈ 3e9 for the gyro) is far above the prior's
  // (≈ 5): the Schur complement cancels it down to ≈ 5, so double precision leaves a
  // relative error ~1e-16 · 3e9 / 5 ≈ 1e-7 (conditioning, not a defect).
  const double dt = 1.0;
  BiasRandomWalkFactor walk(dt, noise);
  LinearPrior prior;
  ASSERT_TRUE(Marginalize({{&prior_factor, nullptr, {Euclidean(sb1)}},
                           {&walk, nullptr, {Euclidean(sb1), Euclidean(sb2)}}},
                          {sb1.data()}, &prior));
  EXPECT_EQ(prior.J.rows(), 6);
  EXPECT_EQ(prior.J.cols(), 9);
  ASSERT_TRUE(prior.J.allFinite());
  ASSERT_TRUE(prior.r0.allFinite());
  EXPECT_LT(prior.J.leftCols(3).norm(), 1e-9 * prior.J.norm());  // no velocity information
  // The bias part is the exact marginal: information (Σ_prior + Σ_walk)⁻¹ per component,
  // and the mean is the prior's bias.
  const Eigen::MatrixXd JtJ = prior.J.transpose() * prior.J;
  for (int k = 3; k < 9; ++k) {
    const double walk_std = (k < 6 ? noise.accel_random_walk_mps3_per_sqrthz
                                   : noise.gyro_random_walk_radps2_per_sqrthz) *
                            std::sqrt(dt);
    const double prior_std = 1.0 / S(k, k);
    const double expected = 1.0 / (prior_std * prior_std + walk_std * walk_std);
    EXPECT_NEAR(JtJ(k, k), expected, 1e-6 * expected) << k;
  }
  // Minimiser of the prior alone = prior means for the biases (any velocity).
  LinearPriorFactor factor(prior);
  Eigen::VectorXd y = sb2;
  ceres::Problem problem(NoOwnership());
  problem.AddResidualBlock(&factor, nullptr, y.data());
  ceres::Solver::Summary summary;
  ceres::Solve(TightSolver(), &problem, &summary);
  EXPECT_LT((y.tail(6) - sb_prior.tail(6)).norm(), 1e-6);
  EXPECT_LT((y.head(3) - sb2.head(3)).norm(), 1e-8);  // free directions not moved

  // A marginalised direction nothing constrains (H_mm singular): x1[3] appears in no
  // factor. The pseudo-inverse keeps the prior finite and exact on the rest.
  Eigen::VectorXd x1 = rng.Vector(4), x2 = rng.Vector(2);
  Eigen::MatrixXd A1 = Eigen::MatrixXd::Zero(3, 4);
  A1.leftCols(3) = rng.Matrix(3, 3) + 2 * Eigen::MatrixXd::Identity(3, 3);
  Eigen::MatrixXd B1 = Eigen::MatrixXd::Zero(2, 4);
  B1.leftCols(3) = rng.Matrix(2, 3);
  LinearCost g1({A1}, rng.Vector(3));
  LinearCost g2({B1, rng.Matrix(2, 2)}, rng.Vector(2));
  LinearPrior prior2;
  ASSERT_TRUE(Marginalize({{&g1, nullptr, {Euclidean(x1)}},
                           {&g2, nullptr, {Euclidean(x1), Euclidean(x2)}}},
                          {x1.data()}, &prior2));
  ASSERT_TRUE(prior2.J.allFinite());
  EXPECT_EQ(prior2.J.rows(), 2);
  // Exact: the 3 used directions of x1 are eliminated from the 5 rows.
  Eigen::MatrixXd J = Eigen::MatrixXd::Zero(5, 5);
  J.block(0, 0, 3, 3) = A1.leftCols(3);
  J.block(3, 0, 2, 3) = B1.leftCols(3);
  J.block(3, 3, 2, 2) = g2.A()[1];
  const Eigen::MatrixXd H = J.transpose() * J;
  const Eigen::MatrixXd H_star = H.bottomRightCorner(2, 2) - H.bottomLeftCorner(2, 3) *
                                                                 H.topLeftCorner(3, 3).inverse() *
                                                                 H.topRightCorner(3, 2);
  EXPECT_LT((prior2.J.transpose() * prior2.J - H_star).norm(), 1e-9 * H_star.norm());

  // Nothing left for the kept blocks at all: false (no prior), not a zero-row factor.
  LinearPrior untouched;
  Eigen::MatrixXd only_x1 = Eigen::MatrixXd::Zero(2, 4);
  only_x1(0, 0) = 1.0;
  only_x1(1, 1) = 1.0;
  LinearCost g3({only_x1, Eigen::MatrixXd::Zero(2, 2)}, rng.Vector(2));
  EXPECT_FALSE(Marginalize({{&g3, nullptr, {Euclidean(x1), Euclidean(x2)}}}, {x1.data()},
                           &untouched));
  EXPECT_EQ(untouched.J.size(), 0);
}

TEST(Marginalization, NonFiniteFactorReturnsFalseAndLeavesPriorUntouched) {
  Rng rng(13);
  Eigen::VectorXd x1 = rng.Vector(3), x2 = rng.Vector(3);
  LinearCost good({Eigen::MatrixXd::Identity(3, 3)}, rng.Vector(3));
  LinearCost bad({rng.Matrix(3, 3), rng.Matrix(3, 3)}, rng.Vector(3));
  bad.Poison();
  LinearPrior prior;
  prior.J = Eigen::MatrixXd::Constant(2, 2, 7.0);
  prior.r0 = Eigen::VectorXd::Constant(2, 3.0);
  const LinearPrior before = prior;
  EXPECT_FALSE(Marginalize({{&good, nullptr, {Euclidean(x1)}},
                            {&bad, nullptr, {Euclidean(x1), Euclidean(x2)}}},
                           {x1.data()}, &prior));
  EXPECT_EQ(prior.J, before.J);
  EXPECT_EQ(prior.r0, before.r0);
  EXPECT_TRUE(prior.blocks.empty());

  // A non-finite parameter value (e.g. a diverged state) likewise.
  LinearCost fine({rng.Matrix(3, 3), rng.Matrix(3, 3)}, rng.Vector(3));
  x2[1] = std::numeric_limits<double>::infinity();
  EXPECT_FALSE(Marginalize({{&good, nullptr, {Euclidean(x1)}},
                            {&fine, nullptr, {Euclidean(x1), Euclidean(x2)}}},
                           {x1.data()}, &prior));
  EXPECT_EQ(prior.J, before.J);
  EXPECT_EQ(prior.r0, before.r0);
}

// ---- nonlinear poses: marginalised at the optimum, the reduced problem keeps it ----

using Pose = std::array<double, kPoseSize>;

Pose MakePose(const Eigen::Vector3d& p, const Eigen::Quaterniond& q) {
  return {p.x(), p.y(), p.z(), q.x(), q.y(), q.z(), q.w()};
}
Eigen::Isometry3d IsoFrom(const Eigen::Vector3d& p, const Eigen::Vector3d& rotvec) {
  Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
  T.linear() = core::ExpSO3(rotvec);
  T.translation() = p;
  return T;
}

TEST(Marginalization, PoseChainMarginalisedAtOptimumKeepsOptimumAndMarginalCovariance) {
  Rng rng(14);
  PoseManifold manifold;
  // Truth: three poses ~0.8 rad and ~1 m apart; noisy between measurements so that the
  // optimum has non-zero residuals (the prior's r0 then matters).
  const Eigen::Isometry3d T1 = IsoFrom(Eigen::Vector3d(0.1, -0.2, 0.3), Eigen::Vector3d(0.2, -0.1, 0.5));
  const Eigen::Isometry3d T2 = T1 * IsoFrom(Eigen::Vector3d(1.0, 0.2, -0.1), Eigen::Vector3d(0.1, 0.3, 0.7));
  const Eigen::Isometry3d T3 = T2 * IsoFrom(Eigen::Vector3d(0.8, -0.5, 0.2), Eigen::Vector3d(-0.4, 0.2, 0.6));
  auto noisy = [&](const Eigen::Isometry3d& T) {
    return T * IsoFrom(rng.Vector(3, 0.05), rng.Vector(3, 0.05));
  };
  Eigen::Matrix<double, 6, 6> S = Eigen::Matrix<double, 6, 6>::Identity() * 20.0;
  S(0, 4) = 3.0;  // a little correlation
  const Eigen::Matrix<double, 6, 6> S_prior = Eigen::Matrix<double, 6, 6>::Identity() * 100.0;
  PosePriorFactor prior1(Eigen::Vector3d(T1.translation()), Eigen::Quaterniond(T1.linear()), S_prior);
  PoseBetweenFactor b12(noisy(T1.inverse() * T2), S);
  PoseBetweenFactor b23(noisy(T2.inverse() * T3), S);
  PoseBetweenFactor b13(noisy(T1.inverse() * T3), S);

  Pose x1 = MakePose(T1.translation(), Eigen::Quaterniond(T1.linear()));
  Pose x2 = MakePose(T2.translation(), Eigen::Quaterniond(T2.linear()));
  Pose x3 = MakePose(T3.translation(), Eigen::Quaterniond(T3.linear()));
  {
    ceres::Problem full(NoOwnership());
    full.AddParameterBlock(x1.data(), kPoseSize, &manifold);
    full.AddParameterBlock(x2.data(), kPoseSize, &manifold);
    full.AddParameterBlock(x3.data(), kPoseSize, &manifold);
    full.AddResidualBlock(&prior1, nullptr, x1.data());
    full.AddResidualBlock(&b12, nullptr, x1.data(), x2.data());
    full.AddResidualBlock(&b23, nullptr, x2.data(), x3.data());
    full.AddResidualBlock(&b13, nullptr, x1.data(), x3.data());
    ceres::Solver::Summary summary;
    ceres::Solve(TightSolver(), &full, &summary);
    ASSERT_TRUE(summary.IsSolutionUsable());
    ASSERT_GT(summary.final_cost, 1.0);  // not a zero-residual problem
  }
  const Pose x2_opt = x2, x3_opt = x3;

  // Full marginal information of (x2, x3) at the optimum: Schur complement of the full
  // tangent-space Gauss-Newton matrix, by hand via EvaluateTangent.
  struct Term {
    const ceres::CostFunction* cost;
    std::vector<int> which;  // 0, 1, 2
  };
  const std::vector<Term> terms = {{&prior1, {0}}, {&b12, {0, 1}}, {&b23, {1, 2}}, {&b13, {0, 2}}};
  const std::array<const double*, 3> xs = {x1.data(), x2.data(), x3.data()};
  Eigen::MatrixXd H = Eigen::MatrixXd::Zero(18, 18);
  for (const Term& t : terms) {
    std::vector<const double*> blocks;
    std::vector<const ceres::Manifold*> manifolds;
    for (int w : t.which) {
      blocks.push_back(xs[w]);
      manifolds.push_back(&manifold);
    }
    Eigen::VectorXd r;
    std::vector<Eigen::MatrixXd> Js;
    ASSERT_TRUE(EvaluateTangent(*t.cost, blocks, manifolds, &r, &Js));
    for (std::size_t a = 0; a < t.which.size(); ++a) {
      for (std::size_t c = 0; c < t.which.size(); ++c) {
        H.block(6 * t.which[a], 6 * t.which[c], 6, 6) += Js[a].transpose() * Js[c];
      }
    }
  }
  const Eigen::MatrixXd marginal_information =
      H.bottomRightCorner(12, 12) -
      H.bottomLeftCorner(12, 6) * H.topLeftCorner(6, 6).inverse() * H.topRightCorner(6, 12);

  const MarginalBlock m1{x1.data(), kPoseSize, kPoseTangentSize, &manifold};
  const MarginalBlock m2{x2.data(), kPoseSize, kPoseTangentSize, &manifold};
  const MarginalBlock m3{x3.data(), kPoseSize, kPoseTangentSize, &manifold};
  LinearPrior prior;
  ASSERT_TRUE(Marginalize({{&prior1, nullptr, {m1}}, {&b12, nullptr, {m1, m2}},
                           {&b13, nullptr, {m1, m3}}},
                          {x1.data()}, &prior));
  ASSERT_EQ(prior.blocks.size(), 2u);
  ASSERT_EQ(prior.blocks[0].data, x2.data());
  EXPECT_EQ(prior.J.rows(), 12);
  LinearPriorFactor prior_factor(prior);

  // Reduced problem: b23 + prior, started away from the optimum (0.2 rad, 0.2 m).
  Eigen::Matrix<double, 6, 1> d2, d3;
  d2 << 0.2, -0.1, 0.1, 0.1, -0.15, 0.05;
  d3 << -0.1, 0.2, 0.1, -0.1, 0.05, 0.15;
  Pose y2, y3;
  manifold.Plus(x2_opt.data(), d2.data(), y2.data());
  manifold.Plus(x3_opt.data(), d3.data(), y3.data());
  ceres::Problem reduced(NoOwnership());
  reduced.AddParameterBlock(y2.data(), kPoseSize, &manifold);
  reduced.AddParameterBlock(y3.data(), kPoseSize, &manifold);
  reduced.AddResidualBlock(&b23, nullptr, y2.data(), y3.data());
  reduced.AddResidualBlock(&prior_factor, nullptr, y2.data(), y3.data());
  ceres::Solver::Summary summary;
  ceres::Solve(TightSolver(), &reduced, &summary);
  ASSERT_TRUE(summary.IsSolutionUsable());
  Eigen::Matrix<double, 6, 1> e2, e3;
  manifold.Minus(y2.data(), x2_opt.data(), e2.data());
  manifold.Minus(y3.data(), x3_opt.data(), e3.data());
  EXPECT_LT(e2.norm(), 1e-7) << e2.transpose();
  EXPECT_LT(e3.norm(), 1e-7) << e3.transpose();

  // Information of the reduced problem at the optimum = the full marginal information.
  Eigen::MatrixXd H_reduced = Eigen::MatrixXd::Zero(12, 12);
  for (const ceres::CostFunction* cost :
       std::vector<const ceres::CostFunction*>{&b23, &prior_factor}) {
    Eigen::VectorXd r;
    std::vector<Eigen::MatrixXd> Js;
    ASSERT_TRUE(EvaluateTangent(*cost, {y2.data(), y3.data()}, {&manifold, &manifold}, &r, &Js));
    Eigen::MatrixXd Jrow(r.size(), 12);
    Jrow << Js[0], Js[1];
    H_reduced += Jrow.transpose() * Jrow;
  }
  EXPECT_LT((H_reduced - marginal_information).norm(), 1e-6 * marginal_information.norm());
}

// ---- LinearPriorFactor Jacobians ----

// Numeric tangent Jacobian of `cost` w.r.t. block k at `blocks`, central differences
// through the manifold's Plus (nullptr: Euclidean).
Eigen::MatrixXd NumericTangentJacobian(const ceres::CostFunction& cost,
                                       std::vector<std::vector<double>> blocks,
                                       const std::vector<const ceres::Manifold*>& manifolds,
                                       int k, double step) {
  const int m = cost.num_residuals();
  const int n = manifolds[k] ? manifolds[k]->TangentSize() : static_cast<int>(blocks[k].size());
  Eigen::MatrixXd J(m, n);
  const std::vector<double> x = blocks[k];
  for (int d = 0; d < n; ++d) {
    Eigen::VectorXd r_plus(m), r_minus(m);
    for (int sign : {+1, -1}) {
      Eigen::VectorXd delta = Eigen::VectorXd::Zero(n);
      delta[d] = sign * step;
      if (manifolds[k]) {
        manifolds[k]->Plus(x.data(), delta.data(), blocks[k].data());
      } else {
        for (int i = 0; i < n; ++i) blocks[k][i] = x[i] + delta[i];
      }
      std::vector<const double*> p;
      for (auto& b : blocks) p.push_back(b.data());
      EXPECT_TRUE(cost.Evaluate(p.data(), sign > 0 ? r_plus.data() : r_minus.data(), nullptr));
    }
    J.col(d) = (r_plus - r_minus) / (2 * step);
  }
  return J;
}

TEST(Marginalization, LinearPriorFactorJacobiansMatchNumericAwayFromLinearisation) {
  Rng rng(15);
  PoseManifold pose_manifold;
  ceres::QuaternionManifold quaternion_manifold;  // generic path (numeric local coordinates)
  // Blocks: Euclidean (4), pose (7/6), Ceres quaternion (4/3, w first).
  Eigen::VectorXd e0 = rng.Vector(4);
  const Eigen::Quaterniond q0 = core::ExpQuat(Eigen::Vector3d(0.3, -0.5, 0.8));
  Pose pose0 = MakePose(Eigen::Vector3d(1.0, -2.0, 0.5), q0);
  const Eigen::Quaterniond g0 = core::ExpQuat(Eigen::Vector3d(-0.6, 0.2, 0.4));
  std::vector<double> quat0 = {g0.w(), g0.x(), g0.y(), g0.z()};

  LinearPrior prior;
  prior.blocks = {MarginalBlock{nullptr, 4, 4, nullptr},
                  MarginalBlock{nullptr, kPoseSize, kPoseTangentSize, &pose_manifold},
                  MarginalBlock{nullptr, 4, 3, &quaternion_manifold}};
  prior.x0 = {e0, Eigen::Map<Eigen::VectorXd>(pose0.data(), kPoseSize),
              Eigen::Map<Eigen::VectorXd>(quat0.data(), 4)};
  prior.J = rng.Matrix(11, 13);
  prior.r0 = rng.Vector(11);
  const LinearPriorFactor factor(prior);
  ASSERT_EQ(factor.num_residuals(), 11);

  // Evaluation point: ~1 rad (pose) and ~1.1 rad (quaternion) from the linearisation.
  std::vector<std::vector<double>> x(3);
  const Eigen::VectorXd e = e0 + rng.Vector(4, 0.7);
  x[0].assign(e.data(), e.data() + 4);
  Eigen::Matrix<double, 6, 1> d_pose;
  d_pose << 0.4, -0.3, 0.2, 0.6, -0.5, 0.6;  // |δθ| ≈ 0.98 rad
  x[1].resize(kPoseSize);
  pose_manifold.Plus(pose0.data(), d_pose.data(), x[1].data());
  const Eigen::Quaterniond g = core::ExpQuat(Eigen::Vector3d(0.7, 0.6, -0.6)) * g0;
  x[2] = {g.w(), g.x(), g.y(), g.z()};
  const std::vector<const ceres::Manifold*> manifolds = {nullptr, &pose_manifold,
                                                         &quaternion_manifold};

  // Residual: r0 + J (x ⊟ x0).
  {
    std::vector<const double*> p = {x[0].data(), x[1].data(), x[2].data()};
    Eigen::VectorXd r(11);
    ASSERT_TRUE(factor.Evaluate(p.data(), r.data(), nullptr));
    Eigen::VectorXd delta(13);
    delta.head(4) = e - e0;
    pose_manifold.Minus(x[1].data(), pose0.data(), delta.data() + 4);
    quaternion_manifold.Minus(x[2].data(), quat0.data(), delta.data() + 10);
    EXPECT_GT(delta.segment(7, 3).norm(), 0.9);
    EXPECT_LT((r - (prior.r0 + prior.J * delta)).norm(), 1e-12 * r.norm());
  }

  Eigen::VectorXd residual;
  std::vector<Eigen::MatrixXd> analytic;
  ASSERT_TRUE(EvaluateTangent(factor, {x[0].data(), x[1].data(), x[2].data()}, manifolds,
                              &residual, &analytic));
  for (int k = 0; k < 3; ++k) {
    const Eigen::MatrixXd numeric = NumericTangentJacobian(factor, x, manifolds, k, 1e-6);
    EXPECT_LT((analytic[k] - numeric).norm(), 1e-6 * numeric.norm())
        << "block " << k << "\nanalytic\n" << analytic[k] << "\nnumeric\n" << numeric;
  }
  // At x0 the tangent Jacobian is exactly the prior's J.
  std::vector<std::vector<double>> at0 = {std::vector<double>(e0.data(), e0.data() + 4),
                                          std::vector<double>(pose0.begin(), pose0.end()), quat0};
  ASSERT_TRUE(EvaluateTangent(factor, {at0[0].data(), at0[1].data(), at0[2].data()}, manifolds,
                              &residual, &analytic));
  EXPECT_LT((residual - prior.r0).norm(), 1e-12);
  EXPECT_LT((analytic[1] - prior.J.middleCols(4, 6)).norm(), 1e-9);
  EXPECT_LT((analytic[2] - prior.J.middleCols(10, 3)).norm(), 1e-6);
}

}  // namespace
}  // namespace tofu::estimator
