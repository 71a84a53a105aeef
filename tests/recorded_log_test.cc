// Reading recorded streams back for replay: the run directories `tofu run` writes (counts,
// kinds, arrival order, mounts composed from calibration.yaml, values of each kind of row,
// ground truth moved to the IMU frame), the EuRoC layout on real data (exact stamps), and
// bad files, which are InputErrors naming file, line and column, while NaN values and
// out-of-order stamps pass through for the estimator to reject and count.

#include <sys/wait.h>
#include <unistd.h>

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <map>
#include <sstream>
#include <string>
#include <tuple>
#include <utility>
#include <variant>
#include <vector>

#include <yaml-cpp/yaml.h>

#include "core/error.h"
#include "replay/recorded_log.h"
#include "replay/run_calibration.h"
#include "tests/test_support.h"

namespace tofu::replay {
namespace {

namespace fs = std::filesystem;
using test::Quote;


void WriteFile(const fs::path& path, const std::string& text) {
  fs::create_directories(path.parent_path());
  std::ofstream out(path, std::ios::binary);
  out << text;
  ASSERT_TRUE(out.good()) << "cannot write " << path;
}

// The data rows of a CSV file, each split at commas (the header dropped).
std::vector<std::vector<std::string>> CsvRows(const fs::path& path) {
  std::ifstream in(path);
  std::vector<std::vector<std::string>> rows;
  std::string line;
  std::getline(in, line);  // header
  while (std::getline(in, line)) {
    if (line.empty()) continue;
    std::vector<std::string> fields;
    std::string field;
    std::stringstream ss(line);
    while (std::getline(ss, field, ',')) fields.push_back(field);
    if (!line.empty() && line.back() == ',') fields.emplace_back();
    rows.push_back(fields);
  }
  return rows;
}

std::vector<std::string> CsvHeader(const fs::path& path) {
  std::ifstream in(path);
  std::string line;
  std::getline(in, line);
  std::vector<std::string> names;
  std::string field;
  std::stringstream ss(line);
  while (std::getline(ss, field, ',')) names.push_back(field);
  return names;
}

int ColumnIndex(const std::vector<std::string>& header, const std::string& name_with_unit) {
  const auto it = std::find(header.begin(), header.end(), name_with_unit);
  EXPECT_NE(it, header.end()) << name_with_unit;
  return static_cast<int>(it - header.begin());
}

Eigen::Isometry3d PoseFromYaml(const YAML::Node& node) {
  Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
  const Eigen::Quaterniond q(node["q_wxyz"][0].as<double>(), node["q_wxyz"][1].as<double>(),
                             node["q_wxyz"][2].as<double>(), node["q_wxyz"][3].as<double>());
  T.linear() = q.normalized().toRotationMatrix();
  T.translation() << node["p_m"][0].as<double>(), node["p_m"][1].as<double>(),
      node["p_m"][2].as<double>();
  return T;
}

// The measurements of one stream, in log order.
std::vector<std::pair<const core::StampedMeasurement*, core::Time>> Of(const RecordedLog& log,
                                                                         const std::string& name) {
  std::vector<std::pair<const core::StampedMeasurement*, core::Time>> out;
  for (size_t i = 0; i < log.measurements.size(); ++i) {
    if (log.measurements[i].sensor == name) out.emplace_back(&log.measurements[i], log.arrival_ns[i]);
  }
  return out;
}

const core::StampedMeasurement* FindAt(const RecordedLog& log, const std::string& name,
                                       core::Time t) {
  for (const auto& m : log.measurements) {
    if (m.sensor == name && m.t_ns == t) return &m;
  }
  return nullptr;
}

// Run directories generated once with the CLI for the whole suite.
class RecordedLogTest : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    root_ = new fs::path(fs::path(::testing::TempDir()) /
                         ("tofu_recorded_log_test_" + std::to_string(::getpid())));
    fs::remove_all(*root_);
    fs::create_directories(*root_);
    for (const auto& [name, scenario] :
         {std::pair<std::string, std::string>{"ws", "scenarios/wall_sensors.yaml"},
          {"pme", "scenarios/paper_metric_evaluation.yaml"}}) {
      const std::string command = Quote(TOFU_BINARY) + " run " +
                                  Quote(std::string(TOFU_SOURCE_DIR) + "/" + scenario) +
                                  " --quiet --out " + Quote((*root_ / name).string()) + " >" +
                                  Quote((*root_ / (name + ".log")).string()) + " 2>&1";
      const int status = std::system(command.c_str());
      // Exit code 1 (a failed expectation) still writes the run directory.
      ASSERT_TRUE(WIFEXITED(status) && (WEXITSTATUS(status) <= 1)) << command;
    }
  }
  static void TearDownTestSuite() {
    fs::remove_all(*root_);
    delete root_;
  }
  static fs::path Dir(const std::string& name) { return *root_ / name; }
  static fs::path* root_;
};
fs::path* RecordedLogTest::root_ = nullptr;

// ---- tofu run directories ----

