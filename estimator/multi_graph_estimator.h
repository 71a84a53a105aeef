#pragma once
// The loosely coupled multi-graph estimator of the seed paper (Lanegger et al., Sec. 2.2):
// one local graph (LocalSmoother: IMU + the relative factors of the sensors chosen for
// fusion) and one frame-alignment graph per sensor (AlignmentGraph: T_AL from the sensor's
// positions against the local estimate). Which sensors constrain the local graph is the
// caller's choice at any time (SetFusedSensors): consensus, a baseline, or none (IMU-only
// propagation, flagged invalid after max_unfused_ns).
//
// Online use: timestamped measurements in (Add), estimates out at the output rate
// (TakeOutputs). Bad data never throws: NaN/Inf values, out-of-order and duplicate
// timestamps are rejected per stream and counted (monotonic gating per stream, as PX4's
// EKF2 does for its sensor buffers).
// Library code: Eigen + Ceres only.

#include <cstdint>
#include <map>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include <Eigen/Core>
#include <Eigen/Geometry>

#include "core/measurement.h"
#include "core/time.h"
#include "core/units.h"
#include "estimator/alignment_graph.h"
#include "estimator/imu_preintegration.h"
#include "estimator/local_smoother.h"
#include "estimator/mission_frame.h"
#include "estimator/pose_noise.h"
#include "estimator/visual_inertial_alignment.h"

namespace tofu::estimator {

enum class SensorKind { kPose, kPosition };

/// How a position sensor (total station, GNSS) constrains the local graph
/// (local_smoother.h AddPosition, AddPositionWithOffset).
enum class PositionFactors {
  kBetween,   ///< displacements between its keyframes (the paper's eq. 3)
  kAbsolute,  ///< each position in L through the frozen T_AL (beyond the paper)
  kOffset,    ///< each position in L up to an offset per chain the graph estimates: the
              ///< displacements with their correlation (beyond the paper)
};

/// How a pose sensor's between factors are weighted.
enum class PoseBetweenNoise {
  kConstant,       ///< one std per factor (between_*_std_m below; the paper's ω_o, ω_q)
  kWhiteAndDrift,  ///< the stream's white error at both ends plus its drift over the
                   ///< distance between the keyframes, bounding the ends' correlation
                   ///< (pose_noise.h; beyond the paper)
};

/// A sensor the estimator can fuse.
struct SensorSpec {
  std::string name;
  SensorKind kind = SensorKind::kPose;
  /// Mount frame s in the IMU frame I (extrinsic calibration).
  Eigen::Isometry3d T_Is = Eigen::Isometry3d::Identity();
  /// Pose sensors: weights of the pose between factor, the paper's concentration
  /// parameters ω_o, ω_q (eq. 2) as the standard deviation of one relative measurement
  /// between keyframes. Odometry's reported absolute covariance grows with its drift and
  /// says nothing about its short-term relative accuracy, so it is not used here.
  double between_position_std_m = 0.01;
  double between_rotation_std_rad = 0.01;
  /// Pose sensors: take the relative position in the sensor's reference frame A (through
  /// the frozen R_AL) rather than in the body as the paper's eq. (2) does. A visual
  /// odometry whose attitude is noisier than its positions (the common case) then does
  /// not bend the fused path with its attitude errors.
  bool between_position_in_reference = false;
  /// Pose sensors without a stated noise (a TUM file): the between-factor stds above are
  /// replaced by the stream's own scatter measured against the IMU over the initial
  /// alignment window (visual_inertial_alignment.h), floored at the values below.
  bool between_noise_from_data = false;
  /// Pose sensors: PoseBetweenNoise::kWhiteAndDrift takes each pose's white error from
  /// the stds below (a VIO's stated covariance is a tracking confidence, not its error),
  /// or, where they are 0, from the sample's stated covariance (a LiDAR odometry states
  /// its registration's); and its drift from `drift`. The floors min_between_* are added.
  PoseBetweenNoise pose_between_noise = PoseBetweenNoise::kConstant;
  double white_position_std_m = 0.0;
  double white_rotation_std_rad = 0.0;
  PoseDriftRates drift;
  double min_between_position_std_m = 5e-4;
  double min_between_rotation_std_rad = 1e-3;
  /// Pose sensors whose stated covariance is the inverse of their registration's
  /// information (a LiDAR odometry): a direction along which that information, with the
  /// other block held fixed, is below 1/std² is one the sensor says it does not observe
  /// (degenerate; Zhang, Kaess & Singh, ICRA 2016, where λ σ_r² < threshold). Its between
  /// factor leaves such directions out, so the drift there is not fused. 0: every
  /// direction is fused with the weights above (the paper).
  double unobserved_position_std_m = 0.0;
  double unobserved_rotation_std_rad = 0.0;
  /// Position sensors: floor on the std (m) of one between factor, added to the stated
  /// covariances of its two ends; of one position with PositionFactors::kAbsolute or
  /// kOffset (so 2·min² on a displacement of an offset chain).
  double min_position_std_m = 0.002;
  /// Position sensors: how each position constrains the local graph. The paper's
  /// displacements keep the local graph free to switch sensors without a jump but are
  /// fused as independent although consecutive ones share a position's noise (an absolute
  /// sensor becomes relative: fused with a drifting odometry, the estimate drifts too).
  PositionFactors position_factors = PositionFactors::kBetween;
  /// Position sensors: the reference frame A is levelled (a total station, GNSS ENU). When
  /// such a sensor is the first one fused, L is chosen with R_AL = I.
  bool reference_is_gravity_aligned = true;
};

struct MultiGraphEstimatorOptions {
  LocalSmootherOptions local;
  AlignmentGraphOptions alignment;
  core::Time output_period_ns = 5'000'000;  ///< 200 Hz output (paper)
  /// IMU-only propagation longer than this (no fused measurement) flags the output invalid.
  core::Time max_unfused_ns = 1'000'000'000;
  /// Covariance of the newest keyframe attached to the outputs at most this often (0: never).
  core::Time covariance_period_ns = 100'000'000;

