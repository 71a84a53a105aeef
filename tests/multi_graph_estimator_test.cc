// The multi-graph estimator as a whole (estimator/multi_graph_estimator.h) on a simulated
// no-fault flight: initialisation in motion, switching the fused sensor at run time, the
// alignment graph of a sensor that is not fused, the gate for streams it does not know and
// for stamps out of range, and a method left with nothing to fuse. Its options (the nested
// ones too) refuse each broken limit by name, and so does the constructor.

#include <unistd.h>

#include <algorithm>
#include <cstdlib>
#include <filesystem>
#include <functional>
#include <limits>
#include <stdexcept>
#include <string>
#include <utility>
#include <variant>
#include <vector>

#include <fmt/format.h>

#include <gtest/gtest.h>

#include "estimator/multi_graph_estimator.h"
#include "replay/recorded_log.h"
#include "replay/replay.h"
#include "replay/trajectory_metrics.h"
#include "tests/broken_options_test_support.h"

namespace tofu {
namespace {

namespace fs = std::filesystem;

class MultiGraphEstimatorTest : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    run_dir_ = new fs::path(fs::temp_directory_path() / ("tofu_multi_graph_estimator_test_" + std::to_string(::getpid())));
    fs::remove_all(*run_dir_);
    const std::string command = std::string(TOFU_BINARY) + " run " + TOFU_SOURCE_DIR +
                                "/scenarios/estimator_arena.yaml --quiet --out " +
                                run_dir_->string();
    ASSERT_EQ(std::system(command.c_str()), 0) << command;
    log_ = new replay::RecordedLog(replay::ReadRecordedLog(*run_dir_));
  }
  // A failed flight in SetUpTestSuite must fail every test, not skip it.
  void SetUp() override { ASSERT_NE(log_, nullptr) << "the fixture's flight failed"; }
  static void TearDownTestSuite() {
    fs::remove_all(*run_dir_);
    delete log_;
    log_ = nullptr;
    delete run_dir_;
  }

  static std::vector<replay::PoseSample> Truth() {
    return log_->ground_truth;
  }

  static fs::path* run_dir_;
  static replay::RecordedLog* log_;
};

fs::path* MultiGraphEstimatorTest::run_dir_ = nullptr;
replay::RecordedLog* MultiGraphEstimatorTest::log_ = nullptr;

