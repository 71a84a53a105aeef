// Wind: stationary Gauss-Markov gusts and quadratic drag.

#include "sim/wind.h"

#include <cmath>

#include <gtest/gtest.h>

namespace tofu::sim {
namespace {

TEST(Wind, GustsHaveTheConfiguredStdAndCorrelationTime) {
  WindOptions options;
  options.gust_std_mps = 0.8;
  options.gust_correlation_time_s = 0.5;
  Wind wind(options, core::RandomStream(11, "wind"));
  const double dt = 0.01;
  const int n = 400000;  // 4000 s: 8000 correlation times
  const int lag = 50;    // 0.5 s = one correlation time
  std::vector<double> x(n);
  for (int k = 0; k < n; ++k) {
    wind.Advance(dt);
    x[k] = wind.velocity_W().x();
  }
  double sum_sq = 0.0, sum_lag = 0.0;
  for (int k = 0; k < n; ++k) sum_sq += x[k] * x[k];
  for (int k = 0; k + lag < n; ++k) sum_lag += x[k] * x[k + lag];
  const double var = sum_sq / n;
  const double rho = (sum_lag / (n - lag)) / var;
  // Effective sample count of a Gauss-Markov sequence: n_eff ~ T / (2 tau) = 4000.
  const double n_eff = n * dt / (2.0 * options.gust_correlation_time_s);
  EXPECT_NEAR(std::sqrt(var), 0.8, 0.8 * 4.0 / std::sqrt(2.0 * n_eff));
  EXPECT_NEAR(rho, std::exp(-1.0), 4.0 / std::sqrt(n_eff));
}

TEST(Wind, DragIsQuadraticInRelativeAirspeed) {
  WindOptions options;
  options.mean_velocity_W_mps = Eigen::Vector3d(2.0, 0.0, 0.0);
  options.drag_area_m2 = 0.25;
  options.air_density_kgpm3 = 1.2;
  Wind wind(options, core::RandomStream(1, "wind"));
  const Eigen::Vector3d f = wind.DragForce_W(Eigen::Vector3d(-1.0, 0.0, 0.0));
  EXPECT_NEAR(f.x(), 0.5 * 1.2 * 0.25 * 9.0, 1e-12);
  EXPECT_NEAR(f.y(), 0.0, 1e-15);
  EXPECT_NEAR(wind.DragForce_W(Eigen::Vector3d(2.0, 0.0, 0.0)).norm(), 0.0, 1e-15);
}

}  // namespace
}  // namespace tofu::sim
