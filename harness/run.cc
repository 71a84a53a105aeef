#include "harness/run.h"

#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <fstream>
#include <limits>
#include <stdexcept>
#include <variant>

#include "core/error.h"
#include "core/lie.h"
#include "core/random.h"
#include "harness/run_directory.h"
#include "harness/run_recorder.h"
#include "harness/sample_stream.h"
#include "replay/recorded_log.h"
#include "sim/allocation.h"
#include "sim/controller.h"
#include "sim/wind.h"

namespace tofu::harness {

using replay::DescribeRunStreams;
using replay::EstimationConfig;
using replay::EstimationSetup;
using replay::LabelEvent;
using replay::MakeEstimationSetup;
using replay::MethodRunner;
using replay::ParseReplayMethod;
using replay::RecordedLog;
using replay::ReplayMethod;
using replay::ReplayResult;
using replay::StreamKind;

namespace {

// The process's resident set [MB] from /proc/self/statm (Linux); 0 where unreadable.
double ResidentMegabytes() {
  std::ifstream statm("/proc/self/statm");
  long total_pages = 0;
  long resident_pages = 0;
  if (!(statm >> total_pages >> resident_pages)) return 0.0;
  return static_cast<double>(resident_pages) * static_cast<double>(::sysconf(_SC_PAGESIZE)) /
         (1024.0 * 1024.0);
}

sim::RobotState ToRobotState(const sim::TruthState& truth) {
  return sim::RobotState{truth.t_ns, truth.p_WB, truth.q_WB, truth.v_WB_W, truth.omega_WB_B};
}

// Contact episodes between the robot and one structure geom. Contacts less than
// kMergeGapNs apart belong to the same episode: a crash bounces and scrapes, and one
// crash should count once, not once per bounce or per robot part.
class CollisionTracker {
 public:
  static constexpr core::Time kMergeGapNs = 250'000'000;

  void Update(core::Time t_ns, const std::vector<sim::Contact>& contacts,
              const sim::World& world, std::vector<CollisionEvent>& events) {
    for (const sim::Contact& c : contacts) {
      Latest* latest = nullptr;
      for (Latest& l : latest_) {
        if (l.structure_geom == c.structure_geom) latest = &l;
      }
      if (latest != nullptr && t_ns - events[latest->event].end_ns <= kMergeGapNs) {
        CollisionEvent& e = events[latest->event];
        e.end_ns = t_ns;
        e.max_penetration_m = std::max(e.max_penetration_m, -c.distance_m);
        continue;
      }
      events.push_back({t_ns, t_ns, world.GeomName(c.robot_geom),
                        world.GeomName(c.structure_geom), -c.distance_m});
      if (latest != nullptr) {
        latest->event = events.size() - 1;
      } else {
        latest_.push_back({c.structure_geom, events.size() - 1});
      }
    }
  }

 private:
  struct Latest {
    int structure_geom;
    size_t event;
  };
  std::vector<Latest> latest_;
};

// The estimation methods that run inside the flight: each fed, in arrival order, the
// samples as the run directory will record them (RecordedMeasurement), configured from
// the calibration the run will write (DescribeRunStreams), so that `tofu estimate` on
// the written run reproduces them. Set up at the first release, once the models have
// latched their reference frames.
class InLoopMethods {
 public:
  InLoopMethods(std::vector<std::string> names, const EstimationConfig& config)
      : names_(std::move(names)), config_(config) {
    for (const std::string& name : names_) any_clean_ |= name.ends_with("@clean");
  }

  bool empty() const { return names_.empty(); }
  bool any_clean() const { return any_clean_; }
  bool started() const { return !runners_.empty() || names_.empty(); }

  void Start(const RunRecord& record) {
    std::vector<std::pair<std::string, StreamKind>> kinds;
    for (const SensorStream& s : record.sensors) {
      const StreamKind kind = s.type == "imu" ? StreamKind::kImu
                              : (s.type == "vio" || s.type == "lidar_odometry") ? StreamKind::kPose
                                                                                : StreamKind::kPosition;
      kinds.emplace_back(s.name, kind);
    }
    const RecordedLog log = DescribeRunStreams(kinds, CalibrationYamlText(record), "");
    const EstimationSetup setup = MakeEstimationSetup(log, config_);
    for (const std::string& name : names_) {
      const ReplayMethod method = ParseReplayMethod(name, log);
      clean_.push_back(method.clean_streams);
      runners_.emplace_back(log, method, setup.estimator, setup.sensors, setup.consensus);
    }
    // The labels known so far: the fault schedule, and the conditions of the first step.
    for (const LabelEvent& label : schedule_) AddLabel(label);
    for (const LabelEvent& label : record.labels) AddLabel(label);
  }

