#pragma once
// The local graph of the seed paper (Lanegger et al., Sec. 2.2, "Local State Estimation"):
// a fixed-lag smoother over keyframe states x_i = [q_LI, p_LI, v_L, b_a, b_g] of the IMU
// frame I in the local frame L, constrained by IMU preintegration (Forster et al. 2016),
// bias random walks, and the relative "between" factors of the fused sensors: the pose
// between factor r^o (eq. 2) and the position between factor r^p (eq. 3). States leaving
// the window are marginalised into a linear prior (Schur complement), not dropped.
//
// Velocity is kept in L rather than in I as in the paper's state: the IMU factor of
// Forster et al. is written for it, and v_I = R_LIᵀ v_L is one rotation away.
//
// L: gravity along −z; its yaw and origin are gauge freedoms that the first state's prior
// fixes (the estimator chooses them from the first fused sensor) and that marginalisation
// carries forward.
// Library code: Eigen + Ceres only. Not thread-safe; one instance per estimator.

#include <cstdint>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include <Eigen/Core>
#include <Eigen/Geometry>

#include "core/time.h"
#include "core/units.h"
#include "estimator/imu_preintegration.h"
#include "estimator/pose_noise.h"

namespace tofu::estimator {

struct LocalSmootherOptions {
  /// Keyframes per fused sensor at most at this rate (paper: the local graph runs at 30 Hz).
  double keyframe_rate_hz = 30.0;
  /// Fixed lag (paper: 0.5 s): keyframes older than newest − window are marginalised.
  core::Time window_ns = 500'000'000;
  /// false: states leaving the window are dropped and the oldest kept pose is held fixed
  /// instead (only to show what marginalisation is worth).
  bool marginalize = true;
  double gravity_mps2 = core::kWorldGravity_mps2;
  ImuNoiseParams imu_noise;
  /// true: an IMU sample stamped t_k is the average over (t_{k−1}, t_k] (tofu's simulated
  /// IMU, most MEMS IMUs with a decimation filter); false: an instantaneous sample, and
  /// (t_{k−1}, t_k] is integrated with the mean of samples k−1 and k (e.g. EuRoC's ADIS).
  bool imu_samples_are_interval_averages = true;
  /// IMU-only keyframes are inserted when no fused measurement made one for this long:
  /// the graph keeps running (and its uncertainty grows) while no sensor is fused.
  core::Time imu_only_keyframe_period_ns = 100'000'000;
  /// A measurement within this of an existing keyframe uses it instead of a new one.
  core::Time keyframe_merge_tolerance_ns = 200'000;
  /// IMU history kept before the graph exists (for initialisation from a rest state).
  core::Time pre_init_imu_buffer_ns = 6'000'000'000;
  /// IMU history kept at least this long while the graph runs (0: only what the window
  /// needs). A caller measuring a stream against the IMU over a window needs it.
  core::Time min_imu_history_ns = 0;

  // ---- solver budget ----
  int max_iterations = 6;
  double max_solver_time_s = 0.005;
  /// Relative cost decrease below which a solve stops. A warm-started window converges in
  /// two or three Gauss-Newton steps; what LM does after that moves states by micrometres.
  double function_tolerance = 1e-5;
  /// First LM step's trust-region radius: λ = 1e-8 diag(H). Almost Gauss-Newton, yet not
  /// nothing: the IMU factors' diagonal is ~1e10 where position and yaw have a marginal
  /// information of ~1e2, so each solve moves the weakly observed directions a little less
  /// than the undamped optimum of its window. Measured on estimator_arena, that is better
  /// for every metric: VIO fused ATE 1.86 vs 1.90 cm, RPE over 1 s 0.90 vs 1.00 cm; total
  /// station fused 3.1 vs 3.3 mm. Ceres's default 1e4 damped warm starts so much that two
  /// thirds of the solves hit the iteration cap.
  double initial_trust_region_radius = 1e8;
  /// > 0: Huber loss on the between factors, in standard deviations.
  double huber_delta = 0.0;
  /// AddPositionWithOffset: a position whose displacement from the chain's previous one
  /// disagrees with the states' beyond this squared Mahalanobis distance (both positions'
  /// covariances; χ²(3) at 1 − 1e-6 by default) starts a new chain: the sensor's frame
  /// jumped (a wrong GNSS fix, a total station re-locked on another prism), and a chain
  /// that kept its offset would pull the state by the whole jump in one solve. The paper's
  /// displacements take such a jump once, in one factor; a new chain takes none of it.
  double offset_chain_restart_chi2 = 30.7;

  // ---- sanity limits: a solve beyond them is a bad solve (reverted, counted) ----
  double max_speed_mps = 50.0;
  double max_accel_bias_mps2 = 3.0;
  double max_gyro_bias_radps = 0.5;

