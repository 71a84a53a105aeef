#pragma once
// Per-sensor frame-alignment graph of the seed paper (Lanegger et al., Sec. 2.2,
// "Sensor Transform Estimation"): estimates T_AL, the pose of the local estimator frame L
// in a sensor's reference frame A (p_A = T_AL p_L), over a sliding window of pairs
//   (sensor position measurement p̄_A of its mount point s,
//    local estimate p_Ls = p_LI + R_LI p_Is of the same point at the measurement time)
// with the paper's residual r^t_AL (eq. 9), whitened by the pair's covariance:
//   r_i = S_i (p̄_A,i − (p_AL + R_AL p_Ls,i)),   S_iᵀ S_i = Σ_i⁻¹.
// Closed-form (Umeyama) initialisation, Levenberg-Marquardt refinement on [p_AL, q_AL]
// with a right perturbation of the rotation (MinimizeLm on the 6x6 normal equations,
// levenberg_marquardt.h; PositionAlignmentCost is the same residual as a Ceres cost, for
// Jacobian checks and comparisons), and an observability analysis of the rotation from
// the information matrix at the solution.
// Library code: Eigen, Ceres, core/ and std only.

#include <deque>
#include <optional>
#include <string>

#include <ceres/manifold.h>
#include <ceres/sized_cost_function.h>
#include <Eigen/Core>
#include <Eigen/Geometry>

#include "core/time.h"

namespace tofu::estimator {

struct AlignmentGraphOptions {
  core::Time window_ns = 20'000'000'000;        ///< sliding window of pairs (paper: 20 s)
  core::Time update_period_ns = 100'000'000;    ///< 10 Hz (paper)
  core::Time min_pair_spacing_ns = 50'000'000;  ///< pairs are decimated to at most 20 Hz
  int min_pairs = 10;                           ///< fewer pairs in the window: no solve (>= 3)
  double position_std_m = 0.02;  ///< used when a pair carries no covariance (zero matrix)
  /// A rotation direction counts as observable when the smallest eigenvalue of the
  /// information of T_AL restricted to it (per pair, i.e. normalised) exceeds this (see
  /// AlignmentEstimate::rotation_information_eigenvalues). Unit 1/rad² per pair.
  ///
  /// For isotropic noise σ the per-pair rotation information about a unit direction e is
  /// (after δp is marginalised) eᵀ(tr(C) I − C)e / σ², C the covariance (m²) of the
  /// p_Ls positions: the spread of the motion across e divided by σ². 100 rad⁻² is
  /// therefore a spread of 0.04 m² (20 cm standard deviation of the motion across the
  /// axis) at the default σ = 2 cm, or 9e-4 m² (3 cm) for a 3 mm sensor. It bounds the
  /// angle's standard deviation by 1/√(100 n) rad: 1.8° at min_pairs = 10, 0.29° with the
  /// full 400-pair window. Vertical flight with a few cm of horizontal hover jitter gives
  /// the yaw information ≈ (0.02 m)²/(0.02 m)² = 1 rad⁻² (unobservable); a few metres of
  /// horizontal motion (spread ~1 m² and more) give ≥ 2500 rad⁻² (observable).
  double min_rotation_information = 100.0;
  double huber_delta = 0.0;  ///< > 0: Huber loss on the standardised residual (unitless)
  int max_iterations = 10;   ///< Levenberg-Marquardt iterations per update
  /// Re-initialise from the closed form when the previous T_AL fits the current window
  /// with an rms residual above this (m): a jump of A (e.g. a GNSS re-fix), or yaw that
  /// was unobservable and became observable far from its guess. The refinement then
  /// starts from whichever of the two has the lower (robust) cost.
  double reinit_rms_residual_m = 0.25;
  /// > 0: both frames are levelled (z against gravity: L by the IMU's initialisation, A a
  /// GNSS's ENU or a levelled total station), so R_AL is a yaw up to L's tilt error, and a
  /// prior of this std (rad) holds the tilt (LevelPriorResidual); only yaw is then left
  /// to the pairs, which a straight level leg observes. 0 (default, the paper): every
  /// rotation from the pairs alone, so a straight leg leaves the roll about it free.
  double level_prior_std_rad = 0.0;

