#include "estimator/multi_graph_estimator.h"

#include <algorithm>
#include <cmath>
#include <deque>
#include <stdexcept>
#include <string>
#include <utility>

#include <Eigen/Eigenvalues>

#include "core/lie.h"
#include "core/units.h"

namespace tofu::estimator {
namespace {

struct SensorState {
  SensorSpec spec;
  int id = 0;
  std::unique_ptr<AlignmentGraph> graph;
  std::optional<Eigen::Isometry3d> known_T_AL;   ///< given by the caller
  std::optional<Eigen::Isometry3d> frozen_T_AL;  ///< held while fused (co-dependence rule)
  /// The T_ALs held the last times the sensor was fused (newest first, a few): one is
  /// reused when the sensor is fused again and the pairs since still fit it (a frame that
  /// did not move). More than one: a sensor re-admitted during a fault its velocities do
  /// not show (a jump) was fused in the fault's frame, and the frame before it is the
  /// right one again once the fault is over.
  std::vector<Eigen::Isometry3d> previous_T_AL;
  bool fused = false;
  /// Absolute position factors (MultiGraphEstimatorOptions::absolute_readmission_rate_mps):
  /// fused again, its first position sets the offset to slew out; the offset in L at
  /// slew_start_ns while slewing.
  bool readmitted = false;
  std::optional<Eigen::Vector3d> slew_offset_L;
  core::Time slew_start_ns = 0;
  bool has_last = false;
  core::Time last_t_ns = 0;
  // between_noise_from_data: the window the stream's noise is measured over.
  std::vector<ImuPoseInA> noise_window;
  std::optional<core::Time> noise_measured_at_ns;
};

// Keeps T_AL among the frames the sensor held last (newest first, no duplicates).
void RememberFrame(const Eigen::Isometry3d& T_AL, SensorState* sensor) {
  constexpr std::size_t kRememberedFrames = 4;
  auto& previous = sensor->previous_T_AL;
  const auto same = std::find_if(previous.begin(), previous.end(),
                                 [&](const auto& T) { return T.isApprox(T_AL, 1e-12); });
  if (same != previous.end()) previous.erase(same);
  previous.insert(previous.begin(), T_AL);
  if (previous.size() > kRememberedFrames) previous.resize(kRememberedFrames);
}

struct ImuSample {
  core::Time t_ns;
  Eigen::Vector3d accel_I_mps2;
  Eigen::Vector3d gyro_I_radps;
};

struct RestState {
  core::Time t_ns = 0;
  NavState state;
  ImuBias bias;
};

struct PendingPair {
  SensorState* sensor = nullptr;
  core::Time t_ns = 0;
  Eigen::Vector3d p_A;
  Eigen::Matrix3d covariance_A;
  bool for_alignment = true;  // the sensor's alignment graph was not frozen
  bool for_mission = false;   // a trusted surveyed sensor: the mission frame's fit
};

// Yaw of a rotation about the z axis of its parent frame (ZYX convention).
double Yaw(const Eigen::Matrix3d& R) { return std::atan2(R(1, 0), R(0, 0)); }

bool Finite(const core::Measurement& value) {
  return std::visit(
      [](const auto& m) {
        using T = std::decay_t<decltype(m)>;
        if constexpr (std::is_same_v<T, core::ImuMeasurement>) {
          return m.acc_I_mps2.allFinite() && m.gyro_I_radps.allFinite();
        } else if constexpr (std::is_same_v<T, core::PoseMeasurement>) {
          return m.p_Ss.allFinite() && m.q_Ss.coeffs().allFinite() &&
                 m.q_Ss.coeffs().norm() > 0.5 && m.covariance.allFinite();
        } else {
          return m.p_Ss.allFinite() && m.covariance.allFinite();
        }
      },
      value);
}

// The first std of a prior that is not positive and finite (its information is 1/std²),
// or nullptr.
const char* BadPriorStd(const InitialStatePrior& prior) {
  const auto good = [](double sigma) { return sigma > 0.0 && std::isfinite(sigma); };
  const auto good3 = [&](const Eigen::Vector3d& sigma) {
    return good(sigma.x()) && good(sigma.y()) && good(sigma.z());
  };
  if (!good3(prior.position_std_m)) return "position_std_m";
  if (!good3(prior.rotation_std_rad)) return "rotation_std_rad";
  if (!good(prior.velocity_std_mps)) return "velocity_std_mps";
  if (!good(prior.accel_bias_std_mps2)) return "accel_bias_std_mps2";
  if (!good(prior.gyro_bias_std_radps)) return "gyro_bias_std_radps";
  return nullptr;
}

// The projector onto the directions a block of a sensor's stated information observes:
// its eigen-directions with information below 1/unobserved_std² are left out (none when
// unobserved_std is 0 or the block does not decompose).
Eigen::Matrix3d ObservedProjector(const Eigen::Matrix3d& information, double unobserved_std) {
  Eigen::Matrix3d projector = Eigen::Matrix3d::Identity();
  if (!(unobserved_std > 0.0)) return projector;
  const Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> eigen(information);
  if (eigen.info() != Eigen::Success) return projector;
  const double min_information = 1.0 / (unobserved_std * unobserved_std);
  for (int k = 0; k < 3; ++k) {
    if (eigen.eigenvalues()(k) < min_information) {
      projector -= eigen.eigenvectors().col(k) * eigen.eigenvectors().col(k).transpose();
    }
  }
  return projector;
}

// The between factor's square-root information without the directions the pose sensor
// states it does not observe (SensorSpec::unobserved_position_std_m). The stated
// covariance is of [δθ_s; δp_S]; its information blocks are conditional (the other block
// held fixed), as a registration's degeneracy test reads them. The factor's rows: the
// position residual in I_i (PoseBetweenFactor) or in L (R_LA given: PositionBetweenFactor
// in A), the rotation residual in I. Both ends of one factor are a keyframe interval
// apart: the current sample's directions stand for the interval's.
void LeaveOutUnobserved(const SensorSpec& spec, const core::PoseMeasurement& pose,
                        const std::optional<Eigen::Matrix3d>& R_LA,
                        Eigen::Matrix<double, 6, 6>* sqrt_information) {
  if (!(spec.unobserved_position_std_m > 0.0) && !(spec.unobserved_rotation_std_rad > 0.0)) return;
  const Eigen::LDLT<Eigen::Matrix<double, 6, 6>> ldlt(pose.covariance);
  if (ldlt.info() != Eigen::Success || !ldlt.isPositive()) return;
  const Eigen::Matrix<double, 6, 6> information =
      ldlt.solve(Eigen::Matrix<double, 6, 6>::Identity());
  if (!information.allFinite()) return;
  const Eigen::Matrix3d R_Is = spec.T_Is.linear();
  const Eigen::Matrix3d P_A =
      ObservedProjector(information.bottomRightCorner<3, 3>(), spec.unobserved_position_std_m);
  const Eigen::Matrix3d R_sA = pose.q_Ss.normalized().toRotationMatrix().transpose();
  const Eigen::Matrix3d R_XA = R_LA ? *R_LA : Eigen::Matrix3d(R_Is * R_sA);
  const Eigen::Matrix3d P_s =
      ObservedProjector(information.topLeftCorner<3, 3>(), spec.unobserved_rotation_std_rad);
  sqrt_information->topLeftCorner<3, 3>() =
      sqrt_information->topLeftCorner<3, 3>() * R_XA * P_A * R_XA.transpose();
  sqrt_information->bottomRightCorner<3, 3>() =
      sqrt_information->bottomRightCorner<3, 3>() * R_Is * P_s * R_Is.transpose();
}

// A pose's own noise for PoseBetweenNoise::kWhiteAndDrift: the stated white stds, or
// where they are 0 the sample's stated covariance.
PoseNoise OwnNoiseOf(const SensorSpec& spec, const core::PoseMeasurement& pose) {
  PoseNoise noise;
  noise.white_covariance = pose.covariance;
  if (spec.white_rotation_std_rad > 0.0) {
    noise.white_covariance.topRows<3>().setZero();
    noise.white_covariance.leftCols<3>().setZero();
    noise.white_covariance.topLeftCorner<3, 3>().diagonal().setConstant(
        spec.white_rotation_std_rad * spec.white_rotation_std_rad);
  }
  if (spec.white_position_std_m > 0.0) {
    noise.white_covariance.bottomRows<3>().setZero();
    noise.white_covariance.rightCols<3>().setZero();
    noise.white_covariance.bottomRightCorner<3, 3>().diagonal().setConstant(
        spec.white_position_std_m * spec.white_position_std_m);
  }
  noise.drift = spec.drift;
  noise.min_position_std_m = spec.min_between_position_std_m;
  noise.min_rotation_std_rad = spec.min_between_rotation_std_rad;
  return noise;
}

// A stream whose noise is measured against the IMU needs the IMU of its window kept.
LocalSmootherOptions LocalOptionsFor(const MultiGraphEstimatorOptions& options,
                                     const std::vector<SensorSpec>& specs) {
  LocalSmootherOptions local = options.local;
  for (const SensorSpec& spec : specs) {
    if (spec.between_noise_from_data) {
      local.min_imu_history_ns = std::max(local.min_imu_history_ns,
                                          options.max_alignment_window_ns + 500'000'000);
    }
  }
  return local;
}

}  // namespace

struct MultiGraphEstimator::Impl {
  Impl(std::string imu, std::vector<SensorSpec> specs, const MultiGraphEstimatorOptions& opts)
      : options(opts), imu_name(std::move(imu)), smoother(LocalOptionsFor(opts, specs)) {
    int id = 0;
    for (SensorSpec& spec : specs) {
      auto s = std::make_unique<SensorState>();
      s->spec = std::move(spec);
      s->id = id++;
      // The level prior holds where A is levelled: a position sensor's stated frame (the
      // odometries' frames are where their sensor booted, tilted with its mount).
      AlignmentGraphOptions graph_options = options.alignment;
      if (s->spec.kind != SensorKind::kPosition || !s->spec.reference_is_gravity_aligned) {
        graph_options.level_prior_std_rad = 0.0;
      }
      s->graph = std::make_unique<AlignmentGraph>(graph_options);
      counters.streams[s->spec.name];
      sensors.push_back(std::move(s));
    }
    counters.streams[imu_name];
  }

