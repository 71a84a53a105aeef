#include "harness/run.h"

#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <exception>
#include <fstream>
#include <limits>
#include <memory>
#include <optional>
#include <stdexcept>
#include <thread>
#include <variant>

#include "core/digest.h"
#include "core/error.h"
#include "core/lie.h"
#include "core/random.h"
#include "harness/client_config.h"
#include "harness/controllers.h"
#include "harness/in_loop_methods.h"
#include "harness/run_directory.h"
#include "harness/run_recorder.h"
#include "harness/sample_stream.h"
#include "replay/recorded_log.h"
#include "replay/run_format.h"
#include "sim/allocation.h"
#include "sim/controller.h"
#include "sim/wind.h"

namespace tofu::harness {

using replay::EstimationConfig;
using replay::LabelEvent;
using replay::MethodRunner;

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

Eigen::Isometry3d PoseOf(const Eigen::Vector3d& p, const Eigen::Quaterniond& q) {
  Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
  T.linear() = q.normalized().toRotationMatrix();
  T.translation() = p;
  return T;
}

// The IMU's nominal mount T_BI (what the flight stack is told), identity without one.
Eigen::Isometry3d NominalImuMount(const Scenario& scenario, const sim::RobotDescription& robot) {
  for (const SensorConfig& config : scenario.sensors) {
    if (!std::holds_alternative<sim::ImuOptions>(config.options)) continue;
    const sim::MountSite* site = robot.FindSite(SensorSite(config.options));
    if (site == nullptr) break;
    return PoseOf(site->p_Bs, site->q_Bs) * config.calibration_error;
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

namespace {

// One flight of a scenario: the world, the controller and its pilot, the sensor models
// with their fault injectors, and the consumers of the arrival-ordered sample stream (the
// recorder and the in-loop methods). Simulate builds it, steps it and finishes it; each
// method is one part of a physics step (DESIGN.md "The run loop").
class Flight {
 public:
  Flight(const Scenario& scenario, const SimulateOptions& options, RunRecord& record)
      : scenario_(scenario), options_(options), record_(record) {
    core::RandomStreamLedger random_streams;
    {
      const core::RandomStreamLedger::Scope scope(random_streams);
      BuildWorld();
      BuildSensors();
      BuildConsumers();
    }
    record_.random_streams_digest = random_streams.Digest();
    wall_start_ = std::chrono::steady_clock::now();  // the flight's wall time, not the set-up's
  }

  int64_t total_steps() const { return total_steps_; }

  // The simulation failed after the robot had hit the structure or the ground (MuJoCo's
  // non-finite accelerations of a robot tumbling under saturated thrust): the crash ended
  // the flight, which is scored as flown with this stated among its events. A failure
  // before any contact stays the simulation's failure (RunRecord::failure).
  bool EndsAfterCollision(const core::SimulationError& e) {
    if (!pilot_ || record_.collisions.empty()) return false;
    ended_after_collision_ = FlightEvent{world_->time_ns(), "ended_after_collision", e.what()};
    return true;
  }

  // One physics step: control (when due), physics, ground truth (when due), sensors, the
  // release of what has arrived, contacts and structure distance.
  void Step(int64_t step) {
    const core::Time t_ns = world_->time_ns();
    const sim::TruthState now = world_->Truth();
    if (t_ns >= next_controller_ns_) Control(t_ns, now);
    wind_->Advance(dt_s_);
    world_->SetExternalForce_W(wind_->DragForce_W(now.v_WB_W));

    const sim::TruthState& truth = world_->Step();
    ++record_.physics_steps;
    if (record_.physics_steps % steps_per_minute_ == 0) {
      record_.minutes.push_back({WallSeconds(), ResidentMegabytes()});
    }
    if (truth.t_ns >= next_output_ns_) RecordGroundTruth(truth);
    if (!models_.empty()) StepSensors(truth);
    // Every sample that has arrived by the end of this step reaches its consumers before
    // the controller's next update.
    Release(truth.t_ns, false);
    WatchStructure();
    if (options_.progress && step % progress_every_ == 0) {
      options_.progress(static_cast<double>(step) / static_cast<double>(total_steps_));
    }
  }

  // After the last step (or a SimulationError): close the recording, hand the samples
  // still in flight to the methods, merge the labels, evaluate consistency.
  void Finish() {
    if (recorder_) recorder_->Close();
    FinishController(*controller_);
    record_.wall_time_s = WallSeconds();
    // The true reference frames are known once the models have started (e.g. VIO's
    // odometry frame is where the camera booted).
    for (size_t i = 0; i < models_.size(); ++i) record_.sensors[i].T_WS = models_[i]->T_WS();
    // What was recorded but had not arrived when the flight ended still reaches the
    // methods: the recorded run's replay sees it too.
    if (!record_.failure) {
      Release(0, true);
      record_.in_loop = in_loop_->Finish();
    }
    if (!in_loop_->empty()) record_.samples_digest = samples_digest_.value();
    if (pilot_) record_.closed_loop->events = pilot_->events();
    if (ended_after_collision_) record_.closed_loop->events.push_back(*ended_after_collision_);
    // Scheduled faults as labels, merged with the condition transitions by time.
    const core::Time run_end_ns = record_.physics_steps * dt_ns_;
    for (const sim::FaultLabel& label : sim::FaultLabels(scenario_.faults, run_end_ns)) {
      record_.labels.push_back({label.t_ns, label.sensor, label.fault, "fault", label.active});
    }
    std::stable_sort(record_.labels.begin(), record_.labels.end(),
                     [](const LabelEvent& a, const LabelEvent& b) { return a.t_ns < b.t_ns; });
    if (scenario_.consistency && !record_.failure) {
      record_.consistency = EvaluateConsistency(record_, *scenario_.consistency);
    }
  }

 private:
  double WallSeconds() const {
    return std::chrono::duration<double>(std::chrono::steady_clock::now() - wall_start_).count();
  }

  // The MuJoCo world, the reference trajectory, the controller, allocation and wind.
  void BuildWorld() {
    sim::WorldOptions world_options;
    world_options.models_dir = options_.models_dir;
    world_options.world = scenario_.world;
    world_options.robot = scenario_.robot;
    world_options.physics_rate_hz = scenario_.physics.rate_hz;
    record_.distance_horizon_m = world_options.distance_horizon_m;
    try {
      world_ = std::make_unique<sim::World>(world_options);
    } catch (const core::InputError& e) {
      // Name the scenario that asked for the model, and the model's own problem.
      throw core::InputError({scenario_.source_file, 0, 0}, e.key_path(), e.what());
    }
    record_.robot = world_->robot();

    sim::TrajectoryContext context;
    context.p_B_tool = record_.robot.FindSite("tool_tip")->p_Bs;
    context.surface_distance = [world = world_.get()](const Eigen::Vector3d& origin_W,
                                                      const Eigen::Vector3d& direction_W) {
      return world->RayDistance(origin_W, direction_W);
    };
    try {
      trajectory_ = sim::BuildTrajectory(scenario_.trajectory, context);
    } catch (const std::invalid_argument& e) {
      throw core::InputError({scenario_.source_file, 0, 0}, "trajectory.segments", e.what());
    }
    record_.segments = trajectory_->segments();
    const sim::Reference first = trajectory_->Sample(0);
    put_down_.p_WB = first.p_WB;
    put_down_.q_WB = first.q_WB;
    for (size_t i = 0; i < record_.segments.size(); ++i) {
      if (record_.segments[i].kind == "approach") approach_segments_.push_back(i);
    }

    const sim::Waypoint& start = scenario_.trajectory.start;
    world_->Reset(sim::Waypoint{start.p_WB + scenario_.initial_offset.position_W_m,
                                start.q_WB * scenario_.initial_offset.q_offset});
    const replay::ClientSpec* client = nullptr;
    if (scenario_.control && scenario_.control->controller) {
      controller_name_ = *scenario_.control->controller;
      client = FindClient(scenario_.clients, controller_name_);
    }
    controller_ = StartController(client, scenario_.controller, record_.robot.rigid_body,
                                  record_.robot.allocation);
    allocator_.emplace(record_.robot.allocation);
    wind_.emplace(scenario_.wind, core::RandomStream(scenario_.seed, "wind"));

    dt_ns_ = world_->timestep_ns();
    dt_s_ = core::TimeToSeconds(dt_ns_);
    controller_period_ns_ = core::PeriodFromRate(scenario_.controller.rate_hz);
    output_period_ns_ = core::PeriodFromRate(scenario_.output.groundtruth_rate_hz);
    total_steps_ = std::llround(scenario_.duration_s * scenario_.physics.rate_hz);
    progress_every_ = std::max<int64_t>(1, total_steps_ / 200);
    steps_per_minute_ = std::max<int64_t>(1, std::llround(60.0 * scenario_.physics.rate_hz));
  }

  // One model per configured stream, its scheduled faults in an injector. Each draws only
  // from streams seeded by (seed, its own name).
  void BuildSensors() {
    for (const SensorConfig& config : scenario_.sensors) {
      try {
        models_.push_back(MakeSensorModel(config, *world_, scenario_.seed));
        imu_models_.push_back(dynamic_cast<const sim::ImuModel*>(models_.back().get()));
      } catch (const std::invalid_argument& e) {
        throw core::InputError({scenario_.source_file, 0, 0}, "sensors." + config.name, e.what());
      }
      std::vector<sim::FaultSpec> specs;
      for (const sim::FaultSpec& fault : scenario_.faults) {
        if (fault.sensor == config.name) specs.push_back(fault);
      }
      injectors_.emplace_back(std::move(specs), scenario_.seed);
      SensorStream stream;
      stream.name = config.name;
      stream.type = std::string(SensorTypeName(config.options));
      stream.kind = SensorMeasurementKind(config.options);
      stream.site = SensorSite(config.options);
      stream.sky_directions_S = models_.back()->sky_directions_S();
      record_.sensors.push_back(std::move(stream));
      conditions_.push_back(sim::kConditionNone);
    }
  }

  // The recorder, what the record keeps, the in-loop methods and their queues, the pilot.
  void BuildConsumers() {
    // With a record_dir every per-sample file is written as produced and the record keeps
    // only what the evaluation needs (RunRecord::recorded_to).
    if (options_.record_dir) {
      recorder_.emplace(*options_.record_dir,
                        RecorderLayoutOf(record_, options_.fly_on.has_value()));
      record_.recorded_to = *options_.record_dir;
    }
    keep_samples_ = !recorder_;
    // The consistency evaluation (consistency_eval.h) reads the non-IMU streams and the
    // ground truth of the whole run after it.
    keep_for_consistency_ = scenario_.consistency.has_value();
    if (keep_samples_) {
      // A sample is ~1.5 kB (core::Measurement holds a pose's two 6x6 covariances): growing
      // the streams by doubling copied them and touched twice their final memory.
      for (size_t i = 0; i < record_.sensors.size(); ++i) {
        SensorStream& stream = record_.sensors[i];
        const auto expected_samples = static_cast<size_t>(std::ceil(
                                          scenario_.duration_s *
                                          SensorRate_hz(scenario_.sensors[i].options))) + 2;
        stream.clean.reserve(expected_samples);
        stream.delivered.reserve(expected_samples);
        stream.delivered_faults.reserve(expected_samples);
        if (stream.kind == core::MeasurementKind::kImu) stream.imu_biases.reserve(expected_samples);
      }
    }

    // The run's consumers of the arrival-ordered sample stream besides the recorder: the
    // estimation methods in the loop, and through the flying one, the controller.
    std::vector<std::string> in_loop_names;
    if (options_.fly_on) {
      in_loop_names.push_back(*options_.fly_on);
    } else if (scenario_.estimation) {
      in_loop_names = scenario_.estimation->methods;
    }
    in_loop_.emplace(in_loop_names,
                     scenario_.estimation ? *scenario_.estimation
                                         : EstimationConfig::Defaults(EstimationConfig::kDefaultProfile),
                     options_.threads, options_.fly_on.has_value());
    const std::vector<uint32_t> stream_rank = RanksByName(record_.sensors);
    delivered_queue_.emplace(stream_rank);
    clean_queue_.emplace(stream_rank);
    std::vector<LabelEvent> schedule;
    for (const sim::FaultLabel& label :
         sim::FaultLabels(scenario_.faults, total_steps_ * dt_ns_)) {
      schedule.push_back({label.t_ns, label.sensor, label.fault, "fault", label.active});
    }
    in_loop_->SetFaultSchedule(std::move(schedule));

    // A closed-loop flight: the pilot between the flying method and the controller.
    if (options_.fly_on) {
      const ControlConfig control = scenario_.control.value_or(ControlConfig{});
      const sim::Waypoint launch_pad = LaunchPad(scenario_);
      pilot_.emplace(control.failsafe, NominalImuMount(scenario_, record_.robot),
                     PoseOf(launch_pad.p_WB, launch_pad.q_WB));
      record_.closed_loop.emplace();
      record_.closed_loop->method = *options_.fly_on;
      record_.closed_loop->control = control;
    }

    const auto output_samples =
        static_cast<size_t>(scenario_.duration_s * scenario_.output.groundtruth_rate_hz + 2);
    record_.tracking.reserve(output_samples);
    if (keep_samples_ || keep_for_consistency_) record_.groundtruth.reserve(output_samples);
    if (keep_samples_) record_.references.reserve(output_samples);
  }

  // The controller's update: the reference, the state it flies on (ground truth, or the
  // pilot's view of the flying method's newest output), allocation to the actuators.
  void Control(core::Time t_ns, const sim::TruthState& now) {
    sim::Reference reference = trajectory_->Sample(t_ns);
    sim::RobotState state = ToRobotState(now);
    if (pilot_) {
      // The flying method's newest output: only samples with arrival <= t_ns made it.
      const estimator::EstimatorOutput* newest = nullptr;
      if (in_loop_->started()) {
        const MethodRunner& flying = in_loop_->SyncFlying();
        newest = flying.newest_output();
      }
      if (!pilot_->handed_over() && pilot_->TryHandover(t_ns, newest)) {
        record_.closed_loop->handover_ns = t_ns;
      }
      if (pilot_->handed_over()) {
        const ClosedLoopPilot::Command command = pilot_->Fly(t_ns, *newest, reference);
        state = command.state;
        reference = command.reference;
        disarmed_ = command.disarmed;
      } else {
        // Until the estimator can fly, the robot holds where it was put down, as one on its
        // pad would: a mission that left before the handover registers M to the estimate
        // at a pose the robot has already left (the pad's), an error the flight never
        // recovers from (a figure-eight from t = 0: 0.47 m at the handover, then 33
        // contacts).
        reference = put_down_;
      }
    }
    sim::AllocationResult allocation =
        ComputeActuation(*controller_, controller_name_, state, pilot_ && pilot_->handed_over(),
                         reference, *allocator_, now.tilt_rad);
    if (disarmed_) allocation.command.rotor_thrust_N.fill(0.0);
    world_->SetCommand(allocation.command);
    record_.saturation.emplace_back(t_ns, allocation.saturated);
    next_controller_ns_ += controller_period_ns_;
  }

  // Tracking error against the reference, ground truth, the closed-loop sample.
  void RecordGroundTruth(const sim::TruthState& truth) {
    const sim::Reference reference = trajectory_->Sample(truth.t_ns);
    const TrackingSample tracking{
        truth.t_ns, (truth.p_WB - reference.p_WB).norm(),
        core::RotationAngleBetween(reference.q_WB.toRotationMatrix(),
                                   truth.q_WB.toRotationMatrix())};
    record_.tracking.push_back(tracking);
    if (keep_samples_ || keep_for_consistency_) record_.groundtruth.push_back(truth);
    if (keep_samples_) record_.references.push_back(reference);
    const ClosedLoopSample* flown = nullptr;
    if (pilot_) {
      ClosedLoopSample sample;
      sample.t_ns = truth.t_ns;
      sample.mode = pilot_->mode();
      if (const auto& believed = pilot_->last_state()) {
        sample.p_WB_est = believed->p_WB;
        sample.q_WB_est = believed->q_WB;
        sample.estimate_squared_error_m2 = (believed->p_WB - truth.p_WB).squaredNorm();
      }
      sample.structure_distance_m = structure_distance_m_;
      record_.closed_loop->samples.push_back(sample);
      flown = &record_.closed_loop->samples.back();
    }
    if (recorder_) recorder_->AddGroundTruth(truth, reference, tracking, flown);
    next_output_ns_ += output_period_ns_;
  }

  // Each model's samples of this step: recorded clean, through its injector, recorded as
  // delivered and queued for the in-loop methods; condition transitions become labels.
  void StepSensors(const sim::TruthState& truth) {
    const auto rotor_thrust_N = world_->RotorThrusts_N();
    const sim::SensorInput input{truth, *world_, rotor_thrust_N};
    for (size_t i = 0; i < models_.size(); ++i) {
      SensorStream& stream = record_.sensors[i];
      const sim::ImuModel* imu = imu_models_[i];
      std::pair<Eigen::Vector3d, Eigen::Vector3d> bias;
      if (imu != nullptr) bias = {imu->gyro_bias_radps(), imu->accel_bias_mps2()};
      sensor_scratch_.clear();
      models_[i]->Step(input, &sensor_scratch_);
      for (const sim::SensorSample& sample : sensor_scratch_) {
        ++stream.produced_count;
        if (keep_samples_) {
          stream.clean.push_back(sample);
          if (imu != nullptr) stream.imu_biases.push_back(bias);
        }
        if (recorder_) recorder_->AddClean(i, sample, imu != nullptr ? &bias : nullptr);
        delivered_scratch_.clear();
        injectors_[i].Apply(sample, &delivered_scratch_);
        const uint32_t faults = injectors_[i].ActiveFaults(sample.t_ns);
        for (sim::SensorSample& delivered : delivered_scratch_) {
          if (options_.tamper && !in_loop_->empty()) options_.tamper(stream.name, delivered);
          RecordDelivered(delivered, faults,
                          keep_samples_ || (keep_for_consistency_ && imu == nullptr), stream);
          if (recorder_) recorder_->AddDelivered(i, delivered, faults);
          if (!in_loop_->empty()) delivered_queue_->Push(i, delivered);
        }
        if (!in_loop_->empty() && in_loop_->any_clean()) clean_queue_->Push(i, sample);
      }
      RecordConditions(i, truth.t_ns);
    }
  }

  void RecordConditions(size_t i, core::Time t_ns) {
    const uint32_t now_conditions = models_[i]->conditions();
    if (now_conditions == conditions_[i]) return;
    for (const sim::Condition bit : sim::AllConditions()) {
      if (((now_conditions ^ conditions_[i]) & bit) == 0) continue;
      record_.labels.push_back({t_ns, record_.sensors[i].name, std::string(sim::ConditionName(bit)),
                                "condition", (now_conditions & bit) != 0});
      if (in_loop_->started()) in_loop_->AddLabel(record_.labels.back());
    }
    conditions_[i] = now_conditions;
  }

  // The samples that have arrived by now_ns (all of them with `flush`) to the in-loop
  // methods, in (arrival, stream rank, t, order).
  void Release(core::Time now_ns, bool flush) {
    if (in_loop_->empty()) return;
    if (!in_loop_->started()) {
      // The models have latched their reference frames by now (first step).
      for (size_t i = 0; i < models_.size(); ++i) record_.sensors[i].T_WS = models_[i]->T_WS();
      in_loop_->Start(record_, options_.record_dir);
    }
    const auto feed = [&](bool clean) {
      return [&, clean](const ArrivedSample& a) {
        if (a.sample->arrival_ns < released_until_ns_) ++record_.late_samples;
        samples_digest_.Add(record_.sensors[a.stream].name).Add(uint64_t{clean});
        samples_digest_.Add(static_cast<uint64_t>(a.sample->t_ns)).Add(static_cast<uint64_t>(a.sample->arrival_ns));
        core::HashMeasurement(a.sample->measured, samples_digest_);
        in_loop_->Feed(clean, record_.sensors, a);
      };
    };
    if (flush) {
      delivered_queue_->Flush(feed(false));
      clean_queue_->Flush(feed(true));
    } else {
      delivered_queue_->Release(now_ns, feed(false));
      clean_queue_->Release(now_ns, feed(true));
      released_until_ns_ = now_ns;
    }
  }

  // Collisions, the closest structure, and where the tool tip stands when an approach
  // segment's reference comes to rest.
  void WatchStructure() {
    const std::vector<sim::Contact>& contacts = world_->Contacts();
    collisions_.Update(world_->time_ns(), contacts, *world_, record_.collisions);
    const auto closest = world_->ClosestStructure();
    structure_distance_m_.reset();
    if (closest) structure_distance_m_ = closest->distance_m;
    if (closest && (!record_.closest_structure ||
                    closest->distance_m < record_.closest_structure->proximity.distance_m)) {
      record_.closest_structure = ProximityRecord{world_->time_ns(), *closest};
    }
    if (next_approach_ < approach_segments_.size()) {
      const sim::SegmentInfo& seg = record_.segments[approach_segments_[next_approach_]];
      if (world_->time_ns() >= seg.end_ns) {
        const Eigen::Isometry3d T_W_tip = world_->SitePose_W("tool_tip");
        record_.approaches.push_back(
            {static_cast<int>(approach_segments_[next_approach_]), world_->time_ns(),
             seg.approach_standoff_m,
             world_->RayDistance(T_W_tip.translation(), seg.approach_direction_W)});
        ++next_approach_;
      }
    }
  }

  const Scenario& scenario_;
  const SimulateOptions& options_;
  RunRecord& record_;

  // The world and what flies the robot.
  std::unique_ptr<sim::World> world_;
  std::unique_ptr<sim::Trajectory> trajectory_;
  /// At rest where the trajectory starts: a closed-loop flight's reference before handover.
  sim::Reference put_down_;
  std::unique_ptr<api::Controller> controller_;
  std::string controller_name_ = kBuiltinControllerName;
  std::optional<sim::Allocator> allocator_;
  std::optional<sim::Wind> wind_;
  std::optional<ClosedLoopPilot> pilot_;
  bool disarmed_ = false;
  std::optional<FlightEvent> ended_after_collision_;

  // Sensors.
  std::vector<std::unique_ptr<sim::SensorModel>> models_;
  /// models_[i] when it is an IMU (whose biases are recorded with its samples), else null.
  std::vector<const sim::ImuModel*> imu_models_;
  std::vector<sim::FaultInjector> injectors_;
  std::vector<uint32_t> conditions_;
  std::vector<sim::SensorSample> sensor_scratch_;
  std::vector<sim::SensorSample> delivered_scratch_;

  // Consumers of the sample stream.
  std::optional<RunRecorder> recorder_;
  bool keep_samples_ = true;
  bool keep_for_consistency_ = false;
  std::optional<InLoopMethods> in_loop_;
  std::optional<ArrivalQueue> delivered_queue_;
  std::optional<ArrivalQueue> clean_queue_;
  core::Time released_until_ns_ = std::numeric_limits<core::Time>::min();
  core::Fnv1a64Hasher samples_digest_;

  // Clocks and what the steps watch.
  core::Time dt_ns_ = 0;
  double dt_s_ = 0.0;
  core::Time controller_period_ns_ = 0;
  core::Time output_period_ns_ = 0;
  int64_t total_steps_ = 0;
  int64_t progress_every_ = 1;
  int64_t steps_per_minute_ = 1;
  core::Time next_controller_ns_ = 0;
  core::Time next_output_ns_ = 0;
  std::vector<size_t> approach_segments_;
  size_t next_approach_ = 0;
  std::optional<double> structure_distance_m_;
  CollisionTracker collisions_;
  std::chrono::steady_clock::time_point wall_start_;
};

}  // namespace

RunRecord Simulate(const Scenario& scenario, const SimulateOptions& options) {
  RunRecord record;
  record.scenario = scenario;
  Flight flight(scenario, options, record);
  try {
    for (int64_t step = 0; step < flight.total_steps(); ++step) flight.Step(step);
  } catch (const core::SimulationError& e) {
    if (!flight.EndsAfterCollision(e)) record.failure = e.what();
  }
  flight.Finish();
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
  const std::vector<std::string>& methods = scenario.control->methods;
  std::vector<SimulateOptions> flown(methods.size());
  for (std::size_t i = 0; i < methods.size(); ++i) {
    SimulateOptions& flight = flown[i];
    flight.models_dir = options.models_dir;
    flight.fly_on = methods[i];
    flight.tamper = options.tamper;
    if (options.record_dir) {
      flight.record_dir = *options.record_dir / "closed_loop" / replay::MethodFileStem(methods[i]);
      std::filesystem::create_directories(*flight.record_dir);
    }
    if (options.closed_loop_progress) {
      flight.progress = [&options, &method = methods[i]](double f) {
        options.closed_loop_progress(method, f);
      };
    }
  }
  // The flights share nothing (each its world, estimator and files) and are the same
  // whichever thread flies them: up to `threads` at a time, each on one thread (its one
  // method is flown on). closed_loop_progress is then called from several threads.
  flights.resize(methods.size());
  const std::size_t parallel =
      std::min<std::size_t>(methods.size(), static_cast<std::size_t>(std::max(1, options.threads)));
  std::atomic<std::size_t> next{0};
  std::vector<std::exception_ptr> errors(methods.size());
  const auto fly = [&] {
    for (std::size_t i = next++; i < methods.size(); i = next++) {
      try {
        flights[i] = Simulate(scenario, flown[i]);
      } catch (...) {
        errors[i] = std::current_exception();
      }
    }
  };
  std::vector<std::thread> pilots;
  for (std::size_t t = 1; t < parallel; ++t) pilots.emplace_back(fly);
  fly();
  for (std::thread& pilot : pilots) pilot.join();
  for (const std::exception_ptr& error : errors) {
    if (error) std::rethrow_exception(error);
  }
  return flights;
}

}  // namespace tofu::harness
