#pragma once
// One run of a scenario: world + trajectory + controller + disturbances stepped at the
// physics rate, recorded in memory (RunRecord), evaluated (evaluation.h) and written to
// a run directory (run_directory.h). Simulate() does no file I/O, so benchmarks and
// tests can run the loop alone.

#include <cstdint>
#include <functional>
#include <optional>
#include <string>
#include <vector>

#include "core/time.h"
#include "harness/consistency_eval.h"
#include "harness/estimation.h"
#include "harness/scenario.h"
#include "harness/sensor_suite.h"
#include "sim/trajectory.h"
#include "sim/world.h"

namespace tofu::harness {

/// Reference and error at one output sample.
struct TrackingSample {
  core::Time t_ns = 0;
  sim::Reference reference;
  double position_error_m = 0.0;
  double attitude_error_rad = 0.0;
};

/// A contact episode between the robot and one structure geom (contacts less than
/// 0.25 s apart merged: one crash, one event). robot_geom is the part that hit first.
struct CollisionEvent {
  core::Time start_ns = 0;
  core::Time end_ns = 0;  ///< last step in contact
  std::string robot_geom;
  std::string structure_geom;
  double max_penetration_m = 0.0;
};

struct ProximityRecord {
  core::Time t_ns = 0;
  sim::Proximity proximity;
};

/// Where an approach segment ended: the tool tip's distance to the surface.
struct ApproachResult {
  int segment_index = 0;
  core::Time t_ns = 0;
  double standoff_m = 0.0;
  std::optional<double> distance_m;  ///< nullopt if the ray hit nothing
};

struct RunRecord {
  Scenario scenario;  ///< with the effective seed
  sim::RobotDescription robot;
  std::vector<sim::SegmentInfo> segments;
  std::vector<sim::TruthState> groundtruth;  ///< at output.groundtruth_rate_hz
  std::vector<TrackingSample> tracking;      ///< at the same instants
  std::vector<std::pair<core::Time, bool>> saturation;  ///< per controller update
  std::vector<CollisionEvent> collisions;
  std::optional<ProximityRecord> closest_structure;  ///< within the distance horizon
  double distance_horizon_m = 0.0;
  std::vector<ApproachResult> approaches;
  std::vector<SensorStream> sensors;  ///< in the order of scenario.sensors
  std::vector<LabelEvent> labels;     ///< condition and fault transitions, by time
  /// With scenario.consistency: the sensors' velocity consistency (consistency_eval.h).
  std::optional<ConsistencyEvaluation> consistency;
  /// With scenario.estimation: each method's scores (filled after the run directory's
  /// streams are written, by RunEstimation).
  std::vector<MethodEvaluation> methods;
  int64_t physics_steps = 0;
  double wall_time_s = 0.0;  ///< the only wall-clock figure; goes to timing.json
  /// Set when the simulation stopped early (MuJoCo bad state): what happened.
  std::optional<std::string> failure;
};

struct SimulateOptions {
  std::string models_dir = sim::DefaultModelsDir();
  /// Called about every 0.5 % of the run with the fraction done (0..1).
  std::function<void(double)> progress;
};

/// Runs the scenario. Throws core::InputError for a scenario the simulator cannot set up
/// (unknown world, an unreachable approach). A simulation that fails mid-run (MuJoCo
/// bad state) returns the record so far with `failure` set.
RunRecord Simulate(const Scenario& scenario, const SimulateOptions& options = {});

}  // namespace tofu::harness
