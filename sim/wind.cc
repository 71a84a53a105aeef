#include "sim/wind.h"

#include <cmath>

namespace tofu::sim {

Wind::Wind(const WindOptions& options, core::RandomStream stream)
    : options_(options), stream_(std::move(stream)) {
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
