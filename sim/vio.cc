#include "sim/vio.h"

#include <cmath>
#include <stdexcept>
#include <utility>

#include "core/lie.h"
#include "core/units.h"
#include "sim/mount_motion.h"

namespace tofu::sim {

// ---- options ----

std::span<const core::OptionField<VioOptions>> VioOptions::Fields() {
  using F = core::OptionField<VioOptions>;
  using R = core::NumberRule;
  static const F kFields[] = {
      F::Name("site", &VioOptions::site),
      F::OptionalVector("frame_position_m", &VioOptions::p_WS_m, R::Any("m")),
      F::OptionalAttitude("frame_rpy_deg", &VioOptions::q_WS),
      F::Number("rate_hz", &VioOptions::rate_hz, R::PositiveAtMost(10000.0, "Hz")),
      F::Number("latency_s", &VioOptions::latency_s, R::Between(0.0, 10.0, "s")),
      F::Number("position_random_walk_m_per_sqrtm", &VioOptions::position_random_walk_m_per_sqrtm,
                R::NonNegative("m/sqrt(m)")),
      F::Degrees("yaw_random_walk_deg_per_sqrtm", &VioOptions::yaw_random_walk_rad_per_sqrtm,
                 R::NonNegative("deg/sqrt(m)")),
      F::Degrees("tilt_random_walk_deg_per_sqrtm", &VioOptions::tilt_random_walk_rad_per_sqrtm,
                 R::NonNegative("deg/sqrt(m)")),
      F::Number("position_noise_m", &VioOptions::position_noise_m, R::NonNegative("m")),
      F::Degrees("rotation_noise_deg", &VioOptions::rotation_noise_rad, R::NonNegative("deg")),
      F::Number("velocity_noise_mps", &VioOptions::velocity_noise_mps, R::NonNegative("m/s")),
      F::Degrees("angular_rate_noise_degps", &VioOptions::angular_rate_noise_radps,
                 R::NonNegative("deg/s")),
      F::Number("feature_check_rate_hz", &VioOptions::feature_check_rate_hz,
                R::PositiveAtMost(1000.0, "Hz")),
      F::Integer("feature_grid_columns", &VioOptions::feature_grid_columns, 1, 64),
      F::Integer("feature_grid_rows", &VioOptions::feature_grid_rows, 1, 64),
      F::Degrees("feature_fov_horizontal_deg", &VioOptions::feature_fov_horizontal_rad,
                 R::Between(1.0, 179.0, "deg")),
      F::Degrees("feature_fov_vertical_deg", &VioOptions::feature_fov_vertical_rad,
                 R::Between(1.0, 179.0, "deg")),
      F::Number("feature_min_depth_m", &VioOptions::feature_min_depth_m, R::NonNegative("m")),
      F::Number("feature_max_depth_m", &VioOptions::feature_max_depth_m, R::Positive("m")),
      F::Number("starved_score_threshold", &VioOptions::starved_score_threshold,
                R::Between(0.0, 1.0, "")),
      F::Number("starved_drift_factor", &VioOptions::starved_drift_factor,
                R::Between(1.0, 1000.0, "")),
      F::Degrees("blur_angular_rate_degps", &VioOptions::blur_angular_rate_radps,
                 R::Positive("deg/s")),
      F::Number("blur_drift_factor", &VioOptions::blur_drift_factor, R::Between(1.0, 1000.0, "")),
      F::Number("lost_velocity_random_walk_mps_per_sqrts",
                &VioOptions::lost_velocity_random_walk_mps_per_sqrts, R::NonNegative("m/s/sqrt(s)")),
      F::Number("reset_after_s", &VioOptions::reset_after_s, R::NonNegative("s")),
      F::Number("reset_jump_position_m", &VioOptions::reset_jump_position_m, R::NonNegative("m")),
      F::Degrees("reset_jump_yaw_deg", &VioOptions::reset_jump_yaw_rad, R::NonNegative("deg")),
      F::Number("reported_pose_variance_base", &VioOptions::reported_pose_variance_base,
                R::Positive("m^2 or rad^2")),
      F::Number("reported_twist_variance_base", &VioOptions::reported_twist_variance_base,
                R::Positive("(m/s)^2 or (rad/s)^2")),
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
namespace {

using core::kPi;

void Require(bool ok, const std::string& name, const std::string& what) {
  if (!ok) throw std::invalid_argument("vio '" + name + "': " + what);
}

}  // namespace

VioModel::VioModel(std::string name, const VioOptions& options, const World& world,
                   uint64_t seed)
    : name_(std::move(name)),
      options_(core::ValidOptions(options, "vio '" + name_ + "'")),
      stream_(seed, "sensor/" + name_),
      period_ns_(core::PeriodFromRate(options.rate_hz)),
      latency_ns_(core::SecondsToTime(options.latency_s)),
      feature_period_ns_(core::PeriodFromRate(options.feature_check_rate_hz)),
      reset_after_ns_(core::SecondsToTime(options.reset_after_s)) {
  const MountSite* mount = world.robot().FindSite(options_.site);
  Require(mount != nullptr, name_, "robot has no site '" + options_.site + "'");
  T_Bs_ = Eigen::Isometry3d::Identity();
  T_Bs_.translation() = mount->p_Bs;
  T_Bs_.linear() = mount->q_Bs.normalized().toRotationMatrix();

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

  // A configured frame is known now; an unconfigured part is latched at the first step.
  if (options_.p_WS_m) T_WS_.translation() = *options_.p_WS_m;
  if (options_.q_WS) T_WS_.linear() = options_.q_WS->normalized().toRotationMatrix();
}

double VioModel::FeatureScore(const World& world, const Eigen::Isometry3d& T_Ws) const {
  const Eigen::Vector3d origin_W = T_Ws.translation();
  const Eigen::Matrix3d R_Ws = T_Ws.linear();
  int features = 0;
  for (const Eigen::Vector3d& u_s : ray_directions_s_) {
    const std::optional<RayHit> hit = world.CastRay(origin_W, R_Ws * u_s, kRayScene);
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
  const double dt_s = core::TimeToSeconds(dt_ns);
  const MountMotion now = MountMotionAt(x, T_Bs_, 0.0);

  // The odometry frame starts where the camera boots (unless configured).
  const bool first_step = !started_;
  if (first_step) {
    if (!options_.p_WS_m) T_WS_.translation() = now.p_Ws;
    if (!options_.q_WS) T_WS_.linear() = now.R_Ws;
    started_ = true;
  }
  const Eigen::Matrix3d R_WS = T_WS_.linear();
  const Eigen::Vector3d p_WS = T_WS_.translation();
  const Eigen::Vector3d p_Ss = R_WS.transpose() * (now.p_Ws - p_WS);
  if (first_step) previous_p_Ss_ = p_Ss;

  // A reset is flagged from the step it happens until the step its sample went out.
  if (reset_reported_) {
    reset_pending_ = false;
    reset_reported_ = false;
  }

  // Feature check at its own rate (ray casts are the expensive part).
  if (next_feature_check_ns_ < t_ns + dt_ns) {
    Eigen::Isometry3d T_Ws = Eigen::Isometry3d::Identity();
    T_Ws.linear() = now.R_Ws;
    T_Ws.translation() = now.p_Ws;
    feature_score_ = FeatureScore(input.world, T_Ws);
    while (next_feature_check_ns_ < t_ns + dt_ns) next_feature_check_ns_ += feature_period_ns_;
  }
  const bool starved = feature_score_ < options_.starved_score_threshold;
  const bool blurred = now.omega_s_s.norm() > options_.blur_angular_rate_radps;
  const bool lost_now = feature_score_ <= 0.0;
  if (lost_now && !lost_) lost_since_ns_ = t_ns;
  if (!lost_now) b_v_S_.setZero();  // tracking resumed: the velocity is observed again
  lost_ = lost_now;

  // Distance-driven drift, inflated by the active degradations.
  double factor = 1.0;
  if (starved) factor *= options_.starved_drift_factor;
  if (blurred) factor *= options_.blur_drift_factor;
  const Eigen::Vector3d step_S = p_Ss - previous_p_Ss_;
  previous_p_Ss_ = p_Ss;
  const double step_m = step_S.norm();
  // The path is integrated with the drifted attitude: dp += (R_err - I) dp_Ss.
  dp_S_ += (R_err_ - Eigen::Matrix3d::Identity()) * step_S;
  // Random walks in distance. Draws depend on the options only (not on the motion), so a
  // seed gives the same noise sequence whatever the robot does.
  {
    const double root = factor * std::sqrt(step_m);
    if (options_.position_random_walk_m_per_sqrtm > 0.0) {
      dp_S_ += options_.position_random_walk_m_per_sqrtm * root *
               stream_.Normal3();
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
      R_err_ = core::ExpSO3(dtheta_S) * R_err_;
    }
  }

  // No feature at all: IMU-only dead reckoning, the velocity error walks away; after
  // reset_after_s the tracker relocalises with a pose jump.
  if (lost_) {
    const double sigma_b = options_.lost_velocity_random_walk_mps_per_sqrts * std::sqrt(dt_s);
    if (sigma_b > 0.0) {
      b_v_S_ += sigma_b * stream_.Normal3();
    }
    dp_S_ += b_v_S_ * dt_s;
    if (t_ns - lost_since_ns_ >= reset_after_ns_) {
      const double jump_p = options_.reset_jump_position_m;
      const double jump_yaw = options_.reset_jump_yaw_rad;
      if (jump_p > 0.0) {
        dp_S_ += jump_p * stream_.Normal3();
      }
      if (jump_yaw > 0.0) {
        const Eigen::Vector3d g_S = R_WS.transpose() * Eigen::Vector3d::UnitZ();
        R_err_ = core::ExpSO3(jump_yaw * stream_.Normal() * g_S) * R_err_;
      }
      b_v_S_.setZero();
      lost_since_ns_ = t_ns;  // still no features: diverges again, resets again
      reset_pending_ = true;
    }
  }

  conditions_ = kConditionNone;
  if (starved) conditions_ |= kFeatureStarved;
  if (lost_) conditions_ |= kLockLost;
  if (blurred) conditions_ |= kMotionBlur;
  if (reset_pending_) conditions_ |= kTrackerReset;

  // Tracker confidence as the T265 reports it: 3 high, 2 medium, 1 low, 0 failed.
  const int confidence = lost_ ? 0 : (starved ? 1 : (blurred ? 2 : 3));
  const double pose_variance =
      options_.reported_pose_variance_base * std::pow(10.0, 3 - confidence);
  const double twist_variance =
      options_.reported_twist_variance_base * std::pow(10.0, 1 - confidence);

  // Samples whose time of validity falls in [t, t + dt).
  while (next_sample_ns_ < t_ns) next_sample_ns_ += period_ns_;
  for (; next_sample_ns_ < t_ns + dt_ns; next_sample_ns_ += period_ns_) {
    const core::Time ts_ns = next_sample_ns_;
    const MountMotion at = MountMotionAt(x, T_Bs_, core::TimeToSeconds(ts_ns - t_ns));

    const core::PoseMeasurement truth = TruePose(at, R_WS, p_WS);
    const Eigen::Matrix3d R_Ss = R_WS.transpose() * at.R_Ws;

    core::PoseMeasurement measured;
    const Eigen::Matrix3d R_hat = R_err_ * R_Ss;
    measured.p_Ss = truth.p_Ss + dp_S_;
    Eigen::Matrix3d R_meas = R_hat;
    if (options_.position_noise_m > 0.0) {
      measured.p_Ss += options_.position_noise_m *
                       stream_.Normal3();
    }
    if (options_.rotation_noise_rad > 0.0) {
      R_meas = R_hat * core::ExpSO3(options_.rotation_noise_rad *
                                    stream_.Normal3());
    }
    measured.q_Ss = core::CanonicalQuat(Eigen::Quaterniond(R_meas));
    measured.covariance = pose_variance * Eigen::Matrix<double, 6, 6>::Identity();
    measured.has_twist = true;
    measured.v_s_s_mps = truth.v_s_s_mps;
    if (lost_) measured.v_s_s_mps += R_hat.transpose() * b_v_S_;
    measured.omega_s_s_radps = truth.omega_s_s_radps;
    AddTwistWhiteNoise(options_.velocity_noise_mps, options_.angular_rate_noise_radps, stream_,
                       &measured);
    measured.twist_covariance = twist_variance * Eigen::Matrix<double, 6, 6>::Identity();

    SensorSample sample;
    sample.t_ns = ts_ns;
    sample.arrival_ns = ts_ns + latency_ns_;
    sample.measured = measured;
    sample.truth = truth;
    sample.conditions = conditions_;
    out->push_back(std::move(sample));
    if (reset_pending_) reset_reported_ = true;
  }
}

}  // namespace tofu::sim
