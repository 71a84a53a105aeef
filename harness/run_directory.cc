#include "harness/run_directory.h"

#include <fcntl.h>
#include <spawn.h>
#include <sys/wait.h>
#include <unistd.h>

#include <cerrno>
#include <charconv>
#include <cmath>
#include <csignal>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <stdexcept>
#include <string_view>

#include <fmt/format.h>
#include <yaml-cpp/yaml.h>

#include "core/error.h"
#include "core/lie.h"
#include "harness/estimation.h"
#include "harness/sensor_config.h"
#include "replay/file_io.h"
#include "replay/interrupt.h"
#include "replay/replay.h"
#include "sim/faults.h"
#include "sim/sensor.h"

namespace tofu::harness {

using replay::EstimationConfig;
using replay::LabelEvent;
using replay::MethodFileStem;
using replay::StagingPath;
using replay::ThrowIfInterrupted;
using replay::WaitForInterrupt;
using replay::WriteFileAtomically;

namespace {

namespace fs = std::filesystem;


// "1.234567890" from integer nanoseconds: exact, no float rounding in time stamps.
std::string SecondsText(core::Time t_ns) {
  const char* sign = t_ns < 0 ? "-" : "";
  const core::Time a = t_ns < 0 ? -t_ns : t_ns;
  return fmt::format("{}{}.{:09d}", sign, a / core::kNanosecondsPerSecond,
                     a % core::kNanosecondsPerSecond);
}

std::string GroundTruthCsv(const RunRecord& record) {
  fmt::memory_buffer out;
  fmt::format_to(std::back_inserter(out),
                 "#timestamp [ns],p_WB_x [m],p_WB_y [m],p_WB_z [m],"
                 "q_WB_w [],q_WB_x [],q_WB_y [],q_WB_z [],"
                 "v_WB_W_x [m/s],v_WB_W_y [m/s],v_WB_W_z [m/s],"
                 "omega_WB_B_x [rad/s],omega_WB_B_y [rad/s],omega_WB_B_z [rad/s],"
                 "a_WB_W_x [m/s^2],a_WB_W_y [m/s^2],a_WB_W_z [m/s^2]\n");
  for (const sim::TruthState& s : record.groundtruth) {
    Eigen::Quaterniond q = s.q_WB;
    if (q.w() < 0.0) q.coeffs() *= -1.0;
    fmt::format_to(std::back_inserter(out),
                   "{},{:.6f},{:.6f},{:.6f},{:.9f},{:.9f},{:.9f},{:.9f},{:.6f},{:.6f},{:.6f},"
                   "{:.6f},{:.6f},{:.6f},{:.5f},{:.5f},{:.5f}\n",
                   s.t_ns, s.p_WB.x(), s.p_WB.y(), s.p_WB.z(), q.w(), q.x(), q.y(), q.z(),
                   s.v_WB_W.x(), s.v_WB_W.y(), s.v_WB_W.z(), s.omega_WB_B.x(),
                   s.omega_WB_B.y(), s.omega_WB_B.z(), s.a_WB_W.x(), s.a_WB_W.y(),
                   s.a_WB_W.z());
  }
  return fmt::to_string(out);
}

// TUM trajectory format (what evo reads): "t x y z qx qy qz qw", t in seconds.
std::string GroundTruthTum(const RunRecord& record) {
  fmt::memory_buffer out;
  for (const sim::TruthState& s : record.groundtruth) {
    Eigen::Quaterniond q = s.q_WB;
    if (q.w() < 0.0) q.coeffs() *= -1.0;
    fmt::format_to(std::back_inserter(out), "{} {:.6f} {:.6f} {:.6f} {:.9f} {:.9f} {:.9f} {:.9f}\n",
                   SecondsText(s.t_ns), s.p_WB.x(), s.p_WB.y(), s.p_WB.z(), q.x(), q.y(), q.z(),
                   q.w());
  }
  return fmt::to_string(out);
}

std::string TrackingCsv(const RunRecord& record) {
  fmt::memory_buffer out;
  fmt::format_to(std::back_inserter(out),
                 "#timestamp [ns],p_ref_x [m],p_ref_y [m],p_ref_z [m],"
                 "q_ref_w [],q_ref_x [],q_ref_y [],q_ref_z [],"
                 "v_ref_x [m/s],v_ref_y [m/s],v_ref_z [m/s],"
                 "position_error [m],attitude_error [deg]\n");
  for (const TrackingSample& s : record.tracking) {
    Eigen::Quaterniond q = s.reference.q_WB;
    if (q.w() < 0.0) q.coeffs() *= -1.0;
    const auto& r = s.reference;
    fmt::format_to(std::back_inserter(out),
                   "{},{:.6f},{:.6f},{:.6f},{:.9f},{:.9f},{:.9f},{:.9f},{:.6f},{:.6f},{:.6f},"
                   "{:.7f},{:.5f}\n",
                   s.t_ns, r.p_WB.x(), r.p_WB.y(), r.p_WB.z(), q.w(), q.x(), q.y(), q.z(),
                   r.v_WB_W.x(), r.v_WB_W.y(), r.v_WB_W.z(), s.position_error_m,
                   s.attitude_error_rad * 180.0 / 3.14159265358979323846);
  }
  return fmt::to_string(out);
}

void EmitPose(YAML::Emitter& out, const std::string& key, const Eigen::Vector3d& p,
              const Eigen::Quaterniond& q_in) {
  const Eigen::Quaterniond q = core::CanonicalQuat(q_in.normalized());
  out << YAML::Key << key << YAML::Value << YAML::BeginMap;
  out << YAML::Key << "p_m" << YAML::Value << YAML::Flow << YAML::BeginSeq;
  for (int k = 0; k < 3; ++k) out << fmt::format("{:.6f}", p(k));
  out << YAML::EndSeq;
  out << YAML::Key << "q_wxyz" << YAML::Value << YAML::Flow << YAML::BeginSeq
      << fmt::format("{:.9f}", q.w()) << fmt::format("{:.9f}", q.x())
      << fmt::format("{:.9f}", q.y()) << fmt::format("{:.9f}", q.z()) << YAML::EndSeq;
  out << YAML::EndMap;
}

// What an estimator is given about the robot (mass properties, nominal mount extrinsics,
// each sensor's nominal noise parameters), and, marked true_*, what it is not given but
// scoring needs: the true extrinsics where a calibration error was configured and the
// true pose of each sensor's reference frame in W.
std::string CalibrationYaml(const RunRecord& record) {
  const sim::RobotDescription& robot = record.robot;
  YAML::Emitter out;
  out << YAML::Comment("tofu calibration. T_B_s: pose of mount frame s in body frame B; "
                       "T_WS: sensor reference frame S in W; quaternions [w, x, y, z].");
  out << YAML::BeginMap;
  out << YAML::Key << "robot" << YAML::Value << record.scenario.robot;
  out << YAML::Key << "mass_kg" << YAML::Value << fmt::format("{:.6f}", robot.rigid_body.mass_kg);
  out << YAML::Key << "inertia_B_kgm2" << YAML::Value << YAML::Flow << YAML::BeginSeq;
  for (int r = 0; r < 3; ++r) {
    out << YAML::Flow << YAML::BeginSeq;
    for (int c = 0; c < 3; ++c) out << fmt::format("{:.6f}", robot.rigid_body.inertia_B_kgm2(r, c));
    out << YAML::EndSeq;
  }
  out << YAML::EndSeq;
  out << YAML::Key << "p_B_CoM_m" << YAML::Value << YAML::Flow << YAML::BeginSeq;
  for (int k = 0; k < 3; ++k) out << fmt::format("{:.6f}", robot.p_B_CoM(k));
  out << YAML::EndSeq;

  out << YAML::Key << "mounts" << YAML::Value << YAML::BeginMap;
  for (const sim::MountSite& site : robot.sites) EmitPose(out, site.name, site.p_B_s, site.q_B_s);
  out << YAML::EndMap;

  out << YAML::Key << "sensors" << YAML::Value << YAML::BeginMap;
  for (size_t i = 0; i < record.sensors.size(); ++i) {
    const SensorStream& stream = record.sensors[i];
    const SensorConfig& config = record.scenario.sensors[i];
    out << YAML::Key << stream.name << YAML::Value << YAML::BeginMap;
    out << YAML::Key << "type" << YAML::Value << stream.type;
    out << YAML::Key << "site" << YAML::Value << stream.site;
    if (const sim::MountSite* site = robot.FindSite(stream.site)) {
      Eigen::Isometry3d T_B_s_true = Eigen::Isometry3d::Identity();
      T_B_s_true.linear() = site->q_B_s.toRotationMatrix();
      T_B_s_true.translation() = site->p_B_s;
      const Eigen::Isometry3d T_B_s = T_B_s_true * config.calibration_error;
      EmitPose(out, "T_B_s", T_B_s.translation(), Eigen::Quaterniond(T_B_s.linear()));
      if (config.calibration_error.matrix() != Eigen::Matrix4d::Identity()) {
        EmitPose(out, "true_T_B_s", site->p_B_s, site->q_B_s);
      }
    }
    EmitPose(out, "true_T_WS", stream.T_WS.translation(), Eigen::Quaterniond(stream.T_WS.linear()));
    out << YAML::Key << "options" << YAML::Value << YAML::BeginMap;
    internal::EmitSensorOptions(out, config.options);
    out << YAML::EndMap;
    out << YAML::EndMap;
  }
  out << YAML::EndMap;
  out << YAML::EndMap;
  return std::string(out.c_str()) + "\n";
}

// ---- sensor streams (one CSV per stream, EuRoC/ASL-style headers with units) ----

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
void AppendUpperTriangle(fmt::memory_buffer& out, const Eigen::Matrix<double, N, N>& c) {
  for (int r = 0; r < N; ++r) {
    for (int k = r; k < N; ++k) fmt::format_to(std::back_inserter(out), ",{:.6e}", c(r, k));
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

std::string SensorCsv(const SensorStream& stream, bool delivered) {
  const std::vector<sim::SensorSample>& samples = delivered ? stream.delivered : stream.clean;
  fmt::memory_buffer out;
  const auto row_faults = [&](size_t i) -> uint32_t {
    return delivered && i < stream.delivered_faults.size() ? stream.delivered_faults[i] : 0u;
  };
  if (stream.type == "imu") {
    // The first seven columns are EuRoC's imu0/data.csv.
    fmt::format_to(std::back_inserter(out),
                   "#timestamp [ns],w_RS_S_x [rad s^-1],w_RS_S_y [rad s^-1],w_RS_S_z [rad s^-1],"
                   "a_RS_S_x [m s^-2],a_RS_S_y [m s^-2],a_RS_S_z [m s^-2],arrival [ns],"
                   "err_w_x [rad s^-1],err_w_y [rad s^-1],err_w_z [rad s^-1],"
                   "err_a_x [m s^-2],err_a_y [m s^-2],err_a_z [m s^-2],conditions,faults\n");
    for (size_t i = 0; i < samples.size(); ++i) {
      const sim::SensorSample& s = samples[i];
      const auto& m = std::get<core::ImuMeasurement>(s.measured);
      const auto& t = std::get<core::ImuMeasurement>(s.truth);
      const Eigen::Vector3d ew = m.gyro_I_radps - t.gyro_I_radps;
      const Eigen::Vector3d ea = m.acc_I_mps2 - t.acc_I_mps2;
      fmt::format_to(std::back_inserter(out),
                     "{},{:.9f},{:.9f},{:.9f},{:.7f},{:.7f},{:.7f},{},{:.9f},{:.9f},{:.9f},{:.7f},"
                     "{:.7f},{:.7f},{},{}\n",
                     s.t_ns, m.gyro_I_radps.x(), m.gyro_I_radps.y(), m.gyro_I_radps.z(),
                     m.acc_I_mps2.x(), m.acc_I_mps2.y(), m.acc_I_mps2.z(), s.arrival_ns, ew.x(),
                     ew.y(), ew.z(), ea.x(), ea.y(), ea.z(), ConditionText(s.conditions),
                     FaultText(row_faults(i)));
    }
  } else if (stream.type == "vio" || stream.type == "lidar_odometry") {
    fmt::format_to(std::back_inserter(out),
                   "#timestamp [ns],arrival [ns],p_Ss_x [m],p_Ss_y [m],p_Ss_z [m],q_Ss_w [],"
                   "q_Ss_x [],q_Ss_y [],q_Ss_z [],v_s_x [m s^-1],v_s_y [m s^-1],v_s_z [m s^-1],"
                   "omega_s_x [rad s^-1],omega_s_y [rad s^-1],omega_s_z [rad s^-1]{}{},"
                   "err_p_x [m],err_p_y [m],err_p_z [m],err_theta_x [rad],err_theta_y [rad],"
                   "err_theta_z [rad],conditions,faults\n",
                   UpperTriangleHeader<6>("cov_pose_", "rad|m"),
                   UpperTriangleHeader<6>("cov_twist_", "m/s|rad/s"));
    for (size_t i = 0; i < samples.size(); ++i) {
      const sim::SensorSample& s = samples[i];
      const auto& m = std::get<core::PoseMeasurement>(s.measured);
      const auto& t = std::get<core::PoseMeasurement>(s.truth);
      const Eigen::Quaterniond q = core::CanonicalQuat(m.q_Ss);
      // True error as the covariance defines it: R_meas = R_true Exp(err_theta).
      const Eigen::Vector3d err_p = m.p_Ss - t.p_Ss;
      const Eigen::Vector3d err_theta = core::LogQuat(t.q_Ss.conjugate() * m.q_Ss);
      fmt::format_to(std::back_inserter(out),
                     "{},{},{:.6f},{:.6f},{:.6f},{:.9f},{:.9f},{:.9f},{:.9f}", s.t_ns,
                     s.arrival_ns, m.p_Ss.x(), m.p_Ss.y(), m.p_Ss.z(), q.w(), q.x(), q.y(), q.z());
      if (m.has_twist) {
        fmt::format_to(std::back_inserter(out), ",{:.6f},{:.6f},{:.6f},{:.6f},{:.6f},{:.6f}",
                       m.v_s_s_mps.x(), m.v_s_s_mps.y(), m.v_s_s_mps.z(), m.omega_s_s_radps.x(),
                       m.omega_s_s_radps.y(), m.omega_s_s_radps.z());
      } else {
        fmt::format_to(std::back_inserter(out), ",,,,,,");
      }
      AppendUpperTriangle<6>(out, m.covariance);
      if (m.has_twist) {
        AppendUpperTriangle<6>(out, m.twist_covariance);
      } else {
        fmt::format_to(std::back_inserter(out), "{}", std::string(21, ','));
      }
      fmt::format_to(std::back_inserter(out), ",{:.6f},{:.6f},{:.6f},{:.7f},{:.7f},{:.7f},{},{}\n",
                     err_p.x(), err_p.y(), err_p.z(), err_theta.x(), err_theta.y(),
                     err_theta.z(), ConditionText(s.conditions), FaultText(row_faults(i)));
    }
  } else {
    fmt::format_to(std::back_inserter(out),
                   "#timestamp [ns],arrival [ns],p_Ss_x [m],p_Ss_y [m],p_Ss_z [m]{},"
                   "err_p_x [m],err_p_y [m],err_p_z [m],conditions,faults\n",
                   UpperTriangleHeader<3>("cov_p_", "m^2"));
    for (size_t i = 0; i < samples.size(); ++i) {
      const sim::SensorSample& s = samples[i];
      const auto& m = std::get<core::PositionMeasurement>(s.measured);
      const auto& t = std::get<core::PositionMeasurement>(s.truth);
      const Eigen::Vector3d err = m.p_Ss - t.p_Ss;
      fmt::format_to(std::back_inserter(out), "{},{},{:.6f},{:.6f},{:.6f}", s.t_ns, s.arrival_ns,
                     m.p_Ss.x(), m.p_Ss.y(), m.p_Ss.z());
      AppendUpperTriangle<3>(out, m.covariance);
      fmt::format_to(std::back_inserter(out), ",{:.6f},{:.6f},{:.6f},{},{}\n", err.x(), err.y(),
                     err.z(), ConditionText(s.conditions), FaultText(row_faults(i)));
    }
  }
  return fmt::to_string(out);
}

std::string LabelsCsv(const RunRecord& record) {
  fmt::memory_buffer out;
  fmt::format_to(std::back_inserter(out), "#timestamp [ns],sensor,label,source,active\n");
  for (const LabelEvent& l : record.labels) {
    fmt::format_to(std::back_inserter(out), "{},{},{},{},{}\n", l.t_ns, l.sensor, l.label,
                   l.source, l.active ? 1 : 0);
  }
  return fmt::to_string(out);
}

// EuRoC's state_groundtruth_estimate0: the IMU frame S (= our I) in R (= W), with the
// true biases of the IMU (from its nearest earlier sample), so that VIO tools read a run.
std::string EurocGroundTruthCsv(const RunRecord& record, const SensorStream& imu) {
  const sim::MountSite* site = record.robot.FindSite(imu.site);
  const Eigen::Vector3d p_B_I = site != nullptr ? site->p_B_s : Eigen::Vector3d::Zero();
  const Eigen::Quaterniond q_B_I = site != nullptr ? site->q_B_s : Eigen::Quaterniond::Identity();
  fmt::memory_buffer out;
  fmt::format_to(std::back_inserter(out),
                 "#timestamp, p_RS_R_x [m], p_RS_R_y [m], p_RS_R_z [m], q_RS_w [], q_RS_x [], "
                 "q_RS_y [], q_RS_z [], v_RS_R_x [m s^-1], v_RS_R_y [m s^-1], v_RS_R_z [m s^-1], "
                 "b_w_RS_S_x [rad s^-1], b_w_RS_S_y [rad s^-1], b_w_RS_S_z [rad s^-1], "
                 "b_a_RS_S_x [m s^-2], b_a_RS_S_y [m s^-2], b_a_RS_S_z [m s^-2]\n");
  size_t k = 0;
  for (const sim::TruthState& s : record.groundtruth) {
    while (k + 1 < imu.clean.size() && imu.clean[k + 1].t_ns <= s.t_ns) ++k;
    const Eigen::Matrix3d R_WB = s.q_WB.toRotationMatrix();
    const Eigen::Vector3d p_WI = s.p_WB + R_WB * p_B_I;
    const Eigen::Vector3d v_WI = s.v_WB_W + R_WB * s.omega_WB_B.cross(p_B_I);
    const Eigen::Quaterniond q_WI = core::CanonicalQuat(s.q_WB * q_B_I);
    const Eigen::Vector3d bw =
        imu.imu_biases.empty() ? Eigen::Vector3d::Zero() : imu.imu_biases[k].first;
    const Eigen::Vector3d ba =
        imu.imu_biases.empty() ? Eigen::Vector3d::Zero() : imu.imu_biases[k].second;
    fmt::format_to(std::back_inserter(out),
                   "{},{:.6f},{:.6f},{:.6f},{:.9f},{:.9f},{:.9f},{:.9f},{:.6f},{:.6f},{:.6f},"
                   "{:.9f},{:.9f},{:.9f},{:.7f},{:.7f},{:.7f}\n",
                   s.t_ns, p_WI.x(), p_WI.y(), p_WI.z(), q_WI.w(), q_WI.x(), q_WI.y(), q_WI.z(),
                   v_WI.x(), v_WI.y(), v_WI.z(), bw.x(), bw.y(), bw.z(), ba.x(), ba.y(), ba.z());
  }
  return fmt::to_string(out);
}

std::string EurocImuCsv(const SensorStream& imu) {
  fmt::memory_buffer out;
  fmt::format_to(std::back_inserter(out),
                 "#timestamp [ns],w_RS_S_x [rad s-1],w_RS_S_y [rad s-1],w_RS_S_z [rad s-1],"
                 "a_RS_S_x [m s-2],a_RS_S_y [m s-2],a_RS_S_z [m s-2]\n");
  for (const sim::SensorSample& s : imu.delivered) {
    const auto& m = std::get<core::ImuMeasurement>(s.measured);
    fmt::format_to(std::back_inserter(out), "{},{:.9f},{:.9f},{:.9f},{:.7f},{:.7f},{:.7f}\n",
                   s.t_ns, m.gyro_I_radps.x(), m.gyro_I_radps.y(), m.gyro_I_radps.z(),
                   m.acc_I_mps2.x(), m.acc_I_mps2.y(), m.acc_I_mps2.z());
  }
  return fmt::to_string(out);
}

std::string ConsistencyCsv(const ConsistencyEvaluation& eval) {
  fmt::memory_buffer out;
  fmt::format_to(std::back_inserter(out), "#timestamp [ns],pair,metric,value\n");
  for (const ConsistencyRow& row : eval.rows) {
    fmt::format_to(std::back_inserter(out), "{},{},{},", row.t_ns, row.pair,
                   estimator::MetricName(row.metric));
    if (row.value) fmt::format_to(std::back_inserter(out), "{:.6g}", *row.value);
    fmt::format_to(std::back_inserter(out), "\n");
  }
  return fmt::to_string(out);
}

std::string AlignmentCsv(const ConsistencyEvaluation& eval) {
  fmt::memory_buffer out;
  fmt::format_to(std::back_inserter(out),
                 "#timestamp [ns],sensor,rotation_error [deg],observable_rotation_dofs,"
                 "rms_residual [m]\n");
  for (const AlignmentRow& row : eval.alignment) {
    fmt::format_to(std::back_inserter(out), "{},{},{:.4f},{},{:.5f}\n", row.t_ns, row.sensor,
                   row.rotation_error_deg, row.observable_rotation_dofs, row.rms_residual_m);
  }
  return fmt::to_string(out);
}

std::string TimingJson(const RunRecord& record) {
  const double simulated_s = record.scenario.physics.rate_hz > 0.0
                                 ? static_cast<double>(record.physics_steps) /
                                       record.scenario.physics.rate_hz
                                 : 0.0;
  nlohmann::json j = {
      {"wall_time_s", record.wall_time_s},
      {"simulated_s", simulated_s},
      {"real_time_factor", record.wall_time_s > 0.0 ? simulated_s / record.wall_time_s : 0.0},
      {"physics_steps_per_s",
       record.wall_time_s > 0.0 ? static_cast<double>(record.physics_steps) / record.wall_time_s
                                : 0.0},
      {"note", "wall-clock figures: the only file of the run that differs between two runs"}};
  // One entry per simulated minute: its real-time factor and the resident set at its end
  // (a long run's memory must stay flat; scripts/soak.py reads these).
  nlohmann::json minutes = nlohmann::json::array();
  double previous_wall_s = 0.0;
  for (size_t i = 0; i < record.minutes.size(); ++i) {
    const RunRecord::MinuteMark& m = record.minutes[i];
    const double wall_s = m.wall_time_s - previous_wall_s;
    minutes.push_back({{"minute", i + 1},
                       {"real_time_factor", wall_s > 0.0 ? 60.0 / wall_s : 0.0},
                       {"resident_mb", m.resident_mb}});
    previous_wall_s = m.wall_time_s;
  }
  j["minutes"] = std::move(minutes);
  return j.dump(2) + "\n";
}

}  // namespace

// Declared in run_directory.h.
int RunQuietly(const std::vector<std::string>& argv) {
  posix_spawn_file_actions_t actions;
  posix_spawn_file_actions_init(&actions);
  posix_spawn_file_actions_addopen(&actions, STDOUT_FILENO, "/dev/null", O_WRONLY, 0);
  posix_spawn_file_actions_addopen(&actions, STDERR_FILENO, "/dev/null", O_WRONLY, 0);
  std::vector<char*> args;
  for (const std::string& a : argv) args.push_back(const_cast<char*>(a.c_str()));
  args.push_back(nullptr);
  pid_t pid = 0;
  const int spawned = posix_spawn(&pid, args[0], &actions, nullptr, args.data(), environ);
  posix_spawn_file_actions_destroy(&actions);
  if (spawned != 0) return -1;
  // Waited for in slices, so that an interruption neither waits for the program nor
  // leaves it drawing into a staging directory that is about to be removed.
  int status = 0;
  for (;;) {
    const pid_t done = waitpid(pid, &status, WNOHANG);
    if (done == pid) break;
    if (done < 0 && errno != EINTR) return -1;
    if (WaitForInterrupt(50)) {
      ::kill(pid, SIGTERM);
      while (waitpid(pid, &status, 0) < 0 && errno == EINTR) {
      }
      ThrowIfInterrupted();
    }
  }
  return WIFEXITED(status) ? WEXITSTATUS(status) : -1;
}

namespace {

// control.csv of a closed-loop flight: at the ground-truth rate, what the controller flew
// on (mode, its estimate of B in W) beside the truth and the mission reference.
std::string ControlCsv(const RunRecord& record) {
  fmt::memory_buffer out;
  fmt::format_to(std::back_inserter(out),
                 "#timestamp [ns],mode,p_ref_x [m],p_ref_y [m],p_ref_z [m],p_true_x [m],"
                 "p_true_y [m],p_true_z [m],p_est_x [m],p_est_y [m],p_est_z [m],"
                 "tracking_error [m],estimate_error [m],structure_distance [m]\n");
  const ClosedLoopFlight& flight = *record.closed_loop;
  const std::size_t n = std::min({flight.samples.size(), record.groundtruth.size(),
                                  record.tracking.size()});
  for (std::size_t k = 0; k < n; ++k) {
    const ClosedLoopSample& s = flight.samples[k];
    const Eigen::Vector3d& p_true = record.groundtruth[k].p_WB;
    const Eigen::Vector3d& p_ref = record.tracking[k].reference.p_WB;
    fmt::format_to(std::back_inserter(out), "{},{},{:.6f},{:.6f},{:.6f},{:.6f},{:.6f},{:.6f}",
                   s.t_ns, FlightModeName(s.mode), p_ref.x(), p_ref.y(), p_ref.z(), p_true.x(),
                   p_true.y(), p_true.z());
    if (s.p_WB_est) {
      fmt::format_to(std::back_inserter(out), ",{:.6f},{:.6f},{:.6f}", s.p_WB_est->x(),
                     s.p_WB_est->y(), s.p_WB_est->z());
    } else {
      fmt::format_to(std::back_inserter(out), ",,,");
    }
    fmt::format_to(std::back_inserter(out), ",{:.6f},", record.tracking[k].position_error_m);
    if (s.p_WB_est) {
      fmt::format_to(std::back_inserter(out), "{:.6f}", (*s.p_WB_est - p_true).norm());
    }
    fmt::format_to(std::back_inserter(out), ",");
    if (s.structure_distance_m) {
      fmt::format_to(std::back_inserter(out), "{:.6f}", *s.structure_distance_m);
    }
    fmt::format_to(std::back_inserter(out), "\n");
  }
  return fmt::to_string(out);
}

std::string EventsCsv(const ClosedLoopFlight& flight) {
  fmt::memory_buffer out;
  fmt::format_to(std::back_inserter(out), "#timestamp [ns],event,detail\n");
  for (const FlightEvent& e : flight.events) {
    fmt::format_to(std::back_inserter(out), "{},{},\"{}\"\n", e.t_ns, e.event, e.detail);
  }
  return fmt::to_string(out);
}

// Every file of a run (no estimation files) into `dir`, which exists.
void WriteRunFiles(const RunRecord& record, const Evaluation& evaluation, const fs::path& dir) {
  WriteFileAtomically(dir / "scenario.yaml", ResolvedScenarioYaml(record.scenario));
  WriteFileAtomically(dir / "groundtruth.csv", GroundTruthCsv(record));
  WriteFileAtomically(dir / "groundtruth.tum", GroundTruthTum(record));
  WriteFileAtomically(dir / "tracking.csv", TrackingCsv(record));
  WriteFileAtomically(dir / "calibration.yaml", CalibrationYaml(record));
  WriteFileAtomically(dir / "summary.json", evaluation.summary.dump(2) + "\n");
  WriteFileAtomically(dir / "timing.json", TimingJson(record));
  if (!record.sensors.empty()) {
    fs::create_directories(dir / "sensors" / "clean");
    for (const SensorStream& stream : record.sensors) {
      WriteFileAtomically(dir / "sensors" / (stream.name + ".csv"), SensorCsv(stream, true));
      WriteFileAtomically(dir / "sensors" / "clean" / (stream.name + ".csv"),
                          SensorCsv(stream, false));
    }
    WriteFileAtomically(dir / "labels.csv", LabelsCsv(record));
    if (record.consistency) {
      WriteFileAtomically(dir / "consistency.csv", ConsistencyCsv(*record.consistency));
      WriteFileAtomically(dir / "alignment.csv", AlignmentCsv(*record.consistency));
    }
    // The EuRoC folder layout of the first IMU, so existing VIO tools read a run.
    for (const SensorStream& stream : record.sensors) {
      if (stream.type != "imu") continue;
      fs::create_directories(dir / "mav0" / "imu0");
      fs::create_directories(dir / "mav0" / "state_groundtruth_estimate0");
      WriteFileAtomically(dir / "mav0" / "imu0" / "data.csv", EurocImuCsv(stream));
      WriteFileAtomically(dir / "mav0" / "state_groundtruth_estimate0" / "data.csv",
                          EurocGroundTruthCsv(record, stream));
      break;
    }
  }
  if (record.closed_loop) {
    WriteFileAtomically(dir / "control.csv", ControlCsv(record));
    WriteFileAtomically(dir / "events.csv", EventsCsv(*record.closed_loop));
  }
}

}  // namespace

void CheckOutputDirectory(const fs::path& out_dir, bool force) {
  if (out_dir.empty()) {
    throw core::InputError({}, "--out", "expected a directory path, got an empty string");
  }
  std::error_code ec;
  const fs::file_status status = fs::status(out_dir, ec);
  if (ec || !fs::exists(status)) return;
  if (!fs::is_directory(status)) {
    throw core::InputError({out_dir.string()}, "--out",
                           "exists and is not a directory: expected a new or empty directory, "
                           "or an earlier tofu run directory with --force");
  }
  if (fs::is_empty(out_dir, ec)) return;
  if (!fs::exists(out_dir / kRunMarkerFile)) {
    throw core::InputError(
        {out_dir.string()}, "--out",
        fmt::format("holds files that are not a tofu run directory (no {}): refusing to replace "
                    "it; choose a new or empty directory",
                    kRunMarkerFile));
  }
  if (!force) {
    throw core::InputError({out_dir.string()}, "--out",
                           "holds an earlier tofu run: --force replaces it (atomically: the old "
                           "run stays until the new one is complete)");
  }
}

void WriteRunDirectory(const RunRecord& record, const Evaluation& evaluation,
                       const std::string& out_dir,
                       const std::function<void(const std::filesystem::path& staging)>& finish) {
  fs::path out = fs::absolute(out_dir).lexically_normal();
  // "run/" names the directory run: its siblings, not its children, are the staging.
  if (out.filename().empty()) out = out.parent_path();
  const fs::path parent = out.parent_path();
  fs::create_directories(parent);
  const fs::path staging = StagingPath(out);
  fs::remove_all(staging);
  try {
    fs::create_directories(staging);
    WriteRunFiles(record, evaluation, staging);
    if (finish) finish(staging);
    // The marker last: only a complete directory holds it, never one that an interruption
    // or a SIGKILL cut short.
    WriteFileAtomically(staging / kRunMarkerFile,
                        "a tofu run directory: `tofu run --out` replaces it only with --force\n");
    // The last check point: after it the run is complete and goes into place.
    ThrowIfInterrupted();
    // Replace atomically from a reader's point of view: old aside, new in, old gone.
    const fs::path old = parent / (out.filename().string() + fmt::format(".old-{}", ::getpid()));
    if (fs::exists(out)) fs::rename(out, old);
    fs::rename(staging, out);
    fs::remove_all(old);
  } catch (...) {
    std::error_code ignored;
    fs::remove_all(staging, ignored);
    throw;
  }
}

namespace {

double SimulatedSeconds(const RunRecord& record) {
  return core::TimeToSeconds(record.physics_steps *
                             core::PeriodFromRate(record.scenario.physics.rate_hz));
}

// Draws a figure with one of scripts/; a missing interpreter or library is a warning.
void Plot(const char* script_name, const fs::path& dir, const fs::path& png) {
  const fs::path script = fs::path(TOFU_SCRIPTS_DIR) / script_name;
  if (!fs::exists(script) ||
      RunQuietly({script.string(), dir.string(), "--out", png.string()}) != 0) {
    fmt::print(stderr, "tofu: warning: no {} ({} failed; needs python3-matplotlib)\n",
               png.filename().string(), script.string());
  }
}

// A closed-loop flight into <staging>/closed_loop/<method>/: its own run files, and the
// estimate of the method that flew, scored like an open-loop method.
void WriteClosedLoopFlight(RunRecord& flight, const fs::path& dir) {
  fs::create_directories(dir);
  if (flight.scenario.estimation && !flight.failure) {
    EstimationConfig config = *flight.scenario.estimation;
    config.methods = {flight.closed_loop->method};
    WriteRunFiles(flight, Evaluate(flight), dir);
    flight.methods = EvaluateEstimation(dir, config, flight.labels, SimulatedSeconds(flight),
                                        flight.in_loop);
  }
  WriteRunFiles(flight, Evaluate(flight), dir);
}

}  // namespace

Evaluation WriteRun(RunRecord& record, const std::string& out_dir,
                    const RunOutputOptions& options) {
  Evaluation evaluation = Evaluate(record);
  const bool estimation = record.scenario.estimation && !record.failure;
  if (!estimation && record.closed_loop_flights.empty()) {
    WriteRunDirectory(record, evaluation, out_dir);
    return evaluation;
  }
  WriteRunDirectory(record, evaluation, out_dir, [&](const fs::path& staging) {
    if (estimation) {
      record.methods = EvaluateEstimation(staging, *record.scenario.estimation, record.labels,
                                          SimulatedSeconds(record), record.in_loop);
    }
    for (RunRecord& flight : record.closed_loop_flights) {
      WriteClosedLoopFlight(flight,
                            staging / "closed_loop" / MethodFileStem(flight.closed_loop->method));
    }
    evaluation = Evaluate(record);
    WriteFileAtomically(staging / "summary.json", evaluation.summary.dump(2) + "\n");
    if (options.plot && estimation) Plot("plot_consensus.py", staging, staging / "consensus.png");
    if (options.plot && !record.closed_loop_flights.empty()) {
      Plot("plot_closed_loop.py", staging, staging / "closed_loop.png");
    }
  });
  return evaluation;
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

std::string CalibrationYamlText(const RunRecord& record) { return CalibrationYaml(record); }

}  // namespace tofu::harness
