#pragma once
// An example tofu estimator plug-in: a cascaded complementary filter.
//
//   1. Attitude R_LI and gyro bias b_g: Mahony's explicit complementary filter (Mahony,
//      Hamel, Pflimlin, "Nonlinear complementary filters on the special orthogonal group",
//      IEEE TAC 53(5), 2008, eqs. (32a-c)): the gyro is integrated and corrected by a
//      "measured" angular velocity omega_mes built from vector observations. The vector
//      here is the specific force, compared with the specific force the anchor's position
//      fixes imply (their second difference over a window, minus gravity), rather than
//      with gravity alone: no "the robot is not accelerating" assumption for tilt, and the
//      changes of its horizontal part observe yaw whenever the robot's horizontal
//      acceleration changes (a 2-D Procrustes fit over a few seconds, see Match()). While
//      the anchor is silent the gyro alone carries the attitude; before the first vector
//      observation, and long after the last, plain accelerometer tilt (the reference
//      vector -g, gated on |f| ~ g) corrects it.
//   2. Position, velocity and accelerometer bias [p_LI; v_L; b_a]: a linear (time-
//      varying) Kalman filter driven by the rotated, gravity-compensated accelerometer,
//      a_L = R_LI (f_I - b_a) + g_L, and updated by the anchor's fixes through the mount
//      lever arm, p_Ss = p_LI + R_LI p_Is. R_LI is an input from stage 1, not a state, so
//      the filter is linear in its state: this is not an error-state EKF.
//
// Frames: L := S, the anchor sensor's frame (a total station's or GNSS's gravity-aligned,
// z-up frame), so position needs no frame alignment. The yaw of I in L is unknown at
// start: it starts at `initial_yaw_rad` (0 unless configured) and is observed only once
// the robot accelerates horizontally (a position sensor alone cannot see a heading while
// hovering). Until then ("unaligned") the Kalman filter assumes a larger acceleration
// noise and does not learn b_a (a Schmidt "consider" state: it would otherwise absorb the
// yaw error, and a horizontal b_a is then traded for a wrong tilt that only rotation can
// undo). ReportJson() says when the filter aligned.
//
// Delayed fixes (arrival after later IMU samples) are applied at their stamp: the filter
// keeps a few seconds of history and re-propagates the stored IMU inputs after the update.

#include <cstdint>
#include <deque>
#include <string>
#include <vector>

#include <Eigen/Core>
#include <Eigen/Geometry>

#include "tofu/api.h"