TEST_F(RecordedLogTest, RunDirectoryStreamsHaveTheirKindsAndEveryCsvRow) {
  const RecordedLog log = ReadRecordedLog(Dir("ws"));
  ASSERT_EQ(log.streams.size(), 3u);
  EXPECT_EQ(log.streams[0].name, "imu");
  EXPECT_EQ(log.streams[1].name, "lidar");
  EXPECT_EQ(log.streams[2].name, "vio");
  EXPECT_EQ(log.streams[0].kind, core::MeasurementKind::kImu);
  EXPECT_EQ(log.streams[1].kind, core::MeasurementKind::kPose);
  EXPECT_EQ(log.streams[2].kind, core::MeasurementKind::kPose);
  EXPECT_EQ(log.imu_stream, "imu");
  size_t total = 0;
  for (const RecordedStream& s : log.streams) {
    const size_t rows = CsvRows(Dir("ws") / "sensors" / (s.name + ".csv")).size();
    EXPECT_GT(rows, 0u) << s.name;
    EXPECT_EQ(s.rows, rows) << s.name;
    EXPECT_EQ(Of(log, s.name).size(), rows) << s.name;
    EXPECT_EQ(s.file, Dir("ws") / "sensors" / (s.name + ".csv"));
    total += rows;
  }
  EXPECT_EQ(log.measurements.size(), total);
  EXPECT_EQ(log.arrival_ns.size(), total);
  for (const auto& m : log.measurements) {
    if (m.sensor == "imu") {
      EXPECT_TRUE(std::holds_alternative<core::ImuMeasurement>(m.value));
    } else {
      EXPECT_TRUE(std::holds_alternative<core::PoseMeasurement>(m.value));
    }
  }
}

TEST_F(RecordedLogTest, MeasurementsAreInArrivalOrderWithEachRowsOwnArrival) {
  const RecordedLog log = ReadRecordedLog(Dir("ws"));
  // Sorted by (arrival, stream name, time of validity).
  for (size_t i = 1; i < log.measurements.size(); ++i) {
    const auto key = [&](size_t k) {
      return std::make_tuple(log.arrival_ns[k], log.measurements[k].sensor,
                             log.measurements[k].t_ns);
    };
    ASSERT_LE(key(i - 1), key(i)) << "at " << i;
  }
  // Each stream's (t, arrival) pairs are exactly its CSV's.
  for (const std::string name : {"imu", "lidar", "vio"}) {
    const fs::path file = Dir("ws") / "sensors" / (name + ".csv");
    const auto header = CsvHeader(file);
    const int t_col = 0;
    const int a_col = ColumnIndex(header, "arrival [ns]");
    std::vector<std::pair<core::Time, core::Time>> expected;
    for (const auto& row : CsvRows(file)) {
      expected.emplace_back(std::stoll(row[t_col]), std::stoll(row[a_col]));
    }
    std::vector<std::pair<core::Time, core::Time>> got;
    for (const auto& [m, arrival] : Of(log, name)) got.emplace_back(m->t_ns, arrival);
    std::sort(expected.begin(), expected.end());
    std::sort(got.begin(), got.end());
    EXPECT_EQ(got, expected) << name;
  }
  // Latency reorders: some sample is seen after a later-stamped one (lidar: 20 ms).
  bool reordered = false;
  for (size_t i = 1; i < log.measurements.size() && !reordered; ++i) {
    reordered = log.measurements[i].t_ns < log.measurements[i - 1].t_ns;
  }
  EXPECT_TRUE(reordered) << "arrival order equals stamp order: the arrival column was not used";
}

TEST_F(RecordedLogTest, MountsAreTheCalibrationsComposedInTheImuFrame) {
  const RecordedLog log = ReadRecordedLog(Dir("ws"));
  const YAML::Node cal = YAML::LoadFile((Dir("ws") / "calibration.yaml").string());
  const Eigen::Isometry3d T_BI = PoseFromYaml(cal["sensors"]["imu"]["T_B_s"]);
  for (const RecordedStream& s : log.streams) {
    const Eigen::Isometry3d T_Bs = PoseFromYaml(cal["sensors"][s.name]["T_B_s"]);
    // T_Is = T_BI^-1 T_Bs, written out: R_Is = R_BI^T R_Bs, p_Is = R_BI^T (p_Bs - p_BI).
    const Eigen::Matrix3d R = T_BI.linear().transpose() * T_Bs.linear();
    const Eigen::Vector3d p = T_BI.linear().transpose() * (T_Bs.translation() - T_BI.translation());
    EXPECT_TRUE(s.T_Is.linear().isApprox(R, 1e-9)) << s.name << "\n" << s.T_Is.linear();
    EXPECT_TRUE(s.T_Is.translation().isApprox(p, 1e-9)) << s.name << " " << s.T_Is.translation().transpose();
  }
  // One by hand: the IMU is mounted upside down (180 deg about x) at (0.03, -0.02, 0.04),
  // the LiDAR at (-0.05, 0, 0.14): p_I_lidar = diag(1, -1, -1) (-0.08, 0.02, 0.10).
  ASSERT_EQ(log.streams[1].name, "lidar");
  if (cal["sensors"]["imu"]["T_B_s"]["q_wxyz"][1].as<double>() == 1.0 &&
      cal["sensors"]["lidar"]["T_B_s"]["p_m"][2].as<double>() == 0.14) {
    EXPECT_TRUE(log.streams[1].T_Is.translation().isApprox(Eigen::Vector3d(-0.08, -0.02, -0.10),
                                                             1e-12))
        << log.streams[1].T_Is.translation().transpose();
  }
  EXPECT_TRUE(log.streams[0].T_Is.isApprox(Eigen::Isometry3d::Identity(), 1e-12));
}

