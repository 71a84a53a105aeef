#include "estimator/velocity.h"

#include <algorithm>
#include <cstddef>

#include <Eigen/Cholesky>

#include "core/lie.h"

namespace tofu::estimator {

Eigen::Vector3d TransferVelocity(const Eigen::Matrix3d& R_Aa, const Eigen::Matrix3d& R_AB,
                                 const Eigen::Matrix3d& R_Bb, const Eigen::Vector3d& v_b_b,
                                 const Eigen::Vector3d& omega_b_b,
                                 const Eigen::Vector3d& p_ba) {
  // Velocity of a's mount point in b (rigid body: v_a = v_b + omega × r_ba), then
  // b -> B -> A -> a.
  const Eigen::Vector3d v_a_b = v_b_b + omega_b_b.cross(p_ba);
  return R_Aa.transpose() * (R_AB * (R_Bb * v_a_b));
}

Eigen::Vector3d TransferVelocityFromReference(const Eigen::Matrix3d& R_Aa,
                                              const Eigen::Matrix3d& R_AB,
                                              const Eigen::Vector3d& v_Bb,
                                              const Eigen::Matrix3d& R_Bb,
                                              const Eigen::Vector3d& omega_b_b,
                                              const Eigen::Vector3d& p_ba) {
  const Eigen::Vector3d v_Ba = v_Bb + R_Bb * omega_b_b.cross(p_ba);
  return R_Aa.transpose() * (R_AB * v_Ba);
}

bool DifferentiationOptions::IsValid(std::string* why) const {
  auto fail = [why](const char* message) {
    if (why != nullptr) *why = message;
    return false;
  };
  if (half_window_ns <= 0) return fail("half_window_ns must be positive");
  if (max_gap_ns <= 0) return fail("max_gap_ns must be positive");
  if (degree != 1 && degree != 2) return fail("degree must be 1 or 2");
  if (min_fit_samples < degree + 1) return fail("min_fit_samples must be at least degree + 1");
  return true;
}

namespace {

// Condition-number floor of the normal equations (basis scaled to [-1, 1]); below it
// the samples do not determine the slope (e.g. all at one instant) and there is no output.
constexpr double kMinRcond = 1e-10;

// Solves the least-squares fit of y(s) = c0 + c1 s (+ c2 s²) for three columns at once
// and returns c1 (the slope per unit s), or false if the fit is degenerate. With weights,
// also the slope's linear weights: c1 = Σ_i w_i y_i with w_i = e_1ᵀ N⁻¹ basis(s_i).
template <int kTerms>
bool FitSlope(const std::vector<double>& s, const std::vector<Eigen::Vector3d>& y,
              Eigen::Vector3d& slope, std::vector<double>* weights = nullptr) {
  using Square = Eigen::Matrix<double, kTerms, kTerms>;
  using Rhs = Eigen::Matrix<double, kTerms, 3>;
  Square normal = Square::Zero();
  Rhs rhs = Rhs::Zero();
  for (std::size_t i = 0; i < s.size(); ++i) {
    Eigen::Matrix<double, kTerms, 1> basis;
    basis[0] = 1.0;
    basis[1] = s[i];
    if constexpr (kTerms == 3) basis[2] = s[i] * s[i];
    normal.noalias() += basis * basis.transpose();
    rhs.noalias() += basis * y[i].transpose();
  }
  const Eigen::LDLT<Square> ldlt(normal);
  if (ldlt.info() != Eigen::Success || !(ldlt.rcond() > kMinRcond)) return false;
  const Rhs coeffs = ldlt.solve(rhs);
  slope = coeffs.row(1).transpose();
  if (weights != nullptr) {
    const Eigen::Matrix<double, kTerms, 1> row =
        ldlt.solve(Eigen::Matrix<double, kTerms, 1>::Unit(1));
    weights->clear();
    for (const double si : s) {
      weights->push_back(row[0] + row[1] * si + (kTerms == 3 ? row[kTerms - 1] * si * si : 0.0));
    }
  }
  return slope.allFinite();
}

// Accepted samples: finite, strictly increasing timestamps.
struct Accepted {
  std::vector<core::Time> t_ns;
  std::vector<std::size_t> source;  // index in the input
};

// The local fits of DifferentiationOptions over accepted samples; relative(k, i) gives
// sample i's value relative to sample k (so the fit passes near zero at s = 0).
// With cov_by_source (the covariance of each input sample, independent samples), each
// output's covariance Σ_i w_i² Σ_i goes to *out_cov.
template <typename Relative>
void FitAll(const Accepted& accepted, const DifferentiationOptions& options,
            Relative relative, std::vector<core::Time>& out_t,
            std::vector<Eigen::Vector3d>& out_d, DifferentiationStats& stats,
            const Eigen::Matrix3d* cov_by_source = nullptr,
            std::vector<Eigen::Matrix3d>* out_cov = nullptr) {
  const auto& t = accepted.t_ns;
  const std::size_t n = t.size();
  const double h_s = core::TimeToSeconds(options.half_window_ns);
  const auto min_count = static_cast<std::size_t>(std::max(options.min_fit_samples,
                                                           options.degree + 1));
  std::vector<double> s;
  std::vector<Eigen::Vector3d> y;
  std::vector<double> weights;
  std::vector<double>* const want_weights = out_cov != nullptr ? &weights : nullptr;
  std::size_t segment_begin = 0;
  while (segment_begin < n) {
    // One gap-free segment [segment_begin, segment_end).
    std::size_t segment_end = segment_begin + 1;
    while (segment_end < n && t[segment_end] - t[segment_end - 1] <= options.max_gap_ns) {
      ++segment_end;
    }
    ++stats.segments;
    std::size_t lo = segment_begin;
    std::size_t hi = segment_begin;  // one past the last sample in the window
    for (std::size_t k = segment_begin; k < segment_end; ++k) {
      while (t[k] - t[lo] > options.half_window_ns) ++lo;
      hi = std::max(hi, k + 1);
      while (hi < segment_end && t[hi] - t[k] <= options.half_window_ns) ++hi;
      const bool both_sides = lo < k && hi > k + 1;
      if (hi - lo < min_count || (options.require_both_sides && !both_sides)) {
        ++stats.without_output;
        continue;
      }
      s.clear();
      y.clear();
      for (std::size_t i = lo; i < hi; ++i) {
        s.push_back(core::TimeToSeconds(t[i] - t[k]) / h_s);
        y.push_back(relative(k, i));
      }
      Eigen::Vector3d slope;
      const bool ok = options.degree == 1 ? FitSlope<2>(s, y, slope, want_weights)
                                          : FitSlope<3>(s, y, slope, want_weights);
      if (!ok) {
        ++stats.without_output;
        continue;
      }
      out_t.push_back(t[k]);
      out_d.push_back(slope / h_s);
      if (out_cov != nullptr) {
        Eigen::Matrix3d cov = Eigen::Matrix3d::Zero();
        for (std::size_t i = lo; i < hi; ++i) {
          const double w = weights[i - lo] / h_s;
          cov += w * w * cov_by_source[accepted.source[i]];
        }
        out_cov->push_back(cov);
      }
    }
    segment_begin = segment_end;
  }
}

// Keeps the samples that are valid (per is_valid) and strictly after the last kept one.
template <typename IsValid>
Accepted Accept(std::span<const core::Time> t_ns, std::size_t n, IsValid is_valid,
                DifferentiationStats& stats) {
  Accepted accepted;
  accepted.t_ns.reserve(n);
  accepted.source.reserve(n);
  for (std::size_t i = 0; i < n; ++i) {
    if (!is_valid(i)) {
      ++stats.rejected_non_finite;
      continue;
    }
    if (!accepted.t_ns.empty() && t_ns[i] <= accepted.t_ns.back()) {
      ++stats.rejected_out_of_order;
      continue;
    }
    accepted.t_ns.push_back(t_ns[i]);
    accepted.source.push_back(i);
  }
  return accepted;
}

}  // namespace

VelocitySeries DifferentiatePositions(std::span<const core::Time> t_ns,
                                      std::span<const Eigen::Vector3d> p_Ss,
                                      const DifferentiationOptions& options,
                                      DifferentiationStats* stats) {
  return DifferentiatePositions(t_ns, p_Ss, {}, options, stats);
}

VelocitySeries DifferentiatePositions(std::span<const core::Time> t_ns,
                                      std::span<const Eigen::Vector3d> p_Ss,
                                      std::span<const Eigen::Matrix3d> cov_p_m2,
                                      const DifferentiationOptions& options,
                                      DifferentiationStats* stats) {
  DifferentiationStats local;
  DifferentiationStats& st = stats != nullptr ? *stats : local;
  st = DifferentiationStats{};
  VelocitySeries out;
  if (!options.IsValid()) return out;
  const std::size_t n = std::min(t_ns.size(), p_Ss.size());
  const Accepted accepted =
      Accept(t_ns, n, [&](std::size_t i) { return p_Ss[i].allFinite(); }, st);
  out.t_ns.reserve(accepted.t_ns.size());
  out.v_mps.reserve(accepted.t_ns.size());
  // Positions relative to the centre sample keep the fit well scaled far from the origin.
  auto relative = [&](std::size_t k, std::size_t i) -> Eigen::Vector3d {
    return p_Ss[accepted.source[i]] - p_Ss[accepted.source[k]];
  };
  const bool with_covariance = cov_p_m2.size() >= n && n > 0;
  FitAll(accepted, options, relative, out.t_ns, out.v_mps, st,
         with_covariance ? cov_p_m2.data() : nullptr,
         with_covariance ? &out.cov_m2ps2 : nullptr);
  return out;
}

AngularRateSeries DifferentiateOrientations(std::span<const core::Time> t_ns,
                                            std::span<const Eigen::Quaterniond> q_Ss,
                                            const DifferentiationOptions& options,
                                            DifferentiationStats* stats) {
  DifferentiationStats local;
  DifferentiationStats& st = stats != nullptr ? *stats : local;
  st = DifferentiationStats{};
  AngularRateSeries out;
  if (!options.IsValid()) return out;
  const std::size_t n = std::min(t_ns.size(), q_Ss.size());
  auto valid = [&](std::size_t i) {
    const double norm = q_Ss[i].coeffs().norm();
    return q_Ss[i].coeffs().allFinite() && norm > 1e-6;
  };
  const Accepted accepted = Accept(t_ns, n, valid, st);
  out.t_ns.reserve(accepted.t_ns.size());
  out.omega_radps.reserve(accepted.t_ns.size());
  // Rotation vector of R_Ss(t_k)^T R_Ss(t_i): its slope at t_k is the body rate in s.
  auto relative = [&](std::size_t k, std::size_t i) -> Eigen::Vector3d {
    const Eigen::Quaterniond q_k = q_Ss[accepted.source[k]].normalized();
    const Eigen::Quaterniond q_i = q_Ss[accepted.source[i]].normalized();
    return core::LogQuat(q_k.conjugate() * q_i);
  };
  FitAll(accepted, options, relative, out.t_ns, out.omega_radps, st);
  return out;
}

}  // namespace tofu::estimator
