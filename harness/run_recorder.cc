#include "harness/run_recorder.h"

#include <cerrno>
#include <charconv>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <iterator>
#include <string_view>
#include <variant>

#include "core/error.h"
#include "core/lie.h"
#include "core/units.h"
#include "harness/run.h"
#include "replay/file_io.h"
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

// Upper triangle of a symmetric matrix, row by row: "c00,c01,...".
template <int N>
void AppendUpperTriangle(replay::AtomicFileWriter& out, const Eigen::Matrix<double, N, N>& c) {
  for (int r = 0; r < N; ++r) {
    for (int k = r; k < N; ++k) out.Format(",{:.6e}", c(r, k));
  }
}

template <int N>
std::string UpperTriangleHeader(const std::string& prefix, const std::string& unit) {
  std::string header;
  for (int r = 0; r < N; ++r) {
    for (int k = r; k < N; ++k) header += fmt::format(",{}{}{} [{}]", prefix, r, k, unit);
  }
  return header;
}

// sensors/<name>.csv: EuRoC/ASL-style headers with units; the IMU's first seven columns
// are EuRoC's imu0/data.csv.
std::string SensorCsvHeader(const std::string& type) {
  if (type == "imu") {
    return "#timestamp [ns],w_RS_S_x [rad s^-1],w_RS_S_y [rad s^-1],w_RS_S_z [rad s^-1],"
           "a_RS_S_x [m s^-2],a_RS_S_y [m s^-2],a_RS_S_z [m s^-2],arrival [ns],"
           "err_w_x [rad s^-1],err_w_y [rad s^-1],err_w_z [rad s^-1],"
           "err_a_x [m s^-2],err_a_y [m s^-2],err_a_z [m s^-2],conditions,faults\n";
  }
  if (type == "vio" || type == "lidar_odometry") {
    return fmt::format(
        "#timestamp [ns],arrival [ns],p_Ss_x [m],p_Ss_y [m],p_Ss_z [m],q_Ss_w [],"
        "q_Ss_x [],q_Ss_y [],q_Ss_z [],v_s_x [m s^-1],v_s_y [m s^-1],v_s_z [m s^-1],"
        "omega_s_x [rad s^-1],omega_s_y [rad s^-1],omega_s_z [rad s^-1]{}{},"
        "err_p_x [m],err_p_y [m],err_p_z [m],err_theta_x [rad],err_theta_y [rad],"
        "err_theta_z [rad],conditions,faults\n",
        UpperTriangleHeader<6>("cov_pose_", "rad|m"),
        UpperTriangleHeader<6>("cov_twist_", "m/s|rad/s"));
  }
  return fmt::format(
      "#timestamp [ns],arrival [ns],p_Ss_x [m],p_Ss_y [m],p_Ss_z [m]{},"
      "err_p_x [m],err_p_y [m],err_p_z [m],conditions,faults\n",
      UpperTriangleHeader<3>("cov_p_", "m^2"));
}

void AppendSensorRow(replay::AtomicFileWriter& out, const std::string& type, const sim::SensorSample& s,
                     uint32_t faults) {
  if (type == "imu") {
    const auto& m = std::get<core::ImuMeasurement>(s.measured);
    const auto& t = std::get<core::ImuMeasurement>(s.truth);
    const Eigen::Vector3d ew = m.gyro_I_radps - t.gyro_I_radps;
    const Eigen::Vector3d ea = m.acc_I_mps2 - t.acc_I_mps2;
    out.Format("{},{:.9f},{:.9f},{:.9f},{:.7f},{:.7f},{:.7f},{},{:.9f},{:.9f},{:.9f},{:.7f},"
                   "{:.7f},{:.7f},{},{}\n",
                   s.t_ns, m.gyro_I_radps.x(), m.gyro_I_radps.y(), m.gyro_I_radps.z(),
                   m.acc_I_mps2.x(), m.acc_I_mps2.y(), m.acc_I_mps2.z(), s.arrival_ns, ew.x(),
                   ew.y(), ew.z(), ea.x(), ea.y(), ea.z(), ConditionText(s.conditions),
                   FaultText(faults));
    return;
  }
  if (type == "vio" || type == "lidar_odometry") {
    const auto& m = std::get<core::PoseMeasurement>(s.measured);
    const auto& t = std::get<core::PoseMeasurement>(s.truth);
    const Eigen::Quaterniond q = core::CanonicalQuat(m.q_Ss);
    // True error as the covariance defines it: R_meas = R_true Exp(err_theta).
    const Eigen::Vector3d err_p = m.p_Ss - t.p_Ss;
    const Eigen::Vector3d err_theta = core::LogQuat(t.q_Ss.conjugate() * m.q_Ss);
    out.Format("{},{},{:.6f},{:.6f},{:.6f},{:.9f},{:.9f},{:.9f},{:.9f}",
                   s.t_ns, s.arrival_ns, m.p_Ss.x(), m.p_Ss.y(), m.p_Ss.z(), q.w(), q.x(), q.y(),
                   q.z());
    if (m.has_twist) {
      out.Format(",{:.6f},{:.6f},{:.6f},{:.6f},{:.6f},{:.6f}",
                     m.v_s_s_mps.x(), m.v_s_s_mps.y(), m.v_s_s_mps.z(), m.omega_s_s_radps.x(),
                     m.omega_s_s_radps.y(), m.omega_s_s_radps.z());
    } else {
      out.Format(",,,,,,");
    }
    AppendUpperTriangle<6>(out, m.covariance);
    if (m.has_twist) {
      AppendUpperTriangle<6>(out, m.twist_covariance);
    } else {
      out.Append(std::string(21, ','));
    }
    out.Format(",{:.6f},{:.6f},{:.6f},{:.7f},{:.7f},{:.7f},{},{}\n",
                   err_p.x(), err_p.y(), err_p.z(), err_theta.x(), err_theta.y(), err_theta.z(),
                   ConditionText(s.conditions), FaultText(faults));
    return;
  }
  const auto& m = std::get<core::PositionMeasurement>(s.measured);
  const auto& t = std::get<core::PositionMeasurement>(s.truth);
  const Eigen::Vector3d err = m.p_Ss - t.p_Ss;
  out.Format("{},{},{:.6f},{:.6f},{:.6f}", s.t_ns, s.arrival_ns,
                 m.p_Ss.x(), m.p_Ss.y(), m.p_Ss.z());
  AppendUpperTriangle<3>(out, m.covariance);
  out.Format(",{:.6f},{:.6f},{:.6f},{},{}\n", err.x(), err.y(),
                 err.z(), ConditionText(s.conditions), FaultText(faults));
}

