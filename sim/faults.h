#pragma once
// Scheduled sensor faults with ground-truth labels. A FaultInjector sits between one
// sensor model and the measurement queue: it turns each clean SensorSample into zero or
// one faulted samples (keeping `truth` untouched so that the true error stays measurable)
// and reports which faults are active at any time; FaultLabels() gives the schedule as
// label transitions for labels.csv.
//
// The failure modes follow the seed paper's corruption experiments (Sec. "Metric
// Evaluation", "Consensus-based Sensor Selection"): a misaligned reference frame
// ("initialized with an offset of 30, 60 and 120 deg in roll, pitch and yaw"), GNSS-like
// non-Gaussian noise "composed of white and brown noise", divergence "by integrating an
// exponentially increasing velocity ... and adding it to the position measurement", and
// drop-outs; freeze, delay, jump and outliers complete the usual catalogue of odometry and
// positioning failures.
//
// Conventions. A fault is active on the half-open window [start, end) of sample stamps
// (time of validity, t_ns); outside its window a fault leaves samples bit-identical.
// Several faults on one sensor may overlap; they are applied in list order, each one to
// the output of the previous (a sample dropped by one never reaches the next). Faults on
// pose and position act in the sensor's reference frame S: the faulted sensor reports its
// pose in a wrong frame F (T_Fs = T_FS T_Ss). The pose twist is expressed in the mount
// frame s, so a change of reference frame leaves it unchanged.

#include <array>
#include <cstdint>
#include <limits>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include <Eigen/Core>
#include <Eigen/Geometry>

#include "core/measurement.h"
#include "core/time.h"
#include "sim/sensor.h"

