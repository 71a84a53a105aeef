// The local window's own Levenberg-Marquardt solver (estimator/window_solver.h) against
// ceres::Solve on the same factors:
//  - a window of the local graph's real factors (IMU preintegration, bias random walk, pose
//    between factors of one sensor, position between factors of another spanning two
//    keyframes with a Huber loss and an outlier, a marginalisation prior over two states)
//    started 5 cm / 3° / 0.2 m/s off: both reach the same optimum and cost;
//  - the newest state's covariance from the banded factor equals the last block of the
//    dense inverse of the information matrix Ceres evaluates;
//  - a constant pose stays put and the rest matches Ceres with that block held constant;
//  - one step only: the iteration cap is reported and the cost decreased;
//  - a non-finite state: failure, states untouched;
//  - with offset blocks (two position chains, one in the marginalisation prior): the same
//    optimum as Ceres, and the newest state's covariance with the offsets marginalised;
//  - LmOptions::IsValid refuses each broken limit by name, and Solve throws for it.

#include "estimator/window_solver.h"

#include <gtest/gtest.h>

#include <array>
#include <cmath>
#include <functional>
#include <limits>
#include <memory>
#include <stdexcept>
#include <string>
#include <utility>
#include <vector>

#include <Eigen/Dense>
#include <ceres/ceres.h>

#include "core/lie.h"
#include "core/random.h"
#include "estimator/imu_preintegration.h"
#include "estimator/local_factors.h"
#include "estimator/marginalization.h"
#include "tests/ceres_test_support.h"