TEST_F(RecordedLogTest, ImuNoiseDensitiesComeFromTheImuOptions) {
  const RecordedLog log = ReadRecordedLog(Dir("ws"));
  const YAML::Node options =
      YAML::LoadFile((Dir("ws") / "calibration.yaml").string())["sensors"]["imu"]["options"];
  ASSERT_TRUE(log.imu_noise.has_value());
  EXPECT_EQ(log.imu_noise->gyro_noise_density_radps_per_sqrthz,
            options["gyro_noise_density_radps_per_sqrthz"].as<double>());
  EXPECT_EQ(log.imu_noise->accel_noise_density_mps2_per_sqrthz,
            options["accel_noise_density_mps2_per_sqrthz"].as<double>());
  EXPECT_EQ(log.imu_noise->gyro_random_walk_radps2_per_sqrthz,
            options["gyro_random_walk_radps2_per_sqrthz"].as<double>());
  EXPECT_EQ(log.imu_noise->accel_random_walk_mps3_per_sqrthz,
            options["accel_random_walk_mps3_per_sqrthz"].as<double>());
}

TEST_F(RecordedLogTest, ImuAndPoseRowsRoundTripTheirValues) {
  const RecordedLog log = ReadRecordedLog(Dir("ws"));
  // IMU row 10.
  {
    const auto rows = CsvRows(Dir("ws") / "sensors" / "imu.csv");
    const auto& row = rows.at(10);
    const auto* m = FindAt(log, "imu", std::stoll(row[0]));
    ASSERT_NE(m, nullptr);
    const auto& imu = std::get<core::ImuMeasurement>(m->value);
    for (int k = 0; k < 3; ++k) {
      EXPECT_EQ(imu.gyro_I_radps(k), std::stod(row[1 + k]));
      EXPECT_EQ(imu.acc_I_mps2(k), std::stod(row[4 + k]));
    }
  }
  // A LiDAR row (its pose covariance is full: position/rotation correlations).
  {
    const fs::path file = Dir("ws") / "sensors" / "lidar.csv";
    const auto header = CsvHeader(file);
    const auto rows = CsvRows(file);
    const auto& row = rows.at(5);
    const auto* m = FindAt(log, "lidar", std::stoll(row[0]));
    ASSERT_NE(m, nullptr);
    const auto& pose = std::get<core::PoseMeasurement>(m->value);
    const auto at = [&](const std::string& name) { return std::stod(row[ColumnIndex(header, name)]); };
    EXPECT_EQ(pose.p_Ss.x(), at("p_Ss_x [m]"));
    EXPECT_EQ(pose.p_Ss.y(), at("p_Ss_y [m]"));
    EXPECT_EQ(pose.p_Ss.z(), at("p_Ss_z [m]"));
    EXPECT_NEAR(pose.q_Ss.w(), at("q_Ss_w []"), 2e-9);
    EXPECT_NEAR(pose.q_Ss.x(), at("q_Ss_x []"), 2e-9);
    EXPECT_NEAR(pose.q_Ss.y(), at("q_Ss_y []"), 2e-9);
    EXPECT_NEAR(pose.q_Ss.z(), at("q_Ss_z []"), 2e-9);
    ASSERT_TRUE(pose.has_twist);
    EXPECT_EQ(pose.v_s_s_mps.y(), at("v_s_y [m s^-1]"));
    EXPECT_EQ(pose.omega_s_s_radps.z(), at("omega_s_z [rad s^-1]"));
    for (int r = 0; r < 6; ++r) {
      for (int k = r; k < 6; ++k) {
        const double c = at("cov_pose_" + std::to_string(r) + std::to_string(k) + " [rad|m]");
        EXPECT_EQ(pose.covariance(r, k), c) << r << k;
        EXPECT_EQ(pose.covariance(k, r), c) << k << r;
        const double ct =
            at("cov_twist_" + std::to_string(r) + std::to_string(k) + " [m/s|rad/s]");
        EXPECT_EQ(pose.twist_covariance(r, k), ct) << r << k;
        EXPECT_EQ(pose.twist_covariance(k, r), ct) << k << r;
      }
    }
    // [delta_theta; delta_p] order: the position block is the large one here.
    const double position_variance = pose.covariance.bottomRightCorner<3, 3>().trace();
    const double rotation_variance = pose.covariance.topLeftCorner<3, 3>().trace();
    EXPECT_GT(position_variance, rotation_variance);
  }
}