  // ---- initialisation ----
  /// Rest detection over this window: per-axis std of gyro and accelerometer below the
  /// thresholds. At rest, gravity fixes roll and pitch and the gyro mean is its bias.
  core::Time static_window_ns = 500'000'000;
  double static_max_gyro_std_radps = 0.05;
  double static_max_accel_std_mps2 = 0.6;
  /// Rest state older than this at the first fused measurement: initialise in motion.
  core::Time max_rest_age_ns = 5'000'000'000;
  InitialStatePrior prior_from_rest;
  /// In motion (no rest state fresher than max_rest_age_ns), or when a pose stream's noise
  /// is to be measured: the local graph starts from a visual-inertial alignment of the
  /// first fused pose stream's window with the IMU, once it makes gravity observable
  /// (outputs before that are not produced). The window keeps at most
  /// max_alignment_window_ns; after max_initialisation_wait_ns without an observable
  /// alignment the estimator falls back to gravity from the mean specific force.
  /// visual_inertial.gravity_mps2 must equal local.gravity_mps2 (IsValid): the
  /// estimator has one gravity.
  VisualInertialAlignmentOptions visual_inertial;
  core::Time max_alignment_window_ns = 3'000'000'000;
  core::Time max_initialisation_wait_ns = 5'000'000'000;
  /// A pose stream's noise measured once the graph already runs (after a rest start) is
  /// measured over at least this much of it: twice the alignment's minimum, since there
  /// is no hurry then. On EuRoC V1_02 the between weights measured over the first 1 s
  /// (during the VIO's take-off transient) gave 6.6 cm ATE, over 2 s 5.5 cm.
  core::Time min_noise_window_ns = 2'000'000'000;
  /// An IMU stream that skips more than max(imu_gap_periods x its usual period,
  /// min_imu_gap_ns) has a gap: nothing can be propagated across it, so the local graph
  /// is dropped and re-initialised from the fused sensors after the gap, in the same
  /// local frame L (the fused sensors' frozen T_AL are kept).
  double imu_gap_periods = 5.0;
  core::Time min_imu_gap_ns = 20'000'000;
  InitialStatePrior prior_in_motion = {Eigen::Vector3d::Constant(1e-3),
                                       Eigen::Vector3d(0.1, 0.1, 1e-3), 2.0, 0.2, 0.01};
  /// A position sensor is fused only with a T_AL whose rotation std is below this and
  /// whose window rms residual is below max_alignment_rms_m (then frozen, paper Sec. 2.2).
  double max_alignment_rotation_std_rad = core::RadFromDeg(0.5);
  double max_alignment_rms_m = 0.05;
  /// Uncertainty of the local estimate's positions over an alignment window, added to each
  /// pair's sensor covariance.
  double alignment_local_position_std_m = 0.02;
  /// Position sensors fused as absolute (PositionFactors::kAbsolute), fused again
  /// while the local graph runs: L drifted with the other sensors meanwhile, and unary
  /// factors would pull it back in one solve (a step of the state the controller flies
  /// on: 0.12 m when the total station came back in total_station_jump). Instead the
  /// offset between the sensor's first position and the state is taken off its positions
  /// and removed at this rate (m/s), so the state slews to the sensor's frame. 0: no
  /// slew (the pull in one solve).
  double absolute_readmission_rate_mps = 0.1;
  /// Consecutive bad solves after which the local graph is re-initialised from the
  /// propagated state.
  int max_consecutive_bad_solves = 3;
  /// The global output T_ML (estimator/mission_frame.h), published once a mission survey
  /// is given (SetMissionSurvey).
  MissionFrameOptions mission;