namespace tofu_example {

/// Everything the scenario's `config:` map may set (all optional; see README.md).
struct ComplementaryConfig {
  std::string anchor;  ///< sensor name; "" = the first position sensor of the setup
  // Attitude (Mahony 2008 eq. (32)): k_P [1/s] proportional and k_I [1/s^2] integral gains.
  double tilt_kp = 0.5;        ///< on the roll/pitch error of the fix-matched vector
  double tilt_ki = 0.02;
  double yaw_kp = 0.3;         ///< on the yaw error of the fix-matched vector, until aligned
  double yaw_kp_aligned = 0.1; ///< the same once aligned (less noise from each fix)
  double yaw_ki = 0.005;
  double accel_kp = 0.3;       ///< plain accelerometer tilt, only while no fix matching
  double accel_ki = 0.0;
  double accel_gate = 0.1;     ///< plain tilt only while ||f| - g| < accel_gate * g
  double accel_fallback_s = 5.0;  ///< plain tilt after this long without a vector
                                  ///< observation (before it, the gyro alone: an anchor
                                  ///< dropout in flight must not level a tilted estimate)
  double match_window_s = 0.5; ///< half-width T of the fix second difference
  double match_period_s = 0.05;  ///< at most one vector observation per this period
  double yaw_horizon_s = 4.0;  ///< vector observations the yaw fit uses (see Match)
  // Linear Kalman filter on [p_LI; v_L; b_a].
  double acc_noise = 0.2;      ///< acceleration process noise [m/s^2/sqrt(Hz)] (IMU,
                               ///< vibration and attitude error)
  double acc_noise_unaligned = 1.0;  ///< the same until yaw has converged (see Match)
  double imu_acc_noise = 0.02; ///< the accelerometer's white noise [m/s^2/sqrt(Hz)], for
                               ///< the vector observation's weight
  double acc_bias_walk = 1e-3; ///< accel bias random walk [m/s^3/sqrt(Hz)]
  double acc_bias_std = 0.1;   ///< initial accel bias std [m/s^2]
  double init_vel_std = 1.0;   ///< initial velocity std [m/s]
  double gate_chi2 = 16.27;    ///< Mahalanobis gate of a fix (chi^2, 3 dof, 99.9 %)
  double default_fix_std = 0.02;  ///< [m] when a fix's covariance is unusable
  // Attitude uncertainty [rad] moved through the lever arm into each fix's covariance
  // (stage 1 has no covariance of its own): tilt, and yaw once aligned / before.
  double attitude_std = 0.02;
  double yaw_std_unaligned = 1.0;
  // Start-up and bookkeeping.
  double init_duration_s = 0.5;   ///< IMU averaged for the initial tilt
  double initial_yaw_rad = 0.0;   ///< yaw of I in L at start, when known
  double anchor_timeout_s = 1.0;  ///< anchor silent longer: fused = {}, valid = false
  /// Report valid estimates before yaw has aligned (true: a closed loop can take off and
  /// fly the motion that shows yaw; false: only aligned estimates are flown and scored).
  bool valid_before_aligned = true;
  double history_s = 3.0;         ///< replay buffer (>= 2 T + the anchor's latency)

  /// Parses the scenario's config JSON; throws std::invalid_argument naming an unknown
  /// key or a value out of range (a typo must not silently fall back to a default).
  static ComplementaryConfig FromJson(const std::string& config_json);
};

class ComplementaryFilter : public tofu::api::Estimator {
 public:
  void Start(const tofu::api::EstimatorSetup& setup) override;
  void Add(const tofu::api::Measurement& measurement,
           std::vector<tofu::api::Estimate>* out) override;
  std::string ReportJson() const override;

  // Read-only state for tests.
  bool initialized() const { return initialized_; }
  bool aligned() const { return aligned_ns_ >= 0; }
  std::int64_t aligned_ns() const { return aligned_ns_; }
  const Eigen::Quaterniond& q_LI() const { return q_LI_; }
  Eigen::Vector3d p_LI_m() const { return x_.segment<3>(0); }
  Eigen::Vector3d bias_gyro_radps() const { return b_g_radps_; }
  Eigen::Vector3d bias_acc_mps2() const { return x_.segment<3>(6); }
  int fixes_accepted() const { return fixes_accepted_; }
  int fixes_rejected() const { return fixes_rejected_; }
  int fixes_too_old() const { return fixes_too_old_; }

 private:
  using Vec3 = Eigen::Vector3d;
  using Mat3 = Eigen::Matrix3d;
  using Vec9 = Eigen::Matrix<double, 9, 1>;
  using Mat9 = Eigen::Matrix<double, 9, 9>;

  /// One IMU step (t_prev, t_ns]: its input and the Kalman state after it.
  struct Step {
    std::int64_t t_ns = 0;
    double dt_s = 0.0;
    Vec3 f_I_mps2;            ///< raw specific force of the sample
    Eigen::Quaterniond q_LI_mid;  ///< attitude at the middle of the step (propagation)
    Eigen::Quaterniond q_LI_end;  ///< attitude at t_ns (lever arm of fixes)
    /// Product of every L-side attitude correction applied up to t_ns (see Match()).
    Eigen::Quaterniond q_correction_L;
    Vec9 x;
    Mat9 P;
  };
  /// One vector observation: the specific-force integral from the fixes (u) and from the
  /// IMU (u_hat, with the attitude as believed at t_ns), both in L.
  struct VectorPair {
    std::int64_t t_ns = 0;
    Vec3 u_L;
    Vec3 u_hat_L;
    Eigen::Quaterniond q_correction_L;  ///< q_correction_L_ when u_hat was formed
    double var_h = 0.0;                 ///< noise variance of each horizontal component
  };
  struct Fix {
    std::int64_t t_ns = 0;
    Vec3 p_Ss_m;
    Mat3 cov_m2;
  };