namespace tofu::estimator {
namespace {

constexpr int kStates = 14;  // one more than the window: state 0 is marginalised
constexpr double kKeyframePeriodS = 1.0 / 30.0;
constexpr int kImuSamplesPerKeyframe = 8;

struct State {
  double pose[kPoseSize];
  double speed_bias[kSpeedBiasSize];
};

struct OwnedFactor {
  std::unique_ptr<ceres::CostFunction> cost;
  std::unique_ptr<ceres::LossFunction> loss;
  std::vector<WindowBlockRef> blocks;
};

// A window of the local graph's factors on a smooth 3-D motion, built noise-free, then
// measurement noise and one outlier added, then every state pushed away from the truth.
class Window {
 public:
  /// offset_chains: 0, or 2 position chains with an offset each (PositionWithOffsetFactor),
  /// keyframes 0-6 and 7-13.
  explicit Window(bool with_outlier = true, int offset_chains = 0) {
    core::RandomStream rng(7, "window_solver_test");
    const Eigen::Vector3d gravity(0, 0, -9.81);
    const ImuNoiseParams noise;
    ImuBias bias;
    bias.accel_mps2 = Eigen::Vector3d(0.05, -0.03, 0.02);
    bias.gyro_radps = Eigen::Vector3d(0.002, 0.001, -0.003);
    NavState truth;
    truth.q_LI = core::ExpQuat(Eigen::Vector3d(0.1, -0.2, 0.7));
    truth.v_L_mps = Eigen::Vector3d(0.8, -0.3, 0.2);
    std::vector<NavState> states_true{truth};
    std::vector<ImuPreintegration> imu;
    const double dt = kKeyframePeriodS / kImuSamplesPerKeyframe;
    for (int i = 1; i < kStates; ++i) {
      ImuPreintegration pre(bias, noise);
      for (int k = 0; k < kImuSamplesPerKeyframe; ++k) {
        const double t = (i * kImuSamplesPerKeyframe + k) * dt;
        const Eigen::Vector3d accel_true(1.5 * std::sin(3 * t), 0.8 * std::cos(2 * t),
                                         9.81 + 0.5 * std::sin(t));
        const Eigen::Vector3d gyro_true(0.4 * std::cos(2 * t), -0.3 * std::sin(t), 0.6);
        pre.Integrate(accel_true + bias.accel_mps2, gyro_true + bias.gyro_radps, dt);
      }
      states_true.push_back(pre.Predict(states_true.back(), bias, gravity));
      imu.push_back(pre);
    }
    for (int i = 0; i < kStates; ++i) {
      State s;
      Set(states_true[i], bias, &s);
      truth_.push_back(s);
    }
    states_ = truth_;

    // Prior on state 0 (as LocalSmoother::Initialize).
    Eigen::Matrix<double, 6, 6> pose_sqrt_info = Eigen::Matrix<double, 6, 6>::Identity() * 1e3;
    Add(std::make_unique<PosePriorFactor>(truth_[0].pose, pose_sqrt_info), nullptr, {{0, true}});
    Add(std::make_unique<SpeedBiasPriorFactor>(truth_[0].speed_bias,
                                               Eigen::Matrix<double, 9, 9>::Identity() * 10.0),
        nullptr, {{0, false}});
    for (int i = 0; i + 1 < kStates; ++i) {
      Add(std::make_unique<ImuFactor>(imu[i], gravity), nullptr,
          {{i, true}, {i, false}, {i + 1, true}, {i + 1, false}});
      Add(std::make_unique<BiasRandomWalkFactor>(kKeyframePeriodS, noise), nullptr,
          {{i, false}, {i + 1, false}});
      // Sensor A: pose between consecutive keyframes, 1 cm / 0.3° noise.
      const Eigen::Isometry3d T_IJ = Pose(states_true[i]).inverse() * Pose(states_true[i + 1]);
      Eigen::Isometry3d measured = T_IJ;
      measured.translation() += 0.01 * Eigen::Vector3d(rng.Normal(), rng.Normal(), rng.Normal());
      measured.linear() =
          measured.linear() *
          core::ExpSO3(0.005 * Eigen::Vector3d(rng.Normal(), rng.Normal(), rng.Normal()));
      Eigen::Matrix<double, 6, 6> sqrt_info = Eigen::Matrix<double, 6, 6>::Identity();
      sqrt_info.topLeftCorner<3, 3>() *= 100.0;
      sqrt_info.bottomRightCorner<3, 3>() *= 200.0;
      Add(std::make_unique<PoseBetweenFactor>(measured, sqrt_info), nullptr,
          {{i, true}, {i + 1, true}});
    }
    // Sensor B: positions of a mount point between every other keyframe (bandwidth 2),
    // Huber at 2σ, 1 cm noise; one outlier of 30 cm.
    const Eigen::Vector3d p_Is(0.1, -0.05, 0.2);
    const Eigen::Matrix3d R_LA = core::ExpSO3(Eigen::Vector3d(0, 0, 0.5));
    for (int i = 0; i + 2 < kStates; i += 2) {
      auto mount = [&](int k) -> Eigen::Vector3d {
        return states_true[k].p_LI + states_true[k].q_LI * p_Is;
      };
      Eigen::Vector3d delta_A = R_LA.transpose() * (mount(i + 2) - mount(i));
      delta_A += 0.01 * Eigen::Vector3d(rng.Normal(), rng.Normal(), rng.Normal());
      if (with_outlier && i == 6) delta_A += Eigen::Vector3d(0.3, 0, 0);
      Add(std::make_unique<PositionBetweenFactor>(p_Is, R_LA, delta_A,
                                                  Eigen::Matrix3d::Identity() * 100.0),
          std::make_unique<ceres::HuberLoss>(2.0), {{i, true}, {i + 2, true}});
    }
    // Sensor C: positions with an offset per chain, 5 mm noise.
    offsets_.resize(offset_chains);
    for (int c = 0; c < offset_chains; ++c) {
      const Eigen::Vector3d o_true(0.3 - 0.4 * c, -0.2 + 0.6 * c, 0.1);
      Eigen::Map<Eigen::Vector3d>{offsets_[c].data()} =
          o_true + 0.05 * Eigen::Vector3d(rng.Normal(), rng.Normal(), rng.Normal());
      for (int i = 7 * c; i < std::min(7 * (c + 1), kStates); ++i) {
        const Eigen::Vector3d mount = states_true[i].p_LI + states_true[i].q_LI * p_Is;
        const Eigen::Vector3d measured_L =
            mount - o_true + 0.005 * Eigen::Vector3d(rng.Normal(), rng.Normal(), rng.Normal());
        Add(std::make_unique<PositionWithOffsetFactor>(p_Is, measured_L,
                                                       Eigen::Matrix3d::Identity() * 200.0),
            nullptr, {{i, true}, {0, false, c}});
      }
    }
    // Push every state away from the truth.
    for (State& s : states_) {
      for (int k = 0; k < 3; ++k) s.pose[k] += 0.05 * rng.Normal();
      Eigen::Map<Eigen::Quaterniond> q(s.pose + 3);
      q = (q * core::ExpQuat(0.05 * Eigen::Vector3d(rng.Normal(), rng.Normal(), rng.Normal())))
              .normalized();
      for (int k = 0; k < 3; ++k) s.speed_bias[k] += 0.2 * rng.Normal();
    }
  }

