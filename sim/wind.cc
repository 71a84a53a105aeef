#include "sim/wind.h"

#include <cmath>

namespace tofu::sim {

// ---- options ----

std::span<const core::OptionField<WindOptions>> WindOptions::Fields() {
  using F = core::OptionField<WindOptions>;
  using R = core::NumberRule;
  using O = WindOptions;
  static const F kFields[] = {
      F::Vector("mean_velocity_mps", &O::mean_velocity_W_mps, R::Any("m/s"))
          .Doc("mean wind velocity in W"),
      F::Number("gust_std_mps", &O::gust_std_mps, R::NonNegative("m/s"))
          .Doc("stationary standard deviation of the gusts per axis"),
      F::Number("gust_correlation_time_s", &O::gust_correlation_time_s, R::Positive("s"))
          .Doc("Gauss-Markov time constant of the gusts"),
      F::Number("drag_area_m2", &O::drag_area_m2, R::NonNegative("m^2"))
          .Doc("drag coefficient times frontal area of the airframe, Cd*A"),
      F::Number("air_density_kgpm3", &O::air_density_kgpm3, R::Positive("kg/m^3"))
          .Doc("air density"),
  };
  return kFields;
}

bool WindOptions::IsValid(std::string* why) const {
  return core::CheckOptionFields<WindOptions>(*this, Fields(), why);
}

Wind::Wind(const WindOptions& options, core::RandomStream stream)
    : options_(core::ValidOptions(options, "wind")), stream_(std::move(stream)) {
  // Start the gust process in its stationary distribution, so no warm-up transient.
  for (int k = 0; k < 3; ++k) gust_W_(k) = options_.gust_std_mps * stream_.Normal();
}

void Wind::Advance(double dt_s) {
  if (options_.gust_std_mps <= 0.0) return;
  // The harness advances by one fixed physics step: the transition is computed once.
  if (dt_s != step_dt_s_) {
    step_dt_s_ = dt_s;
    step_phi_ = std::exp(-dt_s / options_.gust_correlation_time_s);
    step_sigma_ = options_.gust_std_mps * std::sqrt(1.0 - step_phi_ * step_phi_);
  }
  for (int k = 0; k < 3; ++k) gust_W_(k) = step_phi_ * gust_W_(k) + step_sigma_ * stream_.Normal();
}

Eigen::Vector3d Wind::DragForce_W(const Eigen::Vector3d& v_WB_W) const {
  const Eigen::Vector3d v_rel = velocity_W() - v_WB_W;
  return 0.5 * options_.air_density_kgpm3 * options_.drag_area_m2 * v_rel.norm() * v_rel;
}

}  // namespace tofu::sim