TEST_F(RecordedLogTest, GroundTruthIsTheImuFramesPose) {
  const RecordedLog log = ReadRecordedLog(Dir("ws"));
  const auto body = CsvRows(Dir("ws") / "groundtruth.csv");
  ASSERT_EQ(log.ground_truth.size(), body.size());
  // The recorder's EuRoC file holds T_WI computed from the true IMU mount: the same poses.
  const auto euroc = CsvRows(Dir("ws") / "mav0" / "state_groundtruth_estimate0" / "data.csv");
  ASSERT_EQ(euroc.size(), body.size());
  for (size_t i = 0; i < body.size(); i += 97) {
    const PoseSample& g = log.ground_truth[i];
    EXPECT_EQ(g.t_ns, std::stoll(euroc[i][0]));
    for (int k = 0; k < 3; ++k) EXPECT_NEAR(g.p(k), std::stod(euroc[i][1 + k]), 2e-6) << i;
    const Eigen::Quaterniond q(std::stod(euroc[i][4]), std::stod(euroc[i][5]),
                               std::stod(euroc[i][6]), std::stod(euroc[i][7]));
    EXPECT_LT(q.angularDistance(g.q), 1e-7) << i;
  }
}

TEST_F(RecordedLogTest, CleanStreamsAreReadOnRequest) {
  RecordedLogOptions options;
  options.require_imu = false;
  const RecordedLog faulted = ReadRecordedLog(Dir("pme"), options);
  options.use_clean_streams = true;
  const RecordedLog clean = ReadRecordedLog(Dir("pme"), options);
  ASSERT_EQ(clean.streams.size(), 2u);
  EXPECT_EQ(clean.streams[0].file, Dir("pme") / "sensors" / "clean" / "leica.csv");
  EXPECT_EQ(clean.streams[0].rows, CsvRows(clean.streams[0].file).size());
  // The leica stream of this scenario carries a fault: the values differ.
  const auto* a = FindAt(faulted, "leica", 0);
  const auto* b = FindAt(clean, "leica", 0);
  ASSERT_NE(a, nullptr);
  ASSERT_NE(b, nullptr);
  EXPECT_NE(std::get<core::PositionMeasurement>(a->value).p_Ss,
            std::get<core::PositionMeasurement>(b->value).p_Ss);
}

TEST_F(RecordedLogTest, TotalStationRunWithoutImuNeedsRequireImuOff) {
  try {
    ReadRecordedLog(Dir("pme"));
    FAIL() << "no InputError without an IMU stream";
  } catch (const core::InputError& e) {
    EXPECT_CONTAINS(e.what(), "no IMU stream");
    EXPECT_CONTAINS(e.what(), Dir("pme").string());
  }
  RecordedLogOptions options;
  options.require_imu = false;
  const RecordedLog log = ReadRecordedLog(Dir("pme"), options);
  EXPECT_EQ(log.imu_stream, "");
  EXPECT_FALSE(log.imu_noise.has_value());
  ASSERT_EQ(log.streams.size(), 2u);
  EXPECT_EQ(log.streams[0].name, "leica");
  EXPECT_EQ(log.streams[0].kind, core::MeasurementKind::kPosition);
  EXPECT_EQ(log.streams[1].kind, core::MeasurementKind::kPose);
  // Without an IMU, T_Is is the mount in the body frame itself.
  const YAML::Node cal = YAML::LoadFile((Dir("pme") / "calibration.yaml").string());
  EXPECT_TRUE(log.streams[0].T_Is.isApprox(PoseFromYaml(cal["sensors"]["leica"]["T_B_s"]), 1e-12));
  // A total-station row with its position covariance.
  const fs::path file = Dir("pme") / "sensors" / "leica.csv";
  const auto header = CsvHeader(file);
  const auto row = CsvRows(file).at(3);
  const auto* m = FindAt(log, "leica", std::stoll(row[0]));
  ASSERT_NE(m, nullptr);
  const auto& p = std::get<core::PositionMeasurement>(m->value);
  EXPECT_EQ(p.p_Ss.x(), std::stod(row[ColumnIndex(header, "p_Ss_x [m]")]));
  EXPECT_EQ(p.covariance(0, 1), std::stod(row[ColumnIndex(header, "cov_p_01 [m^2]")]));
  EXPECT_EQ(p.covariance(1, 0), std::stod(row[ColumnIndex(header, "cov_p_01 [m^2]")]));
  EXPECT_EQ(p.covariance(2, 2), std::stod(row[ColumnIndex(header, "cov_p_22 [m^2]")]));
  EXPECT_EQ(log.ground_truth.size(), CsvRows(Dir("pme") / "groundtruth.csv").size());
}

// ---- EuRoC (real data) ----

