#pragma once
// Allocation of a body wrench to the OMAV's actuators: six arm tilt angles and twelve
// rotor thrusts (a coaxial pair per arm). Each arm can only push in the plane normal to
// its tilt axis u_i: f_i = x_i e_z + y_i (u_i x e_z), with x_i = T_i cos(a_i),
// y_i = T_i sin(a_i). The wrench is linear in the 12 variables (x_i, y_i):
//   [F; tau] = A [x; y],  A_i = [e_z, u_i x e_z; r_i x e_z, r_i x (u_i x e_z)],
// solved with the minimum-norm pseudo-inverse; then tilt a_i = atan2(y_i, x_i) and arm
// thrust T_i = |(x_i, y_i)| split equally on the pair, whose drag torques cancel
// (Allenspach et al., "Design and optimal control of a tiltrotor micro aerial vehicle
// for efficient omnidirectional flight", IJRR 2020, Sec. 4).

#include <array>

#include <Eigen/Core>

#include "sim/rigid_body.h"

namespace tofu::sim {

inline constexpr int kArmCount = 6;
inline constexpr int kRotorsPerArm = 2;

/// One tiltable arm, in B about the centre of mass.
struct ArmGeometry {
  Eigen::Vector3d p_CoM_hinge_B = Eigen::Vector3d::Zero();  ///< hinge point rel. to CoM [m]
  Eigen::Vector3d tilt_axis_B = Eigen::Vector3d::UnitX();   ///< unit, outward along the arm
};

struct AllocationParams {
  std::array<ArmGeometry, kArmCount> arms;
  double rotor_min_thrust_N = 0.0;
  double rotor_max_thrust_N = 12.0;
  double tilt_min_rad = -3.49;
  double tilt_max_rad = 3.49;
  /// Below this arm thrust the tilt angle is ill-defined and is held [N].
  double tilt_hold_thrust_N = 0.05;
};

struct ActuatorCommand {
  std::array<double, kArmCount> tilt_rad{};
  std::array<double, kArmCount> rotor_thrust_N{};  ///< per rotor (both rotors of an arm)
};

struct AllocationResult {
  ActuatorCommand command;
  bool saturated = false;  ///< a thrust limit was hit: the achieved wrench is scaled
  double wrench_scale = 1.0;  ///< 1 unless saturated
};

class Allocator {
 public:
  explicit Allocator(const AllocationParams& params);

  /// Actuator commands for `wrench`. `current_tilt_rad` picks, among the equivalent
  /// angles a_i + 2k*pi inside the tilt range, the one closest to the current tilt, and
  /// is held where an arm's thrust is below tilt_hold_thrust_N.
  AllocationResult Allocate(const Wrench& wrench,
                            const std::array<double, kArmCount>& current_tilt_rad) const;

  /// The wrench that `command` produces (for tests and reports).
  Wrench WrenchOf(const ActuatorCommand& command) const;

  const AllocationParams& params() const { return params_; }

 private:
  AllocationParams params_;
  Eigen::Matrix<double, 6, 2 * kArmCount> A_;
  Eigen::Matrix<double, 2 * kArmCount, 6> A_pinv_;
};

}  // namespace tofu::sim