  // Marginalises state 0 into a prior (as LocalSmoother does when it leaves the window):
  // the window is then states 1..n−1 with that prior.
  void MarginalizeFirst() {
    std::vector<MarginalFactor> touching;
    std::vector<OwnedFactor> kept;
    PoseManifold* manifold = &pose_manifold_;
    for (OwnedFactor& f : factors_) {
      bool touches = false;
      for (const WindowBlockRef& b : f.blocks) touches |= b.offset < 0 && b.state == 0;
      if (!touches) {
        kept.push_back(std::move(f));
        continue;
      }
      MarginalFactor m{f.cost.get(), f.loss.get(), {}};
      for (const WindowBlockRef& b : f.blocks) {
        if (b.offset >= 0) {
          m.blocks.push_back(MarginalBlock{offsets_[b.offset].data(), 3, 3, nullptr});
          continue;
        }
        State& s = states_[b.state];
        m.blocks.push_back(b.is_pose ? MarginalBlock{s.pose, kPoseSize, 6, manifold}
                                     : MarginalBlock{s.speed_bias, kSpeedBiasSize, 9, nullptr});
      }
      touching.push_back(m);
      marginalised_.push_back(std::move(f));
    }
    LinearPrior prior;
    ASSERT_TRUE(Marginalize(touching, {states_[0].pose, states_[0].speed_bias}, &prior));
    std::vector<WindowBlockRef> blocks;
    for (const MarginalBlock& b : prior.blocks) {
      for (int i = 0; i < kStates; ++i) {
        if (b.data == states_[i].pose) blocks.push_back({i, true});
        if (b.data == states_[i].speed_bias) blocks.push_back({i, false});
      }
      for (std::size_t c = 0; c < offsets_.size(); ++c) {
        if (b.data == offsets_[c].data()) blocks.push_back({0, false, static_cast<int>(c)});
      }
    }
    factors_ = std::move(kept);
    Add(std::make_unique<LinearPriorFactor>(std::move(prior)), nullptr, blocks);
    first_ = 1;
    ASSERT_GT(factors_.back().blocks.size(), 2u);  // the prior spans more than one state
  }

  std::vector<WindowState> WindowStates() {
    std::vector<WindowState> out;
    for (int i = first_; i < kStates; ++i) out.push_back({states_[i].pose, states_[i].speed_bias});
    return out;
  }
  std::vector<WindowFactor> WindowFactors() const {
    std::vector<WindowFactor> out;
    for (const OwnedFactor& f : factors_) {
      WindowFactor w{f.cost.get(), f.loss.get(), f.blocks};
      for (WindowBlockRef& b : w.blocks) {
        if (b.offset < 0) b.state -= first_;
      }
      out.push_back(w);
    }
    return out;
  }

  // The same problem for ceres::Solve.
  std::unique_ptr<ceres::Problem> CeresProblem() {
    ceres::Problem::Options options;
    options.cost_function_ownership = ceres::DO_NOT_TAKE_OWNERSHIP;
    options.loss_function_ownership = ceres::DO_NOT_TAKE_OWNERSHIP;
    options.manifold_ownership = ceres::DO_NOT_TAKE_OWNERSHIP;
    auto problem = std::make_unique<ceres::Problem>(options);
    for (int i = first_; i < kStates; ++i) {
      problem->AddParameterBlock(states_[i].pose, kPoseSize, &pose_manifold_);
      problem->AddParameterBlock(states_[i].speed_bias, kSpeedBiasSize);
    }
    for (auto& o : offsets_) problem->AddParameterBlock(o.data(), 3);
    for (const OwnedFactor& f : factors_) {
      std::vector<double*> blocks;
      for (const WindowBlockRef& b : f.blocks) {
        blocks.push_back(b.offset >= 0 ? offsets_[b.offset].data()
                         : b.is_pose   ? states_[b.state].pose
                                       : states_[b.state].speed_bias);
      }
      problem->AddResidualBlock(f.cost.get(), f.loss.get(), blocks);
    }
    return problem;
  }

  std::vector<State>& states() { return states_; }
  int first() const { return first_; }
  std::vector<double*> Offsets() {
    std::vector<double*> out;
    for (auto& o : offsets_) out.push_back(o.data());
    return out;
  }
  const std::vector<std::array<double, 3>>& offsets() const { return offsets_; }