  void ImuStep(std::int64_t t_ns, const Vec3& gyro_I_radps, const Vec3& f_I_mps2);
  void TryInitialize(std::int64_t t_ns);
  void Propagate(double dt_s, const Eigen::Quaterniond& q_LI_mid, const Vec3& f_I_mps2);
  /// Applies a fix at its stamp: roll back, update, replay. False: too old or rejected.
  bool ApplyFix(const Fix& fix);
  /// Attitude at t_ns from the history (slerp between steps).
  Eigen::Quaterniond AttitudeAt(std::int64_t t_ns) const;
  /// The fix-matched vector observation (Mahony's v_i) ending at the newest fix, and the
  /// yaw fit over the recent ones.
  void Match(std::int64_t t2_ns);
  bool AnchorFresh(std::int64_t t_ns) const;
  tofu::api::Estimate MakeEstimate(std::int64_t t_ns, const Vec3& gyro_I_radps) const;

  ComplementaryConfig config_;
  std::size_t imu_ = 0;     ///< index of the IMU stream
  std::size_t anchor_ = 0;  ///< index of the anchor stream
  std::string anchor_name_;
  Vec3 p_Is_m_ = Vec3::Zero();  ///< the anchor's mount point in I (lever arm)
  Vec3 g_L_mps2_ = Vec3(0.0, 0.0, -9.81);

  // Start-up.
  bool initialized_ = false;
  std::int64_t t_first_imu_ns_ = -1;
  struct InitSample {
    std::int64_t t_ns = 0;
    Vec3 f_I_mps2;
    Vec3 gyro_I_radps;
  };
  std::deque<InitSample> init_imu_;  ///< the start-up window
  std::vector<Fix> fixes_before_init_;

  // Attitude filter.
  Eigen::Quaterniond q_LI_ = Eigen::Quaterniond::Identity();
  Vec3 b_g_radps_ = Vec3::Zero();
  Eigen::Quaterniond q_correction_L_ = Eigen::Quaterniond::Identity();
  Vec3 e_tilt_L_ = Vec3::Zero();  ///< held vector-observation errors [rad], in L
  Vec3 e_yaw_L_ = Vec3::Zero();
  std::int64_t t_last_match_ns_ = -1;      ///< IMU time of the last vector observation
  std::int64_t t_last_match_fix_ns_ = -1;  ///< stamp of the fix that ended it

  // Kalman filter.
  Vec9 x_ = Vec9::Zero();
  Mat9 P_ = Mat9::Identity();
  std::int64_t t_ns_ = -1;  ///< time of x_, P_ (the newest IMU sample)
  std::deque<Step> history_;
  std::deque<Fix> accepted_fixes_;  ///< for the vector observation (Match)
  std::deque<VectorPair> pairs_;    ///< the last yaw_horizon_s of vector observations
  std::vector<Fix> pending_fixes_;  ///< stamped after the newest IMU sample
  std::int64_t t_last_accepted_fix_ns_ = -1;

  // Report.
  int fixes_accepted_ = 0;
  int fixes_rejected_ = 0;
  int fixes_too_old_ = 0;
  int fixes_invalid_ = 0;
  int resets_ = 0;
  int imu_skipped_ = 0;
  int matches_ = 0;
  double yaw_excitation_ = 0.0;  ///< sum of yaw observation weights
  /// When yaw had been observed enough and its error was small: from then on the Kalman
  /// filter learns b_a and uses the nominal process noise (-1: not yet).
  std::int64_t aligned_ns_ = -1;
  int excited_matches_ = 0;         ///< vector observations that showed yaw (w > 0.5)
  double yaw_error_mean_rad_ = 0.0;  ///< their exponential moving average of the yaw error
  std::int64_t initialized_ns_ = -1;
};

}  // namespace tofu_example
