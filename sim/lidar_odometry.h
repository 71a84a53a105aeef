#pragma once
// LiDAR-inertial odometry in the style of a Livox Mid-360 running FAST-LIO: the pose and
// twist of the LiDAR in its own odometry frame, accurate where the scene constrains the
// scan registration and drifting along the directions it leaves degenerate (a single wall,
// a corridor) or everywhere when too few returns come back (open sky).

#include <array>
#include <span>
#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include <Eigen/Core>
#include <Eigen/Geometry>

#include "core/lidar_beam_pattern.h"
#include "core/random.h"
#include "core/option_fields.h"
#include "core/time.h"
#include "core/units.h"
#include "sim/mount_motion.h"
#include "sim/odometry_frame.h"
#include "sim/sensor.h"
#include "sim/world.h"

namespace tofu::sim {

/// The beam pattern (scan rows and columns, ranges: core/lidar_beam_pattern.h, Mid-360
/// defaults) and the odometry built on it.
struct LidarOdometryOptions : core::LidarBeamPattern {
  std::string site = "lidar";  ///< robot mount site of the LiDAR (z = scanner axis)
  /// Odometry frame S in W (YAML frame_position_m, frame_rpy_deg). Each unset part is taken
  /// from the LiDAR pose at the first step (t = 0): FAST-LIO starts where it boots.
  std::optional<Eigen::Vector3d> p_WS_m;
  std::optional<Eigen::Quaterniond> q_WS;

  double rate_hz = 10.0;     ///< Mid-360 frame rate 10 Hz = FAST-LIO output rate
  double latency_s = 0.02;   ///< scan end to odometry out [s] (FAST-LIO ~10-20 ms, assumed)

  /// 1-sigma range precision (Mid-360: <= 2 cm at 10 m); weights the information
  /// H = sum J^T J / sigma^2. 0 switches the registration noise off (H is then reported
  /// with unit weight).
  double range_noise_m = 0.02;

  // ---- degeneracy (Zhang, Kaess & Singh, ICRA 2016) ----
  /// A translation direction u is degenerate when its eigenvalue of the translation block
  /// of H is below this many "effective returns" / sigma^2 (lambda sigma^2 = sum (n.u)^2).
  double degenerate_translation_threshold = 10.0;
  /// A rotation axis is degenerate when its eigenvalue of the rotation block is below
  /// this / sigma^2 [m^2] (lambda sigma^2 = sum ((p x n).u)^2).
  double degenerate_rotation_threshold_m2 = 10.0;
  /// Fewer returns than this: registration fails, the output diverges (kFewReturns).
  int min_returns = 50;

  // ---- drift (random walks in the motion along each direction) ----
  /// Constrained translation directions: sigma = this * sqrt(m moved along it). Assumed
  /// 0.01 m/sqrt(m) (0.1 m after 100 m, FAST-LIO's ~0.1 % class).
  double position_random_walk_m_per_sqrtm = 0.01;
  /// Degenerate translation directions: the IMU alone carries the motion (assumed).
  double degenerate_position_random_walk_m_per_sqrtm = 0.2;
  /// Rotation drift per axis per sqrt(m) travelled (constrained; IMU + scan, small).
  double rotation_random_walk_rad_per_sqrtm = 0.0005;
  /// Degenerate rotation axes: sigma = this * sqrt(rad rotated about the axis).
  double degenerate_rotation_random_walk_rad_per_sqrtrad = 0.02;

  // ---- divergence with too few returns ----
  /// Velocity error drawn N(0, sigma^2) per axis when returns drop below min_returns; it
  /// then grows as exp(t / tau) until returns come back (filter divergence).
  double divergence_velocity_mps = 0.1;
  double divergence_time_constant_s = 1.0;

  // ---- twist noise (FAST-LIO estimates the velocity; gyro-rate angular velocity) ----
  double velocity_noise_mps = 0.02;
  double angular_rate_noise_radps = 0.005;

  // ---- reported covariance: regularised inverse information ----
  /// Largest reported 1-sigma: Cov = (H + diag(1/s_rot^2, 1/s_pos^2))^-1, the prior
  /// playing the part of FAST-LIO's IMU-propagated covariance.
  double max_reported_position_std_m = 1.0;
  double max_reported_rotation_std_rad = 0.1;

