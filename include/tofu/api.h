#pragma once
// tofu's interface for estimators and controllers that are not tofu's own: the types a
// plug-in (a shared library, include/tofu/plugin.h) and a process client (the lockstep
// protocol of docs/INTERFACE.md, whose messages carry exactly these fields) exchange
// with the harness. tofu's built-in methods (consensus, naive, single, fuse, oracle) and
// its SE(3) controller implement the same classes, so every method is scored, recorded
// and flown through one path.
//
// Header-only and free of Eigen, MuJoCo and tofu's own libraries, so that a plug-in
// builds against the installed headers alone (`find_package(tofu)`, target tofu::api).
//
// Conventions (docs/DESIGN.md): SI units, the unit in each name; time as int64
// nanoseconds since the run's start; T_AB is the pose of frame B in frame A
// (p_A = T_AB p_B); quaternions Hamilton, unit, stored (w, x, y, z). Frames: M the
// mission frame, z up: the survey the mission is planned in, which is the simulator's
// world W (the reference trajectory, the structure and the scoring are in it); B the
// body; I the IMU; s a sensor's mount on the body; S a sensor's reference frame (its
// odometry frame, the total station's or the GNSS's ENU frame); L the estimator's own
// local frame, gravity aligned (z up), origin and yaw its own.
//
// Versioning: kApiVersion grows by one whenever a type or virtual function of this file
// (or a message of the protocol) changes in a way an existing client would notice. A
// plug-in reports the version it was built with (TOFU_PLUGIN_API_VERSION in plugin.h)
// and tofu refuses any other; a process client states its version in its hello.

#include <array>
#include <cstddef>
#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#define TOFU_API_VERSION 2

