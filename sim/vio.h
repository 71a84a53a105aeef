#pragma once
// Visual-inertial odometry in the style of the Intel RealSense T265 tracking camera: the
// pose and body twist of the camera in its own odometry frame, drifting with the distance
// travelled, with the feature starvation, motion blur and tracker resets that textureless
// or close-up scenes and fast rotations cause.

#include <cstdint>
#include <span>
#include <optional>
#include <string>
#include <vector>

#include <Eigen/Core>
#include <Eigen/Geometry>

#include "core/random.h"
#include "core/option_fields.h"
#include "core/time.h"
#include "core/units.h"
#include "sim/mount_motion.h"
#include "sim/odometry_frame.h"
#include "sim/sensor.h"
#include "sim/world.h"

namespace tofu::sim {

struct VioOptions {
  std::string site = "vio_camera";  ///< robot mount site (optical frame: z fwd, x right, y down)
  /// Odometry frame S in W (YAML frame_position_m, frame_rpy_deg). Each unset part is taken
  /// from the camera pose at the first step (t = 0): the T265 starts its odometry frame
  /// where it boots.
  std::optional<Eigen::Vector3d> p_WS_m;
  std::optional<Eigen::Quaterniond> q_WS;

  double rate_hz = 200.0;    ///< T265 pose stream: 200 Hz
  double latency_s = 0.005;  ///< stamp-to-delivery delay [s] (Intel: pose latency < 6 ms)

  // ---- drift: random walks in the distance d travelled by the camera [per sqrt(m)] ----
  /// Position drift per axis of S: sigma_p(d) = this * sqrt(d). 0.02 m/sqrt(m) gives a 3D
  /// RMS error of 1.1 % after 10 m (Intel: "< 1 % drift" closed loop).
  double position_random_walk_m_per_sqrtm = 0.02;
  /// Heading (rotation about gravity) drift: sigma_yaw(d) = this * sqrt(d). Assumed
  /// 0.002 rad/sqrt(m) (0.36 deg after 10 m); through the heading error the lateral
  /// position error grows as sigma_yaw sqrt(d^3 / 3) (0.15 m after 40 m, so the total
  /// stays under ~1 % of the distance, Intel's figure).
  double yaw_random_walk_rad_per_sqrtm = 0.002;
  /// Roll/pitch drift (gravity-observable, hence small) per horizontal axis.
  double tilt_random_walk_rad_per_sqrtm = 0.0005;

  // ---- white measurement noise (not accumulated) ----
  double position_noise_m = 0.002;          ///< per axis of S
  double rotation_noise_rad = 0.001;        ///< per axis, right perturbation
  double velocity_noise_mps = 0.01;         ///< per axis of s
  double angular_rate_noise_radps = 0.002;  ///< per axis of s

  // ---- feature availability: a grid of rays through the usable field of view ----
  double feature_check_rate_hz = 15.0;
  int feature_grid_columns = 8;
  int feature_grid_rows = 6;
  /// Usable field of view of the fisheye pair (T265: 163 deg diagonal; the rim carries few
  /// trackable features, hence ~110 x 90 deg).
  double feature_fov_horizontal_rad = core::RadFromDeg(110.0);
  double feature_fov_vertical_rad = core::RadFromDeg(90.0);
  /// A ray whose hit lies in [min, max] along the ray on a textured surface is a feature
  /// (closer: out of focus / no stereo overlap; farther: too little parallax, assumed).
  double feature_min_depth_m = 0.3;
  double feature_max_depth_m = 10.0;
  /// Score (fraction of rays with a feature) below which tracking is starved.
  double starved_score_threshold = 0.25;
  /// Drift rates are multiplied by this while starved (score > 0 but below the threshold).
  double starved_drift_factor = 5.0;

  // ---- motion blur ----
  double blur_angular_rate_radps = 2.5;  ///< |omega_s| beyond this blurs the images
  double blur_drift_factor = 3.0;        ///< drift multiplier while blurred

  // ---- loss of visual tracking (score = 0) and relocalisation ----
  /// With no feature at all the tracker runs on its IMU: the velocity error is a random
  /// walk in time, b_v(t) = this * W(t) per axis, integrated into position.
  double lost_velocity_random_walk_mps_per_sqrts = 0.5;
  /// The tracker resets after the score has been zero this long [s] (assumed).
  double reset_after_s = 1.0;
  /// Pose jump at a reset: N(0, sigma^2) per position axis and about gravity.
  double reset_jump_position_m = 0.3;
  double reset_jump_yaw_rad = 0.05;

  // ---- reported covariance (realsense-ros, base_realsense_node.cpp) ----
  /// Pose covariance diag = this * 10^(3 - c) for tracker confidence c in {0..3}
  /// (realsense-ros linear_accel_cov, default 0.01).
  double reported_pose_variance_base = 0.01;
  /// Twist covariance diag = this * 10^(1 - c) (realsense-ros angular_velocity_cov).
  double reported_twist_variance_base = 0.01;

