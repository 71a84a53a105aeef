// Consensus in use (estimator/consensus_estimator.h and harness/estimation.h): a short
// flight with IMU, VIO and LiDAR odometry whose VIO diverges at 15 s. The consensus
// estimator must fuse the healthy sensors, exclude the diverging one within a second
// (taking its recent factors out of the local graph), and `tofu run` must score every
// method on the same samples, write decisions.csv / errors.csv / consistency_<m>.csv
// deterministically, and reject malformed `estimation:` blocks with file:line. The
// estimator's options (the nested ones too) refuse each broken limit by name, and so does
// its constructor.

#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <functional>
#include <limits>
#include <sstream>
#include <stdexcept>
#include <string>
#include <utility>
#include <variant>
#include <vector>

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include "core/error.h"
#include "estimator/consensus_estimator.h"
#include "harness/scenario.h"
#include "replay/estimation_config.h"
#include "replay/recorded_log.h"
#include "replay/replay.h"
#include "tests/broken_options_test_support.h"

namespace tofu {
namespace {

namespace fs = std::filesystem;

constexpr core::Time kOnsetNs = 15'000'000'000;

const char* const kScenario = R"(name: consensus_estimator_test
world: indoor_arena
duration_s: 30
seed: 3
trajectory:
  start: {position_m: [0, 0, 1.5]}
  limits: {max_speed_mps: 1.0, max_acceleration_mps2: 1.5}
  segments:
    - hover: {duration_s: 2}
    - figure_eight: {center_m: [0, 0, 1.5], half_length_m: 2.5, half_width_m: 1.5, speed_mps: 1.0, laps: 2}
sensors:
  imu: {}
  vio: {position_random_walk_m_per_sqrtm: 0.005}
  lio: {type: lidar_odometry}
faults:
  - {sensor: vio, kind: divergence, start_s: 15, axis: [1, 0, 0], initial_velocity_mps: 0.3, time_constant_s: 8}
estimation:
  methods: [consensus, naive, "single:vio@clean"]
  consensus: {threshold: 0.3, priority: [vio, lio]}
  huber_delta: 3
expect:
  - {metric: methods.consensus.ate_m, relative_to: methods.naive.ate_m, max: 0.5}
  - {metric: methods.consensus.detection_delay_s.divergence, max: 1.0}
)";

std::string ReadFile(const fs::path& path) {
  std::ifstream in(path, std::ios::binary);
  std::stringstream buffer;
  buffer << in.rdbuf();
  return buffer.str();
}

bool Contains(const std::vector<std::string>& names, const std::string& name) {
  return std::find(names.begin(), names.end(), name) != names.end();
}

// The consensus estimator over a log (huber_delta 3, as the scenarios here state), each
// record handed to on_record; returns the local graph's counters.
estimator::LocalSmootherStats ReplayConsensus(
    const replay::RecordedLog& log, const estimator::ConsensusEstimatorOptions& options,
    const std::function<void(estimator::ConsensusRecord&&)>& on_record) {
  estimator::MultiGraphEstimatorOptions estimator_options = replay::DefaultEstimatorOptions(log);
  estimator_options.local.huber_delta = 3.0;
  estimator::ConsensusEstimator consensus(log.imu_stream, replay::SensorSpecsOf(log),
                                          estimator_options, options);
  for (const core::StampedMeasurement& m : log.measurements) {
    consensus.Add(m);
    consensus.TakeOutputs();
    for (auto& r : consensus.TakeRecords()) on_record(std::move(r));
  }
  return consensus.estimator().local().stats();
}

class ConsensusEstimatorTest : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    dir_ = new fs::path(fs::temp_directory_path() / ("tofu_consensus_estimator_test_" + std::to_string(::getpid())));
    fs::remove_all(*dir_);
    fs::create_directories(*dir_);
    std::ofstream(*dir_ / "scenario.yaml") << kScenario;
    for (const char* run : {"a", "b"}) {
      const std::string command = std::string(TOFU_BINARY) + " run " + (*dir_ / "scenario.yaml").string() +
                                  " --quiet --out " + (*dir_ / run).string();
      ASSERT_EQ(std::system(command.c_str()), 0) << command;
    }
    log_ = new replay::RecordedLog(replay::ReadRecordedLog(*dir_ / "a"));
  }
  // A failed flight in SetUpTestSuite must fail every test, not skip it.
  void SetUp() override { ASSERT_NE(log_, nullptr) << "the fixture's flight failed"; }
  static void TearDownTestSuite() {
    fs::remove_all(*dir_);
    delete log_;
    log_ = nullptr;
    delete dir_;
  }

  // The consensus estimator over the log, with the scenario's selection options.
  struct Run {
    std::vector<estimator::ConsensusRecord> records;
    estimator::LocalSmootherStats stats;
  };
  static Run RunConsensus(const replay::RecordedLog& log) {
    estimator::ConsensusEstimatorOptions options;
    options.selection.threshold = 0.3;
    options.selection.priority = {"vio", "lio"};
    Run run;
    run.stats = ReplayConsensus(log, options, [&](estimator::ConsensusRecord&& r) {
      run.records.push_back(std::move(r));
    });
    return run;
  }

  static fs::path* dir_;
  static replay::RecordedLog* log_;
};

