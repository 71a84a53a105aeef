#pragma once
// One run of a scenario: world + trajectory + controller + disturbances stepped at the
// physics rate, evaluated (evaluation.h) and written to a run directory
// (run_directory.h). Its per-sample files are written while it flies when it is given a
// directory (SimulateOptions::record_dir: `tofu run`, whose memory then stays flat with
// flight time), else kept in the RunRecord and written after it (tests, benchmarks,
// corpus episodes), through the same recorder (run_recorder.h).

#include <cstdint>
#include <filesystem>
#include <functional>
#include <optional>
#include <string>
#include <vector>

#include "core/time.h"
#include "harness/closed_loop.h"
#include "harness/consistency_eval.h"
#include "harness/estimation.h"
#include "harness/scenario.h"
#include "harness/sensor_suite.h"
#include "replay/replay.h"
#include "sim/trajectory.h"
#include "sim/world.h"

namespace tofu::harness {

/// The controller's tracking error at one output sample (the reference itself is in
/// tracking.csv, and in RunRecord::references of a run kept in memory).
struct TrackingSample {
  core::Time t_ns = 0;
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

/// One output-rate sample of a closed-loop flight: what the controller flew on.
struct ClosedLoopSample {
  core::Time t_ns = 0;
  FlightMode mode = FlightMode::kTruth;
  /// The estimate of B in W the controller used last (none before the handover).
  std::optional<Eigen::Vector3d> p_WB_est;
  std::optional<Eigen::Quaterniond> q_WB_est;
  /// |p_WB_est - p_WB|² against the truth at this instant, with p_WB_est.
  std::optional<double> estimate_squared_error_m2;
  /// Distance of the robot to the nearest structure (ground aside), when within the
  /// distance horizon.
  std::optional<double> structure_distance_m;
};

/// A flight whose controller flew on an estimation method (`control:`).
struct ClosedLoopFlight {
  std::string method;
  ControlConfig control;
  std::vector<ClosedLoopSample> samples;  ///< at output.groundtruth_rate_hz
  std::vector<FlightEvent> events;
  std::optional<core::Time> handover_ns;
};

struct RunRecord {
  Scenario scenario;  ///< with the effective seed
  sim::RobotDescription robot;
  std::vector<sim::SegmentInfo> segments;
  /// Where the run's per-sample files were written while it flew (record_dir), or
  /// nullopt for a run kept in memory. A recorded run keeps no sample vectors (below)
  /// but what its evaluation needs: ground truth and delivered samples of the
  /// non-IMU streams with scenario.consistency, counts and the digests of SensorStream.
  std::optional<std::filesystem::path> recorded_to;
  std::vector<sim::TruthState> groundtruth;  ///< at output.groundtruth_rate_hz
  std::vector<sim::Reference> references;    ///< at the same instants
  std::vector<TrackingSample> tracking;      ///< at the same instants, in both kinds of run
  std::vector<std::pair<core::Time, bool>> saturation;  ///< per controller update
  std::vector<CollisionEvent> collisions;
  std::optional<ProximityRecord> closest_structure;  ///< within the distance horizon
  double distance_horizon_m = 0.0;
  std::vector<ApproachResult> approaches;
  std::vector<SensorStream> sensors;  ///< in the order of scenario.sensors
  std::vector<replay::LabelEvent> labels;     ///< condition and fault transitions, by time
  /// With scenario.consistency: the sensors' velocity consistency (consistency_eval.h).
  std::optional<ConsistencyEvaluation> consistency;
  /// The estimation methods that ran in the loop, fed by the run's arrival-ordered
  /// sample stream: every method of scenario.estimation in a ground-truth flight, the
  /// flying method in a closed-loop flight.
  std::vector<replay::ReplayResult> in_loop;
  /// Samples released to the in-loop consumers after a later-arriving one (a model whose
  /// sample arrives before the step it was produced in); 0 in a correct run.
  std::size_t late_samples = 0;
  /// What makes two runs comparable sample by sample (core/digest.h): a digest of the
  /// samples the in-loop methods were given, in the order given (each with its stream and
  /// whether it came from the clean stream; nullopt when no method ran), and of the random
  /// streams the flight drew from (common random numbers when equal).
  std::optional<uint64_t> samples_digest;
  uint64_t random_streams_digest = 0;
  /// With scenario.estimation: each method's scores (filled when the run directory is
  /// written, by EvaluateEstimation).
  std::vector<MethodEvaluation> methods;
  /// Set in a flight whose controller flew on an estimate.
  std::optional<ClosedLoopFlight> closed_loop;
  /// `control: {state_source: estimate}`: one closed-loop flight per method, flown after
  /// this (ground-truth) flight, in the order of control.methods.
  std::vector<RunRecord> closed_loop_flights;
  int64_t physics_steps = 0;
  double wall_time_s = 0.0;  ///< the only wall-clock figure; goes to timing.json
  /// At the end of each simulated minute: wall time since the flight began and the
  /// process's resident set (timing.json: per-minute real-time factor, memory growth).
  struct MinuteMark {
    double wall_time_s = 0.0;
    double resident_mb = 0.0;
  };
  std::vector<MinuteMark> minutes;
  /// Set when the simulation stopped early (MuJoCo bad state): what happened.
  std::optional<std::string> failure;
};

struct SimulateOptions {
  std::string models_dir = sim::DefaultModelsDir();
  /// Called about every 0.5 % of the run with the fraction done (0..1).
  std::function<void(double)> progress;
  /// Fly this flight on the named estimation method (a closed-loop flight; only that
  /// method runs in the loop). Unset: fly on ground truth, run every method of
  /// scenario.estimation in the loop, then fly the closed-loop flights of
  /// scenario.control.
  std::optional<std::string> fly_on;
  /// A closed-loop flight's progress: (method, fraction). With threads > 1 the flights
  /// fly at once and this is called from their threads.
  std::function<void(const std::string&, double)> closed_loop_progress;
  /// Write the run's per-sample files into this directory (which exists) while flying,
  /// keeping none of them in memory (RunRecord::recorded_to); the closed-loop flights go
  /// to closed_loop/<method>/ under it. Unset: everything is kept in the record.
  std::optional<std::filesystem::path> record_dir;
  /// Threads the run may use: > 1 runs tofu's own in-loop methods on up to this many
  /// worker threads beside the flight (in_loop_methods.h), and then up to this many
  /// closed-loop flights at once. The output is the same whatever the number; 1 keeps
  /// everything on the caller's thread.
  int threads = 1;
  /// Testing hook: called with every sample before the in-loop consumers see it, to
  /// change it (the causality test alters samples arriving after a given time).
  std::function<void(const std::string& stream, sim::SensorSample&)> tamper;
};

/// Runs the scenario. Throws core::InputError for a scenario the simulator cannot set up
/// (unknown world, an unreachable approach). A simulation that fails mid-run (MuJoCo
/// bad state) returns the record so far with `failure` set.
RunRecord Simulate(const Scenario& scenario, const SimulateOptions& options = {});

/// `control: {state_source: estimate}`: the scenario flown once per control.methods,
/// each a Simulate with fly_on set (what Simulate does after a ground-truth flight).
/// Empty without such a block.
std::vector<RunRecord> FlyClosedLoopFlights(const Scenario& scenario,
                                            const SimulateOptions& options);

}  // namespace tofu::harness