  MultiGraphEstimatorOptions options;
  std::string imu_name;
  LocalSmoother smoother;
  std::vector<std::unique_ptr<SensorState>> sensors;
  std::vector<std::string> fused_names;
  EstimatorCounters counters;
  std::vector<EstimatorOutput> outputs;
  std::optional<MissionFrame> mission;
  std::optional<std::vector<std::string>> mission_candidates;  // unset: the fused sensors

  const std::vector<std::string>& MissionCandidates() const {
    return mission_candidates ? *mission_candidates : fused_names;
  }
  bool IsMissionCandidate(const std::string& name) const {
    const std::vector<std::string>& names = MissionCandidates();
    return std::find(names.begin(), names.end(), name) != names.end();
  }

  bool has_imu = false;
  core::Time last_imu_ns = 0;
  Eigen::Vector3d last_gyro = Eigen::Vector3d::Zero();
  core::Time next_output_ns = INT64_MIN;
  std::deque<ImuSample> recent_imu;                   // the rest-detection window
  std::optional<RestState> rest;
  std::deque<std::pair<core::Time, NavState>> history;  // propagated local estimate
  std::vector<PendingPair> pending_pairs;
  std::optional<core::StampedMeasurement> pending_init;
  std::optional<core::Time> last_fused_ns;
  std::optional<core::Time> last_covariance_ns;
  std::int64_t bad_solves_seen = 0;
  std::int64_t solves_seen = 0;
  std::vector<InitialisationRecord> initialisations;
  // Visual-inertial initialisation: the window of the pose sensor that started it.
  SensorState* init_sensor = nullptr;
  std::vector<ImuPoseInA> init_poses;
  core::Time init_wait_start_ns = 0;
  // IMU gaps: the usual sample period (running mean) and the state before the last gap.
  bool has_prev_imu = false;
  core::Time prev_imu_ns = 0;
  double imu_period_s = 0.0;
  bool reinit_after_gap = false;
  std::optional<NavState> state_before_gap;

  SensorState* Find(const std::string& name) {
    for (auto& s : sensors) {
      if (s->spec.name == name) return s.get();
    }
    return nullptr;
  }

  // ---- gating ----
  bool Gate(const std::string& name, core::Time t_ns, bool finite, bool* has_last,
            core::Time* last_t_ns) {
    StreamGateCounters& c = counters.streams[name];
    if (!core::IsValidTime(t_ns)) {
      ++c.rejected_time_out_of_range;
      return false;
    }
    if (!finite) {
      ++c.rejected_non_finite;
      return false;
    }
    if (*has_last && t_ns == *last_t_ns) {
      ++c.rejected_duplicate;
      return false;
    }
    if (*has_last && t_ns < *last_t_ns) {
      ++c.rejected_out_of_order;
      return false;
    }
    *has_last = true;
    *last_t_ns = t_ns;
    ++c.accepted;
    return true;
  }

  // ---- rest detection (before the graph exists) ----
  void UpdateRest(const ImuSample& sample) {
    recent_imu.push_back(sample);
    while (!recent_imu.empty() && recent_imu.front().t_ns < sample.t_ns - options.static_window_ns) {
      recent_imu.pop_front();
    }
    if (smoother.initialized()) return;
    if (recent_imu.size() < 10 ||
        recent_imu.back().t_ns - recent_imu.front().t_ns < options.static_window_ns * 9 / 10) {
      return;
    }
    Eigen::Vector3d accel_mean = Eigen::Vector3d::Zero(), gyro_mean = Eigen::Vector3d::Zero();
    for (const ImuSample& s : recent_imu) {
      accel_mean += s.accel_I_mps2;
      gyro_mean += s.gyro_I_radps;
    }
    const double n = static_cast<double>(recent_imu.size());
    accel_mean /= n;
    gyro_mean /= n;
    Eigen::Vector3d accel_var = Eigen::Vector3d::Zero(), gyro_var = Eigen::Vector3d::Zero();
    for (const ImuSample& s : recent_imu) {
      accel_var += (s.accel_I_mps2 - accel_mean).cwiseAbs2();
      gyro_var += (s.gyro_I_radps - gyro_mean).cwiseAbs2();
    }
    const double accel_std = std::sqrt((accel_var / n).maxCoeff());
    const double gyro_std = std::sqrt((gyro_var / n).maxCoeff());
    if (accel_std > options.static_max_accel_std_mps2 ||
        gyro_std > options.static_max_gyro_std_radps) {
      return;
    }
    // At rest the specific force is −g expressed in I: it fixes roll and pitch (yaw is a
    // gauge choice made later), and the mean gyro is its bias.
    RestState r;
    r.t_ns = sample.t_ns;
    r.state.q_LI = Eigen::Quaterniond::FromTwoVectors(accel_mean, Eigen::Vector3d::UnitZ());
    r.state.p_LI.setZero();
    r.state.v_L_mps.setZero();
    r.bias.gyro_radps = gyro_mean;
    r.bias.accel_mps2.setZero();
    rest = r;
  }