fs::path* ConsensusEstimatorTest::dir_ = nullptr;
replay::RecordedLog* ConsensusEstimatorTest::log_ = nullptr;

// The LiDAR odometry's degeneracy test, read from its calibration (σ_r / √threshold), is
// what its spec leaves out when the scenario says so; the VIO states no such test.
TEST_F(ConsensusEstimatorTest, TheLidarOdometrysDegeneracyTestReachesItsSpecOnlyWhenLeftOut) {
  const auto stream = [&](const std::string& name) {
    return *std::find_if(log_->streams.begin(), log_->streams.end(),
                         [&](const replay::RecordedStream& s) { return s.name == name; });
  };
  // Mid-360 defaults (sim/lidar_odometry.h): σ_r 0.02 m, thresholds 10 and 10 m².
  ASSERT_TRUE(stream("lio").unobserved_position_std_m.has_value());
  EXPECT_NEAR(*stream("lio").unobserved_position_std_m, 0.02 / std::sqrt(10.0), 1e-12);
  EXPECT_NEAR(stream("lio").unobserved_rotation_std_rad.value_or(0.0), 0.02 / std::sqrt(10.0), 1e-12);
  EXPECT_FALSE(stream("vio").unobserved_position_std_m.has_value());
  for (const bool left_out : {false, true}) {
    replay::EstimationConfig config;
    config.leave_out_degenerate_directions = left_out;
    for (const estimator::SensorSpec& spec : replay::MakeEstimationSetup(*log_, config).sensors) {
      const bool lio = spec.name == "lio";
      EXPECT_EQ(spec.unobserved_position_std_m > 0.0, left_out && lio) << spec.name;
      EXPECT_EQ(spec.unobserved_rotation_std_rad > 0.0, left_out && lio) << spec.name;
    }
  }
}

