// Simulation speed: the harness's run loop on a 200 s scenario at 1 kHz physics against
// bare mj_step on the very same compiled model. Results go to docs/BENCHMARKS.md.
// The machine is shared: pin to one core, repeat, and read the "_min" and "_median" rows:
//
//   taskset -c 1 build/bench/bench_simulation --benchmark_repetitions=10

#include <algorithm>
#include <cmath>
#include <vector>

#include <benchmark/benchmark.h>
#include <mujoco/mujoco.h>

#include "core/lidar_beam_pattern.h"
#include "harness/run.h"
#include "harness/scenario.h"
#include "sim/world.h"

namespace {

using tofu::harness::Scenario;

constexpr double kDurationS = 200.0;

// Figure-eights for 200 s in the indoor arena with gusts: controller, trajectory, wind,
// contacts and distance queries all active; optionally the full sensor suite.
Scenario BenchScenario(bool with_sensors) {
  const std::string sensors = with_sensors ? R"(sensors:
  imu: {}
  vio: {}
  lidar: {type: lidar_odometry}
  leica: {type: total_station}
  gnss: {}
)"
                                           : "";
  return tofu::harness::ParseScenario(R"(
name: bench_figure_eight
world: indoor_arena
duration_s: 200
seed: 1
wind: {gust_std_mps: 0.2}
trajectory:
  start: {position_m: [0, 0, 1.5]}
  limits: {max_speed_mps: 1.0, max_acceleration_mps2: 2.0}
  segments:
    - figure_eight: {center_m: [0, 0, 1.5], half_length_m: 2.0, half_width_m: 1.2, speed_mps: 1.0, laps: 14}
)" + sensors,
                                      "bench_figure_eight");
}

// The fastest of a benchmark's repetitions: on a shared VM, interference only ever adds
// time, so the minimum is the best estimate of what the code costs; the median says what
// a user on a busy machine sees. Both go to docs/BENCHMARKS.md. Google Benchmark applies
// a statistic to every column, so the "_min" row's counters are each counter's smallest
// (the slowest repetition's rates): read the fastest run's factor as 200 s / its time.
double Fastest(const std::vector<double>& v) { return *std::min_element(v.begin(), v.end()); }

// Both benchmarks: a flag argument (0, 1), one 200 s run per repetition, wall time in ms,
// and the fastest repetition beside the median.
void OneRunPerRepetition(benchmark::internal::Benchmark* b, const char* arg_name) {
  b->ArgName(arg_name)
      ->Arg(0)
      ->Arg(1)
      ->Unit(benchmark::kMillisecond)
      ->UseRealTime()
      ->Iterations(1)
      ->ComputeStatistics("min", Fastest);
}

void BM_HarnessRun200s(benchmark::State& state) {
  const Scenario scenario = BenchScenario(state.range(0) != 0);
  double simulated_s = 0.0;
  double loop_s = 0.0;
  for (auto _ : state) {
    const tofu::harness::RunRecord record = tofu::harness::Simulate(scenario);
    benchmark::DoNotOptimize(record.groundtruth.data());
    simulated_s += static_cast<double>(record.physics_steps) / scenario.physics.rate_hz;
    loop_s += record.wall_time_s;
  }
  // End to end (loading the models, building the trajectory, the run, the summary's
  // inputs), as a user's `tofu run` experiences it.
  state.counters["real_time_factor"] =
      benchmark::Counter(simulated_s, benchmark::Counter::kIsRate);
  // The stepping loop alone (what summary.json reports as the run's real-time factor).
  state.counters["loop_real_time_factor"] = simulated_s / loop_s;
  state.counters["steps_per_s"] =
      benchmark::Counter(simulated_s * scenario.physics.rate_hz, benchmark::Counter::kIsRate);
}
// Arg 0: flight only; arg 1: with IMU, VIO, LiDAR odometry, total station and GNSS.
BENCHMARK(BM_HarnessRun200s)->Apply([](benchmark::internal::Benchmark* b) {
  OneRunPerRepetition(b, "sensors");
});

// Bare mj_step on the model the World steps (the robot's visual-only bodies cut out), the
// robot hovering on constant hover controls. Arg 0: MuJoCo's collision detection in every
// step (MuJoCo alone); arg 1: contacts off, as the World's contact gate runs MuJoCo while
// no world geom is within the robot's reach (the floor under the harness's flight).
void BM_BareMjStep200s(benchmark::State& state) {
  tofu::sim::WorldOptions options;
  options.world = "indoor_arena";
  tofu::sim::World world(options);
  world.Reset({Eigen::Vector3d(0, 0, 1.5), Eigen::Quaterniond::Identity()});
  mjModel* m = mj_copyModel(nullptr, world.physics_model());
  if (state.range(0) == 0) {
    m->opt.disableflags &= ~mjDSBL_CONTACT;
  } else {
    m->opt.disableflags |= mjDSBL_CONTACT;
  }
  mjData* d = mj_makeData(m);
  const auto steps = static_cast<int64_t>(kDurationS / m->opt.timestep);
  double simulated_s = 0.0;
  for (auto _ : state) {
    mj_copyData(d, m, world.physics_data());
    for (int64_t k = 0; k < steps; ++k) mj_step(m, d);
    benchmark::DoNotOptimize(d->qpos[0]);
    simulated_s += kDurationS;
  }
  state.counters["real_time_factor"] =
      benchmark::Counter(simulated_s, benchmark::Counter::kIsRate);
  state.counters["steps_per_s"] =
      benchmark::Counter(simulated_s / m->opt.timestep, benchmark::Counter::kIsRate);
  mj_deleteData(d);
  mj_deleteModel(m);
}
BENCHMARK(BM_BareMjStep200s)->Apply([](benchmark::internal::Benchmark* b) {
  OneRunPerRepetition(b, "contacts_off");
});