  // ---- initialisation at the first fused measurement ----
  // Long by design: the first state at the first fused sample, attitude from gravity (at
  // rest or in motion) then the gauge (yaw, origin) from the sensor, built on one state.
  void Initialize(SensorState& sensor, const core::StampedMeasurement& m) {
    const core::Time t = m.t_ns;
    NavState state;
    ImuBias bias;
    InitialStatePrior prior;
    std::optional<NavState> from_rest;
    if (rest && t - rest->t_ns <= options.max_rest_age_ns && t >= rest->t_ns) {
      from_rest = smoother.PredictWithImu(rest->t_ns, rest->state, rest->bias, t);
    }
    if (from_rest) {
      state = *from_rest;
      bias = rest->bias;
      prior = options.prior_from_rest;
      prior.rotation_std_in_L = true;
      // The unknown accelerometer bias has been integrated since the rest state.
      const double age_s = core::TimeToSeconds(t - rest->t_ns);
      prior.velocity_std_mps += prior.accel_bias_std_mps2 * age_s;
    } else {
      // In motion: gravity from the mean specific force of the last window (biased by the
      // mean acceleration, hence the loose prior).
      Eigen::Vector3d accel_mean = Eigen::Vector3d::Zero();
      for (const ImuSample& s : recent_imu) accel_mean += s.accel_I_mps2;
      if (recent_imu.empty() || accel_mean.norm() < 1e-6) accel_mean = Eigen::Vector3d::UnitZ();
      state.q_LI = Eigen::Quaterniond::FromTwoVectors(accel_mean, Eigen::Vector3d::UnitZ());
      prior = options.prior_in_motion;
    }
    // Gauge: yaw and origin of L from the first fused sensor.
    const Eigen::Isometry3d& T_Is = sensor.spec.T_Is;
    Eigen::Matrix3d R_LI = state.q_LI.toRotationMatrix();
    if (const auto* pose = std::get_if<core::PoseMeasurement>(&m.value)) {
      const Eigen::Matrix3d R_AI = pose->q_Ss.normalized().toRotationMatrix() *
                                   T_Is.linear().transpose();
      const Eigen::Matrix3d R_yaw =
          Eigen::AngleAxisd(Yaw(R_AI) - Yaw(R_LI), Eigen::Vector3d::UnitZ()).toRotationMatrix();
      R_LI = R_yaw * R_LI;
      state.v_L_mps = R_yaw * state.v_L_mps;
      state.q_LI = Eigen::Quaterniond(R_LI);
      state.p_LI = pose->p_Ss - R_AI * T_Is.translation();
      Eigen::Isometry3d T_As = Eigen::Isometry3d::Identity();
      T_As.linear() = pose->q_Ss.normalized().toRotationMatrix();
      T_As.translation() = pose->p_Ss;
      Eigen::Isometry3d T_LI = Eigen::Isometry3d::Identity();
      T_LI.linear() = R_LI;
      T_LI.translation() = state.p_LI;
      sensor.frozen_T_AL = T_As * T_Is.inverse() * T_LI.inverse();
    } else if (const auto* position = std::get_if<core::PositionMeasurement>(&m.value)) {
      // A levelled reference frame: L := A in rotation (yaw gauge), origin at the sensor's.
      const Eigen::Matrix3d R_yaw =
          Eigen::AngleAxisd(-Yaw(R_LI), Eigen::Vector3d::UnitZ()).toRotationMatrix();
      R_LI = R_yaw * R_LI;
      state.v_L_mps = R_yaw * state.v_L_mps;
      state.q_LI = Eigen::Quaterniond(R_LI);
      state.p_LI = position->p_Ss - R_LI * T_Is.translation();
      Eigen::Isometry3d T_AL = Eigen::Isometry3d::Identity();
      sensor.frozen_T_AL = T_AL;
    }
    if (reinit_after_gap && state_before_gap &&
        std::holds_alternative<core::PositionMeasurement>(m.value)) {
      // After an IMU gap, L is the sensor's frame as before; the heading before the gap is
      // the best guess there is, and it is a guess: loose.
      const Eigen::Matrix3d R_before = state_before_gap->q_LI.toRotationMatrix();
      const Eigen::Matrix3d R_yaw =
          Eigen::AngleAxisd(Yaw(R_before) - Yaw(R_LI), Eigen::Vector3d::UnitZ()).toRotationMatrix();
      state.q_LI = Eigen::Quaterniond(R_yaw * R_LI);
      state.p_LI = std::get<core::PositionMeasurement>(m.value).p_Ss -
                   state.q_LI * T_Is.translation();
      prior.rotation_std_rad = Eigen::Vector3d(0.1, 0.1, 0.5);
      prior.rotation_std_in_L = true;
    }
    sensor.graph->SetFrozen(true);
    smoother.Initialize(t, state, bias, prior);
    last_fused_ns = t;
    InitialisationRecord record;
    record.t_ns = t;
    record.method = from_rest ? InitialisationRecord::Method::kRest
                              : InitialisationRecord::Method::kMeanSpecificForce;
    record.sensor = sensor.spec.name;
    record.after_imu_gap = reinit_after_gap;
    record.state = state;
    record.bias = bias;
    FinishInitialisation(std::move(record));
  }

  // The stream noise a visual-inertial alignment measured, for a sensor that states none.
  void FillFromAlignment(SensorState& sensor, const VisualInertialAlignment& a,
                         InitialisationRecord* record) {
    record->window_s = a.window_s;
    record->gravity_direction_std_rad = a.gravity_direction_std_rad;
    record->relative_position_std_m = a.relative_position_std_m;
    record->relative_rotation_std_rad = a.relative_rotation_std_rad;
    record->noise_from_data = sensor.spec.between_noise_from_data;
    if (sensor.spec.between_noise_from_data) UseMeasuredNoise(sensor, a, init_poses.back().t_ns);
  }

  void UseMeasuredNoise(SensorState& sensor, const VisualInertialAlignment& a, core::Time t_ns) {
    sensor.spec.between_position_std_m =
        std::max(a.relative_position_std_m, sensor.spec.min_between_position_std_m);
    sensor.spec.between_rotation_std_rad =
        std::max(a.relative_rotation_std_rad, sensor.spec.min_between_rotation_std_rad);
    sensor.spec.between_noise_from_data = false;  // measured once, kept
    sensor.noise_measured_at_ns = t_ns;
    sensor.noise_window.clear();
    sensor.noise_window.shrink_to_fit();
  }

  // A pose stream that states no noise, once the graph runs (it started from rest, or
  // from another sensor): its scatter against the IMU over a window of its own samples,
  // the alignment's residuals (visual_inertial_alignment.h), at the graph's gyro bias (a
  // stream whose rotation drifts against the IMU, a VIO converging after take-off, shows
  // as scatter instead of as a bias). Until then it is fused with the default weights.
  void MeasureStreamNoise(SensorState& sensor, const core::StampedMeasurement& m) {
    const auto* pose = std::get_if<core::PoseMeasurement>(&m.value);
    if (pose == nullptr || !sensor.spec.between_noise_from_data) return;
    if (!AppendSpaced(sensor.spec.T_Is, *pose, m.t_ns, &sensor.noise_window)) return;
    std::optional<Eigen::Vector3d> b_g;
    if (const std::optional<KeyframeState> newest = smoother.NewestKeyframe()) {
      b_g = newest->bias.gyro_radps;
    }
    const std::optional<VisualInertialAlignment> a = Align(sensor.noise_window, b_g);
    if (!a) return;
    if (a->window_s < core::TimeToSeconds(options.min_noise_window_ns)) return;
    if (a->drop_leading_samples > 0) {
      DropLeading(a->drop_leading_samples, &sensor.noise_window);
      return;
    }
    UseMeasuredNoise(sensor, *a, m.t_ns);
  }

