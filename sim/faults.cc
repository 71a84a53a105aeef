#include "sim/faults.h"

#include <algorithm>
#include <cassert>
#include <cmath>
#include <deque>
#include <utility>

#include "core/lie.h"
#include "core/random.h"

namespace tofu::sim {

// ---- names ----

const std::array<FaultKind, kFaultKindCount>& AllFaultKinds() {
  static const std::array<FaultKind, kFaultKindCount> all = {
      FaultKind::kMisalignment, FaultKind::kNonGaussianNoise, FaultKind::kDivergence,
      FaultKind::kDropout,      FaultKind::kFreeze,           FaultKind::kDelay,
      FaultKind::kJump,         FaultKind::kOutliers};
  return all;
}

std::string_view FaultKindName(FaultKind kind) {
  switch (kind) {
    case FaultKind::kMisalignment: return "misalignment";
    case FaultKind::kNonGaussianNoise: return "non_gaussian_noise";
    case FaultKind::kDivergence: return "divergence";
    case FaultKind::kDropout: return "dropout";
    case FaultKind::kFreeze: return "freeze";
    case FaultKind::kDelay: return "delay";
    case FaultKind::kJump: return "jump";
    case FaultKind::kOutliers: return "outliers";
  }
  return "unknown";
}

std::optional<FaultKind> FaultKindFromName(std::string_view name) {
  for (const FaultKind kind : AllFaultKinds()) {
    if (FaultKindName(kind) == name) return kind;
  }
  return std::nullopt;
}

// ---- schedule ----

FaultWindow WindowOf(const FaultSpec& spec) {
  FaultWindow window;
  window.start_ns = core::SecondsToTime(spec.start_s);
  if (std::isfinite(spec.end_s)) window.end_ns = core::SecondsToTime(spec.end_s);
  return window;
}

std::optional<std::string> CheckFaultApplies(const FaultSpec& spec, core::MeasurementKind measured) {
  if (measured == core::MeasurementKind::kImu) {
    switch (spec.kind) {
      case FaultKind::kDropout:
      case FaultKind::kFreeze:
      case FaultKind::kDelay:
        return std::nullopt;
      case FaultKind::kOutliers:
        if (spec.outliers.acc_scale_mps2 > 0.0 || spec.outliers.gyro_scale_radps > 0.0) {
          return std::nullopt;
        }
        return "outliers on imu measurements need acc_scale_mps2 > 0 or gyro_scale_degps > 0";
      default:
        return std::string(FaultKindName(spec.kind)) +
               " does not apply to imu measurements (imu accepts: dropout, freeze, delay, "
               "outliers)";
    }
  }
  if (spec.kind == FaultKind::kOutliers) {
    const bool has_effect = spec.outliers.scale_m > 0.0 ||
                            (measured == core::MeasurementKind::kPose && spec.outliers.rotation_scale_rad > 0.0);
    if (!has_effect) {
      return "outliers on " + std::string(core::MeasurementKindName(measured)) +
             " measurements need scale_m > 0" +
             (measured == core::MeasurementKind::kPose ? " or rotation_scale_deg > 0" : "");
    }
  }
  return std::nullopt;
}

std::vector<FaultLabel> FaultLabels(const std::vector<FaultSpec>& specs, core::Time run_end_ns) {
  std::vector<FaultLabel> labels;
  for (const FaultSpec& spec : specs) {
    const FaultWindow window = WindowOf(spec);
    if (window.start_ns >= run_end_ns) continue;
    const std::string name(FaultKindName(spec.kind));
    labels.push_back({window.start_ns, spec.sensor, name, true});
    if (window.end_ns <= run_end_ns) labels.push_back({window.end_ns, spec.sensor, name, false});
  }
  // Time order; at one instant a fault ending before one starting; else the list order.
  std::stable_sort(labels.begin(), labels.end(), [](const FaultLabel& a, const FaultLabel& b) {
    if (a.t_ns != b.t_ns) return a.t_ns < b.t_ns;
    return !a.active && b.active;
  });
  return labels;
}

// ---- the injector ----

namespace {

/// Multivariate Student-t direction-and-size: s z / sqrt(chi2_nu / nu), z ~ N(0, I3),
/// chi2_nu the sum of nu squared standard normals (Student 1908; e.g. Kotz & Nadarajah,
/// "Multivariate t Distributions", 2004, eq. 1.1).
Eigen::Vector3d StudentT3(core::RandomStream& rng, int dof) {
  const Eigen::Vector3d z = rng.Normal3();
  double chi2 = 0.0;
  for (int i = 0; i < dof; ++i) {
    const double n = rng.Normal();
    chi2 += n * n;
  }
  // chi2 = 0 has probability zero; guard against the (impossible in practice) division.
  chi2 = std::max(chi2, std::numeric_limits<double>::min());
  return z / std::sqrt(chi2 / dof);
}

/// Applies a rigid change of the reference frame, T' = [R, t] T, to a pose or position
/// (the twist is in s and unchanged; delta_theta is a right perturbation, unchanged;
/// delta_p rotates with R).
void TransformReferenceFrame(const Eigen::Quaterniond& q, const Eigen::Vector3d& t,
                             core::Measurement* measurement) {
  const Eigen::Matrix3d R = q.toRotationMatrix();
  if (auto* pose = std::get_if<core::PoseMeasurement>(measurement)) {
    pose->p_Ss = R * pose->p_Ss + t;
    pose->q_Ss = core::CanonicalQuat((q * pose->q_Ss).normalized());
    Eigen::Matrix<double, 6, 6> J = Eigen::Matrix<double, 6, 6>::Identity();
    J.bottomRightCorner<3, 3>() = R;
    pose->covariance = J * pose->covariance * J.transpose();
  } else if (auto* position = std::get_if<core::PositionMeasurement>(measurement)) {
    position->p_Ss = R * position->p_Ss + t;
    position->covariance = R * position->covariance * R.transpose();
  }
}

/// The position a pose or position measurement reports (nullptr for an IMU).
Eigen::Vector3d* MutablePosition(core::Measurement* measurement) {
  if (auto* pose = std::get_if<core::PoseMeasurement>(measurement)) return &pose->p_Ss;
  if (auto* position = std::get_if<core::PositionMeasurement>(measurement)) {
    return &position->p_Ss;
  }
  return nullptr;
}

}  // namespace

/// One fault and its evolving state.
struct FaultInjector::Stage {
  Stage(const FaultSpec& spec_in, uint64_t seed, size_t index)
      : spec(spec_in),
        window(WindowOf(spec_in)),
        rng(seed, "fault/" + spec_in.sensor + "/" + std::to_string(index)),
        delay_ns(core::SecondsToTime(spec_in.delay.delay_s)),
        arrival_delay_ns(core::SecondsToTime(spec_in.delay.arrival_delay_s)) {}

