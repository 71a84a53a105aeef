// The estimator on real logs as they come (issue 21): the shared EuRoC V1_02 excerpt (real
// ADIS16448 IMU at 200 Hz, a real visual pose estimate at 10 Hz without a covariance, Vicon
// ground truth with the IMU biases) cut to start at 0, 5, 10, 15 and 20 s, some
// mid-manoeuvre, and replayed as `tofu estimate` replays a log: the estimator must start
// in motion (visual-inertial alignment), weight the stream by the noise it measures from
// the data, and never make its input worse. Then a 5 s hole in the IMU of one cut.
//
// The bounds are the goal figures, not the measured values: fused ATE ≤ 1.1× the
// stream's own on the same span, rotation ≤ 1.5× + 0.5°, on average below the stream;
// initialisation within 2 s of the first sample in motion. Skipped when ../shared is absent.

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <map>
#include <string>
#include <vector>

#include <fmt/format.h>

#include "core/time.h"
#include "replay/recorded_log.h"
#include "replay/replay.h"
#include "replay/trajectory_metrics.h"

namespace tofu {
namespace {

namespace fs = std::filesystem;
using core::Time;
using replay::RecordedLog;
using replay::ReplayResult;

constexpr Time kSecond = core::kNanosecondsPerSecond;

fs::path EurocDir() { return fs::path(TOFU_SOURCE_DIR) / ".." / "shared" / "data" / "euroc_v1_02"; }

// The log restricted to [first IMU sample + start_s, + length_s]: every stream and the
// ground truth, as a log recorded from that instant on would hold them.
RecordedLog Cut(const RecordedLog& log, double start_s, double length_s) {
  Time first_imu = 0;
  for (const core::StampedMeasurement& m : log.measurements) {
    if (m.sensor == log.imu_stream) {
      first_imu = m.t_ns;
      break;
    }
  }
  const Time from = first_imu + core::SecondsToTime(start_s);
  const Time to = from + core::SecondsToTime(length_s);
  RecordedLog cut = log;
  cut.measurements.clear();
  cut.arrival_ns.clear();
  for (std::size_t i = 0; i < log.measurements.size(); ++i) {
    const Time t = log.measurements[i].t_ns;
    if (t < from || t > to) continue;
    cut.measurements.push_back(log.measurements[i]);
    cut.arrival_ns.push_back(log.arrival_ns[i]);
  }
  cut.ground_truth.clear();
  cut.ground_truth_biases.clear();
  for (std::size_t i = 0; i < log.ground_truth.size(); ++i) {
    const replay::PoseSample& g = log.ground_truth[i];
    if (g.t_ns < from || g.t_ns > to) continue;
    cut.ground_truth.push_back(g);
    if (!log.ground_truth_biases.empty()) cut.ground_truth_biases.push_back(log.ground_truth_biases[i]);
  }
  return cut;
}

ReplayResult ReplaySingle(const RecordedLog& log) {
  return replay::Replay(log, replay::ParseReplayMethod("single:pose_estimate", log),
                         replay::DefaultEstimatorOptions(log), replay::SensorSpecsOf(log));
}

// The fused estimate's errors and its input's on the same span (what `tofu estimate`
// reports as input_check).
replay::InputCheck Check(const RecordedLog& log, const ReplayResult& result) {
  const std::optional<replay::InputCheck> check = replay::ScoreMethod(log, result, {}).input_check;
  EXPECT_TRUE(check.has_value());
  return check.value_or(replay::InputCheck{});
}

struct CutSpec {
  double start_s;
  double length_s;
};
constexpr CutSpec kCuts[] = {{0, 40}, {5, 35}, {10, 30}, {15, 25}, {20, 20}};

struct CutOutcome {
  replay::InputCheck check;
  ReplayResult result;
};

class EurocCutsTest : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    if (!fs::exists(EurocDir() / "mav0" / "imu0" / "data.csv")) return;
    log_ = new RecordedLog(replay::ReadRecordedLog(EurocDir()));
    outcomes_ = new std::map<double, CutOutcome>();
    for (const CutSpec& c : kCuts) {
      const RecordedLog cut = Cut(*log_, c.start_s, c.length_s);
      CutOutcome outcome;
      outcome.result = ReplaySingle(cut);
      outcome.check = Check(cut, outcome.result);
      fmt::print("cut {:>2.0f} s + {:.0f} s: fused {:.1f} cm {:.2f} deg, stream {:.1f} cm {:.2f} deg\n",
                 c.start_s, c.length_s, 100 * outcome.check.ate_m, outcome.check.rotation_deg,
                 100 * outcome.check.input_ate_m, outcome.check.input_rotation_deg);
      outcomes_->emplace(c.start_s, std::move(outcome));
    }
  }
  static void TearDownTestSuite() {
    delete outcomes_;
    delete log_;
    outcomes_ = nullptr;
    log_ = nullptr;
  }
  void SetUp() override {
    if (log_ == nullptr) GTEST_SKIP() << "EuRoC V1_02 not found at " << EurocDir();
  }
  static inline RecordedLog* log_ = nullptr;
  static inline std::map<double, CutOutcome>* outcomes_ = nullptr;
};

