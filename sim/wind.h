#pragma once
// Wind disturbance: a mean wind plus gusts as a first-order Gauss-Markov process per
// axis (the Dryden turbulence model reduced to first order), acting on the airframe as
// quadratic drag F = 1/2 rho CdA |v_rel| v_rel with v_rel = wind - v_WB.

#include <Eigen/Core>

#include "core/option_fields.h"
#include "core/random.h"

namespace tofu::sim {

struct WindOptions {
  Eigen::Vector3d mean_velocity_W_mps = Eigen::Vector3d::Zero();
  double gust_std_mps = 0.0;             ///< stationary standard deviation per axis
  double gust_correlation_time_s = 2.0;  ///< Gauss-Markov time constant
  double drag_area_m2 = 0.25;            ///< drag coefficient times frontal area, Cd*A
  double air_density_kgpm3 = 1.225;

  /// The field table (core/option_fields.h): the YAML key, unit and limits of every
  /// option, which the reader, the writer and IsValid share.
  static std::span<const core::OptionField<WindOptions>> Fields();
  /// Ceres style: false, with "<key>: <problem>" in *why, when an option is outside
  /// its limits.
  /// Wind's constructor throws std::invalid_argument then.
  bool IsValid(std::string* why = nullptr) const;
};

class Wind {
 public:
  Wind(const WindOptions& options, core::RandomStream stream);

  /// Advances the gust process by dt_s (exact discretisation of the Gauss-Markov
  /// process: g_k+1 = e^(-dt/tau) g_k + sigma sqrt(1 - e^(-2dt/tau)) n_k).
  void Advance(double dt_s);

  /// Wind velocity in W now [m/s].
  Eigen::Vector3d velocity_W() const { return options_.mean_velocity_W_mps + gust_W_; }

  /// Drag force on the airframe in W [N] for the robot's velocity v_WB_W.
  Eigen::Vector3d DragForce_W(const Eigen::Vector3d& v_WB_W) const;

 private:
  WindOptions options_;
  core::RandomStream stream_;
  Eigen::Vector3d gust_W_ = Eigen::Vector3d::Zero();
  double step_dt_s_ = -1.0;  // the step the transition below was computed for
  double step_phi_ = 0.0;
  double step_sigma_ = 0.0;
};

}  // namespace tofu::sim