  // Appends a pose (moved to I) to an alignment window if it is a keyframe spacing after the
  // window's newest (the stream's scatter is measured over the interval its between
  // factors will span), and trims the window to max_alignment_window_ns and the buffered
  // IMU. Returns whether it was appended.
  bool AppendSpaced(const Eigen::Isometry3d& T_Is, const core::PoseMeasurement& pose,
                    core::Time t_ns, std::vector<ImuPoseInA>* window) const {
    const core::Time spacing = core::PeriodFromRate(options.local.keyframe_rate_hz) -
                               options.local.keyframe_merge_tolerance_ns;
    if (!window->empty() && t_ns - window->back().t_ns < spacing) return false;
    ImuPoseInA sample;
    sample.t_ns = t_ns;
    sample.R_AI = pose.q_Ss.normalized().toRotationMatrix() * T_Is.linear().transpose();
    sample.p_AI = pose.p_Ss - sample.R_AI * T_Is.translation();
    window->push_back(sample);
    while (window->size() > 2 &&
           (window->back().t_ns - window->front().t_ns > options.max_alignment_window_ns ||
            window->front().t_ns < smoother.oldest_imu_ns())) {
      window->erase(window->begin());
    }
    return true;
  }

  // Aligns the part of a window the IMU already covers: a pose stamped between two IMU
  // samples arrives before the second (the stream is arrival-ordered), and is aligned with
  // the next one.
  std::optional<VisualInertialAlignment> Align(
      const std::vector<ImuPoseInA>& window,
      const std::optional<Eigen::Vector3d>& known_gyro_bias_radps = std::nullopt) const {
    VisualInertialAlignmentOptions vi = options.visual_inertial;
    vi.known_gyro_bias_radps = known_gyro_bias_radps;
    const core::Time newest_imu_ns = smoother.newest_imu_ns();
    const auto covered = std::find_if(window.begin(), window.end(), [&](const ImuPoseInA& p) {
      return p.t_ns > newest_imu_ns;
    });
    return AlignVisualInertial(
        std::vector<ImuPoseInA>(window.begin(), covered),
        [this](core::Time a, core::Time b, const ImuBias& bias) {
          return smoother.PreintegrateImu(a, b, bias);
        },
        vi);
  }

  static void DropLeading(int count, std::vector<ImuPoseInA>* window) {
    window->erase(window->begin(),
                  window->begin() + std::min<std::ptrdiff_t>(count, window->size() - 1));
  }

  void FinishInitialisation(InitialisationRecord record) {
    if (record.after_imu_gap) ++counters.restarts_after_gap;
    initialisations.push_back(std::move(record));
    init_sensor = nullptr;
    init_poses.clear();
    reinit_after_gap = false;
    state_before_gap.reset();
    solves_seen = smoother.stats().solves;
    bad_solves_seen = smoother.stats().bad_solves;
  }

  // Before the local graph exists: start it now from a fresh rest state (the robot was
  // still), or collect the first fused pose stream's window until a visual-inertial
  // alignment makes gravity observable. Returns whether the graph exists now.
  bool TryInitialize(SensorState& sensor, const core::StampedMeasurement& m) {
    const auto* pose = std::get_if<core::PoseMeasurement>(&m.value);
    const bool fresh_rest =
        rest && m.t_ns >= rest->t_ns && m.t_ns - rest->t_ns <= options.max_rest_age_ns;
    if (pose == nullptr || (fresh_rest && !reinit_after_gap)) {
      Initialize(sensor, m);
      return true;
    }
    if (init_sensor == nullptr || !init_sensor->fused) {
      init_sensor = &sensor;
      init_poses.clear();
      init_wait_start_ns = m.t_ns;
    }
    if (&sensor != init_sensor) return false;
    if (!AppendSpaced(sensor.spec.T_Is, *pose, m.t_ns, &init_poses)) return false;
    const std::optional<VisualInertialAlignment> alignment = Align(init_poses);
    if (alignment && alignment->observable) {
      InitializeAligned(sensor, *alignment);
      return true;
    }
    if (alignment && alignment->drop_leading_samples > 0) {
      // The stream's own start-up transient or a jump: what came before it leaves.
      DropLeading(alignment->drop_leading_samples, &init_poses);
    }
    if (m.t_ns - init_wait_start_ns > options.max_initialisation_wait_ns) {
      Initialize(sensor, m);
      return true;
    }
    return false;
  }

  // The local graph from a visual-inertial alignment (visual_inertial_alignment.h), at the
  // window's newest sample. L: z against the aligned gravity, yaw and origin those of A
  // (T_LA a pure tilt), or, after an IMU gap, the L of before (the frozen T_AL).
  void InitializeAligned(SensorState& sensor, const VisualInertialAlignment& a) {
    const ImuPoseInA& newest = init_poses.back();
    Eigen::Isometry3d T_LA = Eigen::Isometry3d::Identity();
    if (sensor.frozen_T_AL) {
      T_LA = sensor.frozen_T_AL->inverse();
    } else {
      T_LA.linear() =
          Eigen::Quaterniond::FromTwoVectors(a.g_A, -Eigen::Vector3d::UnitZ()).toRotationMatrix();
    }
    NavState state;
    state.q_LI = Eigen::Quaterniond(T_LA.linear() * newest.R_AI).normalized();
    state.p_LI = T_LA * newest.p_AI;
    state.v_L_mps = T_LA.linear() * a.v_A_mps.back();
    sensor.frozen_T_AL = T_LA.inverse();
    sensor.graph->SetFrozen(true);
    InitialStatePrior prior;
    // Tilt as well known as the window made gravity (never tighter than 0.2°); yaw and
    // origin are the gauge of L.
    const double tilt_std_rad = std::max(a.gravity_direction_std_rad, core::RadFromDeg(0.2));
    prior.rotation_std_rad = Eigen::Vector3d(tilt_std_rad, tilt_std_rad, 1e-3);
    prior.rotation_std_in_L = true;
    prior.position_std_m = Eigen::Vector3d::Constant(1e-3);
    prior.velocity_std_mps = 0.1;
    prior.accel_bias_std_mps2 = options.visual_inertial.accel_bias_prior_std_mps2;
    prior.gyro_bias_std_radps = options.prior_from_rest.gyro_bias_std_radps;
    InitialisationRecord record;
    FillFromAlignment(sensor, a, &record);
    smoother.Initialize(newest.t_ns, state, a.bias, prior);
    last_fused_ns = newest.t_ns;
    record.t_ns = newest.t_ns;
    record.method = InitialisationRecord::Method::kVisualInertial;
    record.sensor = sensor.spec.name;
    record.after_imu_gap = reinit_after_gap;
    record.state = state;
    record.bias = a.bias;
    FinishInitialisation(std::move(record));
  }