 private:
  static Eigen::Isometry3d Pose(const NavState& s) {
    Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
    T.linear() = s.q_LI.toRotationMatrix();
    T.translation() = s.p_LI;
    return T;
  }
  static void Set(const NavState& n, const ImuBias& b, State* s) {
    const Eigen::Quaterniond q = n.q_LI.normalized();
    const double pose[kPoseSize] = {n.p_LI.x(), n.p_LI.y(), n.p_LI.z(), q.x(), q.y(), q.z(), q.w()};
    std::copy(pose, pose + kPoseSize, s->pose);
    for (int k = 0; k < 3; ++k) {
      s->speed_bias[k] = n.v_L_mps[k];
      s->speed_bias[3 + k] = b.accel_mps2[k];
      s->speed_bias[6 + k] = b.gyro_radps[k];
    }
  }
  void Add(std::unique_ptr<ceres::CostFunction> cost, std::unique_ptr<ceres::LossFunction> loss,
           std::vector<WindowBlockRef> blocks) {
    factors_.push_back({std::move(cost), std::move(loss), std::move(blocks)});
  }

  PoseManifold pose_manifold_;
  std::vector<State> truth_;
  std::vector<State> states_;
  std::vector<OwnedFactor> factors_;
  std::vector<OwnedFactor> marginalised_;  // kept alive: the prior was built from them
  std::vector<std::array<double, 3>> offsets_;
  int first_ = 0;
};

ceres::Solver::Options TightCeres() {
  return test::ReferenceCeresOptions(ceres::SPARSE_NORMAL_CHOLESKY);
}

WindowSolverOptions TightWindow() {
  WindowSolverOptions options;
  options.max_iterations = 100;
  options.max_time_s = 10.0;
  options.function_tolerance = 1e-14;
  options.gradient_tolerance = 1e-14;
  options.parameter_tolerance = 1e-14;
  return options;
}

// Both minima agree in cost to ~1e-14 relative; along the window's weakest directions that
// still leaves ~1e-7 m between them (states started 5 cm and 3° away).
void ExpectSameStates(const std::vector<State>& a, const std::vector<State>& b, int first) {
  for (std::size_t i = first; i < a.size(); ++i) {
    SCOPED_TRACE(::testing::Message() << "state " << i);
    const Eigen::Map<const Eigen::Vector3d> pa(a[i].pose), pb(b[i].pose);
    EXPECT_LT((pa - pb).norm(), 1e-6);
    const Eigen::Map<const Eigen::Quaterniond> qa(a[i].pose + 3), qb(b[i].pose + 3);
    EXPECT_LT(qa.angularDistance(qb), 1e-6);
    const Eigen::Map<const Eigen::Matrix<double, 9, 1>> sa(a[i].speed_bias), sb(b[i].speed_bias);
    EXPECT_LT((sa - sb).cwiseAbs().maxCoeff(), 1e-6);
  }
}

TEST(WindowSolver, ReachesCeresOptimumOnLocalGraphFactorsWithPriorAndHuber) {
  Window ours;
  ours.MarginalizeFirst();
  Window theirs;
  theirs.MarginalizeFirst();

  WindowSolver solver;
  const WindowSolveSummary summary =
      solver.Solve(ours.WindowStates(), ours.WindowFactors(), TightWindow());
  EXPECT_EQ(summary.termination, WindowTermination::kConverged);
  EXPECT_GT(summary.iterations, 1);

  auto problem = theirs.CeresProblem();
  ceres::Solver::Summary ceres_summary;
  ceres::Solve(TightCeres(), problem.get(), &ceres_summary);
  ASSERT_EQ(ceres_summary.termination_type, ceres::CONVERGENCE);

  EXPECT_LT(summary.final_cost, 1e-3 * summary.initial_cost);
  EXPECT_NEAR(summary.initial_cost, ceres_summary.initial_cost, 1e-9 * ceres_summary.initial_cost);
  EXPECT_NEAR(summary.final_cost, ceres_summary.final_cost, 1e-9 * ceres_summary.final_cost);
  ExpectSameStates(ours.states(), theirs.states(), ours.first());
}

TEST(WindowSolver, NewestCovarianceEqualsDenseInverseOfCeresInformation) {
  Window window;
  window.MarginalizeFirst();
  WindowSolver solver;
  solver.Solve(window.WindowStates(), window.WindowFactors(), TightWindow());
  const auto covariance = solver.LastStateCovariance(window.WindowStates(), window.WindowFactors());
  ASSERT_TRUE(covariance.has_value());

  auto problem = window.CeresProblem();
  ceres::CRSMatrix crs;
  ASSERT_TRUE(problem->Evaluate(ceres::Problem::EvaluateOptions(), nullptr, nullptr, nullptr, &crs));
  Eigen::MatrixXd J = Eigen::MatrixXd::Zero(crs.num_rows, crs.num_cols);
  for (int row = 0; row < crs.num_rows; ++row) {
    for (int k = crs.rows[row]; k < crs.rows[row + 1]; ++k) J(row, crs.cols[k]) = crs.values[k];
  }
  const Eigen::MatrixXd H = J.transpose() * J;
  ASSERT_EQ(H.rows(), 15 * (kStates - 1));
  const Eigen::MatrixXd expected = H.inverse().bottomRightCorner(15, 15);
  // H spans eight orders of magnitude (prior, bias random walks): its dense inverse is
  // accurate to ~1e-8 relative, not to machine precision.
  EXPECT_LT((*covariance - expected).norm(), 1e-6 * expected.norm());
  // Not trivially right: the newest state's position is uncertain at the centimetre level.
  EXPECT_GT(std::sqrt(expected(0, 0)), 1e-3);
}

// Offsets join keyframes far apart (a chain's every position): the bordered factorisation
// must reach Ceres's optimum, and the newest state's covariance must be that of the dense
// inverse with the offsets in it. The first chain's offset is in the marginalisation prior.
TEST(WindowSolver, WithOffsetsReachesCeresOptimumAndDenseCovariance) {
  Window ours(true, 2);
  ours.MarginalizeFirst();
  Window theirs(true, 2);
  theirs.MarginalizeFirst();

  WindowSolver solver;
  const WindowSolveSummary summary =
      solver.Solve(ours.WindowStates(), ours.WindowFactors(), TightWindow(), ours.Offsets());
  EXPECT_EQ(summary.termination, WindowTermination::kConverged);
  auto problem = theirs.CeresProblem();
  ceres::Solver::Summary ceres_summary;
  ceres::Solve(TightCeres(), problem.get(), &ceres_summary);
  ASSERT_EQ(ceres_summary.termination_type, ceres::CONVERGENCE);
  EXPECT_NEAR(summary.final_cost, ceres_summary.final_cost, 1e-9 * ceres_summary.final_cost);
  ExpectSameStates(ours.states(), theirs.states(), ours.first());
  for (int c = 0; c < 2; ++c) {
    for (int k = 0; k < 3; ++k) EXPECT_NEAR(ours.offsets()[c][k], theirs.offsets()[c][k], 1e-6);
  }

  const auto covariance =
      solver.LastStateCovariance(ours.WindowStates(), ours.WindowFactors(), ours.Offsets());
  ASSERT_TRUE(covariance.has_value());
  ceres::CRSMatrix crs;
  ASSERT_TRUE(problem->Evaluate(ceres::Problem::EvaluateOptions(), nullptr, nullptr, nullptr, &crs));
  Eigen::MatrixXd J = Eigen::MatrixXd::Zero(crs.num_rows, crs.num_cols);
  for (int row = 0; row < crs.num_rows; ++row) {
    for (int k = crs.rows[row]; k < crs.rows[row + 1]; ++k) J(row, crs.cols[k]) = crs.values[k];
  }
  const int states = kStates - 1;
  ASSERT_EQ(J.cols(), 15 * states + 6);
  const Eigen::MatrixXd H = J.transpose() * J;
  const Eigen::MatrixXd expected = H.inverse().block(15 * (states - 1), 15 * (states - 1), 15, 15);
  EXPECT_LT((*covariance - expected).norm(), 1e-6 * expected.norm());
  // The offsets matter: without them (the band's inverse alone) the covariance differs.
  const Eigen::MatrixXd H_band = H.topLeftCorner(15 * states, 15 * states);
  const Eigen::MatrixXd band_only = H_band.inverse().bottomRightCorner(15, 15);
  EXPECT_GT((band_only - expected).norm(), 1e-3 * expected.norm());
}

TEST(WindowSolver, ConstantPoseStaysAndTheRestMatchesCeres) {
  Window ours(false);
  Window theirs(false);
  std::vector<WindowState> states = ours.WindowStates();
  states[0].pose_constant = true;
  const State before = ours.states()[0];
  WindowSolver solver;
  const WindowSolveSummary summary = solver.Solve(states, ours.WindowFactors(), TightWindow());
  EXPECT_EQ(summary.termination, WindowTermination::kConverged);
  for (int k = 0; k < kPoseSize; ++k) EXPECT_EQ(ours.states()[0].pose[k], before.pose[k]);

  auto problem = theirs.CeresProblem();
  problem->SetParameterBlockConstant(theirs.states()[0].pose);
  ceres::Solver::Summary ceres_summary;
  ceres::Solve(TightCeres(), problem.get(), &ceres_summary);
  EXPECT_NEAR(summary.final_cost, ceres_summary.final_cost, 1e-9 * ceres_summary.final_cost);
  ExpectSameStates(ours.states(), theirs.states(), 0);
}

TEST(WindowSolver, IterationCapIsReportedAndTheStepStillHelps) {
  Window window;
  WindowSolverOptions options = TightWindow();
  options.max_iterations = 1;
  WindowSolver solver;
  const WindowSolveSummary summary =
      solver.Solve(window.WindowStates(), window.WindowFactors(), options);
  EXPECT_EQ(summary.termination, WindowTermination::kIterationCap);
  EXPECT_EQ(summary.iterations, 1);
  EXPECT_LT(summary.final_cost, 0.5 * summary.initial_cost);
}

TEST(WindowSolver, NonFiniteStateFailsAndLeavesStatesUntouched) {
  Window window;
  window.states()[3].speed_bias[1] = std::nan("");
  const std::vector<State> before = window.states();
  WindowSolver solver;
  const WindowSolveSummary summary =
      solver.Solve(window.WindowStates(), window.WindowFactors(), TightWindow());
  EXPECT_EQ(summary.termination, WindowTermination::kFailure);
  for (int i = 0; i < kStates; ++i) {
    for (int k = 0; k < kPoseSize; ++k) EXPECT_EQ(window.states()[i].pose[k], before[i].pose[k]);
  }
  EXPECT_FALSE(solver.LastStateCovariance(window.WindowStates(), window.WindowFactors()));
}

// ---- options ----

TEST(LmOptions, DefaultsAndTheValuesInUseAreValid) {
  std::string why;
  EXPECT_TRUE(LmOptions{}.IsValid(&why)) << why;
  EXPECT_TRUE(TightWindow().IsValid(&why)) << why;
  // The alignment graph's solve: no time cap.
  LmOptions uncapped;
  uncapped.max_time_s = std::numeric_limits<double>::infinity();
  EXPECT_TRUE(uncapped.IsValid(&why)) << why;
  LmOptions zero_tolerances;
  zero_tolerances.function_tolerance = 0.0;
  zero_tolerances.parameter_tolerance = 0.0;
  zero_tolerances.gradient_tolerance = 0.0;
  EXPECT_TRUE(zero_tolerances.IsValid(&why)) << why;
}

TEST(LmOptions, EachBrokenLimitIsNamedAndSolveThrows) {
  const double nan = std::numeric_limits<double>::quiet_NaN();
  const double inf = std::numeric_limits<double>::infinity();
  std::vector<std::pair<std::string, std::function<void(LmOptions&)>>> broken;
  const auto add = [&](std::string field, auto set) { broken.emplace_back(std::move(field), set); };
  add("max_iterations", [](LmOptions& o) { o.max_iterations = 0; });
  for (const double bad : {0.0, -1.0, nan}) {
    add("max_time_s", [bad](LmOptions& o) { o.max_time_s = bad; });
  }
  for (const double bad : {-1e-9, nan, inf}) {
    add("function_tolerance", [bad](LmOptions& o) { o.function_tolerance = bad; });
    add("parameter_tolerance", [bad](LmOptions& o) { o.parameter_tolerance = bad; });
    add("gradient_tolerance", [bad](LmOptions& o) { o.gradient_tolerance = bad; });
  }
  for (const double bad : {0.0, -1.0, nan, inf}) {
    add("initial_trust_region_radius",
        [bad](LmOptions& o) { o.initial_trust_region_radius = bad; });
  }

  Window window;
  const std::vector<State> before = window.states();
  WindowSolver solver;
  for (const auto& [field, set] : broken) {
    LmOptions options = TightWindow();
    set(options);
    std::string why;
    EXPECT_FALSE(options.IsValid(&why)) << field;
    EXPECT_NE(why.find(field), std::string::npos) << field << ": " << why;
    EXPECT_THROW(solver.Solve(window.WindowStates(), window.WindowFactors(), options),
                 std::invalid_argument)
        << field;
  }
  // Nothing was solved.
  for (int i = 0; i < kStates; ++i) {
    for (int k = 0; k < kPoseSize; ++k) EXPECT_EQ(window.states()[i].pose[k], before[i].pose[k]);
  }
}

}  // namespace
}  // namespace tofu::estimator
