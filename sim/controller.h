#pragma once
// Full-pose geometric tracking controller on SE(3) for a fully actuated (omnidirectional)
// aerial robot: position and attitude are tracked independently, so the robot can hover
// tilted. Translational part: PID on position with acceleration feed-forward; rotational
// part: Lee, Leok & McClamroch (CDC 2010), eq. (11)-(12), with the attitude error
// e_R = 1/2 vee(R_d^T R - R^T R_d). Output is a body wrench about the centre of mass.

#include <Eigen/Core>
#include <Eigen/Geometry>

#include "core/option_fields.h"
#include "core/time.h"
#include "sim/rigid_body.h"
#include "sim/trajectory.h"

namespace tofu::sim {

/// The controller's view of the robot's state: ground truth now, an estimator's output
/// in closed-loop co-testing. Body frame B, world W.
struct RobotState {
  core::Time t_ns = 0;
  Eigen::Vector3d p_WB = Eigen::Vector3d::Zero();
  Eigen::Quaterniond q_WB = Eigen::Quaterniond::Identity();
  Eigen::Vector3d v_WB_W = Eigen::Vector3d::Zero();
  Eigen::Vector3d omega_WB_B = Eigen::Vector3d::Zero();
};

/// Where the controller gets its state from (ground truth, or an estimate).
class StateSource {
 public:
  virtual ~StateSource() = default;
  virtual RobotState State() const = 0;
};

/// Gains are in acceleration units (scaled by mass and inertia inside), so they carry
/// over to another robot model unchanged.
struct ControllerOptions {
  double rate_hz = 200.0;
  Eigen::Vector3d position_gain_per_s2 = Eigen::Vector3d(16.0, 16.0, 20.0);
  Eigen::Vector3d velocity_gain_per_s = Eigen::Vector3d(8.0, 8.0, 9.0);
  Eigen::Vector3d position_integral_gain_per_s3 = Eigen::Vector3d(2.0, 2.0, 3.0);
  double integral_limit_mps2 = 2.0;  ///< anti-windup bound of the integral term
  /// Anti-windup: the integrators see the error clipped to this band, so a large
  /// transient (take-off, a push) does not wind them up [m].
  double integral_error_band_m = 0.02;
  Eigen::Vector3d attitude_gain_per_s2 = Eigen::Vector3d(60.0, 60.0, 40.0);
  Eigen::Vector3d angular_rate_gain_per_s = Eigen::Vector3d(14.0, 14.0, 12.0);
  Eigen::Vector3d attitude_integral_gain_per_s3 = Eigen::Vector3d(5.0, 5.0, 4.0);
  double attitude_integral_limit_radps2 = 3.0;
  double attitude_integral_error_band_rad = 0.02;  ///< as integral_error_band_m

  /// The field table (core/option_fields.h): the YAML key, unit and limits of every
  /// option, which the reader, the writer and IsValid share.
  static std::span<const core::OptionField<ControllerOptions>> Fields();
  /// Ceres style: false, with "<key>: <problem>" in *why, when an option is outside
  /// its limits.
  /// GeometricController's constructor throws std::invalid_argument then.
  bool IsValid(std::string* why = nullptr) const;
};



class GeometricController {
 public:
  GeometricController(const ControllerOptions& options, const RigidBodyParams& params);

  /// Wrench that tracks `reference` from `state`. Call at options.rate_hz; the
  /// integrators advance by the time since the previous call.
  Wrench Compute(const RobotState& state, const Reference& reference);

  /// Clear integrators (e.g. on a new mission).
  void Reset();

 private:
  ControllerOptions options_;
  RigidBodyParams params_;
  Eigen::Vector3d position_integral_ = Eigen::Vector3d::Zero();
  Eigen::Vector3d attitude_integral_ = Eigen::Vector3d::Zero();
  core::Time last_t_ns_ = -1;
};

}  // namespace tofu::sim
