#pragma once
// The simulated world: a MuJoCo scene composed of models/common/materials.xml, a robot
// (models/robots/<robot>.xml) and a world (models/worlds/<world>.xml), stepped at the
// physics rate. MuJoCo stays behind this class: its load errors become InputErrors, its
// bad-state warnings (which would otherwise silently reset the simulation) become
// SimulationErrors.

#include <array>
#include <memory>
#include <optional>
#include <span>
#include <string>
#include <vector>

#include <Eigen/Core>
#include <Eigen/Geometry>

#include "core/option_fields.h"
#include "core/time.h"
#include "sim/allocation.h"
#include "sim/rigid_body.h"

struct mjModel_;
struct mjData_;

namespace tofu::sim {

/// Directory of the MJCF models: $TOFU_MODELS_DIR if set, else the source tree's.
std::string DefaultModelsDir();

struct WorldOptions {
  std::string models_dir = DefaultModelsDir();
  std::string world;           ///< models/worlds/<world>.xml
  std::string robot = "omav";  ///< models/robots/<robot>.xml
  double physics_rate_hz = 1000.0;
  /// Robot-to-structure distances are tracked up to this range [m] (measured with
  /// MuJoCo's narrow phase on demand, never a constraint).
  double distance_horizon_m = 1.0;

  /// Each option's key, unit and limits (models_dir, a path, is not among them): a
  /// scenario's `world`, `robot` and `physics.rate_hz` are read, written and checked
  /// through it; `distance_horizon_m` is not a scenario option.
  static std::span<const core::OptionField<WorldOptions>> Fields();
  /// The fields within their limits; otherwise false, *why = "<key>: <problem>".
  bool IsValid(std::string* why = nullptr) const;
};

/// A mount site on the robot: pose of the site frame s in B.
struct MountSite {
  std::string name;
  Eigen::Vector3d p_Bs = Eigen::Vector3d::Zero();
  Eigen::Quaterniond q_Bs = Eigen::Quaterniond::Identity();

  /// The mount as a pose of s in B (q_Bs normalised).
  Eigen::Isometry3d T_Bs() const;
};

/// What the harness and the controller need to know of the robot, read from the model.
struct RobotDescription {
  RigidBodyParams rigid_body;   ///< mass, inertia about CoM in B (zero tilt), gravity
  Eigen::Vector3d p_B_CoM = Eigen::Vector3d::Zero();
  AllocationParams allocation;  ///< arm geometry about the CoM, thrust and tilt limits
  double tilt_servo_max_rate_radps = 5.0;
  std::vector<MountSite> sites;  ///< imu, vio_camera, lidar, prism, gnss_antenna, tool_tip
  const MountSite* FindSite(const std::string& name) const;
  /// The site `name`; std::invalid_argument "<who>: the robot has no site '<name>'" when
  /// the model has none (a sensor model's constructor naming itself as `who`).
  const MountSite& Site(const std::string& name, const std::string& who) const;
};

/// Ground truth of the body frame B at one physics step.
struct TruthState {
  core::Time t_ns = 0;
  Eigen::Vector3d p_WB = Eigen::Vector3d::Zero();
  Eigen::Quaterniond q_WB = Eigen::Quaterniond::Identity();
  Eigen::Vector3d v_WB_W = Eigen::Vector3d::Zero();
  Eigen::Vector3d omega_WB_B = Eigen::Vector3d::Zero();
  Eigen::Vector3d a_WB_W = Eigen::Vector3d::Zero();      ///< d/dt v_WB_W
  Eigen::Vector3d alpha_WB_B = Eigen::Vector3d::Zero();  ///< d/dt omega_WB_B
  std::array<double, kArmCount> tilt_rad{};
};

/// Where a ray met a surface.
struct RayHit {
  double distance_m = 0.0;
  int geom = -1;  ///< MuJoCo geom id (World::GeomName names it)
  Eigen::Vector3d point_W = Eigen::Vector3d::Zero();
  Eigen::Vector3d normal_W = Eigen::Vector3d::Zero();  ///< unit, facing the ray origin
  bool textured = false;  ///< the geom's material has a texture (gives camera features)
  int group = 0;          ///< geom group (0 structure, 1 ground, 2/3 robot, 4 decoration)
};

/// Geom groups a ray sees, as a bit mask over groups (bit g = group g).
enum RayGroups : uint32_t {
  kRayScene = (1u << 0) | (1u << 1),            ///< structure and ground
  kRaySceneAndRobot = kRayScene | (1u << 3),    ///< plus the robot's visual shapes
};

/// A robot-structure contact with penetration (the ground under the feet excluded).
/// Geoms are MuJoCo ids; World::GeomName() names them.
struct Contact {
  int robot_geom = -1;
  int structure_geom = -1;
  double distance_m = 0.0;  ///< negative: penetration depth
};

/// Closest robot-structure pair within the distance horizon (ground excluded).
struct Proximity {
  double distance_m = 0.0;
  int robot_geom = -1;
  int structure_geom = -1;
};

class World;

/// Rays from one origin at one instant (a LiDAR scan): the hits CastRay gives, bit for
/// bit, without its pass over every geom per ray. The geoms the rays may meet are chosen
/// once and sorted by how near they can come to the origin; a ray skips the boxes and
/// bounding spheres it misses and stops at the first geom that cannot be nearer than its
/// hit. Made by World::RaysFrom; valid until the world steps.
class RayFan {
 public:
  /// As World::CastRay(origin, direction_W, groups) for the fan's origin and groups.
  std::optional<RayHit> Cast(const Eigen::Vector3d& direction_W) const;