  /// The field table (core/option_fields.h): the YAML key, unit and limits of every
  /// option, which the reader, the writer and IsValid share.
  static std::span<const core::OptionField<LidarOdometryOptions>> Fields();
  /// Ceres style: false, with "<key>: <problem>" in *why, when an option is outside
  /// its limits or the ranges or elevations are not in order.
  /// The model's constructor throws std::invalid_argument then.
  bool IsValid(std::string* why = nullptr) const;
};

/// What one scan tells the registration: the point-to-plane information about the
/// LiDAR's pose and its eigen-decomposition.
struct LidarScanGeometry {
  int ray_count = 0;
  int return_count = 0;  ///< hits within [min_range, max_range]
  /// Information H = sum J_i^T J_i / sigma^2, J_i = [(p_i x n_i)^T, n_i^T], of a
  /// perturbation [phi; dt] of the sensor pose (rotation about the sensor origin, then
  /// translation), with p_i (relative to the sensor) and n_i in W axes; 1/rad^2, 1/m^2.
  Eigen::Matrix<double, 6, 6> information_W = Eigen::Matrix<double, 6, 6>::Zero();
  /// Eigen-decomposition of the full H (mixed units, ascending; columns = eigenvectors).
  Eigen::Matrix<double, 6, 1> eigenvalues = Eigen::Matrix<double, 6, 1>::Zero();
  Eigen::Matrix<double, 6, 6> eigenvectors = Eigen::Matrix<double, 6, 6>::Identity();
  /// Translation block H_tt = sum n n^T / sigma^2: eigenvalues ascending [1/m^2],
  /// eigenvectors in W (columns), and which of them are degenerate.
  Eigen::Vector3d translation_eigenvalues = Eigen::Vector3d::Zero();
  Eigen::Matrix3d translation_directions_W = Eigen::Matrix3d::Identity();
  std::array<bool, 3> translation_degenerate{true, true, true};
  /// Rotation block H_rr = sum (p x n)(p x n)^T / sigma^2 likewise [1/rad^2].
  Eigen::Vector3d rotation_eigenvalues = Eigen::Vector3d::Zero();
  Eigen::Matrix3d rotation_axes_W = Eigen::Matrix3d::Identity();
  std::array<bool, 3> rotation_degenerate{true, true, true};

  bool few_returns = true;  ///< return_count below min_returns
  bool degenerate = true;   ///< any translation direction degenerate
};

/// LiDAR odometry (Mid-360 + FAST-LIO-like): pose T_Ss and twist of the LiDAR site s in the
/// odometry frame S.
///
/// Scan (at rate_hz, from the LiDAR site at the scan's time of validity): rays on
/// azimuth_count x elevation_count directions [cos e cos a, cos e sin a, sin e] in s, the
/// azimuths shifted each scan by the golden-ratio fraction of a step (Mid-360's pattern is
/// non-repetitive), cast against the scene; hits within [min, max] range are returns with
/// points p_i (relative to the sensor) and surface normals n_i.
/// Information (point-to-plane ICP, residual r_i = n_i . (R p_i + t - q_i)):
///   H = sum_i J_i^T J_i / sigma_r^2,  J_i = [(p_i x n_i)^T, n_i^T].
/// Degeneracy (Zhang, Kaess & Singh 2016): eigen-decompose the translation block
/// H_tt = sum n n^T / sigma^2 (the IMU holds the rotation while the scan fixes the
/// translation) and the rotation block H_rr; eigenvalue lambda_k with
/// lambda_k sigma^2 < threshold => direction u_k degenerate (kDegenerate for translation).
/// Drift, accumulated between scans along the previous scan's eigen-directions, with
/// m_k = path length of s along u_k (sum |u_k . dp_W| per physics step):
///   dp_W += sum_k u_k sigma_k sqrt(m_k) n_k,   sigma_k = degenerate ? sigma_deg : sigma_con;
///   R_err = Exp(sum_k a_k s_k n_k) R_err per rotation axis a_k (s_k = sigma_deg_rot
///   sqrt(rad rotated about a_k) if degenerate, else sigma_rot sqrt(m travelled));
///   and, per physics step, the path integrated with the drifted attitude:
///   dp += (R_err - I) dp_Ss.
/// White registration noise per scan: N(0, H_tt^-1) and N(0, H_rr^-1) restricted to the
/// constrained eigen-directions of each block (sum_k u_k n_k / sqrt(lambda_k)); degenerate
/// directions get the random walk instead.
/// Few returns (< min_returns, kFewReturns): v_div ~ N(0, sigma_div^2) when it starts,
///   then v_div <- v_div exp(dt / tau) and dp += v_div dt every step (FAST-LIO diverging);
///   v_div = 0 once returns come back (the accumulated error stays: no relocalisation).
/// Output: p~ = p_Ss + dp + noise, R~ = R_err R_Ss Exp(noise); twist v_s + R~^T v_div +
/// sigma_v n, omega_s + sigma_w n.
/// Reported covariance of [dtheta_s; dp_S]: A (H + P0^-1)^-1 A^T, A = diag(R_Ws^T, R_WS^T),
/// P0 = diag(s_rot^2 I, s_pos^2 I) (regularised inverse information: it is large exactly
/// along the degenerate directions, as FAST-LIO's would be).
/// Reported twist covariance of [v_s; omega_s]: R_Ws^T (sigma_v^2 I + sum_k u_k u_k^T
/// 2 s_pos^2 rate^2 [u_k degenerate]) R_Ws and sigma_w^2 I: the velocity is the
/// registration's, unconstrained along a degenerate direction like the pose (two poses one
/// scan apart); the angular rate is the gyro's. (The reported velocity along a degenerate
/// direction is still the true one plus sigma_v n: the stated covariance disowns it.)
class LidarOdometryModel final : public SensorModel {
 public:
  /// Throws std::invalid_argument if the site is missing or an option is out of range.
  LidarOdometryModel(std::string name, const LidarOdometryOptions& options, const World& world,
                     uint64_t seed);

