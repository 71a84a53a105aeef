#include "harness/run_recorder.h"

#include <array>
#include <iterator>
#include <variant>

#include "core/error.h"
#include "core/lie.h"
#include "core/units.h"
#include "harness/run.h"
#include "replay/file_io.h"
#include "replay/run_format.h"
#include "sim/faults.h"

namespace tofu::harness {

namespace fs = std::filesystem;

namespace {

const ImuBias kZeroBias{Eigen::Vector3d::Zero(), Eigen::Vector3d::Zero()};

// "1.234567890" from integer nanoseconds: exact, no float rounding in time stamps.
std::string SecondsText(core::Time t_ns) {
  const char* sign = t_ns < 0 ? "-" : "";
  const core::Time a = t_ns < 0 ? -t_ns : t_ns;
  return fmt::format("{}{}.{:09d}", sign, a / core::kNanosecondsPerSecond,
                     a % core::kNanosecondsPerSecond);
}

std::string ConditionText(uint32_t mask) {
  std::string text;
  for (const sim::Condition bit : sim::AllConditions()) {
    if ((mask & bit) == 0) continue;
    if (!text.empty()) text += '|';
    text += sim::ConditionName(bit);
  }
  return text;
}

std::string FaultText(uint32_t mask) {
  std::string text;
  for (const sim::FaultKind kind : sim::AllFaultKinds()) {
    if ((mask & sim::FaultBit(kind)) == 0) continue;
    if (!text.empty()) text += '|';
    text += sim::FaultKindName(kind);
  }
  return text;
}

// A sample's row of sensors/<name>.csv (replay/run_format.h), with the fault bits active
// at its time (0 for the clean stream); `row` is the caller's buffer, reused row to row.
void AppendSensorRow(replay::AtomicFileWriter& out, const sim::SensorSample& s, uint32_t faults,
                     std::string& row) {
  const std::string conditions = ConditionText(s.conditions);
  const std::string fault_names = FaultText(faults);
  row.clear();
  replay::AppendSensorCsvRow({s.t_ns, s.arrival_ns, &s.measured, &s.truth, conditions, fault_names},
                             row);
  out.Append(row);
}

}  // namespace

RecorderLayout RecorderLayoutOf(const RunRecord& record, bool closed_loop) {
  RecorderLayout layout;
  for (const SensorStream& s : record.sensors) layout.streams.push_back({s.name, s.kind, s.site});
  layout.robot = record.robot;
  layout.closed_loop = closed_loop;
  return layout;
}

RunRecorder::RunRecorder(const fs::path& dir, RecorderLayout layout) : layout_(std::move(layout)) {
  groundtruth_csv_ = std::make_unique<replay::AtomicFileWriter>(dir / "groundtruth.csv");
  groundtruth_csv_->Format("#timestamp [ns],p_WB_x [m],p_WB_y [m],p_WB_z [m],"
                 "q_WB_w [],q_WB_x [],q_WB_y [],q_WB_z [],"
                 "v_WB_W_x [m/s],v_WB_W_y [m/s],v_WB_W_z [m/s],"
                 "omega_WB_B_x [rad/s],omega_WB_B_y [rad/s],omega_WB_B_z [rad/s],"
                 "a_WB_W_x [m/s^2],a_WB_W_y [m/s^2],a_WB_W_z [m/s^2]\n");
  // TUM trajectory format (what evo reads): "t x y z qx qy qz qw", t in seconds.
  groundtruth_tum_ = std::make_unique<replay::AtomicFileWriter>(dir / "groundtruth.tum");
  tracking_csv_ = std::make_unique<replay::AtomicFileWriter>(dir / "tracking.csv");
  tracking_csv_->Format("#timestamp [ns],p_ref_x [m],p_ref_y [m],p_ref_z [m],"
                 "q_ref_w [],q_ref_x [],q_ref_y [],q_ref_z [],"
                 "v_ref_x [m/s],v_ref_y [m/s],v_ref_z [m/s],"
                 "position_error [m],attitude_error [deg]\n");
  if (layout_.closed_loop) {
    // control.csv of a closed-loop flight: at the ground-truth rate, what the controller
    // flew on (mode, its estimate of B in W) beside the truth and the mission reference.
    control_csv_ = std::make_unique<replay::AtomicFileWriter>(dir / "control.csv");
    control_csv_->Format("#timestamp [ns],mode,p_ref_x [m],p_ref_y [m],p_ref_z [m],p_true_x [m],"
                   "p_true_y [m],p_true_z [m],p_est_x [m],p_est_y [m],p_est_z [m],"
                   "tracking_error [m],estimate_error [m],structure_distance [m]\n");
  }
  for (std::size_t i = 0; i < layout_.streams.size(); ++i) {
    const RecorderLayout::Stream& stream = layout_.streams[i];
    delivered_.push_back(std::make_unique<replay::AtomicFileWriter>(dir / "sensors" / (stream.name + ".csv")));
    clean_.push_back(std::make_unique<replay::AtomicFileWriter>(dir / "sensors" / "clean" / (stream.name + ".csv")));
    const std::string header = replay::SensorCsvHeader(stream.kind);
    delivered_.back()->Append(header);
    clean_.back()->Append(header);
    // The EuRoC folder layout of the first IMU, so existing VIO tools read a run.
    if (stream.kind != core::MeasurementKind::kImu || euroc_imu_) continue;
    euroc_imu_ = i;
    if (const sim::MountSite* site = layout_.robot.FindSite(stream.site)) {
      p_BI_ = site->p_Bs;
      q_BI_ = site->q_Bs;
    }
    euroc_imu_csv_ = std::make_unique<replay::AtomicFileWriter>(dir / "mav0" / "imu0" / "data.csv");
    euroc_imu_csv_->Format("#timestamp [ns],w_RS_S_x [rad s-1],w_RS_S_y [rad s-1],w_RS_S_z [rad s-1],"
                   "a_RS_S_x [m s-2],a_RS_S_y [m s-2],a_RS_S_z [m s-2]\n");
    // EuRoC's state_groundtruth_estimate0: the IMU frame S (= our I) in R (= W), with the
    // true biases of the IMU (from its nearest earlier sample), so that VIO tools read a run.
    euroc_groundtruth_csv_ =
        std::make_unique<replay::AtomicFileWriter>(dir / "mav0" / "state_groundtruth_estimate0" / "data.csv");
    euroc_groundtruth_csv_->Format("#timestamp, p_RS_R_x [m], p_RS_R_y [m], p_RS_R_z [m], q_RS_w [], q_RS_x [], "
                   "q_RS_y [], q_RS_z [], v_RS_R_x [m s^-1], v_RS_R_y [m s^-1], v_RS_R_z [m s^-1], "
                   "b_w_RS_S_x [rad s^-1], b_w_RS_S_y [rad s^-1], b_w_RS_S_z [rad s^-1], "
                   "b_a_RS_S_x [m s^-2], b_a_RS_S_y [m s^-2], b_a_RS_S_z [m s^-2]\n");
  }
}

RunRecorder::~RunRecorder() = default;

void RunRecorder::AddGroundTruth(const sim::TruthState& s, const sim::Reference& reference,
                                 const TrackingSample& tracking, const ClosedLoopSample* control) {
  Eigen::Quaterniond q = s.q_WB;
  if (q.w() < 0.0) q.coeffs() *= -1.0;
  groundtruth_csv_->Format("{},{:.6f},{:.6f},{:.6f},{:.9f},{:.9f},{:.9f},{:.9f},{:.6f},{:.6f},{:.6f},"
                 "{:.6f},{:.6f},{:.6f},{:.5f},{:.5f},{:.5f}\n",
                 s.t_ns, s.p_WB.x(), s.p_WB.y(), s.p_WB.z(), q.w(), q.x(), q.y(), q.z(),
                 s.v_WB_W.x(), s.v_WB_W.y(), s.v_WB_W.z(), s.omega_WB_B.x(), s.omega_WB_B.y(),
                 s.omega_WB_B.z(), s.a_WB_W.x(), s.a_WB_W.y(), s.a_WB_W.z());
  groundtruth_tum_->Format("{} {:.6f} {:.6f} {:.6f} {:.9f} {:.9f} {:.9f} {:.9f}\n", SecondsText(s.t_ns),
                 s.p_WB.x(), s.p_WB.y(), s.p_WB.z(), q.x(), q.y(), q.z(), q.w());

  Eigen::Quaterniond q_ref = reference.q_WB;
  if (q_ref.w() < 0.0) q_ref.coeffs() *= -1.0;
  const auto& r = reference;
  tracking_csv_->Format("{},{:.6f},{:.6f},{:.6f},{:.9f},{:.9f},{:.9f},{:.9f},{:.6f},{:.6f},{:.6f},"
                 "{:.7f},{:.5f}\n",
                 tracking.t_ns, r.p_WB.x(), r.p_WB.y(), r.p_WB.z(), q_ref.w(), q_ref.x(),
                 q_ref.y(), q_ref.z(), r.v_WB_W.x(), r.v_WB_W.y(), r.v_WB_W.z(),
                 tracking.position_error_m, core::DegFromRad(tracking.attitude_error_rad));

  if (control_csv_ && control != nullptr) {
    replay::AtomicFileWriter& out = *control_csv_;
    out.Format("{},{},{:.6f},{:.6f},{:.6f},{:.6f},{:.6f},{:.6f}",
                   control->t_ns, FlightModeName(control->mode), r.p_WB.x(), r.p_WB.y(),
                   r.p_WB.z(), s.p_WB.x(), s.p_WB.y(), s.p_WB.z());
    if (control->p_WB_est) {
      out.Format(",{:.6f},{:.6f},{:.6f}", control->p_WB_est->x(),
                     control->p_WB_est->y(), control->p_WB_est->z());
    } else {
      out.Format(",,,");
    }
    out.Format(",{:.6f},", tracking.position_error_m);
    if (control->p_WB_est) {
      out.Format("{:.6f}", (*control->p_WB_est - s.p_WB).norm());
    }
    out.Format(",");
    if (control->structure_distance_m) {
      out.Format("{:.6f}", *control->structure_distance_m);
    }
    out.Format("\n");
  }

  if (euroc_imu_) pending_truth_.push_back(s);
}

void RunRecorder::EmitEurocGroundTruth(const sim::TruthState& s, const ImuBias& bias) {
  const Eigen::Matrix3d R_WB = s.q_WB.toRotationMatrix();
  const Eigen::Vector3d p_WI = s.p_WB + R_WB * p_BI_;
  const Eigen::Vector3d v_WI = s.v_WB_W + R_WB * s.omega_WB_B.cross(p_BI_);
  const Eigen::Quaterniond q_WI = core::CanonicalQuat(s.q_WB * q_BI_);
  const Eigen::Vector3d& bw = bias.first;
  const Eigen::Vector3d& ba = bias.second;
  euroc_groundtruth_csv_->Format("{},{:.6f},{:.6f},{:.6f},{:.9f},{:.9f},{:.9f},{:.9f},{:.6f},{:.6f},{:.6f},"
                 "{:.9f},{:.9f},{:.9f},{:.7f},{:.7f},{:.7f}\n",
                 s.t_ns, p_WI.x(), p_WI.y(), p_WI.z(), q_WI.w(), q_WI.x(), q_WI.y(), q_WI.z(),
                 v_WI.x(), v_WI.y(), v_WI.z(), bw.x(), bw.y(), bw.z(), ba.x(), ba.y(), ba.z());
}

void RunRecorder::AddClean(std::size_t stream, const sim::SensorSample& sample,
                           const ImuBias* imu_bias) {
  AppendSensorRow(*clean_[stream], sample, 0u, row_);
  if (!euroc_imu_ || stream != *euroc_imu_) return;
  const ImuBias& bias = imu_bias != nullptr ? *imu_bias : kZeroBias;
  // The rows before this sample carry the latest bias at or before them: this one's for
  // rows before the first sample (the nearest sample there is).
  std::size_t emitted = 0;
  while (emitted < pending_truth_.size() && pending_truth_[emitted].t_ns < sample.t_ns) {
    EmitEurocGroundTruth(pending_truth_[emitted], latest_bias_.value_or(bias));
    ++emitted;
  }
  pending_truth_.erase(pending_truth_.begin(),
                       pending_truth_.begin() + static_cast<std::ptrdiff_t>(emitted));
  latest_bias_ = bias;
}

void RunRecorder::AddDelivered(std::size_t stream, const sim::SensorSample& sample,
                               uint32_t faults) {
  AppendSensorRow(*delivered_[stream], sample, faults, row_);
  if (!euroc_imu_ || stream != *euroc_imu_) return;
  // EuRoC's imu0/data.csv: the first columns of the IMU's own rows, at their precisions.
  static constexpr std::array kEurocImuFields = {
      replay::SensorField::kTimestamp, replay::SensorField::kGyro, replay::SensorField::kAccel};
  row_.clear();
  replay::AppendSensorCsvFields({sample.t_ns, sample.arrival_ns, &sample.measured, nullptr, "", ""},
                                kEurocImuFields, row_);
  euroc_imu_csv_->Append(row_);
}

void RunRecorder::Close() {
  for (const sim::TruthState& s : pending_truth_) {
    EmitEurocGroundTruth(s, latest_bias_.value_or(kZeroBias));
  }
  pending_truth_.clear();
  for (replay::AtomicFileWriter* file : {groundtruth_csv_.get(), groundtruth_tum_.get(), tracking_csv_.get(),
                     control_csv_.get(), euroc_imu_csv_.get(), euroc_groundtruth_csv_.get()}) {
    if (file != nullptr) file->Commit();
  }
  for (auto& file : delivered_) file->Commit();
  for (auto& file : clean_) file->Commit();
}

}  // namespace tofu::harness
