#pragma once
// Reference trajectories of the body frame B in the world W: smooth (continuous
// velocity, acceleration and jerk), time-parametrised by dynamic limits, built from a
// sequence of primitives. Each primitive starts where the previous one ended, at rest,
// so the concatenation is smooth too.

#include <functional>
#include <memory>
#include <optional>
#include <string>
#include <variant>
#include <vector>

#include <Eigen/Core>
#include <Eigen/Geometry>

#include "core/time.h"
#include "sim/rigid_body.h"

namespace tofu::sim {

/// Desired state of the body frame B at one instant.
struct Reference {
  Eigen::Vector3d p_WB = Eigen::Vector3d::Zero();      ///< position [m]
  Eigen::Vector3d v_WB_W = Eigen::Vector3d::Zero();    ///< velocity in W [m/s]
  Eigen::Vector3d a_WB_W = Eigen::Vector3d::Zero();    ///< acceleration in W [m/s^2]
  Eigen::Vector3d j_WB_W = Eigen::Vector3d::Zero();    ///< jerk in W [m/s^3]
  Eigen::Quaterniond q_WB = Eigen::Quaterniond::Identity();
  Eigen::Vector3d omega_WB_B = Eigen::Vector3d::Zero();  ///< angular rate in B [rad/s]
  Eigen::Vector3d alpha_WB_B = Eigen::Vector3d::Zero();  ///< angular accel. in B [rad/s^2]
};


/// Dynamic limits that set the time parametrisation of every primitive.
struct DynamicLimits {
  double max_speed_mps = 1.0;
  double max_acceleration_mps2 = 1.0;
  double max_angular_rate_radps = 0.8;
  double max_angular_acceleration_radps2 = 1.5;
};

// ---- primitives (plain option structs, filled from YAML by the harness) ----

/// Hold the current pose for a duration.
struct HoverSpec {
  double duration_s = 1.0;
};

/// Minimum-snap polynomial through waypoints (rest at the first and last), attitude
/// interpolated on SO(3) between consecutive waypoints.
struct WaypointsSpec {
  std::vector<Waypoint> waypoints;  ///< excluding the current pose, at least one
};

/// Straight line to a point, optionally rotating to a new attitude on the way.
struct LineSpec {
  Eigen::Vector3d to_W = Eigen::Vector3d::Zero();
  std::optional<Eigen::Quaterniond> q_WB;  ///< attitude at the end; unset = keep
};

/// Horizontal circle around a centre, attitude held constant. The robot first
/// transfers to the circle (radially) if it is not on it.
struct CircleSpec {
  Eigen::Vector3d center_W = Eigen::Vector3d::Zero();
  double radius_m = 1.0;
  double speed_mps = 0.5;  ///< cruise speed along the circle
  double laps = 1.0;
  bool clockwise = false;  ///< seen from above (+z)
};

/// Horizontal figure-eight (lemniscate of Gerono) centred at center_W:
/// x = half_length * sin(phi), y = half_width * sin(phi) * cos(phi), attitude constant.
struct FigureEightSpec {
  Eigen::Vector3d center_W = Eigen::Vector3d::Zero();
  double half_length_m = 1.5;
  double half_width_m = 1.0;
  double speed_mps = 1.0;  ///< peak speed along the curve
  double laps = 1.0;
};

/// Move along direction_W until the tool tip is standoff_m from the first surface hit
/// by a ray from the tool tip along direction_W; attitude held.
struct ApproachSpec {
  Eigen::Vector3d direction_W = Eigen::Vector3d::UnitX();  ///< normalised on build
  double standoff_m = 0.3;
  double speed_mps = 0.3;  ///< peak approach speed
};

using PrimitiveSpec =
    std::variant<HoverSpec, WaypointsSpec, LineSpec, CircleSpec, FigureEightSpec, ApproachSpec>;

/// A whole mission: start pose, limits and the primitives in order.
struct TrajectorySpec {
  Waypoint start;
  DynamicLimits limits;
  std::vector<PrimitiveSpec> segments;
};

/// Distance [m] from origin_W along unit direction_W to the first structure surface,
/// or nullopt if the ray hits nothing. The simulator's world answers it with ray casts.
using SurfaceDistanceQuery =
    std::function<std::optional<double>(const Eigen::Vector3d& origin_W,
                                        const Eigen::Vector3d& direction_W)>;

/// What the builder needs to know of the robot.
struct TrajectoryContext {
  Eigen::Vector3d p_B_tool = Eigen::Vector3d::Zero();  ///< tool tip in B [m]
  SurfaceDistanceQuery surface_distance;               ///< required by ApproachSpec
};

/// Per-segment bookkeeping for reports (e.g. the standoff reached by an approach).
struct SegmentInfo {
  std::string kind;       ///< "hover", "waypoints", "line", "circle", "figure_eight", "approach"
  core::Time start_ns = 0;
  core::Time end_ns = 0;
  std::optional<double> approach_target_distance_m;  ///< approach: surface distance at start
  double approach_standoff_m = 0.0;
  Eigen::Vector3d approach_direction_W = Eigen::Vector3d::Zero();
};

/// A time-parametrised reference. Sample() is defined for every t_ns >= 0; after the
/// end it returns the final pose at rest.
class Trajectory {
 public:
  virtual ~Trajectory() = default;
  virtual core::Time duration_ns() const = 0;
  virtual Reference Sample(core::Time t_ns) const = 0;
  virtual const std::vector<SegmentInfo>& segments() const = 0;
};

/// Builds the trajectory of a spec. Throws std::invalid_argument naming the segment
/// index and the violated constraint (e.g. a circle whose centripetal acceleration
/// exceeds max_acceleration_mps2, an approach whose ray hits nothing).
std::unique_ptr<Trajectory> BuildTrajectory(const TrajectorySpec& spec,
                                            const TrajectoryContext& context);

}  // namespace tofu::sim
