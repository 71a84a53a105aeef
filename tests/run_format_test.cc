// The run format of the sensor streams (replay/run_format.h): the headers and rows the
// recorder writes are the ones every run directory has had, a row read back is bit for
// bit what AsRecorded hands the in-loop estimators, and a header without a column the
// reader needs is an InputError naming the file, the column and the expected form.
#include "replay/run_format.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <random>
#include <string>
#include <vector>

#include "core/error.h"
#include "replay/csv_reader.h"
#include "tests/test_support.h"

namespace tofu::replay {
namespace {

using test::InputErrorOf;

// Numbers with every digit used, over the ranges a flight sees (seeded: the same each run).
class Values {
 public:
  double Next(double scale) { return scale * uniform_(random_); }
  Eigen::Vector3d Vector(double scale) { return {Next(scale), Next(scale), Next(scale)}; }
  template <int N>
  Eigen::Matrix<double, N, N> Covariance(double scale) {
    const Eigen::Matrix<double, N, N> a = Eigen::Matrix<double, N, N>::NullaryExpr(
        [&](Eigen::Index, Eigen::Index) { return Next(scale); });
    return a * a.transpose();
  }

 private:
  std::mt19937_64 random_{20261127};
  std::uniform_real_distribution<double> uniform_{-1.0, 1.0};
};

core::ImuMeasurement Imu(Values& v) {
  core::ImuMeasurement m;
  m.gyro_I_radps = v.Vector(3.0);
  m.acc_I_mps2 = v.Vector(20.0);
  return m;
}

core::PoseMeasurement Pose(Values& v, bool twist) {
  core::PoseMeasurement m;
  m.p_Ss = v.Vector(50.0);
  // w < 0: the file holds the canonical sign, the reader normalises.
  m.q_Ss = Eigen::Quaterniond(-0.8, v.Next(0.3), v.Next(0.3), v.Next(0.3)).normalized();
  m.covariance = v.Covariance<6>(0.05);
  m.has_twist = twist;
  if (twist) {
    m.v_s_s_mps = v.Vector(2.0);
    m.omega_s_s_radps = v.Vector(1.0);
    m.twist_covariance = v.Covariance<6>(0.01);
  }
  return m;
}

core::PositionMeasurement Position(Values& v) {
  core::PositionMeasurement m;
  m.p_Ss = v.Vector(200.0);
  m.covariance = v.Covariance<3>(0.02);
  return m;
}

// Rows of `values` as the recorder writes them (truth = the value itself: err_* zero).
std::string CsvOf(const std::vector<core::Measurement>& values) {
  std::string text = SensorCsvHeader(core::MeasurementKindOf(values.front()));
  core::Time t_ns = 1'000'000;
  for (const core::Measurement& value : values) {
    AppendSensorCsvRow({t_ns, t_ns + 7, &value, &value, "occluded", ""}, text);
    t_ns += 5'000'000;
  }
  return text;
}

// The measurements the reader takes from `text`.
std::vector<core::Measurement> ReadBack(const std::string& text) {
  CsvReader csv(CsvText{text, "sensors/s.csv"}, "#timestamp [ns],...");
  const SensorCsvColumns columns = LocateSensorCsvColumns(csv.keys(), csv.name());
  std::vector<core::Measurement> out;
  while (csv.Next()) out.push_back(ReadSensorCsvRow(csv, columns, {}));
  return out;
}

template <typename M>
void ExpectBitIdentical(const core::Measurement& read, const core::Measurement& recorded) {
  ASSERT_TRUE(std::holds_alternative<M>(read));
  ASSERT_TRUE(std::holds_alternative<M>(recorded));
  const M& a = std::get<M>(read);
  const M& b = std::get<M>(recorded);
  if constexpr (std::is_same_v<M, core::ImuMeasurement>) {
    EXPECT_EQ(a.gyro_I_radps, b.gyro_I_radps);
    EXPECT_EQ(a.acc_I_mps2, b.acc_I_mps2);
  } else if constexpr (std::is_same_v<M, core::PoseMeasurement>) {
    EXPECT_EQ(a.p_Ss, b.p_Ss);
    EXPECT_EQ(a.q_Ss.coeffs(), b.q_Ss.coeffs());
    EXPECT_EQ(a.covariance, b.covariance);
    EXPECT_EQ(a.has_twist, b.has_twist);
    EXPECT_EQ(a.v_s_s_mps, b.v_s_s_mps);
    EXPECT_EQ(a.omega_s_s_radps, b.omega_s_s_radps);
    EXPECT_EQ(a.twist_covariance, b.twist_covariance);
  } else {
    EXPECT_EQ(a.p_Ss, b.p_Ss);
    EXPECT_EQ(a.covariance, b.covariance);
  }
}

template <typename M>
void ExpectRoundTrip(const std::vector<core::Measurement>& values) {
  const std::vector<core::Measurement> read = ReadBack(CsvOf(values));
  ASSERT_EQ(read.size(), values.size());
  for (std::size_t i = 0; i < values.size(); ++i) {
    SCOPED_TRACE(i);
    ExpectBitIdentical<M>(read[i], AsRecorded(values[i]));
  }
}

TEST(RunFormat, HeadersAreTheOnesEveryRunDirectoryHas) {
  EXPECT_EQ(SensorCsvHeader(core::MeasurementKind::kImu),
            "#timestamp [ns],w_RS_S_x [rad s^-1],w_RS_S_y [rad s^-1],w_RS_S_z [rad s^-1],"
            "a_RS_S_x [m s^-2],a_RS_S_y [m s^-2],a_RS_S_z [m s^-2],arrival [ns],"
            "err_w_x [rad s^-1],err_w_y [rad s^-1],err_w_z [rad s^-1],"
            "err_a_x [m s^-2],err_a_y [m s^-2],err_a_z [m s^-2],conditions,faults\n");
  EXPECT_EQ(SensorCsvHeader(core::MeasurementKind::kPosition),
            "#timestamp [ns],arrival [ns],p_Ss_x [m],p_Ss_y [m],p_Ss_z [m],cov_p_00 [m^2],"
            "cov_p_01 [m^2],cov_p_02 [m^2],cov_p_11 [m^2],cov_p_12 [m^2],cov_p_22 [m^2],"
            "err_p_x [m],err_p_y [m],err_p_z [m],conditions,faults\n");
  const std::string pose = SensorCsvHeader(core::MeasurementKind::kPose);
  EXPECT_TRUE(pose.starts_with(
      "#timestamp [ns],arrival [ns],p_Ss_x [m],p_Ss_y [m],p_Ss_z [m],q_Ss_w [],q_Ss_x [],"
      "q_Ss_y [],q_Ss_z [],v_s_x [m s^-1],v_s_y [m s^-1],v_s_z [m s^-1],omega_s_x [rad s^-1],"
      "omega_s_y [rad s^-1],omega_s_z [rad s^-1],cov_pose_00 [rad|m],cov_pose_01 [rad|m],"))
      << pose;
  EXPECT_TRUE(pose.ends_with(
      ",cov_twist_45 [m/s|rad/s],cov_twist_55 [m/s|rad/s],err_p_x [m],err_p_y [m],"
      "err_p_z [m],err_theta_x [rad],err_theta_y [rad],err_theta_z [rad],conditions,faults\n"))
      << pose;
  EXPECT_EQ(std::count(pose.begin(), pose.end(), ','), 15 + 21 + 21 + 8 - 1);
}

TEST(RunFormat, ARowHasEachColumnAtItsPrecisionAndTheErrorsAgainstTheTruth) {
  core::PositionMeasurement measured;
  measured.p_Ss = {1.5, -2.25, 3.0000004};
  measured.covariance = 1e-4 * Eigen::Matrix3d::Identity();
  core::PositionMeasurement truth;
  truth.p_Ss = {1.25, -2.25, 3.0};
  const core::Measurement m = measured;
  const core::Measurement t = truth;
  std::string row;
  AppendSensorCsvRow({1000, 1500, &m, &t, "occluded", "jump|delay"}, row);
  EXPECT_EQ(row, "1000,1500,1.500000,-2.250000,3.000000,1.000000e-04,0.000000e+00,"
                 "0.000000e+00,1.000000e-04,0.000000e+00,1.000000e-04,0.250000,0.000000,"
                 "0.000000,occluded,jump|delay\n");
}

TEST(RunFormat, APoseWithoutTwistLeavesTheTwistAndItsCovarianceEmpty) {
  Values v;
  const core::Measurement m = Pose(v, false);
  std::string row;
  AppendSensorCsvRow({1, 2, &m, &m, "", ""}, row);
  // 15 columns before the covariances: the twist is 6 empty fields after the quaternion.
  EXPECT_NE(row.find(",,,,,,,"), std::string::npos) << row;
  EXPECT_EQ(std::count(row.begin(), row.end(), ','), 15 + 21 + 21 + 8 - 1);
  const std::vector<core::Measurement> read = ReadBack(SensorCsvHeader(core::MeasurementKind::kPose) + row);
  ASSERT_EQ(read.size(), 1u);
  EXPECT_FALSE(std::get<core::PoseMeasurement>(read[0]).has_twist);
}

TEST(RunFormat, EveryKindReadBackIsBitForBitWhatTheInLoopEstimatorsAreGiven) {
  Values v;
  std::vector<core::Measurement> imu, pose, position;
  for (int i = 0; i < 200; ++i) {
    imu.push_back(Imu(v));
    pose.push_back(Pose(v, i % 3 != 0));
    position.push_back(Position(v));
  }
  ExpectRoundTrip<core::ImuMeasurement>(imu);
  ExpectRoundTrip<core::PoseMeasurement>(pose);
  ExpectRoundTrip<core::PositionMeasurement>(position);
}

TEST(RunFormat, AsRecordedKeepsTheFilesPrecisionAndCanonicalSign) {
  Values v;
  const core::PoseMeasurement pose = Pose(v, true);
  const core::PoseMeasurement recorded = std::get<core::PoseMeasurement>(AsRecorded(pose));
  EXPECT_GE(recorded.q_Ss.w(), 0.0);
  EXPECT_NEAR(recorded.q_Ss.angularDistance(pose.q_Ss), 0.0, 1e-8);
  EXPECT_LE((recorded.p_Ss - pose.p_Ss).cwiseAbs().maxCoeff(), 0.5e-6);
  EXPECT_NE(recorded.p_Ss, pose.p_Ss);  // rounded to the micrometre, not passed through
}

TEST(RunFormat, AMissingColumnNamesTheFileTheColumnAndWhatItIs) {
  const core::InputError e = InputErrorOf([] {
    LocateSensorCsvColumns({"timestamp", "w_RS_S_x", "w_RS_S_y", "w_RS_S_z", "a_RS_S_x",
                            "a_RS_S_z"},
                           "run/sensors/imu.csv");
  });
  EXPECT_EQ(e.location().file, "run/sensors/imu.csv");
  EXPECT_EQ(e.location().line, 1);
  EXPECT_CONTAINS(e.what(), "missing column 'a_RS_S_y' (IMU specific force in m/s^2)");
}

TEST(RunFormat, APartOfACovarianceOrOfATwistIsAnError) {
  const core::InputError cov = InputErrorOf([] {
    LocateSensorCsvColumns({"timestamp", "p_Ss_x", "p_Ss_y", "p_Ss_z", "cov_p_00", "cov_p_01"},
                           "gnss.csv");
  });
  EXPECT_CONTAINS(cov.what(), "has cov_p_* columns but not 'cov_p_02': expected all 6 "
                              "upper-triangle entries cov_p_00..cov_p_22");
  const core::InputError twist = InputErrorOf([] {
    LocateSensorCsvColumns({"timestamp", "p_Ss_x", "p_Ss_y", "p_Ss_z", "q_Ss_w", "q_Ss_x",
                            "q_Ss_y", "q_Ss_z", "omega_s_x", "omega_s_y", "omega_s_z"},
                           "vio.csv");
  });
  EXPECT_CONTAINS(twist.what(), "missing column 'v_s_x' (twist: velocity of s in s, m/s)");
  const core::InputError kind = InputErrorOf([] {
    LocateSensorCsvColumns({"timestamp", "x", "y"}, "what.csv");
  });
  EXPECT_CONTAINS(kind.what(), "cannot tell the stream kind");
}

TEST(RunFormat, OptionalColumnsMayBeAbsentAndLabelsAreNotRead) {
  const SensorCsvColumns euroc = LocateSensorCsvColumns(
      {"timestamp", "w_RS_S_x", "w_RS_S_y", "w_RS_S_z", "a_RS_S_x", "a_RS_S_y", "a_RS_S_z"},
      "mav0/imu0/data.csv");
  EXPECT_EQ(euroc.kind(), core::MeasurementKind::kImu);
  EXPECT_FALSE(euroc.Has(SensorField::kArrival));
  EXPECT_EQ(euroc.Column(SensorField::kAccel, 2), 6);
  const SensorCsvColumns pose = LocateSensorCsvColumns(
      {"timestamp", "p_Ss_x", "p_Ss_y", "p_Ss_z", "q_Ss_w", "q_Ss_x", "q_Ss_y", "q_Ss_z",
       "err_p_x", "conditions"},
      "tum_like.csv");
  EXPECT_EQ(pose.kind(), core::MeasurementKind::kPose);
  EXPECT_FALSE(pose.Has(SensorField::kVelocity));
  EXPECT_FALSE(pose.Has(SensorField::kPoseCovariance));
  EXPECT_TRUE(pose.IsReadKey("q_Ss_z"));
  EXPECT_FALSE(pose.IsReadKey("conditions"));
  EXPECT_TRUE(pose.IsLabelKey("conditions"));
  EXPECT_FALSE(pose.IsReadKey("p_Ss_w"));
}

TEST(RunFormat, SensorTypesMapToTheKindOfStreamTheyRecord) {
  EXPECT_EQ(MeasurementKindOfSensorType("imu"), core::MeasurementKind::kImu);
  EXPECT_EQ(MeasurementKindOfSensorType("vio"), core::MeasurementKind::kPose);
  EXPECT_EQ(MeasurementKindOfSensorType("lidar_odometry"), core::MeasurementKind::kPose);
  EXPECT_EQ(MeasurementKindOfSensorType("total_station"), core::MeasurementKind::kPosition);
  EXPECT_EQ(MeasurementKindOfSensorType("gnss"), core::MeasurementKind::kPosition);
  EXPECT_EQ(MeasurementKindOfSensorType("sonar"), std::nullopt);
}

}  // namespace
}  // namespace tofu::replay