  /// True when the options are usable; otherwise false with the broken constraint in
  /// *why (if why is not null).
  bool IsValid(std::string* why = nullptr) const;
};

/// One keyframe state of the local graph.
struct KeyframeState {
  core::Time t_ns = 0;
  NavState state;
  ImuBias bias;
  bool imu_only = false;  ///< no fused measurement made this keyframe
};

/// Prior of the first state, standard deviations per tangent direction.
struct InitialStatePrior {
  Eigen::Vector3d position_std_m = Eigen::Vector3d::Constant(1e-3);
  /// Right perturbation of R_LI; roll/pitch from gravity, yaw a gauge choice.
  Eigen::Vector3d rotation_std_rad = Eigen::Vector3d(0.02, 0.02, 1e-3);
  double velocity_std_mps = 0.1;
  double accel_bias_std_mps2 = 0.1;
  double gyro_bias_std_radps = 0.005;
  /// true: rotation_std_rad is about L's axes (x, y: tilt; z: yaw about gravity), i.e.
  /// the prior's information on the right perturbation is diag(1/σ) R_LI. For an IMU
  /// whose z axis is not vertical (EuRoC's ADIS16448 has x up) a tight "yaw" std on I's
  /// own z axis would pin a tilt.
  bool rotation_std_in_L = false;
};

struct LocalSmootherStats {
  std::int64_t keyframes = 0;
  std::int64_t late_keyframes = 0;        ///< inserted before the newest keyframe
  std::int64_t too_old_measurements = 0;  ///< older than the window: not used
  std::int64_t solves = 0;
  std::int64_t iterations = 0;            ///< Levenberg-Marquardt iterations, all solves
  std::int64_t iteration_cap_hits = 0;
  std::int64_t time_cap_hits = 0;
  std::int64_t bad_solves = 0;            ///< non-finite or out-of-limits result, reverted
  std::int64_t discarded_between_factors = 0;  ///< removed with a bad solve
  std::int64_t faulty_between_factors = 0;     ///< removed by DiscardSensor
  std::int64_t marginalisation_failures = 0;
  std::int64_t chain_offsets = 0;               ///< AddPositionWithOffset chains started
  std::int64_t chain_offset_restarts = 0;       ///< of them, at a jump of the frame
  std::int64_t chain_offsets_marginalised = 0;  ///< their offsets gone with the prior
  std::vector<double> solve_time_s;       ///< wall time of each solve (for benchmarks)
};

enum class MeasurementUse {
  kFactor,      ///< a between factor was added
  kAnchor,      ///< first measurement of a chain: a keyframe, no factor yet
  kPending,     ///< waiting for the IMU to reach its time
  kSkipped,     ///< closer than 1/keyframe_rate to the sensor's previous keyframe
  kTooOld,      ///< before the window: dropped
  kRejected,    ///< not initialised, or non-finite
};

/// A pose's own noise (LocalSmoother::AddPose): its white covariance in
/// core::PoseMeasurement's order [δθ_s; δp_A], the stream's drift, and floors added to the
/// between factor's stds.
struct PoseNoise {
  Eigen::Matrix<double, 6, 6> white_covariance = Eigen::Matrix<double, 6, 6>::Zero();
  PoseDriftRates drift;
  double min_position_std_m = 0.0;
  double min_rotation_std_rad = 0.0;
};

class LocalSmoother {
 public:
  /// Throws std::invalid_argument when options.IsValid() is false.
  explicit LocalSmoother(LocalSmootherOptions options = {});
  ~LocalSmoother();
  LocalSmoother(const LocalSmoother&) = delete;
  LocalSmoother& operator=(const LocalSmoother&) = delete;

  const LocalSmootherOptions& options() const { return options_; }
  bool initialized() const;

  /// Starts the graph with a first keyframe at t_ns (IMU samples up to t_ns must have been
  /// added) and a prior on it. Clears any previous graph.
  void Initialize(core::Time t_ns, const NavState& state, const ImuBias& bias,
                  const InitialStatePrior& prior);
  /// Forgets the graph (IMU buffer kept).
  void Reset();
  /// Forgets the graph and the IMU buffer: after a gap in the IMU stream no interval may
  /// span the gap, so the next sample starts a new buffer.
  void ResetAfterImuGap();

  /// IMU sample; t_ns strictly increasing and values finite (the caller gates them).
  void AddImu(core::Time t_ns, const Eigen::Vector3d& accel_I_mps2,
              const Eigen::Vector3d& gyro_I_radps);

