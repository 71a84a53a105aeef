#include "estimator/local_smoother.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <deque>
#include <map>
#include <optional>
#include <stdexcept>
#include <string>
#include <utility>

#include <Eigen/Eigenvalues>
#include <ceres/loss_function.h>

#include "core/lie.h"
#include "estimator/local_factors.h"
#include "estimator/marginalization.h"
#include "estimator/window_solver.h"

namespace tofu::estimator {
namespace {

struct ImuInterval {
  core::Time t_begin_ns = 0;
  core::Time t_end_ns = 0;
  Eigen::Vector3d accel_I_mps2;
  Eigen::Vector3d gyro_I_radps;
};

struct Keyframe {
  core::Time t_ns = 0;
  double pose[kPoseSize] = {0, 0, 0, 0, 0, 0, 1};        // p_LI, q_LI (x y z w)
  double speed_bias[kSpeedBiasSize] = {0, 0, 0, 0, 0, 0, 0, 0, 0};  // v_L, b_a, b_g
  bool imu_only = false;
  bool pose_constant = false;  ///< held fixed (only without marginalisation)
  int index = 0;               ///< position in the window, set before each solve

  NavState state() const {
    NavState s;
    s.p_LI = Eigen::Vector3d(pose[0], pose[1], pose[2]);
    s.q_LI = Eigen::Quaterniond(pose[6], pose[3], pose[4], pose[5]).normalized();
    s.v_L_mps = Eigen::Vector3d(speed_bias[0], speed_bias[1], speed_bias[2]);
    return s;
  }
  ImuBias bias() const {
    ImuBias b;
    b.accel_mps2 = Eigen::Vector3d(speed_bias[3], speed_bias[4], speed_bias[5]);
    b.gyro_radps = Eigen::Vector3d(speed_bias[6], speed_bias[7], speed_bias[8]);
    return b;
  }
  void Set(const NavState& s, const ImuBias& b) {
    const Eigen::Quaterniond q = s.q_LI.normalized();
    pose[0] = s.p_LI.x(); pose[1] = s.p_LI.y(); pose[2] = s.p_LI.z();
    pose[3] = q.x(); pose[4] = q.y(); pose[5] = q.z(); pose[6] = q.w();
    for (int k = 0; k < 3; ++k) {
      speed_bias[k] = s.v_L_mps[k];
      speed_bias[3 + k] = b.accel_mps2[k];
      speed_bias[6 + k] = b.gyro_radps[k];
    }
  }
  KeyframeState Public() const { return KeyframeState{t_ns, state(), bias(), imu_only}; }
};

enum class FactorKind { kImu, kBiasWalk, kBetween, kPrior };

struct Factor {
  FactorKind kind = FactorKind::kPrior;
  std::unique_ptr<ceres::CostFunction> cost;
  std::unique_ptr<ceres::LossFunction> loss;
  std::vector<Keyframe*> keyframes;
  std::vector<MarginalBlock> blocks;
  int sensor = -1;  ///< between factors: the sensor they came from
};

struct PendingMeasurement {
  bool is_pose = true;
  int sensor = 0;
  core::Time t_ns = 0;
  Eigen::Isometry3d T_As = Eigen::Isometry3d::Identity();
  Eigen::Isometry3d T_Is = Eigen::Isometry3d::Identity();
  Eigen::Matrix<double, 6, 6> sqrt_information = Eigen::Matrix<double, 6, 6>::Identity();
  Eigen::Vector3d p_As = Eigen::Vector3d::Zero();
  Eigen::Matrix3d covariance_A = Eigen::Matrix3d::Identity();
  Eigen::Vector3d p_Is = Eigen::Vector3d::Zero();
  Eigen::Matrix3d R_LA = Eigen::Matrix3d::Identity();
  bool position_in_reference = false;  ///< pose: displacement in A through R_LA
  std::optional<PoseNoise> pose_noise;  ///< pose: the factor's covariance from its own noise
  std::optional<Eigen::Vector3d> p_LA;  ///< position: absolute in L through T_LA
  bool with_offset = false;             ///< position: in L up to the chain's offset
  double min_std_m = 0.0;
};

// A position chain's offset o_L (PositionWithOffsetFactor): free from the chain's first
// position on; kept while a factor or the marginalisation prior names it.
struct ChainOffset {
  double o_L[kWindowOffsetSize] = {0, 0, 0};
  bool open = true;  ///< its chain still adds factors
};

// The last measurement of a fused sensor that made (or reused) a keyframe: the start of
// its next between factor.
struct Chain {
  Keyframe* keyframe = nullptr;
  core::Time t_ns = 0;
  Eigen::Isometry3d T_As = Eigen::Isometry3d::Identity();
  Eigen::Vector3d p_As = Eigen::Vector3d::Zero();
  Eigen::Matrix3d covariance_A = Eigen::Matrix3d::Identity();
  /// A pose's white covariance, when its stream states its own noise (PoseNoise).
  std::optional<Eigen::Matrix<double, 6, 6>> white_covariance;
  /// The newest measurement skipped as not yet due: it joins a keyframe another sensor
  /// makes at its time (see ChainDue).
  std::optional<PendingMeasurement> skipped;
  ChainOffset* offset = nullptr;  ///< positions with an offset: the chain's

  void MoveTo(Keyframe* kf, const PendingMeasurement& m) {
    keyframe = kf;
    t_ns = m.t_ns;
    T_As = m.T_As;
    p_As = m.p_As;
    covariance_A = m.covariance_A;
    white_covariance.reset();
    if (m.pose_noise) white_covariance = m.pose_noise->white_covariance;
    skipped.reset();
  }
};

// A position measurement as AddPosition and AddPositionWithOffset take it; nullopt when
// not finite.
std::optional<PendingMeasurement> PositionMeasurement(int sensor, core::Time t_ns,
                                                      const Eigen::Vector3d& p_As,
                                                      const Eigen::Matrix3d& covariance_A,
                                                      const Eigen::Vector3d& p_Is,
                                                      const Eigen::Matrix3d& R_LA,
                                                      double min_std_m) {
  if (!p_As.allFinite() || !covariance_A.allFinite() || !R_LA.allFinite()) return std::nullopt;
  PendingMeasurement p;
  p.is_pose = false;
  p.sensor = sensor;
  p.t_ns = t_ns;
  p.p_As = p_As;
  p.covariance_A = covariance_A;
  p.p_Is = p_Is;
  p.R_LA = R_LA;
  p.min_std_m = min_std_m;
  return p;
}

bool Finite(const Keyframe& kf) {
  for (double v : kf.pose) if (!std::isfinite(v)) return false;
  for (double v : kf.speed_bias) if (!std::isfinite(v)) return false;
  return true;
}

}  // namespace

struct LocalSmoother::Impl {
  explicit Impl(const LocalSmootherOptions& opts, LocalSmootherStats* s)
      : options(opts), stats(s) {
    gravity_L = Eigen::Vector3d(0, 0, -options.gravity_mps2);
  }