  // A gap in the IMU stream: nothing propagates across it. The graph, its IMU buffer and
  // the rest state go; the fused sensors keep their frozen T_AL, so that the graph
  // re-initialised from them after the gap estimates in the same L.
  void OnImuGap(core::Time gap_ns) {
    ++counters.imu_gaps;
    counters.imu_gap_total_s += core::TimeToSeconds(gap_ns);
    if (smoother.initialized()) {
      if (const std::optional<KeyframeState> p = smoother.Propagated()) state_before_gap = p->state;
      reinit_after_gap = true;
    }
    smoother.ResetAfterImuGap();
    history.clear();
    pending_pairs.clear();
    pending_init.reset();
    init_sensor = nullptr;
    init_poses.clear();
    for (auto& s : sensors) s->noise_window.clear();
    rest.reset();
    recent_imu.clear();
    last_fused_ns.reset();
    last_covariance_ns.reset();
  }

  // ---- fusion of one measurement of a fused sensor ----
  void Fuse(SensorState& sensor, const core::StampedMeasurement& m) {
    if (!smoother.initialized()) {
      if (smoother.newest_imu_ns() < m.t_ns) {
        pending_init = m;  // wait for the IMU to reach it
        return;
      }
      if (!TryInitialize(sensor, m)) return;
    } else if (last_fused_ns && m.t_ns - *last_fused_ns > options.max_unfused_ns) {
      RestartAfterGap(m.t_ns);
    }
    MeasurementUse use = MeasurementUse::kRejected;
    if (const auto* pose = std::get_if<core::PoseMeasurement>(&m.value)) {
      Eigen::Isometry3d T_As = Eigen::Isometry3d::Identity();
      T_As.linear() = pose->q_Ss.normalized().toRotationMatrix();
      T_As.translation() = pose->p_Ss;
      const SensorSpec& spec = sensor.spec;
      std::optional<PoseNoise> noise;
      Eigen::Matrix<double, 6, 6> sqrt_information = Eigen::Matrix<double, 6, 6>::Identity();
      if (spec.pose_between_noise == PoseBetweenNoise::kWhiteAndDrift) {
        noise = OwnNoiseOf(spec, *pose);
      } else {
        Eigen::Matrix<double, 6, 1> std_dev;
        std_dev << Eigen::Vector3d::Constant(spec.between_position_std_m),
            Eigen::Vector3d::Constant(spec.between_rotation_std_rad);
        sqrt_information = std_dev.cwiseInverse().asDiagonal();
      }
      std::optional<Eigen::Matrix3d> R_LA;
      if (spec.between_position_in_reference) {
        const std::optional<Eigen::Isometry3d> T_AL = AlignmentOf(sensor);
        if (T_AL) R_LA = T_AL->linear().transpose();
      }
      LeaveOutUnobserved(spec, *pose, R_LA, &sqrt_information);
      use = smoother.AddPose(sensor.id, m.t_ns, T_As, spec.T_Is, sqrt_information, R_LA, noise);
    } else if (const auto* position = std::get_if<core::PositionMeasurement>(&m.value)) {
      const std::optional<Eigen::Isometry3d> T_AL = AlignmentOf(sensor);
      // A position sensor fused before its T_AL was known: its graph kept collecting pairs
      // (it constrained nothing yet); freeze it the moment T_AL is fully observable.
      if (T_AL && !sensor.graph->frozen() && !sensor.frozen_T_AL && !sensor.known_T_AL) {
        sensor.frozen_T_AL = T_AL;
        sensor.graph->SetFrozen(true);
      }
      if (!T_AL) {
        ++counters.streams[sensor.spec.name].not_fused_unaligned;
        return;
      }
      if (sensor.spec.position_factors == PositionFactors::kOffset) {
        use = smoother.AddPositionWithOffset(sensor.id, m.t_ns, position->p_Ss,
                                             position->covariance, sensor.spec.T_Is.translation(),
                                             T_AL->linear().transpose(),
                                             sensor.spec.min_position_std_m);
      } else {
        std::optional<Eigen::Vector3d> p_LA;
        if (sensor.spec.position_factors == PositionFactors::kAbsolute) {
          p_LA = T_AL->inverse().translation() -
                 ReadmissionOffset(sensor, m.t_ns, T_AL->inverse() * position->p_Ss);
        }
        use = smoother.AddPosition(sensor.id, m.t_ns, position->p_Ss, position->covariance,
                                   sensor.spec.T_Is.translation(), T_AL->linear().transpose(),
                                   sensor.spec.min_position_std_m, p_LA);
      }
    }
    if (use == MeasurementUse::kFactor || use == MeasurementUse::kAnchor ||
        use == MeasurementUse::kPending || use == MeasurementUse::kSkipped) {
      last_fused_ns = std::max(last_fused_ns.value_or(m.t_ns), m.t_ns);
    }
  }

  // The part of the offset between an absolute sensor fused again and the state that is
  // still to be slewed out at t_ns (zero when it is not slewing): linear in time at
  // absolute_readmission_rate_mps from its first position p_L_measured (its mount point
  // in L through T_AL) minus the state's mount point there.
  Eigen::Vector3d ReadmissionOffset(SensorState& sensor, core::Time t_ns,
                                    const Eigen::Vector3d& p_L_measured) {
    if (sensor.readmitted) {
      sensor.readmitted = false;
      sensor.slew_offset_L.reset();
      const std::optional<KeyframeState> now = smoother.Propagated();
      if (options.absolute_readmission_rate_mps > 0.0 && now) {
        const Eigen::Vector3d p_L_state =
            now->state.p_LI + now->state.q_LI * sensor.spec.T_Is.translation() +
            now->state.v_L_mps * core::TimeToSeconds(t_ns - now->t_ns);
        sensor.slew_offset_L = p_L_measured - p_L_state;
        sensor.slew_start_ns = t_ns;
      }
    }
    if (!sensor.slew_offset_L) return Eigen::Vector3d::Zero();
    const double offset_m = sensor.slew_offset_L->norm();
    const double remaining_m = offset_m - options.absolute_readmission_rate_mps *
                                              core::TimeToSeconds(t_ns - sensor.slew_start_ns);
    if (remaining_m <= 0.0) {  // also a zero offset
      sensor.slew_offset_L.reset();
      return Eigen::Vector3d::Zero();
    }
    return *sensor.slew_offset_L * (remaining_m / offset_m);
  }

  // An alignment good enough to put a sensor's positions into the local graph: all three
  // rotations observable and known to max_alignment_rotation_std_rad, and positions
  // explained to max_alignment_rms_m. Fusing on the first observable estimate (10 pairs,
  // 0.5 s) froze a T_AL that could be off by tens of degrees.
  bool Usable(const AlignmentEstimate& e) const {
    if (!e.valid || e.observable_rotation_dofs != 3) return false;
    const double rotation_variance = e.covariance.bottomRightCorner<3, 3>().eigenvalues().real().maxCoeff();
    return rotation_variance <= options.max_alignment_rotation_std_rad * options.max_alignment_rotation_std_rad &&
           e.rms_residual_m <= options.max_alignment_rms_m;
  }

  std::optional<Eigen::Isometry3d> AlignmentOf(const SensorState& sensor) const {
    if (sensor.known_T_AL) return sensor.known_T_AL;
    if (sensor.frozen_T_AL) return sensor.frozen_T_AL;
    // Fused again after an exclusion or a gap: the frame it held before, while the pairs
    // collected since (min_pairs of them) still fit it. A re-estimated T_AL would absorb
    // the drift L made without the sensor, and keep it for the rest of the flight; the old
    // one brings L back to the sensor's frame (issue 16: the oracle's and consensus's ATE
    // were dominated by that offset).
    for (const Eigen::Isometry3d& T_AL : sensor.previous_T_AL) {
      // The median: a few pairs from the fault's trailing edge (collected before the
      // exclusion was decided) must not veto a frame that fits all the others.
      const std::optional<double> median_m = sensor.graph->MedianResidualOf(T_AL);
      if (median_m && *median_m <= options.max_alignment_rms_m) return T_AL;
    }
    const AlignmentEstimate& e = sensor.graph->estimate();
    if (Usable(e)) return e.T_AL;
    return std::nullopt;
  }