  /// The scheduled faults as labels, known before the flight (the oracle's); given to
  /// the methods when they start.
  void SetFaultSchedule(std::vector<LabelEvent> schedule) { schedule_ = std::move(schedule); }
  /// A condition transition the run just recorded.
  void AddLabel(const LabelEvent& label) {
    for (MethodRunner& runner : runners_) runner.AddLabel(label);
  }

  void Feed(bool clean_stream, const std::vector<SensorStream>& streams, const ArrivedSample& a) {
    const SensorStream& stream = streams[a.stream];
    const core::StampedMeasurement m{stream.name, a.sample->t_ns,
                                     RecordedMeasurement(stream.type, a.sample->measured)};
    for (std::size_t i = 0; i < runners_.size(); ++i) {
      if (clean_[i] == clean_stream) runners_[i].Add(m);
    }
  }

  const MethodRunner& runner(std::size_t i) const { return runners_[i]; }

  std::vector<ReplayResult> Finish() {
    std::vector<ReplayResult> results;
    for (MethodRunner& r : runners_) results.push_back(std::move(r).Finish());
    return results;
  }

 private:
  std::vector<std::string> names_;
  EstimationConfig config_;
  bool any_clean_ = false;
  std::vector<bool> clean_;
  std::vector<MethodRunner> runners_;
  std::vector<LabelEvent> schedule_;
};

Eigen::Isometry3d PoseOf(const Eigen::Vector3d& p, const Eigen::Quaterniond& q) {
  Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
  T.linear() = q.normalized().toRotationMatrix();
  T.translation() = p;
  return T;
}

// The IMU's nominal mount T_B_I (what the flight stack is told), identity without one.
Eigen::Isometry3d NominalImuMount(const Scenario& scenario, const sim::RobotDescription& robot) {
  for (const SensorConfig& config : scenario.sensors) {
    if (!std::holds_alternative<sim::ImuOptions>(config.options)) continue;
    const sim::MountSite* site = robot.FindSite(SensorSite(config.options));
    if (site == nullptr) break;
    return PoseOf(site->p_B_s, site->q_B_s) * config.calibration_error;
  }
  return Eigen::Isometry3d::Identity();
}

// A delivered sample into the stream's counts and digest (evaluation.h's windowed
// metrics), and into its vectors when the run keeps them.
void RecordDelivered(const sim::SensorSample& sample, uint32_t faults, bool keep,
                     SensorStream& stream) {
  ++stream.delivered_count;
  stream.delivered_t_ns.push_back(sample.t_ns);
  if (const auto* m = std::get_if<core::PositionMeasurement>(&sample.measured)) {
    stream.delivered_position_error_m2.push_back(
        (m->p_Ss - std::get<core::PositionMeasurement>(sample.truth).p_Ss).squaredNorm());
  } else if (const auto* p = std::get_if<core::PoseMeasurement>(&sample.measured)) {
    stream.delivered_position_error_m2.push_back(
        (p->p_Ss - std::get<core::PoseMeasurement>(sample.truth).p_Ss).squaredNorm());
  }
  if (!keep) return;
  stream.delivered.push_back(sample);
  stream.delivered_faults.push_back(faults);
}

// Each stream's place among the streams sorted by name: the tie-break ReadRecordedLog
// uses between samples of equal arrival, so the queue must use it too.
std::vector<uint32_t> RanksByName(const std::vector<SensorStream>& streams) {
  std::vector<std::size_t> by_name(streams.size());
  for (std::size_t i = 0; i < by_name.size(); ++i) by_name[i] = i;
  std::sort(by_name.begin(), by_name.end(),
            [&](std::size_t a, std::size_t b) { return streams[a].name < streams[b].name; });
  std::vector<uint32_t> rank(streams.size());
  for (std::size_t r = 0; r < by_name.size(); ++r) rank[by_name[r]] = static_cast<uint32_t>(r);
  return rank;
}

}  // namespace

RunRecord Simulate(const Scenario& scenario, const SimulateOptions& options) {
  RunRecord record;
  record.scenario = scenario;

  sim::WorldOptions world_options;
  world_options.models_dir = options.models_dir;
  world_options.world = scenario.world;
  world_options.robot = scenario.robot;
  world_options.physics_rate_hz = scenario.physics.rate_hz;
  record.distance_horizon_m = world_options.distance_horizon_m;
  std::unique_ptr<sim::World> world_ptr;
  try {
    world_ptr = std::make_unique<sim::World>(world_options);
  } catch (const core::InputError& e) {
    // Name the scenario that asked for the model, and the model's own problem.
    throw core::InputError({scenario.source_file, 0, 0}, e.key_path(), e.what());
  }
  sim::World& world = *world_ptr;
  record.robot = world.robot();

  sim::TrajectoryContext context;
  context.p_B_tool = record.robot.FindSite("tool_tip")->p_B_s;
  context.surface_distance = [&world](const Eigen::Vector3d& origin_W,
                                      const Eigen::Vector3d& direction_W) {
    return world.RayDistance(origin_W, direction_W);
  };
  std::unique_ptr<sim::Trajectory> trajectory;
  try {
    trajectory = sim::BuildTrajectory(scenario.trajectory, context);
  } catch (const std::invalid_argument& e) {
    throw core::InputError({scenario.source_file, 0, 0}, "trajectory.segments", e.what());
  }
  record.segments = trajectory->segments();

  const sim::Waypoint& start = scenario.trajectory.start;
  world.Reset(sim::Waypoint{start.p_WB + scenario.initial_offset.position_W_m,
                            start.q_WB * scenario.initial_offset.q_offset});
  sim::GeometricController controller(scenario.controller, record.robot.rigid_body);
  const sim::Allocator allocator(record.robot.allocation);
  sim::Wind wind(scenario.wind, core::RandomStream(scenario.seed, "wind"));

  // Sensors: one model per configured stream, its scheduled faults in an injector. Each
  // draws only from streams seeded by (seed, its own name).
  std::vector<std::unique_ptr<sim::SensorModel>> models;
  std::vector<sim::FaultInjector> injectors;
  std::vector<uint32_t> conditions;
  for (const SensorConfig& config : scenario.sensors) {
    try {
      models.push_back(MakeSensorModel(config, world, scenario.seed));
    } catch (const std::invalid_argument& e) {
      throw core::InputError({scenario.source_file, 0, 0}, "sensors." + config.name, e.what());
    }
    std::vector<sim::FaultSpec> specs;
    for (const sim::FaultSpec& fault : scenario.faults) {
      if (fault.sensor == config.name) specs.push_back(fault);
    }
    injectors.emplace_back(std::move(specs), scenario.seed);
    SensorStream stream;
    stream.name = config.name;
    stream.type = std::string(SensorTypeName(config.options));
    stream.site = SensorSite(config.options);
    record.sensors.push_back(std::move(stream));
    conditions.push_back(sim::kConditionNone);
  }
  std::vector<sim::SensorSample> sensor_scratch;
  std::vector<sim::SensorSample> delivered_scratch;

  // The recorder: with a record_dir every per-sample file is written as produced and the
  // record keeps only what the evaluation needs (RunRecord::recorded_to).
  std::optional<RunRecorder> recorder;
  if (options.record_dir) {
    recorder.emplace(*options.record_dir, RecorderLayoutOf(record, options.fly_on.has_value()));
    record.recorded_to = *options.record_dir;
  }
  const bool keep_samples = !recorder;
  // The consistency evaluation (consistency_eval.h) reads the non-IMU streams and the
  // ground truth of the whole run after it.
  const bool keep_for_consistency = scenario.consistency.has_value();
  if (keep_samples) {
    // A sample is ~1.5 kB (core::Measurement holds a pose's two 6x6 covariances): growing
    // the streams by doubling copied them and touched twice their final memory.
    for (size_t i = 0; i < record.sensors.size(); ++i) {
      SensorStream& stream = record.sensors[i];
      const auto expected_samples = static_cast<size_t>(std::ceil(
                                        scenario.duration_s *
                                        SensorRate_hz(scenario.sensors[i].options))) + 2;
      stream.clean.reserve(expected_samples);
      stream.delivered.reserve(expected_samples);
      stream.delivered_faults.reserve(expected_samples);
      if (stream.type == "imu") stream.imu_biases.reserve(expected_samples);
    }
  }

  // The run's consumers of the arrival-ordered sample stream besides the recorder: the
  // estimation methods in the loop, and through the flying one, the controller.
  std::vector<std::string> in_loop_names;
  if (options.fly_on) {
    in_loop_names.push_back(*options.fly_on);
  } else if (scenario.estimation) {
    in_loop_names = scenario.estimation->methods;
  }
  InLoopMethods in_loop(in_loop_names,
                        scenario.estimation ? *scenario.estimation : EstimationConfig{});
  const std::vector<uint32_t> stream_rank = RanksByName(record.sensors);
  ArrivalQueue delivered_queue(stream_rank);
  ArrivalQueue clean_queue(stream_rank);
  core::Time released_until_ns = std::numeric_limits<core::Time>::min();
  const auto release = [&](core::Time now_ns, bool flush) {
    if (in_loop.empty()) return;
    if (!in_loop.started()) {
      // The models have latched their reference frames by now (first step).
      for (size_t i = 0; i < models.size(); ++i) record.sensors[i].T_WS = models[i]->T_WS();
      in_loop.Start(record);
    }
    const auto feed = [&](bool clean) {
      return [&, clean](const ArrivedSample& a) {
        if (a.sample->arrival_ns < released_until_ns) ++record.late_samples;
        in_loop.Feed(clean, record.sensors, a);
      };
    };
    if (flush) {
      delivered_queue.Flush(feed(false));
      clean_queue.Flush(feed(true));
    } else {
      delivered_queue.Release(now_ns, feed(false));
      clean_queue.Release(now_ns, feed(true));
      released_until_ns = now_ns;
    }
  };

  // A closed-loop flight: the pilot between the flying method and the controller.
  std::optional<ClosedLoopPilot> pilot;
  const ControlConfig control = scenario.control.value_or(ControlConfig{});
  if (options.fly_on) {
    pilot.emplace(control.failsafe, NominalImuMount(scenario, record.robot));
    record.closed_loop.emplace();
    record.closed_loop->method = *options.fly_on;
    record.closed_loop->control = control;
  }
  std::optional<double> structure_distance_m;
  bool disarmed = false;

  const core::Time dt_ns = world.timestep_ns();
  const double dt_s = core::TimeToSeconds(dt_ns);
  const core::Time controller_period_ns = core::PeriodFromRate(scenario.controller.rate_hz);
  const core::Time output_period_ns = core::PeriodFromRate(scenario.output.groundtruth_rate_hz);
  const int64_t total_steps =
      std::llround(scenario.duration_s * scenario.physics.rate_hz);
  const int64_t progress_every = std::max<int64_t>(1, total_steps / 200);
  {
    std::vector<LabelEvent> schedule;
    for (const sim::FaultLabel& label : sim::FaultLabels(scenario.faults, total_steps * dt_ns)) {
      schedule.push_back({label.t_ns, label.sensor, label.fault, "fault", label.active});
    }
    in_loop.SetFaultSchedule(std::move(schedule));
  }
  core::Time next_controller_ns = 0;
  core::Time next_output_ns = 0;
  size_t next_approach = 0;
  std::vector<size_t> approach_segments;
  for (size_t i = 0; i < record.segments.size(); ++i) {
    if (record.segments[i].kind == "approach") approach_segments.push_back(i);
  }
  const auto output_samples =
      static_cast<size_t>(scenario.duration_s * scenario.output.groundtruth_rate_hz + 2);
  record.tracking.reserve(output_samples);
  if (keep_samples || keep_for_consistency) record.groundtruth.reserve(output_samples);
  if (keep_samples) record.references.reserve(output_samples);
  CollisionTracker collisions;

  const auto wall_start = std::chrono::steady_clock::now();
  const int64_t steps_per_minute = std::max<int64_t>(1, std::llround(60.0 * scenario.physics.rate_hz));
  try {
    for (int64_t step = 0; step < total_steps; ++step) {
      const core::Time t_ns = world.time_ns();
      const sim::TruthState now = world.Truth();
      if (t_ns >= next_controller_ns) {
        sim::Reference reference = trajectory->Sample(t_ns);
        sim::RobotState state = ToRobotState(now);
        if (pilot) {
          // The flying method's newest output: only samples with arrival <= t_ns made it.
          const estimator::EstimatorOutput* newest = nullptr;
          if (in_loop.started() && !in_loop.runner(0).outputs().empty()) {
            newest = &in_loop.runner(0).outputs().back();
          }
          if (!pilot->handed_over() &&
              pilot->TryHandover(t_ns, newest, PoseOf(now.p_WB, now.q_WB))) {
            record.closed_loop->handover_ns = t_ns;
            record.closed_loop->T_WL = pilot->T_WL();
          }
          if (pilot->handed_over()) {
            const ClosedLoopPilot::Command command = pilot->Fly(t_ns, *newest, reference);
            state = command.state;
            reference = command.reference;
            disarmed = command.disarmed;
          }
        }
        const sim::Wrench wrench = controller.Compute(state, reference);
        sim::AllocationResult allocation = allocator.Allocate(wrench, now.tilt_rad);
        if (disarmed) allocation.command.rotor_thrust_N.fill(0.0);
        world.SetCommand(allocation.command);
        record.saturation.emplace_back(t_ns, allocation.saturated);
        next_controller_ns += controller_period_ns;
      }
      wind.Advance(dt_s);
      world.SetExternalForce_W(wind.DragForce_W(now.v_WB_W));

      const sim::TruthState& truth = world.Step();
      ++record.physics_steps;
      if (record.physics_steps % steps_per_minute == 0) {
        record.minutes.push_back(
            {std::chrono::duration<double>(std::chrono::steady_clock::now() - wall_start).count(),
             ResidentMegabytes()});
      }

      if (truth.t_ns >= next_output_ns) {
        const sim::Reference reference = trajectory->Sample(truth.t_ns);
        const TrackingSample tracking{
            truth.t_ns, (truth.p_WB - reference.p_WB).norm(),
            core::RotationAngleBetween(reference.q_WB.toRotationMatrix(),
                                       truth.q_WB.toRotationMatrix())};
        record.tracking.push_back(tracking);
        if (keep_samples || keep_for_consistency) record.groundtruth.push_back(truth);
        if (keep_samples) record.references.push_back(reference);
        const ClosedLoopSample* flown = nullptr;
        if (pilot) {
          ClosedLoopSample sample;
          sample.t_ns = truth.t_ns;
          sample.mode = pilot->mode();
          if (const auto& believed = pilot->last_state()) {
            sample.p_WB_est = believed->p_WB;
            sample.q_WB_est = believed->q_WB;
            sample.estimate_squared_error_m2 = (believed->p_WB - truth.p_WB).squaredNorm();
          }
          sample.structure_distance_m = structure_distance_m;
          record.closed_loop->samples.push_back(sample);
          flown = &record.closed_loop->samples.back();
        }
        if (recorder) recorder->AddGroundTruth(truth, reference, tracking, flown);
        next_output_ns += output_period_ns;
      }

      if (!models.empty()) {
        const auto rotor_thrust_N = world.RotorThrusts_N();
        const sim::SensorInput input{truth, world, rotor_thrust_N};
        for (size_t i = 0; i < models.size(); ++i) {
          SensorStream& stream = record.sensors[i];
          const auto* imu = dynamic_cast<const sim::ImuModel*>(models[i].get());
          std::pair<Eigen::Vector3d, Eigen::Vector3d> bias;
          if (imu != nullptr) bias = {imu->gyro_bias_radps(), imu->accel_bias_mps2()};
          sensor_scratch.clear();
          models[i]->Step(input, &sensor_scratch);
          for (const sim::SensorSample& sample : sensor_scratch) {
            ++stream.produced_count;
            if (keep_samples) {
              stream.clean.push_back(sample);
              if (imu != nullptr) stream.imu_biases.push_back(bias);
            }
            if (recorder) recorder->AddClean(i, sample, imu != nullptr ? &bias : nullptr);
            delivered_scratch.clear();
            injectors[i].Apply(sample, &delivered_scratch);
            const uint32_t faults = injectors[i].ActiveFaults(sample.t_ns);
            for (sim::SensorSample& delivered : delivered_scratch) {
              if (options.tamper && !in_loop.empty()) options.tamper(stream.name, delivered);
              RecordDelivered(delivered, faults,
                              keep_samples || (keep_for_consistency && imu == nullptr), stream);
              if (recorder) recorder->AddDelivered(i, delivered, faults);
              if (!in_loop.empty()) delivered_queue.Push(i, delivered);
            }
            if (!in_loop.empty() && in_loop.any_clean()) clean_queue.Push(i, sample);
          }
          const uint32_t now_conditions = models[i]->conditions();
          if (now_conditions != conditions[i]) {
            for (const sim::Condition bit : sim::AllConditions()) {
              if (((now_conditions ^ conditions[i]) & bit) == 0) continue;
              record.labels.push_back({truth.t_ns, stream.name,
                                       std::string(sim::ConditionName(bit)), "condition",
                                       (now_conditions & bit) != 0});
              if (in_loop.started()) in_loop.AddLabel(record.labels.back());
            }
            conditions[i] = now_conditions;
          }
        }
      }

      // Every sample that has arrived by the end of this step reaches its consumers before
      // the controller's next update.
      release(truth.t_ns, false);

      const std::vector<sim::Contact>& contacts = world.Contacts();
      collisions.Update(world.time_ns(), contacts, world, record.collisions);
      const auto closest = world.ClosestStructure();
      structure_distance_m.reset();
      if (closest) structure_distance_m = closest->distance_m;
      if (closest && (!record.closest_structure ||
                      closest->distance_m < record.closest_structure->proximity.distance_m)) {
        record.closest_structure = ProximityRecord{world.time_ns(), *closest};
      }

      // Where the tool tip stands when an approach segment's reference comes to rest.
      if (next_approach < approach_segments.size()) {
        const sim::SegmentInfo& seg = record.segments[approach_segments[next_approach]];
        if (world.time_ns() >= seg.end_ns) {
          const Eigen::Isometry3d T_W_tip = world.SitePose_W("tool_tip");
          record.approaches.push_back(
              {static_cast<int>(approach_segments[next_approach]), world.time_ns(),
               seg.approach_standoff_m,
               world.RayDistance(T_W_tip.translation(), seg.approach_direction_W)});
          ++next_approach;
        }
      }

      if (options.progress && step % progress_every == 0) {
        options.progress(static_cast<double>(step) / static_cast<double>(total_steps));
      }
    }
  } catch (const core::SimulationError& e) {
    record.failure = e.what();
  }
  if (recorder) recorder->Close();
  record.wall_time_s =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - wall_start).count();

