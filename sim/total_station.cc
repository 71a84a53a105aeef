#include "sim/total_station.h"

#include <cmath>
#include <stdexcept>
#include <utility>

namespace tofu::sim {

// ---- options ----

std::span<const core::OptionField<TotalStationOptions>> TotalStationOptions::Fields() {
  using F = core::OptionField<TotalStationOptions>;
  using R = core::NumberRule;
  using O = TotalStationOptions;
  static const F kFields[] = {
      F::Name("site", &O::site)
          .Doc("robot mount site of the prism"),
      F::Name("station_site", &O::station_site)
          .Doc("world site whose pose is the station frame S (instrument centre, z up, x = Hz "
               "zero)"),
      F::OptionalVector("station_position_m", &O::p_WS_m, R::Any("m"))
          .Doc("override of the station position in W; unset: station_site's"),
      F::OptionalAttitude("station_rpy_deg", &O::q_WS)
          .Doc("override of the station attitude in W; unset: station_site's"),
      F::Number("rate_hz", &O::rate_hz, R::PositiveAtMost(1000.0, "Hz"))
          .Doc("tracking output rate (MS60: up to 20 Hz)"),
      F::Number("latency_s", &O::latency_s, R::Between(0.0, 10.0, "s"))
          .Doc("delay from a measurement's stamp to its delivery"),
      F::Degrees("horizontal_angle_std_deg", &O::horizontal_angle_std_rad,
                 R::Between(0.0, 1.0, "deg"))
          .Doc("1-sigma noise of the horizontal (Hz) angle"),
      F::Degrees("vertical_angle_std_deg", &O::vertical_angle_std_rad,
                 R::Between(0.0, 1.0, "deg"))
          .Doc("1-sigma noise of the vertical (V) angle"),
      F::Number("distance_std_m", &O::distance_std_m, R::Between(0.0, 1.0, "m"))
          .Doc("constant part of the distance noise: sigma_d = distance_std_m + distance_std_ppm * "
               "1e-6 * d"),
      F::Number("distance_std_ppm", &O::distance_std_ppm, R::Between(0.0, 1000.0, "ppm"))
          .Doc("part of the distance noise proportional to the distance (see distance_std_m)"),
      F::Degrees("max_angular_rate_degps", &O::max_angular_rate_radps, R::Positive("deg/s"))
          .Doc("lock is lost when the prism's angular rate seen from the station exceeds this"),
      F::Number("search_delay_s", &O::search_delay_s, R::NonNegative("s"))
          .Doc("after a loss, re-lock once the prism has been visible and slower than the limit "
               "this long"),
      F::Number("prism_clearance_m", &O::prism_clearance_m, R::Between(0.0, 1.0, "m"))
          .Doc("a ray hit within this distance of the prism centre is the prism itself"),
  };
  return kFields;
}

bool TotalStationOptions::IsValid(std::string* why) const {
  return core::CheckOptionFields<TotalStationOptions>(*this, Fields(), why);
}
namespace {

// Position and velocity in W of a point fixed in B at p_Bs, at t + tau (rigid-body
// kinematics, second-order extrapolation over tau < one physics step):
//   p_Ws = p_WB + R_WB r,  v_Ws = v_WB + R_WB (omega x r),
//   a_Ws = a_WB + R_WB (alpha x r + omega x (omega x r)).
struct PointMotion {
  Eigen::Vector3d p_W;
  Eigen::Vector3d v_W;
};

PointMotion MountPointMotion(const TruthState& x, const Eigen::Vector3d& r, double tau_s) {
  const Eigen::Matrix3d R_WB = x.q_WB.toRotationMatrix();
  const Eigen::Vector3d& w = x.omega_WB_B;
  const Eigen::Vector3d p = x.p_WB + R_WB * r;
  const Eigen::Vector3d v = x.v_WB_W + R_WB * w.cross(r);
  const Eigen::Vector3d a = x.a_WB_W + R_WB * (x.alpha_WB_B.cross(r) + w.cross(w.cross(r)));
  return {p + v * tau_s + 0.5 * a * tau_s * tau_s, v + a * tau_s};
}

}  // namespace

TotalStationModel::TotalStationModel(std::string name, const TotalStationOptions& options,
                                     const World& world, uint64_t seed)
    : name_(std::move(name)),
      options_(core::ValidOptions(options, "total station '" + name_ + "'")),
      stream_(seed, "sensor/" + name_),
      period_ns_(core::PeriodFromRate(options.rate_hz)),
      latency_ns_(core::SecondsToTime(options.latency_s)),
      search_delay_ns_(core::SecondsToTime(options.search_delay_s)) {
  p_Bs_ = world.robot().Site(options_.site, "total station '" + name_ + "'").p_Bs;

  // Station pose: the world site, with the optional overrides.
  T_WS_ = Eigen::Isometry3d::Identity();
  if (!options_.p_WS_m || !options_.q_WS) {
    try {
      T_WS_ = world.SitePose_W(options_.station_site);
    } catch (const std::exception& e) {
      throw std::invalid_argument("total station '" + name_ + "': world has no site '" +
                                  options_.station_site + "' (" + e.what() + ")");
    }
  }
  if (options_.p_WS_m) T_WS_.translation() = *options_.p_WS_m;
  if (options_.q_WS) T_WS_.linear() = options_.q_WS->normalized().toRotationMatrix();
}

Eigen::Matrix3d TotalStationModel::CartesianCovariance(double hz_rad, double v_rad,
                                                       double d_m) const {
  const double ch = std::cos(hz_rad), sh = std::sin(hz_rad);
  const double cv = std::cos(v_rad), sv = std::sin(v_rad);
  Eigen::Matrix3d J;  // d p / d(Hz, V, d)
  J << -d_m * cv * sh, -d_m * sv * ch, cv * ch,  //
      d_m * cv * ch, -d_m * sv * sh, cv * sh,    //
      0.0, d_m * cv, sv;
  const double sigma_d = options_.distance_std_m + options_.distance_std_ppm * 1e-6 * d_m;
  const Eigen::Vector3d var(options_.horizontal_angle_std_rad * options_.horizontal_angle_std_rad,
                            options_.vertical_angle_std_rad * options_.vertical_angle_std_rad,
                            sigma_d * sigma_d);
  return J * var.asDiagonal() * J.transpose();
}

void TotalStationModel::Step(const SensorInput& input, std::vector<SensorSample>* out) {
  const TruthState& x = input.truth;
  const core::Time t_ns = x.t_ns;
  const core::Time dt_ns = input.world.timestep_ns();
  const Eigen::Vector3d p_WS = T_WS_.translation();
  const Eigen::Matrix3d R_WS = T_WS_.linear();

  // Angular rate of the prism seen from the station, every physics step (cheap):
  // omega_los = |v_perp| / d.
  const PointMotion now = MountPointMotion(x, p_Bs_, 0.0);
  const Eigen::Vector3d los_W = now.p_W - p_WS;
  const double d_now = los_W.norm();
  bool too_fast = false;
  if (d_now > 1e-9) {
    const Eigen::Vector3d u = los_W / d_now;
    const Eigen::Vector3d v_perp = now.v_W - u.dot(now.v_W) * u;
    too_fast = v_perp.norm() / d_now > options_.max_angular_rate_radps;
  }
  if (too_fast && track_ != Track::kLost) track_ = Track::kLost;

  // Samples whose time of validity falls in [t, t + dt).
  while (next_sample_ns_ < t_ns) next_sample_ns_ += period_ns_;
  for (; next_sample_ns_ < t_ns + dt_ns; next_sample_ns_ += period_ns_) {
    const core::Time ts_ns = next_sample_ns_;
    const PointMotion at = MountPointMotion(x, p_Bs_, core::TimeToSeconds(ts_ns - t_ns));
    const Eigen::Vector3d ray_W = at.p_W - p_WS;
    const double d_true = ray_W.norm();

    // Line of sight against the scene and the robot's own visual body; the prism's own
    // surface (within the clearance of its centre) does not block.
    const std::optional<RayHit> hit = input.world.CastRay(p_WS, ray_W, kRaySceneAndRobot);
    occluded_ = hit && hit->distance_m < d_true - options_.prism_clearance_m;

    switch (track_) {
      case Track::kLocked:
        if (occluded_) track_ = Track::kLost;
        break;
      case Track::kLost:
        if (!occluded_ && !too_fast) {
          track_ = Track::kSearching;
          search_start_ns_ = ts_ns;
        }
        break;
      case Track::kSearching:
        if (occluded_) {
          track_ = Track::kLost;
        } else if (ts_ns - search_start_ns_ >= search_delay_ns_) {
          track_ = Track::kLocked;
        }
        break;
    }
    if (track_ != Track::kLocked) continue;

    // Spherical coordinates of the prism in S, noise, back to Cartesian.
    const Eigen::Vector3d p_Ss = R_WS.transpose() * ray_W;
    const double hz = std::atan2(p_Ss.y(), p_Ss.x());
    const double v = std::atan2(p_Ss.z(), std::hypot(p_Ss.x(), p_Ss.y()));
    const double sigma_d = options_.distance_std_m + options_.distance_std_ppm * 1e-6 * d_true;
    const double hz_m = hz + options_.horizontal_angle_std_rad * stream_.Normal();
    const double v_m = v + options_.vertical_angle_std_rad * stream_.Normal();
    const double d_m = d_true + sigma_d * stream_.Normal();

    core::PositionMeasurement measured;
    measured.p_Ss = d_m * Eigen::Vector3d(std::cos(v_m) * std::cos(hz_m),
                                          std::cos(v_m) * std::sin(hz_m), std::sin(v_m));
    measured.covariance = CartesianCovariance(hz_m, v_m, d_m);
    core::PositionMeasurement truth;
    truth.p_Ss = p_Ss;
    truth.covariance = Eigen::Matrix3d::Zero();

    out->push_back({ts_ns, ts_ns + latency_ns_, measured, truth, kConditionNone});
  }

  switch (track_) {
    case Track::kLocked: conditions_ = kConditionNone; break;
    case Track::kLost: conditions_ = kLockLost | (occluded_ ? kOccluded : 0u); break;
    case Track::kSearching: conditions_ = kSearching; break;
  }
}

}  // namespace tofu::sim