  const std::string& name() const override { return name_; }
  void Step(const SensorInput& input, std::vector<SensorSample>* out) override;
  uint32_t conditions() const override { return conditions_; }
  /// The odometry frame in W; with the default (start pose) valid after the first Step.
  Eigen::Isometry3d T_WS() const override { return frame_.T_WS(); }
  const std::string& site() const override { return options_.site; }

  /// Casts one scan from a LiDAR at T_Ws (scan_index sets the azimuth shift) and analyses
  /// its information matrix. Deterministic (no noise).
  LidarScanGeometry AnalyseScan(const World& world, const Eigen::Isometry3d& T_Ws,
                                int64_t scan_index = 0) const;
  /// Geometry of the latest scan.
  const LidarScanGeometry& last_scan() const { return geometry_; }

 private:
  /// The motion since the last step: the path along the latest scan's directions, the
  /// position error it carries, the divergence with too few returns.
  void FollowPath(const MountMotion& now, const Eigen::Matrix3d& R_WS, double dt_s);
  /// The random walks of the pose over the path since the previous scan.
  void DrawDriftSinceLastScan(const Eigen::Matrix3d& R_WS);
  /// Casts the scan at `at` and starts or ends the divergence.
  void Scan(const World& world, const MountMotion& at);
  /// The reported pose and twist of the latest scan.
  core::PoseMeasurement MeasuredScan(const MountMotion& at, const core::PoseMeasurement& truth,
                                     const Eigen::Matrix3d& R_WS);
  /// Its pose covariance: the regularised inverse of the scan's information.
  Eigen::Matrix<double, 6, 6> ReportedCovariance(const MountMotion& at,
                                                 const Eigen::Matrix3d& R_WS) const;
  /// Its twist covariance: large along the scan's degenerate translation directions.
  Eigen::Matrix<double, 6, 6> ReportedTwistCovariance(const MountMotion& at) const;

  std::string name_;
  LidarOdometryOptions options_;
  core::RandomStream stream_;
  Eigen::Isometry3d T_Bs_;
  core::Time period_ns_;
  core::Time latency_ns_;

  DriftingOdometryFrame frame_;  ///< S, and the pose error: R_hat = R_err R_Ss, dp_S
  core::Time next_sample_ns_ = 0;
  int64_t scan_index_ = 0;
  Eigen::Vector3d previous_p_Ws_ = Eigen::Vector3d::Zero();

  // Geometry of the latest scan and the motion since, along its eigen-directions.
  LidarScanGeometry geometry_;
  bool have_geometry_ = false;
  Eigen::Vector3d translation_path_m_ = Eigen::Vector3d::Zero();
  Eigen::Vector3d rotation_path_rad_ = Eigen::Vector3d::Zero();
  double distance_m_ = 0.0;
  bool diverging_ = false;  ///< too few returns: the output is diverging

  Eigen::Vector3d v_div_S_ = Eigen::Vector3d::Zero();      ///< diverging velocity error

  uint32_t conditions_ = kConditionNone;
};

}  // namespace tofu::sim