  // The true reference frames are known once the models have started (e.g. VIO's
  // odometry frame is where the camera booted).
  for (size_t i = 0; i < models.size(); ++i) record.sensors[i].T_WS = models[i]->T_WS();
  // What was recorded but had not arrived when the flight ended still reaches the
  // methods: the recorded run's replay sees it too.
  if (!record.failure) {
    release(0, true);
    record.in_loop = in_loop.Finish();
  }
  if (pilot) record.closed_loop->events = pilot->events();
  // Scheduled faults as labels, merged with the condition transitions by time.
  const core::Time run_end_ns = record.physics_steps * dt_ns;
  for (const sim::FaultLabel& label : sim::FaultLabels(scenario.faults, run_end_ns)) {
    record.labels.push_back({label.t_ns, label.sensor, label.fault, "fault", label.active});
  }
  std::stable_sort(record.labels.begin(), record.labels.end(),
                   [](const LabelEvent& a, const LabelEvent& b) { return a.t_ns < b.t_ns; });
  if (scenario.consistency && !record.failure) {
    record.consistency = EvaluateConsistency(record, *scenario.consistency);
  }
  if (options.progress) options.progress(1.0);

  if (!options.fly_on) record.closed_loop_flights = FlyClosedLoopFlights(scenario, options);
  return record;
}

std::vector<RunRecord> FlyClosedLoopFlights(const Scenario& scenario,
                                            const SimulateOptions& options) {
  std::vector<RunRecord> flights;
  if (!scenario.control ||
      scenario.control->state_source != ControlConfig::StateSource::kEstimate) {
    return flights;
  }
  for (const std::string& method : scenario.control->methods) {
    SimulateOptions flight;
    flight.models_dir = options.models_dir;
    flight.fly_on = method;
    flight.tamper = options.tamper;
    if (options.record_dir) {
      flight.record_dir = *options.record_dir / "closed_loop" / replay::MethodFileStem(method);
      std::filesystem::create_directories(*flight.record_dir);
    }
    if (options.closed_loop_progress) {
      flight.progress = [&](double f) { options.closed_loop_progress(method, f); };
    }
    flights.push_back(Simulate(scenario, flight));
  }
  return flights;
}

}  // namespace tofu::harness