 private:
  friend class World;
  // A geom the fan's rays may meet, with what rules most of them out cheaply.
  enum class Bound { kNone, kSphere, kBox };
  static Bound BoundOf(int geom_type);
  struct Candidate {
    int geom = -1;
    Bound bound = Bound::kNone;  ///< planes and height fields: none, every ray is tested
    double lower_bound_m = 0.0;  ///< no hit on it is nearer than this
    Eigen::Vector3d center_from_origin_W = Eigen::Vector3d::Zero();  ///< kSphere
    double squared_center_distance_m2 = 0.0;                         ///< kSphere
    double squared_radius_m2 = 0.0;                                  ///< kSphere
    Eigen::Matrix3d R_WG = Eigen::Matrix3d::Identity();              ///< kBox
    Eigen::Vector3d origin_G = Eigen::Vector3d::Zero();              ///< kBox
    Eigen::Vector3d half_size_m = Eigen::Vector3d::Zero();  ///< kBox, grown by the slack
  };
  const World* world_ = nullptr;
  const mjModel_* model_ = nullptr;  ///< the world's model the rays are cast in
  const mjData_* data_ = nullptr;
  bool full_ = false;  ///< in the complete scene (the robot's visual shapes)
  Eigen::Vector3d origin_W_ = Eigen::Vector3d::Zero();
  std::vector<Candidate> candidates_;  ///< by lower bound, then geom id
};

class World {
 public:
  /// Loads and compiles the scene. Throws core::InputError when a model is missing or
  /// MuJoCo rejects it (its message included), or the robot lacks a required element.
  explicit World(const WorldOptions& options);
  ~World();
  World(const World&) = delete;
  World& operator=(const World&) = delete;

  const RobotDescription& robot() const;
  const WorldOptions& options() const;

  /// Places the robot at `pose` at rest, time 0, with rotors spun up and tilts set to
  /// the hover allocation of that attitude (no start-up transient).
  void Reset(const Waypoint& pose);

  /// Actuator set-points; tilt targets reach the servos through the slew-rate limit.
  void SetCommand(const ActuatorCommand& command);

  /// External force on the robot's centre of mass in W [N], held until changed.
  void SetExternalForce_W(const Eigen::Vector3d& force_W);

  /// Advances the physics by one step. Returns the truth at the start of the step
  /// (state and the acceleration that the step integrates). Throws SimulationError on
  /// MuJoCo's bad qpos/qvel/qacc warnings or a non-finite state.
  const TruthState& Step();

  /// Ground truth now (state only; acceleration is that of the previous step).
  TruthState Truth() const;
  core::Time time_ns() const;
  core::Time timestep_ns() const;

  /// Robot-structure contacts with penetration after the last step. The reference
  /// stays valid until the next call (no allocation per step).
  const std::vector<Contact>& Contacts() const;
  /// Closest robot-structure pair (group 0) at the last step's collision detection, if
  /// within the horizon: exact while apart (spheres in closed form, other proxies by GJK to
  /// 1 um), MuJoCo's contact depth when touching. Computed on the first call after a step.
  std::optional<Proximity> ClosestStructure() const;

  /// Distance along a ray to the first structure or ground surface (robot ignored).
  std::optional<double> RayDistance(const Eigen::Vector3d& origin_W,
                                    const Eigen::Vector3d& direction_W) const;

  /// First surface along a ray (direction need not be normalised) among the geom
  /// groups of `groups`, with its normal and material; nullopt if nothing is hit.
  std::optional<RayHit> CastRay(const Eigen::Vector3d& origin_W,
                                const Eigen::Vector3d& direction_W,
                                uint32_t groups = kRayScene) const;

  /// Rays from one origin now, among the geom groups of `groups` (see RayFan).
  RayFan RaysFrom(const Eigen::Vector3d& origin_W, uint32_t groups = kRayScene) const;

  /// Actual (motor-filtered) rotor thrusts [N], arm-major: [arm0 top, arm0 bottom, ...].
  std::array<double, kArmCount * kRotorsPerArm> RotorThrusts_N() const;

  /// Name of a geom, or "geom<id>" when it has none.
  std::string GeomName(int geom_id) const;

  /// Pose of a site (robot mount or world site, e.g. "station_tripod") in W now.
  Eigen::Isometry3d SitePose_W(const std::string& site) const;

  /// Raw MuJoCo access for sim-internal consumers (sensor models, renderer): the complete
  /// scene, robot visuals included, at the physics state (kinematics of the last step's
  /// start, as every query here). Geom ids in this API are this model's.
  const mjModel_* model() const;
  const mjData_* data() const;
  /// The model MuJoCo steps: the scene without the robot's visual-only bodies (the same
  /// physics; its geom ids differ from model()'s). For benchmarks and tests.
  const mjModel_* physics_model() const;
  const mjData_* physics_data() const;

 private:
  friend class RayFan;
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace tofu::sim
