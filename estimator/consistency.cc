#include "estimator/consistency.h"

#include <algorithm>
#include <cassert>
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <limits>

#include <Eigen/Eigenvalues>

#include "core/units.h"
#include "estimator/consistency_matrix.h"

namespace tofu::estimator {

std::string_view MetricName(ConsistencyMetric metric) {
  switch (metric) {
    case ConsistencyMetric::kMae: return "mae";
    case ConsistencyMetric::kPcc: return "pcc";
    case ConsistencyMetric::kKl: return "kl";
    case ConsistencyMetric::kCm: return "cm";
    case ConsistencyMetric::kNis: return "nis";
  }
  return "unknown";
}

std::optional<ConsistencyMetric> MetricFromName(std::string_view name) {
  for (const ConsistencyMetric m : {ConsistencyMetric::kMae, ConsistencyMetric::kPcc,
                                    ConsistencyMetric::kKl, ConsistencyMetric::kCm,
                                    ConsistencyMetric::kNis}) {
    if (MetricName(m) == name) return m;
  }
  return std::nullopt;
}

bool ConsistencyOptions::IsValid(std::string* why) const {
  auto fail = [why](const char* message) {
    if (why != nullptr) *why = message;
    return false;
  };
  if (window_ns <= 0) return fail("window_ns must be positive");
  if (!(kl_bandwidth_scale > 0.0) || !std::isfinite(kl_bandwidth_scale)) {
    return fail("kl_bandwidth_scale must be positive and finite");
  }
  // No metric is defined on an empty sample.
  if (min_samples < 1) return fail("min_samples must be at least 1");
  if (!(unobserved_std_mps > 0.0) || !std::isfinite(unobserved_std_mps)) {
    return fail("unobserved_std_mps must be positive and finite");
  }
  if (!(std_floor_mps >= 0.0) || !(std_floor_mps < unobserved_std_mps)) {
    return fail("std_floor_mps must be in [0, unobserved_std_mps)");
  }
  return true;
}

namespace {

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

// KL: kernels are truncated at this many bandwidths (exp(-32) ~ 1e-14 of a kernel's peak,
// far below the density floor below).
constexpr double kKernelCutoff = 8.0;
// KL: q is floored at this fraction of its peak on the grid, so log(p/q) stays finite
// where Q has no mass (the divergence then saturates instead of becoming infinite).
constexpr double kDensityFloor = 1e-10;
// KL: the grid spans [min − 4h, max + 4h] with spacing <= h_min / 4, between these many
// Simpson intervals (even).
constexpr int kMinGridIntervals = 256;
constexpr int kMaxGridIntervals = 2048;
// KL: bandwidth floor (m/s) for a sample without spread (all values equal).
constexpr double kMinBandwidth = 1e-6;

// Per-thread scratch so that repeated metric evaluations allocate only while buffers grow.
struct Scratch {
  std::vector<double> p, q;           // one axis of each sample
  std::vector<double> sorted;         // KL: sorted copy for the quantiles
  std::vector<double> grid_p, grid_q; // KL: densities on the grid
  std::vector<double> x, y;           // MAE/PCC: paired values of one axis
  std::vector<std::size_t> a_index;   // finite samples of a in the window
  std::vector<std::size_t> b_index;   // finite samples of b in the window
  std::vector<std::size_t> pair_a;    // MAE/PCC: sample of a of each pair
  std::vector<std::size_t> pair_b;    // MAE/PCC: left bracket in b_index of each pair
  std::vector<double> pair_w;         // MAE/PCC: interpolation weight of the right bracket
};

Scratch& ThreadScratch() {
  thread_local Scratch scratch;
  return scratch;
}

// Copies the finite values of x into out.
void CopyFinite(std::span<const double> x, std::vector<double>& out) {
  out.clear();
  for (const double value : x) {
    if (std::isfinite(value)) out.push_back(value);
  }
}

// Quantile of a sorted sample with linear interpolation between order statistics.
double SortedQuantile(const std::vector<double>& sorted, double prob) {
  const double pos = prob * static_cast<double>(sorted.size() - 1);
  const auto below = static_cast<std::size_t>(std::floor(pos));
  const std::size_t above = std::min(below + 1, sorted.size() - 1);
  const double frac = pos - static_cast<double>(below);
  return sorted[below] + frac * (sorted[above] - sorted[below]);
}

// Silverman's rule of thumb h = 0.9 min(sd, IQR/1.34) n^(-1/5) (sd with n − 1); when the
// IQR is zero the sd alone is used, and without any spread kMinBandwidth.
double SilvermanBandwidth(std::span<const double> x, std::vector<double>& sorted) {
  const auto n = static_cast<double>(x.size());
  double mean = 0.0;
  for (const double value : x) mean += value;
  mean /= n;
  double ss = 0.0;
  for (const double value : x) ss += (value - mean) * (value - mean);
  const double sd = x.size() > 1 ? std::sqrt(ss / (n - 1.0)) : 0.0;
  sorted.assign(x.begin(), x.end());
  std::sort(sorted.begin(), sorted.end());
  const double iqr = SortedQuantile(sorted, 0.75) - SortedQuantile(sorted, 0.25);
  double spread = sd;
  if (iqr > 0.0) spread = std::min(sd, iqr / 1.34);
  const double h = 0.9 * spread * std::pow(n, -0.2);
  return h > kMinBandwidth ? h : kMinBandwidth;
}

// Gaussian KDE of the sorted sample evaluated on the uniform grid lo + k * step; each
// grid point sums only the samples within kKernelCutoff bandwidths (two moving bounds).
void EvaluateKde(std::span<const double> sorted, double h, double lo, double step,
                 int intervals, std::vector<double>& density) {
  density.assign(static_cast<std::size_t>(intervals) + 1, 0.0);
  const double norm = 1.0 / (static_cast<double>(sorted.size()) * h *
                             std::sqrt(core::kTwoPi));
  std::size_t first = 0;
  std::size_t last = 0;
  for (int k = 0; k <= intervals; ++k) {
    const double x = lo + step * k;
    while (first < sorted.size() && sorted[first] < x - kKernelCutoff * h) ++first;
    last = std::max(last, first);
    while (last < sorted.size() && sorted[last] <= x + kKernelCutoff * h) ++last;
    double sum = 0.0;
    for (std::size_t i = first; i < last; ++i) {
      const double z = (x - sorted[i]) / h;
      sum += std::exp(-0.5 * z * z);
    }
    density[static_cast<std::size_t>(k)] = norm * sum;
  }
}

// Half-open index range of the samples with t in (t_eval − window, t_eval].
std::pair<std::size_t, std::size_t> WindowRange(std::span<const core::Time> t_ns,
                                                core::Time t_eval_ns, core::Time window_ns) {
  const auto lo = std::upper_bound(t_ns.begin(), t_ns.end(), t_eval_ns - window_ns);
  const auto hi = std::upper_bound(lo, t_ns.end(), t_eval_ns);
  return {static_cast<std::size_t>(lo - t_ns.begin()),
          static_cast<std::size_t>(hi - t_ns.begin())};
}

// Indices of the samples in [lo, hi) whose three components are finite.
void FiniteIndices(const VelocitySeries& s, std::size_t lo, std::size_t hi,
                   std::vector<std::size_t>& out) {
  out.clear();
  for (std::size_t k = lo; k < hi; ++k) {
    if (s.v_mps[k].allFinite()) out.push_back(k);
  }
}

// Pooled mean and (population) standard deviation of one axis over both windows; the
// scale is 1 when there is no spread, so standardisation then only centres.
void PooledStats(const VelocitySeries& a, const std::vector<std::size_t>& ia,
                 const VelocitySeries& b, const std::vector<std::size_t>& ib, int axis,
                 double& mean, double& scale) {
  double sum = 0.0;
  for (const std::size_t k : ia) sum += a.v_mps[k][axis];
  for (const std::size_t k : ib) sum += b.v_mps[k][axis];
  const auto count = static_cast<double>(ia.size() + ib.size());
  mean = sum / count;
  double ss = 0.0;
  for (const std::size_t k : ia) ss += (a.v_mps[k][axis] - mean) * (a.v_mps[k][axis] - mean);
  for (const std::size_t k : ib) ss += (b.v_mps[k][axis] - mean) * (b.v_mps[k][axis] - mean);
  const double sd = std::sqrt(ss / count);
  scale = (sd > 0.0 && std::isfinite(sd)) ? sd : 1.0;
}

}  // namespace

// ---- one-dimensional distances ----

double CramerVonMisesDistanceSorted(std::span<const double> p_sorted,
                                    std::span<const double> q_sorted) {
  const std::size_t n = p_sorted.size();
  const std::size_t m = q_sorted.size();
  if (n == 0 || m == 0) return kNaN;
  // Walk the merged sorted values z_1 <= z_2 <= ...; after consuming z_k (i values of p,
  // j of q) both ECDFs are constant on [z_k, z_k+1): F_P − F_Q = (i m − j n) / (n m),
  // kept as an exact integer d. Ties need no special case: between tied values the
  // interval has zero width. Branch-light (the pick is a select), and every step consumes
  // one value, so the loop ends even on unsorted or NaN input (with a meaningless result).
  const auto n64 = static_cast<int64_t>(n);
  const auto m64 = static_cast<int64_t>(m);
  std::size_t i = 0;
  std::size_t j = 0;
  int64_t d = 0;
  double prev = std::min(p_sorted[0], q_sorted[0]);
  double acc = 0.0;
  while (i < n && j < m) {
    const double a = p_sorted[i];
    const double b = q_sorted[j];
    const bool take_p = a <= b;
    const double z = take_p ? a : b;
    const auto dd = static_cast<double>(d);
    acc += dd * dd * (z - prev);
    prev = z;
    i += take_p ? 1 : 0;
    j += take_p ? 0 : 1;
    d += take_p ? m64 : -n64;
  }
  for (; i < n; ++i) {
    const auto dd = static_cast<double>(d);
    acc += dd * dd * (p_sorted[i] - prev);
    prev = p_sorted[i];
    d += m64;
  }
  for (; j < m; ++j) {
    const auto dd = static_cast<double>(d);
    acc += dd * dd * (q_sorted[j] - prev);
    prev = q_sorted[j];
    d -= n64;
  }
  // D = (2 ∫ (F_P − F_Q)² dx)^½, eq. (5).
  return std::sqrt(2.0 * acc) / (static_cast<double>(n) * static_cast<double>(m));
}

double CramerVonMisesDistance(std::span<const double> p, std::span<const double> q) {
  // Non-finite values would break the sort's ordering; they are ignored.
  Scratch& s = ThreadScratch();
  CopyFinite(p, s.p);
  CopyFinite(q, s.q);
  std::sort(s.p.begin(), s.p.end());
  std::sort(s.q.begin(), s.q.end());
  return CramerVonMisesDistanceSorted(s.p, s.q);
}

double KlDivergence(std::span<const double> p, std::span<const double> q,
                    double bandwidth_scale) {
  Scratch& s = ThreadScratch();
  CopyFinite(p, s.p);
  CopyFinite(q, s.q);
  if (s.p.empty() || s.q.empty()) return kNaN;
  const double scale = bandwidth_scale > 0.0 ? bandwidth_scale : 1.0;
  // Bandwidths from each sample (Silverman), then sort both for the truncated KDE sums.
  const double h_p = scale * SilvermanBandwidth(s.p, s.sorted);
  const double h_q = scale * SilvermanBandwidth(s.q, s.sorted);
  std::sort(s.p.begin(), s.p.end());
  std::sort(s.q.begin(), s.q.end());

  // Grid over the union of the supports, Simpson's rule needs an even interval count.
  const double h_max = std::max(h_p, h_q);
  const double h_min = std::min(h_p, h_q);
  const double lo = std::min(s.p.front(), s.q.front()) - 4.0 * h_max;
  const double hi = std::max(s.p.back(), s.q.back()) + 4.0 * h_max;
  const double wanted = std::ceil((hi - lo) / (0.25 * h_min));
  int intervals = static_cast<int>(
      std::clamp(wanted, static_cast<double>(kMinGridIntervals),
                 static_cast<double>(kMaxGridIntervals)));
  intervals += intervals % 2;
  const double step = (hi - lo) / intervals;
  // With the grid capped, a kernel much narrower than the other sample's spread (a
  // near-constant axis, e.g. the vertical velocity in level flight) would fall between
  // grid points and integrate to zero: widen kernels to two grid steps at least.
  EvaluateKde(s.p, std::max(h_p, 2.0 * step), lo, step, intervals, s.grid_p);
  EvaluateKde(s.q, std::max(h_q, 2.0 * step), lo, step, intervals, s.grid_q);

  // Floor q, then normalise both densities under the same Simpson weights, so the sum
  // below is a KL divergence of two discrete distributions (>= 0 by Gibbs' inequality).
  const double q_peak = *std::max_element(s.grid_q.begin(), s.grid_q.end());
  const double q_floor = kDensityFloor * q_peak;
  auto weight = [intervals](int k) {
    if (k == 0 || k == intervals) return 1.0;
    return (k % 2 == 1) ? 4.0 : 2.0;
  };
  double mass_p = 0.0;
  double mass_q = 0.0;
  for (int k = 0; k <= intervals; ++k) {
    auto& qk = s.grid_q[static_cast<std::size_t>(k)];
    qk = std::max(qk, q_floor);
    mass_p += weight(k) * s.grid_p[static_cast<std::size_t>(k)];
    mass_q += weight(k) * qk;
  }
  double kl = 0.0;
  for (int k = 0; k <= intervals; ++k) {
    const double pk = s.grid_p[static_cast<std::size_t>(k)] / mass_p;
    if (pk <= 0.0) continue;
    const double qk = s.grid_q[static_cast<std::size_t>(k)] / mass_q;
    kl += weight(k) * pk * std::log(pk / qk);
  }
  return std::max(kl, 0.0);
}

double MeanAbsoluteError(std::span<const double> x, std::span<const double> y) {
  assert(x.size() == y.size());
  const std::size_t n = std::min(x.size(), y.size());
  if (n == 0) return kNaN;
  double sum = 0.0;
  for (std::size_t i = 0; i < n; ++i) sum += std::abs(x[i] - y[i]);
  return sum / static_cast<double>(n);
}

double PearsonCorrelation(std::span<const double> x, std::span<const double> y) {
  assert(x.size() == y.size());
  const std::size_t n = std::min(x.size(), y.size());
  if (n == 0) return 0.0;
  // Two passes (means first) for accuracy, eq. (3).
  double mean_x = 0.0;
  double mean_y = 0.0;
  for (std::size_t i = 0; i < n; ++i) {
    mean_x += x[i];
    mean_y += y[i];
  }
  mean_x /= static_cast<double>(n);
  mean_y /= static_cast<double>(n);
  double sxy = 0.0;
  double sxx = 0.0;
  double syy = 0.0;
  for (std::size_t i = 0; i < n; ++i) {
    const double dx = x[i] - mean_x;
    const double dy = y[i] - mean_y;
    sxy += dx * dy;
    sxx += dx * dx;
    syy += dy * dy;
  }
  if (!(sxx > 0.0) || !(syy > 0.0)) return 0.0;
  return sxy / (std::sqrt(sxx) * std::sqrt(syy));
}

// ---- velocity streams ----

namespace {

// A sample's stated covariance: zero when its stream states none.
Eigen::Matrix3d StatedCovariance(const VelocitySeries& series, std::size_t k) {
  return series.cov_m2ps2.size() == series.t_ns.size() ? series.cov_m2ps2[k]
                                                        : Eigen::Matrix3d::Zero();
}

// kNis over the pairs WindowConsistency formed: Σ_k Σ_observed (uᵀΔv_k)²/λ over Σ_k dof_k,
// with (λ, u) the eigenpairs of S_k = Σ_a + Σ_b + floor² I. Under consistency each term
// has mean 1 whatever the correlation between samples, so the ratio's mean is 1.
std::optional<double> NormalizedSquaredDifference(const VelocitySeries& a,
                                                  const VelocitySeries& b, const Scratch& s,
                                                  const ConsistencyOptions& options) {
  // Two streams that state nothing about themselves cannot be normalised.
  if (a.cov_m2ps2.size() != a.t_ns.size() && b.cov_m2ps2.size() != b.t_ns.size()) {
    return std::nullopt;
  }
  const double max_variance = options.unobserved_std_mps * options.unobserved_std_mps;
  const double floor_variance = options.std_floor_mps * options.std_floor_mps;
  double sum = 0.0;
  int64_t dof = 0;
  for (std::size_t k = 0; k < s.pair_a.size(); ++k) {
    const double w = s.pair_w[k];
    const std::size_t b0 = s.b_index[s.pair_b[k]];
    Eigen::Vector3d v_b = b.v_mps[b0];
    Eigen::Matrix3d cov_b = StatedCovariance(b, b0);
    if (w > 0.0) {
      const std::size_t b1 = s.b_index[s.pair_b[k] + 1];
      v_b += w * (b.v_mps[b1] - v_b);
      cov_b = (1.0 - w) * cov_b + w * StatedCovariance(b, b1);
    }
    Eigen::Matrix3d S = StatedCovariance(a, s.pair_a[k]) + cov_b;
    if (!S.allFinite()) continue;  // a sample whose covariance is unknown
    S.diagonal().array() += floor_variance;
    const Eigen::Vector3d dv = a.v_mps[s.pair_a[k]] - v_b;
    Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> eigen;
    eigen.computeDirect(0.5 * (S + S.transpose()));
    for (int d = 0; d < 3; ++d) {
      const double variance = eigen.eigenvalues()[d];
      if (!(variance > 0.0) || variance > max_variance) continue;
      const double along = eigen.eigenvectors().col(d).dot(dv);
      sum += along * along / variance;
      ++dof;
    }
  }
  if (dof == 0) return std::nullopt;
  return sum / static_cast<double>(dof);
}

}  // namespace

void EraseFront(VelocitySeries& series, std::size_t count) {
  const auto n = static_cast<std::ptrdiff_t>(std::min(count, series.t_ns.size()));
  if (n == 0) return;
  series.t_ns.erase(series.t_ns.begin(), series.t_ns.begin() + n);
  series.v_mps.erase(series.v_mps.begin(), series.v_mps.begin() + n);
  auto& cov = series.cov_m2ps2;
  if (!cov.empty()) cov.erase(cov.begin(), cov.begin() + n);
}

std::optional<double> WindowConsistency(const VelocitySeries& a, const VelocitySeries& b,
                                        core::Time t_eval_ns, ConsistencyMetric metric,
                                        const ConsistencyOptions& options) {
  Scratch& s = ThreadScratch();
  const std::size_t min_samples =
      static_cast<std::size_t>(std::max(1, options.min_samples));
  // Select the window by binary search; samples with a non-finite component are ignored.
  const std::size_t a_size = std::min(a.t_ns.size(), a.v_mps.size());
  const std::size_t b_size = std::min(b.t_ns.size(), b.v_mps.size());
  const auto [a_lo, a_hi] = WindowRange(std::span(a.t_ns.data(), a_size), t_eval_ns,
                                        options.window_ns);
  const auto [b_lo, b_hi] = WindowRange(std::span(b.t_ns.data(), b_size), t_eval_ns,
                                        options.window_ns);
  FiniteIndices(a, a_lo, a_hi, s.a_index);
  FiniteIndices(b, b_lo, b_hi, s.b_index);
  if (s.a_index.size() < min_samples || s.b_index.size() < min_samples) return std::nullopt;

  // MAE, PCC and NIS: pair each sample of a with b interpolated linearly at its time,
  // skipping samples of a outside b's span in the window. Fewer than min_samples pairs:
  // unavailable.
  const bool paired = metric == ConsistencyMetric::kMae || metric == ConsistencyMetric::kPcc ||
                      metric == ConsistencyMetric::kNis;
  if (paired) {
    s.pair_a.clear();
    s.pair_b.clear();
    s.pair_w.clear();
    const core::Time b_first = b.t_ns[s.b_index.front()];
    const core::Time b_last = b.t_ns[s.b_index.back()];
    std::size_t right = 0;  // first finite b sample at or after the current a time
    for (const std::size_t ka : s.a_index) {
      const core::Time t = a.t_ns[ka];
      if (t < b_first || t > b_last) continue;
      while (b.t_ns[s.b_index[right]] < t) ++right;
      if (b.t_ns[s.b_index[right]] == t) {
        s.pair_a.push_back(ka);
        s.pair_b.push_back(right);
        s.pair_w.push_back(0.0);
        continue;
      }
      const core::Time t0 = b.t_ns[s.b_index[right - 1]];
      const core::Time t1 = b.t_ns[s.b_index[right]];
      s.pair_a.push_back(ka);
      s.pair_b.push_back(right - 1);
      s.pair_w.push_back(static_cast<double>(t - t0) / static_cast<double>(t1 - t0));
    }
    if (s.pair_a.size() < min_samples) return std::nullopt;
  }
  if (metric == ConsistencyMetric::kNis) return NormalizedSquaredDifference(a, b, s, options);

  double total = 0.0;
  for (int axis = 0; axis < 3; ++axis) {
    double mean = 0.0;
    double scale = 1.0;
    if (options.standardize) PooledStats(a, s.a_index, b, s.b_index, axis, mean, scale);
    const double inv_scale = 1.0 / scale;
    if (paired) {
      s.x.clear();
      s.y.clear();
      for (std::size_t k = 0; k < s.pair_a.size(); ++k) {
        const double w = s.pair_w[k];
        const double y0 = b.v_mps[s.b_index[s.pair_b[k]]][axis];
        const double y = w > 0.0 ? y0 + w * (b.v_mps[s.b_index[s.pair_b[k] + 1]][axis] - y0)
                                 : y0;
        s.x.push_back((a.v_mps[s.pair_a[k]][axis] - mean) * inv_scale);
        s.y.push_back((y - mean) * inv_scale);
      }
      total += metric == ConsistencyMetric::kMae ? MeanAbsoluteError(s.x, s.y)
                                                 : PearsonCorrelation(s.x, s.y);
      continue;
    }
    s.x.clear();
    s.y.clear();
    for (const std::size_t k : s.a_index) s.x.push_back((a.v_mps[k][axis] - mean) * inv_scale);
    for (const std::size_t k : s.b_index) s.y.push_back((b.v_mps[k][axis] - mean) * inv_scale);
    if (metric == ConsistencyMetric::kCm) {
      std::sort(s.x.begin(), s.x.end());
      std::sort(s.y.begin(), s.y.end());
      total += CramerVonMisesDistanceSorted(s.x, s.y);
    } else {
      total += KlDivergence(s.x, s.y, options.kl_bandwidth_scale);
    }
  }
  return total;
}

bool MeanDifferenceOptions::IsValid(std::string* why) const {
  auto fail = [why](const char* message) {
    if (why != nullptr) *why = message;
    return false;
  };
  for (const MeanNoise* noise : {&a, &b}) {
    if (noise->correlation_time_ns <= 0) return fail("correlation_time_ns must be positive");
    if (noise->position_covariance_m2 && !noise->position_covariance_m2->allFinite()) {
      return fail("position_covariance_m2 must be finite");
    }
  }
  if (!(floor_std_mps >= 0.0) || !std::isfinite(floor_std_mps)) {
    return fail("floor_std_mps must be finite and >= 0");
  }
  if (!(rotation_prior_std_rad > 0.0) || !std::isfinite(rotation_prior_std_rad)) {
    return fail("rotation_prior_std_rad must be positive and finite");
  }
  if (!(unobserved_std_mps > 0.0) || !std::isfinite(unobserved_std_mps)) {
    return fail("unobserved_std_mps must be positive and finite");
  }
  if (min_samples < 2) return fail("min_samples must be at least 2");
  if (!(clip_sigma > 0.0)) return fail("clip_sigma must be positive (+inf: no clipping)");
  if (!(sample_floor_std_mps >= 0.0) || !std::isfinite(sample_floor_std_mps)) {
    return fail("sample_floor_std_mps must be finite and >= 0");
  }
  return true;
}

std::optional<MeanDifference> WindowMeanDifference(const VelocitySeries& a,
                                                   const VelocitySeries& b,
                                                   core::Time t_from_ns, core::Time t_to_ns,
                                                   const MeanDifferenceOptions& options) {
  if (a.cov_m2ps2.size() != a.t_ns.size() || b.cov_m2ps2.size() != b.t_ns.size()) {
    return std::nullopt;
  }
  // The pairs (equal stamps), each difference clipped.
  struct Pair {
    core::Time t_ns;
    Eigen::Vector3d difference;
    Eigen::Vector3d v_a;
    std::size_t ia;
    std::size_t ib;
  };
  const double sample_floor_variance = options.sample_floor_std_mps * options.sample_floor_std_mps;
  std::size_t ia = static_cast<std::size_t>(
      std::upper_bound(a.t_ns.begin(), a.t_ns.end(), t_from_ns) - a.t_ns.begin());
  std::size_t ib = static_cast<std::size_t>(
      std::upper_bound(b.t_ns.begin(), b.t_ns.end(), t_from_ns) - b.t_ns.begin());
  std::vector<Pair> pairs;
  pairs.reserve(std::min(a.t_ns.size() - ia, b.t_ns.size() - ib));
  // Σ_k Σ_a,k and Σ_k Σ_b,k over the pairs: their mean is the pair's typical covariance.
  Eigen::Matrix3d sum_covariance_a = Eigen::Matrix3d::Zero();
  Eigen::Matrix3d sum_covariance_b = Eigen::Matrix3d::Zero();
  while (ia < a.t_ns.size() && ib < b.t_ns.size() && a.t_ns[ia] <= t_to_ns &&
         b.t_ns[ib] <= t_to_ns) {
    if (a.t_ns[ia] != b.t_ns[ib]) {
      (a.t_ns[ia] < b.t_ns[ib] ? ia : ib) += 1;
      continue;
    }
    if (a.cov_m2ps2[ia].allFinite() && b.cov_m2ps2[ib].allFinite() && a.v_mps[ia].allFinite() &&
        b.v_mps[ib].allFinite()) {
      Eigen::Vector3d difference = a.v_mps[ia] - b.v_mps[ib];
      Eigen::Matrix3d S = a.cov_m2ps2[ia] + b.cov_m2ps2[ib];
      S.diagonal().array() += sample_floor_variance;
      const double sigmas = std::sqrt(difference.dot(S.ldlt().solve(difference)));
      if (sigmas > options.clip_sigma) difference *= options.clip_sigma / sigmas;
      pairs.push_back({a.t_ns[ia], difference, a.v_mps[ia], ia, ib});
      sum_covariance_a += a.cov_m2ps2[ia];
      sum_covariance_b += b.cov_m2ps2[ib];
    }
    ++ia;
    ++ib;
  }
  const int n = static_cast<int>(pairs.size());
  if (n < options.min_samples || pairs.back().t_ns <= pairs.front().t_ns) return std::nullopt;
  const double samples = static_cast<double>(n);
  const core::Time span_ns = pairs.back().t_ns - pairs.front().t_ns;
  const double grid_s = core::TimeToSeconds(span_ns) / (samples - 1.0);

  const Eigen::Matrix3d per_sample = sum_covariance_a / samples + sum_covariance_b / samples;

  // b̂ = Σ_k A_k d_k: weighted least squares of d_k = b + δ × v_k, with a prior of
  // rotation_prior_std_rad on δ, or the mean (A_k = I / N). The weight is the samples'
  // typical information: a direction the pair does not observe neither moves δ nor b.
  Eigen::Matrix3d typical = per_sample;
  typical.diagonal().array() += std::max(sample_floor_variance, 1e-12);
  const Eigen::Matrix3d W = typical.inverse();
  // Fixed-size throughout (6 unknowns); without the rotation its Jacobian is zero and its
  // block of H the identity, so δ̂ = 0 and b̂ is the mean.
  using Matrix36 = Eigen::Matrix<double, 3, 6>;
  using Matrix6 = Eigen::Matrix<double, 6, 6>;
  using Vector6 = Eigen::Matrix<double, 6, 1>;
  Matrix6 H = Matrix6::Zero();
  Vector6 g = Vector6::Zero();
  const auto jacobian = [&](const Pair& p) {
    Matrix36 J = Matrix36::Zero();
    J.leftCols<3>().setIdentity();
    if (options.estimate_rotation) {
      // δ × v = −[v]ₓ δ.
      const Eigen::Vector3d& v = p.v_a;
      J.rightCols<3>() << 0, v.z(), -v.y(), -v.z(), 0, v.x(), v.y(), -v.x(), 0;
    }
    return J;
  };
  // Σ_k (W J_k)ᵀ Σ_s,k (W J_k) per stream: with A_k = [H⁻¹]_b J_kᵀ W, Σ_k A_k Σ_s,k A_kᵀ
  // is [H⁻¹]_b M_s [H⁻¹]_bᵀ (below).
  Matrix6 M_a = Matrix6::Zero();
  Matrix6 M_b = Matrix6::Zero();
  for (const Pair& p : pairs) {
    const Matrix36 J = jacobian(p);
    const Matrix36 WJ = W * J;
    H.noalias() += J.transpose() * WJ;
    g.noalias() += WJ.transpose() * p.difference;
    M_a.noalias() += WJ.transpose() * a.cov_m2ps2[p.ia] * WJ;
    M_b.noalias() += WJ.transpose() * b.cov_m2ps2[p.ib] * WJ;
  }
  H.bottomRightCorner<3, 3>().diagonal().array() +=
      options.estimate_rotation
          ? 1.0 / (options.rotation_prior_std_rad * options.rotation_prior_std_rad)
          : 1.0;
  const Eigen::LDLT<Matrix6> solver(H);
  const Vector6 x = solver.solve(g);
  const Eigen::Matrix<double, 3, 6> H_inverse_top = solver.solve(Matrix6::Identity()).topRows<3>();
  const auto weights = [&](const Pair& p) -> Eigen::Matrix3d {
    return H_inverse_top * jacobian(p).transpose() * W;
  };

  // Each stream's share of Cov(b̂). White errors, counted once per correlation time:
  // Σ_k A_k Σ_k A_kᵀ scaled by N / N_eff. Differentiated positions: Σ_k A_k ė(t_k) sums
  // by parts to A_N e(t_N)/Δt − A_1 e(t_1)/Δt and interior terms of order (sensor period /
  // span) smaller, left out; for the plain mean that is 2 P / span².
  const auto share = [&](const MeanNoise& noise, const Matrix6& M) {
    if (noise.position_covariance_m2) {
      const Eigen::Matrix3d first = weights(pairs.front()) / grid_s;
      const Eigen::Matrix3d last = weights(pairs.back()) / grid_s;
      return Eigen::Matrix3d(first * *noise.position_covariance_m2 * first.transpose() +
                             last * *noise.position_covariance_m2 * last.transpose());
    }
    const double independent = std::clamp(
        static_cast<double>(span_ns) / static_cast<double>(noise.correlation_time_ns) + 1.0, 1.0,
        samples);
    return Eigen::Matrix3d(H_inverse_top * M * H_inverse_top.transpose() * samples / independent);
  };

  MeanDifference result;
  result.samples = n;
  result.mean_mps = x.head<3>();
  if (options.estimate_rotation) result.rotation_rad = x.tail<3>();
  result.covariance_m2ps2 = share(options.a, M_a) + share(options.b, M_b) +
                            Eigen::Matrix3d::Identity() *
                                (options.floor_std_mps * options.floor_std_mps);
  // The directions the pair observes: those of the per-sample covariance within the bound.
  Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> eigen;
  eigen.computeDirect(0.5 * (per_sample + per_sample.transpose()));
  const double max_variance = options.unobserved_std_mps * options.unobserved_std_mps;
  Eigen::Matrix<double, 3, Eigen::Dynamic> observed(3, 0);
  for (int d = 0; d < 3; ++d) {
    const double variance = eigen.eigenvalues()[d];
    if (!(variance <= max_variance)) continue;
    observed.conservativeResize(Eigen::NoChange, observed.cols() + 1);
    observed.col(observed.cols() - 1) = eigen.eigenvectors().col(d);
  }
  result.dof = static_cast<int>(observed.cols());
  if (result.dof == 0) return std::nullopt;
  const Eigen::VectorXd d = observed.transpose() * result.mean_mps;
  const Eigen::MatrixXd S = observed.transpose() * result.covariance_m2ps2 * observed;
  result.chi2 = d.dot(S.ldlt().solve(d));
  return result;
}

double ChiSquareUpperQuantile(int dof, double upper_tail) {
  // P(χ²(k) > x): k = 1 erfc(√(x/2)); k = 2 e^(−x/2); k = 3 erfc(√(x/2)) + √(2x/π) e^(−x/2).
  const auto tail = [dof](double x) {
    const double root = std::sqrt(0.5 * x);
    switch (dof) {
      case 1: return std::erfc(root);
      case 2: return std::exp(-0.5 * x);
      default: return std::erfc(root) + std::sqrt(2.0 * x / M_PI) * std::exp(-0.5 * x);
    }
  };
  if (dof < 1 || dof > 3 || !(upper_tail > 0.0 && upper_tail < 1.0)) return kNaN;
  double lo = 0.0;
  double hi = 1.0;
  while (tail(hi) > upper_tail) hi *= 2.0;
  for (int i = 0; i < 200 && hi - lo > 1e-12 * hi; ++i) {
    const double mid = 0.5 * (lo + hi);
    (tail(mid) > upper_tail ? lo : hi) = mid;
  }
  return 0.5 * (lo + hi);
}

}  // namespace tofu::estimator