TEST_F(EurocCutsTest, OnEveryCutTheFusedEstimateIsNoWorseThanItsInput) {
  for (const auto& [start_s, outcome] : *outcomes_) {
    SCOPED_TRACE(fmt::format("cut at {} s", start_s));
    const replay::InputCheck& c = outcome.check;
    ASSERT_GT(c.input_ate_m, 0.0);
    EXPECT_LE(c.ate_m, 1.1 * c.input_ate_m);
    EXPECT_LE(c.rotation_deg, 1.5 * c.input_rotation_deg + 0.5);
    EXPECT_EQ(outcome.result.counters.reinitialisations, 0);
  }
}

TEST_F(EurocCutsTest, AveragedOverTheCutsTheFusedEstimateBeatsItsInput) {
  double fused = 0.0, input = 0.0;
  for (const auto& [start_s, outcome] : *outcomes_) {
    fused += outcome.check.ate_m;
    input += outcome.check.input_ate_m;
  }
  EXPECT_LT(fused, input);
}

TEST_F(EurocCutsTest, FromItsFirstSampleTheFullExcerptStaysUnderSixCentimetres) {
  // Issue 21's floor: no worse than the 5.9 cm of the rest-started replay before it.
  EXPECT_LE(outcomes_->at(0).check.ate_m, 0.059);
}

TEST_F(EurocCutsTest, AMovingStartInitialisesFromTheVisualInertialAlignmentWithinTwoSeconds) {
  for (const auto& [start_s, outcome] : *outcomes_) {
    SCOPED_TRACE(fmt::format("cut at {} s", start_s));
    const ReplayResult& r = outcome.result;
    ASSERT_EQ(r.initialisations.size(), 1u);
    ASSERT_TRUE(r.first_measurement_ns.has_value());
    const estimator::InitialisationRecord& init = r.initialisations.front();
    if (start_s == 0) {
      // The excerpt starts with 4.9 s on the ground: the rest state initialises.
      EXPECT_EQ(init.method, estimator::InitialisationRecord::Method::kRest);
      continue;
    }
    EXPECT_EQ(init.method, estimator::InitialisationRecord::Method::kVisualInertial);
    EXPECT_LE(init.t_ns - *r.first_measurement_ns, 2 * kSecond);
    // The stream states no covariance: its weights are measured from the data, within the
    // physically plausible (mm and sub-degree between 10 Hz samples of a good VIO).
    EXPECT_TRUE(init.noise_from_data);
    EXPECT_GT(init.relative_position_std_m, 1e-4);
    EXPECT_LT(init.relative_position_std_m, 0.02);
    EXPECT_LT(init.relative_rotation_std_rad, 1.0 * M_PI / 180.0);
    EXPECT_EQ(r.stream_noise.at("pose_estimate").source, "measured");
  }
}

// Issue 21: gravity direction error ≤ 1° after initialisation. Roll and pitch against the
// ground truth (L and W are both gravity-aligned: no alignment), RMS over every valid output
// of the cut. (At the instant of initialisation it is 2.25° on the 5 s cut, where the VIO
// itself is in its take-off transient: docs/RESULTS.md.)
TEST_F(EurocCutsTest, TheGravityDirectionStaysWithinADegreeOverEveryCut) {
  for (const auto& [start_s, outcome] : *outcomes_) {
    SCOPED_TRACE(fmt::format("cut at {} s", start_s));
    double sum_sq = 0.0;
    std::size_t n = 0;
    auto truth = log_->ground_truth.begin();
    for (const estimator::EstimatorOutput& o : outcome.result.outputs) {
      if (!o.valid) continue;
      while (truth != log_->ground_truth.end() && truth->t_ns < o.t_ns) ++truth;
      if (truth == log_->ground_truth.end()) break;
      const Eigen::Vector3d down_est = o.state.q_LI.conjugate() * -Eigen::Vector3d::UnitZ();
      const Eigen::Vector3d down_true = truth->q.conjugate() * -Eigen::Vector3d::UnitZ();
      const double deg = std::atan2(down_est.cross(down_true).norm(), down_est.dot(down_true)) * 180.0 / M_PI;
      sum_sq += deg * deg;
      ++n;
    }
    ASSERT_GT(n, 1000u);
    EXPECT_LE(std::sqrt(sum_sq / n), 1.0);
  }
}

