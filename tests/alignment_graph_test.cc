// Per-sensor frame-alignment graph (seed paper Sec. 2.2, eq. 9): Jacobians, the paper's
// metric evaluation (30/60/120° offset, vertical then figure-eight flight), freezing,
// the sliding window, robustness, and the level prior of levelled frames.

#include "estimator/alignment_graph.h"
#include "estimator/frame_alignment.h"
#include "estimator/local_factors.h"

#include <cmath>
#include <cstdint>
#include <functional>
#include <limits>
#include <random>

#include <Eigen/Eigenvalues>
#include <ceres/loss_function.h>
#include <ceres/problem.h>
#include <ceres/solver.h>
#include <gtest/gtest.h>

#include "core/lie.h"
#include "core/time.h"
#include "tests/ceres_test_support.h"

namespace tofu::estimator {
namespace {

constexpr double kDegToRad = M_PI / 180.0;

/// Normal samples that are identical on every standard library: raw mt19937 words to a
/// uniform in (0, 1) with 53 bits, then Box-Muller (std::normal_distribution is not
/// specified exactly and differs between libstdc++ and libc++).
class PortableNormal {
 public:
  explicit PortableNormal(uint32_t seed) : engine_(seed) {}
  double Uniform01() {
    const uint64_t a = engine_() >> 5;  // 27 bits
    const uint64_t b = engine_() >> 6;  // 26 bits
    return (static_cast<double>(a) * 67108864.0 + static_cast<double>(b) + 0.5) /
           9007199254740992.0;
  }
  double Normal() {
    const double u1 = Uniform01();
    const double u2 = Uniform01();
    return std::sqrt(-2.0 * std::log(u1)) * std::cos(2.0 * M_PI * u2);
  }
  Eigen::Vector3d Normal3() { return {Normal(), Normal(), Normal()}; }

 private:
  std::mt19937 engine_;
};

/// The seed paper's metric evaluation offset: roll, pitch, yaw 30°, 60°, 120°, and a
/// translation of several metres.
Eigen::Isometry3d PaperOffset() {
  Eigen::Isometry3d T_AL = Eigen::Isometry3d::Identity();
  T_AL.linear() = core::RotationFromRollPitchYaw(30.0 * kDegToRad, 60.0 * kDegToRad,
                                                 120.0 * kDegToRad);
  T_AL.translation() = Eigen::Vector3d(4.0, -3.0, 1.5);
  return T_AL;
}

double RotationErrorDeg(const Eigen::Isometry3d& a, const Eigen::Isometry3d& b) {
  return core::RotationAngleBetween(a.linear(), b.linear()) / kDegToRad;
}

AlignmentPair MakePair(core::Time t_ns, const Eigen::Isometry3d& T_AL,
                       const Eigen::Vector3d& p_L, double sigma_m, PortableNormal& noise) {
  AlignmentPair pair;
  pair.t_ns = t_ns;
  pair.p_A_measured = T_AL * p_L + sigma_m * noise.Normal3();
  pair.covariance_A = sigma_m * sigma_m * Eigen::Matrix3d::Identity();
  pair.p_Ls_estimated = p_L;
  return pair;
}

/// Figure-eight in the horizontal plane with half-extents 2.5 m × 1.5 m, flown at a
/// constant speed by integrating the phase: φ' = speed / |dp/dφ|.
class FigureEight {
 public:
  FigureEight(double speed_mps, double z_m) : speed_mps_(speed_mps), z_m_(z_m) {}
  Eigen::Vector3d Step(double dt_s) {
    const double dp_dphi = std::hypot(2.5 * std::cos(phase_), 3.0 * std::cos(2.0 * phase_));
    phase_ += speed_mps_ * dt_s / dp_dphi;
    return Position();
  }
  Eigen::Vector3d Position() const {
    return {2.5 * std::sin(phase_), 1.5 * std::sin(2.0 * phase_), z_m_};
  }