// A value as a sensor CSV holds it: formatted as the writer formats it and parsed back
// as the reader (recorded_log.cc) parses it, so that an in-loop consumer sees exactly
// what `tofu estimate` reads from the file.
double AsWritten(double value, std::string_view format) {
  const std::string text = fmt::format(fmt::runtime(format), value);
  double parsed = 0.0;
  const char* first = text.data();
  const char* last = first + text.size();
  const auto [end, ec] = std::from_chars(first, last, parsed);
  if (ec == std::errc::result_out_of_range) return std::strtod(text.c_str(), nullptr);
  return parsed;
}

Eigen::Vector3d AsWritten(const Eigen::Vector3d& v, std::string_view format) {
  return {AsWritten(v.x(), format), AsWritten(v.y(), format), AsWritten(v.z(), format)};
}

// A symmetric matrix from its upper triangle as written (",{:.6e}" each).
template <int N>
Eigen::Matrix<double, N, N> UpperTriangleAsWritten(const Eigen::Matrix<double, N, N>& c) {
  Eigen::Matrix<double, N, N> out;
  for (int r = 0; r < N; ++r) {
    for (int k = r; k < N; ++k) out(r, k) = out(k, r) = AsWritten(c(r, k), "{:.6e}");
  }
  return out;
}

}  // namespace

RecorderLayout RecorderLayoutOf(const RunRecord& record, bool closed_loop) {
  RecorderLayout layout;
  for (const SensorStream& s : record.sensors) layout.streams.push_back({s.name, s.type, s.site});
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
    const std::string header = SensorCsvHeader(stream.type);
    delivered_.back()->Append(header);
    clean_.back()->Append(header);
    // The EuRoC folder layout of the first IMU, so existing VIO tools read a run.
    if (stream.type != "imu" || euroc_imu_) continue;
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
  AppendSensorRow(*clean_[stream], layout_.streams[stream].type, sample, 0u);
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
  AppendSensorRow(*delivered_[stream], layout_.streams[stream].type, sample, faults);
  if (!euroc_imu_ || stream != *euroc_imu_) return;
  const auto& m = std::get<core::ImuMeasurement>(sample.measured);
  euroc_imu_csv_->Format("{},{:.9f},{:.9f},{:.9f},{:.7f},{:.7f},{:.7f}\n", sample.t_ns,
                 m.gyro_I_radps.x(), m.gyro_I_radps.y(), m.gyro_I_radps.z(), m.acc_I_mps2.x(),
                 m.acc_I_mps2.y(), m.acc_I_mps2.z());
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

core::Measurement RecordedMeasurement(const std::string& stream_type,
                                      const core::Measurement& value) {
  if (stream_type == "imu") {
    const auto& m = std::get<core::ImuMeasurement>(value);
    core::ImuMeasurement out;
    out.gyro_I_radps = AsWritten(m.gyro_I_radps, "{:.9f}");
    out.acc_I_mps2 = AsWritten(m.acc_I_mps2, "{:.7f}");
    return out;
  }
  if (stream_type == "vio" || stream_type == "lidar_odometry") {
    const auto& m = std::get<core::PoseMeasurement>(value);
    core::PoseMeasurement out;
    out.p_Ss = AsWritten(m.p_Ss, "{:.6f}");
    const Eigen::Quaterniond q = core::CanonicalQuat(m.q_Ss);
    // The reader normalises what it parsed (when finite and non-zero).
    Eigen::Quaterniond q_read(AsWritten(q.w(), "{:.9f}"), AsWritten(q.x(), "{:.9f}"),
                              AsWritten(q.y(), "{:.9f}"), AsWritten(q.z(), "{:.9f}"));
    const double norm = q_read.norm();
    if (std::isfinite(norm) && norm > 0.0) q_read.coeffs() /= norm;
    out.q_Ss = q_read;
    out.covariance = UpperTriangleAsWritten<6>(m.covariance);
    if (m.has_twist) {
      out.has_twist = true;
      out.v_s_s_mps = AsWritten(m.v_s_s_mps, "{:.6f}");
      out.omega_s_s_radps = AsWritten(m.omega_s_s_radps, "{:.6f}");
      out.twist_covariance = UpperTriangleAsWritten<6>(m.twist_covariance);
    }
    return out;
  }
  const auto& m = std::get<core::PositionMeasurement>(value);
  core::PositionMeasurement out;
  out.p_Ss = AsWritten(m.p_Ss, "{:.6f}");
  out.covariance = UpperTriangleAsWritten<3>(m.covariance);
  return out;
}

}  // namespace tofu::harness