  /// True when the options are usable; otherwise false with the broken constraint in
  /// *why (if why is not null).
  bool IsValid(std::string* why = nullptr) const;
};

struct AlignmentPair {
  core::Time t_ns = 0;                                     ///< measurement time
  Eigen::Vector3d p_A_measured = Eigen::Vector3d::Zero();  ///< p̄_A of mount point s (m)
  /// Covariance of p_A_measured in A (m²). All zero: "none", position_std_m² I is used.
  Eigen::Matrix3d covariance_A = Eigen::Matrix3d::Zero();
  Eigen::Vector3d p_Ls_estimated = Eigen::Vector3d::Zero();  ///< local estimate of s in L (m)
};

struct AlignmentEstimate {
  bool valid = false;  ///< enough pairs and a solved problem (kept until the next solve)
  Eigen::Isometry3d T_AL = Eigen::Isometry3d::Identity();
  /// Covariance of [δp, δθ] (right perturbation of R_AL, δθ in L; δp additive, in A;
  /// m², rad²), the inverse of the information H = Σ w_i J_iᵀ J_i at the solution (w_i:
  /// Huber weight). The rotation block is inverted by eigen-directions with each
  /// variance capped at AlignmentGraph::kUnobservableVariance, so a direction without
  /// information (e.g. yaw in vertical flight) shows up as a huge, finite entry that
  /// propagates through the lever arm into the translation block. Weakly observable
  /// directions keep their honest (large) variance.
  Eigen::Matrix<double, 6, 6> covariance = Eigen::Matrix<double, 6, 6>::Zero();
  /// Ascending; information of δθ after marginalising δp, per pair (divided by `pairs`,
  /// directly comparable with min_rotation_information), 1/rad².
  Eigen::Vector3d rotation_information_eigenvalues = Eigen::Vector3d::Zero();
  /// Eigenvectors (columns, in L) matching rotation_information_eigenvalues.
  Eigen::Matrix3d rotation_information_directions = Eigen::Matrix3d::Identity();
  /// Directions with information per pair above min_rotation_information, or (with the
  /// level prior) held by the prior to its std or better.
  int observable_rotation_dofs = 0;
  /// Rotation about L's z axis (gravity) is observable: the marginal yaw information
  /// (yaw_information_per_pair) exceeds min_rotation_information.
  bool yaw_observable = false;
  /// Marginal information of rotation about L's z axis, per pair (1/rad²):
  /// 1 / (pairs · e_zᵀ Σ_θθ e_z), i.e. with roll and pitch estimated jointly, not held
  /// fixed (the conditional e_zᵀ H_rot e_z would call yaw observable for motion along a
  /// tilted line, where the unobservable rotation about the line carries yaw with it).
  double yaw_information_per_pair = 0.0;
  double rms_residual_m = 0;  ///< rms of |p̄_A − T_AL p_Ls| over the window (m)
  int pairs = 0;              ///< pairs in the solved window
  core::Time t_ns = 0;        ///< time of the last update
  bool frozen = false;        ///< T_AL is held fixed (SetFrozen)
};

/// Paper eq. (9) for one pair, whitened: r = S (p̄_A − (p_AL + R_AL p_Ls)), S = Σ^{-1/2}
/// (any S with SᵀS = Σ⁻¹). One parameter block of 7: [p_AL (3, m), q_AL (4, Eigen
/// x, y, z, w)], used with PoseManifold (estimator/local_factors.h: the same
/// [p, q] block and right perturbation as the local graph's poses). Analytic Jacobians.
class PositionAlignmentCost final : public ceres::SizedCostFunction<3, 7> {
 public:
  PositionAlignmentCost(const Eigen::Vector3d& p_A_measured, const Eigen::Vector3d& p_Ls,
                        const Eigen::Matrix3d& sqrt_information_A);

  /// Residual and the 3x7 Jacobian in the ambient parameters (row-major), as Ceres wants.
  bool Evaluate(double const* const* parameters, double* residuals,
                double** jacobians) const override;

  /// Jacobian in the tangent space [δp, δθ] of PoseManifold:
  ///   ∂r/∂δp = −S,   ∂r/∂δθ = S R_AL [p_Ls]×   (from R_AL Exp(δθ) p_Ls ≈ R_AL(p_Ls + δθ × p_Ls)).
  Eigen::Matrix<double, 3, 6> TangentJacobian(const Eigen::Isometry3d& T_AL) const;

  /// Whitened residual at T_AL.
  Eigen::Vector3d Residual(const Eigen::Isometry3d& T_AL) const;