  /// Pose of mount frame s in the sensor's reference frame A, with the square-root
  /// information of the between factor it forms with the sensor's previous keyframe
  /// (order [δp; δθ] of the relative motion of I). T_Is: the mount in I.
  /// With R_LA given, the position part of the relative measurement is taken in the
  /// sensor's reference frame A instead of the body (a position between factor r^p of the
  /// mount point, eq. 3, beside a rotation-only r^o): the displacement then does not
  /// inherit the sensor's attitude errors, at the price of needing T_AL.
  /// With `noise` (not with R_LA), the between factor's covariance is the stream's own,
  /// from this pose's and the previous one's white errors and the drift between them
  /// (PoseBetweenCovariance, pose_noise.h, plus the floors), and between_sqrt_information
  /// multiplies its square-root information from the right: a projector that leaves out
  /// directions the sensor does not observe, or the identity.
  MeasurementUse AddPose(int sensor, core::Time t_ns, const Eigen::Isometry3d& T_As,
                         const Eigen::Isometry3d& T_Is,
                         const Eigen::Matrix<double, 6, 6>& between_sqrt_information,
                         const std::optional<Eigen::Matrix3d>& R_LA = std::nullopt,
                         const std::optional<PoseNoise>& noise = std::nullopt);
  /// Position of mount point s in A; R_LA from the sensor's alignment graph (frozen while
  /// the sensor is fused); covariance of the single measurement (the between factor's is
  /// the sum of both ends').
  /// With p_LA (the translation of the frozen T_LA) each position constrains its keyframe
  /// directly in L (PositionInLocalFactor) instead of a displacement; min_std_m is then
  /// added to the single measurement's std.
  MeasurementUse AddPosition(int sensor, core::Time t_ns, const Eigen::Vector3d& p_As,
                             const Eigen::Matrix3d& covariance_A, const Eigen::Vector3d& p_Is,
                             const Eigen::Matrix3d& R_LA, double min_std_m,
                             const std::optional<Eigen::Vector3d>& p_LA = std::nullopt);
  /// Position of mount point s in A, constraining its keyframe in L up to an offset o_L
  /// that the graph estimates, one per chain (PositionWithOffsetFactor): r = p_Ls −
  /// (R_LA p_As + o_L). A chain's offset starts at zero residual on its first position and
  /// is free (no prior): the chain constrains the motion since its start, with the
  /// correlation that the paper's displacements (eq. 3) leave out, and a sensor fused again
  /// starts a new chain without a jump. The offset leaves the graph, marginalised, once
  /// its chain has ended and no factor but the marginalisation prior names it.
  MeasurementUse AddPositionWithOffset(int sensor, core::Time t_ns, const Eigen::Vector3d& p_As,
                                       const Eigen::Matrix3d& covariance_A,
                                       const Eigen::Vector3d& p_Is, const Eigen::Matrix3d& R_LA,
                                       double min_std_m);
  /// Ends a sensor's chain of between factors (the sensor is no longer fused, or its
  /// frame jumped): its next measurement starts a new chain.
  void EndChain(int sensor);
  /// A sensor found faulty: ends its chain and removes its between factors that end after
  /// after_ns from the window (what it said since then must not constrain the graph; the
  /// part already marginalised into the prior cannot be taken back). The next Update
  /// solves again. Returns the number of factors removed.
  int DiscardSensor(int sensor, core::Time after_ns);

  /// Solves if a keyframe was added since the last solve, then marginalises what left the
  /// window. Returns true if it solved.
  bool Update();

  /// Newest keyframe, and the state propagated with the IMU to the newest IMU sample.
  std::optional<KeyframeState> NewestKeyframe() const;
  std::optional<KeyframeState> Propagated() const;
  /// All keyframes in the window, oldest first.
  std::vector<KeyframeState> Keyframes() const;
  /// Covariance of the newest keyframe, tangent order [δp, δθ, δv, δb_a, δb_g]
  /// (δθ right perturbation of R_LI), from the window's information matrix.
  std::optional<Eigen::Matrix<double, 15, 15>> NewestCovariance() const;

  /// `state` at t_from propagated with the buffered IMU to t_to (nullopt if the buffer
  /// does not cover the interval).
  std::optional<NavState> PredictWithImu(core::Time t_from, const NavState& state,
                                         const ImuBias& bias, core::Time t_to) const;

  /// Preintegration of the buffered IMU over [t_from, t_to] at `bias` (nullopt if the
  /// buffer does not cover the interval): the same intervals the graph's IMU factors use.
  std::optional<ImuPreintegration> PreintegrateImu(core::Time t_from, core::Time t_to,
                                                   const ImuBias& bias) const;

  const LocalSmootherStats& stats() const { return stats_; }
  core::Time newest_imu_ns() const;
  /// Start of the IMU buffer (INT64_MAX when empty).
  core::Time oldest_imu_ns() const;

 private:
  struct Impl;
  LocalSmootherOptions options_;
  LocalSmootherStats stats_;
  std::unique_ptr<Impl> impl_;
};

}  // namespace tofu::estimator