TEST(RecordedLogEuroc, ReadsImuTumPosesAndGroundTruthWithExactStamps) {
  const fs::path dir = fs::path(TOFU_SOURCE_DIR) / ".." / "shared" / "data" / "euroc_v1_02";
  if (!fs::is_directory(dir)) GTEST_SKIP() << "EuRoC excerpt not found at " << dir;
  const RecordedLog log = ReadRecordedLog(dir);
  ASSERT_EQ(log.streams.size(), 2u);
  EXPECT_EQ(log.imu_stream, "imu");
  EXPECT_EQ(log.streams[0].name, "imu");
  EXPECT_EQ(log.streams[0].kind, core::MeasurementKind::kImu);
  EXPECT_EQ(log.streams[0].rows, 7999u);  // 8000 lines with the header
  EXPECT_EQ(log.streams[1].name, "pose_estimate");
  EXPECT_EQ(log.streams[1].kind, core::MeasurementKind::kPose);
  EXPECT_EQ(log.streams[1].rows, 807u);
  EXPECT_EQ(log.ground_truth.size(), 16702u);
  EXPECT_EQ(log.measurements.size(), 7999u + 807u);
  EXPECT_FALSE(log.imu_noise.has_value());

  // Stamps exact to the ns: the first TUM stamp 1.403715529112143517e+09 s.
  const auto poses = Of(log, "pose_estimate");
  EXPECT_EQ(poses.front().first->t_ns, 1403715529112143517);
  EXPECT_EQ(poses.back().first->t_ns, 1403715609312143564);
  const auto& first_pose = std::get<core::PoseMeasurement>(poses.front().first->value);
  EXPECT_EQ(first_pose.p_Ss.x(), -6.151000000000000217e-02);
  // TUM: qx qy qz qw = 0.81321 -0.0273 0.58066 0.02779 (normalised)
  const Eigen::Quaterniond q_file(2.778999999999999873e-02, 8.132099999999999884e-01,
                                  -2.730000000000000135e-02, 5.806599999999999540e-01);
  EXPECT_LT(first_pose.q_Ss.angularDistance(q_file.normalized()), 1e-12);
  EXPECT_NEAR(first_pose.q_Ss.norm(), 1.0, 1e-15);
  EXPECT_EQ(first_pose.covariance, RecordedLogOptions().default_pose_covariance);
  const auto imu = Of(log, "imu");
  EXPECT_EQ(imu.front().first->t_ns, 1403715523912140000);
  EXPECT_EQ(std::get<core::ImuMeasurement>(imu.front().first->value).acc_I_mps2.x(), 9.218251);
  EXPECT_EQ(log.ground_truth.front().t_ns, 1403715524907143168);
  EXPECT_EQ(log.ground_truth.front().p.x(), 0.515356);
  EXPECT_NEAR(log.ground_truth.front().q.w(), 0.161996, 1e-6);
  EXPECT_NEAR(log.ground_truth.front().q.x(), 0.789985, 1e-6);

  // No arrival column: arrival = t, and the streams interleave by time.
  for (size_t i = 0; i < log.measurements.size(); ++i) {
    ASSERT_EQ(log.arrival_ns[i], log.measurements[i].t_ns);
    if (i > 0) {
      ASSERT_LE(log.arrival_ns[i - 1], log.arrival_ns[i]);
    }
  }
  for (const RecordedStream& s : log.streams) {
    EXPECT_TRUE(s.T_Is.isApprox(Eigen::Isometry3d::Identity())) << s.name;
  }
}

// EuRoC's own IMU calibration (mav0/imu0/sensor.yaml, as the ASL datasets ship it): its
// noise densities are the log's, its T_BS the IMU's mount in the body frame of the other
// streams; calibration.yaml, the user's, wins over it.
class RecordedLogEurocSensorYaml : public ::testing::Test {
 protected:
  void SetUp() override {
    const auto* info = ::testing::UnitTest::GetInstance()->current_test_info();
    dir_ = fs::path(::testing::TempDir()) /
           (std::string("tofu_euroc_sensor_yaml_") + info->name() + "_" + std::to_string(::getpid()));
    fs::remove_all(dir_);
    WriteFile(dir_ / "mav0" / "imu0" / "data.csv",
              "#timestamp [ns],w_RS_S_x [rad s^-1],w_RS_S_y [rad s^-1],w_RS_S_z [rad s^-1],"
              "a_RS_S_x [m s^-2],a_RS_S_y [m s^-2],a_RS_S_z [m s^-2]\n"
              "1000000000,0,0,0,0,0,9.81\n1005000000,0,0,0,0,0,9.81\n");
    WriteFile(dir_ / "vio.tum", "1.0 0 0 0 0 0 0 1\n1.1 0 0 0 0 0 0 1\n");
  }
  void TearDown() override { fs::remove_all(dir_); }
  void WriteSensorYaml(const std::string& noise_lines) {
    // A 90° yaw and a 5 cm offset: the mount is visibly applied.
    WriteFile(dir_ / "mav0" / "imu0" / "sensor.yaml",
              "# General sensor definitions.\nsensor_type: imu\ncomment: VI-Sensor IMU (ADIS16448)\n"
              "T_BS:\n  cols: 4\n  rows: 4\n  data: [0.0, -1.0, 0.0, 0.05,\n"
              "         1.0, 0.0, 0.0, 0.0,\n         0.0, 0.0, 1.0, 0.0,\n"
              "         0.0, 0.0, 0.0, 1.0]\nrate_hz: 200\n" + noise_lines);
  }
  fs::path dir_;
};

