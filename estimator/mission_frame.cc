#include "estimator/mission_frame.h"

#include <algorithm>
#include <cmath>
#include <utility>

#include "core/lie.h"

namespace tofu::estimator {
namespace {

Eigen::Matrix3d Rz(double yaw_rad) {
  return Eigen::AngleAxisd(yaw_rad, Eigen::Vector3d::UnitZ()).toRotationMatrix();
}

double WrapAngle(double angle_rad) { return std::remainder(angle_rad, 2.0 * core::kPi); }

}  // namespace

bool MissionFrameOptions::IsValid(std::string* why) const {
  auto fail = [why](std::string text) {
    if (why != nullptr) *why = std::move(text);
    return false;
  };
  if (!(window_ns > 0)) return fail("window_ns must be > 0");
  if (!(max_fit_chi2_per_dof > 0.0)) return fail("max_fit_chi2_per_dof must be > 0");
  if (!(max_source_std_m > 0.0)) return fail("max_source_std_m must be > 0");
  if (!(local_position_std_m >= 0.0)) return fail("local_position_std_m must be >= 0");
  if (!(drift_rate_std_mps > 0.0)) return fail("drift_rate_std_mps must be > 0");
  if (!(max_position_age_ns > 0)) return fail("max_position_age_ns must be > 0");
  if (min_pair_spacing_ns < 0) return fail("min_pair_spacing_ns must be >= 0");
  if (min_pairs < 3) return fail("min_pairs must be >= 3");
  if (!(min_span_ns >= 0 && min_span_ns < window_ns)) {
    return fail("min_span_ns must be in [0, window_ns)");
  }
  if (!(max_yaw_std_rad > 0.0)) return fail("max_yaw_std_rad must be > 0");
  if (!(max_rate_mps > 0.0)) return fail("max_rate_mps must be > 0");
  if (!(max_rate_radps > 0.0)) return fail("max_rate_radps must be > 0");
  if (!(launch_position_std_m >= 0.0) || !(launch_yaw_std_rad >= 0.0)) {
    return fail("launch stds must be >= 0");
  }
  return true;
}

Eigen::Isometry3d MissionFrameEstimate::T_ML() const {
  Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
  T.linear() = q_ML.normalized().toRotationMatrix();
  T.translation() = p_ML_m;
  return T;
}

double MissionFrameEstimate::yaw_rad() const {
  return core::YawOfNearestZRotation(q_ML.normalized().toRotationMatrix());
}

namespace {

MissionFrameEstimate FrameOf(double yaw_rad, const Eigen::Vector3d& p_ML_m,
                             const Eigen::Vector4d& variance) {
  MissionFrameEstimate frame;
  frame.q_ML = Eigen::Quaterniond(Eigen::AngleAxisd(yaw_rad, Eigen::Vector3d::UnitZ()));
  frame.p_ML_m = p_ML_m;
  frame.variance = variance;
  return frame;
}

}  // namespace

MissionFrame::MissionFrame(MissionFrameOptions options, MissionSurvey survey)
    : options_(std::move(options)), survey_(std::move(survey)) {}

bool MissionFrame::Surveyed(const std::string& sensor) const {
  return survey_.T_MS.count(sensor) != 0;
}

void MissionFrame::AddPair(const std::string& sensor, core::Time t_ns,
                           const Eigen::Vector3d& p_Ss, const Eigen::Vector3d& p_Ls,
                           const Eigen::Matrix3d& covariance_S) {
  if (!Surveyed(sensor)) return;
  std::deque<Pair>& pairs = pairs_[sensor];
  if (!pairs.empty() && t_ns - pairs.back().t_ns < options_.min_pair_spacing_ns) return;
  const double stated_m2 = covariance_S.trace() / 3.0;
  if (!(stated_m2 >= 0.0) || !std::isfinite(stated_m2)) return;
  const double variance_m2 = stated_m2 + options_.local_position_std_m * options_.local_position_std_m;
  if (!(variance_m2 > 0.0)) return;
  pairs.push_back({t_ns, p_Ss, p_Ls, stated_m2, 1.0 / variance_m2});
  while (!pairs.empty() && pairs.front().t_ns < t_ns - options_.window_ns) pairs.pop_front();
}

void MissionFrame::Forget(const std::string& sensor) { pairs_.erase(sensor); }

// The target a candidate's window gives: T_MS T_SL(now) from a weighted 4-DoF fit of its
// positions against the local estimate (below), if the window is fresh, precise (stated
// std) and explained by the fit (χ² per degree of freedom), with the variance of the
// robot's position in M and of the heading.
// Long by design: the gates (fresh, precise, explained) and the 4-DoF fit share the
// window's weighted sums; one sequence that reads against the derivation.
std::optional<MissionFrame::Target> MissionFrame::Fit(core::Time t_ns, const std::string& sensor,
                                                      const Eigen::Vector3d& p_LI,
                                                      double current_yaw_ML_rad) const {
  const auto it = pairs_.find(sensor);
  if (it == pairs_.end()) return std::nullopt;
  const std::deque<Pair>& pairs = it->second;
  if (static_cast<int>(pairs.size()) < options_.min_pairs ||
      pairs.back().t_ns - pairs.front().t_ns < options_.min_span_ns ||
      t_ns - pairs.back().t_ns > options_.max_position_age_ns) {
    return std::nullopt;
  }
  double stated_sum_m2 = 0.0;
  for (const Pair& p : pairs) stated_sum_m2 += p.stated_variance_m2;
  if (!(stated_sum_m2 / static_cast<double>(pairs.size()) <=
        options_.max_source_std_m * options_.max_source_std_m)) {
    return std::nullopt;
  }
  const Eigen::Isometry3d& T_MS = survey_.T_MS.at(sensor);
  const double yaw_MS_rad = core::YawOfNearestZRotation(T_MS.linear());
  double weight_sum = 0.0;
  Eigen::Vector3d c_L = Eigen::Vector3d::Zero();
  for (const Pair& p : pairs) {
    weight_sum += p.weight;
    c_L += p.weight * p.p_L;
  }
  c_L /= weight_sum;
  // The heading: Procrustes in the plane on the centred positions (rigid over the window:
  // L turns against S only with the odometry's yaw drift, a fraction of a degree a minute),
  // its variance 1 / Σ wᵢ |p_L,i − c_L|²_xy. Not fitted (the published heading kept) when
  // the motion's horizontal spread does not pin it to max_yaw_std_rad: a hover. A drift
  // fitted jointly with the heading is not used: along a straight line flown at constant
  // speed a turn of L and a sideways drift explain the positions alike, and such a fit
  // swung the heading by 6° in 1 s (closed_loop_corridor_occlusion).
  Target target;
  target.variance.w() = INFINITY;
  double yaw_SL_rad = current_yaw_ML_rad - yaw_MS_rad;
  double yaw_information = 0.0;
  for (const Pair& p : pairs) yaw_information += p.weight * (p.p_L - c_L).head<2>().squaredNorm();
  if (yaw_information * options_.max_yaw_std_rad * options_.max_yaw_std_rad >= 1.0) {
    Eigen::Vector3d c_S = Eigen::Vector3d::Zero();
    for (const Pair& p : pairs) c_S += p.weight * p.p_S;
    c_S /= weight_sum;
    double dot = 0.0;
    double cross = 0.0;
    for (const Pair& p : pairs) {
      const Eigen::Vector2d q_L = (p.p_L - c_L).head<2>();
      const Eigen::Vector2d q_S = (p.p_S - c_S).head<2>();
      dot += p.weight * q_L.dot(q_S);
      cross += p.weight * (q_L.x() * q_S.y() - q_L.y() * q_S.x());
    }
    yaw_SL_rad = std::atan2(cross, dot);
    target.variance.w() = 1.0 / yaw_information;
  }
  const Eigen::Matrix3d R_SL = Rz(yaw_SL_rad);

  // The translation now. L drifts against S while the odometries are fused (cm/s): with
  // the heading fixed, dᵢ = p_S,i − R p_L,i ≈ t + τᵢ v (τᵢ = tᵢ − now), a weighted linear
  // regression per axis with a prior v ~ N(0, σ_v²) (drift_rate_std_mps), taken at τ = 0
  // where a rigid fit (the window's middle) would lag the drift by half a window. The
  // variance of t there: [A⁻¹]₀₀ of A = [[Σw, Σwτ], [Σwτ, Σwτ² + 1/σ_v²]].
  double w_tau = 0.0;
  double w_tau2 = 1.0 / (options_.drift_rate_std_mps * options_.drift_rate_std_mps);
  Eigen::Vector3d w_d = Eigen::Vector3d::Zero();
  Eigen::Vector3d w_tau_d = Eigen::Vector3d::Zero();
  for (const Pair& p : pairs) {
    const double tau_s = core::TimeToSeconds(p.t_ns - t_ns);
    const Eigen::Vector3d d = p.p_S - R_SL * p.p_L;
    w_tau += p.weight * tau_s;
    w_tau2 += p.weight * tau_s * tau_s;
    w_d += p.weight * d;
    w_tau_d += p.weight * tau_s * d;
  }
  const double det = weight_sum * w_tau2 - w_tau * w_tau;
  const Eigen::Vector3d t_SL = (w_tau2 * w_d - w_tau * w_tau_d) / det;
  const Eigen::Vector3d v_SL = (weight_sum * w_tau_d - w_tau * w_d) / det;
  const double translation_variance = w_tau2 / det;

  // The window must be explained by one 4-DoF transform drifting at one velocity (with
  // the heading kept, a hover's heading error is no misfit: the positions barely move
  // across it).
  double chi2 = 0.0;
  for (const Pair& p : pairs) {
    const double tau_s = core::TimeToSeconds(p.t_ns - t_ns);
    chi2 += p.weight * (p.p_S - (R_SL * p.p_L + t_SL + tau_s * v_SL)).squaredNorm();
  }
  const double dof = 3.0 * static_cast<double>(pairs.size()) - 7.0;
  if (!(chi2 / dof <= options_.max_fit_chi2_per_dof)) return std::nullopt;
  target.yaw_rad = WrapAngle(yaw_MS_rad + yaw_SL_rad);
  target.p_M_of_robot = T_MS * (R_SL * p_LI + t_SL);
  // At the robot: the translation's variance and the heading's through the lever arm from
  // the centroid (about which the heading turns the fit).
  const double lever_m2 = (p_LI - c_L).head<2>().squaredNorm();
  const double heading_m2 = std::isfinite(target.variance.w()) ? target.variance.w() * lever_m2 : 0.0;
  target.variance.head<3>() = Eigen::Vector3d(translation_variance + heading_m2,
                                              translation_variance + heading_m2, translation_variance);
  return target;
}

void MissionFrame::Update(core::Time t_ns, const Eigen::Isometry3d& T_LI,
                          const std::vector<std::string>& candidates) {
  const Eigen::Vector3d p_LI = T_LI.translation();
  if (!published_ && survey_.T_MI_launch) {
    const Eigen::Isometry3d T_ML = core::YawPositionRegistration(*survey_.T_MI_launch, T_LI);
    const double position_variance = options_.launch_position_std_m * options_.launch_position_std_m;
    published_ = FrameOf(core::YawOfNearestZRotation(T_ML.linear()), T_ML.translation(),
                         Eigen::Vector4d(position_variance, position_variance, position_variance,
                                         options_.launch_yaw_std_rad * options_.launch_yaw_std_rad));
    last_update_ns_ = t_ns;
  }
  // The most certain candidate's fit, by its position variance at the robot.
  std::optional<Target> best;
  std::string best_sensor;
  const double current_yaw_rad = published_ ? published_->yaw_rad() : 0.0;
  for (const std::string& sensor : candidates) {
    if (!Surveyed(sensor)) continue;
    const std::optional<Target> target = Fit(t_ns, sensor, p_LI, current_yaw_rad);
    if (target && (!best || target->variance.head<3>().sum() < best->variance.head<3>().sum())) {
      best = target;
      best_sensor = sensor;
    }
  }
  source_ = best_sensor;
  if (!best) {
    last_update_ns_ = t_ns;
    return;
  }
  if (!published_) {
    // Nothing flown on yet (no launch pad): the first fit is the frame.
    Eigen::Vector4d variance = best->variance;
    if (!std::isfinite(variance.w())) variance.w() = core::kPi * core::kPi;
    published_ = FrameOf(best->yaw_rad, best->p_M_of_robot - Rz(best->yaw_rad) * p_LI, variance);
    last_update_ns_ = t_ns;
    return;
  }
  // Move towards the target: the robot's image in M at most max_rate_mps, the heading at
  // most max_rate_radps, both by the same fraction of the way.
  const MissionFrameEstimate& frame = *published_;
  const double dt_s = std::max(0.0, core::TimeToSeconds(t_ns - last_update_ns_));
  last_update_ns_ = t_ns;
  const double yaw_rad = frame.yaw_rad();
  const Eigen::Vector3d p_M_now = frame.T_ML() * p_LI;
  const Eigen::Vector3d step_m = best->p_M_of_robot - p_M_now;
  const double step_yaw_rad = WrapAngle(best->yaw_rad - yaw_rad);
  double fraction = 1.0;
  if (step_m.norm() > 0.0) fraction = std::min(fraction, options_.max_rate_mps * dt_s / step_m.norm());
  if (step_yaw_rad != 0.0) {
    fraction = std::min(fraction, options_.max_rate_radps * dt_s / std::abs(step_yaw_rad));
  }
  const double new_yaw_rad = WrapAngle(yaw_rad + fraction * step_yaw_rad);
  // Still on the way: the distance left is a known error of the published frame.
  const Eigen::Vector3d left_m = (1.0 - fraction) * step_m;
  const double left_yaw_rad = (1.0 - fraction) * step_yaw_rad;
  Eigen::Vector4d variance;
  variance.head<3>() = best->variance.head<3>() + left_m.cwiseAbs2();
  variance.w() = (std::isfinite(best->variance.w()) ? best->variance.w() : frame.variance.w()) +
                 left_yaw_rad * left_yaw_rad;
  published_ = FrameOf(new_yaw_rad, p_M_now + fraction * step_m - Rz(new_yaw_rad) * p_LI, variance);
}

}  // namespace tofu::estimator