namespace tofu::api {

inline constexpr int kApiVersion = TOFU_API_VERSION;

using Vec3 = std::array<double, 3>;
/// A unit quaternion (w, x, y, z), Hamilton convention.
using Quat = std::array<double, 4>;
/// A 3x3 or 6x6 matrix, row-major.
using Mat3 = std::array<double, 9>;
using Mat6 = std::array<double, 36>;

/// A rigid transform T_AB: position of B's origin in A and the rotation of B in A.
struct Pose {
  Vec3 p_m{0.0, 0.0, 0.0};
  Quat q_wxyz{1.0, 0.0, 0.0, 0.0};
};

// ---------------------------------------------------------------------------------------
// Estimators

/// What a stream's samples hold.
enum class SensorKind {
  kImu,       ///< ImuSample
  kPose,      ///< PoseSample: a pose of s in S (VIO, LiDAR odometry)
  kPosition,  ///< PositionSample: a position of s in S (total station, GNSS)
};
inline const char* SensorKindName(SensorKind kind) {
  switch (kind) {
    case SensorKind::kImu: return "imu";
    case SensorKind::kPose: return "pose";
    case SensorKind::kPosition: return "position";
  }
  return "?";
}

/// One stream of the run, as its calibration describes it.
struct SensorInfo {
  std::string name;   ///< the stream's name in the scenario (e.g. "vio", "leica")
  SensorKind kind = SensorKind::kImu;
  /// The nominal mount of s in the IMU frame I (what the flight stack is told, not the
  /// true one): T_Is = T_BI^-1 T_Bs; identity for the IMU itself.
  Pose T_Is;
  /// The samples carry the sensor's own covariance (false: a default was filled in).
  bool covariance_stated = true;
  /// The sensor's reference frame S surveyed in M (a total station set up on surveyed
  /// points, a GNSS ENU frame tied to the site's survey); unset: not surveyed (odometry
  /// frames, which start wherever the sensor boots).
  std::optional<Pose> T_MS;
};

/// Everything an estimator is told before the first sample.
struct EstimatorSetup {
  int api_version = kApiVersion;
  std::string method;  ///< the method's name in the scenario, e.g. "external:my_ekf"
  std::size_t imu = 0; ///< index of the IMU stream in `sensors`
  std::vector<SensorInfo> sensors;
  double gravity_mps2 = 9.81;  ///< |g|; gravity is -z in W and in L
  /// The scenario's `config:` map for this estimator, as JSON text ("{}" when none).
  std::string config_json = "{}";
  /// The run's calibration.yaml (replay/run_calibration.h): noise densities, mounts,
  /// rates. For clients that want more than `sensors` says; most need none of it.
  std::string calibration_yaml;
  /// The scenario's resolved `estimation:` block (YAML): tofu's own estimator settings.
  std::string estimation_yaml;
  /// The IMU's pose in M at launch: the launch pad's surveyed pose through the nominal
  /// mount, "the robot is here" as an operator states it (the robot waits there until
  /// the closed loop hands over to the estimate). Unset: not known (a recorded log).
  std::optional<Pose> T_MI_launch;
};

/// IMU: specific force f_I = R_WI^T (a_WI - g_W) and angular rate of I in I.
struct ImuSample {
  Vec3 acc_I_mps2{0.0, 0.0, 0.0};
  Vec3 gyro_I_radps{0.0, 0.0, 0.0};
};

/// Pose of the mount s in the sensor's frame S, with the sensor's covariance of
/// [delta_theta; delta_p] (rad, m; delta_theta a right perturbation R_Ss Exp(delta_theta),
/// delta_p in S), and the body twist of s where the sensor reports one.
struct PoseSample {
  Pose T_Ss;
  Mat6 covariance{};
  bool has_twist = false;
  Vec3 v_s_mps{0.0, 0.0, 0.0};         ///< linear velocity of s, in s
  Vec3 omega_s_radps{0.0, 0.0, 0.0};   ///< angular velocity of s, in s
  Mat6 twist_covariance{};             ///< of [v; omega], when has_twist
};

/// Position of the mount point s in the sensor's frame S with its covariance [m^2].
struct PositionSample {
  Vec3 p_Ss_m{0.0, 0.0, 0.0};
  Mat3 covariance_m2{};
};

/// One sample, delivered in arrival order (a delayed sample arrives after later-stamped
/// ones, as on the robot). Only the member of `kind` is meaningful.
struct Measurement {
  std::int64_t t_ns = 0;        ///< time of validity (the sensor's stamp)
  std::int64_t arrival_ns = 0;  ///< when it reached the estimator (>= t_ns)
  std::size_t sensor = 0;       ///< index into EstimatorSetup::sensors
  SensorKind kind = SensorKind::kImu;
  ImuSample imu;
  PoseSample pose;
  PositionSample position;
};

/// The estimator's state at a time: the IMU frame in the estimator's local frame L.
struct Estimate {
  std::int64_t t_ns = 0;  ///< the time the state is for (non-decreasing)
  /// The estimate may be flown on and scored. An estimator reports false until it has
  /// started, and when it has lost track (tofu's closed loop then holds and lands).
  bool valid = false;
  /// The estimator has a state at all (false before its initialisation).
  bool initialized = false;
  Pose T_LI;
  Vec3 v_L_mps{0.0, 0.0, 0.0};        ///< velocity of I in L
  Vec3 omega_I_radps{0.0, 0.0, 0.0};  ///< angular velocity of I, in I (bias-corrected)
  Vec3 bias_acc_mps2{0.0, 0.0, 0.0};
  Vec3 bias_gyro_radps{0.0, 0.0, 0.0};
  /// Covariance of p_LI [m^2], when the estimator computes one (scored as NEES).
  std::optional<Mat3> position_covariance_m2;
  /// The sensors (names) it fused at this moment, when it chooses sensors: exclusion,
  /// detection delay and re-admission are then scored for it as for consensus.
  std::optional<std::vector<std::string>> fused;
  /// The global output: the mission frame M in L, gravity aligned (a heading and a
  /// translation), from the launch pad and the surveyed sensors the estimator trusts.
  /// A closed-loop flight flies the mission (stated in M) through it; without it, the
  /// pilot registers L to the launch pad once, at the handover. Keep it continuous: the
  /// controller sees every change of it as motion.
  std::optional<Pose> T_ML;
  /// Covariance of [delta_p (m, in M); delta_theta (rad)] of T_ML, when known.
  std::optional<Mat6> T_ML_covariance;
};

class Estimator {
 public:
  virtual ~Estimator() = default;
  /// Called once, before the first Add.
  virtual void Start(const EstimatorSetup& setup) = 0;
  /// The next sample in arrival order; append the estimates it produced (often none, or
  /// one per IMU sample) to *out. The newest estimate at a controller's instant is what
  /// a closed-loop flight flies on. Throw to report an error: tofu marks the method
  /// failed with the exception's message.
  virtual void Add(const Measurement& measurement, std::vector<Estimate>* out) = 0;
  /// The streams have ended; append any last estimates.
  virtual void Finish(std::vector<Estimate>* out) { (void)out; }
  /// Optional: a JSON object tofu stores as `client_report` in estimate_<method>.json.
  virtual std::string ReportJson() const { return "{}"; }
};

// ---------------------------------------------------------------------------------------
// Controllers

/// The robot and the loop, told once before the first Compute.
struct ControllerSetup {
  int api_version = kApiVersion;
  std::string name;         ///< the controller's name in the scenario
  double rate_hz = 0.0;     ///< Compute is called at this rate
  double mass_kg = 0.0;
  Mat3 inertia_B_kgm2{};    ///< about the centre of mass, in B
  double gravity_mps2 = 9.81;
  int arm_count = 6;        ///< tilt arms, two rotors each (the OMAV)
  double max_rotor_thrust_N = 0.0;  ///< per rotor
  std::string config_json = "{}";   ///< the scenario's `config:` map as JSON text
};

/// What the controller flies on: ground truth, or the estimate moved to B and into W.
struct ControlState {
  std::int64_t t_ns = 0;
  Pose T_WB;
  Vec3 v_W_mps{0.0, 0.0, 0.0};
  Vec3 omega_B_radps{0.0, 0.0, 0.0};
  bool from_estimate = false;
};

/// The reference at the same instant: full pose (the robot is omnidirectional) and its
/// derivatives.
struct ControlReference {
  Pose T_WB;
  Vec3 v_W_mps{0.0, 0.0, 0.0};
  Vec3 a_W_mps2{0.0, 0.0, 0.0};
  Vec3 omega_B_radps{0.0, 0.0, 0.0};
  Vec3 alpha_B_radps2{0.0, 0.0, 0.0};
};

/// A body wrench (tofu's allocation turns it into six tilt angles and twelve rotor
/// thrusts), or those actuator commands directly.
struct ControlCommand {
  enum class Kind { kWrench, kActuators };
  Kind kind = Kind::kWrench;
  Vec3 force_B_N{0.0, 0.0, 0.0};
  Vec3 torque_B_Nm{0.0, 0.0, 0.0};
  std::vector<double> tilt_rad;        ///< kActuators: arm_count angles
  std::vector<double> rotor_thrust_N;  ///< kActuators: arm_count (per rotor of the arm)
};

class Controller {
 public:
  virtual ~Controller() = default;
  virtual void Start(const ControllerSetup& setup) = 0;
  /// One control tick. Throw to report an error (the flight then fails).
  virtual ControlCommand Compute(const ControlState& state, const ControlReference& reference) = 0;
};

}  // namespace tofu::api