constexpr const char* kEurocNoise =
    "gyroscope_noise_density: 1.6968e-04     # [ rad / s / sqrt(Hz) ]\n"
    "gyroscope_random_walk: 1.9393e-05       # [ rad / s^2 / sqrt(Hz) ]\n"
    "accelerometer_noise_density: 2.0000e-3  # [ m / s^2 / sqrt(Hz) ]\n"
    "accelerometer_random_walk: 3.0000e-3    # [ m / s^3 / sqrt(Hz) ]\n";

TEST_F(RecordedLogEurocSensorYaml, NoiseDensitiesAndMountComeFromTheImusSensorYaml) {
  WriteSensorYaml(kEurocNoise);
  const RecordedLog log = ReadRecordedLog(dir_);
  ASSERT_TRUE(log.imu_noise.has_value());
  EXPECT_EQ(log.imu_noise->gyro_noise_density_radps_per_sqrthz, 1.6968e-04);
  EXPECT_EQ(log.imu_noise->gyro_random_walk_radps2_per_sqrthz, 1.9393e-05);
  EXPECT_EQ(log.imu_noise->accel_noise_density_mps2_per_sqrthz, 2.0e-3);
  EXPECT_EQ(log.imu_noise->accel_random_walk_mps3_per_sqrthz, 3.0e-3);
  const auto vio = std::find_if(log.streams.begin(), log.streams.end(),
                                [](const RecordedStream& s) { return s.name == "vio"; });
  ASSERT_NE(vio, log.streams.end());
  // T_Is = T_BI⁻¹ (the stream is of the body frame): the body origin seen from the IMU.
  Eigen::Isometry3d T_BI = Eigen::Isometry3d::Identity();
  T_BI.linear() << 0, -1, 0, 1, 0, 0, 0, 0, 1;
  T_BI.translation() = Eigen::Vector3d(0.05, 0, 0);
  EXPECT_TRUE(vio->T_Is.isApprox(T_BI.inverse(), 1e-12));
  EXPECT_NE(std::find(log.notes.begin(), log.notes.end(),
                      "IMU noise densities from mav0/imu0/sensor.yaml"),
            log.notes.end());
}

TEST_F(RecordedLogEurocSensorYaml, CalibrationYamlWinsOverIt) {
  WriteSensorYaml(kEurocNoise);
  WriteFile(dir_ / "calibration.yaml",
            "sensors:\n  imu:\n    options:\n      gyro_noise_density_radps_per_sqrthz: 1e-3\n"
            "      accel_noise_density_mps2_per_sqrthz: 1e-2\n"
            "      gyro_random_walk_radps2_per_sqrthz: 1e-4\n"
            "      accel_random_walk_mps3_per_sqrthz: 1e-3\n");
  const RecordedLog log = ReadRecordedLog(dir_);
  ASSERT_TRUE(log.imu_noise.has_value());
  EXPECT_EQ(log.imu_noise->gyro_noise_density_radps_per_sqrthz, 1e-3);
  for (const RecordedStream& s : log.streams) {
    EXPECT_TRUE(s.T_Is.isApprox(Eigen::Isometry3d::Identity())) << s.name;
  }
}

TEST_F(RecordedLogEurocSensorYaml, AMissingDensityOrABadTransformNamesFileAndKey) {
  WriteSensorYaml("gyroscope_noise_density: 1.6968e-04\ngyroscope_random_walk: 1.9393e-05\n"
                  "accelerometer_noise_density: 2.0000e-3\n");
  try {
    ReadRecordedLog(dir_);
    ADD_FAILURE() << "no InputError";
  } catch (const core::InputError& e) {
    const std::string what = e.what();
    EXPECT_NE(what.find("sensor.yaml"), std::string::npos) << what;
    EXPECT_NE(what.find("accelerometer_random_walk"), std::string::npos) << what;
  }
  WriteFile(dir_ / "mav0" / "imu0" / "sensor.yaml",
            std::string("T_BS:\n  data: [2, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1]\n") +
                kEurocNoise);
  try {
    ReadRecordedLog(dir_);
    ADD_FAILURE() << "no InputError";
  } catch (const core::InputError& e) {
    const std::string what = e.what();
    EXPECT_NE(what.find("sensor.yaml:2"), std::string::npos) << what;
    EXPECT_NE(what.find("T_BS.data"), std::string::npos) << what;
    EXPECT_NE(what.find("rigid transform"), std::string::npos) << what;
  }
}

// ---- bad input ----

class RecordedLogInputTest : public ::testing::Test {
 protected:
  void SetUp() override {
    const auto* info = ::testing::UnitTest::GetInstance()->current_test_info();
    dir_ = fs::path(::testing::TempDir()) /
           (std::string("tofu_recorded_log_input_") + info->name() + "_" + std::to_string(::getpid()));
    fs::remove_all(dir_);
    fs::create_directories(dir_ / "sensors");
  }
  void TearDown() override { fs::remove_all(dir_); }

  // what() of the InputError that reading dir_ throws (empty if none).
  std::string ErrorOf() {
    try {
      ReadRecordedLog(dir_);
    } catch (const core::InputError& e) {
      return e.what();
    }
    ADD_FAILURE() << "no InputError";
    return "";
  }
  fs::path dir_;
};