namespace tofu::sim {

/// The scheduled failure modes. The value is the bit index in ActiveFaults() masks.
enum class FaultKind : uint8_t {
  kMisalignment = 0,
  kNonGaussianNoise = 1,
  kDivergence = 2,
  kDropout = 3,
  kFreeze = 4,
  kDelay = 5,
  kJump = 6,
  kOutliers = 7,
};

inline constexpr int kFaultKindCount = 8;

/// "misalignment", "non_gaussian_noise", "divergence", "dropout", "freeze", "delay",
/// "jump", "outliers" (scenario key and labels.csv column).
std::string_view FaultKindName(FaultKind kind);
/// Inverse of FaultKindName; nullopt for an unknown name.
std::optional<FaultKind> FaultKindFromName(std::string_view name);
/// Every kind in bit order.
const std::array<FaultKind, kFaultKindCount>& AllFaultKinds();
/// The bit of `kind` in an active-faults mask.
constexpr uint32_t FaultBit(FaultKind kind) { return 1u << static_cast<uint32_t>(kind); }

/// Misalignment: the sensor reports in a wrong reference frame F, rotated and translated
/// from S:  p_Fs = R_FS p_Ss + p_FS,  q_Fs = q_FS q_Ss  (the twist, in s, is unchanged; the
/// position block of the covariance is rotated, Sigma_p' = R_FS Sigma_p R_FS^T).
struct MisalignmentParams {
  Eigen::Quaterniond q_FS = Eigen::Quaterniond::Identity();  ///< YAML rpy_deg
  Eigen::Vector3d p_FS_m = Eigen::Vector3d::Zero();           ///< YAML translation_m
};

/// Non-Gaussian (white + brown) position noise, on every axis of S independently:
///   p' = p + w_k + b_k,  w_k ~ N(0, white_std_m^2),
///   b_k = phi b_{k-1} + brown_std sqrt(tau (1 - phi^2) / 2) n_k,  phi = exp(-dt/tau)
/// (exact discretisation of a Gauss-Markov process with time constant tau; for tau = inf
/// a random walk, b_k = b_{k-1} + brown_std sqrt(dt) n_k, whose variance grows as
/// brown_std^2 t; with tau finite the variance is bounded by brown_std^2 tau / 2). b starts
/// at 0 at the window's start; dt is the time since the previous sample in the window (or
/// since the start). Orientation, twist and the reported covariance are unchanged: the
/// sensor does not know it is noisy. Defaults: metre-level standalone-GNSS errors (white
/// 0.3 m; brown 0.1 m/sqrt(s), i.e. 0.6 m after 36 s), "a similar magnitude to GNSS" as
/// in the paper.
struct NonGaussianNoiseParams {
  double white_std_m = 0.3;
  double brown_std_m_per_sqrt_s = 0.1;
  /// Gauss-Markov time constant tau; +inf (default; no YAML key): random walk.
  double brown_time_constant_s = std::numeric_limits<double>::infinity();
};

/// Divergence: an exponentially growing velocity along a fixed direction a of S,
///   v(x) = v0 exp(x / tau),   x = t - start [s]   (so v(start) = v0),
/// integrated and added to the position:
///   d(x) = v0 tau (exp(x / tau) - 1),   p' = p + d(x) a,
/// and, when the pose carries a twist, v_s' = v_s + R_Ss^T v(x) a (R_Ss as reported).
/// The offset vanishes when the window ends (the sensor is reset).
struct DivergenceParams {
  Eigen::Vector3d axis_S = Eigen::Vector3d::UnitY();  ///< direction, normalised; YAML axis
  double initial_velocity_mps = 0.01;                  ///< v0
  double time_constant_s = 10.0;                       ///< tau
};

/// Delay: a stale value. The sample stamped t carries the measured value of the latest
/// sample (as this fault receives them) stamped at or before t - delay_s (zero-order hold;
/// exact when delay_s is a multiple of the sample period); if there is none yet, the
/// sample is dropped. Its stamp, truth and conditions stay those of t. Independently, the
/// sample arrives arrival_delay_s later (arrival_ns += arrival_delay): a transport delay.
struct DelayParams {
  double delay_s = 0.2;
  double arrival_delay_s = 0.0;
};

/// Jump: a step of the reported pose at the window's start, as a VIO relocalisation does.
/// With p0 the position (as this fault receives it) of the first sample in the window:
///   p' = R_jump (p - p0) + p0 + translation,  q' = q_jump q
/// so the first sample jumps by exactly `translation` and `q_jump`, and the later motion
/// continues in the jumped frame. With q_jump = identity, p' = p + translation.
struct JumpParams {
  Eigen::Vector3d translation_S_m = Eigen::Vector3d::Zero();  ///< YAML translation_m
  Eigen::Quaterniond q_jump = Eigen::Quaterniond::Identity();  ///< YAML rpy_deg
};

/// Outliers: gross errors at Poisson times of rate rate_hz. A sample is an outlier when at
/// least one Poisson event fell in (previous stamp, its stamp] (within the window), i.e.
/// with probability 1 - exp(-rate_hz dt). An outlier adds a heavy-tailed offset drawn from
/// a multivariate Student-t with nu = degrees_of_freedom (nu = 1: Cauchy; nu = 2: infinite
/// variance, P(|x_i| > k s) = 1 - k / sqrt(k^2 + 2) per axis):
///   o = s z / sqrt(chi2_nu / nu),  z ~ N(0, I3),
/// to the position (s = scale_m), the orientation of a pose (q' = Exp(o_theta) q with
/// s = rotation_scale_rad), or the IMU readings (acc_scale_mps2, gyro_scale_radps).
struct OutlierParams {
  double rate_hz = 0.5;
  double scale_m = 1.0;
  double rotation_scale_rad = 0.0;  ///< YAML rotation_scale_deg
  double acc_scale_mps2 = 5.0;
  double gyro_scale_radps = 0.5;    ///< YAML gyro_scale_degps
  int degrees_of_freedom = 2;
};

/// One scheduled fault on one sensor. Only the parameters of `kind` are used.
struct FaultSpec {
  std::string sensor;
  FaultKind kind = FaultKind::kDropout;
  double start_s = 0.0;                                     ///< window start (inclusive)
  double end_s = std::numeric_limits<double>::infinity();  ///< window end (exclusive)
  MisalignmentParams misalignment;
  NonGaussianNoiseParams noise;
  DivergenceParams divergence;
  DelayParams delay;
  JumpParams jump;
  OutlierParams outliers;
};

/// The window [start_ns, end_ns) of a fault; end_ns = max Time for an open end.
struct FaultWindow {
  core::Time start_ns = 0;
  core::Time end_ns = std::numeric_limits<core::Time>::max();
  bool Contains(core::Time t_ns) const { return t_ns >= start_ns && t_ns < end_ns; }
};
FaultWindow WindowOf(const FaultSpec& spec);

/// Why `spec` cannot act on a sensor whose measurements are `measured` (nullopt if it can).
/// IMU accepts dropout, freeze, delay and outliers (with a non-zero IMU scale); pose and
/// position accept every kind; outliers need a non-zero scale for the measurement's kind.
std::optional<std::string> CheckFaultApplies(const FaultSpec& spec, core::MeasurementKind measured);

/// One transition of the ground-truth labels (a row of labels.csv).
struct FaultLabel {
  core::Time t_ns = 0;
  std::string sensor;
  std::string fault;  ///< FaultKindName
  bool active = false;
};

/// The exact schedule as label transitions: {start, active = true} for each fault starting
/// before run_end_ns and {end, active = false} for each whose end is at or before
/// run_end_ns (a fault still active at the run's end has no closing label). Sorted by time;
/// at equal times ends come before starts, otherwise the list order is kept.
std::vector<FaultLabel> FaultLabels(const std::vector<FaultSpec>& specs, core::Time run_end_ns);

/// The faults of one sensor. Each fault owns the random stream
/// core::RandomStream(seed, "fault/<sensor>/<index>"), index = its position in `specs`.
/// Samples must be fed in increasing t_ns order.
class FaultInjector final {
 public:
  /// `specs` all name the same sensor (asserted); any number, overlapping allowed.
  FaultInjector(std::vector<FaultSpec> specs, uint64_t seed);
  ~FaultInjector();
  FaultInjector(FaultInjector&&) noexcept;
  FaultInjector& operator=(FaultInjector&&) noexcept;
  FaultInjector(const FaultInjector&) = delete;
  FaultInjector& operator=(const FaultInjector&) = delete;

  /// Appends the faulted version of `in` to `out` (nothing if a fault drops it). t_ns,
  /// truth and conditions of the output are those of `in` (arrival_ns may grow by a delay
  /// fault). A fault that does not apply to the sample's type (CheckFaultApplies) is
  /// skipped (asserted in debug builds).
  void Apply(const SensorSample& in, std::vector<SensorSample>* out);

  /// Bit mask (FaultBit) of the kinds whose window contains t_ns.
  uint32_t ActiveFaults(core::Time t_ns) const;

  const std::vector<FaultSpec>& specs() const;

 private:
  struct Stage;
  std::vector<Stage> stages_;
  std::vector<FaultSpec> specs_;
};

}  // namespace tofu::sim
