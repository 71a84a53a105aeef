#pragma once
// The statistics of `tofu compare`: exact rank and count tests, a bootstrap interval of a
// median, and false-discovery control over a grid of tests. Distribution functions come
// from Boost.Math; the rank tests' exact null distributions are counted here (a dynamic
// programme over the ranks, ties included), since no packaged C++ library has them.
// tests/statistics_scipy_check.py holds every function to scipy.stats on the same inputs.

#include <cstdint>
#include <vector>

namespace tofu::campaign {

/// Which tail a one-sided test looks at: the statistic larger (kGreater) or smaller
/// (kLess) than the null hypothesis says.
enum class Alternative { kGreater, kLess };

/// The median (the mean of the middle two for an even count). Requires a non-empty input.
double Median(std::vector<double> values);

/// A confidence interval [low, high].
struct Interval {
  double low = 0.0;
  double high = 0.0;
};

/// Percentile bootstrap interval of the median of `values` at `level` (0.95: the 2.5 % and
/// 97.5 % quantiles of `resamples` medians of resamples drawn with replacement). The
/// generator is seeded with `seed`: the same inputs give the same interval on every
/// machine. Requires a non-empty input, 0 < level < 1, resamples >= 1.
Interval BootstrapMedianInterval(const std::vector<double>& values, double level, int resamples,
                                 uint64_t seed);

/// Clopper-Pearson's exact interval of a binomial proportion at `level` from `successes`
/// of `trials` (Boost.Math's beta quantiles): a failure rate over confirmation seeds.
/// Requires 0 <= successes <= trials, trials >= 1, 0 < level < 1.
Interval ClopperPearsonInterval(int successes, int trials, double level);

/// The same for median(y) - median(x) of two independent samples, each resampled on its
/// own.
Interval BootstrapMedianDifferenceInterval(const std::vector<double>& x,
                                           const std::vector<double>& y, double level,
                                           int resamples, uint64_t seed);

/// Wilcoxon's signed-rank test of "the differences are symmetric about 0" against a shift
/// to `alternative`: the p-value of T+, the sum of the ranks of |d| over the positive d.
/// Zero differences are dropped (Wilcoxon's own treatment), tied |d| share their mid-rank,
/// and the null distribution of T+ is counted exactly (all 2^n sign patterns, by a dynamic
/// programme over the doubled ranks), ties included. 1 when no difference is non-zero.
double WilcoxonSignedRankP(const std::vector<double>& differences, Alternative alternative);

/// The Mann-Whitney (Wilcoxon rank-sum) test of "x and y come from one distribution"
/// against y shifted to `alternative` of x: the p-value of the rank sum of y in the pooled
/// sample, mid-ranks for ties, its null distribution counted exactly over all
/// C(n_x + n_y, n_y) assignments (a dynamic programme). 1 when either sample is empty.
double MannWhitneyP(const std::vector<double>& x, const std::vector<double>& y,
                    Alternative alternative);

/// McNemar's exact test for paired yes/no outcomes: of the discordant pairs, `base_only`
/// had the event in the base only and `new_only` in the new only. kGreater: the p-value
/// of "the new has the event more often" (P[X >= new_only], X ~ Binomial(b + c, 1/2)).
/// 1 without discordant pairs.
double McNemarExactP(int base_only, int new_only, Alternative alternative);

/// Fisher's exact test for two independent yes/no samples: `base_yes` of `base_n` and
/// `new_yes` of `new_n`. kGreater: the p-value of "the new has the event more often"
/// (the hypergeometric upper tail of new_yes given the margins).
double FisherExactP(int base_yes, int base_n, int new_yes, int new_n, Alternative alternative);

/// Benjamini-Hochberg adjusted p-values (step-up; each min(1, ...) and monotone), in the
/// input's order: a test is a discovery at false-discovery rate q when its adjusted
/// p-value is <= q. Valid for independent or positively dependent tests (PRDS).
std::vector<double> BenjaminiHochberg(const std::vector<double>& p);

/// Benjamini-Yekutieli: Benjamini-Hochberg times sum_{i<=m} 1/i, valid under any
/// dependence between the tests.
std::vector<double> BenjaminiYekutieli(const std::vector<double>& p);

}  // namespace tofu::campaign