  /// Transforms `sample` in place; false if the sample is dropped.
  bool Process(SensorSample* sample);
  // The kinds whose effect takes more than a few lines, on a sample inside the window;
  // `previous` is the stamp of the sample before (if any).
  void AddNonGaussianNoise(core::Time t, std::optional<core::Time> previous, core::Measurement* m);
  void AddDivergence(core::Time t, core::Measurement* m) const;
  void MaybeAddOutlier(core::Time t, std::optional<core::Time> previous, core::Measurement* m);

  FaultSpec spec;
  FaultWindow window;
  core::RandomStream rng;
  core::Time delay_ns;
  core::Time arrival_delay_ns;

  // State (each kind uses its own part).
  std::optional<core::Time> previous_t_ns;         ///< noise, outliers: last stamp seen
  Eigen::Vector3d brown_m = Eigen::Vector3d::Zero();  ///< noise: b_k
  std::optional<core::Measurement> held;           ///< freeze: last value before start
  std::deque<std::pair<core::Time, core::Measurement>> history;  ///< delay: recent inputs
  std::optional<Eigen::Vector3d> jump_anchor_m;    ///< jump: p0
};

bool FaultInjector::Stage::Process(SensorSample* sample) {
  const core::Time t = sample->t_ns;
  const bool active = window.Contains(t);
  core::Measurement& m = sample->measured;
  const std::optional<core::Time> previous = previous_t_ns;
  previous_t_ns = t;
  if (const auto reason = CheckFaultApplies(spec, core::MeasurementKindOf(m))) {
    assert(false && "fault kind does not apply to this sensor's measurements");
    return true;
  }

  switch (spec.kind) {
    case FaultKind::kMisalignment: {
      if (active) TransformReferenceFrame(spec.misalignment.q_FS, spec.misalignment.p_FS_m, &m);
      return true;
    }

    case FaultKind::kNonGaussianNoise:
      if (active) AddNonGaussianNoise(t, previous, &m);
      return true;

    case FaultKind::kDivergence:
      if (active) AddDivergence(t, &m);
      return true;

    case FaultKind::kDropout:
      return !active;

    case FaultKind::kFreeze: {
      if (!active) {
        if (t < window.start_ns) held = m;
        return true;
      }
      if (!held) held = m;  // nothing before the window: hold its first value
      m = *held;
      return true;
    }

    case FaultKind::kDelay: {
      // Keep the inputs needed to answer "latest value at or before t - delay" now and
      // later (targets only grow): drop entries superseded by a later one at or before it.
      history.emplace_back(t, m);
      const core::Time target = t - delay_ns;
      while (history.size() >= 2 && history[1].first <= target) history.pop_front();
      if (!active) return true;
      if (history.front().first > target) return false;  // no value that old yet
      m = history.front().second;
      sample->arrival_ns += arrival_delay_ns;
      return true;
    }

    case FaultKind::kJump: {
      if (!active) return true;
      Eigen::Vector3d* p = MutablePosition(&m);
      if (!jump_anchor_m) jump_anchor_m = *p;
      // p' = R (p - p0) + p0 + t  ==  [R, p0 - R p0 + t] applied as a frame change.
      const Eigen::Vector3d t_m =
          *jump_anchor_m - spec.jump.q_jump * *jump_anchor_m + spec.jump.translation_S_m;
      TransformReferenceFrame(spec.jump.q_jump, t_m, &m);
      return true;
    }

    case FaultKind::kOutliers:
      if (active) MaybeAddOutlier(t, previous, &m);
      return true;
  }
  return true;
}

void FaultInjector::Stage::AddNonGaussianNoise(core::Time t, std::optional<core::Time> previous,
                                               core::Measurement* m) {
  const NonGaussianNoiseParams& p = spec.noise;
  // Time since the previous sample in the window (or since the window's start).
  const core::Time since = previous && *previous >= window.start_ns ? *previous : window.start_ns;
  const double dt = core::TimeToSeconds(t - since);
  double phi = 1.0;
  double step_std = p.brown_std_m_per_sqrt_s * std::sqrt(dt);
  if (std::isfinite(p.brown_time_constant_s)) {
    const double tau = p.brown_time_constant_s;
    phi = std::exp(-dt / tau);
    step_std = p.brown_std_m_per_sqrt_s * std::sqrt(0.5 * tau * (1.0 - phi * phi));
  }
  for (int i = 0; i < 3; ++i) brown_m[i] = phi * brown_m[i] + step_std * rng.Normal();
  const Eigen::Vector3d white_m = rng.Normal3();
  *MutablePosition(m) += p.white_std_m * white_m + brown_m;
}

void FaultInjector::Stage::AddDivergence(core::Time t, core::Measurement* m) const {
  const DivergenceParams& p = spec.divergence;
  const Eigen::Vector3d axis_S = p.axis_S.normalized();
  const double x = core::TimeToSeconds(t - window.start_ns);
  const double growth = std::exp(x / p.time_constant_s);
  // d(x) = int_0^x v0 e^(u/tau) du = v0 tau (e^(x/tau) - 1).
  *MutablePosition(m) += p.initial_velocity_mps * p.time_constant_s * (growth - 1.0) * axis_S;
  if (auto* pose = std::get_if<core::PoseMeasurement>(m); pose && pose->has_twist) {
    pose->v_s_s_mps += pose->q_Ss.conjugate() * (p.initial_velocity_mps * growth * axis_S);
  }
}

void FaultInjector::Stage::MaybeAddOutlier(core::Time t, std::optional<core::Time> previous,
                                           core::Measurement* m) {
  const OutlierParams& p = spec.outliers;
  // At least one Poisson event in (previous stamp, t] within the window.
  const core::Time since = previous ? std::max(*previous, window.start_ns) : window.start_ns;
  const double dt = core::TimeToSeconds(t - since);
  const double probability = 1.0 - std::exp(-p.rate_hz * dt);
  if (rng.Uniform(0.0, 1.0) >= probability) return;
  const int nu = p.degrees_of_freedom;
  if (auto* imu = std::get_if<core::ImuMeasurement>(m)) {
    imu->acc_I_mps2 += p.acc_scale_mps2 * StudentT3(rng, nu);
    imu->gyro_I_radps += p.gyro_scale_radps * StudentT3(rng, nu);
    return;
  }
  *MutablePosition(m) += p.scale_m * StudentT3(rng, nu);
  if (auto* pose = std::get_if<core::PoseMeasurement>(m); pose && p.rotation_scale_rad > 0.0) {
    pose->q_Ss = core::CanonicalQuat(
        (core::ExpQuat(p.rotation_scale_rad * StudentT3(rng, nu)) * pose->q_Ss).normalized());
  }
}

FaultInjector::FaultInjector(std::vector<FaultSpec> specs, uint64_t seed)
    : specs_(std::move(specs)) {
  stages_.reserve(specs_.size());
  for (size_t i = 0; i < specs_.size(); ++i) {
    assert(specs_[i].sensor == specs_.front().sensor && "one injector per sensor");
    assert(specs_[i].start_s < specs_[i].end_s);
    stages_.emplace_back(specs_[i], seed, i);
  }
}

FaultInjector::~FaultInjector() = default;
FaultInjector::FaultInjector(FaultInjector&&) noexcept = default;
FaultInjector& FaultInjector::operator=(FaultInjector&&) noexcept = default;

const std::vector<FaultSpec>& FaultInjector::specs() const { return specs_; }

void FaultInjector::Apply(const SensorSample& in, std::vector<SensorSample>* out) {
  SensorSample sample = in;
  for (Stage& stage : stages_) {
    if (!stage.Process(&sample)) return;
  }
  out->push_back(std::move(sample));
}

uint32_t FaultInjector::ActiveFaults(core::Time t_ns) const {
  uint32_t mask = 0;
  for (const Stage& stage : stages_) {
    if (stage.window.Contains(t_ns)) mask |= FaultBit(stage.spec.kind);
  }
  return mask;
}

}  // namespace tofu::sim
