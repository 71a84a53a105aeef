#include "sim/vio.h"

#include <cmath>
#include <stdexcept>
#include <utility>

#include "core/lie.h"
#include "core/units.h"
#include "sim/mount_motion.h"
#include "sim/odometry_frame.h"

namespace tofu::sim {

// ---- options ----

std::span<const core::OptionField<VioOptions>> VioOptions::Fields() {
  using F = core::OptionField<VioOptions>;
  using R = core::NumberRule;
  static const F kFields[] = {
      F::Name("site", &VioOptions::site)
          .Doc("robot mount site of the camera (optical frame: z forward, x right, y down)"),
      F::OptionalVector("frame_position_m", &VioOptions::p_WS_m, R::Any("m"))
          .Doc("position of the odometry frame S in W; unset: the camera's position at t = 0"),
      F::OptionalAttitude("frame_rpy_deg", &VioOptions::q_WS)
          .Doc("attitude of the odometry frame S in W; unset: the camera's attitude at t = 0"),
      F::Number("rate_hz", &VioOptions::rate_hz, R::PositiveAtMost(10000.0, "Hz"))
          .Doc("pose output rate (T265 pose stream: 200 Hz)"),
      F::Number("latency_s", &VioOptions::latency_s, R::Between(0.0, 10.0, "s"))
          .Doc("delay from a pose's stamp to its delivery"),
      F::Number("position_random_walk_m_per_sqrtm", &VioOptions::position_random_walk_m_per_sqrtm,
                R::NonNegative("m/sqrt(m)"))
          .Doc("position drift per axis of S: sigma_p = this * sqrt(distance travelled)"),
      F::Degrees("yaw_random_walk_deg_per_sqrtm", &VioOptions::yaw_random_walk_rad_per_sqrtm,
                 R::NonNegative("deg/sqrt(m)"))
          .Doc("heading (rotation about gravity) drift: sigma_yaw = this * sqrt(distance "
               "travelled)"),
      F::Degrees("tilt_random_walk_deg_per_sqrtm", &VioOptions::tilt_random_walk_rad_per_sqrtm,
                 R::NonNegative("deg/sqrt(m)"))
          .Doc("roll/pitch drift per horizontal axis: sigma = this * sqrt(distance travelled)"),
      F::Number("position_noise_m", &VioOptions::position_noise_m, R::NonNegative("m"))
          .Doc("white position noise per axis of S (not accumulated)"),
      F::Degrees("rotation_noise_deg", &VioOptions::rotation_noise_rad, R::NonNegative("deg"))
          .Doc("white rotation noise per axis, a right perturbation (not accumulated)"),
      F::Number("velocity_noise_mps", &VioOptions::velocity_noise_mps, R::NonNegative("m/s"))
          .Doc("white velocity noise per axis of the camera frame s"),
      F::Degrees("angular_rate_noise_degps", &VioOptions::angular_rate_noise_radps,
                 R::NonNegative("deg/s"))
          .Doc("white angular-rate noise per axis of the camera frame s"),
      F::Number("feature_check_rate_hz", &VioOptions::feature_check_rate_hz,
                R::PositiveAtMost(1000.0, "Hz"))
          .Doc("rate of the feature-availability check (a grid of rays through the field of view)"),
      F::Integer("feature_grid_columns", &VioOptions::feature_grid_columns, 1, 64)
          .Doc("columns of the grid of rays through the usable field of view"),
      F::Integer("feature_grid_rows", &VioOptions::feature_grid_rows, 1, 64)
          .Doc("rows of the grid of rays through the usable field of view"),
      F::Degrees("feature_fov_horizontal_deg", &VioOptions::feature_fov_horizontal_rad,
                 R::Between(1.0, 179.0, "deg"))
          .Doc("usable horizontal field of view of the fisheye pair (the rim carries few "
               "features)"),
      F::Degrees("feature_fov_vertical_deg", &VioOptions::feature_fov_vertical_rad,
                 R::Between(1.0, 179.0, "deg"))
          .Doc("usable vertical field of view of the fisheye pair"),
      F::Number("feature_min_depth_m", &VioOptions::feature_min_depth_m, R::NonNegative("m"))
          .Doc("a textured hit nearer than this along the ray is no feature (out of focus, no "
               "stereo overlap)"),
      F::Number("feature_max_depth_m", &VioOptions::feature_max_depth_m, R::Positive("m"))
          .Doc("a textured hit farther than this along the ray is no feature (too little "
               "parallax)"),
      F::Number("starved_score_threshold", &VioOptions::starved_score_threshold,
                R::Between(0.0, 1.0, ""))
          .Doc("score (fraction of rays with a feature) below which tracking is starved"),
      F::Number("starved_drift_factor", &VioOptions::starved_drift_factor,
                R::Between(1.0, 1000.0, ""))
          .Doc("drift rates are multiplied by this while starved (score > 0 but below the "
               "threshold)"),
      F::Degrees("blur_angular_rate_degps", &VioOptions::blur_angular_rate_radps,
                 R::Positive("deg/s"))
          .Doc("camera angular rate beyond which the images blur"),
      F::Number("blur_drift_factor", &VioOptions::blur_drift_factor, R::Between(1.0, 1000.0, ""))
          .Doc("drift multiplier while the images are blurred"),
      F::Number("lost_velocity_random_walk_mps_per_sqrts",
                &VioOptions::lost_velocity_random_walk_mps_per_sqrts, R::NonNegative("m/s/sqrt(s)"))
          .Doc("with no feature at all: random walk in time of the velocity error per axis, "
               "integrated into position"),
      F::Number("reset_after_s", &VioOptions::reset_after_s, R::NonNegative("s"))
          .Doc("the tracker resets after the score has been zero this long"),
      F::Number("reset_jump_position_m", &VioOptions::reset_jump_position_m, R::NonNegative("m"))
          .Doc("std of the position jump per axis at a tracker reset"),
      F::Degrees("reset_jump_yaw_deg", &VioOptions::reset_jump_yaw_rad, R::NonNegative("deg"))
          .Doc("std of the jump about gravity at a tracker reset"),
      F::Number("reported_pose_variance_base", &VioOptions::reported_pose_variance_base,
                R::Positive("m^2 or rad^2"))
          .Doc("reported pose covariance diagonal = this * 10^(3 - c) for tracker confidence c in "
               "0..3"),
      F::Number("reported_twist_variance_base", &VioOptions::reported_twist_variance_base,
                R::Positive("(m/s)^2 or (rad/s)^2"))
          .Doc("reported twist covariance diagonal = this * 10^(1 - c) for tracker confidence c"),
  };
  return kFields;
}

bool VioOptions::IsValid(std::string* why) const {
  if (!core::CheckOptionFields<VioOptions>(*this, Fields(), why)) return false;
  if (!(feature_min_depth_m < feature_max_depth_m)) {
    if (why != nullptr) *why = "feature_max_depth_m: must be greater than feature_min_depth_m";
    return false;
  }
  return true;
}

VioModel::VioModel(std::string name, const VioOptions& options, const World& world,
                   uint64_t seed)
    : name_(std::move(name)),
      options_(core::ValidOptions(options, "vio '" + name_ + "'")),
      stream_(seed, "sensor/" + name_),
      T_Bs_(world.robot().Site(options_.site, "vio '" + name_ + "'").T_Bs()),
      period_ns_(core::PeriodFromRate(options.rate_hz)),
      latency_ns_(core::SecondsToTime(options.latency_s)),
      feature_period_ns_(core::PeriodFromRate(options.feature_check_rate_hz)),
      reset_after_ns_(core::SecondsToTime(options.reset_after_s)),
      frame_(options_.p_WS_m, options_.q_WS) {

  // Equiangular grid over the usable FOV, cell centres: azimuth a about y (image right
  // positive), elevation e about x (image down positive), u = [sin a cos e, sin e, cos a cos e].
  const int columns = options_.feature_grid_columns;
  const int rows = options_.feature_grid_rows;
  const double h = options_.feature_fov_horizontal_rad;
  const double v = options_.feature_fov_vertical_rad;
  ray_directions_s_.reserve(static_cast<size_t>(columns * rows));
  for (int j = 0; j < rows; ++j) {
    const double e = -0.5 * v + v * (j + 0.5) / rows;
    for (int i = 0; i < columns; ++i) {
      const double a = -0.5 * h + h * (i + 0.5) / columns;
      ray_directions_s_.emplace_back(std::sin(a) * std::cos(e), std::sin(e),
                                     std::cos(a) * std::cos(e));
    }
  }
}

double VioModel::FeatureScore(const World& world, const Eigen::Isometry3d& T_Ws) const {
  const Eigen::Vector3d origin_W = T_Ws.translation();
  const Eigen::Matrix3d R_Ws = T_Ws.linear();
  int features = 0;
  const RayFan rays = world.RaysFrom(origin_W, kRayScene);
  for (const Eigen::Vector3d& u_s : ray_directions_s_) {
    const std::optional<RayHit> hit = rays.Cast(R_Ws * u_s);
    if (hit && hit->textured && hit->distance_m >= options_.feature_min_depth_m &&
        hit->distance_m <= options_.feature_max_depth_m) {
      ++features;
    }
  }
  return static_cast<double>(features) / static_cast<double>(ray_directions_s_.size());
}

void VioModel::Step(const SensorInput& input, std::vector<SensorSample>* out) {
  const TruthState& x = input.truth;
  const core::Time t_ns = x.t_ns;
  const core::Time dt_ns = input.world.timestep_ns();
  const MountMotion now = MountMotionAt(x, T_Bs_, 0.0);

  const bool first_step = frame_.Boot(now);
  const Eigen::Matrix3d R_WS = frame_.T_WS().linear();
  const Eigen::Vector3d p_WS = frame_.T_WS().translation();
  const Eigen::Vector3d p_Ss = R_WS.transpose() * (now.p_Ws - p_WS);
  if (first_step) previous_p_Ss_ = p_Ss;

  // A reset is flagged from the step it happens until the step its sample went out.
  if (reset_reported_) {
    reset_pending_ = false;
    reset_reported_ = false;
  }

  const Tracking tracking = UpdateTracking(input.world, now, t_ns, dt_ns);
  WalkWithDistance(p_Ss, R_WS, tracking);
  if (lost_) DeadReckonWhileLost(t_ns, core::TimeToSeconds(dt_ns), R_WS);

  conditions_ = kConditionNone;
  if (tracking.starved) conditions_ |= kFeatureStarved;
  if (lost_) conditions_ |= kLockLost;
  if (tracking.blurred) conditions_ |= kMotionBlur;
  if (reset_pending_) conditions_ |= kTrackerReset;

  // Tracker confidence as the T265 reports it: 3 high, 2 medium, 1 low, 0 failed.
  const int confidence = lost_ ? 0 : (tracking.starved ? 1 : (tracking.blurred ? 2 : 3));

  // Samples whose time of validity falls in [t, t + dt).
  while (next_sample_ns_ < t_ns) next_sample_ns_ += period_ns_;
  for (; next_sample_ns_ < t_ns + dt_ns; next_sample_ns_ += period_ns_) {
    const core::Time ts_ns = next_sample_ns_;
    const MountMotion at = MountMotionAt(x, T_Bs_, core::TimeToSeconds(ts_ns - t_ns));
    const core::PoseMeasurement truth = frame_.TruePose(at);
    out->push_back({ts_ns, ts_ns + latency_ns_, MeasuredPose(at, truth, confidence), truth,
                    conditions_});
    if (reset_pending_) reset_reported_ = true;
  }
}

VioModel::Tracking VioModel::UpdateTracking(const World& world, const MountMotion& now,
                                            core::Time t_ns, core::Time dt_ns) {
  // Feature check at its own rate (ray casts are the expensive part).
  if (next_feature_check_ns_ < t_ns + dt_ns) {
    Eigen::Isometry3d T_Ws = Eigen::Isometry3d::Identity();
    T_Ws.linear() = now.R_Ws;
    T_Ws.translation() = now.p_Ws;
    feature_score_ = FeatureScore(world, T_Ws);
    while (next_feature_check_ns_ < t_ns + dt_ns) next_feature_check_ns_ += feature_period_ns_;
  }
  Tracking tracking;
  tracking.starved = feature_score_ < options_.starved_score_threshold;
  tracking.blurred = now.omega_s_s.norm() > options_.blur_angular_rate_radps;
  const bool lost_now = feature_score_ <= 0.0;
  if (lost_now && !lost_) lost_since_ns_ = t_ns;
  if (!lost_now) b_v_S_.setZero();  // tracking resumed: the velocity is observed again
  lost_ = lost_now;
  return tracking;
}

void VioModel::WalkWithDistance(const Eigen::Vector3d& p_Ss, const Eigen::Matrix3d& R_WS,
                                const Tracking& tracking) {
  // Distance-driven drift, inflated by the active degradations.
  double factor = 1.0;
  if (tracking.starved) factor *= options_.starved_drift_factor;
  if (tracking.blurred) factor *= options_.blur_drift_factor;
  const Eigen::Vector3d step_S = p_Ss - previous_p_Ss_;
  previous_p_Ss_ = p_Ss;
  const double step_m = step_S.norm();
  frame_.IntegratePath(step_S);
  // Random walks in distance. Draws depend on the options only (not on the motion), so a
  // seed gives the same noise sequence whatever the robot does.
  const double root = factor * std::sqrt(step_m);
  if (options_.position_random_walk_m_per_sqrtm > 0.0) {
    frame_.AddPositionError(options_.position_random_walk_m_per_sqrtm * root * stream_.Normal3());
  }
  const double sigma_yaw = options_.yaw_random_walk_rad_per_sqrtm * root;
  const double sigma_tilt = options_.tilt_random_walk_rad_per_sqrtm * root;
  if (options_.yaw_random_walk_rad_per_sqrtm > 0.0 ||
      options_.tilt_random_walk_rad_per_sqrtm > 0.0) {
    // Gravity axis and two horizontal axes of S.
    const Eigen::Vector3d g_S = R_WS.transpose() * Eigen::Vector3d::UnitZ();
    const Eigen::Vector3d h1_S = R_WS.transpose() * Eigen::Vector3d::UnitX();
    const Eigen::Vector3d h2_S = R_WS.transpose() * Eigen::Vector3d::UnitY();
    const Eigen::Vector3d dtheta_S = sigma_yaw * stream_.Normal() * g_S +
                                     sigma_tilt * stream_.Normal() * h1_S +
                                     sigma_tilt * stream_.Normal() * h2_S;
    frame_.RotateError(dtheta_S);
  }
}

void VioModel::DeadReckonWhileLost(core::Time t_ns, double dt_s, const Eigen::Matrix3d& R_WS) {
  // No feature at all: IMU-only dead reckoning, the velocity error walks away; after
  // reset_after_s the tracker relocalises with a pose jump.
  const double sigma_b = options_.lost_velocity_random_walk_mps_per_sqrts * std::sqrt(dt_s);
  if (sigma_b > 0.0) {
    b_v_S_ += sigma_b * stream_.Normal3();
  }
  frame_.AddPositionError(b_v_S_ * dt_s);
  if (t_ns - lost_since_ns_ < reset_after_ns_) return;
  const double jump_p = options_.reset_jump_position_m;
  const double jump_yaw = options_.reset_jump_yaw_rad;
  if (jump_p > 0.0) {
    frame_.AddPositionError(jump_p * stream_.Normal3());
  }
  if (jump_yaw > 0.0) {
    const Eigen::Vector3d g_S = R_WS.transpose() * Eigen::Vector3d::UnitZ();
    frame_.RotateError(jump_yaw * stream_.Normal() * g_S);
  }
  b_v_S_.setZero();
  lost_since_ns_ = t_ns;  // still no features: diverges again, resets again
  reset_pending_ = true;
}

core::PoseMeasurement VioModel::MeasuredPose(const MountMotion& at,
                                             const core::PoseMeasurement& truth,
                                             int confidence) {
  std::optional<Eigen::Vector3d> position_noise_S;
  if (options_.position_noise_m > 0.0) {
    position_noise_S = options_.position_noise_m * stream_.Normal3();
  }
  std::optional<Eigen::Vector3d> rotation_noise_s;
  if (options_.rotation_noise_rad > 0.0) {
    rotation_noise_s = options_.rotation_noise_rad * stream_.Normal3();
  }
  core::PoseMeasurement measured =
      frame_.Measured(at, truth, position_noise_S, rotation_noise_s,
                      lost_ ? std::optional<Eigen::Vector3d>(b_v_S_) : std::nullopt);
  AddTwistWhiteNoise(options_.velocity_noise_mps, options_.angular_rate_noise_radps, stream_,
                     &measured);
  // The covariance a T265 reports: a confidence level, not an error bound.
  measured.covariance = options_.reported_pose_variance_base * std::pow(10.0, 3 - confidence) *
                        Eigen::Matrix<double, 6, 6>::Identity();
  measured.twist_covariance = options_.reported_twist_variance_base *
                              std::pow(10.0, 1 - confidence) *
                              Eigen::Matrix<double, 6, 6>::Identity();
  return measured;
}

}  // namespace tofu::sim
