#include "sim/lidar_odometry.h"

#include <algorithm>
#include <cmath>
#include <stdexcept>
#include <utility>

#include <Eigen/Eigenvalues>

#include "core/lie.h"
#include "core/units.h"
#include "sim/mount_motion.h"

namespace tofu::sim {

// ---- options ----

std::span<const core::OptionField<LidarOdometryOptions>> LidarOdometryOptions::Fields() {
  using F = core::OptionField<LidarOdometryOptions>;
  using R = core::NumberRule;
  using O = LidarOdometryOptions;
  // The beam pattern's fields (core::LidarBeamPattern::Fields()) stand after the latency,
  // where the files have always written them.
  static const F kLeading[] = {
      F::Name("site", &O::site)
          .Doc("robot mount site of the LiDAR (z = scanner axis)"),
      F::OptionalVector("frame_position_m", &O::p_WS_m, R::Any("m"))
          .Doc("position of the odometry frame S in W; unset: the LiDAR's position at t = 0"),
      F::OptionalAttitude("frame_rpy_deg", &O::q_WS)
          .Doc("attitude of the odometry frame S in W; unset: the LiDAR's attitude at t = 0"),
      F::Number("rate_hz", &O::rate_hz, R::PositiveAtMost(1000.0, "Hz"))
          .Doc("frame rate, which is also the odometry output rate (Mid-360: 10 Hz)"),
      F::Number("latency_s", &O::latency_s, R::Between(0.0, 10.0, "s"))
          .Doc("delay from a scan's end to the odometry output"),
  };
  static const F kTrailing[] = {
      F::Number("range_noise_m", &O::range_noise_m, R::NonNegative("m"))
          .Doc("1-sigma range precision, weighting the registration information; 0 switches its "
               "noise off"),
      F::Number("degenerate_translation_threshold", &O::degenerate_translation_threshold,
                R::NonNegative("returns"))
          .Doc("a translation direction is degenerate when its eigenvalue of H is below this many "
               "returns / sigma^2"),
      F::Number("degenerate_rotation_threshold_m2", &O::degenerate_rotation_threshold_m2,
                R::NonNegative("m^2"))
          .Doc("a rotation axis is degenerate when its information eigenvalue times sigma^2 is "
               "below this"),
      F::Integer("min_returns", &O::min_returns, 0, 1000000)
          .Doc("fewer returns than this: registration fails and the output diverges"),
      F::Number("position_random_walk_m_per_sqrtm", &O::position_random_walk_m_per_sqrtm,
                R::NonNegative("m/sqrt(m)"))
          .Doc("drift along a constrained translation direction: sigma = this * sqrt(distance "
               "moved along it)"),
      F::Number("degenerate_position_random_walk_m_per_sqrtm",
                &O::degenerate_position_random_walk_m_per_sqrtm, R::NonNegative("m/sqrt(m)"))
          .Doc("drift along a degenerate translation direction, where the IMU alone carries the "
               "motion"),
      F::Degrees("rotation_random_walk_deg_per_sqrtm", &O::rotation_random_walk_rad_per_sqrtm,
                 R::NonNegative("deg/sqrt(m)"))
          .Doc("rotation drift per constrained axis: sigma = this * sqrt(distance travelled)"),
      F::Number("degenerate_rotation_random_walk_rad_per_sqrtrad",
                &O::degenerate_rotation_random_walk_rad_per_sqrtrad,
                R::NonNegative("rad/sqrt(rad)"))
          .Doc("drift about a degenerate rotation axis: sigma = this * sqrt(angle rotated about "
               "it)"),
      F::Number("divergence_velocity_mps", &O::divergence_velocity_mps, R::NonNegative("m/s"))
          .Doc("std per axis of the velocity error drawn when the returns drop below min_returns"),
      F::Number("divergence_time_constant_s", &O::divergence_time_constant_s, R::Positive("s"))
          .Doc("time constant tau of the divergence: the velocity error grows as exp(t / tau)"),
      F::Number("velocity_noise_mps", &O::velocity_noise_mps, R::NonNegative("m/s"))
          .Doc("white noise of the reported velocity, per axis"),
      F::Degrees("angular_rate_noise_degps", &O::angular_rate_noise_radps,
                 R::NonNegative("deg/s"))
          .Doc("white noise of the reported angular rate, per axis"),
      F::Number("max_reported_position_std_m", &O::max_reported_position_std_m,
                R::Positive("m"))
          .Doc("largest reported position 1-sigma (the prior of the regularised inverse "
               "information)"),
      F::Degrees("max_reported_rotation_std_deg", &O::max_reported_rotation_std_rad,
                 R::Positive("deg"))
          .Doc("largest reported rotation 1-sigma (the prior of the regularised inverse "
               "information)"),
  };
  static const std::vector<F> kFields = [] {
    std::vector<F> fields(std::begin(kLeading), std::end(kLeading));
    for (const auto& beam_field : core::LidarBeamPattern::Fields()) {
      fields.push_back(core::DerivedField<O>(beam_field));
    }
    fields.insert(fields.end(), std::begin(kTrailing), std::end(kTrailing));
    return fields;
  }();
  return kFields;
}

bool LidarOdometryOptions::IsValid(std::string* why) const {
  // The beam pattern's own check adds the order of its ranges and elevations.
  return core::CheckOptionFields<LidarOdometryOptions>(*this, Fields(), why) &&
         core::LidarBeamPattern::IsValid(why);
}
namespace {

/// Fractional part of the golden ratio: successive multiples fill [0, 1) evenly.
constexpr double kGoldenFraction = 0.6180339887498949;

}  // namespace

LidarOdometryModel::LidarOdometryModel(std::string name, const LidarOdometryOptions& options,
                                       const World& world, uint64_t seed)
    : name_(std::move(name)),
      options_(core::ValidOptions(options, "lidar odometry '" + name_ + "'")),
      stream_(seed, "sensor/" + name_),
      T_Bs_(world.robot().Site(options_.site, "lidar odometry '" + name_ + "'").T_Bs()),
      period_ns_(core::PeriodFromRate(options.rate_hz)),
      latency_ns_(core::SecondsToTime(options.latency_s)),
      frame_(options_.p_WS_m, options_.q_WS) {}

LidarScanGeometry LidarOdometryModel::AnalyseScan(const World& world,
                                                  const Eigen::Isometry3d& T_Ws,
                                                  int64_t scan_index) const {
  const core::LidarBeamPattern& beams = options_;
  const Eigen::Vector3d origin_W = T_Ws.translation();
  const Eigen::Matrix3d R_Ws = T_Ws.linear();
  // The azimuths turn by the golden fraction of a step from scan to scan: successive scans
  // sample between each other's rays, as a non-repetitive scan pattern does.
  const double phase = kGoldenFraction * static_cast<double>(scan_index % 1000003);
  const double azimuth_offset = (phase - std::floor(phase)) * beams.AzimuthStepRad();

  // Unscaled information S = sum J^T J, J = [(p x n)^T, n^T] (H = S / sigma^2).
  LidarScanGeometry g;
  g.ray_count = beams.azimuth_count * beams.elevation_count;
  Eigen::Matrix<double, 6, 6> S = Eigen::Matrix<double, 6, 6>::Zero();
  std::vector<Eigen::Vector3d> directions_s;
  beams.Directions_s(azimuth_offset, &directions_s);
  const RayFan rays = world.RaysFrom(origin_W, kRayScene);
  for (const Eigen::Vector3d& u_s : directions_s) {
    const std::optional<RayHit> hit = rays.Cast(R_Ws * u_s);
    if (!hit || !beams.InRange(hit->distance_m)) continue;
    ++g.return_count;
    const Eigen::Vector3d p = hit->point_W - origin_W;
    Eigen::Matrix<double, 6, 1> J;
    J << p.cross(hit->normal_W), hit->normal_W;
    S.selfadjointView<Eigen::Lower>().rankUpdate(J);
  }
  S = S.selfadjointView<Eigen::Lower>();

  // Report H = S / sigma^2 (a vanishing sigma gives the geometry with unit weight).
  const double sigma = options_.range_noise_m;
  const double weight = sigma > 0.0 ? 1.0 / (sigma * sigma) : 1.0;
  g.information_W = weight * S;

  const Eigen::SelfAdjointEigenSolver<Eigen::Matrix<double, 6, 6>> full(g.information_W);
  g.eigenvalues = full.eigenvalues();
  g.eigenvectors = full.eigenvectors();
  const Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> rotation(
      g.information_W.topLeftCorner<3, 3>());
  const Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> translation(
      g.information_W.bottomRightCorner<3, 3>());
  g.rotation_eigenvalues = rotation.eigenvalues();
  g.rotation_axes_W = rotation.eigenvectors();
  g.translation_eigenvalues = translation.eigenvalues();
  g.translation_directions_W = translation.eigenvectors();

  // Degenerate: eigenvalue * sigma^2 (= effective number of constraining returns) below
  // the threshold (Zhang, Kaess & Singh 2016, with the threshold in returns).
  g.degenerate = false;
  for (int k = 0; k < 3; ++k) {
    g.translation_degenerate[k] =
        !(g.translation_eigenvalues[k] > 0.0) ||
        g.translation_eigenvalues[k] / weight < options_.degenerate_translation_threshold;
    g.rotation_degenerate[k] =
        !(g.rotation_eigenvalues[k] > 0.0) ||
        g.rotation_eigenvalues[k] / weight < options_.degenerate_rotation_threshold_m2;
    g.degenerate = g.degenerate || g.translation_degenerate[k];
  }
  g.few_returns = g.return_count < options_.min_returns;
  return g;
}

void LidarOdometryModel::Step(const SensorInput& input, std::vector<SensorSample>* out) {
  const TruthState& x = input.truth;
  const core::Time t_ns = x.t_ns;
  const core::Time dt_ns = input.world.timestep_ns();
  const MountMotion now = MountMotionAt(x, T_Bs_, 0.0);

  if (frame_.Boot(now)) previous_p_Ws_ = now.p_Ws;
  const Eigen::Matrix3d R_WS = frame_.T_WS().linear();
  FollowPath(now, R_WS, core::TimeToSeconds(dt_ns));

  // Scans whose time of validity falls in [t, t + dt).
  while (next_sample_ns_ < t_ns) next_sample_ns_ += period_ns_;
  for (; next_sample_ns_ < t_ns + dt_ns; next_sample_ns_ += period_ns_) {
    const core::Time ts_ns = next_sample_ns_;
    const MountMotion at = MountMotionAt(x, T_Bs_, core::TimeToSeconds(ts_ns - t_ns));
    DrawDriftSinceLastScan(R_WS);
    Scan(input.world, at);
    const core::PoseMeasurement truth = frame_.TruePose(at);
    const core::PoseMeasurement measured = MeasuredScan(at, truth, R_WS);
    conditions_ = kConditionNone;
    if (geometry_.degenerate) conditions_ |= kDegenerate;
    if (geometry_.few_returns) conditions_ |= kFewReturns;
    out->push_back({ts_ns, ts_ns + latency_ns_, measured, truth, conditions_});
  }
}

void LidarOdometryModel::FollowPath(const MountMotion& now, const Eigen::Matrix3d& R_WS,
                                    double dt_s) {
  // Motion since the last step along the latest scan's eigen-directions.
  const Eigen::Vector3d step_W = now.p_Ws - previous_p_Ws_;
  previous_p_Ws_ = now.p_Ws;
  const Eigen::Vector3d rotation_W = now.R_Ws * now.omega_s_s * dt_s;
  distance_m_ += step_W.norm();
  if (have_geometry_) {
    for (int k = 0; k < 3; ++k) {
      translation_path_m_[k] += std::abs(geometry_.translation_directions_W.col(k).dot(step_W));
      rotation_path_rad_[k] += std::abs(geometry_.rotation_axes_W.col(k).dot(rotation_W));
    }
  }
  frame_.IntegratePath(R_WS.transpose() * step_W);
  // Too few returns: the filter diverges exponentially.
  if (diverging_) {
    v_div_S_ *= std::exp(dt_s / options_.divergence_time_constant_s);
    frame_.AddPositionError(v_div_S_ * dt_s);
  }
}

void LidarOdometryModel::DrawDriftSinceLastScan(const Eigen::Matrix3d& R_WS) {
  // Drift accumulated since the previous scan, along that scan's directions. Draws depend
  // on the options only (not on the geometry or the motion), so a seed gives the same
  // noise sequence whatever the robot does.
  const bool translation_walk = options_.position_random_walk_m_per_sqrtm > 0.0 ||
                                options_.degenerate_position_random_walk_m_per_sqrtm > 0.0;
  const bool rotation_walk = options_.rotation_random_walk_rad_per_sqrtm > 0.0 ||
                             options_.degenerate_rotation_random_walk_rad_per_sqrtrad > 0.0;
  if (have_geometry_) {
    Eigen::Vector3d drift_W = Eigen::Vector3d::Zero();
    Eigen::Vector3d theta_W = Eigen::Vector3d::Zero();
    for (int k = 0; k < 3; ++k) {
      if (translation_walk) {
        const double sigma_p = (geometry_.translation_degenerate[k]
                                    ? options_.degenerate_position_random_walk_m_per_sqrtm
                                    : options_.position_random_walk_m_per_sqrtm) *
                               std::sqrt(translation_path_m_[k]);
        drift_W += geometry_.translation_directions_W.col(k) * sigma_p * stream_.Normal();
      }
      if (rotation_walk) {
        const double sigma_r =
            geometry_.rotation_degenerate[k]
                ? options_.degenerate_rotation_random_walk_rad_per_sqrtrad *
                      std::sqrt(rotation_path_rad_[k])
                : options_.rotation_random_walk_rad_per_sqrtm * std::sqrt(distance_m_);
        theta_W += geometry_.rotation_axes_W.col(k) * sigma_r * stream_.Normal();
      }
    }
    frame_.AddPositionError(R_WS.transpose() * drift_W);
    frame_.RotateError(R_WS.transpose() * theta_W);
  }
  translation_path_m_.setZero();
  rotation_path_rad_.setZero();
  distance_m_ = 0.0;
}

void LidarOdometryModel::Scan(const World& world, const MountMotion& at) {
  Eigen::Isometry3d T_Ws = Eigen::Isometry3d::Identity();
  T_Ws.linear() = at.R_Ws;
  T_Ws.translation() = at.p_Ws;
  geometry_ = AnalyseScan(world, T_Ws, scan_index_++);
  have_geometry_ = true;
  if (geometry_.few_returns && !diverging_) {
    diverging_ = true;
    const double sigma = options_.divergence_velocity_mps;
    v_div_S_ = sigma * stream_.Normal3();
  } else if (!geometry_.few_returns) {
    diverging_ = false;
    v_div_S_.setZero();
  }
}

core::PoseMeasurement LidarOdometryModel::MeasuredScan(const MountMotion& at,
                                                       const core::PoseMeasurement& truth,
                                                       const Eigen::Matrix3d& R_WS) {
  // White registration noise N(0, H^-1) along the constrained eigen-directions of each
  // block: sigma_r sum_k u_k n_k / sqrt(lambda_k sigma_r^2).
  const double sigma_range = options_.range_noise_m;
  Eigen::Vector3d noise_p_W = Eigen::Vector3d::Zero();
  Eigen::Vector3d noise_theta_W = Eigen::Vector3d::Zero();
  if (sigma_range > 0.0) {
    for (int k = 0; k < 3; ++k) {
      const double n_p = stream_.Normal();
      const double n_r = stream_.Normal();
      if (!geometry_.translation_degenerate[k]) {
        noise_p_W += geometry_.translation_directions_W.col(k) * n_p /
                     std::sqrt(geometry_.translation_eigenvalues[k]);
      }
      if (!geometry_.rotation_degenerate[k]) {
        noise_theta_W += geometry_.rotation_axes_W.col(k) * n_r /
                         std::sqrt(geometry_.rotation_eigenvalues[k]);
      }
    }
  }
  core::PoseMeasurement measured = frame_.Measured(
      at, truth, Eigen::Vector3d(R_WS.transpose() * noise_p_W),
      sigma_range > 0.0 ? std::optional<Eigen::Vector3d>(at.R_Ws.transpose() * noise_theta_W)
                        : std::nullopt,
      v_div_S_);
  measured.covariance = ReportedCovariance(at, R_WS);
  AddTwistWhiteNoise(options_.velocity_noise_mps, options_.angular_rate_noise_radps, stream_,
                     &measured);
  measured.twist_covariance = ReportedTwistCovariance(at);
  return measured;
}

Eigen::Matrix<double, 6, 6> LidarOdometryModel::ReportedTwistCovariance(
    const MountMotion& at) const {
  // The velocity is the registration's (FAST-LIO's state), so along a degenerate
  // translation direction it is as unconstrained as the pose: the difference of two poses
  // one scan apart, each with the regularised std s_pos of ReportedCovariance, has the std
  // sqrt(2) s_pos rate_hz. The angular rate is the gyro's, which no geometry degrades.
  const double sigma_v = options_.velocity_noise_mps;
  const double sigma_degenerate_v =
      std::sqrt(2.0) * options_.max_reported_position_std_m * options_.rate_hz;
  // In s: sigma_v^2 I + sum over degenerate u_k of sigma_degenerate_v^2 (R_Ws^T u_k)(..)^T;
  // the isotropic part is not rotated, so a non-degenerate scan states it exactly.
  Eigen::Matrix3d velocity_covariance_s = sigma_v * sigma_v * Eigen::Matrix3d::Identity();
  for (int k = 0; k < 3; ++k) {
    if (!geometry_.translation_degenerate[k]) continue;
    const Eigen::Vector3d u_s = at.R_Ws.transpose() * geometry_.translation_directions_W.col(k);
    velocity_covariance_s += sigma_degenerate_v * sigma_degenerate_v * u_s * u_s.transpose();
  }
  Eigen::Matrix<double, 6, 6> covariance = Eigen::Matrix<double, 6, 6>::Zero();
  covariance.topLeftCorner<3, 3>() = velocity_covariance_s;
  covariance.bottomRightCorner<3, 3>() = options_.angular_rate_noise_radps *
                                         options_.angular_rate_noise_radps *
                                         Eigen::Matrix3d::Identity();
  return covariance;
}

Eigen::Matrix<double, 6, 6> LidarOdometryModel::ReportedCovariance(
    const MountMotion& at, const Eigen::Matrix3d& R_WS) const {
  // Regularised inverse information, mapped from W axes to [dtheta in s (right
  // perturbation); dp in S].
  Eigen::Matrix<double, 6, 1> prior_information;
  const double s_rot = options_.max_reported_rotation_std_rad;
  const double s_pos = options_.max_reported_position_std_m;
  prior_information << Eigen::Vector3d::Constant(1.0 / (s_rot * s_rot)),
      Eigen::Vector3d::Constant(1.0 / (s_pos * s_pos));
  Eigen::Matrix<double, 6, 6> information = geometry_.information_W;
  information.diagonal() += prior_information;
  const Eigen::Matrix<double, 6, 6> covariance_W =
      information.selfadjointView<Eigen::Lower>().ldlt().solve(
          Eigen::Matrix<double, 6, 6>::Identity());
  Eigen::Matrix<double, 6, 6> A = Eigen::Matrix<double, 6, 6>::Zero();
  A.topLeftCorner<3, 3>() = at.R_Ws.transpose();
  A.bottomRightCorner<3, 3>() = R_WS.transpose();
  const Eigen::Matrix<double, 6, 6> covariance = A * covariance_W * A.transpose();
  return 0.5 * (covariance + covariance.transpose());
}

}  // namespace tofu::sim