TEST_F(EurocCutsTest, EstimatedBiasesConvergeToTheGroundTruths) {
  // EuRoC's ground truth carries the IMU biases; at the end of each cut the estimate is
  // within what 20-40 s of a VIO-aided ADIS16448 resolves (gyro bias 2e-3 rad/s, accel
  // 0.1 m/s²).
  for (const auto& [start_s, outcome] : *outcomes_) {
    SCOPED_TRACE(fmt::format("cut at {} s", start_s));
    const estimator::EstimatorOutput& last = outcome.result.outputs.back();
    ASSERT_EQ(log_->ground_truth_biases.size(), log_->ground_truth.size());
    const replay::GroundTruthBias* truth = nullptr;
    for (std::size_t i = 0; i < log_->ground_truth.size(); ++i) {
      if (log_->ground_truth[i].t_ns >= last.t_ns) {
        truth = &log_->ground_truth_biases[i];
        break;
      }
    }
    ASSERT_NE(truth, nullptr);
    EXPECT_LT((last.bias.gyro_radps - truth->b_g_radps).norm(), 2e-3);
    EXPECT_LT((last.bias.accel_mps2 - truth->b_a_mps2).norm(), 0.1);
  }
}

// A 5 s hole in the IMU (a driver that stalls): nothing can be propagated across it, so the
// graph restarts after it, from the pose stream, in the same local frame. Outside the hole
// the estimate stays within twice the error of the same cut without it.
TEST_F(EurocCutsTest, AFiveSecondImuGapRestartsTheGraphAndKeepsTheErrorOutsideIt) {
  const RecordedLog cut = Cut(*log_, 10, 30);
  RecordedLog gapped = cut;
  gapped.measurements.clear();
  gapped.arrival_ns.clear();
  const Time gap_from = cut.measurements.front().t_ns + 12 * kSecond;
  const Time gap_to = gap_from + 5 * kSecond;
  for (std::size_t i = 0; i < cut.measurements.size(); ++i) {
    const core::StampedMeasurement& m = cut.measurements[i];
    if (m.sensor == cut.imu_stream && m.t_ns >= gap_from && m.t_ns < gap_to) continue;
    gapped.measurements.push_back(m);
    gapped.arrival_ns.push_back(cut.arrival_ns[i]);
  }
  const ReplayResult r = ReplaySingle(gapped);
  EXPECT_EQ(r.counters.imu_gaps, 1);
  EXPECT_NEAR(r.counters.imu_gap_total_s, 5.0, 0.05);
  EXPECT_EQ(r.counters.restarts_after_gap, 1);
  ASSERT_EQ(r.initialisations.size(), 2u);
  EXPECT_TRUE(r.initialisations.back().after_imu_gap);
  // Back within 2 s of flight data after the hole.
  EXPECT_LE(r.initialisations.back().t_ns - gap_to, 2 * kSecond);
  for (const estimator::EstimatorOutput& o : r.outputs) {
    EXPECT_FALSE(o.t_ns > gap_from + kSecond / 10 && o.t_ns < gap_to) << "an output inside the hole";
  }
  const replay::InputCheck with_gap = Check(gapped, r);
  const replay::InputCheck without = outcomes_->at(10).check;
  fmt::print("IMU gap: fused {:.1f} cm {:.2f} deg, without the gap {:.1f} cm {:.2f} deg\n",
             100 * with_gap.ate_m, with_gap.rotation_deg, 100 * without.ate_m, without.rotation_deg);
  EXPECT_LE(with_gap.ate_m, 2.0 * without.ate_m);
  EXPECT_LE(with_gap.rotation_deg, 2.0 * without.rotation_deg);
}

}  // namespace
}  // namespace tofu
