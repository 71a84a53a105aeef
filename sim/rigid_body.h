// Plain descriptions of the robot's rigid body that the world, the allocation, the
// controller and the trajectory all speak of: its mass properties, a wrench on it and a
// pose of B in W. Kept apart so that
// world.h needs neither the controller nor the trajectory generator.
#pragma once

#include <Eigen/Core>
#include <Eigen/Geometry>

#include "core/units.h"

namespace tofu::sim {

/// Mass properties the controller assumes (read from the model at start).
struct RigidBodyParams {
  double mass_kg = 4.5;
  Eigen::Matrix3d inertia_B_kgm2 = Eigen::Matrix3d::Identity() * 0.1;  ///< about CoM, in B
  double gravity_mps2 = core::kWorldGravity_mps2;
};

/// Body wrench about the centre of mass, in B.
struct Wrench {
  Eigen::Vector3d force_B_N = Eigen::Vector3d::Zero();
  Eigen::Vector3d torque_B_Nm = Eigen::Vector3d::Zero();
};

/// A pose of B in W used as waypoint or start.
struct Waypoint {
  Eigen::Vector3d p_WB = Eigen::Vector3d::Zero();
  Eigen::Quaterniond q_WB = Eigen::Quaterniond::Identity();
};

}  // namespace tofu::sim