 private:
  Eigen::Vector3d p_A_measured_;
  Eigen::Vector3d p_Ls_;
  Eigen::Matrix3d sqrt_information_A_;
};

/// The level prior: r = (e_x, e_y)ᵀ R_AL e_z / σ, the horizontal part in A of L's z axis,
/// zero when R_AL is a pure yaw (the flipped solution R_AL e_z = −e_z is excluded by the
/// closed-form guesses, which are level). Tangent Jacobian [δp, δθ] (right perturbation,
/// R_AL Exp(δθ) e_z ≈ R_AL (e_z + δθ × e_z)): ∂r/∂δp = 0, ∂r/∂δθ = −P_xy R_AL [e_z]× / σ;
/// yaw (δθ ∥ e_z) has no information from it.
Eigen::Vector2d LevelPriorResidual(const Eigen::Isometry3d& T_AL, double std_rad);
Eigen::Matrix<double, 2, 6> LevelPriorTangentJacobian(const Eigen::Isometry3d& T_AL,
                                                      double std_rad);

class AlignmentGraph {
 public:
  /// Variance (rad², and through the lever arm m²) reported for unobservable directions:
  /// huge but finite, so the covariance stays free of inf·0 = NaN.
  static constexpr double kUnobservableVariance = 1e12;

  /// Throws std::invalid_argument when options.IsValid() is false.
  explicit AlignmentGraph(AlignmentGraphOptions options = {});

  /// Adds a pair (rejects non-finite data, a covariance that is not positive definite, or
  /// non-increasing t_ns; returns false then and counts it in rejected_pairs()).
  /// A valid pair returns true but is not stored when it comes less than
  /// min_pair_spacing_ns after the last stored one (decimation) or while frozen (the local
  /// estimate is then built from this sensor's own positions: a pair would compare the
  /// sensor with itself and bias T_AL towards its current value, the circularity the
  /// paper avoids by stopping this graph). Pairs older than t_ns − window are dropped.
  bool AddPair(const AlignmentPair& pair);

  /// Runs the optimisation if update_period has passed since the last one (or none ran
  /// yet) and the graph is not frozen; drops pairs older than now_ns − window first.
  /// Returns true if it solved. With fewer than min_pairs pairs it does not solve and the
  /// previous estimate (if any) is kept unchanged: estimate().t_ns tells its age.
  bool Update(core::Time now_ns);

  /// Co-dependence rule of the paper: while this sensor's positions constrain the local
  /// graph, T_AL is held fixed: Update does nothing and pairs are not added (see
  /// AddPair). The pairs stored before freezing are kept and used after unfreezing (as
  /// long as they are inside the window).
  void SetFrozen(bool frozen);
  bool frozen() const { return frozen_; }

  const AlignmentEstimate& estimate() const { return estimate_; }
  /// The median of |p̄_A − T_AL p_Ls| (m) over the stored pairs at a given T_AL (e.g. an
  /// earlier one); nullopt with fewer than min_pairs pairs.
  std::optional<double> MedianResidualOf(const Eigen::Isometry3d& T_AL) const;
  int rejected_pairs() const { return rejected_pairs_; }
  int decimated_pairs() const { return decimated_pairs_; }           ///< valid, not stored
  int dropped_while_frozen_pairs() const { return dropped_frozen_pairs_; }  ///< valid, not stored
  int stored_pairs() const { return static_cast<int>(pairs_.size()); }
  const AlignmentGraphOptions& options() const { return options_; }

  /// Forget everything (e.g. after the local graph re-initialises): pairs, estimate and
  /// timing. The frozen flag (the owner's policy) and the counters (diagnostics of the
  /// stream) are kept.
  void Reset();

 private:
  struct StoredPair {
    core::Time t_ns = 0;
    Eigen::Vector3d p_A_measured;
    Eigen::Matrix3d sqrt_information_A;
    Eigen::Vector3d p_Ls;
  };

  class Problem;  // eq. (9) for MinimizeLm (alignment_graph.cc)

  void DropOlderThan(core::Time t_oldest_ns);
  bool Solve(core::Time now_ns);
  /// Sum of ρ(|r_i|²) at T_AL (ρ = Huber or identity), plus the level prior's |r|² when it
  /// is on, and the unweighted rms of the pairs (m).
  double RobustCost(const Eigen::Isometry3d& T_AL, double* rms_residual_m) const;
  /// Information, covariance and observability at the solution T_AL into estimate_.
  void AnalyseObservability(const Eigen::Isometry3d& T_AL);

  AlignmentGraphOptions options_;
  std::deque<StoredPair> pairs_;
  AlignmentEstimate estimate_;
  bool frozen_ = false;
  bool has_input_ = false;
  core::Time last_input_t_ns_ = 0;  ///< last valid pair (stored or not): monotonic check
  bool has_stored_ = false;
  core::Time last_stored_t_ns_ = 0;  ///< last stored pair: decimation
  bool has_solved_ = false;
  core::Time last_solve_ns_ = 0;
  int rejected_pairs_ = 0;
  int decimated_pairs_ = 0;
  int dropped_frozen_pairs_ = 0;
};

}  // namespace tofu::estimator