  /// True when the options (the nested ones too) are usable; otherwise false with the
  /// broken constraint in *why (if why is not null).
  bool IsValid(std::string* why = nullptr) const;
};

/// One output sample (200 Hz): the newest state propagated with the IMU.
struct EstimatorOutput {
  core::Time t_ns = 0;
  NavState state;                  ///< T_LI and v_L
  ImuBias bias;
  Eigen::Vector3d omega_I_radps = Eigen::Vector3d::Zero();  ///< bias-corrected gyro
  bool initialized = false;        ///< the local graph exists
  bool valid = false;              ///< initialised and fused within max_unfused_ns
  std::vector<std::string> fused;  ///< sensors constraining the local graph
  /// Covariance of p_LI [m²]: the position block of the newest keyframe's marginal
  /// covariance of [δp, δθ, δv, δb_a, δb_g], when computed for this output. Only this
  /// block is kept: every output of a flight is held until its end (200 Hz per method),
  /// and the whole 15x15 made an output 2 kB (issue 19: memory grows with flight time).
  std::optional<Eigen::Matrix3d> position_covariance_m2;
  /// The mission frame in L (estimator/mission_frame.h), once a survey was given and
  /// either the launch pad registered L or a trusted surveyed sensor aligned it.
  std::optional<MissionFrameEstimate> mission;
};

/// How and when the local graph was (re-)initialised.
struct InitialisationRecord {
  enum class Method { kRest, kVisualInertial, kMeanSpecificForce };
  core::Time t_ns = 0;
  Method method = Method::kRest;
  std::string sensor;  ///< the fused sensor that initialised it
  bool after_imu_gap = false;
  /// The initial state (gravity direction is its z axis in L).
  NavState state;
  ImuBias bias;
  /// Visual-inertial: the window, the gravity direction's 1σ, and the stream noise
  /// measured (used when the sensor's between_noise_from_data).
  double window_s = 0.0;
  double gravity_direction_std_rad = 0.0;
  double relative_position_std_m = 0.0;
  double relative_rotation_std_rad = 0.0;
  bool noise_from_data = false;
};

const char* InitialisationMethodName(InitialisationRecord::Method method);

/// Per-stream gate counters.
struct StreamGateCounters {
  std::int64_t accepted = 0;
  std::int64_t rejected_non_finite = 0;
  std::int64_t rejected_out_of_order = 0;
  std::int64_t rejected_duplicate = 0;
  /// Stamps outside ±core::kMaxValidTimeNs (e.g. INT64_MAX): no arithmetic on such a
  /// stamp can be trusted.
  std::int64_t rejected_time_out_of_range = 0;
  std::int64_t not_fused_unaligned = 0;  ///< fused position sensor without a usable T_AL
};

struct EstimatorCounters {
  std::map<std::string, StreamGateCounters> streams;
  std::int64_t unknown_stream = 0;
  std::int64_t reinitialisations = 0;
  /// New local windows started because a fused measurement came after more than
  /// max_unfused_ns of IMU-only propagation.
  std::int64_t restarts_after_gap = 0;
  /// Gaps in the IMU stream (see MultiGraphEstimatorOptions::imu_gap_periods) and their
  /// total length.
  std::int64_t imu_gaps = 0;
  double imu_gap_total_s = 0.0;

