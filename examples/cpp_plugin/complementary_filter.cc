#include "complementary_filter.h"

#include <algorithm>
#include <cmath>
#include <stdexcept>
#include <utility>

#include <nlohmann/json.hpp>

namespace tofu_example {
namespace {

using Vec3 = Eigen::Vector3d;
using Mat3 = Eigen::Matrix3d;
using Quat = Eigen::Quaterniond;

constexpr double kSecondsPerNs = 1e-9;
/// Attitude errors [rad] below which the gyro bias is integrated (anti-windup).
constexpr double kIntegrateBelowRad = 0.05;

/// Exp: so(3) -> SO(3) as a unit quaternion (rotation vector phi [rad]).
Quat ExpQ(const Vec3& phi_rad) {
  const double angle = phi_rad.norm();
  if (angle < 1e-12) return Quat(1.0, 0.5 * phi_rad.x(), 0.5 * phi_rad.y(), 0.5 * phi_rad.z()).normalized();
  return Quat(Eigen::AngleAxisd(angle, phi_rad / angle));
}

Vec3 ToEigen(const tofu::api::Vec3& v) { return Vec3(v[0], v[1], v[2]); }

bool AllFinite(const tofu::api::Vec3& v) {
  return std::isfinite(v[0]) && std::isfinite(v[1]) && std::isfinite(v[2]);
}

/// The api's Pose T_AB as (R_AB, p_AB).
Eigen::Isometry3d ToIsometry(const tofu::api::Pose& T_AB) {
  Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
  T.linear() = Quat(T_AB.q_wxyz[0], T_AB.q_wxyz[1], T_AB.q_wxyz[2], T_AB.q_wxyz[3])
                   .normalized()
                   .toRotationMatrix();
  T.translation() = ToEigen(T_AB.p_m);
  return T;
}

/// Integral over [a, b] of the hat kernel K of the second difference on t0 < t1 < t2:
/// K rises 0 -> 1 on [t0, t1] and falls 1 -> 0 on [t1, t2]. Then
///   (p2 - p1) / (t2 - t1) - (p1 - p0) / (t1 - t0) = integral of K(t) a(t) dt
/// for any p(t) with p'' = a: mean velocity of the second interval minus that of the first.
double HatIntegral(double a, double b, double t0, double t1, double t2) {
  auto K = [&](double t) {
    if (t <= t0 || t >= t2) return 0.0;
    return t <= t1 ? (t - t0) / (t1 - t0) : (t2 - t) / (t2 - t1);
  };
  double sum = 0.0;
  // K is linear on [t0, t1] and [t1, t2]: the trapezoid rule is exact on each piece.
  const double cuts[] = {t0, t1, t2};
  double lo = std::max(a, t0);
  const double hi = std::min(b, t2);
  for (double cut : cuts) {
    if (cut <= lo || cut >= hi) continue;
    sum += 0.5 * (K(lo) + K(cut)) * (cut - lo);
    lo = cut;
  }
  if (hi > lo) sum += 0.5 * (K(lo) + K(hi)) * (hi - lo);
  return sum;
}

}  // namespace

// ---------------------------------------------------------------------------------------
// Configuration

ComplementaryConfig ComplementaryConfig::FromJson(const std::string& config_json) {
  ComplementaryConfig c;
  nlohmann::json j;
  try {
    j = nlohmann::json::parse(config_json.empty() ? std::string("{}") : config_json);
  } catch (const nlohmann::json::exception& e) {
    throw std::invalid_argument(std::string("complementary: config is not JSON: ") + e.what());
  }
  if (!j.is_object()) throw std::invalid_argument("complementary: config must be a map");

  struct Field {
    const char* key;
    double* value;
    double min;
    double max;
  };
  const Field gains[] = {
      {"tilt_kp", &c.tilt_kp, 0.0, 100.0}, {"tilt_ki", &c.tilt_ki, 0.0, 100.0},
      {"yaw_kp", &c.yaw_kp, 0.0, 100.0},   {"yaw_kp_aligned", &c.yaw_kp_aligned, 0.0, 100.0},
      {"yaw_ki", &c.yaw_ki, 0.0, 100.0},
      {"accel_kp", &c.accel_kp, 0.0, 100.0}, {"accel_ki", &c.accel_ki, 0.0, 100.0},
  };
  const Field fields[] = {
      {"accel_gate", &c.accel_gate, 0.0, 1.0},
      {"accel_fallback_s", &c.accel_fallback_s, 0.0, 1e9},
      {"attitude_std", &c.attitude_std, 0.0, 10.0},
      {"yaw_std_unaligned", &c.yaw_std_unaligned, 0.0, 10.0},
      {"match_window_s", &c.match_window_s, 0.05, 5.0},
      {"match_period_s", &c.match_period_s, 0.0, 5.0},
      {"yaw_horizon_s", &c.yaw_horizon_s, 0.0, 60.0},
      {"acc_noise", &c.acc_noise, 1e-6, 100.0},
      {"acc_noise_unaligned", &c.acc_noise_unaligned, 1e-6, 100.0},
      {"imu_acc_noise", &c.imu_acc_noise, 1e-6, 100.0},
      {"acc_bias_walk", &c.acc_bias_walk, 0.0, 10.0},
      {"acc_bias_std", &c.acc_bias_std, 1e-6, 10.0},
      {"init_vel_std", &c.init_vel_std, 1e-6, 100.0},
      {"gate_chi2", &c.gate_chi2, 0.1, 1e9},
      {"default_fix_std", &c.default_fix_std, 1e-6, 100.0},
      {"init_duration_s", &c.init_duration_s, 0.0, 10.0},
      {"initial_yaw_rad", &c.initial_yaw_rad, -10.0, 10.0},
      {"anchor_timeout_s", &c.anchor_timeout_s, 0.01, 100.0},
      {"history_s", &c.history_s, 0.1, 60.0},
  };
  auto set = [](const Field& f, const nlohmann::json& v, const std::string& where) {
    if (!v.is_number()) throw std::invalid_argument("complementary: " + where + " must be a number");
    const double x = v.get<double>();
    if (!(x >= f.min && x <= f.max)) {
      throw std::invalid_argument("complementary: " + where + " = " + v.dump() +
                                  " is outside [" + nlohmann::json(f.min).dump() + ", " +
                                  nlohmann::json(f.max).dump() + "]");
    }
    *f.value = x;
  };
  for (const auto& item : j.items()) {
    const std::string key = item.key();
    const nlohmann::json& value = item.value();
    if (key == "anchor") {
      if (!value.is_string()) throw std::invalid_argument("complementary: anchor must be a string");
      c.anchor = value.get<std::string>();
      continue;
    }
    if (key == "valid_before_aligned") {
      if (!value.is_boolean()) throw std::invalid_argument("complementary: valid_before_aligned must be true or false");
      c.valid_before_aligned = value.get<bool>();
      continue;
    }
    if (key == "gains") {
      if (!value.is_object()) throw std::invalid_argument("complementary: gains must be a map");
      for (const auto& item : value.items()) {
        // Named copies: C++17 lambdas cannot capture structured bindings (clang refuses).
        const std::string gain_key = item.key();
        const nlohmann::json& gain_value = item.value();
        const auto* f = std::find_if(std::begin(gains), std::end(gains),
                                     [&](const Field& g) { return gain_key == g.key; });
        if (f == std::end(gains)) {
          throw std::invalid_argument("complementary: unknown key gains." + gain_key);
        }
        set(*f, gain_value, "gains." + gain_key);
      }
      continue;
    }
    const auto* f = std::find_if(std::begin(fields), std::end(fields),
                                 [&](const Field& g) { return key == g.key; });
    if (f == std::end(fields)) throw std::invalid_argument("complementary: unknown key " + key);
    set(*f, value, key);
  }
  return c;
}

// ---------------------------------------------------------------------------------------
// Start

void ComplementaryFilter::Start(const tofu::api::EstimatorSetup& setup) {
  if (setup.api_version != tofu::api::kApiVersion) {
    throw std::runtime_error("complementary: setup has API version " +
                             std::to_string(setup.api_version) + ", built with " +
                             std::to_string(tofu::api::kApiVersion));
  }
  config_ = ComplementaryConfig::FromJson(setup.config_json);
  if (setup.imu >= setup.sensors.size()) {
    throw std::invalid_argument("complementary: the setup's imu index is out of range");
  }

  // The anchor: named, or the first position sensor. A pose sensor may anchor too (its
  // position only): its S must then be gravity aligned, as a VIO's odometry frame is.
  bool found = false;
  for (std::size_t i = 0; i < setup.sensors.size(); ++i) {
    const auto& s = setup.sensors[i];
    const bool match = config_.anchor.empty() ? s.kind == tofu::api::SensorKind::kPosition
                                              : s.name == config_.anchor;
    if (match) {
      anchor_ = i;
      found = true;
      break;
    }
  }
  if (!found) {
    throw std::invalid_argument(
        config_.anchor.empty()
            ? std::string("complementary: no position sensor in the setup to anchor to")
            : "complementary: anchor '" + config_.anchor + "' is not a sensor of the setup");
  }
  if (setup.sensors[anchor_].kind == tofu::api::SensorKind::kImu) {
    throw std::invalid_argument("complementary: anchor '" + setup.sensors[anchor_].name +
                                "' is an IMU, not a position or pose sensor");
  }
  anchor_name_ = setup.sensors[anchor_].name;

  // Lever arm: the setup gives each mount in I, T_Is = T_BI^-1 T_Bs; the anchor's
  // position samples are of the point s, whose position in I is T_Is's translation.
  p_Is_m_ = ToIsometry(setup.sensors[anchor_].T_Is).translation();
  if (!p_Is_m_.allFinite()) throw std::invalid_argument("complementary: the anchor's T_Is is not finite");
  g_L_mps2_ = Vec3(0.0, 0.0, -setup.gravity_mps2);
  imu_ = setup.imu;
}

// ---------------------------------------------------------------------------------------
// Samples

void ComplementaryFilter::Add(const tofu::api::Measurement& m,
                              std::vector<tofu::api::Estimate>* out) {
  if (m.sensor == imu_ && m.kind == tofu::api::SensorKind::kImu) {
    if (!AllFinite(m.imu.acc_I_mps2) || !AllFinite(m.imu.gyro_I_radps) ||
        (t_ns_ >= 0 && m.t_ns <= t_ns_)) {
      ++imu_skipped_;  // a faulty sample (NaN, repeated or regressing stamp): skip it
      return;
    }
    const Vec3 gyro = ToEigen(m.imu.gyro_I_radps);
    ImuStep(m.t_ns, gyro, ToEigen(m.imu.acc_I_mps2));
    if (initialized_ && out != nullptr) out->push_back(MakeEstimate(m.t_ns, gyro));
    return;
  }
  if (m.sensor != anchor_) return;  // this design fuses the anchor only

  Fix fix;
  fix.t_ns = m.t_ns;
  if (m.kind == tofu::api::SensorKind::kPosition) {
    fix.p_Ss_m = ToEigen(m.position.p_Ss_m);
    fix.cov_m2 = Eigen::Map<const Eigen::Matrix<double, 3, 3, Eigen::RowMajor>>(
        m.position.covariance_m2.data());
  } else if (m.kind == tofu::api::SensorKind::kPose) {
    fix.p_Ss_m = ToEigen(m.pose.T_Ss.p_m);
    // [delta_theta; delta_p]: the position block is rows/columns 3..5.
    const Eigen::Map<const Eigen::Matrix<double, 6, 6, Eigen::RowMajor>> cov(m.pose.covariance.data());
    fix.cov_m2 = cov.block<3, 3>(3, 3);
  } else {
    return;
  }
  if (!fix.p_Ss_m.allFinite()) {
    ++fixes_invalid_;
    return;
  }
  // A covariance that is not finite and positive definite gets the configured default.
  fix.cov_m2 = 0.5 * (fix.cov_m2 + fix.cov_m2.transpose()).eval();
  if (!fix.cov_m2.allFinite() || fix.cov_m2.llt().info() != Eigen::Success ||
      fix.cov_m2.diagonal().minCoeff() <= 0.0) {
    fix.cov_m2 = Mat3::Identity() * config_.default_fix_std * config_.default_fix_std;
  }

  if (!initialized_) {
    fixes_before_init_.push_back(fix);
    if (fixes_before_init_.size() > 64) fixes_before_init_.erase(fixes_before_init_.begin());
    return;
  }
  if (fix.t_ns > t_ns_) {
    // Stamped after the newest IMU sample: applied once the IMU has passed it.
    pending_fixes_.push_back(fix);
    if (pending_fixes_.size() > 256) pending_fixes_.erase(pending_fixes_.begin());
    return;
  }
  ApplyFix(fix);
}

void ComplementaryFilter::ImuStep(std::int64_t t_ns, const Vec3& gyro_I_radps,
                                  const Vec3& f_I_mps2) {
  if (!initialized_) {
    if (t_first_imu_ns_ < 0) t_first_imu_ns_ = t_ns;
    init_imu_.push_back({t_ns, f_I_mps2, gyro_I_radps});
    const auto window_ns = static_cast<std::int64_t>(config_.init_duration_s * 1e9);
    while (init_imu_.size() > 1 && init_imu_.front().t_ns < t_ns - window_ns) init_imu_.pop_front();
    t_ns_ = t_ns;
    TryInitialize(t_ns);
    return;
  }

  const double dt = static_cast<double>(t_ns - t_ns_) * kSecondsPerNs;
  const Mat3 R_LI = q_LI_.toRotationMatrix();

  // Mahony et al. 2008, eq. (32): dR/dt = R (omega_y - b + k_P omega_mes)^, db/dt =
  // -k_I omega_mes. omega_mes comes from the fix-matched vector (held between fixes, in L
  // as e_tilt, e_yaw); without it for a while the gyro alone carries the attitude (an
  // anchor dropout in flight must not level a tilted robot); before the first and long
  // after the last, the accelerometer alone corrects tilt (eq. (32c) with v = f/|f|
  // measured and v0 = z_L, i.e. "specific force points up").
  Vec3 omega_P_I = Vec3::Zero();
  Vec3 omega_I_I = Vec3::Zero();
  const bool matched = t_last_match_ns_ >= 0 && t_ns - t_last_match_ns_ <= 500'000'000 &&
                       AnchorFresh(t_ns);
  if (matched) {
    // The yaw gain drops once aligned: a large gain pulls the unknown initial yaw in
    // quickly, a small one then averages the fixes' noise (a few degrees per observation).
    const double yaw_kp = aligned_ns_ >= 0 ? config_.yaw_kp_aligned : config_.yaw_kp;
    omega_P_I = R_LI.transpose() * (config_.tilt_kp * e_tilt_L_ + yaw_kp * e_yaw_L_);
    // Anti-windup: the integral term estimates the gyro bias, which the error only shows
    // once the attitude is close; while a large error (the unknown initial yaw) is being
    // pulled in, integrating it would wind b_g up and leave a slow yaw drift behind. So
    // the yaw part integrates only once aligned, the tilt part only for small errors.
    const double ki_tilt = e_tilt_L_.norm() < kIntegrateBelowRad ? config_.tilt_ki : 0.0;
    const double ki_yaw = aligned_ns_ >= 0 && e_yaw_L_.norm() < kIntegrateBelowRad ? config_.yaw_ki : 0.0;
    omega_I_I = R_LI.transpose() * (ki_tilt * e_tilt_L_ + ki_yaw * e_yaw_L_);
  } else if (t_last_match_ns_ < 0 ||
             static_cast<double>(t_ns - t_last_match_ns_) * kSecondsPerNs > config_.accel_fallback_s) {
    // Raw f, as in the vector observation: tilt takes up a horizontal accel bias in both.
    const Vec3& f = f_I_mps2;
    const double g = g_L_mps2_.norm();
    if (std::abs(f.norm() - g) < config_.accel_gate * g) {
      const Vec3 v_I = f.normalized();
      const Vec3 v_hat_I = R_LI.transpose() * Vec3::UnitZ();
      const Vec3 omega_mes_I = v_I.cross(v_hat_I);
      omega_P_I = config_.accel_kp * omega_mes_I;
      omega_I_I = config_.accel_ki * omega_mes_I;
    }
  }
  b_g_radps_ -= omega_I_I * dt;
  const Vec3 omega_I = gyro_I_radps - b_g_radps_ + omega_P_I;
  // The correction in L: R Exp(w) = Exp(R w) R. Match() uses the product of these to
  // move old attitudes to today's belief before comparing them with the fixes.
  q_correction_L_ = (ExpQ(R_LI * omega_P_I * dt) * q_correction_L_).normalized();
  // The sample is the average over (t_prev, t]: propagate with the mid-step attitude.
  const Quat q_mid = (q_LI_ * ExpQ(0.5 * dt * omega_I)).normalized();
  q_LI_ = (q_LI_ * ExpQ(dt * omega_I)).normalized();

  Propagate(dt, q_mid, f_I_mps2);
  t_ns_ = t_ns;
  history_.push_back({t_ns, dt, f_I_mps2, q_mid, q_LI_, q_correction_L_, x_, P_});
  const auto keep_ns = static_cast<std::int64_t>(config_.history_s * 1e9);
  while (history_.size() > 2 && history_[1].t_ns < t_ns - keep_ns) history_.pop_front();

  if (!pending_fixes_.empty()) {
    std::stable_sort(pending_fixes_.begin(), pending_fixes_.end(),
                     [](const Fix& a, const Fix& b) { return a.t_ns < b.t_ns; });
    std::size_t n = 0;
    while (n < pending_fixes_.size() && pending_fixes_[n].t_ns <= t_ns_) ++n;
    std::vector<Fix> due(pending_fixes_.begin(), pending_fixes_.begin() + static_cast<long>(n));
    pending_fixes_.erase(pending_fixes_.begin(), pending_fixes_.begin() + static_cast<long>(n));
    for (const Fix& fix : due) ApplyFix(fix);
  }
}

void ComplementaryFilter::TryInitialize(std::int64_t t_ns) {
  const auto window_ns = static_cast<std::int64_t>(config_.init_duration_s * 1e9);
  if (t_ns - t_first_imu_ns_ < window_ns || fixes_before_init_.empty()) return;
  const auto timeout_ns = static_cast<std::int64_t>(config_.anchor_timeout_s * 1e9);
  // The newest fix not after now and not older than the anchor timeout.
  const Fix* fix = nullptr;
  for (const Fix& f : fixes_before_init_) {
    if (f.t_ns <= t_ns && t_ns - f.t_ns <= timeout_ns && (fix == nullptr || f.t_ns > fix->t_ns)) fix = &f;
  }
  if (fix == nullptr) return;

  Vec3 f_mean = Vec3::Zero();
  Vec3 gyro_mean = Vec3::Zero();
  for (const auto& s : init_imu_) {
    f_mean += s.f_I_mps2;
    gyro_mean += s.gyro_I_radps;
  }
  f_mean /= static_cast<double>(init_imu_.size());
  gyro_mean /= static_cast<double>(init_imu_.size());

  // Tilt from the mean specific force, f = R_LI^T (0, 0, g) for R = Rz(yaw) Ry(pitch)
  // Rx(roll): f = g (-sin pitch, cos pitch sin roll, cos pitch cos roll). Yaw is not
  // observable from the IMU: the configured initial yaw (0: L's x along I's heading).
  const double roll = std::atan2(f_mean.y(), f_mean.z());
  const double pitch = std::atan2(-f_mean.x(), std::hypot(f_mean.y(), f_mean.z()));
  q_LI_ = Quat(Eigen::AngleAxisd(config_.initial_yaw_rad, Vec3::UnitZ()) *
               Eigen::AngleAxisd(pitch, Vec3::UnitY()) * Eigen::AngleAxisd(roll, Vec3::UnitX()));
  // At rest (or in a steady hover) the mean rate is the gyro bias. When moving it is not,
  // and the bias starts at zero; eq. (32b) estimates it either way.
  const double g = g_L_mps2_.norm();
  if (std::abs(f_mean.norm() - g) < 0.05 * g && gyro_mean.norm() < 0.05) b_g_radps_ = gyro_mean;

  const Mat3 R_LI = q_LI_.toRotationMatrix();
  const double age_s = static_cast<double>(t_ns - fix->t_ns) * kSecondsPerNs;
  x_.setZero();
  x_.segment<3>(0) = fix->p_Ss_m - R_LI * p_Is_m_;
  P_.setZero();
  const double vel_var = config_.init_vel_std * config_.init_vel_std;
  // The fix, the motion since its stamp, and the unknown yaw through the lever arm.
  const Vec3 r_L = R_LI * p_Is_m_;
  const double r_h2 = r_L.x() * r_L.x() + r_L.y() * r_L.y();
  P_.block<3, 3>(0, 0) = fix->cov_m2 + Mat3::Identity() * vel_var * age_s * age_s;
  P_.block<2, 2>(0, 0) += Eigen::Matrix2d::Identity() * r_h2 * config_.yaw_std_unaligned * config_.yaw_std_unaligned;
  P_.block<3, 3>(3, 3) = Mat3::Identity() * vel_var;
  P_.block<3, 3>(6, 6) = Mat3::Identity() * config_.acc_bias_std * config_.acc_bias_std;
  t_ns_ = t_ns;
  history_.clear();
  history_.push_back({t_ns, 0.0, f_mean, q_LI_, q_LI_, q_correction_L_, x_, P_});
  initialized_ = true;
  initialized_ns_ = t_ns;
  ++fixes_accepted_;
  t_last_accepted_fix_ns_ = fix->t_ns;
  accepted_fixes_.push_back(*fix);
  for (const Fix& f : fixes_before_init_) {
    if (f.t_ns > t_ns) pending_fixes_.push_back(f);
  }
  fixes_before_init_.clear();
  init_imu_.clear();
}

// ---------------------------------------------------------------------------------------
// The linear Kalman filter on [p_LI; v_L; b_a]

void ComplementaryFilter::Propagate(double dt, const Quat& q_LI_mid, const Vec3& f_I_mps2) {
  if (dt <= 0.0) return;
  const Mat3 R = q_LI_mid.toRotationMatrix();
  // a_L = R_LI (f_I - b_a) + g_L: the kinematic acceleration of I in L (f_I = R_LI^T
  // (a_L - g_L)); p and v integrate it exactly for a constant a over the step.
  const Vec3 a_L = R * (f_I_mps2 - x_.segment<3>(6)) + g_L_mps2_;
  x_.segment<3>(0) += x_.segment<3>(3) * dt + 0.5 * a_L * dt * dt;
  x_.segment<3>(3) += a_L * dt;
  Mat9 F = Mat9::Identity();
  F.block<3, 3>(0, 3) = Mat3::Identity() * dt;
  F.block<3, 3>(0, 6) = -0.5 * R * dt * dt;
  F.block<3, 3>(3, 6) = -R * dt;
  // White acceleration noise q [m^2/s^3] integrated twice over dt (the standard discrete
  // white-noise-acceleration model), plus a random walk on b_a.
  const double sigma_a = aligned_ns_ >= 0 ? config_.acc_noise : config_.acc_noise_unaligned;
  const double q = sigma_a * sigma_a;
  const double qb = config_.acc_bias_walk * config_.acc_bias_walk;
  Mat9 Q = Mat9::Zero();
  Q.block<3, 3>(0, 0) = Mat3::Identity() * q * dt * dt * dt / 3.0;
  Q.block<3, 3>(0, 3) = Mat3::Identity() * q * dt * dt / 2.0;
  Q.block<3, 3>(3, 0) = Q.block<3, 3>(0, 3);
  Q.block<3, 3>(3, 3) = Mat3::Identity() * q * dt;
  Q.block<3, 3>(6, 6) = Mat3::Identity() * qb * dt;
  P_ = F * P_ * F.transpose() + Q;
}

Quat ComplementaryFilter::AttitudeAt(std::int64_t t_ns) const {
  if (history_.empty()) return q_LI_;
  auto it = std::upper_bound(history_.begin(), history_.end(), t_ns,
                             [](std::int64_t t, const Step& s) { return t < s.t_ns; });
  if (it == history_.begin()) return history_.front().q_LI_end;
  if (it == history_.end()) return history_.back().q_LI_end;
  const Step& b = *it;
  const Step& a = *(it - 1);
  const double u = static_cast<double>(t_ns - a.t_ns) / static_cast<double>(b.t_ns - a.t_ns);
  return a.q_LI_end.slerp(u, b.q_LI_end);
}

bool ComplementaryFilter::ApplyFix(const Fix& fix) {
  if (fix.t_ns < initialized_ns_) return false;  // stamped before the filter started
  if (history_.empty() || fix.t_ns < history_.front().t_ns) {
    ++fixes_too_old_;  // older than the replay buffer (history_s): cannot be applied
    return false;
  }
  // Roll back to the last step at or before the fix's stamp.
  auto it = std::upper_bound(history_.begin(), history_.end(), fix.t_ns,
                             [](std::int64_t t, const Step& s) { return t < s.t_ns; });
  const std::size_t k = static_cast<std::size_t>(it - history_.begin()) - 1;
  const Vec9 x_now = x_;
  const Mat9 P_now = P_;
  x_ = history_[k].x;
  P_ = history_[k].P;
  const bool replay = k + 1 < history_.size();
  if (replay) {
    Propagate(static_cast<double>(fix.t_ns - history_[k].t_ns) * kSecondsPerNs,
              history_[k + 1].q_LI_mid, history_[k + 1].f_I_mps2);
  }

  // z = p_Ss = p_LI + R_LI p_Is: linear in p_LI for the attitude of stage 1 at the stamp.
  // The attitude's error delta_theta (in L) moves the lever-arm term by
  // -[R_LI p_Is]x delta_theta: part of this fix's noise for the position filter.
  const Vec3 r_L = AttitudeAt(fix.t_ns).toRotationMatrix() * p_Is_m_;
  const Vec3 z_LI = fix.p_Ss_m - r_L;
  const Vec3 y = z_LI - x_.segment<3>(0);
  Mat3 r_cross;
  r_cross << 0.0, -r_L.z(), r_L.y(), r_L.z(), 0.0, -r_L.x(), -r_L.y(), r_L.x(), 0.0;
  const double yaw_std = aligned_ns_ >= 0 ? config_.attitude_std : config_.yaw_std_unaligned;
  const Eigen::Vector3d att_var(config_.attitude_std * config_.attitude_std,
                                config_.attitude_std * config_.attitude_std, yaw_std * yaw_std);
  const Mat3 R_fix = fix.cov_m2 + r_cross * att_var.asDiagonal() * r_cross.transpose();
  const Mat3 S = P_.block<3, 3>(0, 0) + R_fix;
  const Eigen::LDLT<Mat3> S_ldlt(S);
  const double d2 = y.dot(S_ldlt.solve(y));
  if (!(d2 <= config_.gate_chi2)) {
    if (AnchorFresh(fix.t_ns)) {
      ++fixes_rejected_;  // an outlier while the anchor is otherwise consistent
      x_ = x_now;
      P_ = P_now;
      return false;
    }
    // The anchor has been silent (or rejected) for longer than the timeout: L is the
    // anchor's frame, so trust it again over dead reckoning and re-anchor the position.
    ++resets_;
    x_.segment<3>(0) = z_LI;
    P_.block<3, 6>(0, 3).setZero();
    P_.block<6, 3>(3, 0).setZero();
    P_.block<3, 3>(0, 0) = R_fix;
    P_.block<3, 3>(3, 3) += Mat3::Identity() * config_.init_vel_std * config_.init_vel_std;
  } else {
    // Kalman update with H = [I 0 0]; Joseph form keeps P symmetric positive definite.
    const Eigen::Matrix<double, 9, 3> PHt = P_.block<9, 3>(0, 0);
    Eigen::Matrix<double, 9, 3> K = S_ldlt.solve(PHt.transpose()).transpose();
    // Unaligned: b_a is a consider state (Schmidt): its uncertainty is accounted for but
    // it is not corrected; the Joseph form below stays valid for this suboptimal gain.
    if (aligned_ns_ < 0) K.block<3, 3>(6, 0).setZero();
    x_ += K * y;
    Mat9 IKH = Mat9::Identity();
    IKH.block<9, 3>(0, 0) -= K;
    P_ = IKH * P_ * IKH.transpose() + K * R_fix * K.transpose();
  }
  P_ = 0.5 * (P_ + P_.transpose()).eval();

  // Replay the stored IMU inputs from the stamp to now.
  if (replay) {
    Propagate(static_cast<double>(history_[k + 1].t_ns - fix.t_ns) * kSecondsPerNs,
              history_[k + 1].q_LI_mid, history_[k + 1].f_I_mps2);
    history_[k + 1].x = x_;
    history_[k + 1].P = P_;
    for (std::size_t j = k + 2; j < history_.size(); ++j) {
      Propagate(history_[j].dt_s, history_[j].q_LI_mid, history_[j].f_I_mps2);
      history_[j].x = x_;
      history_[j].P = P_;
    }
  } else {
    history_[k].x = x_;
    history_[k].P = P_;
  }

  ++fixes_accepted_;
  const bool newest = accepted_fixes_.empty() || fix.t_ns > accepted_fixes_.back().t_ns;
  t_last_accepted_fix_ns_ = std::max(t_last_accepted_fix_ns_, fix.t_ns);
  auto pos = std::upper_bound(accepted_fixes_.begin(), accepted_fixes_.end(), fix.t_ns,
                              [](std::int64_t t, const Fix& f) { return t < f.t_ns; });
  accepted_fixes_.insert(pos, fix);
  while (!accepted_fixes_.empty() && accepted_fixes_.front().t_ns < history_.front().t_ns) {
    accepted_fixes_.pop_front();
  }
  if (newest) Match(fix.t_ns);
  return true;
}

// ---------------------------------------------------------------------------------------
// The vector observation of the attitude filter

void ComplementaryFilter::Match(std::int64_t t2_ns) {
  const auto period_ns = static_cast<std::int64_t>(config_.match_period_s * 1e9);
  if (t_last_match_fix_ns_ >= 0 && t2_ns - t_last_match_fix_ns_ < period_ns) return;
  const auto T_ns = static_cast<std::int64_t>(config_.match_window_s * 1e9);
  // The fixes nearest to t2 - T and t2 - 2T (within T / 4).
  auto nearest = [&](std::int64_t target) -> const Fix* {
    const Fix* best = nullptr;
    for (const Fix& f : accepted_fixes_) {
      if (best == nullptr || std::llabs(f.t_ns - target) < std::llabs(best->t_ns - target)) best = &f;
    }
    return best != nullptr && std::llabs(best->t_ns - target) <= T_ns / 4 ? best : nullptr;
  };
  const Fix* f2 = &accepted_fixes_.back();
  const Fix* f1 = nearest(t2_ns - T_ns);
  const Fix* f0 = nearest(t2_ns - 2 * T_ns);
  if (f0 == nullptr || f1 == nullptr || !(f0->t_ns < f1->t_ns && f1->t_ns < f2->t_ns)) return;
  if (history_.front().t_ns > f0->t_ns) return;

  // Times in seconds relative to t2 (keeps the doubles exact enough).
  auto rel = [&](std::int64_t t) { return static_cast<double>(t - t2_ns) * kSecondsPerNs; };
  const double t0 = rel(f0->t_ns), t1 = rel(f1->t_ns), t2 = 0.0;

  // From the fixes: the hat-kernel integral of a_L (HatIntegral), minus gravity's share,
  // leaves that of the specific force in L: u = int K (a_L - g_L) dt = int K R_LI f_I dt.
  auto p_LI = [&](const Fix& f) {
    return Vec3(f.p_Ss_m - AttitudeAt(f.t_ns).toRotationMatrix() * p_Is_m_);
  };
  const Vec3 p0 = p_LI(*f0), p1 = p_LI(*f1), p2 = p_LI(*f2);
  const Vec3 dv_fix = (p2 - p1) / (t2 - t1) - (p1 - p0) / (t1 - t0);
  const Vec3 u_L = dv_fix - g_L_mps2_ * 0.5 * (t2 - t0);

  // From the IMU: the same integral of R_LI f_I with each step's attitude brought to the
  // current belief by the corrections applied since (q_correction_L now * then^-1), so the
  // comparison measures today's attitude error and the loop is not delayed by the window.
  Vec3 u_hat_L = Vec3::Zero();
  auto it = std::upper_bound(history_.begin(), history_.end(), f0->t_ns,
                             [](std::int64_t t, const Step& s) { return t < s.t_ns; });
  for (; it != history_.end(); ++it) {
    const double hi = rel(it->t_ns);
    const double lo = hi - it->dt_s;
    if (lo >= t2) break;
    const double w = HatIntegral(lo, hi, t0, t1, t2);
    if (w <= 0.0) continue;
    const Quat q = q_correction_L_ * it->q_correction_L.conjugate() * it->q_LI_mid;
    u_hat_L += w * (q * it->f_I_mps2);
  }
  // A window with a gap in the IMU or a fault in a fix: no observation.
  if (std::abs(u_L.norm() - u_hat_L.norm()) > 0.3 * u_L.norm()) return;

  // Noise of u's horizontal part: the fixes' through the second difference, the IMU's
  // through the kernel (int K^2 dt = (t2 - t0) / 3 for the hat).
  const double var_p = (f0->cov_m2.trace() + f1->cov_m2.trace() + f2->cov_m2.trace()) / 9.0;
  const double d1 = t1 - t0, d2 = t2 - t1;
  const double var_fix = var_p * (1.0 / (d1 * d1) + std::pow(1.0 / d1 + 1.0 / d2, 2) + 1.0 / (d2 * d2));
  const double var_imu = config_.imu_acc_noise * config_.imu_acc_noise * (t2 - t0) / 3.0;
  const double var_h = var_fix + var_imu;

  pairs_.push_back({t2_ns, u_L, u_hat_L, q_correction_L_, var_h});
  const auto horizon_ns = static_cast<std::int64_t>(config_.yaw_horizon_s * 1e9);
  while (!pairs_.empty() && pairs_.front().t_ns < t2_ns - horizon_ns) pairs_.pop_front();

  // Yaw: one pair cannot tell a yaw error from a tilt error (or a horizontal accelerometer
  // bias) while the horizontal acceleration keeps its direction: both shift u_hat's
  // horizontal part by a constant. Their *changes* over the last yaw_horizon_s can: the
  // 2-D orthogonal Procrustes fit of the centred horizontal parts (Wahba's problem about
  // z; Umeyama 1991), u_h,i - mean = Rz(psi) (u_hat_h,i - mean), exact at any angle, with
  // the constant offset (tilt, bias) taken out by the centring. Older pairs are moved to
  // today's belief by the corrections applied since they were formed.
  std::vector<Eigen::Vector2d> a, b;
  Eigen::Vector2d a_mean = Eigen::Vector2d::Zero(), b_mean = Eigen::Vector2d::Zero();
  double var_h_mean = 0.0;
  for (const VectorPair& pair : pairs_) {
    const Vec3 u_hat_now = (q_correction_L_ * pair.q_correction_L.conjugate()) * pair.u_hat_L;
    a.emplace_back(u_hat_now.head<2>());
    b.emplace_back(pair.u_L.head<2>());
    a_mean += a.back();
    b_mean += b.back();
    var_h_mean += pair.var_h;
  }
  const double n = static_cast<double>(pairs_.size());
  a_mean /= n;
  b_mean /= n;
  var_h_mean /= n;
  double sum_cross = 0.0, sum_dot = 0.0, spread = 0.0;
  for (std::size_t i = 0; i < a.size(); ++i) {
    const Eigen::Vector2d ai = a[i] - a_mean, bi = b[i] - b_mean;
    sum_cross += ai.x() * bi.y() - ai.y() * bi.x();
    sum_dot += ai.dot(bi);
    spread += ai.squaredNorm();
  }
  // Its variance: the horizontal noise of both sides over the spread of u_hat, times the
  // overlap of the windows (each sample of the IMU and fixes is in (t2 - t0) /
  // match_period pairs, so the pairs are far from independent).
  const double overlap = std::max(1.0, (t2 - t0) / std::max(config_.match_period_s, 1e-3));
  const double var_psi = spread > 0.0 ? 2.0 * var_h_mean * overlap / spread : 1e9;
  constexpr double kYawStdRef = 0.1;  // [rad]: a fit this good gets half the gain
  double w_yaw = 0.0;
  double dpsi = 0.0;
  if (pairs_.size() >= 3 && var_psi < 0.2 * 0.2) {
    w_yaw = 1.0 / (1.0 + var_psi / (kYawStdRef * kYawStdRef));
    dpsi = std::atan2(sum_cross, sum_dot);
  }
  e_yaw_L_ = Vec3(0.0, 0.0, w_yaw * dpsi);
  // Tilt: Mahony's v x v_hat for the vectors after the yaw part is taken out, in L:
  // (u_hat x u) / (|u_hat| |u|) is the rotation (sin of the angle) taking u_hat to u. It
  // also takes up a horizontal accelerometer bias (|b_a,h| / g), as in Mahony's filter.
  const Vec3 u_hat_yawed = Eigen::AngleAxisd(w_yaw * dpsi, Vec3::UnitZ()) * u_hat_L;
  const Vec3 e = u_hat_yawed.cross(u_L) / (u_hat_yawed.norm() * u_L.norm());
  e_tilt_L_ = Vec3(e.x(), e.y(), 0.0);

  t_last_match_ns_ = t_ns_;
  t_last_match_fix_ns_ = t2_ns;
  ++matches_;
  yaw_excitation_ += w_yaw;
  // Aligned: at least twenty well-excited yaw fits (a second at 20 Hz) and their moving
  // average (over ~10) under 2 deg.
  if (w_yaw > 0.5) {
    ++excited_matches_;
    yaw_error_mean_rad_ += 0.1 * (dpsi - yaw_error_mean_rad_);
  }
  if (aligned_ns_ < 0 && excited_matches_ >= 20 && std::abs(yaw_error_mean_rad_) < 0.035) {
    aligned_ns_ = t2_ns;
  }
}

// ---------------------------------------------------------------------------------------
// Output

bool ComplementaryFilter::AnchorFresh(std::int64_t t_ns) const {
  return t_last_accepted_fix_ns_ >= 0 &&
         static_cast<double>(t_ns - t_last_accepted_fix_ns_) * kSecondsPerNs <= config_.anchor_timeout_s;
}

tofu::api::Estimate ComplementaryFilter::MakeEstimate(std::int64_t t_ns, const Vec3& gyro_I_radps) const {
  tofu::api::Estimate e;
  e.t_ns = t_ns;
  e.initialized = true;
  const bool fresh = AnchorFresh(t_ns);
  e.valid = fresh && (config_.valid_before_aligned || aligned_ns_ >= 0);
  Quat q = q_LI_.normalized();
  if (q.w() < 0.0) q.coeffs() *= -1.0;
  e.T_LI.p_m = {x_(0), x_(1), x_(2)};
  e.T_LI.q_wxyz = {q.w(), q.x(), q.y(), q.z()};
  e.v_L_mps = {x_(3), x_(4), x_(5)};
  const Vec3 omega = gyro_I_radps - b_g_radps_;
  e.omega_I_radps = {omega.x(), omega.y(), omega.z()};
  e.bias_acc_mps2 = {x_(6), x_(7), x_(8)};
  e.bias_gyro_radps = {b_g_radps_.x(), b_g_radps_.y(), b_g_radps_.z()};
  // Of p_LI given the attitude (the attitude's own uncertainty is not in it).
  tofu::api::Mat3 cov{};
  for (int r = 0; r < 3; ++r) {
    for (int c = 0; c < 3; ++c) cov[static_cast<std::size_t>(3 * r + c)] = 0.5 * (P_(r, c) + P_(c, r));
  }
  e.position_covariance_m2 = cov;
  e.fused = fresh ? std::vector<std::string>{anchor_name_} : std::vector<std::string>{};
  return e;
}

std::string ComplementaryFilter::ReportJson() const {
  nlohmann::json j;
  j["design"] = "Mahony complementary attitude filter + linear Kalman filter on p, v, b_a";
  j["anchor"] = anchor_name_;
  j["p_Is_m"] = {p_Is_m_.x(), p_Is_m_.y(), p_Is_m_.z()};
  j["initialized_ns"] = initialized_ns_;
  j["aligned_ns"] = aligned_ns_;  // -1: never enough horizontal acceleration to see yaw
  j["fixes_accepted"] = fixes_accepted_;
  j["fixes_rejected"] = fixes_rejected_;
  j["fixes_too_old"] = fixes_too_old_;
  j["fixes_invalid"] = fixes_invalid_;
  j["position_resets"] = resets_;
  j["imu_skipped"] = imu_skipped_;
  j["vector_observations"] = matches_;
  j["bias_gyro_radps"] = {b_g_radps_.x(), b_g_radps_.y(), b_g_radps_.z()};
  j["bias_acc_mps2"] = {x_(6), x_(7), x_(8)};
  return j.dump();
}

}  // namespace tofu_example
