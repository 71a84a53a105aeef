#include "sim/geom_distance.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>

#include <Eigen/Dense>
#include <mujoco/mujoco.h>

namespace tofu::sim {
namespace {

// A geom as a convex core swept by a sphere (spheres and capsules are a point and a
// segment of radius r): GJK runs on the cores, whose supports are exact and cheap.
struct Core {
  const ConvexGeom* geom = nullptr;
  double radius_m = 0.0;
};

Core CoreOf(const ConvexGeom& g) {
  const bool swept = g.type == mjGEOM_SPHERE || g.type == mjGEOM_CAPSULE;
  return {&g, swept ? g.size.x() : 0.0};
}

// The core's farthest point along dir_W.
Eigen::Vector3d Support(const Core& core, const Eigen::Vector3d& dir_W) {
  const ConvexGeom& g = *core.geom;
  const Eigen::Vector3d d = g.R_W.transpose() * dir_W;
  Eigen::Vector3d s = Eigen::Vector3d::Zero();
  const auto sign = [](double x) { return x >= 0.0 ? 1.0 : -1.0; };
  switch (g.type) {
    case mjGEOM_SPHERE:
      break;
    case mjGEOM_CAPSULE:
      s.z() = sign(d.z()) * g.size.y();
      break;
    case mjGEOM_BOX:
      s = Eigen::Vector3d(sign(d.x()) * g.size.x(), sign(d.y()) * g.size.y(),
                          sign(d.z()) * g.size.z());
      break;
    case mjGEOM_CYLINDER: {
      const double radial = std::hypot(d.x(), d.y());
      if (radial > 0.0) s.head<2>() = g.size.x() * d.head<2>() / radial;
      s.z() = sign(d.z()) * g.size.y();
      break;
    }
    case mjGEOM_ELLIPSOID: {
      const Eigen::Vector3d a2d = g.size.cwiseProduct(g.size).cwiseProduct(d);
      const double norm = std::sqrt(a2d.dot(d));
      if (norm > 0.0) s = a2d / norm;
      break;
    }
    default:
      break;
  }
  return g.p_W + g.R_W * s;
}

// Closest point to the origin of the convex hull of `simplex` (1 to 4 points); the
// simplex shrinks to the points whose hull face holds it. Every face is tried: the closest
// point lies in the relative interior of one, where it is that face's affine projection.
Eigen::Vector3d ClosestToOrigin(std::array<Eigen::Vector3d, 4>& simplex, int& n) {
  double best_sq = std::numeric_limits<double>::infinity();
  Eigen::Vector3d best = simplex[0];
  int best_mask = 1;
  for (int mask = 1; mask < (1 << n); ++mask) {
    std::array<int, 4> idx{};
    int k = 0;
    for (int i = 0; i < n; ++i) {
      if (mask & (1 << i)) idx[k++] = i;
    }
    const Eigen::Vector3d& p0 = simplex[idx[0]];
    Eigen::Vector3d x = p0;
    if (k > 1) {
      Eigen::Matrix<double, 3, Eigen::Dynamic> E(3, k - 1);
      for (int j = 1; j < k; ++j) E.col(j - 1) = simplex[idx[j]] - p0;
      const Eigen::MatrixXd gram = E.transpose() * E;
      Eigen::FullPivLU<Eigen::MatrixXd> lu(gram);
      if (lu.rank() < k - 1) continue;  // degenerate face: its sub-faces cover it
      const Eigen::VectorXd mu = lu.solve(-E.transpose() * p0);
      if ((mu.array() < 0.0).any() || mu.sum() > 1.0) continue;  // projection outside
      x = p0 + E * mu;
    }
    const double sq = x.squaredNorm();
    if (sq < best_sq) {
      best_sq = sq;
      best = x;
      best_mask = mask;
    }
  }
  int m = 0;
  for (int i = 0; i < n; ++i) {
    if (best_mask & (1 << i)) simplex[m++] = simplex[i];
  }
  n = m;
  return best;
}

// GJK distance between two cores (0 if they overlap).
double CoreDistance(const Core& a, const Core& b) {
  Eigen::Vector3d v = a.geom->p_W - b.geom->p_W;
  if (v.squaredNorm() == 0.0) v = Eigen::Vector3d::UnitX();
  v = Support(a, -v) - Support(b, v);
  std::array<Eigen::Vector3d, 4> simplex{v};
  int n = 1;
  for (int iteration = 0; iteration < 128; ++iteration) {
    const double norm = v.norm();
    if (norm <= 1e-12) return 0.0;
    const Eigen::Vector3d w = Support(a, -v) - Support(b, v);
    // |v| is an upper bound of the distance, v.w/|v| a lower one.
    if (norm - v.dot(w) / norm <= kGeomDistanceTolerance_m) return norm;
    bool known = false;
    for (int i = 0; i < n; ++i) known |= (simplex[i] - w).squaredNorm() < 1e-24;
    if (known) return norm;  // no progress possible: v is as close as it gets
    simplex[n++] = w;
    v = ClosestToOrigin(simplex, n);
    if (n == 4) return 0.0;  // the origin is inside a tetrahedron
  }
  return v.norm();
}

bool Supported(int type) {
  return type == mjGEOM_SPHERE || type == mjGEOM_CAPSULE || type == mjGEOM_BOX ||
         type == mjGEOM_CYLINDER || type == mjGEOM_ELLIPSOID;
}

}  // namespace

std::optional<double> GeomDistance(const ConvexGeom& a, const ConvexGeom& b) {
  if (a.type == mjGEOM_PLANE || b.type == mjGEOM_PLANE) {
    const ConvexGeom& plane = a.type == mjGEOM_PLANE ? a : b;
    const ConvexGeom& other = a.type == mjGEOM_PLANE ? b : a;
    if (!Supported(other.type)) return std::nullopt;
    const Core core = CoreOf(other);
    const Eigen::Vector3d n_W = plane.R_W.col(2);
    const double height_m = n_W.dot(Support(core, -n_W) - plane.p_W) - core.radius_m;
    return std::max(height_m, 0.0);
  }
  if (!Supported(a.type) || !Supported(b.type)) return std::nullopt;
  const Core ca = CoreOf(a);
  const Core cb = CoreOf(b);
  return std::max(CoreDistance(ca, cb) - ca.radius_m - cb.radius_m, 0.0);
}

}  // namespace tofu::sim
