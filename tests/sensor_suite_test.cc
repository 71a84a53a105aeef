// The sensor suite inside a run: configuration errors, independence of the streams,
// labels, and the run directory's sensor files.

#include <algorithm>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>

#include <gtest/gtest.h>
#include <yaml-cpp/yaml.h>

#include "core/error.h"
#include "harness/evaluation.h"
#include "harness/run.h"
#include "harness/run_directory.h"
#include "harness/scenario.h"

namespace tofu::harness {
namespace {

using replay::LabelEvent;

constexpr const char* kLabel = "sensors.yaml";

std::string BaseScenario(const std::string& sensors, const std::string& faults = "") {
  return R"(name: sensor_suite
world: bridge
duration_s: 6
seed: 5
trajectory:
  start: {position_m: [-9, 0, 3.0]}
  segments:
    - hover: {duration_s: 1}
    - line: {to_m: [-6, 0, 3.0]}
)" + sensors + faults;
}

const std::string kAllSensors = R"(sensors:
  imu: {}
  vio: {}
  lidar: {type: lidar_odometry}
  leica: {type: total_station}
  gnss: {}
)";

core::InputError ParseError(const std::string& yaml) {
  try {
    ParseScenario(yaml, kLabel);
  } catch (const core::InputError& e) {
    return e;
  }
  ADD_FAILURE() << "no InputError for:\n" << yaml;
  return core::InputError({}, "", "");
}

int LineOf(const std::string& yaml, const std::string& needle) {
  const size_t at = yaml.find(needle);
  return at == std::string::npos ? -1
                                 : 1 + static_cast<int>(std::count(yaml.begin(),
                                                                   yaml.begin() + at, '\n'));
}

TEST(SensorConfig, NegativeRateNamesLineAndKey) {
  const std::string yaml = BaseScenario("sensors:\n  leica:\n    type: total_station\n    rate_hz: -5\n");
  const core::InputError e = ParseError(yaml);
  EXPECT_EQ(e.location().file, kLabel);
  EXPECT_EQ(e.location().line, LineOf(yaml, "rate_hz: -5"));
  EXPECT_EQ(e.key_path(), "sensors.leica.rate_hz");
}

TEST(SensorConfig, UnknownTypeAndNamelessTypeAreErrors) {
  const std::string unknown = BaseScenario("sensors:\n  cam:\n    type: sonar\n");
  const core::InputError e = ParseError(unknown);
  EXPECT_EQ(e.location().line, LineOf(unknown, "type: sonar"));
  EXPECT_NE(e.message().find("total_station"), std::string::npos) << e.what();
  const std::string nameless = BaseScenario("sensors:\n  cam: {rate_hz: 10}\n");
  const core::InputError n = ParseError(nameless);
  EXPECT_EQ(n.key_path(), "sensors.cam");
  EXPECT_NE(n.message().find("type"), std::string::npos) << n.what();
}

TEST(SensorConfig, UnknownFaultKindWindowOutsideRunAndUnknownSensorAreErrors) {
  const std::string kind =
      BaseScenario(kAllSensors, "faults:\n  - {sensor: vio, kind: gremlins, start_s: 1}\n");
  const core::InputError k = ParseError(kind);
  EXPECT_EQ(k.location().line, LineOf(kind, "gremlins"));
  EXPECT_EQ(k.key_path(), "faults[0].kind");

  const std::string window =
      BaseScenario(kAllSensors, "faults:\n  - {sensor: vio, kind: dropout, start_s: 2, end_s: 60}\n");
  const core::InputError w = ParseError(window);
  EXPECT_EQ(w.location().line, LineOf(window, "end_s: 60"));
  EXPECT_EQ(w.key_path(), "faults[0].end_s");

  const std::string sensor =
      BaseScenario(kAllSensors, "faults:\n  - {sensor: sonar, kind: dropout, start_s: 2}\n");
  const core::InputError s = ParseError(sensor);
  EXPECT_EQ(s.location().line, LineOf(sensor, "sonar"));
  EXPECT_EQ(s.key_path(), "faults[0].sensor");

  const std::string incompatible =
      BaseScenario(kAllSensors, "faults:\n  - {sensor: imu, kind: divergence, start_s: 2}\n");
  const core::InputError i = ParseError(incompatible);
  EXPECT_EQ(i.key_path(), "faults[0].kind");
}

