#include "replay/api_convert.h"

#include <stdexcept>
#include <variant>

#include "replay/recorded_log.h"

namespace tofu::replay {
namespace {

template <int N>
std::array<double, N * N> ToApiMatrix(const Eigen::Matrix<double, N, N>& m) {
  std::array<double, N * N> out{};
  for (int r = 0; r < N; ++r) {
    for (int c = 0; c < N; ++c) out[static_cast<std::size_t>(r * N + c)] = m(r, c);
  }
  return out;
}

template <int N>
Eigen::Matrix<double, N, N> FromApiMatrix(const std::array<double, N * N>& a) {
  Eigen::Matrix<double, N, N> m;
  for (int r = 0; r < N; ++r) {
    for (int c = 0; c < N; ++c) m(r, c) = a[static_cast<std::size_t>(r * N + c)];
  }
  return m;
}

}  // namespace

api::Quat ToApi(const Eigen::Quaterniond& q) { return {q.w(), q.x(), q.y(), q.z()}; }
Eigen::Quaterniond FromApi(const api::Quat& q) { return {q[0], q[1], q[2], q[3]}; }

api::Vec3 ToApi(const Eigen::Vector3d& v) { return {v.x(), v.y(), v.z()}; }
Eigen::Vector3d FromApi(const api::Vec3& v) { return {v[0], v[1], v[2]}; }

api::Pose ToApiPose(const Eigen::Isometry3d& T_AB) {
  return {ToApi(Eigen::Vector3d(T_AB.translation())), ToApi(Eigen::Quaterniond(T_AB.linear()))};
}

Eigen::Isometry3d FromApiPose(const api::Pose& T_AB) {
  Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
  T.linear() = FromApi(T_AB.q_wxyz).normalized().toRotationMatrix();
  T.translation() = FromApi(T_AB.p_m);
  return T;
}

api::Measurement ToApiMeasurement(const core::StampedMeasurement& measurement,
                                  core::Time arrival_ns, std::size_t sensor_index) {
  api::Measurement m;
  m.t_ns = measurement.t_ns;
  m.arrival_ns = arrival_ns;
  m.sensor = sensor_index;
  if (const auto* imu = std::get_if<core::ImuMeasurement>(&measurement.value)) {
    m.kind = api::SensorKind::kImu;
    m.imu = {ToApi(imu->acc_I_mps2), ToApi(imu->gyro_I_radps)};
  } else if (const auto* pose = std::get_if<core::PoseMeasurement>(&measurement.value)) {
    m.kind = api::SensorKind::kPose;
    m.pose.T_Ss = {ToApi(pose->p_Ss), ToApi(pose->q_Ss)};
    m.pose.covariance = ToApiMatrix<6>(pose->covariance);
    m.pose.has_twist = pose->has_twist;
    m.pose.v_s_mps = ToApi(pose->v_s_s_mps);
    m.pose.omega_s_radps = ToApi(pose->omega_s_s_radps);
    m.pose.twist_covariance = ToApiMatrix<6>(pose->twist_covariance);
  } else {
    const auto& position = std::get<core::PositionMeasurement>(measurement.value);
    m.kind = api::SensorKind::kPosition;
    m.position = {ToApi(position.p_Ss), ToApiMatrix<3>(position.covariance)};
  }
  return m;
}

core::StampedMeasurement FromApiMeasurement(const api::Measurement& m, const std::string& sensor) {
  core::StampedMeasurement out;
  out.sensor = sensor;
  out.t_ns = m.t_ns;
  switch (m.kind) {
    case api::SensorKind::kImu:
      out.value = core::ImuMeasurement{FromApi(m.imu.acc_I_mps2), FromApi(m.imu.gyro_I_radps)};
      break;
    case api::SensorKind::kPose: {
      core::PoseMeasurement pose;
      pose.p_Ss = FromApi(m.pose.T_Ss.p_m);
      pose.q_Ss = FromApi(m.pose.T_Ss.q_wxyz);
      pose.covariance = FromApiMatrix<6>(m.pose.covariance);
      pose.has_twist = m.pose.has_twist;
      pose.v_s_s_mps = FromApi(m.pose.v_s_mps);
      pose.omega_s_s_radps = FromApi(m.pose.omega_s_radps);
      pose.twist_covariance = FromApiMatrix<6>(m.pose.twist_covariance);
      out.value = pose;
      break;
    }
    case api::SensorKind::kPosition:
      out.value = core::PositionMeasurement{FromApi(m.position.p_Ss_m),
                                            FromApiMatrix<3>(m.position.covariance_m2)};
      break;
  }
  return out;
}

api::Estimate ToApiEstimate(estimator::EstimatorOutput&& o) {
  api::Estimate e;
  e.t_ns = o.t_ns;
  e.valid = o.valid;
  e.initialized = o.initialized;
  e.T_LI = {ToApi(o.state.p_LI), ToApi(o.state.q_LI)};
  e.v_L_mps = ToApi(o.state.v_L_mps);
  e.omega_I_radps = ToApi(o.omega_I_radps);
  e.bias_acc_mps2 = ToApi(o.bias.accel_mps2);
  e.bias_gyro_radps = ToApi(o.bias.gyro_radps);
  if (o.position_covariance_m2) e.position_covariance_m2 = ToApiMatrix<3>(*o.position_covariance_m2);
  e.fused = std::move(o.fused);
  if (o.mission) {
    e.T_ML = api::Pose{ToApi(o.mission->p_ML_m), ToApi(o.mission->q_ML)};
    // [δp; δθ]: the heading is the rotation about z; roll and pitch are gravity's.
    Eigen::Matrix<double, 6, 6> covariance = Eigen::Matrix<double, 6, 6>::Zero();
    covariance.diagonal() << o.mission->variance.head<3>(), 0.0, 0.0, o.mission->variance.w();
    e.T_ML_covariance = ToApiMatrix<6>(covariance);
  }
  return e;
}

estimator::EstimatorOutput FromApiEstimate(api::Estimate&& e) {
  estimator::EstimatorOutput o;
  o.t_ns = e.t_ns;
  o.valid = e.valid;
  o.initialized = e.initialized;
  o.state.p_LI = FromApi(e.T_LI.p_m);
  o.state.q_LI = FromApi(e.T_LI.q_wxyz);
  o.state.v_L_mps = FromApi(e.v_L_mps);
  o.omega_I_radps = FromApi(e.omega_I_radps);
  o.bias.accel_mps2 = FromApi(e.bias_acc_mps2);
  o.bias.gyro_radps = FromApi(e.bias_gyro_radps);
  if (e.position_covariance_m2) o.position_covariance_m2 = FromApiMatrix<3>(*e.position_covariance_m2);
  if (e.fused) o.fused = std::move(*e.fused);
  if (e.T_ML) {
    estimator::MissionFrameEstimate& mission = o.mission.emplace();
    mission.p_ML_m = FromApi(e.T_ML->p_m);
    mission.q_ML = FromApi(e.T_ML->q_wxyz);
    if (e.T_ML_covariance) {
      const Eigen::Matrix<double, 6, 6> covariance = FromApiMatrix<6>(*e.T_ML_covariance);
      mission.variance << covariance.diagonal().head<3>(), covariance(5, 5);
    }
  }
  return o;
}

api::SensorKind ToApi(core::MeasurementKind kind) {
  switch (kind) {
    case core::MeasurementKind::kImu: return api::SensorKind::kImu;
    case core::MeasurementKind::kPose: return api::SensorKind::kPose;
    case core::MeasurementKind::kPosition: return api::SensorKind::kPosition;
  }
  return api::SensorKind::kPosition;
}

core::MeasurementKind FromApi(api::SensorKind kind) {
  switch (kind) {
    case api::SensorKind::kImu: return core::MeasurementKind::kImu;
    case api::SensorKind::kPose: return core::MeasurementKind::kPose;
    case api::SensorKind::kPosition: return core::MeasurementKind::kPosition;
  }
  return core::MeasurementKind::kPosition;
}

api::EstimatorSetup ApiSetupOf(const RecordedLog& log, double gravity_mps2) {
  api::EstimatorSetup setup;
  setup.gravity_mps2 = gravity_mps2;
  for (const RecordedStream& s : log.streams) {
    api::SensorInfo info;
    info.name = s.name;
    info.kind = ToApi(s.kind);
    info.T_Is = ToApiPose(s.T_Is);
    info.covariance_stated = s.covariance_stated;
    if (s.T_MS) info.T_MS = ToApiPose(*s.T_MS);
    if (s.name == log.imu_stream) setup.imu = setup.sensors.size();
    setup.sensors.push_back(std::move(info));
  }
  if (log.T_MI_launch) setup.T_MI_launch = ToApiPose(*log.T_MI_launch);
  return setup;
}

}  // namespace tofu::replay