  // ---- alignment pairs: the sensor's position against the local estimate ----
  std::optional<NavState> LocalAt(core::Time t_ns) const {
    if (history.empty() || t_ns < history.front().first || t_ns > history.back().first) {
      return std::nullopt;
    }
    auto after = std::lower_bound(history.begin(), history.end(), t_ns,
                                  [](const auto& h, core::Time t) { return h.first < t; });
    if (after->first == t_ns || after == history.begin()) return after->second;
    auto before = std::prev(after);
    const double u = static_cast<double>(t_ns - before->first) /
                     static_cast<double>(after->first - before->first);
    NavState s;
    s.p_LI = (1 - u) * before->second.p_LI + u * after->second.p_LI;
    s.v_L_mps = (1 - u) * before->second.v_L_mps + u * after->second.v_L_mps;
    s.q_LI = before->second.q_LI.slerp(u, after->second.q_LI);
    return s;
  }

  void AddPairs() {
    std::vector<PendingPair> still;
    for (const PendingPair& p : pending_pairs) {
      if (!history.empty() && p.t_ns > history.back().first) {
        still.push_back(p);
        continue;
      }
      const std::optional<NavState> local = LocalAt(p.t_ns);
      if (!local) continue;
      AlignmentPair pair;
      pair.t_ns = p.t_ns;
      pair.p_A_measured = p.p_A;
      // The local estimate is uncertain too (its drift over the window, cm): without that
      // a millimetre-precise total station would call hover jitter "observable" rotation.
      pair.covariance_A = p.covariance_A + Eigen::Matrix3d::Identity() *
                                               (options.alignment_local_position_std_m *
                                                options.alignment_local_position_std_m);
      pair.p_Ls_estimated = local->p_LI + local->q_LI * p.sensor->spec.T_Is.translation();
      if (p.for_mission && mission) {
        mission->AddPair(p.sensor->spec.name, p.t_ns, p.p_A, pair.p_Ls_estimated, p.covariance_A);
      }
      if (!p.for_alignment) continue;
      p.sensor->graph->AddPair(pair);
      p.sensor->graph->Update(p.t_ns);
    }
    pending_pairs = std::move(still);
  }

  // ---- IMU: propagation, solves, outputs ----
  void HandleImu(core::Time t, const core::ImuMeasurement& imu) {
    if (has_prev_imu) {
      const double dt_s = core::TimeToSeconds(t - prev_imu_ns);
      const double gap_s = std::max(core::TimeToSeconds(options.min_imu_gap_ns),
                                    options.imu_gap_periods * imu_period_s);
      if (imu_period_s > 0.0 && dt_s > gap_s) {
        OnImuGap(t - prev_imu_ns);
      } else {
        imu_period_s = imu_period_s > 0.0 ? 0.99 * imu_period_s + 0.01 * dt_s : dt_s;
      }
    }
    has_prev_imu = true;
    prev_imu_ns = t;
    smoother.AddImu(t, imu.acc_I_mps2, imu.gyro_I_radps);
    last_gyro = imu.gyro_I_radps;
    UpdateRest(ImuSample{t, imu.acc_I_mps2, imu.gyro_I_radps});
    if (pending_init && pending_init->t_ns <= t) {
      const core::StampedMeasurement m = *pending_init;
      pending_init.reset();
      if (SensorState* s = Find(m.sensor); s != nullptr && s->fused) Fuse(*s, m);
    }
    if (!smoother.initialized()) return;
    smoother.Update();
    const LocalSmootherStats& st = smoother.stats();
    if (st.solves != solves_seen) {
      counters.consecutive_bad_solves =
          st.bad_solves != bad_solves_seen ? counters.consecutive_bad_solves + 1 : 0;
      solves_seen = st.solves;
      bad_solves_seen = st.bad_solves;
    }
    const std::optional<KeyframeState> now = smoother.Propagated();
    if (!now) return;
    if (counters.consecutive_bad_solves >= options.max_consecutive_bad_solves ||
        !now->state.p_LI.allFinite() || now->state.v_L_mps.norm() > options.local.max_speed_mps) {
      Reinitialize();
      return;
    }
    history.emplace_back(now->t_ns, now->state);
    while (!history.empty() && history.front().first < t - 3 * core::kNanosecondsPerSecond) {
      history.pop_front();
    }
    AddPairs();
    if (next_output_ns == INT64_MIN) {
      next_output_ns = (t / options.output_period_ns) * options.output_period_ns;
    }
    if (t >= next_output_ns) {
      EstimatorOutput out;
      out.t_ns = now->t_ns;
      out.state = now->state;
      out.bias = now->bias;
      out.omega_I_radps = last_gyro - now->bias.gyro_radps;
      out.initialized = true;
      out.valid = last_fused_ns && t - *last_fused_ns <= options.max_unfused_ns &&
                  !fused_names.empty();
      out.fused = fused_names;
      if (options.covariance_period_ns > 0 &&
          (!last_covariance_ns || t - *last_covariance_ns >= options.covariance_period_ns)) {
        if (const std::optional<Eigen::Matrix<double, 15, 15>> P = smoother.NewestCovariance()) {
          out.position_covariance_m2 = P->topLeftCorner<3, 3>();
        }
        last_covariance_ns = t;
      }
      if (mission) {
        Eigen::Isometry3d T_LI = Eigen::Isometry3d::Identity();
        T_LI.linear() = now->state.q_LI.normalized().toRotationMatrix();
        T_LI.translation() = now->state.p_LI;
        mission->Update(now->t_ns, T_LI, MissionCandidates());
        out.mission = mission->published();
      }
      outputs.push_back(std::move(out));
      while (next_output_ns <= t) next_output_ns += options.output_period_ns;
    }
  }

  // The first fused measurement after a long IMU-only stretch: the graph's velocity and
  // its linearisation points have drifted far, and solving the old window against the new
  // relative factors takes many iterations with half-solved (jumping) outputs between
  // them. Start a new window at the propagated state instead: position and yaw keep their
  // values (no jump in the gauge directions), velocity gets the loose in-motion prior, the
  // biases keep their estimates.
  void RestartAfterGap(core::Time t_ns) {
    const std::optional<KeyframeState> newest = smoother.NewestKeyframe();
    if (!newest) return;
    NavState state = newest->state;
    if (t_ns > newest->t_ns) {
      if (const auto predicted = smoother.PredictWithImu(newest->t_ns, newest->state, newest->bias, t_ns)) {
        state = *predicted;
      }
    } else {
      t_ns = newest->t_ns;
    }
    InitialStatePrior prior = options.prior_in_motion;
    prior.accel_bias_std_mps2 = options.prior_from_rest.accel_bias_std_mps2;
    prior.gyro_bias_std_radps = options.prior_from_rest.gyro_bias_std_radps;
    smoother.Initialize(t_ns, state, newest->bias, prior);
    ++counters.restarts_after_gap;
    solves_seen = smoother.stats().solves;
    bad_solves_seen = smoother.stats().bad_solves;
  }

