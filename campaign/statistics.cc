#include "campaign/statistics.h"

#include <algorithm>
#include <cmath>
#include <functional>
#include <numeric>
#include <random>
#include <stdexcept>

#include <boost/math/distributions/binomial.hpp>
#include <boost/math/distributions/hypergeometric.hpp>

namespace tofu::campaign {
namespace {

// Mid-ranks (1-based, ties share their mean rank) of `values`, doubled so that they are
// whole numbers: the exact null distributions below are counted over integer sums.
std::vector<int> DoubledMidRanks(const std::vector<double>& values) {
  std::vector<std::size_t> order(values.size());
  std::iota(order.begin(), order.end(), 0);
  std::stable_sort(order.begin(), order.end(),
                   [&](std::size_t a, std::size_t b) { return values[a] < values[b]; });
  std::vector<int> ranks(values.size());
  for (std::size_t i = 0; i < order.size();) {
    std::size_t j = i;
    while (j + 1 < order.size() && values[order[j + 1]] == values[order[i]]) ++j;
    // Ranks i+1 .. j+1 share their mean (i + j + 2) / 2; doubled: i + j + 2.
    for (std::size_t k = i; k <= j; ++k) ranks[order[k]] = static_cast<int>(i + j + 2);
    i = j + 1;
  }
  return ranks;
}

// P[S >= observed] or P[S <= observed] of a distribution given as probabilities by sum.
double Tail(const std::vector<double>& probability, int observed, Alternative alternative) {
  double p = 0.0;
  if (alternative == Alternative::kGreater) {
    for (std::size_t s = std::max(observed, 0); s < probability.size(); ++s) p += probability[s];
  } else {
    for (int s = 0; s <= observed && s < static_cast<int>(probability.size()); ++s) {
      p += probability[s];
    }
  }
  return std::min(1.0, p);
}

// Linear interpolation between order statistics (numpy's default quantile) of sorted data.
double SortedQuantile(const std::vector<double>& sorted, double q) {
  const double position = q * static_cast<double>(sorted.size() - 1);
  const auto below = static_cast<std::size_t>(std::floor(position));
  const std::size_t above = std::min(below + 1, sorted.size() - 1);
  const double fraction = position - static_cast<double>(below);
  return sorted[below] + fraction * (sorted[above] - sorted[below]);
}

// The median of a resample of `values` drawn with `engine` into `buffer`.
double ResampledMedian(const std::vector<double>& values, std::mt19937_64& engine,
                       std::vector<double>& buffer) {
  buffer.resize(values.size());
  // engine() % n: a bias of n / 2^64, nothing next to the bootstrap's own error, and the
  // same draw on every standard library (std::uniform_int_distribution is not).
  for (double& b : buffer) b = values[engine() % values.size()];
  const std::size_t middle = buffer.size() / 2;
  std::nth_element(buffer.begin(), buffer.begin() + middle, buffer.end());
  double m = buffer[middle];
  if (buffer.size() % 2 == 0) {
    m = 0.5 * (m + *std::max_element(buffer.begin(), buffer.begin() + middle));
  }
  return m;
}

Interval PercentileInterval(std::vector<double> medians, double level) {
  std::sort(medians.begin(), medians.end());
  const double tail = 0.5 * (1.0 - level);
  return {SortedQuantile(medians, tail), SortedQuantile(medians, 1.0 - tail)};
}

void RequireBootstrapArguments(double level, int resamples) {
  if (!(level > 0.0 && level < 1.0)) throw std::invalid_argument("bootstrap: level not in (0, 1)");
  if (resamples < 1) throw std::invalid_argument("bootstrap: resamples < 1");
}

}  // namespace

double Median(std::vector<double> values) {
  if (values.empty()) throw std::invalid_argument("Median of no values");
  const std::size_t middle = values.size() / 2;
  std::nth_element(values.begin(), values.begin() + middle, values.end());
  double m = values[middle];
  if (values.size() % 2 == 0) {
    m = 0.5 * (m + *std::max_element(values.begin(), values.begin() + middle));
  }
  return m;
}

Interval BootstrapMedianInterval(const std::vector<double>& values, double level, int resamples,
                                 uint64_t seed) {
  if (values.empty()) throw std::invalid_argument("bootstrap of no values");
  RequireBootstrapArguments(level, resamples);
  // Every resample of equal values has their median: the interval without resampling (a
  // paired cell of an unchanged method, the common case of a comparison in CI).
  if (std::adjacent_find(values.begin(), values.end(), std::not_equal_to<>()) == values.end()) {
    return {values.front(), values.front()};
  }
  std::mt19937_64 engine(seed);
  std::vector<double> medians(resamples);
  std::vector<double> buffer;
  for (double& m : medians) m = ResampledMedian(values, engine, buffer);
  return PercentileInterval(std::move(medians), level);
}

Interval BootstrapMedianDifferenceInterval(const std::vector<double>& x,
                                           const std::vector<double>& y, double level,
                                           int resamples, uint64_t seed) {
  if (x.empty() || y.empty()) throw std::invalid_argument("bootstrap of no values");
  RequireBootstrapArguments(level, resamples);
  const auto constant = [](const std::vector<double>& v) {
    return std::adjacent_find(v.begin(), v.end(), std::not_equal_to<>()) == v.end();
  };
  if (constant(x) && constant(y)) return {y.front() - x.front(), y.front() - x.front()};
  std::mt19937_64 engine(seed);
  std::vector<double> differences(resamples);
  std::vector<double> buffer;
  for (double& d : differences) {
    const double mx = ResampledMedian(x, engine, buffer);
    d = ResampledMedian(y, engine, buffer) - mx;
  }
  return PercentileInterval(std::move(differences), level);
}

double WilcoxonSignedRankP(const std::vector<double>& differences, Alternative alternative) {
  std::vector<double> magnitudes;
  std::vector<bool> positive;
  for (const double d : differences) {
    if (d == 0.0) continue;
    magnitudes.push_back(std::abs(d));
    positive.push_back(d > 0.0);
  }
  if (magnitudes.empty()) return 1.0;
  const std::vector<int> ranks = DoubledMidRanks(magnitudes);
  int observed = 0;
  int total = 0;
  for (std::size_t i = 0; i < ranks.size(); ++i) {
    total += ranks[i];
    if (positive[i]) observed += ranks[i];
  }
  // Under the null each sign is + or - with probability 1/2, independently: the
  // distribution of the doubled T+ by convolution, one rank at a time.
  std::vector<double> probability(total + 1, 0.0);
  probability[0] = 1.0;
  int reach = 0;
  for (const int r : ranks) {
    for (int s = reach; s >= 0; --s) {
      const double half = 0.5 * probability[s];
      probability[s] = half;
      probability[s + r] += half;
    }
    reach += r;
  }
  return Tail(probability, observed, alternative);
}

double MannWhitneyP(const std::vector<double>& x, const std::vector<double>& y,
                    Alternative alternative) {
  if (x.empty() || y.empty()) return 1.0;
  std::vector<double> pooled = x;
  pooled.insert(pooled.end(), y.begin(), y.end());
  const std::vector<int> ranks = DoubledMidRanks(pooled);
  int observed = 0;
  int total = 0;
  for (std::size_t i = 0; i < ranks.size(); ++i) {
    total += ranks[i];
    if (i >= x.size()) observed += ranks[i];
  }
  // count[k][s]: subsets of k of the pooled ranks whose doubled sum is s; under the null
  // every subset of y.size() is equally likely to be y's.
  const std::size_t ny = y.size();
  std::vector<std::vector<double>> count(ny + 1, std::vector<double>(total + 1, 0.0));
  count[0][0] = 1.0;
  int reach = 0;
  for (std::size_t i = 0; i < ranks.size(); ++i) {
    const int r = ranks[i];
    for (std::size_t k = std::min(i + 1, ny); k >= 1; --k) {
      for (int s = reach; s >= 0; --s) {
        if (count[k - 1][s] != 0.0) count[k][s + r] += count[k - 1][s];
      }
    }
    reach += r;
  }
  std::vector<double>& sums = count[ny];
  const double subsets = std::accumulate(sums.begin(), sums.end(), 0.0);
  for (double& c : sums) c /= subsets;
  return Tail(sums, observed, alternative);
}

Interval ClopperPearsonInterval(int successes, int trials, double level) {
  if (trials < 1 || successes < 0 || successes > trials || !(level > 0.0 && level < 1.0)) {
    throw std::invalid_argument("ClopperPearsonInterval: needs 0 <= successes <= trials, trials >= 1, 0 < level < 1");
  }
  using boost::math::binomial_distribution;
  const double alpha = (1.0 - level) / 2.0;
  const auto n = static_cast<double>(trials);
  const auto k = static_cast<double>(successes);
  Interval interval;
  interval.low = successes == 0 ? 0.0
                                : binomial_distribution<double>::find_lower_bound_on_p(
                                      n, k, alpha, binomial_distribution<double>::clopper_pearson_exact_interval);
  interval.high = successes == trials ? 1.0
                                      : binomial_distribution<double>::find_upper_bound_on_p(
                                            n, k, alpha, binomial_distribution<double>::clopper_pearson_exact_interval);
  return interval;
}

double McNemarExactP(int base_only, int new_only, Alternative alternative) {
  if (base_only < 0 || new_only < 0) throw std::invalid_argument("McNemar: negative count");
  const int n = base_only + new_only;
  if (n == 0) return 1.0;
  const boost::math::binomial_distribution<double> discordant(n, 0.5);
  if (alternative == Alternative::kGreater) {
    return new_only == 0 ? 1.0 : boost::math::cdf(boost::math::complement(discordant, new_only - 1));
  }
  return boost::math::cdf(discordant, new_only);
}

double FisherExactP(int base_yes, int base_n, int new_yes, int new_n, Alternative alternative) {
  if (base_yes < 0 || new_yes < 0 || base_yes > base_n || new_yes > new_n) {
    throw std::invalid_argument("Fisher: counts outside 0..n");
  }
  const auto yes = static_cast<unsigned>(base_yes + new_yes);
  const auto population = static_cast<unsigned>(base_n + new_n);
  const auto drawn = static_cast<unsigned>(new_n);
  if (population == 0) return 1.0;
  // new_yes ~ the yes among new_n drawn from the pooled population, given the margins.
  const boost::math::hypergeometric_distribution<double> hypergeometric(yes, drawn, population);
  const unsigned lowest = drawn + yes > population ? drawn + yes - population : 0u;
  const unsigned highest = std::min(yes, drawn);
  double p = 0.0;
  for (unsigned k = lowest; k <= highest; ++k) {
    const bool in_tail = alternative == Alternative::kGreater ? k >= static_cast<unsigned>(new_yes)
                                                              : k <= static_cast<unsigned>(new_yes);
    if (in_tail) p += boost::math::pdf(hypergeometric, k);
  }
  return std::min(1.0, p);
}

std::vector<double> BenjaminiHochberg(const std::vector<double>& p) {
  const std::size_t m = p.size();
  std::vector<std::size_t> order(m);
  std::iota(order.begin(), order.end(), 0);
  std::stable_sort(order.begin(), order.end(), [&](std::size_t a, std::size_t b) { return p[a] < p[b]; });
  std::vector<double> adjusted(m, 1.0);
  double running = 1.0;
  for (std::size_t rank = m; rank >= 1; --rank) {
    const std::size_t i = order[rank - 1];
    running = std::min(running, p[i] * static_cast<double>(m) / static_cast<double>(rank));
    adjusted[i] = std::min(1.0, running);
  }
  return adjusted;
}

std::vector<double> BenjaminiYekutieli(const std::vector<double>& p) {
  double harmonic = 0.0;
  for (std::size_t i = 1; i <= p.size(); ++i) harmonic += 1.0 / static_cast<double>(i);
  std::vector<double> scaled = p;
  for (double& v : scaled) v = std::min(1.0, v * harmonic);
  return BenjaminiHochberg(scaled);
}

}  // namespace tofu::campaign