TEST(SensorConfig, ResolvedScenarioKeepsSensorsAndFaults) {
  const Scenario original = ParseScenario(
      BaseScenario(kAllSensors, "faults:\n  - {sensor: leica, kind: jump, start_s: 2, "
                                "translation_m: [0.1, 0, 0]}\n"),
      kLabel);
  const std::string text = ResolvedScenarioYaml(original);
  const Scenario reloaded = ParseScenario(text, "resolved.yaml");
  ASSERT_EQ(reloaded.sensors.size(), 5u);
  EXPECT_EQ(reloaded.sensors[2].name, "lidar");
  EXPECT_EQ(SensorTypeName(reloaded.sensors[2].options), "lidar_odometry");
  ASSERT_EQ(reloaded.faults.size(), 1u);
  EXPECT_EQ(reloaded.faults[0].kind, sim::FaultKind::kJump);
  EXPECT_EQ(ResolvedScenarioYaml(reloaded), text);
}

// Every random stream is seeded by (seed, its sensor's name): a stream's samples do not
// depend on which other sensors fly along.
TEST(SensorSuite, AddingOrRemovingASensorLeavesTheOthersUnchanged) {
  const RunRecord all = Simulate(ParseScenario(BaseScenario(kAllSensors), kLabel));
  const RunRecord two = Simulate(ParseScenario(
      BaseScenario("sensors:\n  leica: {type: total_station}\n  vio: {}\n"), kLabel));
  const auto find = [](const RunRecord& r, const std::string& name) -> const SensorStream& {
    return *std::find_if(r.sensors.begin(), r.sensors.end(),
                         [&](const SensorStream& s) { return s.name == name; });
  };
  for (const std::string name : {"leica", "vio"}) {
    const SensorStream& a = find(all, name);
    const SensorStream& b = find(two, name);
    ASSERT_FALSE(a.delivered.empty()) << name;
    ASSERT_EQ(a.delivered.size(), b.delivered.size()) << name;
    for (size_t i = 0; i < a.delivered.size(); ++i) {
      ASSERT_EQ(a.delivered[i].t_ns, b.delivered[i].t_ns);
      std::visit(
          [&](const auto& ma) {
            using M = std::decay_t<decltype(ma)>;
            const M& mb = std::get<M>(b.delivered[i].measured);
            if constexpr (std::is_same_v<M, core::PositionMeasurement>) {
              ASSERT_EQ(ma.p_Ss, mb.p_Ss) << name << " sample " << i;
            } else if constexpr (std::is_same_v<M, core::PoseMeasurement>) {
              ASSERT_EQ(ma.p_Ss, mb.p_Ss) << name << " sample " << i;
              ASSERT_EQ(ma.q_Ss.coeffs(), mb.q_Ss.coeffs()) << name << " sample " << i;
            }
          },
          a.delivered[i].measured);
    }
  }
  // The suite does not disturb the flight either.
  ASSERT_EQ(all.groundtruth.size(), two.groundtruth.size());
  EXPECT_EQ(all.groundtruth.back().p_WB, two.groundtruth.back().p_WB);
}

