// The simulated world (sim::World) on the real models: every world loads with the OMAV,
// the robot description read from the MJCF is physically sensible, ray casts see the
// structure and never the robot, Reset/Step keep an exact integer clock and a resting
// hover, MuJoCo's bad states surface as SimulationErrors instead of silent resets, the
// stepped model is the scene without the robot's visual-only bodies, the contact gate never
// hides a contact and ClosestStructure is the exact minimum over all robot-structure pairs.

#include "sim/world.h"

#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <numbers>
#include <set>
#include <string>
#include <vector>

#include <Eigen/Eigenvalues>
#include <mujoco/mujoco.h>
#include <random>

#include "core/error.h"
#include "core/lie.h"
#include "sim/allocation.h"
#include "sim/geom_distance.h"
#include "tests/test_support.h"

namespace tofu::sim {
namespace {


constexpr double kRadPerDeg = std::numbers::pi / 180.0;

const char* const kWorlds[] = {"indoor_arena", "inspection_wall", "building_window", "bridge"};
const char* const kMountSites[] = {"imu",   "vio_camera",   "lidar",
                                   "prism", "gnss_antenna", "tool_tip"};

WorldOptions OptionsFor(const std::string& world, double physics_rate_hz = 1000.0) {
  WorldOptions options;
  options.world = world;
  options.physics_rate_hz = physics_rate_hz;
  return options;
}

Waypoint Pose(const Eigen::Vector3d& p_WB, double roll_deg = 0.0, double pitch_deg = 0.0,
              double yaw_deg = 0.0) {
  return Waypoint{p_WB, Eigen::Quaterniond(core::RotationFromRollPitchYaw(
                            roll_deg * kRadPerDeg, pitch_deg * kRadPerDeg, yaw_deg * kRadPerDeg))};
}

// The open-loop command that holds `q_WB` still: gravity compensation in B, no torque.
ActuatorCommand HoverCommand(const World& world, const Eigen::Quaterniond& q_WB,
                             const std::array<double, kArmCount>& tilt_rad) {
  const RigidBodyParams& rb = world.robot().rigid_body;
  const Wrench hover{q_WB.toRotationMatrix().transpose() *
                         Eigen::Vector3d(0.0, 0.0, rb.mass_kg * rb.gravity_mps2),
                     Eigen::Vector3d::Zero()};
  const AllocationResult a = Allocator(world.robot().allocation).Allocate(hover, tilt_rad);
  EXPECT_FALSE(a.saturated);
  return a.command;
}

// ---- models ----

TEST(World, EveryWorldLoadsWithThePhysicallySensibleOmav) {
  for (const char* name : kWorlds) {
    SCOPED_TRACE(name);
    const World world(OptionsFor(name));
    const RobotDescription& robot = world.robot();

    EXPECT_GE(robot.rigid_body.mass_kg, 4.0);
    EXPECT_LE(robot.rigid_body.mass_kg, 5.0);
    EXPECT_NEAR(robot.rigid_body.gravity_mps2, 9.81, 0.01);

    const Eigen::Matrix3d& J = robot.rigid_body.inertia_B_kgm2;
    EXPECT_LT((J - J.transpose()).norm(), 1e-12) << J;
    const Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> eig(J);
    EXPECT_GT(eig.eigenvalues().minCoeff(), 1e-3) << J;
    // A rigid body's principal moments obey the triangle inequality.
    const Eigen::Vector3d m = eig.eigenvalues();
    EXPECT_LE(m(2), m(0) + m(1) + 1e-12);

    // Mount sites: all six, each at its own non-zero lever arm.
    ASSERT_EQ(robot.sites.size(), 6u);
    int rotated = 0;
    for (const char* site_name : kMountSites) {
      SCOPED_TRACE(site_name);
      const MountSite* site = robot.FindSite(site_name);
      ASSERT_NE(site, nullptr);
      EXPECT_GT(site->p_Bs.norm(), 0.01);
      EXPECT_NEAR(site->q_Bs.norm(), 1.0, 1e-9);
      EXPECT_GE(site->q_Bs.w(), 0.0);
      if (site->q_Bs.angularDistance(Eigen::Quaterniond::Identity()) > 1e-3) ++rotated;
    }
    EXPECT_GE(rotated, 2);
    for (size_t i = 0; i < robot.sites.size(); ++i) {
      for (size_t j = i + 1; j < robot.sites.size(); ++j) {
        EXPECT_GT((robot.sites[i].p_Bs - robot.sites[j].p_Bs).norm(), 0.01)
            << robot.sites[i].name << " and " << robot.sites[j].name << " share a lever arm";
      }
    }
    EXPECT_EQ(robot.FindSite("no_such_site"), nullptr);

    // Six tiltable arms: unit axes, hinges 0.35 m from the CoM, 60 deg apart.
    for (int k = 0; k < kArmCount; ++k) {
      SCOPED_TRACE(k);
      const ArmGeometry& arm = robot.allocation.arms[k];
      EXPECT_NEAR(arm.tilt_axis_B.norm(), 1.0, 1e-9);
      EXPECT_NEAR(arm.p_CoM_hinge_B.norm(), 0.35, 0.01);
      // The tilt axis points outward along the arm, in the body's x-y plane.
      EXPECT_GT(arm.tilt_axis_B.dot(arm.p_CoM_hinge_B.normalized()), 0.99);
      const double yaw = std::atan2(arm.p_CoM_hinge_B.y(), arm.p_CoM_hinge_B.x());
      const double expected_yaw = std::remainder(k * std::numbers::pi / 3.0, 2 * std::numbers::pi);
      EXPECT_NEAR(std::remainder(yaw - expected_yaw, 2 * std::numbers::pi), 0.0, 1e-6);
    }
    EXPECT_LT(robot.allocation.rotor_min_thrust_N, robot.allocation.rotor_max_thrust_N);
    EXPECT_GT(robot.allocation.rotor_max_thrust_N * 2 * kArmCount,
              robot.rigid_body.mass_kg * robot.rigid_body.gravity_mps2);
  }
}

TEST(World, UnknownWorldIsAnInputErrorListingTheAvailableWorlds) {
  try {
    const World world(OptionsFor("nowhere"));
    FAIL() << "expected an InputError";
  } catch (const core::InputError& e) {
    EXPECT_EQ(e.key_path(), "world");
    EXPECT_CONTAINS(e.what(), "nowhere");
    for (const char* name : kWorlds) EXPECT_CONTAINS(e.message(), name);
  }
}

TEST(World, UnknownRobotIsAnInputErrorListingTheAvailableRobots) {
  WorldOptions options = OptionsFor("indoor_arena");
  options.robot = "quadcopter";
  try {
    const World world(options);
    FAIL() << "expected an InputError";
  } catch (const core::InputError& e) {
    EXPECT_EQ(e.key_path(), "robot");
    EXPECT_CONTAINS(e.message(), "omav");
  }
}

// ---- ray casts ----

TEST(WorldRay, HitsTheFacadeAndItsTexturedSkinAndMissesTheOpenSky) {
  const World world(OptionsFor("inspection_wall"));
  // Below z = 3 the 2 mm textured band stands in front of the facade (front at 4.998).
  const std::optional<double> band = world.RayDistance({0, 0, 2}, {1, 0, 0});
  ASSERT_TRUE(band.has_value());
  EXPECT_NEAR(*band, 4.998, 1e-6);
  // Above it, the plain facade face at x = 5.
  const std::optional<double> facade = world.RayDistance({0, 0, 5}, {1, 0, 0});
  ASSERT_TRUE(facade.has_value());
  EXPECT_NEAR(*facade, 5.0, 1e-6);
  // The direction need not be normalised; the distance is along the unit ray.
  const std::optional<double> scaled = world.RayDistance({0, 0, 5}, {3, 0, 0});
  ASSERT_TRUE(scaled.has_value());
  EXPECT_NEAR(*scaled, 5.0, 1e-6);
  // Oblique: 45 deg in the x-y plane travels sqrt(2) times further.
  const std::optional<double> oblique = world.RayDistance({0, 0, 5}, {1, 1, 0});
  ASSERT_TRUE(oblique.has_value());
  EXPECT_NEAR(*oblique, 5.0 * std::sqrt(2.0), 1e-6);
  // Down to the ground (group 1 counts as a surface), up into the open sky, away.
  const std::optional<double> ground = world.RayDistance({0, 0, 2}, {0, 0, -1});
  ASSERT_TRUE(ground.has_value());
  EXPECT_NEAR(*ground, 2.0, 1e-6);
  EXPECT_FALSE(world.RayDistance({0, 0, 2}, {0, 0, 1}).has_value());
  EXPECT_FALSE(world.RayDistance({0, 0, 2}, {-1, 0, 1}).has_value());
}

TEST(WorldRay, IgnoresTheRobotItself) {
  World world(OptionsFor("inspection_wall"));
  // The ray starts inside the hub box and passes through rotor_guard_1 (0.35 m ahead).
  world.Reset(Pose({0, 0, 2}));
  ASSERT_NEAR((world.SitePose_W("tool_tip").translation() - Eigen::Vector3d(0.6, 0, 1.82)).norm(),
              0.0, 1e-9);
  const std::optional<double> ahead = world.RayDistance({0, 0, 2}, {1, 0, 0});
  ASSERT_TRUE(ahead.has_value());
  EXPECT_NEAR(*ahead, 4.998, 1e-6);
  const std::optional<double> down = world.RayDistance({0, 0, 2}, {0, 0, -1});
  ASSERT_TRUE(down.has_value());
  EXPECT_NEAR(*down, 2.0, 1e-6);
  // Along the tool from its root, through the tool capsule, to the wall.
  const std::optional<double> tool = world.RayDistance({0.1, 0, 1.82}, {1, 0, 0});
  ASSERT_TRUE(tool.has_value());
  EXPECT_NEAR(*tool, 4.898, 1e-6);
}

// ---- reset, clock and hover ----

TEST(WorldStep, ResetPlacesTheRobotAtRestAtTheGivenPose) {
  World world(OptionsFor("indoor_arena"));
  for (const Waypoint& pose : {Pose({1.0, -2.0, 1.5}), Pose({-0.5, 0.5, 2.0}, 30, -10, 120)}) {
    world.Reset(pose);
    const TruthState truth = world.Truth();
    EXPECT_EQ(truth.t_ns, 0);
    EXPECT_EQ(world.time_ns(), 0);
    EXPECT_LT((truth.p_WB - pose.p_WB).norm(), 1e-12);
    EXPECT_LT(truth.q_WB.angularDistance(pose.q_WB), 1e-9);
    EXPECT_EQ(truth.v_WB_W, Eigen::Vector3d::Zero());
    EXPECT_EQ(truth.omega_WB_B, Eigen::Vector3d::Zero());
  }
}

TEST(WorldStep, TimeAdvancesByExactlyOneTimestepPerStep) {
  for (const double rate_hz : {1000.0, 3000.0, 400.0}) {
    SCOPED_TRACE(rate_hz);
    World world(OptionsFor("indoor_arena", rate_hz));
    const core::Time dt = world.timestep_ns();
    EXPECT_EQ(dt, core::PeriodFromRate(rate_hz));
    world.Reset(Pose({0, 0, 1.5}));
    for (int k = 0; k < 300; ++k) {
      const core::Time before = world.time_ns();
      ASSERT_EQ(before, k * dt);
      const TruthState& truth = world.Step();
      // Step returns the state at the start of the step it integrated.
      ASSERT_EQ(truth.t_ns, before);
      ASSERT_EQ(world.time_ns(), before + dt);
      ASSERT_EQ(world.Truth().t_ns, before + dt);
    }
    // Reset starts the clock again.
    world.Reset(Pose({0, 0, 1.5}));
    EXPECT_EQ(world.time_ns(), 0);
  }
}

TEST(WorldStep, HoverCommandHoldsTheRobotStillLevelAndTilted) {
  World world(OptionsFor("indoor_arena"));
  for (const Waypoint& pose : {Pose({0, 0, 1.5}), Pose({1, 1, 2.0}, 30, 0, 0),
                               Pose({-1, 0, 2.0}, 0, -45, 60)}) {
    world.Reset(pose);
    const ActuatorCommand command = HoverCommand(world, pose.q_WB, world.Truth().tilt_rad);
    world.SetCommand(command);
    // The model's hover and the allocator's agree: Reset already set these tilts.
    for (int k = 0; k < kArmCount; ++k) {
      EXPECT_NEAR(world.Truth().tilt_rad[k], command.tilt_rad[k], 1e-9);
    }
    for (int k = 0; k < 500; ++k) world.Step();  // 0.5 s open loop
    const TruthState truth = world.Truth();
    EXPECT_EQ(truth.t_ns, 500 * world.timestep_ns());
    EXPECT_LT((truth.p_WB - pose.p_WB).norm(), 2e-3) << truth.p_WB.transpose();
    EXPECT_LT(truth.q_WB.angularDistance(pose.q_WB), 0.2 * kRadPerDeg);
    EXPECT_LT(truth.v_WB_W.norm(), 1e-2);
    EXPECT_LT(truth.omega_WB_B.norm(), 1e-2);
    // Gravity is balanced: the acceleration of the last step is (almost) zero.
    EXPECT_LT(truth.a_WB_W.norm(), 0.05);
  }
}

TEST(WorldStep, WithoutThrustTheRobotFallsAtG) {
  World world(OptionsFor("indoor_arena"));
  world.Reset(Pose({0, 0, 3.0}));
  ActuatorCommand off;
  off.tilt_rad = world.Truth().tilt_rad;
  world.SetCommand(off);
  // Motors spin down with a 40 ms time constant; after 0.3 s the robot is in free fall.
  for (int k = 0; k < 300; ++k) world.Step();
  EXPECT_NEAR(world.Step().a_WB_W.z(), -9.81, 0.05);
  EXPECT_LT(world.Truth().p_WB.z(), 3.0 - 0.1);
}

TEST(WorldStep, ExternalForceAcceleratesTheRobot) {
  World world(OptionsFor("indoor_arena"));
  world.Reset(Pose({0, 0, 1.5}));
  world.SetCommand(HoverCommand(world, Eigen::Quaterniond::Identity(), world.Truth().tilt_rad));
  const double mass = world.robot().rigid_body.mass_kg;
  world.SetExternalForce_W({mass * 1.0, 0, 0});  // 1 m/s^2 along x
  for (int k = 0; k < 100; ++k) world.Step();
  EXPECT_NEAR(world.Step().a_WB_W.x(), 1.0, 0.02);
  EXPECT_NEAR(world.Truth().v_WB_W.x(), 0.1, 0.01);
}

TEST(WorldStep, ExternalForceIsHeldInWAtAnyAttitude) {
  World world(OptionsFor("indoor_arena"));
  const Eigen::Quaterniond q_WB(Eigen::AngleAxisd(0.7, Eigen::Vector3d::UnitZ()) *
                                Eigen::AngleAxisd(0.5, Eigen::Vector3d::UnitX()));
  world.Reset({Eigen::Vector3d(0, 0, 1.5), q_WB});
  world.SetCommand(HoverCommand(world, q_WB, world.Truth().tilt_rad));
  const double mass = world.robot().rigid_body.mass_kg;
  world.SetExternalForce_W({0, mass * 1.0, 0});  // 1 m/s^2 along W's y
  for (int k = 0; k < 100; ++k) world.Step();
  const TruthState truth = world.Step();
  EXPECT_NEAR(truth.a_WB_W.x(), 0.0, 0.02);
  EXPECT_NEAR(truth.a_WB_W.y(), 1.0, 0.02);
  // A force through the CoM does not turn the robot.
  EXPECT_LT(truth.alpha_WB_B.norm(), 0.05);
}

// ---- bad states ----

// Steps until a SimulationError; fails the test if none comes within `max_steps`.
std::string StepUntilError(World& world, int max_steps) {
  for (int k = 0; k < max_steps; ++k) {
    try {
      world.Step();
    } catch (const core::SimulationError& e) {
      return e.what();
    }
  }
  ADD_FAILURE() << "no SimulationError within " << max_steps << " steps";
  return "";
}

TEST(WorldBadState, AbsurdForceIsASimulationErrorNamingTheTime) {
  World world(OptionsFor("indoor_arena"));
  world.Reset(Pose({0, 0, 1.5}));
  world.SetCommand(HoverCommand(world, Eigen::Quaterniond::Identity(), world.Truth().tilt_rad));
  for (int k = 0; k < 250; ++k) world.Step();  // fly normally until t = 0.25 s
  world.SetExternalForce_W({1e12, 0, 0});
  const std::string what = StepUntilError(world, 1);
  EXPECT_CONTAINS(what, "qacc");
  // The time of the failure, not the time after MuJoCo's internal reset (0).
  EXPECT_CONTAINS(what, "t = 0.25");
}

TEST(WorldBadState, NanThrustIsASimulationErrorNamingTheTime) {
  World world(OptionsFor("indoor_arena"));
  world.Reset(Pose({0, 0, 1.5}));
  ActuatorCommand command =
      HoverCommand(world, Eigen::Quaterniond::Identity(), world.Truth().tilt_rad);
  world.SetCommand(command);
  for (int k = 0; k < 100; ++k) world.Step();
  command.rotor_thrust_N[2] = std::numeric_limits<double>::quiet_NaN();
  world.SetCommand(command);
  const std::string what = StepUntilError(world, 1);
  EXPECT_CONTAINS(what, "ctrl");
  EXPECT_CONTAINS(what, "t = 0.10");
}

TEST(WorldBadState, NanTiltTargetIsASimulationError) {
  World world(OptionsFor("indoor_arena"));
  world.Reset(Pose({0, 0, 1.5}));
  ActuatorCommand command =
      HoverCommand(world, Eigen::Quaterniond::Identity(), world.Truth().tilt_rad);
  command.tilt_rad[0] = std::numeric_limits<double>::quiet_NaN();
  world.SetCommand(command);
  const std::string what = StepUntilError(world, 10);
  EXPECT_CONTAINS(what, "simulation failed at t = ");
}

// ---- the physics model and the complete scene ----

TEST(World, StepsTheSceneWithoutTheRobotsVisualOnlyBodiesAndRaysStillSeeThem) {
  World world(OptionsFor("indoor_arena"));
  const mjModel* physics = world.physics_model();
  const mjModel* full = world.model();
  EXPECT_LT(physics->ngeom + 50, full->ngeom);
  for (int g = 0; g < physics->ngeom; ++g) EXPECT_NE(physics->geom_group[g], 3);
  EXPECT_EQ(physics->nq, full->nq);
  EXPECT_EQ(physics->nv, full->nv);
  EXPECT_EQ(physics->nu, full->nu);
  const int base = mj_name2id(physics, mjOBJ_BODY, "base");
  EXPECT_EQ(physics->body_subtreemass[base],
            full->body_subtreemass[mj_name2id(full, mjOBJ_BODY, "base")]);

  world.Reset(Pose({0, 0, 1.5}));
  for (int k = 0; k < 10; ++k) world.Step();
  // Towards the robot from 1 m ahead: its shapes (complete scene) or the wall behind it.
  const auto robot = world.CastRay({1.0, 0, 1.5}, {-1, 0, 0}, kRaySceneAndRobot);
  ASSERT_TRUE(robot.has_value());
  EXPECT_EQ(robot->group, 3);
  EXPECT_EQ(full->geom_group[robot->geom], 3);
  EXPECT_LT(robot->distance_m, 0.7);
  const auto wall = world.CastRay({1.0, 0, 1.5}, {-1, 0, 0}, kRayScene);
  ASSERT_TRUE(wall.has_value());
  EXPECT_EQ(world.GeomName(wall->geom), "wall_west");
  EXPECT_NEAR(wall->distance_m, 7.0, 1e-9);
  // Both models agree on where the robot is.
  EXPECT_LT((world.SitePose_W("tool_tip").translation() -
             Eigen::Vector3d(world.data()->site_xpos + 3 * mj_name2id(full, mjOBJ_SITE,
                                                                       "tool_tip")))
                .norm(),
            1e-12);
}

TEST(World, PhysicsModelHasSmallBuiltinTexturesAndTheSameTexturedMaterials) {
  World world(OptionsFor("indoor_arena"));
  const mjModel* physics = world.physics_model();
  const mjModel* full = world.model();
  ASSERT_EQ(physics->ntex, full->ntex);
  ASSERT_EQ(physics->nmat, full->nmat);
  for (int t = 0; t < physics->ntex; ++t) {
    EXPECT_LE(physics->tex_width[t], 8) << mj_id2name(physics, mjOBJ_TEXTURE, t);
    EXPECT_GE(full->tex_width[t], 128) << mj_id2name(full, mjOBJ_TEXTURE, t);
  }
  for (int k = 0; k < physics->nmat; ++k) {
    EXPECT_EQ(physics->mat_texid[k] >= 0, full->mat_texid[k] >= 0);
  }
  // Rays (cast in the physics model) still tell textured from plain surfaces.
  world.Reset(Pose({0, 0, 1.5}));
  const auto brick = world.CastRay({0, 0, 1.5}, {0, 1, 0}, kRayScene);
  ASSERT_TRUE(brick.has_value());
  EXPECT_EQ(world.GeomName(brick->geom), "wall_north");
  EXPECT_TRUE(brick->textured);
  const auto plain = world.CastRay({0, 0, 1.5}, {0, -1, 0}, kRayScene);
  ASSERT_TRUE(plain.has_value());
  EXPECT_EQ(world.GeomName(plain->geom), "wall_south");
  EXPECT_FALSE(plain->textured);
}

// A fan of rays (what the LiDAR model casts) gives CastRay's hits bit for bit: the same
// geom, distance, point and normal, from anywhere (in the open, inside a wall, on a face)
// along any direction, including rays along a box's axes and at its corners and edges,
// where the fan's own tests of boxes and spheres are closest to ruling out a hit.
TEST(World, RayFanHitsAreCastRaysBitForBit) {
  std::mt19937_64 rng(7);
  std::uniform_real_distribution<double> uniform(-1.0, 1.0);
  auto random_unit = [&] {
    Eigen::Vector3d u;
    do u = Eigen::Vector3d(uniform(rng), uniform(rng), uniform(rng));
    while (u.norm() < 0.1);
    return u.normalized();
  };
  int hits = 0;
  for (const char* name : {"indoor_arena", "inspection_wall", "building_window", "bridge",
                           "corridor_hall"}) {
    World world(OptionsFor(name));
    world.Reset(Pose({0.3, -0.2, 1.5}, 5, -3, 40));
    for (int k = 0; k < 5; ++k) world.Step();
    const mjModel* m = world.physics_model();
    const mjData* d = world.physics_data();
    std::vector<Eigen::Vector3d> origins = {Eigen::Vector3d(0.3, -0.2, 1.5),
                                            Eigen::Vector3d(1.0, 0.0, 1.5)};
    std::vector<Eigen::Vector3d> targets;
    for (int g = 0; g < m->ngeom; ++g) {
      if (m->geom_type[g] == mjGEOM_PLANE) continue;
      const Eigen::Vector3d p(d->geom_xpos + 3 * g);
      const Eigen::Matrix3d R = Eigen::Map<const Eigen::Matrix<double, 3, 3, Eigen::RowMajor>>(
          d->geom_xmat + 9 * g);
      const Eigen::Vector3d size(m->geom_size + 3 * g);
      origins.push_back(p);                                  // inside the geom
      origins.push_back(p + R * Eigen::Vector3d(size.x(), 0.0, 0.0));  // on a face
      origins.push_back(p + R * Eigen::Vector3d(0.0, 0.0, size.z() + 1.5));
      for (double sx : {-1.0, 1.0}) {
        for (double sz : {-1.0, 1.0}) {
          targets.push_back(p + R * Eigen::Vector3d(sx * size.x(), size.y(), sz * size.z()));
          targets.push_back(p + R * Eigen::Vector3d(sx * size.x(), 0.0, sz * size.z()));
        }
      }
    }
    for (int k = 0; k < 20; ++k) {
      origins.emplace_back(6.0 * uniform(rng), 6.0 * uniform(rng), 1.5 + 1.4 * uniform(rng));
    }
    for (const uint32_t groups : {static_cast<uint32_t>(kRayScene),
                                  static_cast<uint32_t>(kRaySceneAndRobot)}) {
      for (const Eigen::Vector3d& origin_W : origins) {
        std::vector<Eigen::Vector3d> directions = {
            Eigen::Vector3d::UnitX(),  -Eigen::Vector3d::UnitX(), Eigen::Vector3d::UnitY(),
            -Eigen::Vector3d::UnitY(), Eigen::Vector3d::UnitZ(),  -Eigen::Vector3d::UnitZ()};
        for (int k = 0; k < 200; ++k) directions.push_back(random_unit());
        for (const Eigen::Vector3d& target : targets) {
          if ((target - origin_W).norm() > 1e-6) directions.push_back(target - origin_W);
        }
        const RayFan fan = world.RaysFrom(origin_W, groups);
        for (const Eigen::Vector3d& direction_W : directions) {
          const std::optional<RayHit> cast = world.CastRay(origin_W, direction_W, groups);
          const std::optional<RayHit> fanned = fan.Cast(direction_W);
          ASSERT_EQ(cast.has_value(), fanned.has_value())
              << name << " from " << origin_W.transpose() << " along " << direction_W.transpose();
          if (!cast) continue;
          ++hits;
          ASSERT_EQ(cast->geom, fanned->geom) << name << " from " << origin_W.transpose();
          ASSERT_EQ(cast->distance_m, fanned->distance_m);
          ASSERT_EQ(cast->point_W, fanned->point_W);
          ASSERT_EQ(cast->normal_W, fanned->normal_W);
          ASSERT_EQ(cast->textured, fanned->textured);
          ASSERT_EQ(cast->group, fanned->group);
        }
      }
    }
  }
  EXPECT_GT(hits, 100000);
}

// ---- contacts and distances to structure ----

// Robot poses close to (and into) each world's structure: around a random static group-0
// geom, within its extent plus a metre, at a random attitude.
std::vector<Waypoint> PosesNearStructure(const mjModel* m, int count, uint32_t seed) {
  std::vector<int> structure;
  for (int g = 0; g < m->ngeom; ++g) {
    if (m->geom_group[g] == 0 && m->geom_bodyid[g] == 0) structure.push_back(g);
  }
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> unit(-1.0, 1.0);
  std::vector<Waypoint> poses;
  mjData* d = mj_makeData(m);
  mj_forward(m, d);
  for (int i = 0; i < count; ++i) {
    const int g = structure[rng() % structure.size()];
    const mjtNum* size = m->geom_size + 3 * g;
    Eigen::Vector3d extent(size[0], size[1], size[2]);
    if (m->geom_type[g] == mjGEOM_CYLINDER) extent = Eigen::Vector3d(size[0], size[0], size[1]);
    extent = extent.cwiseMin(8.0) + Eigen::Vector3d::Constant(1.2);
    Eigen::Matrix3d R;
    const mjtNum* x = d->geom_xmat + 9 * g;
    R << x[0], x[1], x[2], x[3], x[4], x[5], x[6], x[7], x[8];
    const Eigen::Vector3d offset(unit(rng) * extent.x(), unit(rng) * extent.y(),
                                 unit(rng) * extent.z());
    const Eigen::Vector3d p = Eigen::Vector3d(d->geom_xpos[3 * g], d->geom_xpos[3 * g + 1],
                                              d->geom_xpos[3 * g + 2]) + R * offset;
    poses.push_back(Pose(p, 40 * unit(rng), 40 * unit(rng), 180 * unit(rng)));
  }
  mj_deleteData(d);
  return poses;
}

// MuJoCo's full collision pipeline, contacts never gated, on a copy of a model and state,
// the robot proxies (group 2) given `margin_m` and an equal gap.
struct Reference {
  mjModel* m = nullptr;
  mjData* d = nullptr;
  Reference(const mjModel* model, const mjData* data, double margin_m) {
    m = mj_copyModel(nullptr, model);
    m->opt.disableflags &= ~mjDSBL_CONTACT;
    for (int g = 0; g < m->ngeom; ++g) {
      if (m->geom_group[g] != 2) continue;
      m->geom_margin[g] = margin_m;
      m->geom_gap[g] = margin_m;
    }
    d = mj_makeData(m);
    mju_copy(d->qpos, data->qpos, m->nq);
    mj_forward(m, d);
  }
  ~Reference() {
    mj_deleteData(d);
    mj_deleteModel(m);
  }
};

// Brute force: every proxy against every structure geom, exact while apart (GeomDistance),
// MuJoCo's contact depth (margin 0, full pipeline) when they touch.
TEST(WorldDistance, ClosestStructureIsTheExactMinimumOverAllPairsNearEveryStructure) {
  for (const char* name : kWorlds) {
    SCOPED_TRACE(name);
    World world(OptionsFor(name));
    const double horizon_m = world.options().distance_horizon_m;
    int within_horizon = 0;
    int touching = 0;
    for (const Waypoint& pose : PosesNearStructure(world.model(), 300, 7)) {
      world.Reset(pose);
      const Reference reference(world.model(), world.data(), 0.0);
      const mjModel* m = reference.m;
      const mjData* d = reference.d;
      const auto geom = [&](int g) {
        Eigen::Matrix3d R;
        const mjtNum* x = d->geom_xmat + 9 * g;
        R << x[0], x[1], x[2], x[3], x[4], x[5], x[6], x[7], x[8];
        return ConvexGeom{m->geom_type[g],
                          Eigen::Vector3d(m->geom_size[3 * g], m->geom_size[3 * g + 1],
                                          m->geom_size[3 * g + 2]),
                          Eigen::Vector3d(d->geom_xpos[3 * g], d->geom_xpos[3 * g + 1],
                                          d->geom_xpos[3 * g + 2]),
                          R};
      };
      std::optional<double> expected_m;
      for (int p = 0; p < m->ngeom; ++p) {
        if (m->geom_group[p] != 2) continue;
        for (int g = 0; g < m->ngeom; ++g) {
          if (m->geom_group[g] != 0 || m->geom_bodyid[g] != 0) continue;
          std::optional<double> pair_m;
          for (int i = 0; i < d->ncon; ++i) {
            const mjContact& c = d->contact[i];
            if ((c.geom1 == p && c.geom2 == g) || (c.geom1 == g && c.geom2 == p)) {
              pair_m = std::min(pair_m.value_or(0.0), c.dist);
            }
          }
          if (!pair_m) pair_m = *GeomDistance(geom(p), geom(g));
          if (*pair_m < horizon_m && (!expected_m || *pair_m < *expected_m)) {
            expected_m = *pair_m;
          }
        }
      }
      const std::optional<Proximity> closest = world.ClosestStructure();
      ASSERT_EQ(closest.has_value(), expected_m.has_value()) << pose.p_WB.transpose();
      if (!closest) continue;
      ++within_horizon;
      touching += *expected_m <= 0.0;
      EXPECT_NEAR(closest->distance_m, *expected_m, 2 * kGeomDistanceTolerance_m)
          << pose.p_WB.transpose();
      EXPECT_EQ(m->geom_group[closest->structure_geom], 0);
      EXPECT_EQ(m->geom_group[closest->robot_geom], 2);
    }
    EXPECT_GT(within_horizon, 100);
    EXPECT_GT(touching, 10);
  }
}

TEST(WorldDistance, ContactGateNeverHidesAContact) {
  for (const char* name : kWorlds) {
    SCOPED_TRACE(name);
    World world(OptionsFor(name));
    int touching = 0;
    for (const Waypoint& pose : PosesNearStructure(world.model(), 300, 11)) {
      world.Reset(pose);
      const mjData* d = world.physics_data();
      const Reference reference(world.physics_model(), d, 0.0);
      ASSERT_EQ(d->ncon, reference.d->ncon) << pose.p_WB.transpose();
      for (int i = 0; i < reference.d->ncon; ++i) {
        EXPECT_EQ(d->contact[i].geom1, reference.d->contact[i].geom1);
        EXPECT_EQ(d->contact[i].geom2, reference.d->contact[i].geom2);
        // Cylinder pairs go through libccd's MPR, iterative to 1e-6: rounding-level input
        // differences (the copied state) can move its depth by that much.
        EXPECT_NEAR(d->contact[i].dist, reference.d->contact[i].dist, 1e-6);
      }
      touching += reference.d->ncon > 0;
    }
    EXPECT_GT(touching, 10);
  }
}

}  // namespace
}  // namespace tofu::sim
