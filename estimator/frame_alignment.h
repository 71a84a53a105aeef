#pragma once
// Closed-form alignment of a sensor's reference frame A to the local frame L from pairs
// of positions: p_A,i ≈ T_AL p_L,i (Umeyama, "Least-squares estimation of transformation
// parameters between two point patterns", PAMI 1991, without scale). The seed paper's
// per-sensor graphs (Sec. 2.2, eq. 9) refine T_AL by optimisation; this is their
// initialisation and, until they exist, the alignment the consistency evaluation uses.
// Library code: Eigen only.

#include <optional>
#include <vector>

#include <Eigen/Core>
#include <Eigen/Geometry>

namespace tofu::estimator {

struct AlignmentResult {
  Eigen::Isometry3d T_AL = Eigen::Isometry3d::Identity();
  /// Singular values of the centred cross-covariance of the L points (descending, m^2
  /// per point): the spread of the motion along its principal directions. A rotation
  /// about a direction is unobservable when the points span less than a line across it:
  /// with motion along one line only (e.g. vertical flight), rotation about that line
  /// (yaw) is undetermined.
  Eigen::Vector3d spread_m2 = Eigen::Vector3d::Zero();
  /// Number of observable rotation directions: 3 when the points span a plane or more,
  /// 2 when they lie on a line, 0 when they collapse to a point.
  int observable_rotation_dofs = 0;
  double rms_residual_m = 0.0;
};

/// Best rigid T_AL with p_A ≈ T_AL p_L. nullopt with fewer than 3 pairs or a degenerate
/// (point-like) configuration. `min_spread_m2` sets when a principal direction counts as
/// spanned (variance of the positions along it).
std::optional<AlignmentResult> AlignPositions(const std::vector<Eigen::Vector3d>& p_L,
                                              const std::vector<Eigen::Vector3d>& p_A,
                                              double min_spread_m2 = 0.01);

/// Best T_AL that is a yaw about z and a translation (both frames levelled): the 2-D
/// closed form on the horizontal components, ψ = atan2(Σ a_i × b_i, Σ a_i · b_i) of the
/// centred horizontal positions a_i (L) and b_i (A), t = c_A − R_z(ψ) c_L. Defined for any
/// motion a line or more apart (a vertical line or a point gives ψ = 0, unobservable);
/// nullopt with fewer than 3 pairs.
std::optional<Eigen::Isometry3d> AlignPositionsLevel(const std::vector<Eigen::Vector3d>& p_L,
                                                     const std::vector<Eigen::Vector3d>& p_A);

}  // namespace tofu::estimator