TEST_F(MultiGraphEstimatorTest, InitialisesInMotionWhenTheLogStartsMidFlight) {
  // Drop the first 10 s (hover and take-off of the figure-eight): no rest to start from.
  replay::RecordedLog cut = *log_;
  cut.measurements.clear();
  cut.arrival_ns.clear();
  const core::Time start_ns = 10'000'000'000;
  for (std::size_t i = 0; i < log_->measurements.size(); ++i) {
    if (log_->measurements[i].t_ns < start_ns) continue;
    cut.measurements.push_back(log_->measurements[i]);
    cut.arrival_ns.push_back(log_->arrival_ns[i]);
  }
  const replay::ReplayResult result =
      replay::Replay(cut, replay::ParseReplayMethod("single:vio", cut),
                      replay::DefaultEstimatorOptions(cut), replay::SensorSpecsOf(cut));
  ASSERT_FALSE(result.outputs.empty());
  // Nothing is output until a visual-inertial alignment of the VIO's first second with the
  // IMU makes gravity observable (issue 21); then at once.
  ASSERT_EQ(result.initialisations.size(), 1u);
  EXPECT_EQ(result.initialisations.front().method,
            estimator::InitialisationRecord::Method::kVisualInertial);
  EXPECT_LT(result.outputs.front().t_ns, start_ns + 1'500'000'000)
      << "the first output comes once the VIO's first second is aligned";
  EXPECT_GE(result.outputs.front().t_ns, start_ns + 1'000'000'000);
  // Converged after 5 s: the loose in-motion prior (velocity 2 m/s) was corrected.
  replay::TrajectoryErrorOptions options;
  options.align_from_ns = start_ns + 5'000'000'000;
  std::vector<replay::PoseSample> late;
  for (const auto& p : replay::OutputTrajectory(result)) {
    if (p.t_ns >= options.align_from_ns) late.push_back(p);
  }
  const replay::TrajectoryErrors errors = replay::EvaluateTrajectory(late, Truth(), options);
  EXPECT_LT(errors.ate_position_rmse_m, 0.05);
  EXPECT_LT(errors.rotation_rmse_deg, 1.5);
  EXPECT_EQ(result.counters.reinitialisations, 0);
}

TEST_F(MultiGraphEstimatorTest, SwitchingTheFusedSensorKeepsTheEstimateContinuous) {
  const replay::RecordedLog& log = *log_;
  estimator::MultiGraphEstimator estimator(log.imu_stream, replay::SensorSpecsOf(log),
                                           replay::DefaultEstimatorOptions(log));
  estimator.SetFusedSensors({"leica"});
  std::vector<estimator::EstimatorOutput> outputs;
  double max_step_m = 0.0;
  core::Time max_step_t_ns = 0;
  int phase = 0;
  for (const core::StampedMeasurement& m : log.measurements) {
    // VIO from 20 s, the total station back from 40 s: each switch freezes the incoming
    // sensor's T_AL at its alignment graph's estimate (paper: co-dependence rule).
    if (m.t_ns >= 20'000'000'000 && phase == 0) {
      ASSERT_TRUE(estimator.SetFusedSensors({"vio"}));
      phase = 1;
    }
    if (m.t_ns >= 40'000'000'000 && phase == 1) {
      ASSERT_TRUE(estimator.SetFusedSensors({"leica"}));
      phase = 2;
    }
    estimator.Add(m);
    for (auto& o : estimator.TakeOutputs()) {
      if (!outputs.empty()) {
        const double dt_s = 1e-9 * static_cast<double>(o.t_ns - outputs.back().t_ns);
        // A 200 Hz output at ≤ 1.5 m/s moves ≤ 1 cm per sample unless the estimate jumps.
        // (The first second is the initial convergence: cm-level corrections are expected.)
        if (dt_s < 0.02 && o.t_ns > 2'000'000'000) {
          const double step = (o.state.p_LI - outputs.back().state.p_LI).norm();
          if (step > max_step_m) max_step_t_ns = o.t_ns;
          max_step_m = std::max(max_step_m, step);
        }
      }
      outputs.push_back(std::move(o));
    }
  }
  EXPECT_LT(max_step_m, 0.02) << "the estimate jumped at t = " << 1e-9 * max_step_t_ns << " s";
  std::vector<replay::PoseSample> trajectory;
  for (const auto& o : outputs) {
    EXPECT_TRUE(o.valid);
    trajectory.push_back({o.t_ns, o.state.p_LI, o.state.q_LI});
  }
  const replay::TrajectoryErrors errors = replay::EvaluateTrajectory(trajectory, Truth());
  EXPECT_LT(errors.ate_position_rmse_m, 0.03);
  EXPECT_EQ(estimator.counters().reinitialisations, 0);
}

// The total station fused as absolute (unary factors through its T_AL), then VIO alone for
// 20 s with a drift of 1 cm/s added to its positions (L drifts with it), then the total
// station again in its old frame: with the slew, the state moves back to it at the stated
// rate (no step); without it, in one solve.
struct Readmission {
  double largest_step_m = 0.0;  ///< of the position error, 40-60 s
  double late_error_m = 0.0;    ///< RMS after the slew had time to finish (48-60 s)
};
Readmission ReadmitTotalStation(
    const replay::RecordedLog& log, double rate_mps,
    estimator::PositionFactors factors = estimator::PositionFactors::kAbsolute) {
  std::vector<estimator::SensorSpec> specs = replay::SensorSpecsOf(log);
  for (auto& s : specs) {
    if (s.name == "leica") s.position_factors = factors;
  }
  estimator::MultiGraphEstimatorOptions options = replay::DefaultEstimatorOptions(log);
  options.absolute_readmission_rate_mps = rate_mps;
  estimator::MultiGraphEstimator estimator(log.imu_stream, specs, options);
  estimator.SetFusedSensors({"leica"});
  constexpr core::Time kVioNs = 20'000'000'000;
  constexpr core::Time kBackNs = 40'000'000'000;
  int phase = 0;
  std::optional<Eigen::Isometry3d> T_AL;
  std::vector<replay::PoseSample> after;
  for (core::StampedMeasurement m : log.measurements) {
    if (m.t_ns >= kVioNs && phase == 0) {
      T_AL = estimator.AlignmentOf("leica");
      estimator.SetFusedSensors({"vio"});
      phase = 1;
    }
    if (m.t_ns >= kBackNs && phase == 1) {
      // Its old frame (as consensus takes it back once the pairs fit it).
      estimator.SetKnownAlignment("leica", *T_AL);
      estimator.SetFusedSensors({"leica"});
      phase = 2;
    }
    if (auto* pose = std::get_if<core::PoseMeasurement>(&m.value); pose && m.sensor == "vio" &&
                                                                     m.t_ns >= kVioNs) {
      pose->p_Ss.x() += 0.01 * core::TimeToSeconds(std::min(m.t_ns, kBackNs) - kVioNs);
    }
    estimator.Add(m);
    for (const auto& o : estimator.TakeOutputs()) {
      if (o.t_ns >= kBackNs && o.t_ns < 60'000'000'000 && o.valid) {
        after.push_back({o.t_ns, o.state.p_LI, o.state.q_LI});
      }
    }
  }
  EXPECT_EQ(phase, 2);
  Readmission r;
  // The frame of 40-60 s is the total station's again: align on the last 12 s only.
  replay::TrajectoryErrorOptions evaluation;
  evaluation.align_from_ns = 48'000'000'000;
  const replay::TrajectoryErrors errors = replay::EvaluateTrajectory(after, log.ground_truth, evaluation);
  r.largest_step_m = errors.position_step_max_m;
  double sum = 0.0;
  std::size_t n = 0;
  for (std::size_t k = 0; k < errors.t_ns.size(); ++k) {
    if (errors.t_ns[k] < evaluation.align_from_ns) continue;
    sum += errors.position_error_m[k] * errors.position_error_m[k];
    ++n;
  }
  r.late_error_m = std::sqrt(sum / static_cast<double>(n));
  return r;
}

TEST_F(MultiGraphEstimatorTest, AnAbsoluteSensorFusedAgainSlewsTheStateBackAtTheStatedRate) {
  const Readmission jump = ReadmitTotalStation(*log_, 0.0);
  const Readmission slew = ReadmitTotalStation(*log_, 0.1);
  RecordProperty("jump_largest_step_mm", std::to_string(1e3 * jump.largest_step_m));
  RecordProperty("slew_largest_step_mm", std::to_string(1e3 * slew.largest_step_m));
  RecordProperty("jump_late_error_mm", std::to_string(1e3 * jump.late_error_m));
  RecordProperty("slew_late_error_mm", std::to_string(1e3 * slew.late_error_m));
  // 20 s at 1 cm/s: L is ~0.2 m off when the total station comes back.
  EXPECT_GT(jump.largest_step_m, 0.05) << "without the slew the state is pulled in one solve";
  // 0.1 m/s over a 5 ms output is 0.5 mm; the rest is the estimate's own noise.
  EXPECT_LT(slew.largest_step_m, 0.01);
  // ~0.2 m at 0.1 m/s is done in ~2 s: from 48 s both agree with the total station.
  EXPECT_LT(slew.late_error_m, 0.01);
  EXPECT_LT(jump.late_error_m, 0.01);
}

// The same with the total station's positions fused with an offset per chain: its new
// chain starts where the state is, so the state is not pulled back to the old frame (L
// keeps what it drifted; the global output T_ML is what follows the frame). What moves
// the state at the switch is the window giving up the drifting VIO's velocity, as with
// the paper's displacements (both ~11 mm once, 0.3 s after the switch).
TEST_F(MultiGraphEstimatorTest, ASensorFusedAgainWithAnOffsetSwitchesAsSmoothlyAsDisplacements) {
  const Readmission offset =
      ReadmitTotalStation(*log_, 0.0, estimator::PositionFactors::kOffset);
  const Readmission between =
      ReadmitTotalStation(*log_, 0.0, estimator::PositionFactors::kBetween);
  RecordProperty("offset_largest_step_mm", std::to_string(1e3 * offset.largest_step_m));
  RecordProperty("between_largest_step_mm", std::to_string(1e3 * between.largest_step_m));
  RecordProperty("offset_late_error_mm", std::to_string(1e3 * offset.late_error_m));
  EXPECT_LT(offset.largest_step_m, 1.1 * between.largest_step_m);
  EXPECT_LT(offset.largest_step_m, 0.02);  // the old frame would be a ~0.18 m step
  EXPECT_LT(offset.late_error_m, 0.01);
}

// A pose sensor that drifts along a direction its stated information calls unobserved (a
// LiDAR odometry along a corridor), fused with the total station: with every direction of
// its between factors fused, the estimate follows part of the drift; with the unobserved
// direction left out (SensorSpec::unobserved_position_std_m), it does not.
double AteWithVioDriftingAlongX(const replay::RecordedLog& log, double drift_mps,
                                double unobserved_position_std_m) {
  std::vector<estimator::SensorSpec> specs = replay::SensorSpecsOf(log);
  for (auto& s : specs) {
    if (s.name == "vio") s.unobserved_position_std_m = unobserved_position_std_m;
  }
  estimator::MultiGraphEstimator estimator(log.imu_stream, specs, replay::DefaultEstimatorOptions(log));
  estimator.SetFusedSensors({"leica", "vio"});
  std::vector<replay::PoseSample> estimate;
  for (core::StampedMeasurement m : log.measurements) {
    if (auto* pose = std::get_if<core::PoseMeasurement>(&m.value); pose && m.sensor == "vio") {
      pose->p_Ss.x() += drift_mps * core::TimeToSeconds(m.t_ns);
      // [δθ; δp_S]: millimetres and milliradians, one metre along S's x.
      Eigen::Matrix<double, 6, 1> variance;
      variance << 1e-6, 1e-6, 1e-6, 1.0, 1e-6, 1e-6;
      pose->covariance = variance.asDiagonal();
    }
    estimator.Add(m);
    for (const auto& o : estimator.TakeOutputs()) {
      if (o.valid) estimate.push_back({o.t_ns, o.state.p_LI, o.state.q_LI});
    }
  }
  return replay::EvaluateTrajectory(estimate, log.ground_truth).ate_position_rmse_m;
}

TEST_F(MultiGraphEstimatorTest, ADirectionThePoseSensorSaysItDoesNotObserveIsNotFused) {
  const double clean = AteWithVioDriftingAlongX(*log_, 0.0, 0.0);
  const double fused = AteWithVioDriftingAlongX(*log_, 0.05, 0.0);
  const double left_out = AteWithVioDriftingAlongX(*log_, 0.05, 0.05);
  RecordProperty("clean_ate_mm", std::to_string(1e3 * clean));
  RecordProperty("drift_fused_ate_mm", std::to_string(1e3 * fused));
  RecordProperty("drift_left_out_ate_mm", std::to_string(1e3 * left_out));
  // 0.05 m/s over 60 s is 3 m of drift along x; fused, a share of it stays in the estimate.
  EXPECT_GT(fused, 3.0 * clean + 0.01);
  // Left out, x rests on the total station alone: as good as without the drift.
  EXPECT_LT(left_out, 1.5 * clean + 0.003);
}

TEST_F(MultiGraphEstimatorTest, AlignmentGraphOfAnUnfusedSensorExplainsItsPositions) {
  // VIO fused; the total station's graph estimates T_AL from its positions against the
  // local estimate. Horizontal figure-eights: all three rotations observable.
  const replay::ReplayResult result = replay::Replay(
      *log_, replay::ParseReplayMethod("single:vio", *log_),
      replay::DefaultEstimatorOptions(*log_), replay::SensorSpecsOf(*log_));
  const estimator::AlignmentEstimate& leica = result.alignment.at("leica");
  ASSERT_TRUE(leica.valid);
  EXPECT_EQ(leica.observable_rotation_dofs, 3);
  EXPECT_TRUE(leica.yaw_observable);
  // Residual = the local estimate's drift over the 20 s window plus 3 mm of station noise.
  EXPECT_LT(leica.rms_residual_m, 0.02);
  // The total station's frame is levelled and L is gravity-aligned: T_AL's rotation is a
  // yaw only, up to the local estimate's tilt error (< 1 deg).
  const Eigen::Vector3d z_A_of_L = leica.T_AL.linear() * Eigen::Vector3d::UnitZ();
  EXPECT_GT(z_A_of_L.z(), std::cos(1.0 * M_PI / 180.0));
}

TEST_F(MultiGraphEstimatorTest, ARestartedAlignmentTakesBackItsFrameWhenTheNewPairsFitIt) {
  // VIO fused; the total station's alignment is usable by 30 s. Consensus finds it
  // inconsistent for a moment (no fault) and restarts its alignment: its old frame is
  // taken back once a second of new pairs fits it, not after a new 20 s alignment window
  // (wall_contact_inspection, seed 5: 44 s unfusable, the degenerate LIO fused instead).
  const replay::RecordedLog& log = *log_;
  estimator::MultiGraphEstimator estimator(log.imu_stream, replay::SensorSpecsOf(log),
                                           replay::DefaultEstimatorOptions(log));
  ASSERT_TRUE(estimator.SetFusedSensors({"vio"}));
  constexpr core::Time kRestartNs = 30'000'000'000;
  std::optional<Eigen::Isometry3d> before;
  std::optional<core::Time> usable_again_ns;
  for (const core::StampedMeasurement& m : log.measurements) {
    if (m.t_ns >= kRestartNs && !before) {
      before = estimator.AlignmentOf("leica");
      ASSERT_TRUE(before.has_value()) << "no usable alignment to restart from";
      ASSERT_TRUE(estimator.RestartAlignment("leica"));
      EXPECT_FALSE(estimator.AlignmentOf("leica").has_value()) << "no new pair yet";
    }
    estimator.Add(m);
    estimator.TakeOutputs();
    if (before && !usable_again_ns && estimator.AlignmentOf("leica")) usable_again_ns = m.t_ns;
  }
  ASSERT_TRUE(usable_again_ns.has_value());
  EXPECT_LT(1e-9 * static_cast<double>(*usable_again_ns - kRestartNs), 2.0);
  EXPECT_TRUE(estimator.AlignmentOf("leica")->isApprox(*before, 1e-12))
      << "the old frame, not one re-estimated from the new pairs";
  EXPECT_FALSE(estimator.RestartAlignment("no_such_sensor"));
}

TEST_F(MultiGraphEstimatorTest, CountsStreamsItDoesNotKnowAndWrongKinds) {
  estimator::MultiGraphEstimator estimator(log_->imu_stream, replay::SensorSpecsOf(*log_),
                                           replay::DefaultEstimatorOptions(*log_));
  EXPECT_FALSE(estimator.SetFusedSensors({"vio", "no_such_sensor"}));
  EXPECT_EQ(estimator.fused_sensors(), std::vector<std::string>{"vio"});
  estimator.Add({"no_such_sensor", 1000, core::PositionMeasurement{}});
  estimator.Add({"vio", 2000, core::PositionMeasurement{}});  // vio is a pose stream
  estimator.Add({log_->imu_stream, 3000, core::PoseMeasurement{}});
  EXPECT_EQ(estimator.counters().unknown_stream, 3);
  EXPECT_EQ(estimator.counters().streams.at("vio").accepted, 0);
}

// Stamps no clock can produce (INT64_MAX, INT64_MIN: a corrupted log's) are rejected per
// stream and counted, before they can poison the order gate (one INT64_MAX accepted would
// make every later sample "out of order") or overflow a time difference.
TEST_F(MultiGraphEstimatorTest, StampsOutsideTheValidRangeAreRejectedAndCounted) {
  estimator::MultiGraphEstimator estimator(log_->imu_stream, replay::SensorSpecsOf(*log_),
                                           replay::DefaultEstimatorOptions(*log_));
  estimator.SetFusedSensors({"vio"});
  std::size_t outputs_after_bad = 0;
  bool injected = false;
  for (const core::StampedMeasurement& m : log_->measurements) {
    if (m.t_ns > 20'000'000'000) break;
    if (!injected && m.t_ns > 10'000'000'000 && m.sensor == "vio") {
      core::StampedMeasurement bad = m;
      bad.t_ns = std::numeric_limits<core::Time>::max();
      estimator.Add(bad);
      bad.t_ns = std::numeric_limits<core::Time>::min();
      estimator.Add(bad);
      core::StampedMeasurement bad_imu{log_->imu_stream, std::numeric_limits<core::Time>::max(),
                                       core::ImuMeasurement{}};
      estimator.Add(bad_imu);
      injected = true;
    }
    estimator.Add(m);
    const std::size_t n = estimator.TakeOutputs().size();
    if (injected) outputs_after_bad += n;
  }
  ASSERT_TRUE(injected);
  EXPECT_EQ(estimator.counters().streams.at("vio").rejected_time_out_of_range, 2);
  EXPECT_EQ(estimator.counters().streams.at(log_->imu_stream).rejected_time_out_of_range, 1);
  EXPECT_EQ(estimator.counters().streams.at("vio").rejected_out_of_order, 0);
  EXPECT_EQ(estimator.counters().streams.at(log_->imu_stream).rejected_out_of_order, 0);
  // The 200 Hz output went on over the 10 s after the bad stamps.
  EXPECT_GT(outputs_after_bad, 1900u);
}

// A method none of whose samples the estimator accepted has nothing to fuse: `tofu
// estimate` exits 1 with the reason per sensor instead of reporting an IMU-only dead
// reckoning as the sensor's result.
TEST_F(MultiGraphEstimatorTest, AMethodWhoseEverySampleWasRejectedHasNothingToFuse) {
  replay::RecordedLog log = *log_;
  for (core::StampedMeasurement& m : log.measurements) {
    if (m.sensor != "vio") continue;
    auto& pose = std::get<core::PoseMeasurement>(m.value);
    pose.p_Ss.x() = std::numeric_limits<double>::quiet_NaN();
  }
  const replay::ReplayResult all_nan =
      replay::Replay(log, replay::ParseReplayMethod("single:vio", log),
                      replay::DefaultEstimatorOptions(log), replay::SensorSpecsOf(log));
  const std::optional<std::string> why = replay::NothingToFuse(all_nan, log.imu_stream);
  ASSERT_TRUE(why.has_value());
  EXPECT_NE(why->find("single:vio"), std::string::npos) << *why;
  const std::size_t vio_rows = std::count_if(
      log.measurements.begin(), log.measurements.end(),
      [](const core::StampedMeasurement& m) { return m.sensor == "vio"; });
  EXPECT_NE(why->find(fmt::format("vio: {} non-finite", vio_rows)), std::string::npos) << *why;
  // The same log with its total station fused has something to fuse; imu_only never needs any.
  const replay::ReplayResult leica =
      replay::Replay(log, replay::ParseReplayMethod("fuse:vio+leica", log),
                      replay::DefaultEstimatorOptions(log), replay::SensorSpecsOf(log));
  EXPECT_FALSE(replay::NothingToFuse(leica, log.imu_stream).has_value());
  const replay::ReplayResult imu_only =
      replay::Replay(log, replay::ParseReplayMethod("imu_only", log),
                      replay::DefaultEstimatorOptions(log), replay::SensorSpecsOf(log));
  EXPECT_FALSE(replay::NothingToFuse(imu_only, log.imu_stream).has_value());
}

// ---- options ----

// The options a replay uses (tofu estimate, tofu run), at the ends of the CLI's ranges.
void ExpectTheReplayOptionsValid(const replay::RecordedLog& log) {
  std::string why;
  estimator::MultiGraphEstimatorOptions options = replay::DefaultEstimatorOptions(log);
  EXPECT_TRUE(options.IsValid(&why)) << why;
  for (const double window_s : {1e-3, 60.0}) {
    for (const double keyframe_rate_hz : {0.1, 1000.0}) {
      for (const double huber_delta : {0.0, 100.0}) {
        for (const double noise_scale : {1e-3, 1000.0}) {
          estimator::MultiGraphEstimatorOptions o = options;
          o.local.window_ns = core::SecondsToTime(window_s);
          o.local.keyframe_rate_hz = keyframe_rate_hz;
          o.local.huber_delta = huber_delta;
          o.local.imu_noise.gyro_noise_density_radps_per_sqrthz *= noise_scale;
          o.local.imu_noise.accel_noise_density_mps2_per_sqrthz *= noise_scale;
          EXPECT_TRUE(o.IsValid(&why)) << why;
        }
      }
    }
  }
}

TEST(MultiGraphEstimatorOptions, DefaultsAndTheReplayOptionsAreValid) {
  std::string why;
  EXPECT_TRUE(estimator::MultiGraphEstimatorOptions{}.IsValid(&why)) << why;
  ExpectTheReplayOptionsValid(replay::RecordedLog{});  // no calibration: default IMU noise
}

TEST_F(MultiGraphEstimatorTest, TheReplayOptionsOfTheFlightAreValid) {
  ExpectTheReplayOptionsValid(*log_);  // the IMU noise of its calibration.yaml
}

TEST(MultiGraphEstimatorOptions, EachBrokenLimitIsNamedAndTheConstructorThrows) {
  using Options = estimator::MultiGraphEstimatorOptions;
  const double nan = std::numeric_limits<double>::quiet_NaN();
  const double inf = std::numeric_limits<double>::infinity();
  test::BrokenOptions<Options> broken;
  const auto add = [&](std::string field, auto set) { broken.Add(std::move(field), set); };
  // The nested options: their own limits, under the field's path.
  add("local.window_ns", [](Options& o) { o.local.window_ns = 0; });
  add("local.imu_noise.accel_random_walk_mps3_per_sqrthz",
      [](Options& o) { o.local.imu_noise.accel_random_walk_mps3_per_sqrthz = 0.0; });
  add("alignment.min_pairs", [](Options& o) { o.alignment.min_pairs = 2; });
  add("visual_inertial.gravity_refinement_iterations",
      [](Options& o) { o.visual_inertial.gravity_refinement_iterations = 0; });
  // Each gravity valid on its own, but two of them.
  add("visual_inertial.gravity_mps2", [](Options& o) { o.visual_inertial.gravity_mps2 = 9.80; });
  add("visual_inertial.gravity_mps2", [](Options& o) { o.local.gravity_mps2 = 9.80; });
  add("prior_from_rest.position_std_m",
      [](Options& o) { o.prior_from_rest.position_std_m.y() = 0.0; });
  add("prior_from_rest.gyro_bias_std_radps",
      [nan](Options& o) { o.prior_from_rest.gyro_bias_std_radps = nan; });
  add("prior_in_motion.rotation_std_rad",
      [inf](Options& o) { o.prior_in_motion.rotation_std_rad.z() = inf; });
  add("prior_in_motion.velocity_std_mps",
      [](Options& o) { o.prior_in_motion.velocity_std_mps = -1.0; });
  add("prior_in_motion.accel_bias_std_mps2",
      [](Options& o) { o.prior_in_motion.accel_bias_std_mps2 = 0.0; });
  // Positive and finite.
  const std::pair<const char*, double Options::*> positive[] = {
      {"static_max_gyro_std_radps", &Options::static_max_gyro_std_radps},
      {"static_max_accel_std_mps2", &Options::static_max_accel_std_mps2},
      {"max_alignment_rotation_std_rad", &Options::max_alignment_rotation_std_rad},
      {"max_alignment_rms_m", &Options::max_alignment_rms_m}};
  for (const auto& [field, member] : positive) broken.AddNotPositiveFinite(field, member);
  for (const double bad : {-1e-3, nan, inf}) {
    add("alignment_local_position_std_m",
        [bad](Options& o) { o.alignment_local_position_std_m = bad; });
  }
  for (const double bad : {1.0, 0.0, nan, inf}) {
    add("imu_gap_periods", [bad](Options& o) { o.imu_gap_periods = bad; });
  }
  add("output_period_ns", [](Options& o) { o.output_period_ns = 0; });
  add("max_unfused_ns", [](Options& o) { o.max_unfused_ns = 0; });
  for (const double bad : {-1e-3, nan, inf}) {
    add("absolute_readmission_rate_mps",
        [bad](Options& o) { o.absolute_readmission_rate_mps = bad; });
  }
  add("covariance_period_ns", [](Options& o) { o.covariance_period_ns = -1; });
  add("static_window_ns", [](Options& o) { o.static_window_ns = 0; });
  add("max_rest_age_ns", [](Options& o) { o.max_rest_age_ns = -1; });
  add("max_alignment_window_ns", [](Options& o) { o.max_alignment_window_ns = 0; });
  // Shorter than the alignment's own minimum window (1 s): it would never align.
  add("max_alignment_window_ns", [](Options& o) {
    o.max_alignment_window_ns = 900'000'000;
    o.min_noise_window_ns = 0;
  });
  add("max_initialisation_wait_ns", [](Options& o) { o.max_initialisation_wait_ns = -1; });
  add("min_noise_window_ns", [](Options& o) { o.min_noise_window_ns = -1; });
  add("min_noise_window_ns", [](Options& o) { o.min_noise_window_ns = 4'000'000'000; });
  add("min_imu_gap_ns", [](Options& o) { o.min_imu_gap_ns = -1; });
  add("max_consecutive_bad_solves", [](Options& o) { o.max_consecutive_bad_solves = 0; });

  estimator::SensorSpec vio;
  vio.name = "vio";
  broken.ExpectEachRejected([&](const std::string& field, const Options& options,
                                 [[maybe_unused]] const std::string& why) {
    EXPECT_THROW(estimator::MultiGraphEstimator("imu", {vio}, options), std::invalid_argument)
        << field;
  });
  Options options;
  options.local.window_ns = 0;
  try {
    estimator::MultiGraphEstimator graph("imu", {vio}, options);
    ADD_FAILURE() << "expected std::invalid_argument";
  } catch (const std::invalid_argument& e) {
    EXPECT_EQ(std::string(e.what()),
              "MultiGraphEstimatorOptions: local.window_ns must be positive");
  }
  // Boundaries that are allowed.
  options = {};
  options.covariance_period_ns = 0;  // never
  options.max_rest_age_ns = 0;
  options.max_initialisation_wait_ns = 0;
  options.min_noise_window_ns = options.max_alignment_window_ns;
  options.min_imu_gap_ns = 0;
  options.alignment_local_position_std_m = 0.0;
  std::string why;
  EXPECT_TRUE(options.IsValid(&why)) << why;
  EXPECT_NO_THROW(estimator::MultiGraphEstimator("imu", {vio}, options));
}

// The level prior reaches only the alignments of position sensors stating a levelled
// frame: an odometry's frame is where it booted, tilted with its mount.
TEST(MultiGraphEstimatorOptions, TheLevelPriorHoldsOnlyForLevelledPositionSensors) {
  estimator::SensorSpec vio;
  vio.name = "vio";
  vio.kind = estimator::SensorKind::kPose;
  estimator::SensorSpec gnss;
  gnss.name = "gnss";
  gnss.kind = estimator::SensorKind::kPosition;
  estimator::SensorSpec tilted_station = gnss;
  tilted_station.name = "station";
  tilted_station.reference_is_gravity_aligned = false;
  estimator::MultiGraphEstimatorOptions options;
  options.alignment.level_prior_std_rad = 0.004;
  const estimator::MultiGraphEstimator estimator("imu", {vio, gnss, tilted_station}, options);
  EXPECT_EQ(estimator.AlignmentGraphOf("gnss")->options().level_prior_std_rad, 0.004);
  EXPECT_EQ(estimator.AlignmentGraphOf("vio")->options().level_prior_std_rad, 0.0);
  EXPECT_EQ(estimator.AlignmentGraphOf("station")->options().level_prior_std_rad, 0.0);
}

}  // namespace
}  // namespace tofu
