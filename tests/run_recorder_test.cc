// The recorder (harness/run_recorder.h): `tofu run` writes every per-sample file while it
// flies, so its memory does not grow with what it records (issue 19, finding 10: every
// sample was kept until the end, 1.8 GB after 600 s). A run recorded so writes the same
// bytes as a run kept in memory and written after it (the tests', the corpus's), and
// keeps no sample in memory beyond what its evaluation needs.

#include <gtest/gtest.h>

#include <cstddef>
#include <filesystem>
#include <string>
#include <vector>

#include "harness/run.h"
#include "harness/run_directory.h"
#include "harness/scenario.h"
#include "replay/run_calibration.h"
#include "test_support.h"

namespace tofu::harness {
namespace {

namespace fs = std::filesystem;

Scenario Load(const std::string& relative_path, double duration_s) {
  Scenario scenario = LoadScenario(std::string(TOFU_SOURCE_DIR) + "/" + relative_path);
  scenario.duration_s = duration_s;
  return scenario;
}

RunRecord FlyRecorded(const Scenario& scenario, const fs::path& out) {
  SimulateOptions options;
  options.record_dir = CreateStagingDirectory(out.string());
  return Simulate(scenario, options);
}

std::size_t LineCount(const fs::path& file) {
  const std::string text = test::ReadFile(file);
  std::size_t lines = 0;
  for (const char c : text) lines += c == '\n' ? 1 : 0;
  return lines;
}

// Both ways of writing a run give the same files, byte for byte (timing*.json hold wall
// clock figures; figures are not drawn here).
void ExpectSameRunBothWays(const std::string& scenario_path, double duration_s) {
  SCOPED_TRACE(scenario_path);
  const Scenario scenario = Load(scenario_path, duration_s);
  const fs::path root = test::PerTestDirectory("recorder_");
  const fs::path in_memory = root / "memory";
  const fs::path recorded = root / "recorded";
  RunOutputOptions no_plots;
  no_plots.plot = false;

  RunRecord kept = Simulate(scenario);
  ASSERT_FALSE(kept.failure.has_value()) << *kept.failure;
  ASSERT_FALSE(kept.recorded_to.has_value());
  WriteRun(kept, in_memory.string(), no_plots);

  RunRecord streamed = FlyRecorded(scenario, recorded);
  ASSERT_FALSE(streamed.failure.has_value()) << *streamed.failure;
  ASSERT_TRUE(streamed.recorded_to.has_value());
  WriteRun(streamed, recorded.string(), no_plots);
  EXPECT_FALSE(fs::exists(*streamed.recorded_to)) << "the staging directory went into place";

  const std::set<std::string> files = test::FilesIn(in_memory);
  EXPECT_EQ(files, test::FilesIn(recorded));
  EXPECT_GT(files.size(), 10u);
  for (const std::string& file : files) {
    if (fs::path(file).filename().string().starts_with("timing")) continue;
    if (!fs::exists(recorded / file)) continue;  // named by the set comparison above
    EXPECT_TRUE(test::ReadFile(in_memory / file) == test::ReadFile(recorded / file))
        << file << " differs between the recorded run and the run kept in memory";
  }
  fs::remove_all(root);
}

TEST(RecordedRun, WritesTheSameFilesAsARunKeptInMemory) {
  // Sensors with scheduled faults, the EuRoC layout, labels.
  ExpectSameRunBothWays("scenarios/wall_sensors.yaml", 6.0);
  // The consistency evaluation, which keeps the non-IMU streams and the ground truth.
  ExpectSameRunBothWays("scenarios/paper_metric_evaluation.yaml", 8.0);
  // Estimation in the loop and a closed-loop flight (control.csv, closed_loop/<method>/).
  ExpectSameRunBothWays("scenarios/closed_loop_vio_divergence_wall.yaml", 8.0);
}

TEST(RecordedRun, KeepsNoSampleInMemoryAndEveryRowOnDisk) {
  const Scenario scenario = Load("scenarios/wall_sensors.yaml", 6.0);
  const fs::path out = test::PerTestDirectory("recorder_");
  const RunRecord record = FlyRecorded(scenario, out);
  ASSERT_FALSE(record.failure.has_value()) << *record.failure;
  const fs::path dir = *record.recorded_to;

  // Nothing per sample stays in memory but the 8-16 bytes of the digest.
  EXPECT_TRUE(record.groundtruth.empty());
  EXPECT_TRUE(record.references.empty());
  ASSERT_FALSE(record.sensors.empty());
  for (const SensorStream& stream : record.sensors) {
    SCOPED_TRACE(stream.name);
    EXPECT_TRUE(stream.clean.empty());
    EXPECT_TRUE(stream.delivered.empty());
    EXPECT_TRUE(stream.delivered_faults.empty());
    EXPECT_TRUE(stream.imu_biases.empty());
    EXPECT_GT(stream.produced_count, 0u);
    EXPECT_EQ(stream.delivered_t_ns.size(), stream.delivered_count);
    // Every sample is on disk: a header line and a row per sample.
    EXPECT_EQ(LineCount(dir / "sensors" / (stream.name + ".csv")), stream.delivered_count + 1);
    EXPECT_EQ(LineCount(dir / "sensors" / "clean" / (stream.name + ".csv")),
              stream.produced_count + 1);
  }
  ASSERT_FALSE(record.tracking.empty());
  EXPECT_EQ(LineCount(dir / "groundtruth.csv"), record.tracking.size() + 1);
  EXPECT_EQ(LineCount(dir / "groundtruth.tum"), record.tracking.size());
  EXPECT_EQ(LineCount(dir / "mav0" / "state_groundtruth_estimate0" / "data.csv"),
            record.tracking.size() + 1);

  // A run kept in memory holds them all.
  const RunRecord kept = Simulate(scenario);
  EXPECT_EQ(kept.groundtruth.size(), record.tracking.size());
  for (std::size_t i = 0; i < kept.sensors.size(); ++i) {
    EXPECT_EQ(kept.sensors[i].delivered.size(), record.sensors[i].delivered_count);
    EXPECT_EQ(kept.sensors[i].clean.size(), record.sensors[i].produced_count);
  }
  fs::remove_all(dir);
}

TEST(RecordedRun, KeepsWhatTheConsistencyEvaluationReads) {
  const Scenario scenario = Load("scenarios/paper_metric_evaluation.yaml", 6.0);
  ASSERT_TRUE(scenario.consistency.has_value());
  const fs::path out = test::PerTestDirectory("recorder_");
  const RunRecord record = FlyRecorded(scenario, out);
  ASSERT_FALSE(record.failure.has_value()) << *record.failure;
  EXPECT_EQ(record.groundtruth.size(), record.tracking.size());
  for (const SensorStream& stream : record.sensors) {
    SCOPED_TRACE(stream.name);
    EXPECT_TRUE(stream.clean.empty());
    EXPECT_EQ(stream.delivered.size(), stream.type == "imu" ? 0u : stream.delivered_count);
  }
  ASSERT_TRUE(record.consistency.has_value());
  EXPECT_FALSE(record.consistency->rows.empty());
  fs::remove_all(*record.recorded_to);
}

// calibration.yaml carries what a reader of the run needs and only the models knew: the
// GNSS satellites' directions, read back bit for bit by replay's one calibration reader
// (the renderer draws them from there, without the scenario or the sensor models).
TEST(RecordedRun, CalibrationCarriesTheGnssSkyBitForBit) {
  const Scenario scenario = Load("scenarios/bridge_sensors.yaml", 1.0);
  RunRecord record = Simulate(scenario);
  ASSERT_FALSE(record.failure.has_value()) << *record.failure;
  std::vector<Eigen::Vector3d> sky;
  for (const SensorStream& stream : record.sensors) {
    if (stream.type == "gnss") {
      sky = stream.sky_directions_S;
    } else {
      EXPECT_TRUE(stream.sky_directions_S.empty()) << stream.name;
    }
  }
  ASSERT_FALSE(sky.empty());
  const fs::path dir = test::PerTestDirectory("recorder_sky_");
  RunOutputOptions no_plots;
  no_plots.plot = false;
  WriteRun(record, dir.string(), no_plots);
  const replay::RunCalibration calibration = replay::ReadRunCalibration(dir / "calibration.yaml");
  ASSERT_EQ(calibration.sensors.count("gnss"), 1u);
  EXPECT_EQ(calibration.sensors.at("gnss").sky_directions_S, sky);
  EXPECT_EQ(calibration.OptionNumber("gnss", "satellite_count"), static_cast<double>(sky.size()));
  for (const auto& [name, sensor] : calibration.sensors) {
    if (name != "gnss") {
      EXPECT_TRUE(sensor.sky_directions_S.empty()) << name;
    }
  }
  fs::remove_all(dir);
}

}  // namespace
}  // namespace tofu::harness