  LocalSmootherOptions options;
  LocalSmootherStats* stats;
  Eigen::Vector3d gravity_L;
  PoseManifold pose_manifold;
  // The window's own LM solver (window_solver.h) and the problem handed to it, rebuilt
  // from keyframes and factors before each solve (buffers reused).
  WindowSolver solver;
  std::vector<WindowState> window_states;
  std::vector<WindowFactor> window_factors;
  std::vector<double*> window_offsets;
  std::vector<std::unique_ptr<Keyframe>> keyframes;  // sorted by time
  std::vector<std::unique_ptr<ChainOffset>> offsets;  // in order of creation
  std::vector<std::unique_ptr<Factor>> factors;
  std::deque<ImuInterval> imu;
  bool has_last_raw = false;
  core::Time last_raw_t_ns = 0;
  Eigen::Vector3d last_raw_accel, last_raw_gyro;
  std::map<int, Chain> chains;
  std::vector<PendingMeasurement> pending;
  bool dirty = false;
  // Between factors added since the last good solve: a bad solve removes them (a wild
  // measurement must not stay in the window and be folded into the prior).
  std::vector<Factor*> unconfirmed_between;
  // Propagation of the newest keyframe to the newest IMU sample (the 200 Hz output).
  std::optional<ImuPreintegration> propagation;
  core::Time propagated_to_ns = 0;

  core::Time newest_imu_ns() const { return imu.empty() ? INT64_MIN : imu.back().t_end_ns; }

  // ---- IMU ----
  ImuPreintegration Preintegrate(core::Time t_from, core::Time t_to, const ImuBias& bias) const {
    ImuPreintegration pre(bias, options.imu_noise);
    for (const ImuInterval& s : imu) {
      if (s.t_end_ns <= t_from) continue;
      if (s.t_begin_ns >= t_to) break;
      const core::Time a = std::max(s.t_begin_ns, t_from);
      const core::Time b = std::min(s.t_end_ns, t_to);
      if (b > a) pre.Integrate(s.accel_I_mps2, s.gyro_I_radps, core::TimeToSeconds(b - a));
    }
    return pre;
  }

  void TrimImu() {
    if (imu.empty()) return;
    const core::Time keep_from =
        keyframes.empty() ? newest_imu_ns() - options.pre_init_imu_buffer_ns
                          : std::min(keyframes.front()->t_ns - options.window_ns / 4,
                                     newest_imu_ns() - options.min_imu_history_ns);
    while (imu.size() > 1 && imu.front().t_end_ns < keep_from) imu.pop_front();
  }

  // ---- factors ----
  Factor* AddFactor(FactorKind kind, std::unique_ptr<ceres::CostFunction> cost,
                    std::unique_ptr<ceres::LossFunction> loss, std::vector<Keyframe*> kfs,
                    std::vector<MarginalBlock> blocks) {
    auto factor = std::make_unique<Factor>();
    factor->kind = kind;
    factor->cost = std::move(cost);
    factor->loss = std::move(loss);
    factor->keyframes = std::move(kfs);
    factor->blocks = std::move(blocks);
    factors.push_back(std::move(factor));
    return factors.back().get();
  }

  MarginalBlock PoseBlock(Keyframe* kf) {
    return MarginalBlock{kf->pose, kPoseSize, kPoseTangentSize, &pose_manifold};
  }
  static MarginalBlock SpeedBiasBlock(Keyframe* kf) {
    return MarginalBlock{kf->speed_bias, kSpeedBiasSize, kSpeedBiasSize, nullptr};
  }

  static bool Names(const Factor& f, const ChainOffset& o) {
    return std::any_of(f.blocks.begin(), f.blocks.end(),
                       [&](const MarginalBlock& b) { return b.data == o.o_L; });
  }

  // Ends a chain: its offset takes no new factor and will be marginalised.
  static void Close(Chain& chain) {
    if (chain.offset != nullptr) chain.offset->open = false;
    chain.offset = nullptr;
  }

  // Offsets that no factor names any more (their factors discarded) leave the graph.
  void PruneOffsets() {
    std::erase_if(offsets, [&](const std::unique_ptr<ChainOffset>& o) {
      if (std::any_of(factors.begin(), factors.end(),
                      [&](const auto& f) { return Names(*f, *o); })) {
        return false;
      }
      for (auto& [sensor, chain] : chains) {
        if (chain.offset == o.get()) chain.offset = nullptr;
      }
      return true;
    });
  }

  // The window as the solver sees it: keyframes in time order, factors by state index,
  // offsets after them.
  void BuildWindow() {
    window_offsets.clear();
    for (const auto& o : offsets) {
      const auto names = [&](const auto& f) { return Names(*f, *o); };
      if (std::any_of(factors.begin(), factors.end(), names)) {
        window_offsets.push_back(o->o_L);
      }
    }
    window_states.resize(keyframes.size());
    for (std::size_t i = 0; i < keyframes.size(); ++i) {
      Keyframe& kf = *keyframes[i];
      kf.index = static_cast<int>(i);
      window_states[i] = WindowState{kf.pose, kf.speed_bias, kf.pose_constant};
    }
    window_factors.resize(factors.size());
    for (std::size_t f = 0; f < factors.size(); ++f) {
      const Factor& factor = *factors[f];
      WindowFactor& w = window_factors[f];
      w.cost = factor.cost.get();
      w.loss = factor.loss.get();
      w.blocks.resize(factor.blocks.size());
      for (std::size_t b = 0; b < factor.blocks.size(); ++b) {
        const double* data = factor.blocks[b].data;
        const auto offset = std::find(window_offsets.begin(), window_offsets.end(), data);
        if (offset != window_offsets.end()) {
          w.blocks[b] = WindowBlockRef{0, false, static_cast<int>(offset - window_offsets.begin())};
          continue;
        }
        for (const Keyframe* kf : factor.keyframes) {
          if (kf->pose == data || kf->speed_bias == data) {
            w.blocks[b] = WindowBlockRef{kf->index, kf->pose == data};
            break;
          }
        }
      }
    }
  }

