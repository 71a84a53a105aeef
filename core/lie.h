#pragma once
// SO(3) helpers on Eigen types. Conventions (DESIGN.md): R_AB maps B coordinates to A,
// quaternions are Hamilton, unit, and stored with w >= 0.

#include <Eigen/Core>
#include <Eigen/Geometry>

namespace tofu::core {

/// Skew-symmetric matrix [v]x such that [v]x * u = v x u.
Eigen::Matrix3d Hat(const Eigen::Vector3d& v);

/// Inverse of Hat for a (near) skew-symmetric matrix: takes the antisymmetric part.
Eigen::Vector3d Vee(const Eigen::Matrix3d& m);

/// Exponential map so(3) -> SO(3) (Rodrigues), accurate near zero.
Eigen::Matrix3d ExpSO3(const Eigen::Vector3d& rotation_vector);

/// Logarithm SO(3) -> so(3), angle in [0, pi], accurate near zero and near pi.
Eigen::Vector3d LogSO3(const Eigen::Matrix3d& R);

/// Unit quaternion from a rotation vector.
Eigen::Quaterniond ExpQuat(const Eigen::Vector3d& rotation_vector);

/// Rotation vector of a unit quaternion (shortest rotation, angle in [0, pi]).
Eigen::Vector3d LogQuat(const Eigen::Quaterniond& q);

/// The quaternion with w >= 0 representing the same rotation (storage convention).
Eigen::Quaterniond CanonicalQuat(const Eigen::Quaterniond& q);

/// Rotation from roll, pitch, yaw in radians, R = Rz(yaw) * Ry(pitch) * Rx(roll).
Eigen::Matrix3d RotationFromRollPitchYaw(double roll_rad, double pitch_rad, double yaw_rad);

/// Angle in radians of the rotation R_a^T R_b, in [0, pi].
double RotationAngleBetween(const Eigen::Matrix3d& R_a, const Eigen::Matrix3d& R_b);

/// Yaw (rad, about z) of the rotation about z nearest to R in the Frobenius norm:
/// atan2(R10 - R01, R00 + R11). For two gravity-aligned frames, their relative heading.
double YawOfNearestZRotation(const Eigen::Matrix3d& R);

/// The gravity-aligned registration T_AB (a rotation about z and a translation) that maps
/// the pose X as B knows it onto the pose X as A knows it: yaw from R_AX R_BXᵀ (nearest z
/// rotation), translation so that T_AB p_BX = p_AX exactly. Two frames that share the
/// gravity direction (a VIO's local frame, a surveyed mission frame) differ by such a
/// transform; "the robot is here" is T_AX.
Eigen::Isometry3d YawPositionRegistration(const Eigen::Isometry3d& T_AX,
                                          const Eigen::Isometry3d& T_BX);

/// Right Jacobian of SO(3): Exp(φ + δφ) ≈ Exp(φ) Exp(Jr(φ) δφ) (Forster et al. 2016, eq. 8).
Eigen::Matrix3d RightJacobianSO3(const Eigen::Vector3d& phi);
/// Its inverse: Log(Exp(φ) Exp(δφ)) ≈ φ + Jr⁻¹(φ) δφ (Forster et al. 2016, eq. 9).
Eigen::Matrix3d InverseRightJacobianSO3(const Eigen::Vector3d& phi);

}  // namespace tofu::core