  /// The field table (core/option_fields.h): the YAML key, unit and limits of every
  /// option, which the reader, the writer and IsValid share.
  static std::span<const core::OptionField<VioOptions>> Fields();
  /// Ceres style: false, with "<key>: <problem>" in *why, when an option is outside
  /// its limits or feature_min_depth_m >= feature_max_depth_m.
  /// The model's constructor throws std::invalid_argument then.
  bool IsValid(std::string* why = nullptr) const;
};

/// VIO (T265-like): pose T_Ss and body twist of the camera site s in the odometry frame S.
///
/// Truth. With T_Ws(t) from the body state and the mount T_Bs:
///   T_Ss = T_WS^-1 T_Ws,  v_s = R_Ws^T (v_WB + R_WB (omega_B x r)),  omega_s = R_Bs^T omega_B.
/// Error state (per physics step, d = distance travelled by s, dd its increment, f the
/// drift multiplier of the active conditions, g_S = R_WS^T e_z the gravity axis in S):
///   R_hat = R_err R_Ss,  p_hat = p_Ss + dp,
///   dp    += (R_err - I) dp_Ss + f sigma_p sqrt(dd) n + b_v dt       (heading error bends the
///                                                                     integrated path)
///   R_err  = Exp(f sqrt(dd) (sigma_yaw n_1 g_S + sigma_tilt (n_2 h_1 + n_3 h_2))) R_err,
/// h_1, h_2 horizontal axes of S; so Var(dp) = sigma_p^2 d per axis (a velocity error of
/// intensity sigma_p^2 |v| integrated into position) and Var(yaw) = sigma_yaw^2 d.
/// Features. At feature_check_rate_hz a grid of rays (columns x rows, equiangular over the
/// usable FOV: u = [sin a cos e, sin e, cos a cos e] in s) is cast from the camera against
/// the scene; score = fraction of rays hitting a textured surface at a depth within
/// [min, max]. score < threshold: kFeatureStarved, f *= starved_drift_factor.
/// |omega_s| > blur limit: kMotionBlur, f *= blur_drift_factor.
/// score = 0: visual tracking lost (kLockLost | kFeatureStarved): b_v += sigma_lost sqrt(dt) n
/// (position error diverges ~ t^1.5); after reset_after_s of zero score the tracker resets:
/// dp += sigma_jump n, yaw += sigma_jump_yaw n, b_v = 0 (kTrackerReset until the next
/// sample); tracking then resumes. b_v = 0 as soon as a feature is seen again.
/// Output at rate_hz: p_Ss~ = p_hat + sigma n, R_Ss~ = R_hat Exp(sigma n),
/// v~ = v_s + R_hat^T b_v + sigma n, omega~ = omega_s + sigma n.
/// Reported covariance (what a T265 reports through realsense-ros): tracker confidence
/// c = 3 (tracking well), 2 (motion blur), 1 (starved), 0 (lost); pose covariance
/// diag = base * 10^(3 - c), twist covariance diag = base * 10^(1 - c). It is a confidence
/// level, not an error bound: the true drift can exceed it.
class VioModel final : public SensorModel {
 public:
  /// Throws std::invalid_argument if the site is missing or an option is out of range.
  VioModel(std::string name, const VioOptions& options, const World& world, uint64_t seed);

  const std::string& name() const override { return name_; }
  void Step(const SensorInput& input, std::vector<SensorSample>* out) override;
  uint32_t conditions() const override { return conditions_; }
  /// The odometry frame in W; with the default (start pose) valid after the first Step.
  Eigen::Isometry3d T_WS() const override { return frame_.T_WS(); }
  const std::string& site() const override { return options_.site; }

  /// Feature score in [0, 1] of a camera at T_Ws (s optical frame) in `world`: the
  /// fraction of the ray grid hitting textured surfaces within the depth band.
  double FeatureScore(const World& world, const Eigen::Isometry3d& T_Ws) const;
  /// Score of the latest feature check (1 before the first).
  double feature_score() const { return feature_score_; }

 private:
  // The degradations of this step's tracking.
  struct Tracking {
    bool starved = false;  ///< feature score below starved_score_threshold
    bool blurred = false;  ///< angular rate above blur_angular_rate_radps
  };
  /// Feature check (at its own rate) and the tracking state it sets.
  Tracking UpdateTracking(const World& world, const MountMotion& now, core::Time t_ns,
                          core::Time dt_ns);
  /// The random walks of the pose with the distance moved since the last step.
  void WalkWithDistance(const Eigen::Vector3d& p_Ss, const Eigen::Matrix3d& R_WS,
                        const Tracking& tracking);
  /// No feature: the velocity error walks, and after reset_after_s the pose jumps.
  void DeadReckonWhileLost(core::Time t_ns, double dt_s, const Eigen::Matrix3d& R_WS);
  /// The reported pose and twist of one sample, with the covariances of `confidence`.
  core::PoseMeasurement MeasuredPose(const MountMotion& at, const core::PoseMeasurement& truth,
                                     int confidence);

  std::string name_;
  VioOptions options_;
  core::RandomStream stream_;
  Eigen::Isometry3d T_Bs_;
  std::vector<Eigen::Vector3d> ray_directions_s_;  ///< unit, feature grid
  core::Time period_ns_;
  core::Time latency_ns_;
  core::Time feature_period_ns_;
  core::Time reset_after_ns_;

  DriftingOdometryFrame frame_;  ///< S, and the pose error: R_hat = R_err R_Ss, dp_S
  core::Time next_sample_ns_ = 0;
  core::Time next_feature_check_ns_ = 0;
  Eigen::Vector3d previous_p_Ss_ = Eigen::Vector3d::Zero();

  Eigen::Vector3d b_v_S_ = Eigen::Vector3d::Zero();        ///< velocity error while lost [m/s]

  double feature_score_ = 1.0;
  bool lost_ = false;  ///< score = 0
  core::Time lost_since_ns_ = 0;
  bool reset_pending_ = false;   ///< a reset happened; flagged until its sample went out
  bool reset_reported_ = false;  ///< the reset's sample went out in this step
  uint32_t conditions_ = kConditionNone;
};

}  // namespace tofu::sim