  void AddImuFactors(Keyframe* a, Keyframe* b) {
    const ImuPreintegration pre = Preintegrate(a->t_ns, b->t_ns, a->bias());
    AddFactor(FactorKind::kImu, std::make_unique<ImuFactor>(pre, gravity_L), nullptr, {a, b},
              {PoseBlock(a), SpeedBiasBlock(a), PoseBlock(b), SpeedBiasBlock(b)});
    AddFactor(FactorKind::kBiasWalk,
              std::make_unique<BiasRandomWalkFactor>(core::TimeToSeconds(b->t_ns - a->t_ns),
                                                     options.imu_noise),
              nullptr, {a, b}, {SpeedBiasBlock(a), SpeedBiasBlock(b)});
  }

  void RemoveFactor(Factor* factor) {
    unconfirmed_between.erase(
        std::remove(unconfirmed_between.begin(), unconfirmed_between.end(), factor),
        unconfirmed_between.end());
    factors.erase(std::find_if(factors.begin(), factors.end(),
                               [&](const auto& f) { return f.get() == factor; }));
  }

  // ---- keyframes ----
  Keyframe* FindKeyframe(core::Time t_ns) const {
    for (const auto& kf : keyframes) {
      if (std::llabs(kf->t_ns - t_ns) <= options.keyframe_merge_tolerance_ns) return kf.get();
    }
    return nullptr;
  }

  // A keyframe at t_ns: an existing one within the merge tolerance, a new one after the
  // newest (predicted by the IMU), or one inserted between two (late measurement: the
  // IMU factor between them is split in two). nullptr before the window.
  Keyframe* KeyframeAt(core::Time t_ns, bool imu_only) {
    if (Keyframe* existing = FindKeyframe(t_ns)) {
      if (!imu_only) existing->imu_only = false;
      return existing;
    }
    if (keyframes.empty() || t_ns < keyframes.front()->t_ns) return nullptr;
    auto next = std::upper_bound(keyframes.begin(), keyframes.end(), t_ns,
                                 [](core::Time t, const auto& kf) { return t < kf->t_ns; });
    Keyframe* before = std::prev(next)->get();
    Keyframe* after = next == keyframes.end() ? nullptr : next->get();
    auto kf = std::make_unique<Keyframe>();
    kf->t_ns = t_ns;
    kf->imu_only = imu_only;
    const ImuPreintegration pre = Preintegrate(before->t_ns, t_ns, before->bias());
    kf->Set(pre.Predict(before->state(), before->bias(), gravity_L), before->bias());
    Keyframe* raw = kf.get();
    keyframes.insert(next, std::move(kf));
    if (after != nullptr) {
      ++stats->late_keyframes;
      std::vector<Factor*> split;
      for (auto& f : factors) {
        if ((f->kind == FactorKind::kImu || f->kind == FactorKind::kBiasWalk) &&
            f->keyframes.size() == 2 && f->keyframes[0] == before && f->keyframes[1] == after) {
          split.push_back(f.get());
        }
      }
      for (Factor* f : split) RemoveFactor(f);
      AddImuFactors(before, raw);
      AddImuFactors(raw, after);
    } else {
      AddImuFactors(before, raw);
    }
    ++stats->keyframes;
    dirty = true;
    return raw;
  }

  core::Time KeyframeSpacing(double fraction) const {
    return static_cast<core::Time>(fraction * 1e9 / std::max(options.keyframe_rate_hz, 1e-3));
  }

  // A sensor's measurement makes a keyframe 0.9/rate after its previous one, or joins a
  // keyframe that another fused sensor made at the same time once 0.5/rate has passed.
  // Sharing keyframes keeps the window near 30 Hz with two sensors fused (VIO at 200 Hz
  // and a 20 Hz total station made 47 keyframes a second apart, 40 shared), and the
  // solve's cost grows with the square of the keyframes per window.
  bool ChainDue(int sensor, core::Time t_ns) const {
    auto it = chains.find(sensor);
    if (it == chains.end() || it->second.keyframe == nullptr) return true;
    const core::Time since = t_ns - it->second.t_ns;
    if (since >= KeyframeSpacing(0.9)) return true;
    return since >= KeyframeSpacing(0.5) && FindKeyframe(t_ns) != nullptr;
  }

  // A keyframe made by `maker`'s measurement: the other chains' skipped measurements of
  // the same time join it (they arrived before it existed).
  void JoinSkipped(Keyframe* kf, int maker) {
    for (auto& [sensor, chain] : chains) {
      if (sensor == maker || !chain.skipped || chain.keyframe == nullptr ||
          chain.keyframe == kf) {
        continue;
      }
      const PendingMeasurement m = *chain.skipped;
      if (std::llabs(m.t_ns - kf->t_ns) > options.keyframe_merge_tolerance_ns ||
          m.t_ns - chain.t_ns < KeyframeSpacing(0.5)) {
        continue;
      }
      AddBetweenFrom(chain, kf, m);
    }
  }

  void AddBetweenFrom(Chain& chain, Keyframe* kf, const PendingMeasurement& m) {
    if (m.is_pose) {
      AddPoseBetween(chain, kf, m);
    } else if (m.p_LA) {
      AddPositionInLocal(kf, m);
    } else if (m.with_offset) {
      AddPositionWithOffset(chain, kf, m);
    } else {
      AddPositionBetween(chain, kf, m);
    }
    dirty = true;
    chain.MoveTo(kf, m);
  }

  // A between factor of a fused sensor from keyframe a to b; it stays "unconfirmed" until
  // a solve with it succeeds.
  void AddBetween(int sensor, std::unique_ptr<ceres::CostFunction> cost, Keyframe* a,
                  Keyframe* b) {
    Factor* factor = AddFactor(FactorKind::kBetween, std::move(cost), BetweenLoss(), {a, b},
                               {PoseBlock(a), PoseBlock(b)});
    factor->sensor = sensor;
    unconfirmed_between.push_back(factor);
  }

