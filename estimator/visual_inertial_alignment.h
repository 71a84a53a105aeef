#pragma once
// Visual-inertial alignment: initialising the local graph in motion from a window of a
// pose stream together with the IMU, as VINS-Mono (Qin et al., T-RO 2018, Sec. V) and
// OpenVINS's dynamic initialiser do, for a metric pose stream (VIO, a motion-capture or
// SLAM pose): no scale to estimate.
//
// With R_k, p_k the pose of the IMU frame I in the stream's frame A at the stream's
// instants t_k, and the IMU preintegrated between them (Forster eqs. 33, 44):
//   gyro bias:  R_kᵀ R_{k+1} = ΔR_k Exp(J^R_bg δb_g)            (linear in δb_g)
//   p_{k+1} = p_k + v_k Δt_k + ½ g_A Δt_k² + R_k (Δp_k + J^p_ba b_a)
//   v_{k+1} = v_k + g_A Δt_k + R_k (Δv_k + J^v_ba b_a)            (linear in v, g_A, b_a)
// solved by weighted least squares, then with |g_A| = g on its tangent plane (VINS-Mono's
// gravity refinement). The gravity direction's standard deviation (the solution's
// covariance scaled by its residuals) says whether the window makes it observable.
// The residuals of the same equations measure the stream: the scatter of its relative
// positions and rotations between consecutive samples that the IMU does not explain.
// That is what a stream without a stated covariance (a TUM file) is weighted with.
//
// Library code: Eigen only.

#include <functional>
#include <optional>
#include <string>
#include <vector>

#include <Eigen/Core>
#include <Eigen/Geometry>

#include "core/time.h"
#include "core/units.h"
#include "estimator/imu_preintegration.h"

namespace tofu::estimator {

/// One sample of the pose stream, moved to the IMU frame: T_AI = T_As T_Is⁻¹.
struct ImuPoseInA {
  core::Time t_ns = 0;
  Eigen::Matrix3d R_AI = Eigen::Matrix3d::Identity();
  Eigen::Vector3d p_AI = Eigen::Vector3d::Zero();
};

struct VisualInertialAlignmentOptions {
  double gravity_mps2 = core::kWorldGravity_mps2;
  /// The window must span this long and hold this many samples before it is solved.
  double min_window_s = 1.0;
  int min_samples = 6;
  /// Observable: the gravity direction known to this (1σ) from the window. Without
  /// rotation in the window, tilt and accelerometer bias are one unknown: the bound then
  /// rests on the bias prior (0.1 m/s² ~ 0.6°); rotation separates them.
  double max_gravity_direction_std_rad = core::RadFromDeg(1.0);
  /// The unconstrained |g_A| within this fraction of gravity_mps2 (a stream whose time
  /// stamps or scale are grossly off fails here instead of initialising wrongly; a
  /// moderate scale error, 1.5x, may pass and shows in relative_position_std_m instead).
  double max_gravity_norm_error = 0.1;
  /// The gyro bias, when an estimator already knows it (its graph runs): not re-estimated,
  /// so that a stream whose rotation drifts against the IMU shows that drift as scatter
  /// instead of hiding it in a bias. Unset: estimated from the window.
  std::optional<Eigen::Vector3d> known_gyro_bias_radps;
  /// Prior on the accelerometer bias (weakly observable over a short window).
  double accel_bias_prior_std_mps2 = 0.1;
  /// Before the stream's noise is known, the weight of the position equation (the
  /// rotation equation is weighted by the window's own gyro-bias residuals from the start).
  double nominal_relative_position_std_m = 0.01;
  int gravity_refinement_iterations = 4;
  /// An interval whose residual exceeds this many robust standard deviations (from the
  /// median of the window's residuals) makes the window inconsistent.
  double outlier_sigmas = 6.0;

  /// True when the options are usable; otherwise false with the broken constraint in
  /// *why (if why is not null).
  bool IsValid(std::string* why = nullptr) const;
};

struct VisualInertialAlignment {
  bool observable = false;
  Eigen::Vector3d g_A = Eigen::Vector3d(0, 0, -core::kWorldGravity_mps2);  ///< gravity in A, |g_A| = g
  double unconstrained_gravity_norm_mps2 = 0.0;
  double gravity_direction_std_rad = 0.0;
  std::vector<Eigen::Vector3d> v_A_mps;  ///< velocity of I in A at each sample
  ImuBias bias;
  /// Std of one relative position / rotation between consecutive samples, per axis, from
  /// the residuals' median (robust to the odd bad sample).
  double relative_position_std_m = 0.0;
  double relative_rotation_std_rad = 0.0;
  double window_s = 0.0;
  int samples = 0;
  /// A window whose worst interval is an outlier against the others' scatter (a pose
  /// stream's own start-up transient, a jump): not observable, and the samples up to that
  /// interval's end should leave the window. 0 when consistent.
  int drop_leading_samples = 0;
};

/// Preintegration of the IMU over [t_from, t_to] at a bias, nullopt if not available.
using ImuPreintegrator =
    std::function<std::optional<ImuPreintegration>(core::Time, core::Time, const ImuBias&)>;

/// Aligns the window `poses` (time order, distinct stamps) with the IMU. nullopt when the
/// window is too short or the IMU does not cover it; otherwise the solution, with
/// `observable` telling whether it may initialise an estimator. Throws
/// std::invalid_argument when !options.IsValid() (MultiGraphEstimator checks the options
/// it holds at construction, so it never sees the throw).
std::optional<VisualInertialAlignment> AlignVisualInertial(
    const std::vector<ImuPoseInA>& poses, const ImuPreintegrator& preintegrate,
    const VisualInertialAlignmentOptions& options = {});

}  // namespace tofu::estimator
