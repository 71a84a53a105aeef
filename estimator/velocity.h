#pragma once
// Velocities for the consistency metric (Lanegger et al., Sec. 2.1):
//  - paper eq. (1): sensor b's velocity transferred to sensor a's mount point and frame;
//  - linear velocities from position streams and body angular rates from orientation
//    streams by local least-squares fits that cope with unequal rates, jitter and gaps.
// Frames (DESIGN.md): sensor s has its reference frame S and its mount frame s on the
// body; R_Ss is the attitude of s in S, p_Ss the position of s in S.
// Library code: no MuJoCo, no simulator, no I/O.

#include <cstdint>
#include <span>
#include <string>
#include <vector>

#include <Eigen/Core>
#include <Eigen/Geometry>

#include "core/time.h"
#include "estimator/consistency.h"

namespace tofu::estimator {

// ---- paper eq. (1) ----

/// Linear velocity of mount point a, expressed in mount frame a, as measured by sensor b
/// (paper eq. 1):
///   v_a_a = R_Aa^T R_AB R_Bb (v_b_b + omega_b_b × p_ba)
/// R_Aa: attitude of a in its reference frame A; R_AB: rotation of B in A (frame
/// alignment, e.g. from the sensor-transform graph, or ground truth in evaluation);
/// R_Bb: attitude of b in B; v_b_b: b's measured velocity of its mount point, in b (m/s);
/// omega_b_b: the body's angular rate, in b (rad/s); p_ba: lever arm, position of a's
/// mount point in frame b (m, the intrinsic calibration). A and B are taken as inertial
/// (not rotating w.r.t. each other).
Eigen::Vector3d TransferVelocity(const Eigen::Matrix3d& R_Aa, const Eigen::Matrix3d& R_AB,
                                 const Eigen::Matrix3d& R_Bb, const Eigen::Vector3d& v_b_b,
                                 const Eigen::Vector3d& omega_b_b,
                                 const Eigen::Vector3d& p_ba);

/// Eq. (1) for a position-only sensor b (total station, GNSS): its velocity is known in
/// its reference frame B (v_Bb, e.g. from DifferentiatePositions), not in b, so
///   v_a_a = R_Aa^T R_AB (v_Bb + R_Bb (omega_b_b × p_ba)).
/// Such a sensor measures no attitude: R_Bb (and omega_b_b) must come from elsewhere,
/// e.g. R_Bb = R_BL R_LI R_Ib from the local estimate's attitude R_LI, the frame
/// alignment R_BL and the mount extrinsics R_Ib, and omega_b_b = R_Ib^T omega_I from the
/// gyroscope. Errors in R_Bb only enter through the lever-arm term.
Eigen::Vector3d TransferVelocityFromReference(const Eigen::Matrix3d& R_Aa,
                                              const Eigen::Matrix3d& R_AB,
                                              const Eigen::Vector3d& v_Bb,
                                              const Eigen::Matrix3d& R_Bb,
                                              const Eigen::Vector3d& omega_b_b,
                                              const Eigen::Vector3d& p_ba);

// ---- differentiation of pose streams ----

/// Local least-squares differentiation. For every sample k, a polynomial of `degree` in
/// (t − t_k) is fitted by least squares to the samples with |t − t_k| <= half_window_ns in
/// the same gap-free segment, and its slope at t_k is the derivative at t_k.
///
/// Centred window, so the output is stamped at the sample's own time t_k (no timestamp
/// bias), but it is known only once the samples up to t_k + half_window have arrived:
/// an online user has a delay of half_window_ns (plus up to one sample period), and
/// should evaluate consistency at t_now − half_window_ns.
///
/// degree 2 (default) is exact for constant acceleration whatever the sample spacing
/// (jitter, unequal rates), and for symmetric spacing has the same noise as degree 1;
/// its truncation error is ~|p'''| half_window² / 6. Noise: a slope fitted to n samples
/// spread over ±h has sd ≈ σ_p √3 / (h √n). Choose half_window >= 1.5 sample periods so
/// every sample has neighbours on both sides (e.g. >= 150 ms for a 10 Hz stream).
struct DifferentiationOptions {
  core::Time half_window_ns = 100'000'000;
  /// Consecutive samples further apart than this split the stream: no fit spans a gap,
  /// so no velocity is produced from samples on both sides of it.
  core::Time max_gap_ns = 250'000'000;
  int degree = 2;  ///< 1 (line) or 2 (parabola)
  /// Fewer samples in a window (at least degree + 1): no output at that sample.
  int min_fit_samples = 3;
  /// Output only where the window holds samples both before and after t_k (no one-sided
  /// extrapolation at segment ends).
  bool require_both_sides = true;

  /// True when usable; otherwise false with the broken constraint in *why.
  bool IsValid(std::string* why = nullptr) const;
};

/// What the differentiation skipped.
struct DifferentiationStats {
  int64_t rejected_non_finite = 0;    ///< input samples with a NaN/inf component
  int64_t rejected_out_of_order = 0;  ///< timestamps not after the last accepted one
  int64_t segments = 0;               ///< gap-free segments of the accepted samples
  int64_t without_output = 0;         ///< accepted samples that got no derivative
};

/// Linear velocity v_Ss (m/s, in the stream's frame S) of the positions p_Ss (m) stamped
/// t_ns, by DifferentiationOptions. Non-finite and non-increasing samples are rejected
/// (counted in *stats); output timestamps are a subset of the accepted input stamps.
/// Returns an empty series (and stats with everything rejected) if the options are
/// invalid or the spans differ in length beyond the shorter one.
VelocitySeries DifferentiatePositions(std::span<const core::Time> t_ns,
                                      std::span<const Eigen::Vector3d> p_Ss,
                                      const DifferentiationOptions& options = {},
                                      DifferentiationStats* stats = nullptr);
/// The same, with each position's stated covariance [m², in S]: the output also carries
/// each velocity's covariance Σ_i w_i² Σ_i [m²/s²], w_i the fit's linear weights (the
/// samples' errors taken as independent). cov_p_m2 shorter than the positions: none.
VelocitySeries DifferentiatePositions(std::span<const core::Time> t_ns,
                                      std::span<const Eigen::Vector3d> p_Ss,
                                      std::span<const Eigen::Matrix3d> cov_p_m2,
                                      const DifferentiationOptions& options = {},
                                      DifferentiationStats* stats = nullptr);

/// A body angular-rate stream, strictly increasing timestamps.
struct AngularRateSeries {
  std::vector<core::Time> t_ns;
  std::vector<Eigen::Vector3d> omega_radps;
};

/// Body angular rate omega_s_s (rad/s, in the mount frame s) from the attitudes q_Ss by
/// the same local fit applied to the rotation vectors Log(R_Ss(t_k)^T R_Ss(t_i)), whose
/// slope at t_k is the body rate (exact for a constant body rate). Quaternions are
/// normalised; non-finite or (near) zero ones are rejected. Requires |omega| half_window
/// well below pi.
AngularRateSeries DifferentiateOrientations(std::span<const core::Time> t_ns,
                                            std::span<const Eigen::Quaterniond> q_Ss,
                                            const DifferentiationOptions& options = {},
                                            DifferentiationStats* stats = nullptr);

}  // namespace tofu::estimator