  // Pose: r^o (eq. 2), optionally with the position part as r^p in A.
  void AddPoseBetween(const Chain& chain, Keyframe* kf, const PendingMeasurement& m) {
    // Relative motion of I between the two times from the sensor's relative motion of s:
    // T_IJ = T_Is (T_As,i⁻¹ T_As,j) T_Is⁻¹ (the lever arm and mount rotation of eq. 2).
    const Eigen::Isometry3d T_IJ = m.T_Is * (chain.T_As.inverse() * m.T_As) * m.T_Is.inverse();
    Eigen::Matrix<double, 6, 6> sqrt_information = m.sqrt_information;
    if (m.pose_noise) {
      // The distance the mount travelled, from the states, not from this measurement
      // (PoseBetweenCovariance).
      const double distance_m =
          MountDisplacementL(*chain.keyframe, *kf, m.T_Is.translation()).norm();
      // A chain begun by a pose without its own noise (none of a sensor's are) would take
      // this pose's for both ends.
      const Eigen::Matrix<double, 6, 6>& white_i =
          chain.white_covariance ? *chain.white_covariance : m.pose_noise->white_covariance;
      Eigen::Matrix<double, 6, 6> covariance =
          PoseBetweenCovariance(chain.T_As, white_i, m.T_As, m.pose_noise->white_covariance,
                                m.T_Is, m.pose_noise->drift, distance_m);
      covariance.topLeftCorner<3, 3>().diagonal().array() +=
          m.pose_noise->min_position_std_m * m.pose_noise->min_position_std_m;
      covariance.bottomRightCorner<3, 3>().diagonal().array() +=
          m.pose_noise->min_rotation_std_rad * m.pose_noise->min_rotation_std_rad;
      sqrt_information = ObservedSqrtInformation(covariance, m.sqrt_information);
    }
    if (m.position_in_reference) {
      sqrt_information.topRows<3>().setZero();
      AddBetween(m.sensor, std::make_unique<PositionBetweenFactor>(
                     m.T_Is.translation(), m.R_LA,
                     m.T_As.translation() - chain.T_As.translation(),
                     m.sqrt_information.topLeftCorner<3, 3>()),
                 chain.keyframe, kf);
    }
    AddBetween(m.sensor, std::make_unique<PoseBetweenFactor>(T_IJ, sqrt_information),
               chain.keyframe, kf);
  }

  // The between factors' robust loss (none unless huber_delta > 0).
  std::unique_ptr<ceres::LossFunction> BetweenLoss() const {
    if (options.huber_delta <= 0) return nullptr;
    return std::make_unique<ceres::HuberLoss>(options.huber_delta);
  }

  // Square-root information in L of a position covariance stated in A, plus the floor.
  static Eigen::Matrix3d SqrtInformationInL(const Eigen::Matrix3d& covariance_A,
                                            const Eigen::Matrix3d& R_LA, double min_std_m) {
    Eigen::Matrix3d covariance = R_LA * covariance_A * R_LA.transpose();
    covariance += Eigen::Matrix3d::Identity() * (min_std_m * min_std_m);
    return Eigen::LLT<Eigen::Matrix3d>(covariance.inverse()).matrixU();
  }

  // Position in L through the frozen T_AL: one measurement's noise, plus the floor. A
  // factor of the sensor's like a between factor (discarded with it at an exclusion).
  void AddPositionInLocal(Keyframe* kf, const PendingMeasurement& m) {
    const Eigen::Matrix3d sqrt_information =
        SqrtInformationInL(m.covariance_A, m.R_LA, m.min_std_m);
    Factor* factor = AddFactor(
        FactorKind::kBetween,
        std::make_unique<PositionInLocalFactor>(m.p_Is, m.R_LA * m.p_As + *m.p_LA,
                                                sqrt_information),
        BetweenLoss(), {kf}, {PoseBlock(kf)});
    factor->sensor = m.sensor;
    unconfirmed_between.push_back(factor);
  }

  // Position in L up to the chain's offset, which starts where the keyframe's state puts
  // the first position (zero residual: no jump when a sensor is fused again).
  void AddPositionWithOffset(Chain& chain, Keyframe* kf, const PendingMeasurement& m) {
    const Eigen::Vector3d p_L_measured = m.R_LA * m.p_As;
    // After a dropout longer than the window the chain's previous position has left it and
    // the chain resumes on its offset untested: what L drifted meanwhile is pulled back (an
    // occlusion; measured on the suite, a restart there doubled the corridor oracle's ATE),
    // and so would be a frame change during the dropout, as with absolute factors.
    if (chain.offset != nullptr && chain.keyframe != nullptr && FrameJumped(chain, kf, m)) {
      Close(chain);
      ++stats->chain_offset_restarts;
    }
    if (chain.offset == nullptr) {
      auto offset = std::make_unique<ChainOffset>();
      const NavState s = kf->state();
      Eigen::Map<Eigen::Vector3d>{offset->o_L} = s.p_LI + s.q_LI * m.p_Is - p_L_measured;
      chain.offset = offset.get();
      offsets.push_back(std::move(offset));
      ++stats->chain_offsets;
    }
    const Eigen::Matrix3d sqrt_information =
        SqrtInformationInL(m.covariance_A, m.R_LA, m.min_std_m);
    // A factor of the sensor's like a between factor (discarded with it at an exclusion).
    Factor* factor = AddFactor(
        FactorKind::kBetween,
        std::make_unique<PositionWithOffsetFactor>(m.p_Is, p_L_measured, sqrt_information),
        BetweenLoss(), {kf},
        {PoseBlock(kf), MarginalBlock{chain.offset->o_L, kWindowOffsetSize, kWindowOffsetSize,
                                      nullptr}});
    factor->sensor = m.sensor;
    unconfirmed_between.push_back(factor);
  }

  // The displacement of the mount point p_Is in L between two keyframes' states (the newer
  // one predicted by the IMU until a solve has it).
  static Eigen::Vector3d MountDisplacementL(const Keyframe& a, const Keyframe& b,
                                            const Eigen::Vector3d& p_Is) {
    const NavState s_a = a.state();
    const NavState s_b = b.state();
    return (s_b.p_LI + s_b.q_LI * p_Is) - (s_a.p_LI + s_a.q_LI * p_Is);
  }

  // The displacement since the chain's previous position against the states' (both in the
  // window; the new keyframe predicted by the IMU), normalised by both positions' noise.
  bool FrameJumped(const Chain& chain, const Keyframe* kf, const PendingMeasurement& m) const {
    const Eigen::Vector3d measured = m.R_LA * (m.p_As - chain.p_As);
    const Eigen::Vector3d predicted = MountDisplacementL(*chain.keyframe, *kf, m.p_Is);
    Eigen::Matrix3d covariance =
        m.R_LA * (m.covariance_A + chain.covariance_A) * m.R_LA.transpose();
    covariance += Eigen::Matrix3d::Identity() * (2.0 * m.min_std_m * m.min_std_m);
    const Eigen::Vector3d d = measured - predicted;
    return d.dot(covariance.ldlt().solve(d)) > options.offset_chain_restart_chi2;
  }

