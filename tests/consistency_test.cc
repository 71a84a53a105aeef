// The consistency metrics of Lanegger et al. (eq. 2-5), their window selection and the
// consistency matrix. Hand-computed values and an independent brute-force integral; the
// options' limits.

#include <algorithm>
#include <cmath>
#include <cstddef>
#include <limits>
#include <optional>
#include <random>
#include <stdexcept>
#include <string>
#include <utility>
#include <vector>

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <gtest/gtest.h>

#include "core/random.h"
#include "core/time.h"
#include "estimator/consistency.h"
#include "estimator/consistency_matrix.h"
#include "estimator/velocity.h"

namespace tofu::estimator {
namespace {

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

std::vector<double> NormalSample(std::size_t n, double mean, double sd, const char* name) {
  core::RandomStream random(1, name);
  std::vector<double> x(n);
  for (double& value : x) value = mean + sd * random.Normal();
  return x;
}

// Reference for eq. (5), independent of the merge: both ECDFs evaluated by counting at
// the midpoint of every interval between consecutive distinct merged values (where both
// are constant), times the interval's length. O(K n).
double BruteForceCramerVonMises(const std::vector<double>& p, const std::vector<double>& q) {
  std::vector<double> knots = p;
  knots.insert(knots.end(), q.begin(), q.end());
  std::sort(knots.begin(), knots.end());
  knots.erase(std::unique(knots.begin(), knots.end()), knots.end());
  auto ecdf = [](const std::vector<double>& sample, double x) {
    double count = 0.0;
    for (const double value : sample) count += value <= x ? 1.0 : 0.0;
    return count / static_cast<double>(sample.size());
  };
  double integral = 0.0;
  for (std::size_t k = 0; k + 1 < knots.size(); ++k) {
    const double mid = 0.5 * (knots[k] + knots[k + 1]);
    const double diff = ecdf(p, mid) - ecdf(q, mid);
    integral += diff * diff * (knots[k + 1] - knots[k]);
  }
  return std::sqrt(2.0 * integral);
}

// ---- Cramér-von Mises ----

TEST(CramerVonMises, IdenticalSamplesGiveZero) {
  const std::vector<double> p = NormalSample(50, 0.3, 1.0, "p");
  EXPECT_EQ(CramerVonMisesDistance(p, p), 0.0);
}

TEST(CramerVonMises, TwoPointMassesGiveSqrtOfTwiceTheirDistance) {
  // F_P − F_Q = ±1 on [a, b): D = (2 |a − b|)^½, whatever the multiplicities.
  const std::vector<double> a = {0.7};
  const std::vector<double> b = {-1.3};
  EXPECT_NEAR(CramerVonMisesDistance(a, b), std::sqrt(2.0 * 2.0), 1e-15);
  const std::vector<double> a3 = {0.7, 0.7, 0.7};
  const std::vector<double> b2 = {2.2, 2.2};
  EXPECT_NEAR(CramerVonMisesDistance(a3, b2), std::sqrt(2.0 * 1.5), 1e-15);
}

TEST(CramerVonMises, HandComputedTwoAgainstOne) {
  // P = {0, 2}, Q = {1}: F_P − F_Q = 1/2 on [0, 1), −1/2 on [1, 2): ∫ = 1/2, D = 1.
  EXPECT_NEAR(CramerVonMisesDistance(std::vector<double>{0.0, 2.0}, std::vector<double>{1.0}),
              1.0, 1e-15);
}

TEST(CramerVonMises, IsSymmetric) {
  const std::vector<double> p = NormalSample(40, 0.0, 1.0, "p");
  const std::vector<double> q = NormalSample(70, 0.5, 2.0, "q");
  EXPECT_DOUBLE_EQ(CramerVonMisesDistance(p, q), CramerVonMisesDistance(q, p));
}

TEST(CramerVonMises, IndependentOfSampleOrder) {
  std::vector<double> p = NormalSample(40, 0.0, 1.0, "p");
  const std::vector<double> q = NormalSample(70, 0.5, 2.0, "q");
  const double d = CramerVonMisesDistance(p, q);
  std::mt19937_64 engine(5);
  std::shuffle(p.begin(), p.end(), engine);
  EXPECT_EQ(CramerVonMisesDistance(p, q), d);
  std::reverse(p.begin(), p.end());
  EXPECT_EQ(CramerVonMisesDistance(p, q), d);
}

TEST(CramerVonMises, CommonShiftLeavesItUnchanged) {
  std::vector<double> p = NormalSample(40, 0.0, 1.0, "p");
  std::vector<double> q = NormalSample(70, 0.5, 2.0, "q");
  const double d = CramerVonMisesDistance(p, q);
  for (double& value : p) value += 3.25;
  for (double& value : q) value += 3.25;
  EXPECT_NEAR(CramerVonMisesDistance(p, q), d, 1e-12 * d);
}

TEST(CramerVonMises, ScalesWithTheSquareRootOfTheUnit) {
  std::vector<double> p = NormalSample(40, 0.0, 1.0, "p");
  std::vector<double> q = NormalSample(70, 0.5, 2.0, "q");
  const double d = CramerVonMisesDistance(p, q);
  for (double& value : p) value *= 4.0;
  for (double& value : q) value *= 4.0;
  EXPECT_NEAR(CramerVonMisesDistance(p, q), 2.0 * d, 1e-12 * d);
}

TEST(CramerVonMises, EqualsBruteForceIntegralWithUnequalSizesAndTies) {
  core::RandomStream random(3, "cm_brute_force");
  for (int trial = 0; trial < 20; ++trial) {
    const auto n = static_cast<std::size_t>(5 + trial * 7);
    const auto m = static_cast<std::size_t>(3 + trial * 11);
    std::vector<double> p(n);
    std::vector<double> q(m);
    // Values on a 0.1 grid so that ties within and across the samples are common.
    for (double& value : p) value = std::round(10.0 * random.Normal()) / 10.0;
    for (double& value : q) value = std::round(10.0 * (0.3 + 1.5 * random.Normal())) / 10.0;
    const double reference = BruteForceCramerVonMises(p, q);
    ASSERT_GT(reference, 0.0);
    EXPECT_NEAR(CramerVonMisesDistance(p, q), reference, 1e-9 * reference)
        << "n = " << n << ", m = " << m;
  }
}

TEST(CramerVonMises, EmptySampleIsNaNAndNonFiniteValuesAreIgnored) {
  EXPECT_TRUE(std::isnan(CramerVonMisesDistance(std::vector<double>{}, std::vector<double>{1.0})));
  EXPECT_NEAR(CramerVonMisesDistance(std::vector<double>{0.0, kNaN}, std::vector<double>{2.0}),
              2.0, 1e-15);
}

TEST(CramerVonMises, SortedKernelMatchesAndTerminatesOnBadInput) {
  std::vector<double> p = NormalSample(40, 0.0, 1.0, "p");
  std::vector<double> q = NormalSample(70, 0.5, 2.0, "q");
  const double d = CramerVonMisesDistance(p, q);
  std::sort(p.begin(), p.end());
  std::sort(q.begin(), q.end());
  EXPECT_EQ(CramerVonMisesDistanceSorted(p, q), d);
  // Broken preconditions (NaN, unsorted) give a meaningless value but never hang.
  const std::vector<double> bad = {kNaN, 3.0, -1.0, kNaN};
  const std::vector<double> good = {0.0, 1.0};
  (void)CramerVonMisesDistanceSorted(bad, good);
  (void)CramerVonMisesDistanceSorted(good, bad);
  EXPECT_TRUE(std::isnan(CramerVonMisesDistanceSorted(good, std::vector<double>{})));
}

// ---- Kullback-Leibler ----

TEST(KlDivergence, IdenticalSamplesGiveZero) {
  const std::vector<double> p = NormalSample(100, 0.0, 1.0, "p");
  EXPECT_NEAR(KlDivergence(p, p), 0.0, 1e-12);
}

TEST(KlDivergence, GrowsWithTheShiftOfOneSample) {
  const std::vector<double> p = NormalSample(200, 0.0, 1.0, "p");
  double previous = 0.0;
  for (const double shift : {0.1, 0.3, 1.0, 3.0}) {
    std::vector<double> q = p;
    for (double& value : q) value += shift;
    const double kl = KlDivergence(p, q);
    EXPECT_GT(kl, previous) << "shift " << shift;
    EXPECT_TRUE(std::isfinite(kl));
    previous = kl;
  }
  // Small shifts: close to the Gaussian value shift² / (2 (sd² + h²)), h Silverman's.
  std::vector<double> q = p;
  for (double& value : q) value += 0.1;
  EXPECT_NEAR(KlDivergence(p, q), 0.01 / (2.0 * 1.1), 0.002);
}

TEST(KlDivergence, BandwidthScaleChangesIt) {
  const std::vector<double> p = NormalSample(200, 0.0, 1.0, "p");
  std::vector<double> q = p;
  for (double& value : q) value += 0.5;
  const double narrow = KlDivergence(p, q, 0.5);
  const double nominal = KlDivergence(p, q, 1.0);
  const double wide = KlDivergence(p, q, 2.0);
  EXPECT_GT(narrow, nominal * 1.05);
  EXPECT_GT(nominal, wide * 1.05);
}

TEST(KlDivergence, StaysFiniteForANearConstantSampleAgainstAWideOne) {
  // A hovering axis (spread 1e-6) against a noisy sensor (spread 0.1): the narrow KDE must
  // not vanish between the grid points of the wide one's support.
  std::vector<double> narrow, wide;
  for (int i = 0; i < 200; ++i) {
    narrow.push_back(1e-6 * std::sin(0.37 * i));
    wide.push_back(0.1 * std::sin(1.3 * i + 0.2) + 0.05 * std::cos(0.7 * i));
  }
  const double a = KlDivergence(narrow, wide);
  const double b = KlDivergence(wide, narrow);
  EXPECT_TRUE(std::isfinite(a)) << a;
  EXPECT_TRUE(std::isfinite(b)) << b;
  EXPECT_GT(a, 0.5);
  EXPECT_GT(b, 0.5);
}

TEST(KlDivergence, StaysFiniteForDisjointSamples) {
  const std::vector<double> p = NormalSample(50, 0.0, 1.0, "p");
  const std::vector<double> q = NormalSample(50, 100.0, 1.0, "q");
  const double kl = KlDivergence(p, q);
  EXPECT_TRUE(std::isfinite(kl));
  EXPECT_GT(kl, 10.0);  // saturated at the density floor, log(1e10) ~ 23
}

// ---- MAE and PCC ----

TEST(MeanAbsoluteError, HandComputed) {
  const std::vector<double> x = {1.0, 2.0, 3.0, 4.0};
  const std::vector<double> y = {1.5, 1.0, 3.0, 6.0};
  EXPECT_DOUBLE_EQ(MeanAbsoluteError(x, y), (0.5 + 1.0 + 0.0 + 2.0) / 4.0);
}

TEST(PearsonCorrelation, HandComputed) {
  const std::vector<double> x = {1.0, 2.0, 3.0, 4.0};
  const std::vector<double> y = {2.0, 4.0, 5.0, 9.0};
  // dx = (−1.5, −0.5, 0.5, 1.5), dy = (−3, −1, 0, 4): sxy = 11, sxx = 5, syy = 26.
  EXPECT_NEAR(PearsonCorrelation(x, y), 11.0 / std::sqrt(5.0 * 26.0), 1e-15);
  const std::vector<double> line = {3.0, 1.0, -1.0, -3.0};
  EXPECT_NEAR(PearsonCorrelation(x, line), -1.0, 1e-15);
  const std::vector<double> constant = {2.0, 2.0, 2.0, 2.0};
  EXPECT_EQ(PearsonCorrelation(x, constant), 0.0);
}

// ---- WindowConsistency ----

// Samples every 100 ms from 0 to 2 s; value k on x, −2k on y, k² on z.
VelocitySeries Ramp(double scale, double offset) {
  VelocitySeries s;
  for (int k = 0; k <= 20; ++k) {
    s.t_ns.push_back(k * 100'000'000);
    const double x = scale * k + offset;
    s.v_mps.emplace_back(x, -2.0 * x, x * x);
  }
  return s;
}

std::vector<double> Axis(const VelocitySeries& s, int axis, int first, int last) {
  std::vector<double> out;
  for (int k = first; k <= last; ++k) out.push_back(s.v_mps[static_cast<std::size_t>(k)][axis]);
  return out;
}

TEST(WindowConsistency, SelectsExactlyTheSamplesInTheHalfOpenWindow) {
  const VelocitySeries a = Ramp(1.0, 0.0);
  const VelocitySeries b = Ramp(1.3, 0.4);
  ConsistencyOptions options;
  options.window_ns = 500'000'000;
  // t_eval = 1.0 s lands on sample 10; (0.5 s, 1.0 s] holds samples 6..10.
  const core::Time t_eval = 1'000'000'000;
  double expected_cm = 0.0;
  for (int axis = 0; axis < 3; ++axis) {
    expected_cm += CramerVonMisesDistance(Axis(a, axis, 6, 10), Axis(b, axis, 6, 10));
  }
  const auto cm = WindowConsistency(a, b, t_eval, ConsistencyMetric::kCm, options);
  ASSERT_TRUE(cm.has_value());
  EXPECT_NEAR(*cm, expected_cm, 1e-12 * expected_cm);
  // Samples 5 or 11 in the window would change it.
  double with_five = 0.0;
  for (int axis = 0; axis < 3; ++axis) {
    with_five += CramerVonMisesDistance(Axis(a, axis, 5, 10), Axis(b, axis, 5, 10));
  }
  EXPECT_GT(std::abs(with_five - expected_cm), 1e-3);
  // MAE on equal stamps: per axis the mean |a − b| of samples 6..10.
  double expected_mae = 0.0;
  for (int axis = 0; axis < 3; ++axis) {
    expected_mae += MeanAbsoluteError(Axis(a, axis, 6, 10), Axis(b, axis, 6, 10));
  }
  const auto mae = WindowConsistency(a, b, t_eval, ConsistencyMetric::kMae, options);
  ASSERT_TRUE(mae.has_value());
  EXPECT_NEAR(*mae, expected_mae, 1e-12 * expected_mae);
  // One nanosecond earlier, sample 10 leaves and sample 5 enters.
  double shifted = 0.0;
  for (int axis = 0; axis < 3; ++axis) {
    shifted += CramerVonMisesDistance(Axis(a, axis, 5, 9), Axis(b, axis, 5, 9));
  }
  const auto cm_earlier = WindowConsistency(a, b, t_eval - 1, ConsistencyMetric::kCm, options);
  ASSERT_TRUE(cm_earlier.has_value());
  EXPECT_NEAR(*cm_earlier, shifted, 1e-12 * shifted);
}

TEST(WindowConsistency, MaeAndPccPairWithLinearlyInterpolatedB) {
  // b: v = t (seconds) at 0.05, 0.15, ...; a: v = t + 0.2 at 0.1, 0.2, ...: every a
  // sample inside b's span pairs with b(t) = t exactly, so MAE = 0.2 per axis.
  VelocitySeries a;
  VelocitySeries b;
  for (int k = 0; k < 20; ++k) {
    const double tb = 0.05 + 0.1 * k;
    b.t_ns.push_back(core::SecondsToTime(tb));
    b.v_mps.emplace_back(tb, 2.0 * tb, -tb);
    const double ta = 0.1 * (k + 1);
    a.t_ns.push_back(core::SecondsToTime(ta));
    a.v_mps.emplace_back(ta + 0.2, 2.0 * ta + 0.2, -ta + 0.2);
  }
  ConsistencyOptions options;
  options.window_ns = 1'000'000'000;
  const auto mae = WindowConsistency(a, b, core::SecondsToTime(1.5), ConsistencyMetric::kMae,
                                     options);
  ASSERT_TRUE(mae.has_value());
  EXPECT_NEAR(*mae, 3 * 0.2, 1e-9);
  const auto pcc = WindowConsistency(a, b, core::SecondsToTime(1.5), ConsistencyMetric::kPcc,
                                     options);
  ASSERT_TRUE(pcc.has_value());
  EXPECT_NEAR(*pcc, 3.0, 1e-9);
}

TEST(WindowConsistency, UnavailableWhenAStreamHasTooFewSamples) {
  const VelocitySeries a = Ramp(1.0, 0.0);
  VelocitySeries b = Ramp(1.0, 0.1);
  ConsistencyOptions options;
  options.window_ns = 300'000'000;
  options.min_samples = 3;
  // (0.7 s, 1.0 s] holds three samples of each.
  for (const ConsistencyMetric metric : {ConsistencyMetric::kMae, ConsistencyMetric::kPcc,
                                         ConsistencyMetric::kKl, ConsistencyMetric::kCm}) {
    EXPECT_TRUE(WindowConsistency(a, b, 1'000'000'000, metric, options).has_value());
    options.min_samples = 4;
    EXPECT_FALSE(WindowConsistency(a, b, 1'000'000'000, metric, options).has_value());
    options.min_samples = 3;
  }
  // Past the end of b's data: unavailable, not zero.
  EXPECT_FALSE(WindowConsistency(a, b, 3'000'000'000, ConsistencyMetric::kCm, options));
  // An empty stream.
  EXPECT_FALSE(WindowConsistency(a, VelocitySeries{}, 1'000'000'000, ConsistencyMetric::kCm,
                                 options));
  // Non-finite samples do not count.
  b.v_mps[9].y() = kNaN;
  EXPECT_FALSE(WindowConsistency(a, b, 1'000'000'000, ConsistencyMetric::kCm, options));
}

TEST(WindowConsistency, StandardisationMakesTheMetricScaleFree) {
  // A pair and a scaled (and offset) copy of the same pair, e.g. the same data in other
  // units: raw CM differs by √scale, standardised (pooled mean and sd) it is the same.
  const VelocitySeries a = Ramp(1.0, 0.0);
  const VelocitySeries b = Ramp(1.1, 0.3);
  VelocitySeries a_scaled = a;
  VelocitySeries b_scaled = b;
  for (auto& v : a_scaled.v_mps) v = 9.0 * v + Eigen::Vector3d(1.0, -2.0, 3.0);
  for (auto& v : b_scaled.v_mps) v = 9.0 * v + Eigen::Vector3d(1.0, -2.0, 3.0);
  ConsistencyOptions raw;
  ConsistencyOptions standardized;
  standardized.standardize = true;
  const core::Time t = 1'500'000'000;
  for (const ConsistencyMetric metric : {ConsistencyMetric::kMae, ConsistencyMetric::kKl,
                                         ConsistencyMetric::kCm}) {
    const double d_raw = *WindowConsistency(a, b, t, metric, raw);
    const double d_raw_scaled = *WindowConsistency(a_scaled, b_scaled, t, metric, raw);
    const double d_std = *WindowConsistency(a, b, t, metric, standardized);
    const double d_std_scaled = *WindowConsistency(a_scaled, b_scaled, t, metric, standardized);
    EXPECT_NEAR(d_std_scaled, d_std, 1e-9 * d_std) << MetricName(metric);
    if (metric != ConsistencyMetric::kKl) {  // KL is scale-free even raw
      EXPECT_GT(std::abs(d_raw_scaled - d_raw), 0.5 * d_raw) << MetricName(metric);
    }
  }
  // Standardised, a copy of a stream is consistent with it.
  EXPECT_NEAR(*WindowConsistency(a, a, t, ConsistencyMetric::kCm, standardized), 0.0, 1e-15);
}

// ---- ConsistencyMatrix ----

// Noise-free velocity of a smooth motion plus an optional offset.
Eigen::Vector3d Motion(core::Time t_ns) {
  const double t = core::TimeToSeconds(t_ns);
  return {std::sin(t), 0.5 * std::cos(1.3 * t), 0.2 * t};
}

TEST(ConsistencyMatrix, PairsAreOrderedAndIndexed) {
  const ConsistencyMatrix matrix({"a", "b", "c", "d"});
  ASSERT_EQ(matrix.Values().size(), 6u);
  int index = 0;
  for (int i = 0; i < 4; ++i) {
    for (int j = i + 1; j < 4; ++j) {
      EXPECT_EQ(ConsistencyMatrix::PairIndex(i, j, 4), index);
      EXPECT_EQ(matrix.Values()[static_cast<std::size_t>(index)].i, i);
      EXPECT_EQ(matrix.Values()[static_cast<std::size_t>(index)].j, j);
      ++index;
    }
  }
  EXPECT_EQ(matrix.StreamIndex("c"), 2);
  EXPECT_FALSE(matrix.StreamIndex("x").has_value());
}

TEST(ConsistencyMatrix, EmptyStreamIsUnavailable) {
  ConsistencyMatrix matrix({"vio", "lio", "gnss"});
  for (const auto& pair : matrix.Values()) EXPECT_FALSE(pair.value.has_value());
  for (core::Time t = 0; t <= 2'000'000'000; t += 10'000'000) {
    matrix.Add(0, t, Motion(t));
    matrix.Add(1, t + 3'000'000, Motion(t + 3'000'000));
  }
  matrix.Evaluate(2'000'000'000);
  ASSERT_TRUE(matrix.Value(0, 1).has_value());
  EXPECT_LT(*matrix.Value(1, 0), 0.05);
  EXPECT_FALSE(matrix.Value(0, 2).has_value());
  EXPECT_FALSE(matrix.Value(2, 1).has_value());
  EXPECT_FALSE(matrix.Value(1, 1).has_value());
  EXPECT_FALSE(matrix.Value(0, 7).has_value());
  // A stream whose samples all left the window is unavailable again.
  matrix.Evaluate(3'500'000'000);
  EXPECT_FALSE(matrix.Value(0, 1).has_value());
}

TEST(ConsistencyMatrix, RejectsAndCountsNanAndOutOfOrderSamples) {
  ConsistencyMatrix matrix({"a", "b"});
  ConsistencyMatrix clean({"a", "b"});
  for (core::Time t = 0; t <= 1'000'000'000; t += 20'000'000) {
    for (int s = 0; s < 2; ++s) {
      const Eigen::Vector3d v = Motion(t) + Eigen::Vector3d(0.1 * s, 0.0, 0.0);
      EXPECT_EQ(matrix.Add(s, t, v), AddResult::kAccepted);
      clean.Add(s, t, v);
    }
  }
  EXPECT_EQ(matrix.Add(0, 1'010'000'000, Eigen::Vector3d(kNaN, 0.0, 0.0)),
            AddResult::kRejectedNonFinite);
  EXPECT_EQ(matrix.Add(0, 1'020'000'000,
                       Eigen::Vector3d(0.0, std::numeric_limits<double>::infinity(), 0.0)),
            AddResult::kRejectedNonFinite);
  EXPECT_EQ(matrix.Add(1, 1'000'000'000, Eigen::Vector3d::Zero()),
            AddResult::kRejectedOutOfOrder);  // repeated stamp
  EXPECT_EQ(matrix.Add(1, 500'000'000, Eigen::Vector3d::Zero()),
            AddResult::kRejectedOutOfOrder);  // going back
  EXPECT_EQ(matrix.Add(2, 1'100'000'000, Eigen::Vector3d::Zero()),
            AddResult::kRejectedUnknownStream);
  EXPECT_EQ(matrix.Add(-1, 1'100'000'000, Eigen::Vector3d::Zero()),
            AddResult::kRejectedUnknownStream);
  EXPECT_EQ(matrix.Counters(0).rejected_non_finite, 2);
  EXPECT_EQ(matrix.Counters(0).rejected_out_of_order, 0);
  EXPECT_EQ(matrix.Counters(1).rejected_out_of_order, 2);
  EXPECT_EQ(matrix.Counters(1).rejected_non_finite, 0);
  EXPECT_EQ(matrix.Counters(0).accepted, 51);
  EXPECT_EQ(matrix.rejected_unknown_stream(), 2);
  EXPECT_EQ(matrix.StoredSamples(0), 51u);
  // Nothing rejected reached the value.
  const double value = *matrix.Evaluate(1'000'000'000)[0].value;
  EXPECT_TRUE(std::isfinite(value));
  EXPECT_EQ(value, *clean.Evaluate(1'000'000'000)[0].value);
}

TEST(ConsistencyMatrix, DropsOldSamplesSoMemoryStaysBounded) {
  ConsistencyMatrixOptions options;
  options.history_ns = 2'000'000'000;
  ConsistencyMatrix matrix({"fast", "slow"}, options);
  VelocitySeries fast;
  VelocitySeries slow;
  const core::Time period = 5'000'000;  // 200 Hz
  std::size_t most_stored = 0;
  for (core::Time t = 0; t <= 100'000'000'000; t += period) {
    matrix.Add(0, t, Motion(t));
    fast.t_ns.push_back(t);
    fast.v_mps.push_back(Motion(t));
    if (t % 50'000'000 == 0) {  // 20 Hz
      const Eigen::Vector3d v = Motion(t) + Eigen::Vector3d(0.05, 0.0, 0.0);
      matrix.Add(1, t, v);
      slow.t_ns.push_back(t);
      slow.v_mps.push_back(v);
    }
    if (t % 100'000'000 == 0) matrix.Evaluate(t);  // 10 Hz
    most_stored = std::max(most_stored, matrix.StoredSamples(0));
  }
  // At most ~2 histories of samples, never the 100 s that went through.
  EXPECT_LE(most_stored, static_cast<std::size_t>(2 * 2 * 200 + 2));
  EXPECT_EQ(matrix.Counters(0).dropped + static_cast<int64_t>(matrix.StoredSamples(0)),
            matrix.Counters(0).accepted);
  EXPECT_GT(matrix.Counters(0).dropped, 19'000);
  // The windowed value is the one on the full series.
  const core::Time t_end = 100'000'000'000;
  const auto expected = WindowConsistency(fast, slow, t_end, ConsistencyMetric::kCm);
  const auto value = matrix.Evaluate(t_end)[0].value;
  ASSERT_TRUE(expected.has_value());
  ASSERT_TRUE(value.has_value());
  EXPECT_NEAR(*value, *expected, 1e-12);
}

TEST(ConsistencyMatrix, HardCapBoundsAStreamWithAbsurdRate) {
  ConsistencyMatrixOptions options;
  options.max_samples_per_stream = 1000;
  ConsistencyMatrix matrix({"a", "b"}, options);
  for (core::Time t = 0; t < 1'000'000'000; t += 100'000) matrix.Add(0, t, Motion(t));  // 10 kHz
  EXPECT_LE(matrix.StoredSamples(0), 1000u);
  EXPECT_EQ(matrix.Counters(0).accepted, 10'000);
}

TEST(ConsistencyMatrix, MatchesWindowConsistencyForEveryMetricAndStandardisation) {
  // Streams at unequal rates with noise; the matrix's pre-sorted CM path and the other
  // metrics agree with WindowConsistency.
  const double rates_hz[] = {200.0, 200.0, 10.0, 20.0, 10.0, 30.0};
  core::RandomStream random(9, "matrix");
  std::vector<VelocitySeries> series(6);
  for (std::size_t s = 0; s < series.size(); ++s) {
    const core::Time period = core::PeriodFromRate(rates_hz[s]);
    for (core::Time t = period; t <= 3'000'000'000; t += period) {
      series[s].t_ns.push_back(t);
      series[s].v_mps.push_back(Motion(t) + 0.05 * Eigen::Vector3d(random.Normal(),
                                                                   random.Normal(),
                                                                   random.Normal()) +
                                Eigen::Vector3d(s == 4 ? 0.5 : 0.0, 0.0, 0.0));
    }
  }
  for (const ConsistencyMetric metric : {ConsistencyMetric::kMae, ConsistencyMetric::kPcc,
                                         ConsistencyMetric::kKl, ConsistencyMetric::kCm}) {
    for (const bool standardize : {false, true}) {
      ConsistencyMatrixOptions options;
      options.metric = metric;
      options.consistency.standardize = standardize;
      ConsistencyMatrix matrix({"local", "vio", "lio", "ts", "gnss", "extra"}, options);
      for (std::size_t s = 0; s < series.size(); ++s) {
        for (std::size_t k = 0; k < series[s].t_ns.size(); ++k) {
          matrix.Add(static_cast<int>(s), series[s].t_ns[k], series[s].v_mps[k]);
        }
      }
      const core::Time t_eval = 2'750'000'000;
      const auto& pairs = matrix.Evaluate(t_eval);
      for (const auto& pair : pairs) {
        const auto expected =
            WindowConsistency(series[static_cast<std::size_t>(pair.i)],
                              series[static_cast<std::size_t>(pair.j)], t_eval, metric,
                              options.consistency);
        ASSERT_EQ(pair.value.has_value(), expected.has_value());
        ASSERT_TRUE(expected.has_value());
        EXPECT_NEAR(*pair.value, *expected, 1e-9 * std::max(1.0, std::abs(*expected)))
            << MetricName(metric) << " standardize " << standardize << " pair " << pair.i
            << "," << pair.j;
      }
    }
  }
}

TEST(ConsistencyMatrix, SlidingEvaluationsMatchWindowConsistency) {
  // The matrix updates its sorted windows incrementally while the window slides forward;
  // check every evaluation of a long run (forward steps, steps back, jumps past the
  // window, samples arriving between evaluations, values with many ties) against
  // WindowConsistency on the full series.
  ConsistencyMatrixOptions options;
  options.history_ns = 3'000'000'000;
  for (const bool standardize : {false, true}) {
    options.consistency.standardize = standardize;
    ConsistencyMatrix matrix({"a", "b", "c"}, options);
    std::vector<VelocitySeries> series(3);
    const core::Time periods[] = {5'000'000, 50'000'000, 33'000'000};
    core::RandomStream random(14, "sliding");
    core::Time t_eval = 0;
    int evaluations = 0;
    for (core::Time t = 0; t <= 30'000'000'000; t += 1'000'000) {
      for (std::size_t s = 0; s < 3; ++s) {
        if (t % periods[s] != 0) continue;
        // Rounded to 0.05 m/s so equal values are common.
        const Eigen::Vector3d v =
            (20.0 * (Motion(t) + 0.1 * Eigen::Vector3d(random.Normal(), random.Normal(),
                                                       random.Normal())))
                .array()
                .round() /
            20.0;
        matrix.Add(static_cast<int>(s), t, v);
        series[s].t_ns.push_back(t);
        series[s].v_mps.push_back(v);
      }
      if (t % 100'000'000 != 0) continue;
      // Mostly the newest time; sometimes 0.5 s back, or (for a while) lagging.
      t_eval = (t % 2'300'000'000 == 0) ? t - 500'000'000 : t;
      if (t > 20'000'000'000 && t < 21'000'000'000) continue;  // a pause, then a jump
      const auto& pairs = matrix.Evaluate(t_eval);
      ++evaluations;
      for (const auto& pair : pairs) {
        const auto expected = WindowConsistency(series[static_cast<std::size_t>(pair.i)],
                                                series[static_cast<std::size_t>(pair.j)],
                                                t_eval, ConsistencyMetric::kCm,
                                                options.consistency);
        ASSERT_EQ(pair.value.has_value(), expected.has_value()) << t_eval;
        if (expected.has_value()) {
          ASSERT_NEAR(*pair.value, *expected, 1e-9 * std::max(1.0, *expected))
              << "t_eval " << t_eval << " pair " << pair.i << "," << pair.j;
        }
      }
    }
    EXPECT_GT(evaluations, 280);
  }
}

TEST(ConsistencyMatrix, AFaultySensorShowsTheCrossPattern) {
  // Four sensors, sensor 2 biased by 0.5 m/s on x: its row and column exceed the paper's
  // 0.1 threshold, every other pair stays below it.
  ConsistencyMatrix matrix({"s1", "s2", "s3", "s4"});
  core::RandomStream random(10, "cross");
  for (core::Time t = 0; t <= 2'000'000'000; t += 10'000'000) {
    for (int s = 0; s < 4; ++s) {
      const Eigen::Vector3d noise =
          0.01 * Eigen::Vector3d(random.Normal(), random.Normal(), random.Normal());
      const Eigen::Vector3d bias(s == 2 ? 0.5 : 0.0, 0.0, 0.0);
      matrix.Add(s, t + s * 1'000'000, Motion(t) + noise + bias);
    }
  }
  matrix.Evaluate(2'000'000'000);
  for (int i = 0; i < 4; ++i) {
    for (int j = i + 1; j < 4; ++j) {
      ASSERT_TRUE(matrix.Value(i, j).has_value());
      if (i == 2 || j == 2) {
        EXPECT_GT(*matrix.Value(i, j), 0.1) << i << "," << j;
      } else {
        EXPECT_LT(*matrix.Value(i, j), 0.1) << i << "," << j;
      }
    }
  }
}

TEST(ConsistencyMatrix, InvalidOptionsAndNamesThrow) {
  ConsistencyMatrixOptions options;
  options.history_ns = 100;  // shorter than the window
  std::string why;
  EXPECT_FALSE(options.IsValid(&why));
  EXPECT_NE(why.find("history_ns"), std::string::npos);
  EXPECT_THROW(ConsistencyMatrix({"a", "b"}, options), std::invalid_argument);
  EXPECT_THROW(ConsistencyMatrix({"a", "a"}), std::invalid_argument);
  EXPECT_THROW(ConsistencyMatrix({"a", ""}), std::invalid_argument);
}

TEST(ConsistencyOptions, EachBrokenLimitIsNamedAlsoThroughTheMatrixOptions) {
  const double nan = std::numeric_limits<double>::quiet_NaN();
  const double inf = std::numeric_limits<double>::infinity();
  std::string why;
  EXPECT_TRUE(ConsistencyOptions{}.IsValid(&why)) << why;
  EXPECT_TRUE(ConsistencyMatrixOptions{}.IsValid(&why)) << why;
  ConsistencyOptions one_sample;
  one_sample.min_samples = 1;
  EXPECT_TRUE(one_sample.IsValid(&why)) << why;

  std::vector<std::pair<std::string, ConsistencyOptions>> broken;
  ConsistencyOptions o;
  o.window_ns = 0;
  broken.emplace_back("window_ns", o);
  o.window_ns = -1;
  broken.emplace_back("window_ns", o);
  for (const double bad : {0.0, -1.0, nan, inf}) {
    o = {};
    o.kl_bandwidth_scale = bad;
    broken.emplace_back("kl_bandwidth_scale", o);
  }
  o = {};
  o.min_samples = 0;
  broken.emplace_back("min_samples", o);
  for (const double bad : {0.0, -1.0, kNaN, std::numeric_limits<double>::infinity()}) {
    o = {};
    o.unobserved_std_mps = bad;
    broken.emplace_back("unobserved_std_mps", o);
  }
  for (const double bad : {-0.001, kNaN, 1.0}) {  // 1.0: not below unobserved_std_mps
    o = {};
    o.std_floor_mps = bad;
    broken.emplace_back("std_floor_mps", o);
  }
  for (const auto& [field, options] : broken) {
    EXPECT_FALSE(options.IsValid(&why)) << field;
    EXPECT_NE(why.find(field), std::string::npos) << field << ": " << why;
    // The matrix's options hold them: the same limit, under the field's path.
    ConsistencyMatrixOptions matrix_options;
    matrix_options.consistency = options;
    matrix_options.history_ns = 10'000'000'000;
    EXPECT_FALSE(matrix_options.IsValid(&why)) << field;
    EXPECT_NE(why.find("consistency." + field), std::string::npos) << field << ": " << why;
    EXPECT_THROW(ConsistencyMatrix({"a", "b"}, matrix_options), std::invalid_argument) << field;
  }
  ConsistencyMatrixOptions unknown_metric;
  unknown_metric.metric = static_cast<ConsistencyMetric>(17);
  EXPECT_FALSE(unknown_metric.IsValid(&why));
  EXPECT_NE(why.find("metric"), std::string::npos) << why;
  ConsistencyMatrixOptions few;
  few.max_samples_per_stream = 1;
  EXPECT_FALSE(few.IsValid(&why));
  EXPECT_NE(why.find("max_samples_per_stream"), std::string::npos) << why;
}

// ---- kNis: velocity differences normalised by what each stream states ----

// A 50 Hz stream of a sinusoidal velocity plus Gaussian noise of the stated per-axis
// standard deviations (and a constant bias), each sample stating that covariance.
VelocitySeries NoisyStream(double duration_s, const Eigen::Vector3d& sd_mps,
                           const Eigen::Vector3d& bias_mps, const char* name) {
  core::RandomStream random(3, name);
  VelocitySeries series;
  const core::Time period_ns = 20'000'000;
  for (core::Time t = period_ns; t <= core::SecondsToTime(duration_s); t += period_ns) {
    const double t_s = core::TimeToSeconds(t);
    const Eigen::Vector3d truth(std::sin(t_s), 0.5 * std::cos(0.7 * t_s), 0.2);
    Eigen::Vector3d noise;
    for (int axis = 0; axis < 3; ++axis) noise[axis] = sd_mps[axis] * random.Normal();
    series.t_ns.push_back(t);
    series.v_mps.push_back(truth + bias_mps + noise);
    series.cov_m2ps2.push_back(sd_mps.cwiseAbs2().asDiagonal());
  }
  return series;
}

ConsistencyOptions NisOptions(double window_s) {
  ConsistencyOptions o;
  o.window_ns = core::SecondsToTime(window_s);
  o.std_floor_mps = 0.0;  // the streams state their whole noise
  return o;
}

// Mean of χ²(k)/k over k = 3 × 1000 degrees of freedom: sd √(2/k) = 0.026 (the samples of
// a pair are independent here), so 4 sd = 0.10.
TEST(NisConsistency, ConsistentStreamsAverageOnePerDegreeOfFreedomWhateverTheirNoise) {
  const double kTolerance = 4.0 * std::sqrt(2.0 / 3000.0);
  const ConsistencyOptions options = NisOptions(20.0);
  const Eigen::Vector3d zero = Eigen::Vector3d::Zero();
  const VelocitySeries total_station = NoisyStream(20.0, Eigen::Vector3d::Constant(0.01), zero, "ts");
  const VelocitySeries vio = NoisyStream(20.0, Eigen::Vector3d::Constant(0.02), zero, "vio");
  const VelocitySeries gnss = NoisyStream(20.0, Eigen::Vector3d(0.5, 0.5, 0.9), zero, "gnss");
  const core::Time t_end = core::SecondsToTime(20.0);
  for (const auto& [a, b] : {std::pair(&total_station, &vio), std::pair(&total_station, &gnss),
                             std::pair(&vio, &gnss)}) {
    const std::optional<double> value =
        WindowConsistency(*a, *b, t_end, ConsistencyMetric::kNis, options);
    ASSERT_TRUE(value.has_value());
    EXPECT_NEAR(*value, 1.0, kTolerance);
  }
}

// A bias β along one axis adds β²/σ² to that axis's term: (3 + 9) / 3 = 4 per dof for a
// 3σ bias on x. The noncentral χ²'s sd per term is √(2 + 4λ) on that axis: over 1000
// samples the ratio's sd is < 0.05; 0.25 is 5 of them.
TEST(NisConsistency, ABiasShowsAsItsSquareOverThePairsVariance) {
  const ConsistencyOptions options = NisOptions(20.0);
  const Eigen::Vector3d sd(0.03, 0.03, 0.03);
  const Eigen::Vector3d combined_sd = std::sqrt(2.0) * sd;
  const VelocitySeries a = NoisyStream(20.0, sd, Eigen::Vector3d::Zero(), "a");
  const VelocitySeries b =
      NoisyStream(20.0, sd, Eigen::Vector3d(3.0 * combined_sd.x(), 0.0, 0.0), "b");
  const std::optional<double> value =
      WindowConsistency(a, b, core::SecondsToTime(20.0), ConsistencyMetric::kNis, options);
  ASSERT_TRUE(value.has_value());
  EXPECT_NEAR(*value, 4.0, 0.25);
  // The same bias judged by the paper's CM distance is a fixed number of m/s, whatever
  // the noise: what a threshold in m/s cannot tell apart.
}

// A LiDAR odometry degenerate along x states a huge variance there: a bias along x (its
// drift) neither votes nor is voted down, and the other two axes still compare.
TEST(NisConsistency, AnUnobservedDirectionNeitherVotesNorIsVotedDown) {
  ConsistencyOptions options = NisOptions(20.0);
  options.unobserved_std_mps = 1.0;
  const VelocitySeries reference =
      NoisyStream(20.0, Eigen::Vector3d::Constant(0.02), Eigen::Vector3d::Zero(), "ref");
  const VelocitySeries degenerate =
      NoisyStream(20.0, Eigen::Vector3d(3.0, 0.02, 0.02), Eigen::Vector3d(2.0, 0.0, 0.0), "lio");
  const core::Time t_end = core::SecondsToTime(20.0);
  const std::optional<double> value =
      WindowConsistency(reference, degenerate, t_end, ConsistencyMetric::kNis, options);
  ASSERT_TRUE(value.has_value());
  // Two observed axes of 1000 samples: sd √(2/2000) = 0.032.
  EXPECT_NEAR(*value, 1.0, 4.0 * std::sqrt(2.0 / 2000.0));
  // Observed (the cap above its 3 m/s), the degenerate axis does vote: its bias of 2 m/s
  // over 3 m/s adds 0.44 / 3 and its noise its own 1.
  options.unobserved_std_mps = 10.0;
  const std::optional<double> voting =
      WindowConsistency(reference, degenerate, t_end, ConsistencyMetric::kNis, options);
  ASSERT_TRUE(voting.has_value());
  EXPECT_NEAR(*voting, 1.0 + (4.0 / 9.0) / 3.0, 0.1);
  // Fully unobserved: unavailable, not consistent.
  options.unobserved_std_mps = 0.01;
  EXPECT_FALSE(WindowConsistency(reference, degenerate, t_end, ConsistencyMetric::kNis, options));
}

TEST(NisConsistency, StreamsThatStateNothingAreUnavailableAndOneSidedStatementsNormalise) {
  const ConsistencyOptions options = NisOptions(20.0);
  VelocitySeries a = NoisyStream(20.0, Eigen::Vector3d::Constant(0.05), Eigen::Vector3d::Zero(), "a");
  VelocitySeries exact = NoisyStream(20.0, Eigen::Vector3d::Zero(), Eigen::Vector3d::Zero(), "exact");
  const core::Time t_end = core::SecondsToTime(20.0);
  exact.cov_m2ps2.clear();  // states nothing (the local estimate): taken as exact
  const std::optional<double> one_sided =
      WindowConsistency(a, exact, t_end, ConsistencyMetric::kNis, options);
  ASSERT_TRUE(one_sided.has_value());
  EXPECT_NEAR(*one_sided, 1.0, 4.0 * std::sqrt(2.0 / 3000.0));
  a.cov_m2ps2.clear();
  EXPECT_FALSE(WindowConsistency(a, exact, t_end, ConsistencyMetric::kNis, options));
}

// The matrix keeps each stream's covariances beside its samples through drops and the cap,
// and gives the same value as WindowConsistency; a sample added without one in a stream
// that states them is skipped, not taken as exact.
TEST(NisConsistency, TheMatrixKeepsCovariancesInStepWithTheSamples) {
  ConsistencyMatrixOptions options;
  options.metric = ConsistencyMetric::kNis;
  options.consistency = NisOptions(1.0);
  options.history_ns = 2'000'000'000;
  ConsistencyMatrix matrix({"a", "b"}, options);
  const VelocitySeries a = NoisyStream(20.0, Eigen::Vector3d::Constant(0.05), Eigen::Vector3d::Zero(), "a");
  const VelocitySeries b = NoisyStream(20.0, Eigen::Vector3d::Constant(0.05), Eigen::Vector3d::Zero(), "b");
  for (std::size_t k = 0; k < a.t_ns.size(); ++k) {
    matrix.Add(0, a.t_ns[k], a.v_mps[k], &a.cov_m2ps2[k]);
    matrix.Add(1, b.t_ns[k], b.v_mps[k], &b.cov_m2ps2[k]);
  }
  for (int stream = 0; stream < 2; ++stream) {
    EXPECT_LT(matrix.StoredSamples(stream), a.t_ns.size());  // old ones were dropped
    EXPECT_EQ(matrix.Samples(stream).cov_m2ps2.size(), matrix.StoredSamples(stream));
  }
  const core::Time t_end = a.t_ns.back();
  matrix.Evaluate(t_end);
  const std::optional<double> direct = WindowConsistency(
      matrix.Samples(0), matrix.Samples(1), t_end, ConsistencyMetric::kNis, options.consistency);
  ASSERT_TRUE(matrix.Value(0, 1).has_value());
  EXPECT_EQ(*matrix.Value(0, 1), *direct);
  // A huge difference in a sample that states no covariance does not count.
  matrix.Add(0, t_end + 20'000'000, Eigen::Vector3d::Constant(100.0));
  matrix.Add(1, t_end + 20'000'000, b.v_mps.back(), &b.cov_m2ps2.back());
  matrix.Evaluate(t_end + 20'000'000);
  ASSERT_TRUE(matrix.Value(0, 1).has_value());
  EXPECT_LT(*matrix.Value(0, 1), 3.0);
}


// ---- the mean-difference test: a bias that every short window hides ----

TEST(ChiSquareUpperQuantile, MatchesTabulatedValues) {
  EXPECT_NEAR(ChiSquareUpperQuantile(1, 0.05), 3.8415, 1e-3);
  EXPECT_NEAR(ChiSquareUpperQuantile(2, 0.05), 5.9915, 1e-3);
  EXPECT_NEAR(ChiSquareUpperQuantile(3, 0.05), 7.8147, 1e-3);
  EXPECT_NEAR(ChiSquareUpperQuantile(2, 1e-4), -2.0 * std::log(1e-4), 1e-6);
  EXPECT_NEAR(ChiSquareUpperQuantile(3, 1e-4), 21.108, 1e-2);
  EXPECT_TRUE(std::isnan(ChiSquareUpperQuantile(4, 0.05)));
  EXPECT_TRUE(std::isnan(ChiSquareUpperQuantile(3, 0.0)));
}

MeanDifferenceOptions WhiteMeanOptions() {
  MeanDifferenceOptions o;
  o.a.correlation_time_ns = 20'000'000;  // NoisyStream's period: independent samples
  o.b.correlation_time_ns = 20'000'000;
  o.floor_std_mps = 0.0;
  return o;
}

// Independent white streams over 100 windows of 10 s: χ²(3) each, so the mean over the
// windows is 3 with sd √(6/100) = 0.24; 4 sd = 1.0. Their 1 s NIS sits at 1 either way.
TEST(MeanDifference, WhiteStreamsGiveChiSquareWithThreeDegreesOfFreedom) {
  const VelocitySeries a = NoisyStream(1000.0, Eigen::Vector3d::Constant(0.02),
                                       Eigen::Vector3d::Zero(), "mean_a");
  const VelocitySeries b = NoisyStream(1000.0, Eigen::Vector3d(0.01, 0.05, 0.03),
                                       Eigen::Vector3d::Zero(), "mean_b");
  double sum = 0.0;
  constexpr int kWindows = 100;
  for (int w = 0; w < kWindows; ++w) {
    const std::optional<MeanDifference> d =
        WindowMeanDifference(a, b, core::SecondsToTime(10.0 * w), core::SecondsToTime(10.0 * (w + 1)),
                             WhiteMeanOptions());
    ASSERT_TRUE(d.has_value());
    EXPECT_EQ(d->dof, 3);
    EXPECT_EQ(d->samples, 500);
    sum += d->chi2;
  }
  EXPECT_NEAR(sum / kWindows, 3.0, 4.0 * std::sqrt(6.0 / kWindows));
}

// A bias of 2 mm/s on x, a tenth of the per-sample sd: 1 s windows of the NIS cannot see
// it ((0.1)²/2 adds 0.005 per dof), while the mean over 10 s of 500 samples is 2 mm/s
// against a sd of √(2·0.02²/500) = 1.26 mm/s per axis: noncentral χ², λ = 2.5 per window,
// over 100 windows mean 5.5 ± 0.35 (sd √(2·3 + 4λ)/10).
TEST(MeanDifference, ABiasTheShortWindowHidesShowsInTheMean) {
  const Eigen::Vector3d sd = Eigen::Vector3d::Constant(0.02);
  const VelocitySeries a = NoisyStream(1000.0, sd, Eigen::Vector3d::Zero(), "bias_a");
  const VelocitySeries b = NoisyStream(1000.0, sd, Eigen::Vector3d(0.002, 0.0, 0.0), "bias_b");
  double sum = 0.0;
  for (int w = 0; w < 100; ++w) {
    const auto d = WindowMeanDifference(a, b, core::SecondsToTime(10.0 * w),
                                        core::SecondsToTime(10.0 * (w + 1)), WhiteMeanOptions());
    ASSERT_TRUE(d.has_value());
    sum += d->chi2;
  }
  EXPECT_NEAR(sum / 100.0, 5.5, 4.0 * std::sqrt(2.0 * 3.0 + 4.0 * 2.5) / 10.0);
  // Over the whole 1000 s the same bias is 2 mm/s against 0.13 mm/s: far beyond any bound
  // (d̄ = a − b: b is the biased one).
  const auto whole = WindowMeanDifference(a, b, 0, core::SecondsToTime(1000.0), WhiteMeanOptions());
  ASSERT_TRUE(whole.has_value());
  EXPECT_GT(whole->chi2, ChiSquareUpperQuantile(3, 1e-9));
  EXPECT_NEAR(whole->mean_mps.x(), -0.002, 4.0 * std::sqrt(2.0 * 0.02 * 0.02 / 50000.0));
}

// Correlated samples count once per correlation time: the same streams stated as
// correlated over 0.2 s (10 samples) give a tenth of the χ².
TEST(MeanDifference, SamplesWithinTheCorrelationTimeCountOnce) {
  const Eigen::Vector3d sd = Eigen::Vector3d::Constant(0.02);
  const VelocitySeries a = NoisyStream(20.0, sd, Eigen::Vector3d::Zero(), "corr_a");
  const VelocitySeries b = NoisyStream(20.0, sd, Eigen::Vector3d(0.01, 0.0, 0.0), "corr_b");
  MeanDifferenceOptions correlated = WhiteMeanOptions();
  correlated.a.correlation_time_ns = 200'000'000;
  correlated.b.correlation_time_ns = 200'000'000;
  const auto white = WindowMeanDifference(a, b, 0, core::SecondsToTime(20.0), WhiteMeanOptions());
  const auto slow = WindowMeanDifference(a, b, 0, core::SecondsToTime(20.0), correlated);
  ASSERT_TRUE(white && slow);
  // N_eff = span / 0.2 s + 1 = 100.9 of 1000 samples.
  EXPECT_NEAR(slow->chi2 / white->chi2, 100.9 / 1000.0, 1e-3);
}

// Velocities differentiated from white positions telescope: their mean is the
// displacement over the span, whose error 2 P / span² bounds (each end a fit's average of
// positions). Stated per sample with a fit's correlation time instead, the same streams'
// χ² would be a small fraction of it: a drift would have to be several times larger to
// be seen.
TEST(MeanDifference, DifferentiatedPositionsAreJudgedByTheirDisplacement) {
  core::RandomStream random(21, "telescope");
  const double sd_p_m = 0.003;
  const core::Time period_ns = 50'000'000;  // a 20 Hz total station
  std::vector<core::Time> t;
  std::vector<Eigen::Vector3d> p;
  std::vector<Eigen::Matrix3d> cov_p;
  for (core::Time k = 0; k <= core::SecondsToTime(1000.0); k += period_ns) {
    const double s = core::TimeToSeconds(k);
    Eigen::Vector3d noise(random.Normal(), random.Normal(), random.Normal());
    t.push_back(k);
    // Slow enough that the fit's curvature error (the third derivative's) stays far
    // below the noise.
    p.push_back(Eigen::Vector3d(2.0 * std::cos(0.3 * s), 0.5 * std::sin(0.2 * s), 0.2 * s) +
                sd_p_m * noise);
    cov_p.push_back(Eigen::Matrix3d::Identity() * sd_p_m * sd_p_m);
  }
  DifferentiationOptions diff;
  diff.half_window_ns = 160'000'000;
  const VelocitySeries station = DifferentiatePositions(t, p, cov_p, diff);
  // A twist of 1 mm/s at the station's stamps, exact velocity otherwise.
  VelocitySeries twist;
  core::RandomStream twist_noise(22, "telescope_twist");
  for (const core::Time k : station.t_ns) {
    const double s = core::TimeToSeconds(k);
    twist.t_ns.push_back(k);
    twist.v_mps.push_back(Eigen::Vector3d(-0.6 * std::sin(0.3 * s), 0.1 * std::cos(0.2 * s), 0.2) +
                          0.001 * Eigen::Vector3d(twist_noise.Normal(), twist_noise.Normal(),
                                                  twist_noise.Normal()));
    twist.cov_m2ps2.push_back(Eigen::Matrix3d::Identity() * 1e-6);
  }
  MeanDifferenceOptions telescoping = WhiteMeanOptions();
  telescoping.a.position_covariance_m2 = Eigen::Matrix3d::Identity() * sd_p_m * sd_p_m;
  telescoping.b.correlation_time_ns = period_ns;
  MeanDifferenceOptions per_sample = telescoping;
  per_sample.a.position_covariance_m2.reset();
  per_sample.a.correlation_time_ns = 2 * diff.half_window_ns;
  double sum_telescoping = 0.0;
  double sum_per_sample = 0.0;
  for (int w = 0; w < 100; ++w) {
    const core::Time from = core::SecondsToTime(10.0 * w);
    const core::Time to = core::SecondsToTime(10.0 * (w + 1));
    const auto d = WindowMeanDifference(station, twist, from, to, telescoping);
    const auto e = WindowMeanDifference(station, twist, from, to, per_sample);
    ASSERT_TRUE(d && e);
    sum_telescoping += d->chi2;
    sum_per_sample += e->chi2;
  }
  // A bound, not an equality: below χ²(3)'s mean of 3 (4 sd of 100 windows: +1.0). Each
  // end is a fit's average of 7 positions, 0.18 of a sample's variance for a line: about
  // 3 × 0.18 = 0.54 expected (0.65 measured with the twist's share), well above 0.35.
  EXPECT_LT(sum_telescoping / 100.0, 3.0 + 1.0);
  EXPECT_GT(sum_telescoping / 100.0, 0.35);
  EXPECT_LT(sum_per_sample, 0.2 * sum_telescoping);
}

// A burst of gross errors (15 samples 2 m/s off: one outlier of a total station through
// its fit) moves the plain mean of 500 samples by 6 cm/s, 40 of its sd; shrunk to 3 sd
// each it moves it by 0.09 sample sd, within the bound. A drift inside the scatter is
// untouched by the clipping.
TEST(MeanDifference, GrossErrorsAreClippedWhileADriftIsNot) {
  const Eigen::Vector3d sd = Eigen::Vector3d::Constant(0.02);
  const VelocitySeries a = NoisyStream(10.0, sd, Eigen::Vector3d::Zero(), "clip_a");
  VelocitySeries b = NoisyStream(10.0, sd, Eigen::Vector3d::Zero(), "clip_b");
  for (std::size_t k = 200; k < 215; ++k) b.v_mps[k].x() += 2.0;
  MeanDifferenceOptions clipped = WhiteMeanOptions();
  MeanDifferenceOptions plain = clipped;
  plain.clip_sigma = std::numeric_limits<double>::infinity();
  const core::Time end = core::SecondsToTime(10.0);
  const auto with_burst = WindowMeanDifference(a, b, 0, end, clipped);
  const auto unclipped = WindowMeanDifference(a, b, 0, end, plain);
  ASSERT_TRUE(with_burst && unclipped);
  EXPECT_GT(unclipped->chi2, ChiSquareUpperQuantile(3, 1e-9));
  EXPECT_LT(with_burst->chi2, ChiSquareUpperQuantile(3, 1e-4));
  const VelocitySeries drifting =
      NoisyStream(10.0, sd, Eigen::Vector3d(0.01, 0.0, 0.0), "clip_b");
  const auto drift_clipped = WindowMeanDifference(a, drifting, 0, end, clipped);
  const auto drift_plain = WindowMeanDifference(a, drifting, 0, end, plain);
  ASSERT_TRUE(drift_clipped && drift_plain);
  EXPECT_GT(drift_clipped->chi2, 0.95 * drift_plain->chi2);
  EXPECT_GT(drift_clipped->chi2, ChiSquareUpperQuantile(3, 1e-4));
}

// A position sensor's velocity comes through its alignment: 1° of yaw error moves the
// difference by 1.7 cm/s at 1 m/s, turning with the velocity. Fitted as a rotation, it
// is not a bias (χ² back to χ²(3)'s range, δ̂ the 1°), while a drift beside it still is.
TEST(MeanDifference, ARotationBetweenTheFramesIsFittedAndADriftBesideItIsNot) {
  const Eigen::Vector3d sd = Eigen::Vector3d::Constant(0.01);
  const double yaw_rad = M_PI / 180.0;
  const Eigen::Matrix3d R = Eigen::AngleAxisd(yaw_rad, Eigen::Vector3d::UnitZ()).toRotationMatrix();
  // A flight with a mean horizontal velocity of 0.58 m/s over the window (a figure-eight's
  // part) besides NoisyStream's oscillation.
  const Eigen::Vector3d cruise(0.5, 0.3, 0.0);
  const VelocitySeries reference = NoisyStream(20.0, sd, cruise, "rot_ref");
  const auto rotated = [&](const Eigen::Vector3d& bias, const char* name) {
    VelocitySeries s = NoisyStream(20.0, sd, cruise, name);
    for (Eigen::Vector3d& v : s.v_mps) v = R * v + bias;
    return s;
  };
  const VelocitySeries misaligned = rotated(Eigen::Vector3d::Zero(), "rot_b");
  MeanDifferenceOptions options = WhiteMeanOptions();
  const core::Time end = core::SecondsToTime(20.0);
  const auto plain = WindowMeanDifference(misaligned, reference, 0, end, options);
  options.estimate_rotation = true;
  const auto fitted = WindowMeanDifference(misaligned, reference, 0, end, options);
  ASSERT_TRUE(plain && fitted);
  EXPECT_GT(plain->chi2, ChiSquareUpperQuantile(3, 1e-6));
  EXPECT_LT(fitted->chi2, ChiSquareUpperQuantile(3, 1e-3));
  EXPECT_NEAR(fitted->rotation_rad.z(), yaw_rad, 0.1 * yaw_rad);
  const VelocitySeries drifting = rotated(Eigen::Vector3d(0.005, -0.005, 0.0), "rot_b");
  const auto drift = WindowMeanDifference(drifting, reference, 0, end, options);
  ASSERT_TRUE(drift.has_value());
  EXPECT_GT(drift->chi2, ChiSquareUpperQuantile(3, 1e-4));
  EXPECT_NEAR(drift->mean_mps.x(), 0.005, 0.0015);
}

// A direction the pair does not observe (a degenerate LiDAR odometry's) is left out of
// the test, its bias with it.
TEST(MeanDifference, AnUnobservedDirectionIsLeftOut) {
  const VelocitySeries reference = NoisyStream(20.0, Eigen::Vector3d::Constant(0.02),
                                               Eigen::Vector3d::Zero(), "unobs_ref");
  const VelocitySeries degenerate = NoisyStream(20.0, Eigen::Vector3d(3.0, 0.02, 0.02),
                                                Eigen::Vector3d(2.0, 0.0, 0.0), "unobs_lio");
  const auto d = WindowMeanDifference(reference, degenerate, 0, core::SecondsToTime(20.0),
                                      WhiteMeanOptions());
  ASSERT_TRUE(d.has_value());
  EXPECT_EQ(d->dof, 2);
  EXPECT_LT(d->chi2, ChiSquareUpperQuantile(2, 1e-4));
}

TEST(MeanDifference, NoCovarianceOrTooFewPairsIsUnavailableAndBrokenOptionsAreNamed) {
  VelocitySeries a = NoisyStream(1.0, Eigen::Vector3d::Constant(0.02), Eigen::Vector3d::Zero(), "na");
  const VelocitySeries b = NoisyStream(1.0, Eigen::Vector3d::Constant(0.02), Eigen::Vector3d::Zero(), "nb");
  MeanDifferenceOptions options = WhiteMeanOptions();
  options.min_samples = 60;  // 50 pairs in 1 s
  EXPECT_FALSE(WindowMeanDifference(a, b, 0, core::SecondsToTime(1.0), options).has_value());
  a.cov_m2ps2.clear();
  EXPECT_FALSE(WindowMeanDifference(a, b, 0, core::SecondsToTime(1.0)).has_value());
  std::string why;
  MeanDifferenceOptions broken;
  broken.b.correlation_time_ns = 0;
  EXPECT_FALSE(broken.IsValid(&why));
  EXPECT_NE(why.find("correlation_time_ns"), std::string::npos) << why;
  broken = {};
  broken.min_samples = 1;
  EXPECT_FALSE(broken.IsValid(&why));
  EXPECT_NE(why.find("min_samples"), std::string::npos) << why;
}

}  // namespace
}  // namespace tofu::estimator
