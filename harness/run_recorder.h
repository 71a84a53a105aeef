#pragma once
// The recorder: the run directory's consumer of the run loop (docs/DESIGN.md, "Data flow
// of one run"). It writes every per-sample file of a run directory: sensors/<name>.csv
// and sensors/clean/<name>.csv in the format their readers share (replay/run_format.h),
// and the files of its own format (groundtruth.csv/.tum, tracking.csv, the EuRoC layout
// under mav0/, control.csv). It writes each row when the run produces it, so that a
// flight's memory does not grow with the samples it records (issue 19).
// A run recorded in memory (a test's, a corpus episode's) is written through the same
// recorder after the flight (run_directory.cc), so both give the same bytes.

#include <cstdint>
#include <cstdio>
#include <filesystem>
#include <memory>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include <Eigen/Core>
#include <fmt/format.h>

#include "core/measurement.h"
#include "core/time.h"
#include "replay/file_io.h"
#include "replay/run_format.h"
#include "sim/sensor.h"
#include "sim/trajectory.h"
#include "sim/world.h"

namespace tofu::harness {

struct ClosedLoopSample;  // run.h
struct RunRecord;         // run.h
struct TrackingSample;    // run.h

/// What the recorder must know of a run before its first sample.
struct RecorderLayout {
  struct Stream {
    std::string name;
    core::MeasurementKind kind = core::MeasurementKind::kImu;  ///< the columns of its CSV
    std::string site;  ///< mount site
  };
  std::vector<Stream> streams;  ///< in the order of the run's sensor list
  sim::RobotDescription robot;  ///< mounts (the EuRoC ground truth is of the IMU frame)
  bool closed_loop = false;     ///< a flight on an estimate: control.csv
};

/// The layout of a run's record: its streams and robot; `closed_loop` for a flight on an
/// estimate.
RecorderLayout RecorderLayoutOf(const RunRecord& record, bool closed_loop);

/// The true biases (gyro [rad/s], accel [m/s²]) of an IMU's clean sample.
using ImuBias = std::pair<Eigen::Vector3d, Eigen::Vector3d>;

class RunRecorder {
 public:
  /// Opens every per-sample file of `layout` in `dir` (created if missing) and writes its
  /// header. Each file is written through replay::AtomicFileWriter: it appears under its
  /// name when Close() completes it. Throws core::IoError naming the file when one cannot
  /// be created.
  RunRecorder(const std::filesystem::path& dir, RecorderLayout layout);
  ~RunRecorder();
  RunRecorder(const RunRecorder&) = delete;
  RunRecorder& operator=(const RunRecorder&) = delete;

  /// A ground-truth output instant: groundtruth.csv/.tum and tracking.csv rows, the
  /// control.csv row of a closed-loop flight (`control`), and the EuRoC ground truth once
  /// the IMU's bias at that instant is known.
  void AddGroundTruth(const sim::TruthState& truth, const sim::Reference& reference,
                      const TrackingSample& tracking, const ClosedLoopSample* control);
  /// A sample as the model produced it (sensors/clean/<name>.csv); `imu_bias` for an IMU.
  void AddClean(std::size_t stream, const sim::SensorSample& sample,
                const ImuBias* imu_bias = nullptr);
  /// A sample as delivered after the scheduled faults (sensors/<name>.csv, and for the
  /// first IMU mav0/imu0/data.csv), with the fault bits active at its time.
  void AddDelivered(std::size_t stream, const sim::SensorSample& sample, uint32_t faults);
  /// Writes what is pending and completes every file. Throws core::IoError naming the
  /// file when a write failed (a full disk). Not called (an exception unwinding the
  /// run), the files' temporaries are removed.
  void Close();

 private:
  void EmitEurocGroundTruth(const sim::TruthState& truth, const ImuBias& bias);

  RecorderLayout layout_;
  std::unique_ptr<replay::AtomicFileWriter> groundtruth_csv_;
  std::unique_ptr<replay::AtomicFileWriter> groundtruth_tum_;
  std::unique_ptr<replay::AtomicFileWriter> tracking_csv_;
  std::unique_ptr<replay::AtomicFileWriter> control_csv_;
  std::vector<std::unique_ptr<replay::AtomicFileWriter>> delivered_;
  std::vector<std::unique_ptr<replay::AtomicFileWriter>> clean_;
  // The first IMU stream's EuRoC files; rows of ground truth wait in pending_truth_ until
  // an IMU sample after them fixes the bias they carry (the latest at or before them).
  std::optional<std::size_t> euroc_imu_;
  std::unique_ptr<replay::AtomicFileWriter> euroc_imu_csv_;
  std::unique_ptr<replay::AtomicFileWriter> euroc_groundtruth_csv_;
  std::vector<sim::TruthState> pending_truth_;
  std::string row_;  // a sensor row's text, its buffer kept from row to row
  std::optional<ImuBias> latest_bias_;
  Eigen::Vector3d p_BI_ = Eigen::Vector3d::Zero();
  Eigen::Quaterniond q_BI_ = Eigen::Quaterniond::Identity();
};

}  // namespace tofu::harness