  // Position: r^p (eq. 3); both ends' noise enters the displacement (white position noise).
  void AddPositionBetween(const Chain& chain, Keyframe* kf, const PendingMeasurement& m) {
    Eigen::Matrix3d covariance = chain.covariance_A + m.covariance_A;
    covariance = m.R_LA * covariance * m.R_LA.transpose();
    covariance += Eigen::Matrix3d::Identity() * (m.min_std_m * m.min_std_m);
    const Eigen::Matrix3d sqrt_information =
        Eigen::LLT<Eigen::Matrix3d>(covariance.inverse()).matrixU();
    AddBetween(m.sensor,
               std::make_unique<PositionBetweenFactor>(m.p_Is, m.R_LA, m.p_As - chain.p_As,
                                                       sqrt_information),
               chain.keyframe, kf);
  }

  MeasurementUse Apply(const PendingMeasurement& m) {
    if (!ChainDue(m.sensor, m.t_ns)) {
      chains[m.sensor].skipped = m;
      return MeasurementUse::kSkipped;
    }
    Keyframe* kf = KeyframeAt(m.t_ns, false);
    if (kf == nullptr) {
      ++stats->too_old_measurements;
      return MeasurementUse::kTooOld;
    }
    Chain& chain = chains[m.sensor];
    MeasurementUse use = MeasurementUse::kAnchor;
    if (!m.is_pose && (m.p_LA || m.with_offset) && chain.keyframe != kf) {
      // Absolute or with an offset: every due measurement constrains its keyframe, the
      // first one too.
      AddBetweenFrom(chain, kf, m);
      use = MeasurementUse::kFactor;
    } else if (chain.keyframe != nullptr && chain.keyframe != kf) {
      AddBetweenFrom(chain, kf, m);
      use = MeasurementUse::kFactor;
    } else {
      chain.MoveTo(kf, m);
    }
    JoinSkipped(kf, m.sensor);
    return use;
  }

  MeasurementUse Submit(PendingMeasurement m) {
    if (keyframes.empty()) return MeasurementUse::kRejected;
    if (m.t_ns > newest_imu_ns()) {
      pending.push_back(std::move(m));
      return MeasurementUse::kPending;
    }
    return Apply(m);
  }

  void ApplyDuePending() {
    if (pending.empty()) return;
    const core::Time imu_t = newest_imu_ns();
    std::vector<PendingMeasurement> still;
    for (PendingMeasurement& m : pending) {
      if (m.t_ns <= imu_t) {
        Apply(m);
      } else {
        still.push_back(std::move(m));
      }
    }
    pending = std::move(still);
  }

  // ---- marginalisation ----
  Keyframe* KeyframeOfBlock(const double* data) {
    for (auto& kf : keyframes) {
      if (kf->pose == data || kf->speed_bias == data) return kf.get();
    }
    return nullptr;
  }

  void MarginalizeOldest() {
    PruneOffsets();
    Keyframe* old = keyframes.front().get();
    const auto touches_old = [&](const Factor& f) {
      return std::find(f.keyframes.begin(), f.keyframes.end(), old) != f.keyframes.end();
    };
    // A closed chain's offset goes with the oldest keyframe once nothing else names it but
    // the marginalisation prior.
    std::vector<double*> marginalised = {old->pose, old->speed_bias};
    std::vector<ChainOffset*> leaving;
    for (const auto& o : offsets) {
      if (o->open) continue;
      const bool only_prior_or_old =
          std::all_of(factors.begin(), factors.end(), [&](const auto& f) {
            return !Names(*f, *o) || f->kind == FactorKind::kPrior || touches_old(*f);
          });
      if (only_prior_or_old) {
        leaving.push_back(o.get());
        marginalised.push_back(o->o_L);
      }
    }
    std::vector<Factor*> touching;
    for (auto& f : factors) {
      const bool names_leaving = std::any_of(leaving.begin(), leaving.end(),
                                             [&](const ChainOffset* o) { return Names(*f, *o); });
      if (touches_old(*f) || names_leaving) touching.push_back(f.get());
    }
    std::optional<LinearPrior> prior;
    if (options.marginalize) {
      std::vector<MarginalFactor> linearised;
      for (Factor* f : touching) linearised.push_back({f->cost.get(), f->loss.get(), f->blocks});
      LinearPrior result;
      if (Marginalize(linearised, marginalised, &result)) {
        prior = std::move(result);
      } else {
        ++stats->marginalisation_failures;
      }
    }
    for (Factor* f : touching) RemoveFactor(f);
    for (auto& [sensor, chain] : chains) {
      if (chain.keyframe == old) chain.keyframe = nullptr;
    }
    keyframes.erase(keyframes.begin());
    std::erase_if(offsets, [&](const std::unique_ptr<ChainOffset>& o) {
      return std::find(leaving.begin(), leaving.end(), o.get()) != leaving.end();
    });
    if (prior) stats->chain_offsets_marginalised += static_cast<std::int64_t>(leaving.size());
    if (prior) {
      std::vector<Keyframe*> kfs;
      for (const MarginalBlock& b : prior->blocks) {
        Keyframe* kf = KeyframeOfBlock(b.data);
        if (kf != nullptr && std::find(kfs.begin(), kfs.end(), kf) == kfs.end()) kfs.push_back(kf);
      }
      std::vector<MarginalBlock> blocks = prior->blocks;
      AddFactor(FactorKind::kPrior, std::make_unique<LinearPriorFactor>(std::move(*prior)),
                nullptr, std::move(kfs), std::move(blocks));
    } else if (!options.marginalize && !keyframes.empty()) {
      // Without a prior nothing holds the gauge (position, yaw): hold the oldest pose.
      keyframes.front()->pose_constant = true;
    }
  }