TEST(SensorSuite, FaultLabelsMatchTheScheduleAndStreamsAreWritten) {
  const Scenario scenario = ParseScenario(
      BaseScenario(kAllSensors, "faults:\n  - {sensor: leica, kind: dropout, start_s: 2, end_s: 3}\n"
                                "  - {sensor: vio, kind: divergence, start_s: 4}\n"),
      kLabel);
  const RunRecord record = Simulate(scenario);
  std::vector<LabelEvent> faults;
  for (const LabelEvent& l : record.labels) {
    if (l.source == "fault") faults.push_back(l);
  }
  ASSERT_EQ(faults.size(), 3u);
  EXPECT_EQ(faults[0].t_ns, 2'000'000'000);
  EXPECT_EQ(faults[0].label, "dropout");
  EXPECT_TRUE(faults[0].active);
  EXPECT_EQ(faults[1].t_ns, 3'000'000'000);
  EXPECT_FALSE(faults[1].active);
  EXPECT_EQ(faults[2].sensor, "vio");
  EXPECT_EQ(faults[2].label, "divergence");
  EXPECT_TRUE(std::is_sorted(record.labels.begin(), record.labels.end(),
                             [](const LabelEvent& a, const LabelEvent& b) { return a.t_ns < b.t_ns; }));
  // The dropout removes exactly the window from the delivered stream, not the clean one.
  const SensorStream& leica = record.sensors[3];
  for (const sim::SensorSample& s : leica.delivered) {
    EXPECT_TRUE(s.t_ns < 2'000'000'000 || s.t_ns >= 3'000'000'000) << s.t_ns;
  }
  EXPECT_GT(leica.clean.size(), leica.delivered.size());

  const std::filesystem::path out = std::filesystem::path(::testing::TempDir()) / "sensor_suite_run";
  WriteRunDirectory(record, Evaluate(record), out.string());
  for (const char* file : {"sensors/imu.csv", "sensors/vio.csv", "sensors/lidar.csv",
                           "sensors/leica.csv", "sensors/gnss.csv", "sensors/clean/vio.csv",
                           "labels.csv", "mav0/imu0/data.csv",
                           "mav0/state_groundtruth_estimate0/data.csv"}) {
    EXPECT_TRUE(std::filesystem::is_regular_file(out / file)) << file;
  }
  std::ifstream labels(out / "labels.csv");
  std::string header;
  std::getline(labels, header);
  EXPECT_EQ(header, "#timestamp [ns],sensor,label,source,active");
  std::ifstream vio(out / "sensors/vio.csv");
  std::string vio_header;
  std::getline(vio, vio_header);
  EXPECT_EQ(vio_header.rfind("#timestamp [ns],arrival [ns],p_Ss_x [m]", 0), 0u) << vio_header;
  std::filesystem::remove_all(out);
}

// calibration.yaml gives the estimator nominal extrinsics that are off by the configured
// calibration error, beside the truth for scoring; the simulation itself uses the truth.
TEST(SensorSuite, CalibrationErrorShiftsTheNominalExtrinsicsOnly) {
  const Scenario scenario = ParseScenario(
      BaseScenario("sensors:\n  vio:\n    calibration_error: {translation_m: [0.01, 0, 0], "
                   "rpy_deg: [0, 0, 2]}\n"),
      kLabel);
  ASSERT_EQ(scenario.sensors.size(), 1u);
  EXPECT_NEAR(scenario.sensors[0].calibration_error.translation().x(), 0.01, 1e-15);
  // The resolved scenario keeps the error.
  const Scenario reloaded = ParseScenario(ResolvedScenarioYaml(scenario), "resolved.yaml");
  EXPECT_TRUE(reloaded.sensors[0].calibration_error.isApprox(scenario.sensors[0].calibration_error,
                                                             1e-12));

  const RunRecord record = Simulate(scenario);
  const std::filesystem::path out = std::filesystem::path(::testing::TempDir()) / "calib_run";
  WriteRunDirectory(record, Evaluate(record), out.string());
  const YAML::Node calibration = YAML::LoadFile((out / "calibration.yaml").string());
  const YAML::Node vio = calibration["sensors"]["vio"];
  ASSERT_TRUE(vio["true_T_B_s"]) << "the truth is written beside the nominal value";
  const sim::MountSite* site = record.robot.FindSite("vio_camera");
  ASSERT_NE(site, nullptr);
  const Eigen::Vector3d expected =
      site->p_Bs + site->q_Bs.toRotationMatrix() * Eigen::Vector3d(0.01, 0, 0);
  for (int k = 0; k < 3; ++k) {
    EXPECT_NEAR(vio["T_B_s"]["p_m"][k].as<double>(), expected(k), 1e-6);
    EXPECT_NEAR(vio["true_T_B_s"]["p_m"][k].as<double>(), site->p_Bs(k), 1e-6);
  }
  EXPECT_EQ(vio["options"]["rate_hz"].as<double>(), 200.0);
  std::filesystem::remove_all(out);
}

}  // namespace
}  // namespace tofu::harness
