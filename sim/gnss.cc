#include "sim/gnss.h"

#include <algorithm>
#include <cmath>
#include <stdexcept>
#include <utility>

#include <fmt/format.h>

#include "core/units.h"

namespace tofu::sim {

// ---- options ----

std::span<const core::OptionField<GnssFixErrorOptions>> GnssFixErrorOptions::Fields() {
  using F = core::OptionField<GnssFixErrorOptions>;
  using R = core::NumberRule;
  using O = GnssFixErrorOptions;
  static const F kFields[] = {
      F::Number("std_horizontal_m", &O::std_horizontal_m, R::Positive("m"))
          .Doc("reported 1-sigma per horizontal axis (E, N)"),
      F::Number("std_vertical_m", &O::std_vertical_m, R::Positive("m"))
          .Doc("reported 1-sigma on U"),
      F::Number("correlated_fraction", &O::correlated_fraction, R::Between(0.0, 1.0, ""))
          .Doc("share of the variance in the Gauss-Markov (correlated) part"),
      F::Number("correlation_time_s", &O::correlation_time_s, R::Positive("s"))
          .Doc("time constant of the Gauss-Markov part"),
      F::Number("multipath_std_m", &O::multipath_std_m, R::NonNegative("m"))
          .Doc("std per axis of the Gauss-Markov multipath error, scaled by the blocked sky "
               "fraction"),
  };
  return kFields;
}

bool GnssFixErrorOptions::IsValid(std::string* why) const {
  return core::CheckOptionFields<GnssFixErrorOptions>(*this, Fields(), why);
}

std::span<const core::OptionField<GnssOptions>> GnssOptions::Fields() {
  using F = core::OptionField<GnssOptions>;
  using R = core::NumberRule;
  using O = GnssOptions;
  static const F kFields[] = {
      F::Name("site", &O::site)
          .Doc("robot mount site of the antenna phase centre"),
      F::Number("rate_hz", &O::rate_hz, R::PositiveAtMost(100.0, "Hz"))
          .Doc("RTK output rate (F9P: up to 20 Hz RTK)"),
      F::Number("latency_s", &O::latency_s, R::Between(0.0, 10.0, "s"))
          .Doc("delay from a fix's stamp to its delivery"),
      F::Vector("enu_origin_m", &O::enu_origin_W_m, R::Any("m"))
          .Doc("origin of the ENU frame S in W"),
      F::Degrees("enu_yaw_deg", &O::enu_yaw_rad, R::Between(-360.0, 360.0, "deg"))
          .Doc("yaw of E from x_W (S's z is W's z)"),
      F::Integer("satellite_count", &O::satellite_count, 0, 200)
          .Doc("satellites in view, drawn once per scenario over the sky above the elevation mask"),
      F::Degrees("elevation_mask_deg", &O::elevation_mask_rad, R::Between(0.0, 89.0, "deg"))
          .Doc("elevation mask: satellites are drawn above it only"),
      F::Number("sky_ray_length_m", &O::sky_ray_length_m, R::Positive("m"))
          .Doc("length of the rays towards the satellites; hits beyond it count as clear sky"),
      // A position fix needs 4 satellites; the order single <= float <= fixed is IsValid's.
      F::Integer("min_satellites_single", &O::min_satellites_single, 4, 200)
          .Doc("fewer visible satellites than this: no fix"),
      F::Integer("min_satellites_float", &O::min_satellites_float, 4, 200)
          .Doc("fewer visible satellites than this: a single fix; else RTK float"),
      F::Integer("min_satellites_fixed", &O::min_satellites_fixed, 4, 200)
          .Doc("RTK float becomes fixed once this many have been visible for time_to_fix_s"),
      F::Number("time_to_fix_s", &O::time_to_fix_s, R::NonNegative("s"))
          .Doc("time from (re-)acquisition to RTK fixed (ambiguity resolution)"),
      F::Flag("fixed_at_start", &O::fixed_at_start)
          .Doc("true: already RTK fixed at the run's start when enough satellites are visible"),
      F::Number("multipath_min_blocked_fraction", &O::multipath_min_blocked_fraction,
                R::Between(0.0, 1.0, ""))
          .Doc("multipath is reported when at least this fraction of the sky is blocked"),
      F::Number("multipath_correlation_time_s", &O::multipath_correlation_time_s,
                R::Positive("s"))
          .Doc("time constant of the Gauss-Markov multipath error"),
  };
  return kFields;
}

bool GnssOptions::IsValid(std::string* why) const {
  if (!core::CheckOptionFields<GnssOptions>(*this, Fields(), why)) return false;
  auto fail = [why](std::string message) {
    if (why != nullptr) *why = std::move(message);
    return false;
  };
  if (min_satellites_float < min_satellites_single) {
    return fail(fmt::format("min_satellites_float: expected min_satellites_single ({}) <= "
                            "min_satellites_float ({})",
                            min_satellites_single, min_satellites_float));
  }
  if (min_satellites_fixed < min_satellites_float) {
    return fail(fmt::format("min_satellites_fixed: expected min_satellites_float ({}) <= "
                            "min_satellites_fixed ({})",
                            min_satellites_float, min_satellites_fixed));
  }
  const auto fields = GnssFixErrorOptions::Fields();
  return core::CheckOptionFields(rtk_fixed, fields, why, "rtk_fixed.") &&
         core::CheckOptionFields(rtk_float, fields, why, "rtk_float.") &&
         core::CheckOptionFields(single, fields, why, "single.");
}
namespace {

// Position in W of a point fixed in B at p_Bs, at t + tau (rigid-body kinematics,
// second-order extrapolation over tau < one physics step):
//   p_Ws = p_WB + R_WB r,  v_Ws = v_WB + R_WB (omega x r),
//   a_Ws = a_WB + R_WB (alpha x r + omega x (omega x r)).
Eigen::Vector3d MountPointPosition(const TruthState& x, const Eigen::Vector3d& r, double tau_s) {
  const Eigen::Matrix3d R_WB = x.q_WB.toRotationMatrix();
  const Eigen::Vector3d& w = x.omega_WB_B;
  const Eigen::Vector3d v = x.v_WB_W + R_WB * w.cross(r);
  const Eigen::Vector3d a = x.a_WB_W + R_WB * (x.alpha_WB_B.cross(r) + w.cross(w.cross(r)));
  return x.p_WB + R_WB * r + v * tau_s + 0.5 * a * tau_s * tau_s;
}

// Index of a fix type's brown-error state (none has no state).
int BrownIndex(GnssFix fix) {
  switch (fix) {
    case GnssFix::kSingle: return 0;
    case GnssFix::kFloat: return 1;
    case GnssFix::kFixed: return 2;
    case GnssFix::kNone: break;
  }
  return -1;
}

constexpr GnssFix kFixTypes[3] = {GnssFix::kSingle, GnssFix::kFloat, GnssFix::kFixed};

}  // namespace

GnssModel::GnssModel(std::string name, const GnssOptions& options, const World& world,
                     uint64_t seed)
    : name_(std::move(name)),
      options_(core::ValidOptions(options, "gnss '" + name_ + "'")),
      stream_(seed, "sensor/" + name_),
      period_ns_(core::PeriodFromRate(options.rate_hz)),
      latency_ns_(core::SecondsToTime(options.latency_s)),
      time_to_fix_ns_(core::SecondsToTime(options.time_to_fix_s)) {
  p_Bs_ = world.robot().Site(options_.site, "gnss '" + name_ + "'").p_Bs;

  T_WS_ = Eigen::Isometry3d::Identity();
  T_WS_.translation() = options_.enu_origin_W_m;
  T_WS_.linear() =
      Eigen::AngleAxisd(options_.enu_yaw_rad, Eigen::Vector3d::UnitZ()).toRotationMatrix();

  // The sky: uniform over the cap above the mask (area element d(sin el) d az).
  core::RandomStream sky(seed, "sensor/" + name_ + "/sky");
  const double sin_mask = std::sin(options_.elevation_mask_rad);
  for (int i = 0; i < options_.satellite_count; ++i) {
    const double az = sky.Uniform(0.0, core::kTwoPi);
    const double sin_el = sky.Uniform(sin_mask, 1.0);
    const double cos_el = std::sqrt(std::max(0.0, 1.0 - sin_el * sin_el));
    sky_S_.emplace_back(cos_el * std::cos(az), cos_el * std::sin(az), sin_el);
  }

  // Correlated errors start in their stationary distribution (no warm-up transient).
  for (const GnssFix fix : kFixTypes) {
    const GnssFixErrorOptions& e = ErrorOptions(fix);
    const double s = std::sqrt(e.correlated_fraction);
    const Eigen::Vector3d sigma(e.std_horizontal_m, e.std_horizontal_m, e.std_vertical_m);
    Eigen::Vector3d b;
    for (int k = 0; k < 3; ++k) b(k) = s * sigma(k) * stream_.Normal();
    brown_S_[BrownIndex(fix)] = b;
  }
  for (int k = 0; k < 3; ++k) multipath_unit_(k) = stream_.Normal();
}

const GnssFixErrorOptions& GnssModel::ErrorOptions(GnssFix fix) const {
  switch (fix) {
    case GnssFix::kSingle: return options_.single;
    case GnssFix::kFloat: return options_.rtk_float;
    case GnssFix::kFixed:
    case GnssFix::kNone: break;
  }
  return options_.rtk_fixed;
}

void GnssModel::AdvanceErrors(double dt_s) {
  // Exact discretisation of dx = -x/tau dt + sigma sqrt(2/tau) dW:
  //   x_k+1 = phi x_k + sigma sqrt(1 - phi^2) n_k, phi = e^(-dt/tau).
  for (const GnssFix fix : kFixTypes) {
    const GnssFixErrorOptions& e = ErrorOptions(fix);
    const double phi = std::exp(-dt_s / e.correlation_time_s);
    const double s = std::sqrt(e.correlated_fraction) * std::sqrt(1.0 - phi * phi);
    const Eigen::Vector3d sigma(e.std_horizontal_m, e.std_horizontal_m, e.std_vertical_m);
    Eigen::Vector3d& b = brown_S_[BrownIndex(fix)];
    for (int k = 0; k < 3; ++k) b(k) = phi * b(k) + s * sigma(k) * stream_.Normal();
  }
  const double phi = std::exp(-dt_s / options_.multipath_correlation_time_s);
  const double s = std::sqrt(1.0 - phi * phi);
  for (int k = 0; k < 3; ++k) multipath_unit_(k) = phi * multipath_unit_(k) + s * stream_.Normal();
}

// Long by design: one GNSS epoch (sky, blockage, fix type, errors, sample) as the model
// documents it in gnss.h, the steps sharing the epoch's geometry.
void GnssModel::Step(const SensorInput& input, std::vector<SensorSample>* out) {
  const TruthState& x = input.truth;
  const core::Time t_ns = x.t_ns;
  const core::Time dt_ns = input.world.timestep_ns();
  const Eigen::Matrix3d R_WS = T_WS_.linear();

  while (next_sample_ns_ < t_ns) next_sample_ns_ += period_ns_;
  for (; next_sample_ns_ < t_ns + dt_ns; next_sample_ns_ += period_ns_) {
    const core::Time ts_ns = next_sample_ns_;
    const Eigen::Vector3d p_Ws = MountPointPosition(x, p_Bs_, core::TimeToSeconds(ts_ns - t_ns));

    // Sky visibility: one ray per satellite against structure and ground.
    int visible = 0;
    for (const Eigen::Vector3d& dir_S : sky_S_) {
      const std::optional<RayHit> hit = input.world.CastRay(p_Ws, R_WS * dir_S, kRayScene);
      if (!hit || hit->distance_m > options_.sky_ray_length_m) ++visible;
    }
    visible_ = visible;
    const double blocked_fraction =
        sky_S_.empty() ? 1.0
                       : static_cast<double>(options_.satellite_count - visible) /
                             static_cast<double>(options_.satellite_count);

    // Fix type; RTK fixed needs min_satellites_fixed continuously for time_to_fix_s.
    if (visible >= options_.min_satellites_fixed) {
      if (!fixable_since_ns_) {
        fixable_since_ns_ = (first_epoch_ && options_.fixed_at_start) ? ts_ns - time_to_fix_ns_
                                                                      : ts_ns;
      }
    } else {
      fixable_since_ns_.reset();
    }
    first_epoch_ = false;
    if (visible < options_.min_satellites_single) {
      fix_ = GnssFix::kNone;
    } else if (visible < options_.min_satellites_float) {
      fix_ = GnssFix::kSingle;
    } else if (fixable_since_ns_ && ts_ns - *fixable_since_ns_ >= time_to_fix_ns_) {
      fix_ = GnssFix::kFixed;
    } else {
      fix_ = GnssFix::kFloat;
    }

    // Error processes advance at every epoch, with or without a fix.
    if (last_epoch_ns_) AdvanceErrors(core::TimeToSeconds(ts_ns - *last_epoch_ns_));
    last_epoch_ns_ = ts_ns;

    uint32_t conditions = kConditionNone;
    switch (fix_) {
      case GnssFix::kNone: conditions = kNoFix; break;
      case GnssFix::kSingle: conditions = kSingleFix; break;
      case GnssFix::kFloat: conditions = kFloatFix; break;
      case GnssFix::kFixed: break;
    }
    if (fix_ != GnssFix::kNone && blocked_fraction >= options_.multipath_min_blocked_fraction &&
        blocked_fraction > 0.0) {
      conditions |= kMultipath;
    }
    conditions_ = conditions;
    if (fix_ == GnssFix::kNone) continue;

    // Reported position: truth + white + brown + multipath; reported covariance is the
    // fix type's stated one.
    const GnssFixErrorOptions& e = ErrorOptions(fix_);
    const Eigen::Vector3d sigma(e.std_horizontal_m, e.std_horizontal_m, e.std_vertical_m);
    const double white_scale = std::sqrt(1.0 - e.correlated_fraction);
    Eigen::Vector3d white;
    for (int k = 0; k < 3; ++k) white(k) = white_scale * sigma(k) * stream_.Normal();
    const Eigen::Vector3d multipath = blocked_fraction * e.multipath_std_m * multipath_unit_;

    const Eigen::Vector3d p_Ss = R_WS.transpose() * (p_Ws - T_WS_.translation());
    core::PositionMeasurement measured;
    measured.p_Ss = p_Ss + white + brown_S_[BrownIndex(fix_)] + multipath;
    measured.covariance = sigma.cwiseAbs2().asDiagonal();
    core::PositionMeasurement truth;
    truth.p_Ss = p_Ss;
    truth.covariance = Eigen::Matrix3d::Zero();

    out->push_back({ts_ns, ts_ns + latency_ns_, measured, truth, conditions});
  }
}

}  // namespace tofu::sim