  // ---- propagation ----
  void RebuildPropagation() {
    if (keyframes.empty()) {
      propagation.reset();
      return;
    }
    const Keyframe& newest = *keyframes.back();
    propagation = Preintegrate(newest.t_ns, newest_imu_ns(), newest.bias());
    propagated_to_ns = std::max(newest.t_ns, newest_imu_ns());
  }
};

bool LocalSmootherOptions::IsValid(std::string* why) const {
  auto fail = [why](std::string message) {
    if (why != nullptr) *why = std::move(message);
    return false;
  };
  // The estimator turns the rate into a period (core::PeriodFromRate): at least 1 ns, and
  // small enough for a core::Time.
  if (!(keyframe_rate_hz >= 1e-9 && keyframe_rate_hz <= 1e9)) {
    return fail("keyframe_rate_hz must be in [1e-9, 1e9]");
  }
  if (window_ns <= 0) return fail("window_ns must be positive");
  if (!(gravity_mps2 > 0.0) || !std::isfinite(gravity_mps2)) {
    return fail("gravity_mps2 must be positive and finite");
  }
  // Zero noise makes the IMU and bias factors' information infinite (their constructors
  // refuse it mid-run).
  const std::pair<const char*, double> densities[] = {
      {"gyro_noise_density_radps_per_sqrthz", imu_noise.gyro_noise_density_radps_per_sqrthz},
      {"accel_noise_density_mps2_per_sqrthz", imu_noise.accel_noise_density_mps2_per_sqrthz},
      {"gyro_random_walk_radps2_per_sqrthz", imu_noise.gyro_random_walk_radps2_per_sqrthz},
      {"accel_random_walk_mps3_per_sqrthz", imu_noise.accel_random_walk_mps3_per_sqrthz}};
  for (const auto& [name, value] : densities) {
    if (!(value > 0.0) || !std::isfinite(value)) {
      return fail(std::string("imu_noise.") + name + " must be positive and finite");
    }
  }
  if (imu_only_keyframe_period_ns <= 0) {
    return fail("imu_only_keyframe_period_ns must be positive");
  }
  if (keyframe_merge_tolerance_ns < 0) {
    return fail("keyframe_merge_tolerance_ns must not be negative");
  }
  if (pre_init_imu_buffer_ns < 0) return fail("pre_init_imu_buffer_ns must not be negative");
  if (min_imu_history_ns < 0) return fail("min_imu_history_ns must not be negative");
  // The solver budget is LmOptions' (levenberg_marquardt.h), under this struct's names.
  if (max_iterations < 1) return fail("max_iterations must be at least 1");
  // Infinity is allowed: no wall-time cap.
  if (!(max_solver_time_s > 0.0)) return fail("max_solver_time_s must be positive");
  if (!(function_tolerance >= 0.0) || !std::isfinite(function_tolerance)) {
    return fail("function_tolerance must be >= 0 and finite");
  }
  if (!(initial_trust_region_radius > 0.0) || !std::isfinite(initial_trust_region_radius)) {
    return fail("initial_trust_region_radius must be positive and finite");
  }
  if (!(huber_delta >= 0.0) || !std::isfinite(huber_delta)) {
    return fail("huber_delta must be >= 0 and finite");
  }
  if (!(offset_chain_restart_chi2 > 0.0)) {
    return fail("offset_chain_restart_chi2 must be > 0 (+inf: never restart)");
  }
  if (!(max_speed_mps > 0.0) || !std::isfinite(max_speed_mps)) {
    return fail("max_speed_mps must be positive and finite");
  }
  if (!(max_accel_bias_mps2 > 0.0) || !std::isfinite(max_accel_bias_mps2)) {
    return fail("max_accel_bias_mps2 must be positive and finite");
  }
  if (!(max_gyro_bias_radps > 0.0) || !std::isfinite(max_gyro_bias_radps)) {
    return fail("max_gyro_bias_radps must be positive and finite");
  }
  return true;
}

LocalSmoother::LocalSmoother(LocalSmootherOptions options)
    : options_(options), impl_(std::make_unique<Impl>(options_, &stats_)) {
  std::string why;
  if (!options_.IsValid(&why)) throw std::invalid_argument("LocalSmootherOptions: " + why);
}

LocalSmoother::~LocalSmoother() = default;

bool LocalSmoother::initialized() const { return !impl_->keyframes.empty(); }

core::Time LocalSmoother::newest_imu_ns() const { return impl_->newest_imu_ns(); }

core::Time LocalSmoother::oldest_imu_ns() const {
  return impl_->imu.empty() ? INT64_MAX : impl_->imu.front().t_begin_ns;
}

void LocalSmoother::Reset() {
  Impl& m = *impl_;
  m.factors.clear();
  m.unconfirmed_between.clear();
  m.keyframes.clear();
  m.chains.clear();
  m.offsets.clear();
  m.pending.clear();
  m.propagation.reset();
  m.dirty = false;
}

void LocalSmoother::ResetAfterImuGap() {
  Reset();
  Impl& m = *impl_;
  m.imu.clear();
  m.has_last_raw = false;
}

void LocalSmoother::Initialize(core::Time t_ns, const NavState& state, const ImuBias& bias,
                               const InitialStatePrior& prior) {
  Reset();
  Impl& m = *impl_;
  auto kf = std::make_unique<Keyframe>();
  kf->t_ns = t_ns;
  kf->Set(state, bias);
  Keyframe* raw = kf.get();
  m.keyframes.push_back(std::move(kf));
  Eigen::Matrix<double, 6, 1> pose_std;
  pose_std << prior.position_std_m, prior.rotation_std_rad;
  Eigen::Matrix<double, 9, 1> speed_bias_std;
  speed_bias_std << Eigen::Vector3d::Constant(prior.velocity_std_mps),
      Eigen::Vector3d::Constant(prior.accel_bias_std_mps2),
      Eigen::Vector3d::Constant(prior.gyro_bias_std_radps);
  Eigen::Matrix<double, 6, 6> pose_sqrt_info = pose_std.cwiseInverse().asDiagonal();
  if (prior.rotation_std_in_L) {
    pose_sqrt_info.bottomRightCorner<3, 3>() = prior.rotation_std_rad.cwiseInverse().asDiagonal() *
                                               state.q_LI.normalized().toRotationMatrix();
  }
  const Eigen::Matrix<double, 9, 9> speed_bias_sqrt_info =
      speed_bias_std.cwiseInverse().asDiagonal();
  Eigen::Matrix<double, 7, 1> pose0;
  std::copy(raw->pose, raw->pose + kPoseSize, pose0.data());
  Eigen::Matrix<double, 9, 1> speed_bias0;
  std::copy(raw->speed_bias, raw->speed_bias + kSpeedBiasSize, speed_bias0.data());
  m.AddFactor(FactorKind::kPrior, std::make_unique<PosePriorFactor>(pose0.data(), pose_sqrt_info),
              nullptr, {raw}, {m.PoseBlock(raw)});
  m.AddFactor(FactorKind::kPrior,
              std::make_unique<SpeedBiasPriorFactor>(speed_bias0, speed_bias_sqrt_info), nullptr,
              {raw}, {Impl::SpeedBiasBlock(raw)});
  ++stats_.keyframes;
  m.RebuildPropagation();
}

void LocalSmoother::AddImu(core::Time t_ns, const Eigen::Vector3d& accel_I_mps2,
                           const Eigen::Vector3d& gyro_I_radps) {
  Impl& m = *impl_;
  if (m.has_last_raw && t_ns > m.last_raw_t_ns) {
    ImuInterval s;
    s.t_begin_ns = m.last_raw_t_ns;
    s.t_end_ns = t_ns;
    if (options_.imu_samples_are_interval_averages) {
      s.accel_I_mps2 = accel_I_mps2;
      s.gyro_I_radps = gyro_I_radps;
    } else {
      s.accel_I_mps2 = 0.5 * (accel_I_mps2 + m.last_raw_accel);
      s.gyro_I_radps = 0.5 * (gyro_I_radps + m.last_raw_gyro);
    }
    m.imu.push_back(s);
    if (m.propagation && t_ns > m.propagated_to_ns) {
      const core::Time a = std::max(s.t_begin_ns, m.propagated_to_ns);
      m.propagation->Integrate(s.accel_I_mps2, s.gyro_I_radps, core::TimeToSeconds(t_ns - a));
      m.propagated_to_ns = t_ns;
    }
  }
  m.has_last_raw = true;
  m.last_raw_t_ns = t_ns;
  m.last_raw_accel = accel_I_mps2;
  m.last_raw_gyro = gyro_I_radps;
  if (!initialized()) {
    m.TrimImu();
    return;
  }
  m.ApplyDuePending();
  // Keep the graph running while nothing is fused.
  if (t_ns - m.keyframes.back()->t_ns >= options_.imu_only_keyframe_period_ns &&
      m.pending.empty()) {
    m.KeyframeAt(t_ns, true);
  }
}

MeasurementUse LocalSmoother::AddPose(int sensor, core::Time t_ns, const Eigen::Isometry3d& T_As,
                                      const Eigen::Isometry3d& T_Is,
                                      const Eigen::Matrix<double, 6, 6>& between_sqrt_information,
                                      const std::optional<Eigen::Matrix3d>& R_LA,
                                      const std::optional<PoseNoise>& noise) {
  if (!T_As.matrix().allFinite() || !between_sqrt_information.allFinite()) {
    return MeasurementUse::kRejected;
  }
  PendingMeasurement p;
  p.is_pose = true;
  p.sensor = sensor;
  p.t_ns = t_ns;
  p.T_As = T_As;
  p.T_Is = T_Is;
  p.sqrt_information = between_sqrt_information;
  if (R_LA) {
    if (!R_LA->allFinite() || noise) return MeasurementUse::kRejected;
    p.position_in_reference = true;
    p.R_LA = *R_LA;
  }
  if (noise) {
    // A covariance read back from text is symmetric, and positive semi-definite, to its
    // digits only: a rounding's negative eigenvalue is clamped, a larger one rejected.
    Eigen::Matrix<double, 6, 6> W = 0.5 * (noise->white_covariance + noise->white_covariance.transpose());
    bool psd = W.allFinite() && Eigen::LDLT<Eigen::Matrix<double, 6, 6>>(W).isPositive();
    if (!psd && W.allFinite()) {
      const Eigen::SelfAdjointEigenSolver<Eigen::Matrix<double, 6, 6>> eigen(W);
      const Eigen::Matrix<double, 6, 1> lambda = eigen.eigenvalues();
      psd = lambda.minCoeff() >= -1e-9 * lambda.cwiseAbs().maxCoeff();
      W = eigen.eigenvectors() * lambda.cwiseMax(0.0).asDiagonal() * eigen.eigenvectors().transpose();
    }
    const bool valid = psd &&
                       noise->drift.position_random_walk_m_per_sqrtm >= 0.0 &&
                       noise->drift.rotation_random_walk_rad_per_sqrtm >= 0.0 &&
                       noise->min_position_std_m > 0.0 && noise->min_rotation_std_rad > 0.0 &&
                       std::isfinite(noise->drift.position_random_walk_m_per_sqrtm +
                                     noise->drift.rotation_random_walk_rad_per_sqrtm +
                                     noise->min_position_std_m + noise->min_rotation_std_rad);
    if (!valid) return MeasurementUse::kRejected;
    p.pose_noise = noise;
    p.pose_noise->white_covariance = W;
  }
  return impl_->Submit(std::move(p));
}

MeasurementUse LocalSmoother::AddPosition(int sensor, core::Time t_ns, const Eigen::Vector3d& p_As,
                                          const Eigen::Matrix3d& covariance_A,
                                          const Eigen::Vector3d& p_Is, const Eigen::Matrix3d& R_LA,
                                          double min_std_m,
                                          const std::optional<Eigen::Vector3d>& p_LA) {
  std::optional<PendingMeasurement> p =
      PositionMeasurement(sensor, t_ns, p_As, covariance_A, p_Is, R_LA, min_std_m);
  if (!p) return MeasurementUse::kRejected;
  if (p_LA) {
    if (!p_LA->allFinite()) return MeasurementUse::kRejected;
    p->p_LA = p_LA;
  }
  return impl_->Submit(std::move(*p));
}

MeasurementUse LocalSmoother::AddPositionWithOffset(int sensor, core::Time t_ns,
                                                    const Eigen::Vector3d& p_As,
                                                    const Eigen::Matrix3d& covariance_A,
                                                    const Eigen::Vector3d& p_Is,
                                                    const Eigen::Matrix3d& R_LA, double min_std_m) {
  std::optional<PendingMeasurement> p =
      PositionMeasurement(sensor, t_ns, p_As, covariance_A, p_Is, R_LA, min_std_m);
  if (!p) return MeasurementUse::kRejected;
  p->with_offset = true;
  return impl_->Submit(std::move(*p));
}

void LocalSmoother::EndChain(int sensor) {
  if (auto chain = impl_->chains.find(sensor); chain != impl_->chains.end()) {
    Impl::Close(chain->second);
    impl_->chains.erase(chain);
  }
  auto& pending = impl_->pending;
  pending.erase(std::remove_if(pending.begin(), pending.end(),
                               [&](const PendingMeasurement& m) { return m.sensor == sensor; }),
                pending.end());
}

int LocalSmoother::DiscardSensor(int sensor, core::Time after_ns) {
  EndChain(sensor);
  Impl& m = *impl_;
  std::vector<Factor*> discard;
  for (const auto& f : m.factors) {
    if (f->kind == FactorKind::kBetween && f->sensor == sensor && f->keyframes.back()->t_ns > after_ns) {
      discard.push_back(f.get());
    }
  }
  for (Factor* f : discard) m.RemoveFactor(f);
  if (!discard.empty()) m.dirty = true;
  stats_.faulty_between_factors += static_cast<int64_t>(discard.size());
  return static_cast<int>(discard.size());
}

bool LocalSmoother::Update() {
  Impl& m = *impl_;
  if (m.keyframes.empty() || !m.dirty) return false;
  // Snapshot to revert a bad solve.
  std::vector<std::pair<std::array<double, kPoseSize>, std::array<double, kSpeedBiasSize>>> saved;
  for (auto& kf : m.keyframes) {
    std::pair<std::array<double, kPoseSize>, std::array<double, kSpeedBiasSize>> s;
    std::copy(kf->pose, kf->pose + kPoseSize, s.first.begin());
    std::copy(kf->speed_bias, kf->speed_bias + kSpeedBiasSize, s.second.begin());
    saved.push_back(s);
  }
  WindowSolverOptions solver;
  solver.max_iterations = options_.max_iterations;
  solver.max_time_s = options_.max_solver_time_s;
  solver.function_tolerance = options_.function_tolerance;
  solver.initial_trust_region_radius = options_.initial_trust_region_radius;
  m.PruneOffsets();
  m.BuildWindow();
  std::vector<std::array<double, kWindowOffsetSize>> saved_offsets;
  for (const auto& o : m.offsets) {
    saved_offsets.emplace_back();
    std::copy(o->o_L, o->o_L + kWindowOffsetSize, saved_offsets.back().begin());
  }
  const auto start = std::chrono::steady_clock::now();
  const WindowSolveSummary summary =
      m.solver.Solve(m.window_states, m.window_factors, solver, m.window_offsets);
  stats_.solve_time_s.push_back(
      std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count());
  ++stats_.solves;
  stats_.iterations += summary.iterations;
  if (summary.termination == WindowTermination::kIterationCap) ++stats_.iteration_cap_hits;
  if (summary.termination == WindowTermination::kTimeCap) ++stats_.time_cap_hits;
  bool good = summary.termination != WindowTermination::kFailure &&
              std::isfinite(summary.final_cost);
  for (const auto& o : m.offsets) {
    good = good && std::all_of(o->o_L, o->o_L + kWindowOffsetSize,
                               [](double v) { return std::isfinite(v); });
  }
  for (auto& kf : m.keyframes) {
    if (!good) break;
    const NavState s = kf->state();
    const ImuBias b = kf->bias();
    good = Finite(*kf) && s.v_L_mps.norm() <= options_.max_speed_mps &&
           b.accel_mps2.norm() <= options_.max_accel_bias_mps2 &&
           b.gyro_radps.norm() <= options_.max_gyro_bias_radps;
  }
  if (!good) {
    ++stats_.bad_solves;
    for (std::size_t i = 0; i < m.keyframes.size(); ++i) {
      std::copy(saved[i].first.begin(), saved[i].first.end(), m.keyframes[i]->pose);
      std::copy(saved[i].second.begin(), saved[i].second.end(), m.keyframes[i]->speed_bias);
    }
    for (std::size_t i = 0; i < saved_offsets.size(); ++i) {
      std::copy(saved_offsets[i].begin(), saved_offsets[i].end(), m.offsets[i]->o_L);
    }
    // The measurements that made the solve go wrong leave with it; their sensors' chains
    // restart at the next measurement.
    const std::vector<Factor*> discard = std::move(m.unconfirmed_between);
    m.unconfirmed_between.clear();
    for (Factor* f : discard) {
      ++stats_.discarded_between_factors;
      m.RemoveFactor(f);
    }
    for (auto& [sensor, chain] : m.chains) Impl::Close(chain);
    m.chains.clear();
  }
  m.unconfirmed_between.clear();
  m.dirty = false;
  const core::Time newest = m.keyframes.back()->t_ns;
  while (m.keyframes.size() > 2 && m.keyframes.front()->t_ns < newest - options_.window_ns) {
    m.MarginalizeOldest();
  }
  m.TrimImu();
  m.RebuildPropagation();
  return good;
}

std::optional<NavState> LocalSmoother::PredictWithImu(core::Time t_from, const NavState& state,
                                                      const ImuBias& bias,
                                                      core::Time t_to) const {
  const std::optional<ImuPreintegration> pre = PreintegrateImu(t_from, t_to, bias);
  if (!pre) return std::nullopt;
  return pre->Predict(state, bias, impl_->gravity_L);
}

std::optional<ImuPreintegration> LocalSmoother::PreintegrateImu(core::Time t_from,
                                                                core::Time t_to,
                                                                const ImuBias& bias) const {
  const Impl& m = *impl_;
  if (m.imu.empty() || t_from < m.imu.front().t_begin_ns || t_to > m.newest_imu_ns() ||
      t_to < t_from) {
    return std::nullopt;
  }
  return m.Preintegrate(t_from, t_to, bias);
}

std::optional<KeyframeState> LocalSmoother::NewestKeyframe() const {
  if (impl_->keyframes.empty()) return std::nullopt;
  return impl_->keyframes.back()->Public();
}

std::optional<KeyframeState> LocalSmoother::Propagated() const {
  const Impl& m = *impl_;
  if (m.keyframes.empty() || !m.propagation) return std::nullopt;
  const Keyframe& newest = *m.keyframes.back();
  KeyframeState out;
  out.t_ns = std::max(newest.t_ns, m.propagated_to_ns);
  out.bias = newest.bias();
  out.state = m.propagation->Predict(newest.state(), out.bias, m.gravity_L);
  out.imu_only = newest.imu_only;
  return out;
}

std::vector<KeyframeState> LocalSmoother::Keyframes() const {
  std::vector<KeyframeState> out;
  for (const auto& kf : impl_->keyframes) out.push_back(kf->Public());
  return out;
}

std::optional<Eigen::Matrix<double, 15, 15>> LocalSmoother::NewestCovariance() const {
  Impl& m = *impl_;
  if (m.keyframes.empty()) return std::nullopt;
  // Σ = H⁻¹ of the window's information at the current estimate (Laplace approximation),
  // read off the banded Cholesky factor with the newest keyframe ordered last among the
  // states, the offsets marginalised (WindowSolver::LastStateCovariance).
  m.BuildWindow();
  return m.solver.LastStateCovariance(m.window_states, m.window_factors, m.window_offsets);
}

}  // namespace tofu::estimator