// A closed-loop flight (the controller flying on the estimate): the same 200 s figure-eights
// with the full sensor suite, one method in the loop. Arg 0: consensus; arg 1: naive. The
// local update's solve times in the loop (p50, p99) are reported beside the real-time
// factor: they say whether the estimator would keep up on the robot.
void BM_ClosedLoopFlight200s(benchmark::State& state) {
  Scenario scenario = BenchScenario(true);
  tofu::replay::EstimationConfig estimation =
      tofu::replay::EstimationConfig::Defaults(tofu::replay::EstimationConfig::kDefaultProfile);
  estimation.methods = {"consensus", "naive"};
  scenario.estimation = estimation;
  tofu::harness::SimulateOptions options;
  options.fly_on = estimation.methods[static_cast<std::size_t>(state.range(0))];
  double simulated_s = 0.0;
  std::vector<double> solve_ms;
  // How the flight went, beside how fast: a flight in contact with the walls runs MuJoCo's
  // constraint solver in every step and times something else than a flight.
  double squared_error_m2 = 0.0;
  std::size_t tracking_samples = 0;
  std::size_t contacts = 0;
  for (auto _ : state) {
    const tofu::harness::RunRecord record = tofu::harness::Simulate(scenario, options);
    benchmark::DoNotOptimize(record.groundtruth.data());
    simulated_s += static_cast<double>(record.physics_steps) / scenario.physics.rate_hz;
    for (const double t : record.in_loop.front().solver.solve_time_s) solve_ms.push_back(t * 1e3);
    for (const tofu::harness::TrackingSample& t : record.tracking) {
      squared_error_m2 += t.position_error_m * t.position_error_m;
    }
    tracking_samples += record.tracking.size();
    contacts += record.collisions.size();
  }
  state.counters["tracking_rmse_m"] =
      tracking_samples > 0 ? std::sqrt(squared_error_m2 / static_cast<double>(tracking_samples)) : 0.0;
  state.counters["contacts"] = static_cast<double>(contacts);
  state.counters["real_time_factor"] =
      benchmark::Counter(simulated_s, benchmark::Counter::kIsRate);
  std::sort(solve_ms.begin(), solve_ms.end());
  if (!solve_ms.empty()) {
    state.counters["update_p50_ms"] = solve_ms[solve_ms.size() / 2];
    state.counters["update_p99_ms"] = solve_ms[(solve_ms.size() * 99) / 100];
  }
}
BENCHMARK(BM_ClosedLoopFlight200s)->Apply([](benchmark::internal::Benchmark* b) {
  b->ArgName("naive")->Arg(0)->Arg(1)->Unit(benchmark::kMillisecond)->UseRealTime()->Iterations(1)
      ->ComputeStatistics("min", Fastest);
});

// One LiDAR scan's rays (the default Mid-360 pattern, 72 x 12) from 1.5 m above the indoor
// arena's floor, tilted so that walls, floor and ceiling are all hit. Arg 0: a CastRay per
// ray (mj_ray over every geom); arg 1: one RayFan for the scan, what the LiDAR model casts.
// The same hits either way (ctest World.RayFanHitsAreCastRaysBitForBit).
void BM_LidarScanRays(benchmark::State& state) {
  tofu::sim::WorldOptions options;
  options.world = "indoor_arena";
  tofu::sim::World world(options);
  world.Reset({Eigen::Vector3d(0.5, -0.3, 1.5), Eigen::Quaterniond::Identity()});
  const tofu::core::LidarBeamPattern beams;
  std::vector<Eigen::Vector3d> directions_s;
  beams.Directions_s(0.0, &directions_s);
  const Eigen::Vector3d origin_W(0.5, -0.3, 1.5);
  const Eigen::Matrix3d R_Ws =
      Eigen::AngleAxisd(0.3, Eigen::Vector3d(1.0, 0.5, 0.0).normalized()).toRotationMatrix();
  const bool fan = state.range(0) != 0;
  std::size_t hits = 0;
  for (auto _ : state) {
    if (fan) {
      const tofu::sim::RayFan rays = world.RaysFrom(origin_W);
      for (const Eigen::Vector3d& u_s : directions_s) hits += rays.Cast(R_Ws * u_s).has_value();
    } else {
      for (const Eigen::Vector3d& u_s : directions_s) {
        hits += world.CastRay(origin_W, R_Ws * u_s).has_value();
      }
    }
  }
  state.counters["rays_per_s"] = benchmark::Counter(
      static_cast<double>(state.iterations() * directions_s.size()), benchmark::Counter::kIsRate);
  state.counters["hit_fraction"] =
      static_cast<double>(hits) / static_cast<double>(state.iterations() * directions_s.size());
}
BENCHMARK(BM_LidarScanRays)->ArgName("fan")->Arg(0)->Arg(1)->Unit(benchmark::kMicrosecond);

}  // namespace

BENCHMARK_MAIN();
