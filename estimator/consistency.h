#pragma once
// Consistency metrics between two sensors' body velocities (Lanegger et al., "To Fuse or
// Not to Fuse", Sec. 2.1): MAE (eq. 2), Pearson correlation (eq. 3), Kullback-Leibler
// divergence between kernel density estimates (eq. 4) and the Cramér-von Mises distance
// (eq. 5), each per axis over a sliding window and summed over the three axes; and,
// beyond the paper, a normalised test that knows what each sensor states about itself
// (kNis below).
// Library code: no MuJoCo, no simulator, no I/O.

#include <optional>
#include <span>
#include <string>
#include <string_view>
#include <vector>

#include <Eigen/Core>

#include "core/time.h"

namespace tofu::estimator {

/// kNis (beyond the paper): the velocity difference of each pair of samples, normalised
/// by the two samples' stated covariances, Δvᵀ (Σ_a + Σ_b)⁻¹ Δv, summed over the window and
/// divided by the degrees of freedom it summed: 1 on average for two consistent streams
/// whatever their noise (a 1 cm total station and a 2 m GNSS alike), growing with a bias
/// as (bias/σ)². Directions in which the pair's standard deviation exceeds
/// ConsistencyOptions::unobserved_std_mps are left out: a sensor that does not observe a
/// direction (a LiDAR odometry's degenerate axis) neither votes there nor is voted down.
/// Its value is unitless; the other metrics' are m/s.
enum class ConsistencyMetric { kMae, kPcc, kKl, kCm, kNis };

/// "mae", "pcc", "kl", "cm", "nis".
std::string_view MetricName(ConsistencyMetric metric);
std::optional<ConsistencyMetric> MetricFromName(std::string_view name);

struct ConsistencyOptions {
  core::Time window_ns = 1'000'000'000;  ///< samples with t in (t_eval - window, t_eval]
  /// Centre and scale both samples of an axis by the pooled mean and standard deviation
  /// before comparing (the paper's comparison figure); off by default.
  bool standardize = false;
  /// KL only: Silverman's rule-of-thumb bandwidth h = 0.9 min(sd, IQR/1.34) n^(-1/5),
  /// multiplied by this factor (the paper notes KL's sensitivity to the bandwidth).
  double kl_bandwidth_scale = 1.0;
  /// Fewer samples than this in a window (either stream) makes the pair unavailable.
  int min_samples = 3;
  /// kNis only: a direction whose pair standard deviation exceeds this [m/s] is not
  /// observed by the pair and is left out of the statistic.
  double unobserved_std_mps = 1.0;
  /// kNis only: added in quadrature to the pair's standard deviation in every direction
  /// [m/s]: what no stated covariance includes (interpolation onto a common grid, lever
  /// arms, time stamps), and a guard against a sensor that claims to be exact.
  double std_floor_mps = 0.005;

