#pragma once
// Euclidean distance between convex MuJoCo primitives, for measuring how far the robot is
// from structure. MuJoCo 2.2 has no distance query (mj_geomDistance came with 3.x), and its
// contact functions are not distances outside contact: box-box with a margin, for one,
// reports separations decimetres below the true one.

#include <Eigen/Core>
#include <optional>

namespace tofu::sim {

/// A MuJoCo geom: type (mjtGeom), size as in mjModel::geom_size, pose in W.
struct ConvexGeom {
  int type = 0;
  Eigen::Vector3d size = Eigen::Vector3d::Zero();
  Eigen::Vector3d p_W = Eigen::Vector3d::Zero();
  Eigen::Matrix3d R_W = Eigen::Matrix3d::Identity();
};

/// GeomDistance's accuracy on separated geoms [m] (GJK's duality gap at termination).
inline constexpr double kGeomDistanceTolerance_m = 1e-6;

/// Distance between two geoms of types sphere, capsule, ellipsoid, cylinder or box (or one
/// plane, solid below its z = 0), within kGeomDistanceTolerance_m; 0 when they touch or
/// overlap (how deep is MuJoCo's contact business); nullopt for other types (meshes,
/// height fields).
std::optional<double> GeomDistance(const ConvexGeom& a, const ConvexGeom& b);

}  // namespace tofu::sim