constexpr const char* kImuHeader =
    "#timestamp [ns],w_RS_S_x [rad s^-1],w_RS_S_y [rad s^-1],w_RS_S_z [rad s^-1],"
    "a_RS_S_x [m s^-2],a_RS_S_y [m s^-2],a_RS_S_z [m s^-2],arrival [ns]\n";

TEST_F(RecordedLogInputTest, NonNumericFieldNamesFileLineAndColumn) {
  WriteFile(dir_ / "sensors" / "imu.csv", std::string(kImuHeader) +
                                              "1000,0,0,0,0,0,9.81,1000\n"
                                              "2000,0,0,0,0,abc,9.81,2000\n");
  const std::string what = ErrorOf();
  EXPECT_CONTAINS(what, "imu.csv:3:");
  EXPECT_CONTAINS(what, "a_RS_S_y");
  EXPECT_CONTAINS(what, "'abc'");
  EXPECT_CONTAINS(what, "expected a number");
}

TEST_F(RecordedLogInputTest, NonIntegerTimestampIsAnError) {
  WriteFile(dir_ / "sensors" / "imu.csv", std::string(kImuHeader) + "1.5e3,0,0,0,0,0,9.81,1000\n");
  const std::string what = ErrorOf();
  EXPECT_CONTAINS(what, "imu.csv:2:1");
  EXPECT_CONTAINS(what, "timestamp [ns]");
  EXPECT_CONTAINS(what, "integer");
}

TEST_F(RecordedLogInputTest, WrongColumnCountNamesTheMissingColumn) {
  WriteFile(dir_ / "sensors" / "imu.csv", std::string(kImuHeader) +
                                              "1000,0,0,0,0,0,9.81,1000\n"
                                              "2000,0,0,0,0,0,9.81,2000\n"
                                              "3000,0,0,0,0,0,9.81\n");
  const std::string what = ErrorOf();
  EXPECT_CONTAINS(what, "imu.csv:4");
  EXPECT_CONTAINS(what, "arrival [ns]");
  EXPECT_CONTAINS(what, "expected 8 comma-separated fields");
}

TEST_F(RecordedLogInputTest, MissingHeaderIsAnError) {
  WriteFile(dir_ / "sensors" / "imu.csv", "1000,0,0,0,0,0,9.81,1000\n");
  const std::string what = ErrorOf();
  EXPECT_CONTAINS(what, "imu.csv:1:");
  EXPECT_CONTAINS(what, "missing header");
  EXPECT_CONTAINS(what, "#timestamp [ns]");
}

TEST_F(RecordedLogInputTest, MissingColumnOfAKindIsNamed) {
  WriteFile(dir_ / "sensors" / "imu.csv",
            "#timestamp [ns],w_RS_S_x,w_RS_S_y,w_RS_S_z,a_RS_S_x,a_RS_S_y\n");
  const std::string what = ErrorOf();
  EXPECT_CONTAINS(what, "imu.csv:1");
  EXPECT_CONTAINS(what, "a_RS_S_z");
}

TEST_F(RecordedLogInputTest, NoImuStreamIsAnError) {
  WriteFile(dir_ / "sensors" / "vio.csv",
            "#timestamp [ns],p_Ss_x [m],p_Ss_y [m],p_Ss_z [m],q_Ss_w [],q_Ss_x [],q_Ss_y [],"
            "q_Ss_z []\n0,1,2,3,1,0,0,0\n");
  EXPECT_CONTAINS(ErrorOf(), "no IMU stream");
  // ... and an empty directory, and a missing one.
  fs::remove_all(dir_ / "sensors");
  EXPECT_CONTAINS(ErrorOf(), "no IMU stream");
  fs::remove_all(dir_);
  EXPECT_CONTAINS(ErrorOf(), "no such directory");
}

TEST_F(RecordedLogInputTest, UnknownStreamKindIsAnError) {
  WriteFile(dir_ / "sensors" / "imu.csv", std::string(kImuHeader));
  WriteFile(dir_ / "sensors" / "odd.csv", "#timestamp [ns],speed [m/s]\n0,1\n");
  const std::string what = ErrorOf();
  EXPECT_CONTAINS(what, "odd.csv:1");
  EXPECT_CONTAINS(what, "cannot tell the stream kind");
}