  // A graph that keeps failing starts afresh from its propagated state with loose priors.
  void Reinitialize() {
    ++counters.reinitialisations;
    counters.consecutive_bad_solves = 0;
    std::optional<KeyframeState> start;
    for (auto it = history.rbegin(); it != history.rend(); ++it) {
      if (it->second.p_LI.allFinite() && it->second.v_L_mps.norm() < options.local.max_speed_mps) {
        start = KeyframeState{it->first, it->second, ImuBias{}, true};
        break;
      }
    }
    const core::Time t = smoother.newest_imu_ns();
    NavState state;
    if (start) {
      const std::optional<NavState> predicted =
          smoother.PredictWithImu(start->t_ns, start->state, ImuBias{}, t);
      state = predicted ? *predicted : start->state;
    }
    if (!state.v_L_mps.allFinite() || state.v_L_mps.norm() > options.local.max_speed_mps) {
      state.v_L_mps.setZero();
    }
    InitialStatePrior prior = options.prior_in_motion;
    prior.position_std_m = Eigen::Vector3d::Constant(0.05);
    smoother.Initialize(t, state, ImuBias{}, prior);
    history.clear();
    solves_seen = smoother.stats().solves;
    bad_solves_seen = smoother.stats().bad_solves;
  }
};

bool MultiGraphEstimatorOptions::IsValid(std::string* why) const {
  auto fail = [why](std::string message) {
    if (why != nullptr) *why = std::move(message);
    return false;
  };
  std::string nested;
  if (!local.IsValid(&nested)) return fail("local." + nested);
  if (!alignment.IsValid(&nested)) return fail("alignment." + nested);
  if (!mission.IsValid(&nested)) return fail("mission." + nested);
  if (!visual_inertial.IsValid(&nested)) return fail("visual_inertial." + nested);
  // One gravity for the whole estimator: the alignment's must be the local graph's.
  if (visual_inertial.gravity_mps2 != local.gravity_mps2) {
    return fail("visual_inertial.gravity_mps2 must equal local.gravity_mps2 (the estimator has "
                "one gravity)");
  }
  if (output_period_ns <= 0) return fail("output_period_ns must be positive");
  // 0 would restart the local window at every fused measurement.
  if (max_unfused_ns <= 0) return fail("max_unfused_ns must be positive");
  if (!(absolute_readmission_rate_mps >= 0.0) || !std::isfinite(absolute_readmission_rate_mps)) {
    return fail("absolute_readmission_rate_mps must be finite and >= 0 (0: no slew)");
  }
  if (covariance_period_ns < 0) return fail("covariance_period_ns must not be negative");
  if (static_window_ns <= 0) return fail("static_window_ns must be positive");
  if (!(static_max_gyro_std_radps > 0.0) || !std::isfinite(static_max_gyro_std_radps)) {
    return fail("static_max_gyro_std_radps must be positive and finite");
  }
  if (!(static_max_accel_std_mps2 > 0.0) || !std::isfinite(static_max_accel_std_mps2)) {
    return fail("static_max_accel_std_mps2 must be positive and finite");
  }
  if (max_rest_age_ns < 0) return fail("max_rest_age_ns must not be negative");
  if (const char* bad = BadPriorStd(prior_from_rest)) {
    return fail(std::string("prior_from_rest.") + bad + " must be positive and finite");
  }
  // A window shorter than the alignment's minimum would never align.
  if (max_alignment_window_ns <= 0 ||
      core::TimeToSeconds(max_alignment_window_ns) < visual_inertial.min_window_s) {
    return fail(
        "max_alignment_window_ns must be positive and at least visual_inertial.min_window_s");
  }
  if (max_initialisation_wait_ns < 0) {
    return fail("max_initialisation_wait_ns must not be negative");
  }
  // The noise is measured over a window of at most max_alignment_window_ns.
  if (min_noise_window_ns < 0 || min_noise_window_ns > max_alignment_window_ns) {
    return fail("min_noise_window_ns must be in [0, max_alignment_window_ns]");
  }
  // A gap is longer than the usual period: at 1 period or less, a sample merely late by
  // jitter would be one (unless min_imu_gap_ns covers it).
  if (!(imu_gap_periods > 1.0) || !std::isfinite(imu_gap_periods)) {
    return fail("imu_gap_periods must be > 1 and finite");
  }
  if (min_imu_gap_ns < 0) return fail("min_imu_gap_ns must not be negative");
  if (const char* bad = BadPriorStd(prior_in_motion)) {
    return fail(std::string("prior_in_motion.") + bad + " must be positive and finite");
  }
  if (!(max_alignment_rotation_std_rad > 0.0) || !std::isfinite(max_alignment_rotation_std_rad)) {
    return fail("max_alignment_rotation_std_rad must be positive and finite");
  }
  if (!(max_alignment_rms_m > 0.0) || !std::isfinite(max_alignment_rms_m)) {
    return fail("max_alignment_rms_m must be positive and finite");
  }
  if (!(alignment_local_position_std_m >= 0.0) || !std::isfinite(alignment_local_position_std_m)) {
    return fail("alignment_local_position_std_m must be >= 0 and finite");
  }
  if (max_consecutive_bad_solves < 1) return fail("max_consecutive_bad_solves must be at least 1");
  return true;
}

MultiGraphEstimator::MultiGraphEstimator(std::string imu_name, std::vector<SensorSpec> sensors,
                                         MultiGraphEstimatorOptions options) {
  std::string why;
  if (!options.IsValid(&why)) throw std::invalid_argument("MultiGraphEstimatorOptions: " + why);
  for (const SensorSpec& spec : sensors) {
    if (spec.pose_between_noise != PoseBetweenNoise::kWhiteAndDrift) continue;
    const double values[] = {spec.white_position_std_m, spec.white_rotation_std_rad,
                             spec.drift.position_random_walk_m_per_sqrtm,
                             spec.drift.rotation_random_walk_rad_per_sqrtm};
    for (double v : values) {
      if (!(v >= 0.0) || !std::isfinite(v)) {
        throw std::invalid_argument("SensorSpec " + spec.name +
                                    ": white and drift noise must be >= 0 and finite");
      }
    }
    // The floors keep a factor's covariance positive definite where the white error and
    // the drift are zero (a standing robot, a stream that states no error).
    if (!(spec.min_between_position_std_m > 0.0) || !(spec.min_between_rotation_std_rad > 0.0) ||
        !std::isfinite(spec.min_between_position_std_m + spec.min_between_rotation_std_rad)) {
      throw std::invalid_argument("SensorSpec " + spec.name +
                                  ": min_between_*_std must be > 0 and finite with "
                                  "PoseBetweenNoise::kWhiteAndDrift");
    }
    if (spec.between_position_in_reference) {
      throw std::invalid_argument("SensorSpec " + spec.name +
                                  ": between_position_in_reference takes constant between "
                                  "weights, not PoseBetweenNoise::kWhiteAndDrift");
    }
  }
  impl_ = std::make_unique<Impl>(std::move(imu_name), std::move(sensors), options);
}

MultiGraphEstimator::~MultiGraphEstimator() = default;

void MultiGraphEstimator::Add(const core::StampedMeasurement& m) {
  Impl& impl = *impl_;
  const bool finite = Finite(m.value);
  if (m.sensor == impl.imu_name) {
    const auto* imu = std::get_if<core::ImuMeasurement>(&m.value);
    if (imu == nullptr) {
      ++impl.counters.unknown_stream;
      return;
    }
    if (!impl.Gate(m.sensor, m.t_ns, finite, &impl.has_imu, &impl.last_imu_ns)) return;
    impl.HandleImu(m.t_ns, *imu);
    return;
  }
  SensorState* sensor = impl.Find(m.sensor);
  const bool kind_matches =
      sensor != nullptr &&
      ((sensor->spec.kind == SensorKind::kPose && std::holds_alternative<core::PoseMeasurement>(m.value)) ||
       (sensor->spec.kind == SensorKind::kPosition &&
        std::holds_alternative<core::PositionMeasurement>(m.value)));
  if (!kind_matches) {
    ++impl.counters.unknown_stream;
    return;
  }
  if (!impl.Gate(m.sensor, m.t_ns, finite, &sensor->has_last, &sensor->last_t_ns)) return;

  // Alignment pair (not while frozen: the local estimate then follows this very sensor);
  // the mission frame takes the positions of the trusted surveyed sensors, fused or not
  // (it only reads where L is, it does not feed the local graph).
  const bool for_alignment = !sensor->graph->frozen();
  const bool for_mission = impl.mission && impl.IsMissionCandidate(m.sensor) &&
                           impl.mission->Surveyed(m.sensor) &&
                           std::holds_alternative<core::PositionMeasurement>(m.value);
  if (impl.smoother.initialized() && (for_alignment || for_mission)) {
    PendingPair pair;
    pair.sensor = sensor;
    pair.t_ns = m.t_ns;
    pair.for_alignment = for_alignment;
    pair.for_mission = for_mission;
    if (const auto* pose = std::get_if<core::PoseMeasurement>(&m.value)) {
      pair.p_A = pose->p_Ss;
      pair.covariance_A = pose->covariance.bottomRightCorner<3, 3>();
    } else {
      const auto& position = std::get<core::PositionMeasurement>(m.value);
      pair.p_A = position.p_Ss;
      pair.covariance_A = position.covariance;
    }
    impl.pending_pairs.push_back(pair);
    impl.AddPairs();
  }
  if (impl.smoother.initialized()) impl.MeasureStreamNoise(*sensor, m);
  if (sensor->fused) impl.Fuse(*sensor, m);
}

bool MultiGraphEstimator::SetFusedSensors(const std::vector<std::string>& names) {
  Impl& impl = *impl_;
  bool all_known = true;
  std::vector<std::string> fused;
  for (const std::string& name : names) {
    if (impl.Find(name) == nullptr) {
      all_known = false;
    } else if (std::find(fused.begin(), fused.end(), name) == fused.end()) {
      fused.push_back(name);
    }
  }
  for (auto& s : impl.sensors) {
    const bool want = std::find(fused.begin(), fused.end(), s->spec.name) != fused.end();
    if (want && !s->fused) {
      s->readmitted = impl.smoother.initialized();
      // Co-dependence rule: T_AL is held at its current estimate while the sensor's
      // positions constrain the local graph. A position sensor without a usable T_AL yet
      // constrains nothing: its graph keeps estimating until it has one (see Fuse).
      if (!s->known_T_AL) s->frozen_T_AL = impl.AlignmentOf(*s);
      const bool aligned = s->known_T_AL || s->frozen_T_AL;
      s->graph->SetFrozen(aligned || s->spec.kind == SensorKind::kPose);
    } else if (!want && s->fused) {
      impl.smoother.EndChain(s->id);
      if (impl.mission && !impl.mission_candidates) impl.mission->Forget(s->spec.name);
      s->graph->SetFrozen(false);
      if (s->frozen_T_AL) RememberFrame(*s->frozen_T_AL, s.get());
      s->frozen_T_AL.reset();
    }
    s->fused = want;
  }
  impl.fused_names = fused;
  return all_known;
}

const std::vector<std::string>& MultiGraphEstimator::fused_sensors() const {
  return impl_->fused_names;
}

bool MultiGraphEstimator::DiscardSensor(const std::string& name, core::Time after_ns) {
  SensorState* s = impl_->Find(name);
  if (s == nullptr) return false;
  std::vector<std::string> fused = fused_sensors();
  fused.erase(std::remove(fused.begin(), fused.end(), name), fused.end());
  SetFusedSensors(fused);
  impl_->smoother.DiscardSensor(s->id, after_ns);
  return true;
}

bool MultiGraphEstimator::RestartAlignment(const std::string& name) {
  SensorState* s = impl_->Find(name);
  if (s == nullptr) return false;
  if (s->fused || s->known_T_AL) return true;
  // The frame it had before the restart stays a candidate (AlignmentOf tries it against
  // the pairs that come after): a sensor found inconsistent for a moment without a fault
  // (e.g. at its first evaluation after an occlusion) is fusable again as soon as the new
  // pairs fit its old frame, not only after a whole new alignment window, which the local
  // frame may not hold still for (wall_contact_inspection, seed 5: 44 s). Pairs taken
  // during a fault (a jump) do not fit the frame of before it, and a frame estimated from
  // them fits only such pairs: neither is taken back wrongly once the fault is over.
  if (impl_->Usable(s->graph->estimate())) RememberFrame(s->graph->estimate().T_AL, s);
  s->graph->Reset();
  return true;
}

void MultiGraphEstimator::SetKnownAlignment(const std::string& sensor,
                                            const Eigen::Isometry3d& T_AL) {
  if (SensorState* s = impl_->Find(sensor)) s->known_T_AL = T_AL;
}

void MultiGraphEstimator::SetMissionSurvey(MissionSurvey survey) {
  impl_->mission.emplace(impl_->options.mission, std::move(survey));
}

void MultiGraphEstimator::SetMissionCandidates(const std::vector<std::string>& names) {
  Impl& impl = *impl_;
  if (impl.mission) {
    for (const std::string& name : impl.MissionCandidates()) {
      if (std::find(names.begin(), names.end(), name) == names.end()) impl.mission->Forget(name);
    }
  }
  impl.mission_candidates = names;
}

std::vector<EstimatorOutput> MultiGraphEstimator::TakeOutputs() {
  std::vector<EstimatorOutput> out;
  out.swap(impl_->outputs);
  return out;
}

std::optional<Eigen::Isometry3d> MultiGraphEstimator::AlignmentOf(const std::string& sensor) const {
  for (const auto& s : impl_->sensors) {
    if (s->spec.name == sensor) return impl_->AlignmentOf(*s);
  }
  return std::nullopt;
}

const AlignmentGraph* MultiGraphEstimator::AlignmentGraphOf(const std::string& sensor) const {
  for (const auto& s : impl_->sensors) {
    if (s->spec.name == sensor) return s->graph.get();
  }
  return nullptr;
}

const LocalSmoother& MultiGraphEstimator::local() const { return impl_->smoother; }

const std::vector<InitialisationRecord>& MultiGraphEstimator::initialisations() const {
  return impl_->initialisations;
}

std::optional<MultiGraphEstimator::BetweenNoise> MultiGraphEstimator::BetweenNoiseOf(
    const std::string& sensor) const {
  for (const auto& s : impl_->sensors) {
    if (s->spec.name == sensor && s->spec.kind == SensorKind::kPose &&
        s->spec.pose_between_noise == PoseBetweenNoise::kConstant) {
      return BetweenNoise{s->spec.between_position_std_m, s->spec.between_rotation_std_rad,
                          s->noise_measured_at_ns};
    }
  }
  return std::nullopt;
}

const char* InitialisationMethodName(InitialisationRecord::Method method) {
  switch (method) {
    case InitialisationRecord::Method::kRest: return "rest";
    case InitialisationRecord::Method::kVisualInertial: return "visual_inertial";
    case InitialisationRecord::Method::kMeanSpecificForce: return "mean_specific_force";
  }
  return "?";
}

const EstimatorCounters& MultiGraphEstimator::counters() const { return impl_->counters; }

}  // namespace tofu::estimator
