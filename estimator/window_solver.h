#pragma once
// Levenberg-Marquardt for the local graph's fixed-lag window, on its block-banded normal
// equations.
//
// Why not ceres::Solve: the window is small (15-30 keyframes of 15 tangent dimensions) and
// is re-solved 30-60 times a second from a warm start in one or two Gauss-Newton steps.
// Each ceres::Solve call rebuilds its reduced program, orders it and runs a new symbolic
// sparse Cholesky analysis; with Ceres's block-sparse JᵀJ that fixed cost was ~70 % of a
// local update (docs/BENCHMARKS.md). The window's factors on keyframe states only join
// keyframes that are close in time (IMU and bias factors join neighbours, a sensor's
// between factor joins its consecutive keyframes, the marginalisation prior the oldest
// few), so with keyframes in time order that part of H = JᵀJ is block-banded with a
// bandwidth of one to three keyframes, and its Cholesky factor has no fill-in outside that
// band. The band is factorised with dense 15x15 blocks, cost O(N b²), no symbolic phase;
// and the newest keyframe, ordered last among the states, has its marginal covariance in
// the last diagonal block of the factor: Σ_nn = (L_nn L_nnᵀ)⁻¹. Offset blocks (a position
// chain's, shared by keyframes far apart) border the band (Solve below).
//
// The factors stay ceres::CostFunctions with their analytic Jacobians (tested against
// numeric differentiation in local_factors_test), robust losses get Triggs et al. 1999's
// first-order correction as in Ceres, and the LM strategy is Ceres's (MinimizeLm,
// levenberg_marquardt.h), so both solve the same problem to the same optimum
// (window_solver_test compares them).
// Library code: Eigen + Ceres only. Not thread-safe.

#include <memory>
#include <optional>
#include <vector>

#include <Eigen/Core>
#include <ceres/cost_function.h>
#include <ceres/loss_function.h>

#include "estimator/levenberg_marquardt.h"

namespace tofu::estimator {

/// Tangent dimensions of a keyframe state: pose [δp, δθ] then speed-bias [δv, δb_a, δb_g].
constexpr int kStateTangentSize = 15;
using StateCovariance = Eigen::Matrix<double, kStateTangentSize, kStateTangentSize>;

/// A keyframe state of the window, in time order: its pose block (local_factors.h layout,
/// PoseManifold) and its speed-bias block (Euclidean). The solver updates them in place.
struct WindowState {
  double* pose = nullptr;
  double* speed_bias = nullptr;
  bool pose_constant = false;  ///< held fixed (its tangent columns are not estimated)
};

/// Size of an offset block: a Euclidean 3-vector shared by factors at any keyframes (a
/// position sensor's chain offset, local_factors.h PositionWithOffsetFactor).
constexpr int kWindowOffsetSize = 3;

/// A parameter block of a factor: which state, and which of its two blocks; or, with
/// offset ≥ 0, the offset block of that index (state and is_pose unused).
struct WindowBlockRef {
  int state = 0;
  bool is_pose = true;
  int offset = -1;
};

/// A factor: its cost, its robust loss (may be null) and its blocks in the cost's
/// parameter order. Blocks are pose (7), speed-bias (9) or offset (3) blocks, as the cost
/// declares.
struct WindowFactor {
  const ceres::CostFunction* cost = nullptr;
  const ceres::LossFunction* loss = nullptr;
  std::vector<WindowBlockRef> blocks;
};

/// The LM driver's options, termination and summary (levenberg_marquardt.h).
using WindowSolverOptions = LmOptions;
using WindowTermination = LmTermination;
using WindowSolveSummary = LmSummary;

class WindowSolver {
 public:
  WindowSolver();
  ~WindowSolver();
  WindowSolver(const WindowSolver&) = delete;
  WindowSolver& operator=(const WindowSolver&) = delete;

  /// Minimises ½ Σ ρ(‖r_f‖²) over the states and offsets (in place). Factors must only
  /// name states of `states` and offsets of `offsets` (kWindowOffsetSize numbers each); a
  /// factor whose blocks do not match its cost's parameter sizes, or options that are not
  /// IsValid(), are a programming error (std::invalid_argument).
  ///
  /// Offsets join factors far apart in time, so they are ordered after the band: the
  /// bordered system [[A, B], [Bᵀ, C]] is factorised as the band A, then X = L_A⁻¹ B and
  /// the Schur complement C − XᵀX (dense, 3 per offset).
  WindowSolveSummary Solve(const std::vector<WindowState>& states,
                           const std::vector<WindowFactor>& factors,
                           const WindowSolverOptions& options,
                           const std::vector<double*>& offsets = {});

  /// Marginal covariance of the last state (tangent order [δp, δθ, δv, δb_a, δb_g]) from
  /// the information matrix at the states' current values (Laplace approximation), the
  /// offsets marginalised. nullopt if a factor does not evaluate or the information is
  /// not positive definite.
  std::optional<StateCovariance> LastStateCovariance(const std::vector<WindowState>& states,
                                                     const std::vector<WindowFactor>& factors,
                                                     const std::vector<double*>& offsets = {});

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace tofu::estimator