TEST_F(ConsensusEstimatorTest, ExcludesTheDivergingFusedSensorWithinOneSecondAndDropsItsFactors) {
  const Run run = RunConsensus(*log_);
  ASSERT_GT(run.records.size(), 250u);  // 10 Hz over 30 s
  // Healthy until the onset: the preferred sensor (vio) fused, nobody excluded.
  int healthy = 0, clean = 0, vio_fused = 0;
  std::optional<core::Time> excluded_at;
  for (const auto& r : run.records) {
    if (r.t_ns > 5'000'000'000 && r.t_ns < kOnsetNs) {
      ++healthy;
      clean += r.decision.excluded.empty() ? 1 : 0;
      vio_fused += Contains(r.decision.fused, "vio") ? 1 : 0;
    }
    if (r.t_ns >= kOnsetNs && !excluded_at && Contains(r.decision.excluded, "vio")) excluded_at = r.t_ns;
  }
  EXPECT_GE(clean, healthy * 95 / 100) << "healthy sensors excluded before the fault";
  EXPECT_GE(vio_fused, healthy * 90 / 100) << "the preferred sensor of a consistent pair is fused";
  ASSERT_TRUE(excluded_at.has_value()) << "the diverging VIO was never excluded";
  EXPECT_LE(*excluded_at - kOnsetNs, 1'000'000'000);
  // From then on the healthy LIO is fused and the VIO not (it keeps diverging).
  for (const auto& r : run.records) {
    if (r.t_ns < *excluded_at + 500'000'000) continue;
    EXPECT_FALSE(Contains(r.decision.fused, "vio")) << r.t_ns << ": " << r.decision.reason;
    EXPECT_TRUE(Contains(r.decision.fused, "lio")) << r.t_ns << ": " << r.decision.reason;
  }
  EXPECT_GT(run.stats.faulty_between_factors, 0) << "what the VIO said before detection stayed";
  // The matrix values behind every decision: every pair and each sensor against local.
  const auto& values = run.records.back().values;
  ASSERT_EQ(values.size(), 3u);
  EXPECT_EQ(values[0].first, "lio-vio");
  EXPECT_EQ(values[1].first, "lio-local");
  EXPECT_EQ(values[2].first, "vio-local");
  EXPECT_GT(values[0].second.value_or(0.0), 0.3) << "diverged VIO inconsistent with LIO";
  EXPECT_LT(values[1].second.value_or(1e9), 0.3) << "fused LIO consistent with the local estimate";
}

// Issue 19, finding 3: a sensor whose every sample the estimator's gate rejects (here LIO
// with NaN covariances) is unavailable to consensus, never selected, so that consensus
// never fuses a stream it then has nothing of (0 outputs, exit 0 before).
TEST_F(ConsensusEstimatorTest, ASensorWhoseEverySampleIsRejectedIsNeverSelected) {
  replay::RecordedLog log = *log_;
  int poisoned = 0;
  for (core::StampedMeasurement& m : log.measurements) {
    if (m.sensor != "lio") continue;
    if (auto* pose = std::get_if<core::PoseMeasurement>(&m.value)) {
      pose->covariance(0, 0) = std::numeric_limits<double>::quiet_NaN();
      ++poisoned;
    }
  }
  ASSERT_GT(poisoned, 100);
  const Run run = RunConsensus(log);
  ASSERT_GT(run.records.size(), 250u);
  for (const auto& r : run.records) {
    EXPECT_FALSE(Contains(r.decision.fused, "lio")) << r.t_ns << ": " << r.decision.reason;
    EXPECT_TRUE(Contains(r.decision.unavailable, "lio")) << r.t_ns << ": " << r.decision.reason;
  }
}

TEST_F(ConsensusEstimatorTest, PoseStreamsWithoutTwistAreDifferentiated) {
  // The same flight as a log whose odometry reports poses only (TUM files, real logs):
  // velocities come from the positions, and the divergence is still found.
  replay::RecordedLog no_twist = *log_;
  for (core::StampedMeasurement& m : no_twist.measurements) {
    if (auto* pose = std::get_if<core::PoseMeasurement>(&m.value)) pose->has_twist = false;
  }
  const Run run = RunConsensus(no_twist);
  int available_before = 0, before = 0;
  std::optional<core::Time> excluded_at;
  for (const auto& r : run.records) {
    if (r.t_ns > 5'000'000'000 && r.t_ns < kOnsetNs) {
      ++before;
      available_before += r.decision.unavailable.empty() ? 1 : 0;
    }
    if (r.t_ns >= kOnsetNs && !excluded_at && Contains(r.decision.excluded, "vio")) excluded_at = r.t_ns;
  }
  EXPECT_GE(available_before, before * 95 / 100);
  ASSERT_TRUE(excluded_at.has_value());
  EXPECT_LE(*excluded_at - kOnsetNs, 1'500'000'000) << "differentiation adds its half window";
}

TEST_F(ConsensusEstimatorTest, RunScoresEveryMethodAndWritesItsDecisions) {
  const nlohmann::json summary = nlohmann::json::parse(ReadFile(*dir_ / "a" / "summary.json"));
  ASSERT_TRUE(summary.contains("methods"));
  const auto& methods = summary["methods"];
  for (const char* m : {"consensus", "naive", "single:vio@clean"}) {
    ASSERT_TRUE(methods.contains(m)) << m;
    EXPECT_TRUE(methods[m]["ate_m"].is_number()) << m;
  }
  const auto& consensus = methods["consensus"];
  ASSERT_EQ(consensus["detections"].size(), 1u);
  EXPECT_EQ(consensus["detections"][0]["sensor"], "vio");
  EXPECT_EQ(consensus["detections"][0]["fault"], "divergence");
  EXPECT_TRUE(consensus["detections"][0]["detected"].get<bool>());
  // Consensus beats fusing the diverging VIO naively, on the very same samples.
  EXPECT_LT(consensus["ate_m"].get<double>(), 0.5 * methods["naive"]["ate_m"].get<double>());
  EXPECT_TRUE(summary["passed"].get<bool>()) << summary["expectations"].dump(1);

  const std::string decisions = ReadFile(*dir_ / "a" / "decisions.csv");
  EXPECT_EQ(decisions.rfind("#timestamp [ns],method,fused,excluded,unavailable,reason\n", 0), 0u);
  EXPECT_NE(decisions.find(",consensus,lio,vio,,"), std::string::npos);
  const std::string errors = ReadFile(*dir_ / "a" / "errors.csv");
  for (const char* m : {",consensus,", ",naive,", ",single:vio@clean,"}) {
    EXPECT_NE(errors.find(m), std::string::npos) << m;
  }
  EXPECT_NE(ReadFile(*dir_ / "a" / "consistency_consensus.csv").find(",lio-vio,cm,"), std::string::npos);
}

TEST_F(ConsensusEstimatorTest, EstimateCommandRunsConsensusOnARecordedLog) {
  // `tofu estimate` on the run's streams (what a real robot's log would be): the same
  // decisions as the run's own consensus method when given the same threshold.
  const fs::path out = *dir_ / "estimate";
  const std::string command = std::string(TOFU_BINARY) + " estimate " + (*dir_ / "a").string() +
                              " --method consensus --set consensus.threshold=0.3 --quiet --out " +
                              out.string();
  ASSERT_EQ(std::system(command.c_str()), 0) << command;
  const std::string decisions = ReadFile(out / "decisions.csv");
  EXPECT_EQ(decisions.rfind(replay::kDecisionsCsvHeader, 0), 0u);
  EXPECT_NE(decisions.find(",consensus,lio,vio,,"), std::string::npos) << "VIO never excluded";
  EXPECT_NE(ReadFile(out / "consistency_consensus.csv").find(",vio-local,cm,"), std::string::npos);
}

TEST_F(ConsensusEstimatorTest, SameScenarioAndSeedGiveIdenticalEstimationFiles) {
  for (const char* file : {"summary.json", "decisions.csv", "errors.csv", "consistency_consensus.csv",
                           "estimate_consensus.csv", "estimate_naive.csv",
                           "estimate_single_vio@clean.csv"}) {
    EXPECT_EQ(ReadFile(*dir_ / "a" / file), ReadFile(*dir_ / "b" / file)) << file;
  }
}

// ---- malformed estimation blocks and expectations: file:line, key, expected form ----

std::string ErrorOf(const std::string& yaml) {
  try {
    harness::ParseScenario(yaml, "bad.yaml");
  } catch (const core::InputError& e) {
    return e.what();
  }
  return "";
}

std::string With(const std::string& from, const std::string& to) {
  std::string text = kScenario;
  const std::size_t at = text.find(from);
  EXPECT_NE(at, std::string::npos) << from;
  return text.replace(at, from.size(), to);
}

TEST(EstimationScenario, TheTestScenarioIsValid) { EXPECT_EQ(ErrorOf(kScenario), ""); }

TEST(EstimationScenario, UnknownSensorInAMethodIsAnErrorWithLineAndKnownSensors) {
  const std::string error = ErrorOf(With("\"single:vio@clean\"", "\"single:gps\""));
  EXPECT_NE(error.find("bad.yaml:18:"), std::string::npos) << error;
  EXPECT_NE(error.find("estimation.methods[2]"), std::string::npos) << error;
  EXPECT_NE(error.find("known: vio, lio"), std::string::npos) << error;
}

TEST(EstimationScenario, PriorityMustNameSensorsAndThresholdsMustBeOrdered) {
  std::string error = ErrorOf(With("priority: [vio, lio]", "priority: [vio, gnss]"));
  EXPECT_NE(error.find("bad.yaml:19:"), std::string::npos) << error;
  EXPECT_NE(error.find("gnss"), std::string::npos) << error;
  error = ErrorOf(With("threshold: 0.3,", "threshold: 0.3, leave_threshold: 0.2,"));
  EXPECT_NE(error.find("estimation.consensus.leave_threshold"), std::string::npos) << error;
  EXPECT_NE(error.find("at least threshold (0.3)"), std::string::npos) << error;
  error = ErrorOf(With("threshold: 0.3,", "threshold: 0.3, fuse: vote,"));
  EXPECT_NE(error.find("pair_member or consistent_set"), std::string::npos) << error;
}

// The consensus compares by cm (the paper) or nis; the other metrics of the consistency
// block are not decision rules, and nis needs the stated covariances only consensus has.
TEST(EstimationScenario, ConsensusMetricIsCmOrNisAndRoundTrips) {
  EXPECT_EQ(ErrorOf(With("threshold: 0.3,", "metric: nis, threshold: 3,")), "");
  const std::string error = ErrorOf(With("threshold: 0.3,", "metric: kl, threshold: 0.3,"));
  EXPECT_NE(error.find("bad.yaml:19:"), std::string::npos) << error;
  EXPECT_NE(error.find("cm or nis"), std::string::npos) << error;
  const harness::Scenario nis =
      harness::ParseScenario(With("threshold: 0.3,", "metric: nis, threshold: 3,"), "nis.yaml");
  ASSERT_TRUE(nis.estimation.has_value());
  EXPECT_EQ(nis.estimation->consensus.metric, estimator::ConsistencyMetric::kNis);
  const std::string echoed = harness::ResolvedScenarioYaml(nis);
  EXPECT_NE(echoed.find("metric: nis"), std::string::npos) << echoed;
  const harness::Scenario again = harness::ParseScenario(echoed, "echoed.yaml");
  EXPECT_EQ(again.estimation->consensus.metric, estimator::ConsistencyMetric::kNis);
  // The resolved block writes the paper's metric too (every key, resolved).
  const std::string cm = harness::ResolvedScenarioYaml(harness::ParseScenario(kScenario, "cm.yaml"));
  EXPECT_NE(cm.find("metric: cm"), std::string::npos) << cm;
  EXPECT_EQ(cm.find("metric: nis"), std::string::npos) << cm;
}

// A LiDAR odometry's degenerate directions are fused (the paper) or left out; either is
// written back.
TEST(EstimationScenario, DegenerateDirectionsAreFusedOrLeftOutAndRoundTrip) {
  const std::string error =
      ErrorOf(With("  huber_delta: 3", "  huber_delta: 3\n  degenerate_directions: ignored"));
  EXPECT_NE(error.find("fused or left_out"), std::string::npos) << error;
  const harness::Scenario left_out = harness::ParseScenario(
      With("  huber_delta: 3", "  huber_delta: 3\n  degenerate_directions: left_out"), "d.yaml");
  ASSERT_TRUE(left_out.estimation.has_value());
  EXPECT_TRUE(left_out.estimation->leave_out_degenerate_directions);
  const std::string echoed = harness::ResolvedScenarioYaml(left_out);
  EXPECT_NE(echoed.find("degenerate_directions: left_out"), std::string::npos) << echoed;
  EXPECT_TRUE(harness::ParseScenario(echoed, "echoed.yaml").estimation->leave_out_degenerate_directions);
  const harness::Scenario fused = harness::ParseScenario(kScenario, "fused.yaml");
  EXPECT_FALSE(fused.estimation->leave_out_degenerate_directions);
  EXPECT_NE(harness::ResolvedScenarioYaml(fused).find("degenerate_directions: fused"), std::string::npos);
}

// Pose sensors' between weights: constant (the paper) or from each stream's white error and
// drift; either is written back, and the latter reaches the pose sensors' specs alone.
TEST(EstimationScenario, PoseBetweenNoiseIsReadAndRoundTripsAndReachesPoseSensorsOnly) {
  const std::string error =
      ErrorOf(With("  huber_delta: 3", "  huber_delta: 3\n  pose_between_noise: drift"));
  EXPECT_NE(error.find("constant or white_and_drift"), std::string::npos) << error;
  const harness::Scenario own = harness::ParseScenario(
      With("  huber_delta: 3", "  huber_delta: 3\n  pose_between_noise: white_and_drift"),
      "n.yaml");
  ASSERT_TRUE(own.estimation.has_value());
  EXPECT_EQ(own.estimation->pose_between_noise, estimator::PoseBetweenNoise::kWhiteAndDrift);
  const std::string echoed = harness::ResolvedScenarioYaml(own);
  EXPECT_NE(echoed.find("pose_between_noise: white_and_drift"), std::string::npos) << echoed;
  EXPECT_EQ(harness::ParseScenario(echoed, "echoed.yaml").estimation->pose_between_noise,
            estimator::PoseBetweenNoise::kWhiteAndDrift);
  replay::RecordedLog log;
  log.streams.resize(2);
  log.streams[0].name = "vio";
  log.streams[0].kind = core::MeasurementKind::kPose;
  log.streams[0].position_noise_m = 0.002;
  log.streams[0].position_random_walk_m_per_sqrtm = 0.02;
  log.streams[0].rotation_random_walk_rad_per_sqrtm = 0.002;
  log.streams[1].name = "leica";
  log.streams[1].kind = core::MeasurementKind::kPosition;
  const replay::EstimationSetup setup = replay::MakeEstimationSetup(log, *own.estimation);
  ASSERT_EQ(setup.sensors.size(), 2u);
  EXPECT_EQ(setup.sensors[0].pose_between_noise, estimator::PoseBetweenNoise::kWhiteAndDrift);
  EXPECT_EQ(setup.sensors[0].white_position_std_m, 0.002);
  EXPECT_EQ(setup.sensors[0].white_rotation_std_rad, 0.0);  // from each sample's covariance
  EXPECT_EQ(setup.sensors[0].drift.position_random_walk_m_per_sqrtm, 0.02);
  EXPECT_EQ(setup.sensors[0].drift.rotation_random_walk_rad_per_sqrtm, 0.002);
  EXPECT_EQ(setup.sensors[1].pose_between_noise, estimator::PoseBetweenNoise::kConstant);
  // A pose stream that states its white error nowhere (a TUM file) cannot be weighted by it:
  // it keeps constant weights, the other streams keep their own noise.
  log.streams[0].covariance_stated = false;
  log.streams.push_back(log.streams[0]);
  log.streams[2].name = "lio";
  log.streams[2].covariance_stated = true;
  const replay::EstimationSetup unstated = replay::MakeEstimationSetup(log, *own.estimation);
  ASSERT_EQ(unstated.sensors.size(), 3u);
  EXPECT_EQ(unstated.sensors[0].pose_between_noise, estimator::PoseBetweenNoise::kConstant);
  EXPECT_EQ(unstated.sensors[2].pose_between_noise, estimator::PoseBetweenNoise::kWhiteAndDrift);
  log.streams[0].rotation_noise_rad = 0.001;
  EXPECT_EQ(replay::MakeEstimationSetup(log, *own.estimation).sensors[0].pose_between_noise,
            estimator::PoseBetweenNoise::kWhiteAndDrift);
  const harness::Scenario paper =
      harness::ParseScenario(With("  huber_delta: 3", "  huber_delta: 3\n  profile: paper"), "paper.yaml");
  EXPECT_EQ(paper.estimation->pose_between_noise, estimator::PoseBetweenNoise::kConstant);
  EXPECT_NE(harness::ResolvedScenarioYaml(paper).find("pose_between_noise: constant"), std::string::npos);
}

// The level prior of the position sensors' alignments: off unless stated, bounded, written
// back; it reaches the estimator's alignment options.
TEST(EstimationScenario, AlignmentLevelPriorIsReadBoundedAndRoundTrips) {
  const std::string error = ErrorOf(
      With("  huber_delta: 3", "  huber_delta: 3\n  alignment_level_prior_deg: 20"));
  EXPECT_NE(error.find("alignment_level_prior_deg"), std::string::npos) << error;
  const harness::Scenario level = harness::ParseScenario(
      With("  huber_delta: 3", "  huber_delta: 3\n  alignment_level_prior_deg: 0.2"), "l.yaml");
  ASSERT_TRUE(level.estimation.has_value());
  EXPECT_EQ(level.estimation->alignment_level_prior_deg, 0.2);
  const std::string echoed = harness::ResolvedScenarioYaml(level);
  EXPECT_NE(echoed.find("alignment_level_prior_deg: 0.2"), std::string::npos) << echoed;
  EXPECT_EQ(harness::ParseScenario(echoed, "echoed.yaml").estimation->alignment_level_prior_deg,
            0.2);
  EXPECT_NEAR(replay::MakeEstimationSetup(replay::RecordedLog{}, *level.estimation)
                  .estimator.alignment.level_prior_std_rad,
              0.2 * M_PI / 180.0, 1e-15);
  const harness::Scenario paper =
      harness::ParseScenario(With("  huber_delta: 3", "  huber_delta: 3\n  profile: paper"), "paper.yaml");
  EXPECT_EQ(paper.estimation->alignment_level_prior_deg, 0.0);
  EXPECT_NE(harness::ResolvedScenarioYaml(paper).find("alignment_level_prior_deg: 0\n"), std::string::npos);
}

// The bias test of consensus: off unless stated, bounded, written back, and it reaches the
// consensus estimator's options.
TEST(EstimationScenario, TheBiasTestIsReadBoundedAndRoundTrips) {
  std::string error = ErrorOf(With("threshold: 0.3,", "bias_window_s: 0.2, threshold: 0.3,"));
  EXPECT_NE(error.find("bias_window_s"), std::string::npos) << error;
  EXPECT_NE(error.find("0 (off) or at least 0.5 (s)"), std::string::npos) << error;
  error = ErrorOf(With("threshold: 0.3,", "bias_false_alarm: 0.9, threshold: 0.3,"));
  EXPECT_NE(error.find("bias_false_alarm"), std::string::npos) << error;
  const harness::Scenario bias = harness::ParseScenario(
      With("threshold: 0.3,",
           "bias_window_s: 8, bias_false_alarm: 1e-3, bias_floor_mps: 0.002, threshold: 0.3,"),
      "b.yaml");
  ASSERT_TRUE(bias.estimation.has_value());
  EXPECT_EQ(bias.estimation->consensus.bias_window_s, 8.0);
  const std::string echoed = harness::ResolvedScenarioYaml(bias);
  EXPECT_NE(echoed.find("bias_window_s: 8"), std::string::npos) << echoed;
  const harness::Scenario again = harness::ParseScenario(echoed, "echoed.yaml");
  EXPECT_EQ(again.estimation->consensus.bias_window_s, 8.0);
  EXPECT_EQ(again.estimation->consensus.bias_false_alarm, 1e-3);
  const replay::EstimationSetup setup =
      replay::MakeEstimationSetup(replay::RecordedLog{}, *bias.estimation);
  EXPECT_EQ(setup.consensus.bias_window_ns, 8'000'000'000);
  EXPECT_EQ(setup.consensus.bias_false_alarm, 1e-3);
  EXPECT_EQ(setup.consensus.bias.floor_std_mps, 0.002);
  EXPECT_EQ(again.estimation->consensus.bias_floor_mps, 0.002);
  const harness::Scenario paper =
      harness::ParseScenario(With("  huber_delta: 3", "  huber_delta: 3\n  profile: paper"), "paper.yaml");
  EXPECT_EQ(paper.estimation->consensus.bias_window_s, 0.0);
  EXPECT_NE(harness::ResolvedScenarioYaml(paper).find("bias_window_s: 0\n"), std::string::npos);
}

TEST(EstimationScenario, ExpectationsMustNameListedMethodsAndKnownRelativeMetrics) {
  std::string error = ErrorOf(With("methods.naive.ate_m, max: 0.5", "methods.naive.ate_m, max: 0.5}\n  - {metric: methods.single:lio.ate_m, max: 1"));
  EXPECT_NE(error.find("bad.yaml:23:"), std::string::npos) << error;
  EXPECT_NE(error.find("does not list"), std::string::npos) << error;
  error = ErrorOf(With("relative_to: methods.naive.ate_m", "relative_to: methods.naive.speed"));
  EXPECT_NE(error.find("bad.yaml:22:"), std::string::npos) << error;
  EXPECT_NE(error.find("relative_to"), std::string::npos) << error;
  error = ErrorOf(With("relative_to: methods.naive.ate_m", "relative_to: methods.consensus.switches"));
  EXPECT_NE(error.find("same unit"), std::string::npos) << error;
}

// ---- options ----

TEST(ConsensusEstimatorOptions, DefaultsAndTheScenarioRangesAreValid) {
  std::string why;
  EXPECT_TRUE(estimator::ConsensusEstimatorOptions{}.IsValid(&why)) << why;
  // A scenario's estimation.consensus at the ends of its ranges (harness/scenario.cc).
  for (const double window_s : {0.1, 60.0}) {
    for (const double rate_hz : {0.5, 100.0}) {
      replay::EstimationConfig config;
      config.consensus.window_s = window_s;
      config.consensus.rate_hz = rate_hz;
      config.consensus.threshold = 1e-6;
      config.consensus.leave_threshold = 100.0;
      config.consensus.min_dwell_s = 3600.0;
      config.consensus.policy = estimator::ConsensusPolicy::kConsistentSet;
      config.consensus.priority = {"vio", "lio"};
      config.huber_delta = 100.0;
      const replay::EstimationSetup setup =
          replay::MakeEstimationSetup(replay::RecordedLog{}, config);
      EXPECT_TRUE(setup.consensus.IsValid(&why)) << why;
      EXPECT_TRUE(setup.estimator.IsValid(&why)) << why;
    }
  }
}

TEST(ConsensusEstimatorOptions, EachBrokenLimitIsNamedAndTheConstructorThrows) {
  using Options = estimator::ConsensusEstimatorOptions;
  const double nan = std::numeric_limits<double>::quiet_NaN();
  const double inf = std::numeric_limits<double>::infinity();
  test::BrokenOptions<Options> broken;
  const auto add = [&](std::string field, auto set) { broken.Add(std::move(field), set); };
  // The nested options: their own limits, under the field's path.
  add("selection.threshold", [nan](Options& o) { o.selection.threshold = nan; });
  add("selection.min_dwell_ns", [](Options& o) { o.selection.min_dwell_ns = -1; });
  add("consistency.history_ns", [](Options& o) { o.consistency.history_ns = 1; });
  add("consistency.consistency.window_ns",
      [](Options& o) { o.consistency.consistency.window_ns = 0; });
  add("consistency.consistency.min_samples",
      [](Options& o) { o.consistency.consistency.min_samples = 0; });
  // Those its constructor refused before they were options' limits, and the others.
  add("evaluation_period_ns", [](Options& o) { o.evaluation_period_ns = 0; });
  add("evaluation_period_ns", [](Options& o) { o.evaluation_period_ns = -1; });
  for (const double bad : {0.0, -1.0, nan, inf, 1e-10, 2e9}) {
    add("grid_rate_hz", [bad](Options& o) { o.grid_rate_hz = bad; });
  }
  add("max_interpolation_gap_ns", [](Options& o) { o.max_interpolation_gap_ns = 0; });
  add("min_differentiation_half_window_ns",
      [](Options& o) { o.min_differentiation_half_window_ns = 0; });
  add("evaluation_margin_ns", [](Options& o) { o.evaluation_margin_ns = -1; });
  add("bias_window_ns", [](Options& o) { o.bias_window_ns = -1; });
  // The bias test's limits are checked only when it is on.
  const auto with_bias = [](Options& o) { o.bias_window_ns = 10'000'000'000; };
  add("bias_min_span_ns", [with_bias](Options& o) {
    with_bias(o);
    o.bias_min_span_ns = 20'000'000'000;
  });
  add("bias_false_alarm", [with_bias, nan](Options& o) {
    with_bias(o);
    o.bias_false_alarm = nan;
  });
  add("bias.floor_std_mps", [with_bias](Options& o) {
    with_bias(o);
    o.bias.floor_std_mps = -1.0;
  });

  estimator::SensorSpec vio, lio;
  vio.name = "vio";
  lio.name = "lio";
  broken.ExpectEachRejected([&](const std::string& field, const Options& options,
                                 [[maybe_unused]] const std::string& why) {
    try {
      estimator::ConsensusEstimator consensus("imu", {vio, lio}, {}, options);
      ADD_FAILURE() << field << ": expected std::invalid_argument";
    } catch (const std::invalid_argument& e) {
      EXPECT_EQ(std::string(e.what()), "ConsensusEstimatorOptions: " + why);
    }
  });
  // Boundaries that are allowed; and the estimator's own options are checked too.
  Options options;
  options.evaluation_margin_ns = 0;
  options.grid_rate_hz = 1e9;
  EXPECT_NO_THROW(estimator::ConsensusEstimator("imu", {vio, lio}, {}, options));
  estimator::MultiGraphEstimatorOptions estimator_options;
  estimator_options.local.huber_delta = -1.0;
  EXPECT_THROW(estimator::ConsensusEstimator("imu", {vio, lio}, estimator_options, {}),
               std::invalid_argument);
}


// ---- the bias test: a slow drift that every 1 s window hides ----

// A total station creeping at 1.5 cm/s from 20 s (a constant velocity: time constant far
// beyond the flight), beside VIO and LIO: within the scatter of each 1 s window (CM
// 0.3 m/s), so the paper's test does not see it for as long as this flight lasts, while
// the mean of the velocity differences over a few seconds does.
const char* const kSlowDriftScenario = R"(name: consensus_bias_test
world: indoor_arena
duration_s: 38
seed: 4
trajectory:
  start: {position_m: [0, 0, 1.5]}
  limits: {max_speed_mps: 1.0, max_acceleration_mps2: 1.5}
  segments:
    - hover: {duration_s: 2}
    - figure_eight: {center_m: [0, 0, 1.5], half_length_m: 2.5, half_width_m: 1.5, speed_mps: 1.0, laps: 3}
sensors:
  imu: {}
  vio: {position_random_walk_m_per_sqrtm: 0.005}
  lio: {type: lidar_odometry}
  leica: {type: total_station}
faults:
  - {sensor: leica, kind: divergence, start_s: 20, axis: [1, -1, 0], initial_velocity_mps: 0.015, time_constant_s: 1000}
)";

constexpr core::Time kDriftOnsetNs = 20'000'000'000;

// When consensus first excludes the total station after the drift's onset (nullopt:
// never), with and without the bias test, and whether it excluded anything before it.
struct DriftRun {
  std::optional<core::Time> excluded_after_ns;
  int exclusions_before_onset = 0;
};

DriftRun RunDrift(const replay::RecordedLog& log, core::Time bias_window_ns) {
  estimator::ConsensusEstimatorOptions options;
  options.selection.threshold = 0.3;
  options.selection.priority = {"leica", "vio", "lio"};
  options.bias_window_ns = bias_window_ns;
  DriftRun run;
  ReplayConsensus(log, options, [&](estimator::ConsensusRecord&& r) {
    // The first few seconds align the total station: not judged here.
    if (r.t_ns > 8'000'000'000 && r.window_end_ns < kDriftOnsetNs &&
        !r.decision.inconsistent.empty()) {
      ++run.exclusions_before_onset;
    }
    if (r.window_end_ns >= kDriftOnsetNs && !run.excluded_after_ns &&
        Contains(r.decision.inconsistent, "leica")) {
      run.excluded_after_ns = r.window_end_ns - kDriftOnsetNs;
    }
    if (bias_window_ns > 0 && r.t_ns > 8'000'000'000) {
      EXPECT_EQ(r.bias_chi2.size(), 3u);
    }
  });
  return run;
}

TEST(ConsensusBiasTest, ASlowDriftHiddenFromTheWindowIsExcludedByItsMean) {
  const fs::path dir =
      fs::temp_directory_path() / ("tofu_consensus_bias_test_" + std::to_string(::getpid()));
  fs::remove_all(dir);
  fs::create_directories(dir);
  std::ofstream(dir / "scenario.yaml") << kSlowDriftScenario;
  const std::string command = std::string(TOFU_BINARY) + " run " +
                              (dir / "scenario.yaml").string() + " --quiet --out " +
                              (dir / "run").string();
  ASSERT_EQ(std::system(command.c_str()), 0) << command;
  const replay::RecordedLog log = replay::ReadRecordedLog(dir / "run");
  fs::remove_all(dir);

  const DriftRun paper = RunDrift(log, 0);
  EXPECT_FALSE(paper.excluded_after_ns.has_value() &&
               *paper.excluded_after_ns < 10'000'000'000)
      << "the 1 s window saw the drift after " << core::TimeToSeconds(*paper.excluded_after_ns)
      << " s: the scenario no longer tests what the window hides";
  const DriftRun bias = RunDrift(log, 10'000'000'000);
  ASSERT_TRUE(bias.excluded_after_ns.has_value()) << "the drifting total station was never excluded";
  EXPECT_LT(*bias.excluded_after_ns, 10'000'000'000);
  EXPECT_EQ(bias.exclusions_before_onset, paper.exclusions_before_onset)
      << "the bias test excluded a healthy sensor";
}

}  // namespace
}  // namespace tofu
