// GeomDistance (GJK on MuJoCo primitives) against closed-form distances: face, edge and
// vertex contacts of boxes, curved sides of cylinders and capsules, planes and overlaps.

#include "sim/geom_distance.h"

#include <gtest/gtest.h>
#include <mujoco/mujoco.h>

#include <cmath>

#include <Eigen/Geometry>

namespace tofu::sim {
namespace {

ConvexGeom Geom(int type, const Eigen::Vector3d& size, const Eigen::Vector3d& p_W,
                const Eigen::Matrix3d& R_W = Eigen::Matrix3d::Identity()) {
  return {type, size, p_W, R_W};
}

Eigen::Matrix3d Rz(double angle_rad) {
  return Eigen::AngleAxisd(angle_rad, Eigen::Vector3d::UnitZ()).toRotationMatrix();
}

constexpr double kTol = 2 * kGeomDistanceTolerance_m;

TEST(GeomDistance, BoxesApartAlongADiagonalAreTheNormOfTheGaps) {
  const ConvexGeom a = Geom(mjGEOM_BOX, {1, 1, 1}, {0, 0, 0});
  const ConvexGeom b = Geom(mjGEOM_BOX, {0.5, 2, 1}, {3.5, 3.5, 2.5});
  // gaps: x 3.5-1-0.5 = 2, y 3.5-1-2 = 0.5, z 2.5-1-1 = 0.5
  EXPECT_NEAR(*GeomDistance(a, b), std::sqrt(4.0 + 0.25 + 0.25), kTol);
  EXPECT_NEAR(*GeomDistance(b, a), std::sqrt(4.0 + 0.25 + 0.25), kTol);
}

TEST(GeomDistance, RotatedBoxEdgeFacingABoxFace) {
  const ConvexGeom a = Geom(mjGEOM_BOX, {1, 1, 1}, {0, 0, 0}, Rz(M_PI / 4));
  const ConvexGeom b = Geom(mjGEOM_BOX, {1, 3, 3}, {5, 0.3, 0});
  EXPECT_NEAR(*GeomDistance(a, b), 5 - 1 - std::sqrt(2.0), kTol);
}

TEST(GeomDistance, SpheresAndCapsulesAreSweptPointsAndSegments) {
  const ConvexGeom sphere = Geom(mjGEOM_SPHERE, {0.14, 0, 0}, {0, 0, 2});
  const ConvexGeom box = Geom(mjGEOM_BOX, {6, 5, 0.1}, {0, 0, 4.1});
  EXPECT_NEAR(*GeomDistance(sphere, box), 4.0 - 2 - 0.14, kTol);
  // A capsule along x (MuJoCo capsules lie along their z) next to a vertical cylinder.
  const Eigen::Matrix3d z_to_x =
      Eigen::AngleAxisd(M_PI / 2, Eigen::Vector3d::UnitY()).toRotationMatrix();
  const ConvexGeom capsule = Geom(mjGEOM_CAPSULE, {0.1, 1, 0}, {3, 0, 1}, z_to_x);
  const ConvexGeom cylinder = Geom(mjGEOM_CYLINDER, {0.6, 4, 0}, {0, 0, 2});
  EXPECT_NEAR(*GeomDistance(capsule, cylinder), 3 - 1 - 0.6 - 0.1, kTol);
  // Its tip past the cylinder's top rim: rim (0.6, 0, 6) to the tip's axis (2, 0, 6.5).
  const ConvexGeom high = Geom(mjGEOM_CAPSULE, {0.1, 1, 0}, {3, 0, 6.5}, z_to_x);
  EXPECT_NEAR(*GeomDistance(high, cylinder), std::hypot(1.4, 0.5) - 0.1, kTol);
}

TEST(GeomDistance, CylinderSideFacingABoxCorner) {
  const ConvexGeom cylinder = Geom(mjGEOM_CYLINDER, {0.5, 1, 0}, {0, 0, 0});
  // Axis-aligned, its corner (1.5, 1.5) is nearest the axis; turned by 45 deg, a face.
  const ConvexGeom box = Geom(mjGEOM_BOX, {0.5, 0.5, 0.5}, {2, 2, 0});
  EXPECT_NEAR(*GeomDistance(cylinder, box), 1.5 * std::sqrt(2.0) - 0.5, kTol);
  const ConvexGeom turned = Geom(mjGEOM_BOX, {0.5, 0.5, 0.5}, {2, 2, 0}, Rz(M_PI / 4));
  EXPECT_NEAR(*GeomDistance(cylinder, turned), 2 * std::sqrt(2.0) - 0.5 - 0.5, kTol);
}

TEST(GeomDistance, PlanesAndEllipsoids) {
  const ConvexGeom floor = Geom(mjGEOM_PLANE, {5, 5, 0.1}, {0, 0, 0});
  const ConvexGeom ellipsoid = Geom(mjGEOM_ELLIPSOID, {0.3, 0.2, 0.1}, {0, 0, 1});
  EXPECT_NEAR(*GeomDistance(floor, ellipsoid), 0.9, kTol);
  const ConvexGeom tilted = Geom(mjGEOM_ELLIPSOID, {0.3, 0.2, 0.1}, {0, 0, 1},
                                 Eigen::AngleAxisd(M_PI / 2, Eigen::Vector3d::UnitY())
                                     .toRotationMatrix());
  EXPECT_NEAR(*GeomDistance(tilted, floor), 0.7, kTol);
  const ConvexGeom wall = Geom(mjGEOM_BOX, {0.1, 2, 2}, {1.4, 0, 1});
  EXPECT_NEAR(*GeomDistance(ellipsoid, wall), 1.4 - 0.1 - 0.3, kTol);
}

TEST(GeomDistance, TouchingOrOverlappingIsZeroAndMeshesAreUnknown) {
  const ConvexGeom a = Geom(mjGEOM_BOX, {1, 1, 1}, {0, 0, 0});
  EXPECT_EQ(*GeomDistance(a, Geom(mjGEOM_BOX, {1, 1, 1}, {1.5, 0.2, 0}, Rz(0.3))), 0.0);
  EXPECT_EQ(*GeomDistance(a, Geom(mjGEOM_SPHERE, {0.5, 0, 0}, {0, 0, 0})), 0.0);
  EXPECT_EQ(*GeomDistance(Geom(mjGEOM_PLANE, {1, 1, 1}, {0, 0, 0}), a), 0.0);
  EXPECT_FALSE(GeomDistance(a, Geom(mjGEOM_MESH, {1, 1, 1}, {5, 0, 0})).has_value());
}

}  // namespace
}  // namespace tofu::sim