TEST_F(RecordedLogInputTest, NanAndOutOfOrderValuesPassThrough) {
  WriteFile(dir_ / "sensors" / "imu.csv", std::string(kImuHeader) +
                                              "1000,nan,0,0,0,0,9.81,1000\n"
                                              "3000,0,-inf,0,0,0,9.81,3000\n"
                                              "2000,0,0,NaN,0,0,9.81,3500\n");
  WriteFile(dir_ / "sensors" / "gnss.csv",
            "#timestamp [ns],arrival [ns],p_Ss_x [m],p_Ss_y [m],p_Ss_z [m]\n"
            "1500,1600,nan,2,3\n");
  const RecordedLog log = ReadRecordedLog(dir_);
  ASSERT_EQ(log.measurements.size(), 4u);
  // Arrival order: 1000 (imu), 1600 (gnss), 3000 (imu), 3500 (imu, stamped 2000).
  EXPECT_EQ(log.measurements[0].t_ns, 1000);
  EXPECT_TRUE(std::isnan(std::get<core::ImuMeasurement>(log.measurements[0].value).gyro_I_radps.x()));
  EXPECT_EQ(log.measurements[1].sensor, "gnss");
  const auto& gnss = std::get<core::PositionMeasurement>(log.measurements[1].value);
  EXPECT_TRUE(std::isnan(gnss.p_Ss.x()));
  EXPECT_EQ(gnss.covariance, RecordedLogOptions().default_position_covariance);
  EXPECT_EQ(std::get<core::ImuMeasurement>(log.measurements[2].value).gyro_I_radps.y(),
            -std::numeric_limits<double>::infinity());
  EXPECT_EQ(log.measurements[3].t_ns, 2000);  // out of order: passed through
  EXPECT_TRUE(std::isnan(std::get<core::ImuMeasurement>(log.measurements[3].value).gyro_I_radps.z()));
  EXPECT_TRUE(log.ground_truth.empty());
}

TEST_F(RecordedLogInputTest, BadCalibrationNamesItsKeyAndLine) {
  WriteFile(dir_ / "sensors" / "imu.csv", std::string(kImuHeader));
  WriteFile(dir_ / "calibration.yaml",
            "sensors:\n  imu:\n    type: imu\n    T_B_s:\n      p_m: [0, 0, zero]\n"
            "      q_wxyz: [1, 0, 0, 0]\n");
  const std::string what = ErrorOf();
  EXPECT_CONTAINS(what, "calibration.yaml:5:");
  EXPECT_CONTAINS(what, "sensors.imu.T_B_s.p_m[2]");
}

TEST_F(RecordedLogInputTest, EmptyStreamsAreAllowed) {
  WriteFile(dir_ / "sensors" / "imu.csv", std::string(kImuHeader));
  const RecordedLog log = ReadRecordedLog(dir_);
  ASSERT_EQ(log.streams.size(), 1u);
  EXPECT_EQ(log.streams[0].rows, 0u);
  EXPECT_EQ(log.imu_stream, "imu");
}

// calibration.yaml has one reader (replay/run_calibration.h) for `tofu estimate`, `tofu
// consistency` and the renderer: malformed content is an InputError at its line and key,
// read where it is asked for.
TEST(RunCalibration, MalformedFieldsNameTheirLineAndKey) {
  const auto error_of = [](const auto& read) { return test::InputErrorOf(read); };
  const std::string text =
      "sensors:\n"
      "  vio:\n"
      "    type: vio\n"
      "    options: {position_noise_m: abc, rotation_noise_deg: [1, 2]}\n"
      "  lidar:\n"
      "    type: lidar_odometry\n"
      "    options:\n"
      "      azimuth_count: 0\n"
      "      elevation_count: 4\n"
      "      elevation_min_deg: -7\n"
      "      elevation_max_deg: 52\n"
      "      min_range_m: 0.5\n"
      "      max_range_m: 40\n";
  const replay::RunCalibration cal = replay::ParseRunCalibration(text, "cal.yaml");
  const core::InputError not_a_number = error_of([&] { cal.OptionNumber("vio", "position_noise_m"); });
  EXPECT_EQ(not_a_number.location().line, 4) << not_a_number.what();
  EXPECT_EQ(not_a_number.key_path(), "sensors.vio.options.position_noise_m");
  const core::InputError a_list = error_of([&] { cal.OptionNumber("vio", "rotation_noise_deg"); });
  EXPECT_EQ(a_list.location().line, 4) << a_list.what();
  EXPECT_NE(std::string(a_list.what()).find("expected a number"), std::string::npos);
  const core::InputError zero_azimuths = error_of([&] { cal.LidarBeams("lidar"); });
  EXPECT_EQ(zero_azimuths.location().line, 8) << zero_azimuths.what();
  EXPECT_EQ(zero_azimuths.key_path(), "sensors.lidar.options.azimuth_count");
  EXPECT_FALSE(cal.LidarBeams("vio").has_value());
  EXPECT_EQ(cal.OptionNumber("lidar", "missing_key"), std::nullopt);

  const core::InputError list_root =
      error_of([] { replay::ParseRunCalibration("- a\n- b\n", "cal.yaml"); });
  EXPECT_EQ(list_root.location().line, 1) << list_root.what();
  const core::InputError nan_mount = error_of([] {
    replay::ParseRunCalibration("mounts:\n  imu: {p_m: [0, .nan, 0], q_wxyz: [1, 0, 0, 0]}\n",
                                "cal.yaml");
  });
  EXPECT_EQ(nan_mount.key_path(), "mounts.imu.p_m[1]") << nan_mount.what();
  EXPECT_FALSE(replay::ReadRunCalibration("/nonexistent/calibration.yaml").present);
}

}  // namespace
}  // namespace tofu::replay