  std::int64_t consecutive_bad_solves = 0;
};

class MultiGraphEstimator {
 public:
  /// Throws std::invalid_argument when options.IsValid() is false.
  MultiGraphEstimator(std::string imu_name, std::vector<SensorSpec> sensors,
                      MultiGraphEstimatorOptions options = {});
  ~MultiGraphEstimator();
  MultiGraphEstimator(const MultiGraphEstimator&) = delete;
  MultiGraphEstimator& operator=(const MultiGraphEstimator&) = delete;

  /// Any measurement of a known stream, in arrival order. Never throws for bad data.
  void Add(const core::StampedMeasurement& measurement);

  /// The sensors that constrain the local graph from now on. Unknown names are ignored
  /// (returns false). A sensor leaving the set ends its chain of between factors.
  bool SetFusedSensors(const std::vector<std::string>& names);
  const std::vector<std::string>& fused_sensors() const;

  /// A sensor found faulty (by consensus): it leaves the fused set and its between
  /// factors ending after after_ns leave the local window, so that what it said while
  /// the fault went unnoticed stops pulling the estimate. Unknown names: false.
  bool DiscardSensor(const std::string& name, core::Time after_ns);

  /// A sensor judged inconsistent (by consensus) while not fused: the pairs its alignment
  /// graph holds are dropped and T_AL is estimated afresh from the pairs that follow
  /// (AlignmentGraph::Reset); a usable T_AL it had stays a candidate that is taken back
  /// when the new pairs fit it (as after an exclusion). Nothing happens to a fused sensor
  /// (its T_AL is frozen) or to one with a known T_AL. Unknown names: false.
  bool RestartAlignment(const std::string& name);

  /// A known T_AL (e.g. the ground truth handed to the naive baseline), used instead of
  /// the sensor's alignment graph.
  void SetKnownAlignment(const std::string& sensor, const Eigen::Isometry3d& T_AL);

  /// What is known of the mission frame M: from now on every output carries T_ML
  /// (registered at the first output to the launch pad, then following the fused
  /// surveyed sensors). Without a call, outputs carry none.
  void SetMissionSurvey(MissionSurvey survey);
  /// The surveyed sensors T_ML may follow (each also has to explain its positions:
  /// MissionFrameOptions::max_fit_chi2_per_dof). Until the first call: the fused ones.
  /// Consensus names every sensor it has not excluded, so that one it cannot judge yet
  /// still serves when its positions fit.
  void SetMissionCandidates(const std::vector<std::string>& names);

  /// Outputs produced since the last call.
  std::vector<EstimatorOutput> TakeOutputs();

  /// T_AL of a sensor in use: the known one, the one frozen at fusion start, or the
  /// alignment graph's. nullopt when none is valid.
  std::optional<Eigen::Isometry3d> AlignmentOf(const std::string& sensor) const;
  const AlignmentGraph* AlignmentGraphOf(const std::string& sensor) const;

  const LocalSmoother& local() const;
  const EstimatorCounters& counters() const;
  /// Every (re-)initialisation of the local graph, oldest first.
  const std::vector<InitialisationRecord>& initialisations() const;
  /// The between-factor stds in use for a pose sensor weighted by constant stds (the
  /// measured ones once known); nullopt for one weighted by its own noise
  /// (PoseBetweenNoise::kWhiteAndDrift: each factor has its own covariance).
  struct BetweenNoise {
    double position_std_m = 0.0;
    double rotation_std_rad = 0.0;
    std::optional<core::Time> measured_at_ns;  ///< when measured from the data
  };
  std::optional<BetweenNoise> BetweenNoiseOf(const std::string& sensor) const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace tofu::estimator