 private:
  double speed_mps_;
  double z_m_;
  double phase_ = 0.0;
};

// ---- cost function and manifold ----

/// A few poses with large rotations (up to nearly π) and a non-isotropic covariance.
std::vector<Eigen::Isometry3d> LargeRotationPoses() {
  std::vector<Eigen::Isometry3d> poses;
  const Eigen::Vector3d axes[] = {{1.0, 2.0, -0.5}, {-0.3, 0.2, 1.0}, {0.7, -1.0, 0.1}};
  const double angles_rad[] = {2.1, 3.1, -1.3};
  for (int k = 0; k < 3; ++k) {
    Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
    T.linear() = Eigen::AngleAxisd(angles_rad[k], axes[k].normalized()).toRotationMatrix();
    T.translation() = Eigen::Vector3d(3.0 - k, -2.0 + 0.5 * k, 1.0 + k);
    poses.push_back(T);
  }
  poses.push_back(PaperOffset());
  return poses;
}

Eigen::Matrix<double, 7, 1> Parameters(const Eigen::Isometry3d& T) {
  Eigen::Matrix<double, 7, 1> x;
  x.head<3>() = T.translation();
  x.tail<4>() = Eigen::Quaterniond(T.linear()).coeffs();  // x, y, z, w
  return x;
}

/// Central differences of residual(Plus(x, ±h e_k)) in PoseManifold's tangent space
/// [δp, δθ]; `residual` takes the 7 ambient parameters.
template <int Rows, typename Residual>
Eigen::Matrix<double, Rows, 6> NumericTangentJacobian(const Eigen::Matrix<double, 7, 1>& x,
                                                      Residual&& residual) {
  const PoseManifold manifold;
  Eigen::Matrix<double, Rows, 6> J;
  const double h = 1e-6;
  for (int k = 0; k < 6; ++k) {
    Eigen::Matrix<double, 6, 1> delta = Eigen::Matrix<double, 6, 1>::Zero();
    Eigen::Matrix<double, 7, 1> x_plus, x_minus;
    delta(k) = h;
    manifold.Plus(x.data(), delta.data(), x_plus.data());
    delta(k) = -h;
    manifold.Plus(x.data(), delta.data(), x_minus.data());
    J.col(k) = (residual(x_plus) - residual(x_minus)) / (2.0 * h);
  }
  return J;
}

TEST(PositionAlignmentCost, TangentJacobianMatchesCentralDifferencesAtLargeRotations) {
  // Whitening of a correlated covariance, S = L⁻¹ with Σ = L Lᵀ.
  Eigen::Matrix3d covariance;
  covariance << 4e-4, 1e-4, -5e-5, 1e-4, 2e-4, 3e-5, -5e-5, 3e-5, 9e-4;
  const Eigen::Matrix3d S =
      covariance.llt().matrixL().solve(Eigen::Matrix3d::Identity());
  const Eigen::Vector3d p_Ls(2.5, -1.2, 1.7);
  const Eigen::Vector3d p_A(0.3, 4.0, -2.0);
  const PositionAlignmentCost cost(p_A, p_Ls, S);
  const PoseManifold manifold;

  for (const Eigen::Isometry3d& T : LargeRotationPoses()) {
    const Eigen::Matrix<double, 7, 1> x = Parameters(T);
    // Analytic: ambient Jacobian (Ceres' interface) times the manifold's PlusJacobian.
    Eigen::Vector3d r;
    Eigen::Matrix<double, 3, 7, Eigen::RowMajor> J_ambient;
    Eigen::Matrix<double, 7, 6, Eigen::RowMajor> J_plus;
    const double* parameters[] = {x.data()};
    double* jacobians[] = {J_ambient.data()};
    ASSERT_TRUE(cost.Evaluate(parameters, r.data(), jacobians));
    ASSERT_TRUE(manifold.PlusJacobian(x.data(), J_plus.data()));
    const Eigen::Matrix<double, 3, 6> J_analytic = J_ambient * J_plus;
    EXPECT_LT((r - cost.Residual(T)).norm(), 1e-9);

    // Numeric: central differences of r(Plus(x, ±h e_k)) in the tangent space.
    const Eigen::Matrix<double, 3, 6> J_numeric =
        NumericTangentJacobian<3>(x, [&](const Eigen::Matrix<double, 7, 1>& v) {
          Eigen::Vector3d residual;
          const double* parameters_v[] = {v.data()};
          cost.Evaluate(parameters_v, residual.data(), nullptr);
          return residual;
        });
    const double scale = J_numeric.cwiseAbs().maxCoeff();
    EXPECT_LT((J_analytic - J_numeric).cwiseAbs().maxCoeff(), 1e-7 * scale)
        << "analytic\n" << J_analytic << "\nnumeric\n" << J_numeric;
    // The closed form used for the information matrix agrees too.
    EXPECT_LT((cost.TangentJacobian(T) - J_numeric).cwiseAbs().maxCoeff(), 1e-7 * scale);
  }
}

TEST(LevelPrior, TangentJacobianMatchesCentralDifferences) {
  const double std_rad = 0.2 * kDegToRad;
  for (const Eigen::Isometry3d& T : LargeRotationPoses()) {
    const Eigen::Matrix<double, 7, 1> x = Parameters(T);
    const Eigen::Matrix<double, 2, 6> J_analytic = LevelPriorTangentJacobian(T, std_rad);
    const Eigen::Matrix<double, 2, 6> J_numeric =
        NumericTangentJacobian<2>(x, [&](const Eigen::Matrix<double, 7, 1>& v) {
          Eigen::Isometry3d pose = Eigen::Isometry3d::Identity();
          pose.translation() = v.head<3>();
          pose.linear() = Eigen::Quaterniond(v.tail<4>()).normalized().toRotationMatrix();
          return LevelPriorResidual(pose, std_rad);
        });
    const double scale = J_numeric.cwiseAbs().maxCoeff();
    EXPECT_LT((J_analytic - J_numeric).cwiseAbs().maxCoeff(), 1e-7 * scale)
        << "analytic\n" << J_analytic << "\nnumeric\n" << J_numeric;
  }
  // A pure yaw: no residual, and no information on yaw.
  Eigen::Isometry3d yaw = Eigen::Isometry3d::Identity();
  yaw.linear() = Eigen::AngleAxisd(1.1, Eigen::Vector3d::UnitZ()).toRotationMatrix();
  EXPECT_LT(LevelPriorResidual(yaw, std_rad).norm(), 1e-12);
  EXPECT_LT(LevelPriorTangentJacobian(yaw, std_rad).col(5).norm(), 1e-12);
}

TEST(AlignmentGraph, AStraightLevelLegObservesYawOnlyWithTheLevelPrior) {
  // A levelled sensor frame (a GNSS's ENU: yaw 35° and an offset from L) and a straight,
  // level leg at 1 m/s for 15 s, 2 cm noise: the roll about the leg is not observed from
  // the pairs (2 rotations), and the prior's tilt makes all three known, yaw from the leg.
  Eigen::Isometry3d T_AL = Eigen::Isometry3d::Identity();
  T_AL.linear() = Eigen::AngleAxisd(35.0 * kDegToRad, Eigen::Vector3d::UnitZ()).toRotationMatrix();
  T_AL.translation() = Eigen::Vector3d(-11.7, -2.4, 0.3);
  const Eigen::Vector3d direction_L = Eigen::Vector3d(0.99, 0.1, 0.0).normalized();
  const auto solve = [&](double level_prior_std_rad) {
    AlignmentGraphOptions options;
    options.level_prior_std_rad = level_prior_std_rad;
    AlignmentGraph graph(options);
    PortableNormal noise(7);
    core::Time t_ns = 0;
    for (int i = 0; i <= 150; ++i, t_ns += 100'000'000) {
      const Eigen::Vector3d p_L = Eigen::Vector3d(-12.0, -2.5, 2.5) + 0.1 * i * direction_L;
      graph.AddPair(MakePair(t_ns, T_AL, p_L, 0.02, noise));
    }
    EXPECT_TRUE(graph.Update(t_ns));
    return graph.estimate();
  };
  const AlignmentEstimate free = solve(0.0);
  ASSERT_TRUE(free.valid);
  EXPECT_EQ(free.observable_rotation_dofs, 2);

  const double level_std_rad = 0.2 * kDegToRad;
  const AlignmentEstimate level = solve(level_std_rad);
  ASSERT_TRUE(level.valid);
  EXPECT_EQ(level.observable_rotation_dofs, 3);
  EXPECT_TRUE(level.yaw_observable);
  EXPECT_LT(RotationErrorDeg(level.T_AL, T_AL), 0.1);
  EXPECT_LT((level.T_AL.translation() - T_AL.translation()).norm(), 0.02);
  // The tilt's std is the prior's at most; the estimator's 0.5° usability bound holds.
  const double rotation_variance =
      level.covariance.bottomRightCorner<3, 3>().eigenvalues().real().maxCoeff();
  EXPECT_LE(std::sqrt(rotation_variance), level_std_rad * (1.0 + 1e-9));
}

TEST(AlignmentGraph, PaperEvaluationYawUnobservableInVerticalFlightThenRecovered) {
  const Eigen::Isometry3d T_AL = PaperOffset();
  AlignmentGraph graph;  // paper defaults: 20 s window, 10 Hz, 20 Hz pairs
  PortableNormal noise(20240611);
  const double sigma_m = 0.003;          // sensor
  const double local_sigma_m = 0.001;    // local estimate of the mount point
  const double dt_s = 0.01;              // pairs offered at 100 Hz
  const double t_horizontal_s = 35.0;

  // Vertical: z bounces between 0.8 and 2.2 m at 0.5 m/s, with 5 mm of horizontal hover
  // jitter (no flight is perfectly vertical).
  auto vertical = [](double t_s) {
    const double leg_m = 1.4;
    const double travel_m = std::fmod(0.5 * t_s, 2.0 * leg_m);
    const double z_m = 0.8 + (travel_m < leg_m ? travel_m : 2.0 * leg_m - travel_m);
    return Eigen::Vector3d(0.005 * std::sin(1.3 * t_s), 0.005 * std::cos(0.9 * t_s), z_m);
  };
  FigureEight eight(0.8, vertical(t_horizontal_s).z());

  int vertical_solves = 0;
  int recovered_solves = 0;
  double first_yaw_observable_s = -1.0;
  for (int k = 0; k <= 7000; ++k) {
    const double t_s = k * dt_s;
    const core::Time t_ns = core::SecondsToTime(t_s);
    const Eigen::Vector3d p_L =
        t_s < t_horizontal_s ? vertical(t_s) : eight.Step(dt_s);
    AlignmentPair pair = MakePair(t_ns, T_AL, p_L, sigma_m, noise);
    pair.p_Ls_estimated += local_sigma_m * noise.Normal3();
    ASSERT_TRUE(graph.AddPair(pair));
    if (!graph.Update(t_ns)) continue;
    const AlignmentEstimate& estimate = graph.estimate();
    ASSERT_TRUE(estimate.valid);
    ASSERT_TRUE(estimate.covariance.allFinite());
    if (t_s < t_horizontal_s) {
      ++vertical_solves;
      EXPECT_FALSE(estimate.yaw_observable) << "t = " << t_s << " s";
      EXPECT_EQ(estimate.observable_rotation_dofs, 2) << "t = " << t_s << " s";
      // Yaw has little information (hover jitter only): its standard deviation is
      // above 1°, while roll and pitch, once the window is full, are known to < 0.1°.
      EXPECT_GT(std::sqrt(estimate.covariance(5, 5)), 1.0 * kDegToRad) << "t = " << t_s;
      if (t_s >= 20.0) {
        EXPECT_LT(std::sqrt(estimate.covariance(3, 3)), 0.1 * kDegToRad) << "t = " << t_s;
        EXPECT_LT(std::sqrt(estimate.covariance(4, 4)), 0.1 * kDegToRad) << "t = " << t_s;
      }
      // The points are still fitted to the noise level.
      EXPECT_LT(estimate.rms_residual_m, 0.01);
    } else if (first_yaw_observable_s < 0.0 && estimate.yaw_observable) {
      first_yaw_observable_s = t_s;
    }
    if (t_s >= t_horizontal_s + 10.0) {
      ++recovered_solves;
      EXPECT_LT(RotationErrorDeg(estimate.T_AL, T_AL), 1.0) << "t = " << t_s << " s";
      EXPECT_LT((estimate.T_AL.translation() - T_AL.translation()).norm(), 0.02)
          << "t = " << t_s << " s";
      EXPECT_TRUE(estimate.yaw_observable) << "t = " << t_s << " s";
      EXPECT_EQ(estimate.observable_rotation_dofs, 3);
      // The covariance is the honest one: 3 mm over 400 pairs gives well below 0.1°.
      EXPECT_LT(std::sqrt(estimate.covariance(5, 5)), 0.1 * kDegToRad);
    }
  }
  EXPECT_GT(vertical_solves, 300);  // 10 Hz from the 10th pair on
  EXPECT_GT(recovered_solves, 200);
  EXPECT_GT(first_yaw_observable_s, t_horizontal_s);
  EXPECT_LT(first_yaw_observable_s, t_horizontal_s + 10.0);
  std::printf("yaw observable %.1f s after horizontal motion started\n",
              first_yaw_observable_s - t_horizontal_s);
}

TEST(AlignmentGraph, YawIsTheMarginalNotTheConditionalInformation) {
  // Motion along a line: rotation about the line is unobservable. Tilted 45° from the
  // vertical, the free rotation has a yaw component, so yaw is undetermined even though
  // the conditional information e_zᵀ H_rot e_z is large; along a horizontal line, yaw is
  // observable (with 2 observable rotation DoFs).
  const Eigen::Isometry3d T_AL = PaperOffset();
  const Eigen::Vector3d directions[] = {Eigen::Vector3d(1.0, 0.0, 1.0).normalized(),
                                        Eigen::Vector3d::UnitX()};
  const bool expect_yaw_observable[] = {false, true};
  for (int d = 0; d < 2; ++d) {
    AlignmentGraph graph;
    PortableNormal noise(7);
    for (int k = 0; k < 200; ++k) {
      const double t_s = 0.05 * k;
      const Eigen::Vector3d p_L = Eigen::Vector3d(0.0, 0.0, 1.5) +
                                  1.0 * std::sin(0.5 * t_s) * directions[d];
      ASSERT_TRUE(graph.AddPair(MakePair(core::SecondsToTime(t_s), T_AL, p_L, 0.003, noise)));
    }
    ASSERT_TRUE(graph.Update(core::SecondsToTime(10.0)));
    const AlignmentEstimate& estimate = graph.estimate();
    EXPECT_EQ(estimate.observable_rotation_dofs, 2) << "direction " << d;
    EXPECT_EQ(estimate.yaw_observable, expect_yaw_observable[d]) << "direction " << d;
    // The unobservable direction is the line's (in L).
    EXPECT_GT(std::abs(estimate.rotation_information_directions.col(0).dot(directions[d])),
              0.999);
  }
}

// ---- co-dependence: frozen ----

TEST(AlignmentGraph, FrozenHoldsTransformAndIgnoresPairsThenResumes) {
  const Eigen::Isometry3d T_AL = PaperOffset();
  AlignmentGraph graph;
  AlignmentGraph reference;  // never sees the pairs offered while frozen
  PortableNormal noise(11);
  PortableNormal noise_reference(11);
  FigureEight eight(0.8, 1.5);
  FigureEight eight_reference(0.8, 1.5);
  auto step = [&](int k, bool feed_graph, bool feed_reference) {
    const core::Time t_ns = core::SecondsToTime(0.05 * k);
    const AlignmentPair pair = MakePair(t_ns, T_AL, eight.Step(0.05), 0.003, noise);
    const AlignmentPair pair_reference =
        MakePair(t_ns, T_AL, eight_reference.Step(0.05), 0.003, noise_reference);
    if (feed_graph) graph.AddPair(pair);
    if (feed_reference) reference.AddPair(pair_reference);
  };
  for (int k = 0; k < 100; ++k) {
    step(k, true, true);
    graph.Update(core::SecondsToTime(0.05 * k));
    reference.Update(core::SecondsToTime(0.05 * k));
  }
  ASSERT_TRUE(graph.estimate().valid);
  const AlignmentEstimate before = graph.estimate();
  const int stored_before = graph.stored_pairs();

  graph.SetFrozen(true);
  reference.SetFrozen(true);
  EXPECT_TRUE(graph.estimate().frozen);
  // Corrupted pairs (the sensor is 10 m off) and later ones: valid input, not stored.
  for (int k = 100; k < 160; ++k) {
    const core::Time t_ns = core::SecondsToTime(0.05 * k);
    AlignmentPair corrupted = MakePair(t_ns, T_AL, eight.Step(0.05), 0.003, noise);
    corrupted.p_A_measured += Eigen::Vector3d(10.0, -10.0, 10.0);
    eight_reference.Step(0.05);
    noise_reference.Normal3();
    EXPECT_TRUE(graph.AddPair(corrupted));
    EXPECT_FALSE(graph.Update(t_ns));
  }
  EXPECT_EQ(graph.stored_pairs(), stored_before);
  EXPECT_EQ(graph.dropped_while_frozen_pairs(), 60);
  EXPECT_EQ(graph.rejected_pairs(), 0);
  EXPECT_TRUE(graph.estimate().T_AL.isApprox(before.T_AL, 0.0));
  EXPECT_EQ(graph.estimate().t_ns, before.t_ns);

  // Unfrozen: it resumes, exactly as if the frozen-period pairs had never been offered.
  graph.SetFrozen(false);
  reference.SetFrozen(false);
  EXPECT_FALSE(graph.estimate().frozen);
  int solves = 0;
  for (int k = 160; k < 200; ++k) {
    step(k, true, true);
    const bool solved = graph.Update(core::SecondsToTime(0.05 * k));
    EXPECT_EQ(solved, reference.Update(core::SecondsToTime(0.05 * k)));
    solves += solved ? 1 : 0;
  }
  EXPECT_GT(solves, 10);
  EXPECT_GT(graph.estimate().t_ns, before.t_ns);
  EXPECT_TRUE(graph.estimate().T_AL.isApprox(reference.estimate().T_AL, 1e-12));
  EXPECT_LT(RotationErrorDeg(graph.estimate().T_AL, T_AL), 0.1);
  EXPECT_LT((graph.estimate().T_AL.translation() - T_AL.translation()).norm(), 0.005);
}

// ---- sliding window ----

/// Tracks a frame whose translation drifts at 1 cm/s along x of A and returns the mean
/// lag (s) of the estimate behind the truth, (p_true(t) − p_est(t))·x / (1 cm/s), over
/// the updates after the window has filled twice.
double DriftLagSeconds(core::Time window_ns, double* max_rotation_error_deg) {
  AlignmentGraphOptions options;
  options.window_ns = window_ns;
  AlignmentGraph graph(options);
  PortableNormal noise(3);
  FigureEight eight(1.5, 1.5);
  const double drift_mps = 0.01;
  const Eigen::Isometry3d T_AL_0 = PaperOffset();
  double lag_sum_s = 0.0;
  int lags = 0;
  *max_rotation_error_deg = 0.0;
  const double t_start_s = 2.0 * core::TimeToSeconds(window_ns);
  for (int k = 0; k < 9000; ++k) {
    const double t_s = 0.01 * k;
    const core::Time t_ns = core::SecondsToTime(t_s);
    Eigen::Isometry3d T_AL = T_AL_0;
    T_AL.translation().x() += drift_mps * t_s;
    graph.AddPair(MakePair(t_ns, T_AL, eight.Step(0.01), 0.003, noise));
    if (!graph.Update(t_ns) || t_s < t_start_s) continue;
    lag_sum_s += (T_AL.translation().x() - graph.estimate().T_AL.translation().x()) / drift_mps;
    ++lags;
    *max_rotation_error_deg =
        std::max(*max_rotation_error_deg, RotationErrorDeg(graph.estimate().T_AL, T_AL));
  }
  return lag_sum_s / lags;
}

TEST(AlignmentGraph, SlidingWindowTracksDriftWithHalfWindowLag) {
  // Least squares over a window of uniformly spaced pairs estimates the average of a
  // linearly drifting translation: a lag of window / 2.
  for (const double window_s : {20.0, 6.0}) {
    double max_rotation_error_deg = 0.0;
    const double lag_s = DriftLagSeconds(core::SecondsToTime(window_s), &max_rotation_error_deg);
    EXPECT_NEAR(lag_s, 0.5 * window_s, 0.1 * window_s) << "window " << window_s << " s";
    // The drift within the window correlates with the motion and tilts the fit a little.
    EXPECT_LT(max_rotation_error_deg, 1.0) << "window " << window_s << " s";
    std::printf("window %.0f s: lag %.2f s, max rotation error %.3f deg\n", window_s, lag_s,
                max_rotation_error_deg);
  }
}

// ---- robustness ----

TEST(AlignmentGraph, RejectsNonFiniteOutOfOrderAndBadCovariancePairs) {
  AlignmentGraph graph;
  const Eigen::Isometry3d T_AL = PaperOffset();
  PortableNormal noise(5);
  EXPECT_TRUE(graph.AddPair(MakePair(1'000'000'000, T_AL, {1.0, 0.0, 1.0}, 0.003, noise)));
  AlignmentPair nan_pair = MakePair(2'000'000'000, T_AL, {1.0, 1.0, 1.0}, 0.003, noise);
  nan_pair.p_Ls_estimated.y() = std::numeric_limits<double>::quiet_NaN();
  EXPECT_FALSE(graph.AddPair(nan_pair));
  EXPECT_EQ(graph.rejected_pairs(), 1);
  AlignmentPair inf_pair = MakePair(2'000'000'000, T_AL, {1.0, 1.0, 1.0}, 0.003, noise);
  inf_pair.p_A_measured.x() = std::numeric_limits<double>::infinity();
  EXPECT_FALSE(graph.AddPair(inf_pair));
  EXPECT_EQ(graph.rejected_pairs(), 2);
  // Out of order and repeated stamps.
  EXPECT_FALSE(graph.AddPair(MakePair(500'000'000, T_AL, {1.0, 1.0, 1.0}, 0.003, noise)));
  EXPECT_FALSE(graph.AddPair(MakePair(1'000'000'000, T_AL, {1.0, 1.0, 1.0}, 0.003, noise)));
  EXPECT_EQ(graph.rejected_pairs(), 4);
  // A covariance that is not positive definite.
  AlignmentPair bad_covariance = MakePair(3'000'000'000, T_AL, {1.0, 1.0, 1.0}, 0.003, noise);
  bad_covariance.covariance_A(2, 2) = -1e-6;
  EXPECT_FALSE(graph.AddPair(bad_covariance));
  EXPECT_EQ(graph.rejected_pairs(), 5);
  EXPECT_EQ(graph.stored_pairs(), 1);
  // No covariance (zero matrix): position_std_m is used, the pair is stored.
  AlignmentPair no_covariance = MakePair(4'000'000'000, T_AL, {1.0, 1.0, 1.0}, 0.003, noise);
  no_covariance.covariance_A.setZero();
  EXPECT_TRUE(graph.AddPair(no_covariance));
  EXPECT_EQ(graph.stored_pairs(), 2);
  // Decimation: 10 ms after the last stored pair is valid but not stored.
  EXPECT_TRUE(graph.AddPair(MakePair(4'010'000'000, T_AL, {1.0, 1.0, 1.1}, 0.003, noise)));
  EXPECT_EQ(graph.stored_pairs(), 2);
  EXPECT_EQ(graph.decimated_pairs(), 1);
  EXPECT_EQ(graph.rejected_pairs(), 5);
  // Too few pairs: no solve.
  EXPECT_FALSE(graph.Update(4'100'000'000));
  EXPECT_FALSE(graph.estimate().valid);
}

/// Final rotation (deg) and translation (m) errors with 15 % outliers 0.5 m off in z.
void OutlierErrors(double huber_delta, double* rotation_error_deg, double* translation_error_m) {
  AlignmentGraphOptions options;
  options.huber_delta = huber_delta;
  AlignmentGraph graph(options);
  const Eigen::Isometry3d T_AL = PaperOffset();
  PortableNormal noise(17);
  FigureEight eight(0.8, 1.5);
  for (int k = 0; k < 400; ++k) {
    const core::Time t_ns = core::SecondsToTime(0.05 * k);
    AlignmentPair pair = MakePair(t_ns, T_AL, eight.Step(0.05), 0.003, noise);
    if (noise.Uniform01() < 0.15) pair.p_A_measured.z() += 0.5;
    graph.AddPair(pair);
    graph.Update(t_ns);
  }
  ASSERT_TRUE(graph.estimate().valid);
  *rotation_error_deg = RotationErrorDeg(graph.estimate().T_AL, T_AL);
  *translation_error_m = (graph.estimate().T_AL.translation() - T_AL.translation()).norm();
}

TEST(AlignmentGraph, HuberLossLimitsTheEffectOfOutliers) {
  double rotation_plain_deg = 0.0, translation_plain_m = 0.0;
  double rotation_huber_deg = 0.0, translation_huber_m = 0.0;
  OutlierErrors(0.0, &rotation_plain_deg, &translation_plain_m);
  OutlierErrors(3.0, &rotation_huber_deg, &translation_huber_m);
  std::printf("plain: %.3f deg %.4f m; Huber: %.3f deg %.4f m\n", rotation_plain_deg,
              translation_plain_m, rotation_huber_deg, translation_huber_m);
  EXPECT_GT(translation_plain_m, 0.03);  // the outliers do bias least squares
  EXPECT_LT(translation_huber_m, 0.3 * translation_plain_m);
  EXPECT_LT(translation_huber_m, 0.01);
  EXPECT_LT(rotation_huber_deg, rotation_plain_deg + 0.05);
}

// The graph's own Levenberg-Marquardt (levenberg_marquardt.h) reaches the optimum that
// ceres::Solve finds for the same robust problem: PositionAlignmentCost on every pair,
// Huber loss, PoseManifold, from the same closed-form start, Ceres run to its tightest
// tolerances. The graph stops at Ceres's default function tolerance (1e-6 of the cost),
// which for 190 pairs of 3 mm leaves the optimum within a few µm.
TEST(AlignmentGraph, SolvesToTheOptimumOfCeresOnTheSameRobustProblem) {
  AlignmentGraphOptions options;
  options.huber_delta = 3.0;
  options.max_iterations = 50;
  AlignmentGraph graph(options);
  const Eigen::Isometry3d T_AL = PaperOffset();
  PortableNormal noise(29);
  FigureEight eight(0.8, 1.5);
  std::vector<AlignmentPair> pairs;
  for (int k = 0; k < 190; ++k) {
    AlignmentPair pair = MakePair(core::SecondsToTime(0.1 * k), T_AL, eight.Step(0.1), 0.003, noise);
    if (noise.Uniform01() < 0.15) pair.p_A_measured.z() += 0.5;  // outliers
    ASSERT_TRUE(graph.AddPair(pair));
    pairs.push_back(pair);
  }
  ASSERT_TRUE(graph.Update(pairs.back().t_ns));
  ASSERT_EQ(graph.stored_pairs(), static_cast<int>(pairs.size()));

  std::vector<Eigen::Vector3d> p_L, p_A;
  for (const AlignmentPair& pair : pairs) {
    p_L.push_back(pair.p_Ls_estimated);
    p_A.push_back(pair.p_A_measured);
  }
  const auto start = AlignPositions(p_L, p_A, 0.0);
  ASSERT_TRUE(start.has_value());
  Eigen::Matrix<double, 7, 1> x = Parameters(start->T_AL);
  PoseManifold manifold;
  ceres::HuberLoss huber(options.huber_delta);
  ceres::Problem::Options problem_options;
  problem_options.manifold_ownership = ceres::DO_NOT_TAKE_OWNERSHIP;
  problem_options.loss_function_ownership = ceres::DO_NOT_TAKE_OWNERSHIP;
  ceres::Problem problem(problem_options);
  problem.AddParameterBlock(x.data(), 7, &manifold);
  const Eigen::Matrix3d S = Eigen::Matrix3d::Identity() / 0.003;
  for (const AlignmentPair& pair : pairs) {
    problem.AddResidualBlock(
        new PositionAlignmentCost(pair.p_A_measured, pair.p_Ls_estimated, S), &huber, x.data());
  }
  ceres::Solver::Summary summary;
  ceres::Solve(test::ReferenceCeresOptions(), &problem, &summary);
  ASSERT_TRUE(summary.IsSolutionUsable());

  Eigen::Isometry3d T_ceres = Eigen::Isometry3d::Identity();
  T_ceres.translation() = x.head<3>();
  T_ceres.linear() = Eigen::Quaterniond(x[6], x[3], x[4], x[5]).normalized().toRotationMatrix();
  const Eigen::Isometry3d& T_graph = graph.estimate().T_AL;
  std::printf("graph vs Ceres: %.2e m, %.2e deg (Ceres: %d steps)\n",
              (T_graph.translation() - T_ceres.translation()).norm(),
              RotationErrorDeg(T_graph, T_ceres), static_cast<int>(summary.iterations.size()));
  EXPECT_LT((T_graph.translation() - T_ceres.translation()).norm(), 2e-5);
  EXPECT_LT(RotationErrorDeg(T_graph, T_ceres), 1e-3);
  // And both are the robust estimate, millimetres from the truth despite the outliers.
  EXPECT_LT((T_graph.translation() - T_AL.translation()).norm(), 0.01);
}

TEST(AlignmentGraph, ResetForgetsPairsAndEstimate) {
  AlignmentGraph graph;
  const Eigen::Isometry3d T_AL = PaperOffset();
  PortableNormal noise(23);
  FigureEight eight(0.8, 1.5);
  for (int k = 0; k < 40; ++k) {
    const core::Time t_ns = core::SecondsToTime(0.05 * k);
    graph.AddPair(MakePair(t_ns, T_AL, eight.Step(0.05), 0.003, noise));
    graph.Update(t_ns);
  }
  ASSERT_TRUE(graph.estimate().valid);
  graph.Reset();
  EXPECT_FALSE(graph.estimate().valid);
  EXPECT_EQ(graph.stored_pairs(), 0);
  // Time may start over after a reset.
  EXPECT_TRUE(graph.AddPair(MakePair(0, T_AL, eight.Step(0.05), 0.003, noise)));
  EXPECT_EQ(graph.stored_pairs(), 1);
}

TEST(AlignmentGraphOptions, IsValidNamesTheBrokenConstraint) {
  AlignmentGraphOptions options;
  std::string why;
  EXPECT_TRUE(options.IsValid(&why));
  options.min_rotation_information = 0.0;
  EXPECT_FALSE(options.IsValid(&why));
  EXPECT_NE(why.find("min_rotation_information"), std::string::npos);
  EXPECT_THROW(AlignmentGraph{options}, std::invalid_argument);
  options = AlignmentGraphOptions{};
  options.level_prior_std_rad = -0.01;
  EXPECT_FALSE(options.IsValid(&why));
  EXPECT_NE(why.find("level_prior_std_rad"), std::string::npos);
}

}  // namespace
}  // namespace tofu::estimator