  /// True when the options are usable; otherwise false with the broken constraint in
  /// *why (if why is not null).
  bool IsValid(std::string* why = nullptr) const;
};

// ---- one-dimensional distances between two samples ----

/// Cramér-von Mises distance of eq. (5), D = (2 ∫ (F_P(x) − F_Q(x))² dx)^½ between the
/// empirical CDFs, computed exactly from the merged sorted samples in O(n log n).
/// Both samples non-empty.
double CramerVonMisesDistance(std::span<const double> p, std::span<const double> q);

/// KL divergence D(P||Q) between Gaussian kernel density estimates of p and q, by
/// quadrature over the union of the samples' support (bandwidths per ConsistencyOptions).
double KlDivergence(std::span<const double> p, std::span<const double> q,
                    double bandwidth_scale = 1.0);

/// Mean absolute difference of paired samples (equal lengths).
double MeanAbsoluteError(std::span<const double> x, std::span<const double> y);

/// Pearson correlation coefficient of paired samples (equal lengths); 0 when either
/// sample has zero variance.
double PearsonCorrelation(std::span<const double> x, std::span<const double> y);

// ---- velocity streams ----

/// A velocity stream in a common frame, strictly increasing timestamps.
struct VelocitySeries {
  std::vector<core::Time> t_ns;
  std::vector<Eigen::Vector3d> v_mps;
  /// The stated covariance of each sample [m²/s²], or empty when the stream states none
  /// (kNis then takes it as exact; a non-finite matrix marks one sample as unknown).
  std::vector<Eigen::Matrix3d> cov_m2ps2;
};

/// Drops the first `count` samples of a series (its covariances too, when it has them).
void EraseFront(VelocitySeries& series, std::size_t count);

/// The metric between streams a and b over the window ending at t_eval_ns, per axis and
/// summed over x, y, z (kNis: over the observed directions, per degree of freedom). MAE,
/// PCC and NIS pair each sample of a with b linearly interpolated at its time (samples of
/// a outside b's span in the window are skipped; b's covariance is interpolated with the
/// same weights, which bounds the interpolated velocity's from above). kNis is unavailable
/// when no pair has an observed direction or neither stream states covariances. nullopt means
/// "unavailable": a stream has fewer than min_samples samples in the window. options must
/// be IsValid(): this function never throws, so it does not check them (ConsistencyMatrix
/// does, at construction).
std::optional<double> WindowConsistency(const VelocitySeries& a, const VelocitySeries& b,
                                        core::Time t_eval_ns, ConsistencyMetric metric,
                                        const ConsistencyOptions& options = {});

/// Beyond the paper: a test for a bias that a short window cannot see. A slow drift (a
/// total station creeping at 1 cm/s) hides in the scatter of every 1 s window, but it is
/// the same vector for seconds in a frame both streams share, while the streams' own
/// errors average out: b̂, the mean difference of the paired samples over a long window
/// (or, with estimate_rotation, the constant part of d_k = b + δ × v_k fitted by weighted
/// least squares, δ a small rotation between the streams' frames: an alignment's R_AL
/// error moves the difference with the velocity, a drift does not), tested against the
/// covariance the streams state for it,
///   χ² = b̂ᵀ Σ̄⁻¹ b̂,   b̂ = Σ_k A_k d_k,   Σ̄ = Σ̄_a + Σ̄_b + floor² I.
/// Each stream's Σ̄_s depends on what its errors are (MeanNoise): a twist's white errors
/// give Σ_k A_k Σ_k A_kᵀ · N / N_eff, N_eff = min(N, span / correlation_time + 1) (an
/// interpolated grid sample shares its error with its neighbours); the velocities of a
/// differentiated position stream telescope, Σ_k A_k ė_k summing by parts to its two
/// ends' position errors (2 P / span² for the mean). floor is what no stated covariance
/// includes. Under consistency χ² follows χ²(dof), dof the directions the pair observes
/// (a little less: the clipping below only shrinks).
struct MeanNoise {
  /// White errors: samples closer than this in time share theirs [ns].
  core::Time correlation_time_ns = 20'000'000;
  /// Velocities differentiated from positions with this white-noise covariance [m²], in
  /// the series' frame: the mean's error telescopes (see above).
  std::optional<Eigen::Matrix3d> position_covariance_m2;
};

struct MeanDifferenceOptions {
  MeanNoise a;
  MeanNoise b;
  /// Added in quadrature to the mean's standard deviation in every direction [m/s].
  double floor_std_mps = 0.001;
  /// Fit a small rotation δ between the two streams' frames beside the bias (for a pair
  /// with a velocity rotated through an estimated alignment), with this prior std [rad].
  bool estimate_rotation = false;
  double rotation_prior_std_rad = 0.035;
  /// A direction whose per-sample pair standard deviation exceeds this [m/s] is not
  /// observed and left out (ConsistencyOptions::unobserved_std_mps).
  double unobserved_std_mps = 1.0;
  /// Fewer paired samples: unavailable.
  int min_samples = 10;
  /// A sample's difference beyond this many of its standard deviations (Mahalanobis, by
  /// the two stated covariances plus sample_floor_std_mps² I) is shrunk to it before
  /// averaging: a gross error (an outlier, a step's edge) is the window metric's to judge,
  /// and must not hold the mean off for a whole window. A drift within the samples'
  /// scatter is untouched; symmetric noise stays unbiased.
  double clip_sigma = 3.0;
  double sample_floor_std_mps = 0.005;

  bool IsValid(std::string* why = nullptr) const;
};

struct MeanDifference {
  Eigen::Vector3d mean_mps = Eigen::Vector3d::Zero();          ///< b̂ (a − b)
  Eigen::Vector3d rotation_rad = Eigen::Vector3d::Zero();      ///< δ̂ (estimate_rotation)
  Eigen::Matrix3d covariance_m2ps2 = Eigen::Matrix3d::Zero();  ///< Σ̄
  double chi2 = 0.0;  ///< d̄ᵀ Σ̄⁻¹ d̄ over the observed directions
  int dof = 0;        ///< observed directions (0-3)
  int samples = 0;    ///< paired samples N
};

/// The mean-difference test of a and b over (t_from_ns, t_to_ns], pairing the samples
/// with equal stamps (two streams on one grid). nullopt with fewer than min_samples pairs,
/// when a stream states no covariances, or when no direction is observed.
std::optional<MeanDifference> WindowMeanDifference(const VelocitySeries& a,
                                                   const VelocitySeries& b,
                                                   core::Time t_from_ns, core::Time t_to_ns,
                                                   const MeanDifferenceOptions& options = {});

/// x with P(χ²(dof) > x) = upper_tail, for dof 1-3 (the test's observed directions) and
/// upper_tail in (0, 1); by bisection on the closed-form distribution functions.
double ChiSquareUpperQuantile(int dof, double upper_tail);

}  // namespace tofu::estimator
