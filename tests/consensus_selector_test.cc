// Consensus-based sensor selection (estimator/consensus_selector.h): the four-sensor
// cross patterns of the paper's Fig. "consensus", the two-sensor degenerate case resolved
// against the local estimate (both ways), dropouts, unknown values, hysteresis and dwell
// against a value oscillating around the threshold, priority, the largest-set policy and
// the input checks. Every matrix is written by hand; threshold 0.1 m/s unless stated.

#include <cmath>
#include <cstddef>
#include <limits>
#include <optional>
#include <stdexcept>
#include <string>
#include <utility>
#include <vector>

#include <gtest/gtest.h>

#include "core/time.h"
#include "estimator/consensus_selector.h"
#include "estimator/consistency_matrix.h"

namespace tofu::estimator {
namespace {

using Names = std::vector<std::string>;

constexpr core::Time kStep = 100'000'000;  // 10 Hz decisions

Names Sensors(int n) {
  Names names;
  for (int i = 1; i <= n; ++i) {
    std::string name = "S";
    name += std::to_string(i);
    names.push_back(std::move(name));
  }
  return names;
}

// A consistency matrix written by hand: sensors are numbered from 1 as in the paper.
class Matrix {
 public:
  explicit Matrix(int n, double all_pairs = 0.05) : n_(n) {
    input_.available.assign(static_cast<std::size_t>(n), true);
    input_.pair.assign(static_cast<std::size_t>(n * (n - 1) / 2), all_pairs);
    input_.vs_local.assign(static_cast<std::size_t>(n), std::nullopt);
  }
  Matrix& Pair(int a, int b, std::optional<double> value) {
    if (a > b) std::swap(a, b);
    input_.pair[static_cast<std::size_t>(ConsistencyMatrix::PairIndex(a - 1, b - 1, n_))] = value;
    return *this;
  }
  // Every pair of sensor a (its row and column: the cross).
  Matrix& Row(int a, std::optional<double> value) {
    for (int b = 1; b <= n_; ++b) {
      if (b != a) Pair(a, b, value);
    }
    return *this;
  }
  Matrix& Local(int a, std::optional<double> value) {
    input_.vs_local[static_cast<std::size_t>(a - 1)] = value;
    return *this;
  }
  // The pair failed the bias test (ConsensusInput::pair_biased), whatever its value.
  Matrix& Biased(int a, int b) {
    if (a > b) std::swap(a, b);
    input_.pair_biased.resize(input_.pair.size(), false);
    input_.pair_biased[static_cast<std::size_t>(ConsistencyMatrix::PairIndex(a - 1, b - 1, n_))] =
        true;
    return *this;
  }
  Matrix& Unavailable(int a) {
    input_.available[static_cast<std::size_t>(a - 1)] = false;
    return *this;
  }
  ConsensusInput At(core::Time t_ns) const {
    ConsensusInput input = input_;
    input.t_ns = t_ns;
    return input;
  }

 private:
  int n_;
  ConsensusInput input_;
};

// Decide, and check the invariants of every decision on the way.
ConsensusDecision Decide(ConsensusSelector& selector, const ConsensusInput& input) {
  ConsensusDecision d = selector.Decide(input);
  EXPECT_EQ(d.reason.find(','), std::string::npos) << d.reason;
  EXPECT_EQ(d.reason.find('\n'), std::string::npos) << d.reason;
  EXPECT_FALSE(d.reason.empty());
  EXPECT_EQ(d.t_ns, input.t_ns);
  EXPECT_EQ(selector.fused(), d.fused);
  for (const std::string& f : d.fused) {
    for (const std::string& e : d.excluded) EXPECT_NE(f, e) << d.reason;
    for (const std::string& u : d.unavailable) EXPECT_NE(f, u) << d.reason;
  }
  return d;
}

bool Contains(const std::string& text, const std::string& part) {
  return text.find(part) != std::string::npos;
}

ConsensusOptions WithPriority(Names priority) {
  ConsensusOptions options;
  options.priority = std::move(priority);
  return options;
}

// ---- the paper's four-sensor patterns (Fig. "consensus") ----

TEST(ConsensusSelectorCross, NoFailureExcludesNothingAndFusesOneOfTheMostConsistentPair) {
  ConsensusSelector selector(Sensors(4));
  const Matrix m = Matrix(4, 0.05).Pair(1, 3, 0.031).Pair(2, 4, 0.04);
  const ConsensusDecision d = Decide(selector, m.At(0));
  EXPECT_TRUE(d.excluded.empty()) << d.reason;
  EXPECT_TRUE(d.unavailable.empty());
  EXPECT_EQ(d.fused, Names{"S1"}) << d.reason;
  EXPECT_TRUE(Contains(d.reason, "most consistent pair S1-S3 (0.031)")) << d.reason;
  EXPECT_TRUE(d.changed);
}

TEST(ConsensusSelectorCross, FailingS4IsExcluded) {
  // S4's row and column high, the others low: the cross of S4.
  ConsensusSelector selector(Sensors(4), WithPriority({"S4", "S3"}));
  const Matrix m = Matrix(4, 0.05).Row(4, 0.6).Pair(1, 3, 0.031);
  const ConsensusDecision d = Decide(selector, m.At(0));
  EXPECT_EQ(d.excluded, Names{"S4"}) << d.reason;
  // Priority says S3 before S1 within the most consistent pair S1-S3.
  EXPECT_EQ(d.fused, Names{"S3"}) << d.reason;
  EXPECT_TRUE(Contains(d.reason, "S4 inconsistent with 3 of 3 (cross pattern)")) << d.reason;
  EXPECT_TRUE(Contains(d.reason, "most consistent pair S1-S3 (0.031)")) << d.reason;
}

TEST(ConsensusSelectorCross, FailingS2AndS4AreBothExcludedAndS1S3Stays) {
  // Two crosses: every pair with S2 or S4 high (S2-S4 too: two different faults); only
  // S1-S3 low. S1 and S3 are each inconsistent with 2 of 3 as well, but the sensors they
  // disagree with do not agree among themselves.
  ConsensusSelector selector(Sensors(4));
  const Matrix m = Matrix(4).Row(2, 0.4).Row(4, 0.5).Pair(2, 4, 0.7).Pair(1, 3, 0.031);
  const ConsensusDecision d = Decide(selector, m.At(0));
  EXPECT_EQ(d.excluded, (Names{"S2", "S4"})) << d.reason;
  EXPECT_EQ(d.fused, Names{"S1"}) << d.reason;
  EXPECT_TRUE(Contains(d.reason, "S2 inconsistent with 3 of 3 (cross pattern)")) << d.reason;
  EXPECT_TRUE(Contains(d.reason, "S4 inconsistent with 3 of 3 (cross pattern)")) << d.reason;
  EXPECT_TRUE(Contains(d.reason, "most consistent pair S1-S3 (0.031)")) << d.reason;
}

TEST(ConsensusSelectorCross, ThreeSensorsOneCross) {
  ConsensusSelector selector(Sensors(3), WithPriority({"S3"}));
  const ConsensusDecision d = Decide(selector, Matrix(3, 0.05).Row(3, 0.3).At(0));
  EXPECT_EQ(d.excluded, Names{"S3"}) << d.reason;
  EXPECT_EQ(d.fused, Names{"S1"}) << d.reason;
}

// A slow drift: every value low (the 1 s window sees nothing), but S3's mean differences
// with S1 and S2 failed the bias test: S3 is the cross, and is not taken back while they
// fail.
TEST(ConsensusSelectorCross, APairThatFailedTheBiasTestIsInconsistentWhateverItsValue) {
  ConsensusSelector selector(Sensors(3), WithPriority({"S3", "S1"}));
  const ConsensusDecision clean = Decide(selector, Matrix(3, 0.05).At(0));
  EXPECT_EQ(clean.fused, Names{"S3"}) << clean.reason;
  const Matrix drifting = Matrix(3, 0.05).Biased(3, 1).Biased(3, 2);
  const ConsensusDecision d = Decide(selector, drifting.At(kStep));
  EXPECT_EQ(d.excluded, Names{"S3"}) << d.reason;
  EXPECT_EQ(d.inconsistent, Names{"S3"}) << d.reason;
  EXPECT_EQ(d.fused, Names{"S1"}) << d.reason;
  EXPECT_TRUE(Contains(d.reason, "S3 inconsistent with 2 of 2 (cross pattern)")) << d.reason;
  // One biased pair of two is no majority: nobody is the cross.
  ConsensusSelector other(Sensors(3), WithPriority({"S3", "S1"}));
  const ConsensusDecision one = Decide(other, Matrix(3, 0.05).Biased(3, 1).At(0));
  EXPECT_TRUE(one.excluded.empty()) << one.reason;
  // A pair_biased of the wrong size is refused like a wrong pair vector.
  ConsensusInput wrong = Matrix(3, 0.05).At(2 * kStep);
  wrong.pair_biased.assign(2, false);
  EXPECT_THROW(selector.Decide(wrong), std::invalid_argument);
}

TEST(ConsensusSelectorCross, TwoAgainstTwoIsResolvedByTheLocalEstimate) {
  // S1-S2 agree, S3-S4 agree, the groups disagree: each sensor is inconsistent with 2 of 3.
  // The pairs cannot tell which group is right; the distance to the local estimate does.
  const Matrix base = Matrix(4, 0.5).Pair(1, 2, 0.02).Pair(3, 4, 0.03);
  {
    ConsensusSelector selector(Sensors(4));
    const Matrix m = Matrix(base).Local(1, 0.03).Local(2, 0.04).Local(3, 0.4).Local(4, 0.5);
    const ConsensusDecision d = Decide(selector, m.At(0));
    EXPECT_EQ(d.excluded, (Names{"S3", "S4"})) << d.reason;
    EXPECT_EQ(d.fused, Names{"S1"}) << d.reason;
  }
  {
    ConsensusSelector selector(Sensors(4));
    const Matrix m = Matrix(base).Local(1, 0.4).Local(2, 0.5).Local(3, 0.03).Local(4, 0.04);
    const ConsensusDecision d = Decide(selector, m.At(0));
    EXPECT_EQ(d.excluded, (Names{"S1", "S2"})) << d.reason;
    EXPECT_EQ(d.fused, Names{"S3"}) << d.reason;
  }
}

TEST(ConsensusSelectorCross, NoConsensusAmongFourIsResolvedAgainstLocal) {
  // Every pair inconsistent: no cross can be trusted; the sensor closest to the local
  // estimate (and consistent with it) is fused, the others are inconsistent with it.
  ConsensusSelector selector(Sensors(4));
  const Matrix m = Matrix(4, 0.5).Local(1, 0.3).Local(2, 0.2).Local(3, 0.05).Local(4, 0.4);
  const ConsensusDecision d = Decide(selector, m.At(0));
  EXPECT_EQ(d.fused, Names{"S3"}) << d.reason;
  EXPECT_EQ(d.excluded, (Names{"S1", "S2", "S4"})) << d.reason;
  EXPECT_TRUE(Contains(d.reason, "no consistent eligible pair among 4 sensors")) << d.reason;
}

TEST(ConsensusSelector, KeepsTheFusedSensorWhileItIsInAConsistentPair) {
  ConsensusSelector selector(Sensors(4));
  // t0: S1-S2 is the most consistent pair: S1 (priority).
  EXPECT_EQ(Decide(selector, Matrix(4, 0.05).Pair(1, 2, 0.01).At(0)).fused, Names{"S1"});
  // t1: S3-S4 is now the most consistent pair, but S1 still agrees with S2: no switch.
  const ConsensusDecision kept =
      Decide(selector, Matrix(4, 0.05).Pair(1, 2, 0.06).Pair(3, 4, 0.01).At(kStep));
  EXPECT_EQ(kept.fused, Names{"S1"}) << kept.reason;
  EXPECT_FALSE(kept.changed);
  EXPECT_TRUE(Contains(kept.reason, "keeping S1 (consistent with S3 0.050)")) << kept.reason;
  // t2: S1 fails (cross): S3 of the most consistent pair S3-S4.
  const ConsensusDecision moved =
      Decide(selector, Matrix(4, 0.05).Row(1, 0.4).Pair(3, 4, 0.01).At(2 * kStep));
  EXPECT_EQ(moved.fused, Names{"S3"}) << moved.reason;
  EXPECT_TRUE(moved.changed);
  EXPECT_EQ(selector.switches(), 1);
}

// ---- two sensors: the degenerate case, resolved against the local estimate ----

TEST(ConsensusSelectorTwo, ConsistentPairFusesByPriority) {
  ConsensusSelector by_order(Sensors(2));
  EXPECT_EQ(Decide(by_order, Matrix(2, 0.05).At(0)).fused, Names{"S1"});
  ConsensusSelector by_priority(Sensors(2), WithPriority({"S2"}));
  const ConsensusDecision d = Decide(by_priority, Matrix(2, 0.05).At(0));
  EXPECT_EQ(d.fused, Names{"S2"}) << d.reason;
  EXPECT_TRUE(d.excluded.empty());
}

TEST(ConsensusSelectorTwo, FusedConsistentWithLocalIsKeptAndTheOtherExcluded) {
  ConsensusSelector selector(Sensors(2));
  ASSERT_EQ(Decide(selector, Matrix(2, 0.05).At(0)).fused, Names{"S1"});
  const ConsensusDecision d =
      Decide(selector, Matrix(2, 0.3).Local(1, 0.03).Local(2, 0.4).At(kStep));
  EXPECT_EQ(d.fused, Names{"S1"}) << d.reason;
  EXPECT_EQ(d.excluded, Names{"S2"}) << d.reason;
  EXPECT_FALSE(d.changed);
  EXPECT_TRUE(Contains(d.reason, "S1-S2 inconsistent (0.300)")) << d.reason;
  EXPECT_TRUE(Contains(d.reason, "keeping S1 (consistent with local 0.030")) << d.reason;
}

TEST(ConsensusSelectorTwo, FusedInconsistentWithLocalIsReplacedAndExcluded) {
  ConsensusSelector selector(Sensors(2));
  ASSERT_EQ(Decide(selector, Matrix(2, 0.05).At(0)).fused, Names{"S1"});
  const ConsensusDecision d =
      Decide(selector, Matrix(2, 0.3).Local(1, 0.4).Local(2, 0.03).At(kStep));
  EXPECT_EQ(d.fused, Names{"S2"}) << d.reason;
  EXPECT_EQ(d.excluded, Names{"S1"}) << d.reason;
  EXPECT_TRUE(d.changed);
  EXPECT_TRUE(Contains(d.reason, "switching to S2 (consistent with local 0.030")) << d.reason;
}

TEST(ConsensusSelectorTwo, BothInconsistentWithLocalFusesTheCloserOneEitherWay) {
  // S1 closer to the local estimate.
  {
    ConsensusSelector selector(Sensors(2), WithPriority({"S2"}));
    const ConsensusDecision d =
        Decide(selector, Matrix(2, 0.3).Local(1, 0.2).Local(2, 0.5).At(0));
    EXPECT_EQ(d.fused, Names{"S1"}) << d.reason;
    EXPECT_EQ(d.excluded, Names{"S2"}) << d.reason;
    EXPECT_TRUE(Contains(d.reason, "all inconsistent with local: fusing S1 as the closest"))
        << d.reason;
  }
  // S2 closer, even though S1 is fused and preferred.
  {
    ConsensusSelector selector(Sensors(2), WithPriority({"S1"}));
    ASSERT_EQ(Decide(selector, Matrix(2, 0.05).At(0)).fused, Names{"S1"});
    const ConsensusDecision d =
        Decide(selector, Matrix(2, 0.3).Local(1, 0.5).Local(2, 0.2).At(kStep));
    EXPECT_EQ(d.fused, Names{"S2"}) << d.reason;
    EXPECT_EQ(d.excluded, Names{"S1"}) << d.reason;
    EXPECT_TRUE(Contains(d.reason, "fusing S2 as the closest (inconsistent with local 0.200"))
        << d.reason;
  }
}

TEST(ConsensusSelectorTwo, LocalUnknownKeepsTheCurrentChoiceOrPriority) {
  // Nothing fused yet: priority.
  {
    ConsensusSelector selector(Sensors(2), WithPriority({"S2"}));
    const ConsensusDecision d = Decide(selector, Matrix(2, 0.3).At(0));
    EXPECT_EQ(d.fused, Names{"S2"}) << d.reason;
    EXPECT_EQ(d.excluded, Names{"S1"}) << d.reason;
    EXPECT_TRUE(Contains(d.reason, "by priority (vs local unknown)")) << d.reason;
  }
  // S2 fused (the only one at first), then the pair disagrees with no local value: S2 stays
  // although S1 has the priority.
  {
    ConsensusSelector selector(Sensors(2), WithPriority({"S1"}));
    ASSERT_EQ(Decide(selector, Matrix(2, 0.05).Unavailable(1).At(0)).fused, Names{"S2"});
    const ConsensusDecision d = Decide(selector, Matrix(2, 0.3).At(kStep));
    EXPECT_EQ(d.fused, Names{"S2"}) << d.reason;
    EXPECT_EQ(d.excluded, Names{"S1"}) << d.reason;
    EXPECT_TRUE(Contains(d.reason, "keeping S2 (vs local unknown")) << d.reason;
  }
}

// ---- dropouts, one sensor, unknown values ----

TEST(ConsensusSelector, AllUnavailableFusesNothing) {
  ConsensusSelector selector(Sensors(3));
  ASSERT_EQ(Decide(selector, Matrix(3).At(0)).fused, Names{"S1"});
  const ConsensusDecision d =
      Decide(selector, Matrix(3).Unavailable(1).Unavailable(2).Unavailable(3).At(kStep));
  EXPECT_TRUE(d.fused.empty());
  EXPECT_TRUE(d.excluded.empty());
  EXPECT_EQ(d.unavailable, (Names{"S1", "S2", "S3"}));
  EXPECT_EQ(d.reason, "all sensors unavailable");
  EXPECT_TRUE(d.changed);
  EXPECT_EQ(selector.switches(), 1);
}

TEST(ConsensusSelector, UnavailableSensorsAreNeverFusedNorExcluded) {
  ConsensusSelector selector(Sensors(4), WithPriority({"S2"}));
  // S2 is the preferred sensor and its (stale) values look perfect, but it delivered nothing.
  const Matrix m = Matrix(4, 0.05).Row(2, 0.001).Unavailable(2).Row(4, 0.5);
  const ConsensusDecision d = Decide(selector, m.At(0));
  EXPECT_EQ(d.unavailable, Names{"S2"});
  EXPECT_EQ(d.excluded, Names{"S4"}) << d.reason;
  EXPECT_EQ(d.fused, Names{"S1"}) << d.reason;
}

TEST(ConsensusSelector, OneSensorIsFusedUnlessInconsistentWithLocal) {
  ConsensusSelector selector(Sensors(3));
  const Matrix one = Matrix(3).Unavailable(2).Unavailable(3);
  const ConsensusDecision unknown = Decide(selector, one.At(0));
  EXPECT_EQ(unknown.fused, Names{"S1"}) << unknown.reason;
  EXPECT_TRUE(Contains(unknown.reason, "only available sensor")) << unknown.reason;
  const ConsensusDecision consistent = Decide(selector, Matrix(one).Local(1, 0.05).At(kStep));
  EXPECT_EQ(consistent.fused, Names{"S1"}) << consistent.reason;
  const ConsensusDecision bad = Decide(selector, Matrix(one).Local(1, 0.3).At(2 * kStep));
  EXPECT_TRUE(bad.fused.empty()) << bad.reason;
  EXPECT_EQ(bad.excluded, Names{"S1"}) << bad.reason;
  EXPECT_TRUE(Contains(bad.reason, "S1 inconsistent with local (0.300)")) << bad.reason;
}

TEST(ConsensusSelector, UnknownValuesAreNotEvidence) {
  // S4 has no known value: neither excluded (unknown is not inconsistent) nor part of the
  // most consistent pair (unknown is not consistent), although it has the priority.
  ConsensusSelector selector(Sensors(4), WithPriority({"S4"}));
  const Matrix m = Matrix(4, 0.05).Pair(1, 2, 0.02).Row(4, std::nullopt);
  const ConsensusDecision d = Decide(selector, m.At(0));
  EXPECT_TRUE(d.excluded.empty()) << d.reason;
  EXPECT_TRUE(d.unavailable.empty());
  EXPECT_EQ(d.fused, Names{"S1"}) << d.reason;

  // One known inconsistent pair among three sensors, the rest unknown: no cross pattern
  // (nobody is corroborated); the degenerate rule picks by the local estimate.
  ConsensusSelector three(Sensors(3));
  const Matrix sparse = Matrix(3, std::numeric_limits<double>::quiet_NaN())
                            .Pair(1, 3, 0.5)
                            .Local(1, 0.3)
                            .Local(3, 0.02);
  const ConsensusDecision s = Decide(three, sparse.At(0));
  EXPECT_EQ(s.fused, Names{"S3"}) << s.reason;
  EXPECT_EQ(s.excluded, Names{"S1"}) << s.reason;
  EXPECT_EQ(three.ignored_values(), 2);  // the two NaN pairs
}

// ---- hysteresis and dwell ----

// Two sensors that disagree (0.3) and take turns being just below / just above the
// threshold against the local estimate: the paper's "keeps switching between a valid and
// a corrupted sensor".
ConsensusInput LocalPingPong(int k) {
  const bool even = k % 2 == 0;
  return Matrix(2, 0.3).Local(1, even ? 0.09 : 0.11).Local(2, even ? 0.11 : 0.09).At(k * kStep);
}

// Four sensors: S1's cross and S2's cross take turns at 0.11, just above the threshold.
ConsensusInput CrossPingPong(int k) {
  Matrix m = Matrix(4, 0.05).Pair(1, 2, 0.02).Pair(3, 4, 0.08);
  if (k > 0) m.Pair(1, 2, 0.11).Row(k % 2 == 1 ? 1 : 2, 0.11);
  return m.At(k * kStep);
}

int SwitchesOver(ConsensusSelector& selector, ConsensusInput (*input)(int), int steps) {
  for (int k = 0; k < steps; ++k) Decide(selector, input(k));
  return selector.switches();
}

TEST(ConsensusSelectorHysteresis, TwoSensorPingPongStopsWithLeaveThreshold) {
  ConsensusSelector paper(Sensors(2));
  EXPECT_EQ(SwitchesOver(paper, LocalPingPong, 20), 19);

  ConsensusOptions options;
  options.leave_threshold = 0.15;
  ConsensusSelector hysteresis(Sensors(2), options);
  EXPECT_EQ(SwitchesOver(hysteresis, LocalPingPong, 20), 0);
  EXPECT_EQ(hysteresis.fused(), Names{"S1"});
}

TEST(ConsensusSelectorHysteresis, CrossPingPongStopsWithLeaveThreshold) {
  ConsensusSelector paper(Sensors(4));
  EXPECT_EQ(SwitchesOver(paper, CrossPingPong, 20), 19);

  ConsensusOptions options;
  options.leave_threshold = 0.15;
  ConsensusSelector hysteresis(Sensors(4), options);
  EXPECT_EQ(SwitchesOver(hysteresis, CrossPingPong, 20), 0);
  EXPECT_EQ(hysteresis.fused(), Names{"S1"});
  // The sensor that is not fused still has to get below `threshold`: S2 at 0.11 is out.
  const ConsensusDecision d = Decide(hysteresis, CrossPingPong(20));
  EXPECT_EQ(d.excluded, Names{"S2"}) << d.reason;
}

TEST(ConsensusSelectorDwell, PingPongsStopWithMinDwell) {
  ConsensusOptions options;
  options.min_dwell_ns = core::SecondsToTime(1.0);
  ConsensusSelector two(Sensors(2), options);
  EXPECT_EQ(SwitchesOver(two, LocalPingPong, 20), 0);
  EXPECT_EQ(two.fused(), Names{"S1"});
  // Four sensors: S1 fails (S2 taken at once), then S2 fails (S3 taken at once, S1 not yet
  // re-admitted); from then on neither S1 nor S2 is consistent for 1 s in a row.
  ConsensusSelector four(Sensors(4), options);
  EXPECT_EQ(SwitchesOver(four, CrossPingPong, 20), 2);
  EXPECT_EQ(four.fused(), Names{"S3"});
}

TEST(ConsensusSelectorDwell, NoSwitchForPreferenceWithinTheDwell) {
  // t0: all agree, S1 fused. Then S1's values become unknown (not faulty): the paper policy
  // moves to the most consistent pair S2-S3 at once; with a 0.5 s dwell only after 0.5 s.
  const Matrix unknown_s1 = Matrix(3).Row(1, std::nullopt).Pair(2, 3, 0.02);
  ConsensusSelector paper(Sensors(3));
  Decide(paper, Matrix(3).At(0));
  EXPECT_EQ(Decide(paper, unknown_s1.At(kStep)).fused, Names{"S2"});

  ConsensusOptions options;
  options.min_dwell_ns = 5 * kStep;
  ConsensusSelector selector(Sensors(3), options);
  ASSERT_EQ(Decide(selector, Matrix(3).At(0)).fused, Names{"S1"});
  for (int k = 1; k <= 4; ++k) {
    const ConsensusDecision d = Decide(selector, unknown_s1.At(k * kStep));
    EXPECT_EQ(d.fused, Names{"S1"}) << "k=" << k << " " << d.reason;
    if (k == 1) {
      EXPECT_TRUE(Contains(d.reason, "holding S1 (dwell 0.10 of 0.50 s)")) << d.reason;
    }
  }
  const ConsensusDecision after = Decide(selector, unknown_s1.At(5 * kStep));
  EXPECT_EQ(after.fused, Names{"S2"}) << after.reason;
  EXPECT_EQ(selector.switches(), 1);
}

TEST(ConsensusSelectorDwell, DegenerateTieBreakIsHeldWithinTheDwell) {
  // Both inconsistent with local, S2 closer: the paper switches; within the dwell the fused
  // S1 is held and S2 (inconsistent with it) stays excluded.
  const Matrix both_bad = Matrix(2, 0.3).Local(1, 0.3).Local(2, 0.2);
  ConsensusSelector paper(Sensors(2));
  Decide(paper, Matrix(2, 0.05).At(0));
  EXPECT_EQ(Decide(paper, both_bad.At(kStep)).fused, Names{"S2"});

  ConsensusOptions options;
  options.min_dwell_ns = core::SecondsToTime(1.0);
  ConsensusSelector selector(Sensors(2), options);
  Decide(selector, Matrix(2, 0.05).At(0));
  const ConsensusDecision d = Decide(selector, both_bad.At(kStep));
  EXPECT_EQ(d.fused, Names{"S1"}) << d.reason;
  EXPECT_EQ(d.excluded, Names{"S2"}) << d.reason;
  EXPECT_TRUE(Contains(d.reason, "holding S1")) << d.reason;
}

TEST(ConsensusSelectorDwell, FaultyOrUnavailableFusedSensorIsDroppedAtOnce) {
  ConsensusOptions options;
  options.min_dwell_ns = core::SecondsToTime(10.0);
  ConsensusSelector selector(Sensors(4), options);
  ASSERT_EQ(Decide(selector, Matrix(4).At(0)).fused, Names{"S1"});
  // 0.1 s into a 10 s dwell, S1 fails: dropped now.
  const ConsensusDecision faulty = Decide(selector, Matrix(4).Row(1, 0.5).At(kStep));
  EXPECT_EQ(faulty.fused, Names{"S2"}) << faulty.reason;
  EXPECT_EQ(faulty.excluded, Names{"S1"}) << faulty.reason;
  // S2 stops delivering: dropped now too; S1 is healthy again but waits for its dwell.
  const ConsensusDecision gone = Decide(selector, Matrix(4).Unavailable(2).At(2 * kStep));
  EXPECT_EQ(gone.fused, Names{"S3"}) << gone.reason;
  EXPECT_EQ(gone.excluded, Names{"S1"}) << gone.reason;
  EXPECT_TRUE(Contains(gone.reason, "S2 unavailable")) << gone.reason;
  EXPECT_TRUE(Contains(gone.reason, "S1 awaiting re-admission")) << gone.reason;
  EXPECT_EQ(selector.switches(), 2);
}

TEST(ConsensusSelectorDwell, ExcludedSensorIsReadmittedAfterDwellWithoutInterruption) {
  // S4 fails over steps 1-3 and is healthy from step 4 on, except a blip at step 6 in the
  // interrupted run.
  auto input = [](int k, bool blip) {
    Matrix m(4);
    if ((k >= 1 && k <= 3) || (blip && k == 6)) m.Row(4, 0.5);
    return m.At(k * kStep);
  };
  auto excluded_s4 = [](const ConsensusDecision& d) {
    return d.excluded == Names{"S4"};
  };
  ConsensusSelector paper(Sensors(4));
  for (int k = 0; k <= 3; ++k) Decide(paper, input(k, false));
  EXPECT_TRUE(Decide(paper, input(4, false)).excluded.empty());  // paper: back at once

  ConsensusOptions options;
  options.min_dwell_ns = 5 * kStep;
  ConsensusSelector steady(Sensors(4), options);
  for (int k = 0; k <= 12; ++k) {
    const ConsensusDecision d = Decide(steady, input(k, false));
    // Consistent since step 4: 0.5 s reached at step 9.
    EXPECT_EQ(excluded_s4(d), k >= 1 && k <= 8) << "k=" << k << " " << d.reason;
    if (k == 9) {
      EXPECT_TRUE(Contains(d.reason, "S4 re-admitted")) << d.reason;
    }
  }
  ConsensusSelector interrupted(Sensors(4), options);
  for (int k = 0; k <= 14; ++k) {
    const ConsensusDecision d = Decide(interrupted, input(k, true));
    // The blip at step 6 restarts the clock at step 7: re-admitted at step 12.
    EXPECT_EQ(excluded_s4(d), k >= 1 && k <= 11) << "k=" << k << " " << d.reason;
  }
  EXPECT_EQ(interrupted.fused(), Names{"S1"});
  EXPECT_EQ(interrupted.switches(), 0);
}

// ---- priority ----

TEST(ConsensusSelector, PriorityOrderIsRespected) {
  // Most consistent pair S2-S3.
  const Matrix m = Matrix(4, 0.05).Pair(2, 3, 0.01);
  ConsensusSelector by_order(Sensors(4));
  EXPECT_EQ(Decide(by_order, m.At(0)).fused, Names{"S2"});
  ConsensusSelector s3_first(Sensors(4), WithPriority({"S3"}));
  EXPECT_EQ(Decide(s3_first, m.At(0)).fused, Names{"S3"});
  ConsensusSelector s4_s2(Sensors(4), WithPriority({"S4", "S2"}));
  EXPECT_EQ(Decide(s4_s2, m.At(0)).fused, Names{"S2"});
  // Unlisted sensors come after the listed ones, in constructor order: pair S1-S3 with
  // only S4 listed gives S1; with S3 listed, S3.
  const Matrix m13 = Matrix(4, 0.05).Pair(1, 3, 0.01);
  ConsensusSelector only_s4(Sensors(4), WithPriority({"S4"}));
  EXPECT_EQ(Decide(only_s4, m13.At(0)).fused, Names{"S1"});
  ConsensusSelector s3_s1(Sensors(4), WithPriority({"S4", "S3", "S1"}));
  EXPECT_EQ(Decide(s3_s1, m13.At(0)).fused, Names{"S3"});
}

// ---- largest consistent set ----

TEST(ConsensusSelectorLargestSet, PicksTheThreeSetOverTheMostConsistentPair) {
  // {S1 S2 S3} agree (0.06-0.08); S4-S5 agree best (0.01) but each disagrees with two of
  // the three (no cross: 2 of 4 is no strict majority), so no 3-set contains them.
  const Matrix m = Matrix(5, 0.05)
                       .Pair(1, 2, 0.06)
                       .Pair(1, 3, 0.07)
                       .Pair(2, 3, 0.08)
                       .Pair(4, 5, 0.01)
                       .Pair(2, 4, 0.5)
                       .Pair(3, 4, 0.5)
                       .Pair(1, 5, 0.5)
                       .Pair(3, 5, 0.5);
  ConsensusSelector paper(Sensors(5), WithPriority({"S5", "S4"}));
  const ConsensusDecision p = Decide(paper, m.At(0));
  EXPECT_EQ(p.fused, Names{"S5"}) << p.reason;
  EXPECT_TRUE(p.excluded.empty()) << p.reason;

  ConsensusOptions options = WithPriority({"S3", "S5", "S4"});
  options.policy = ConsensusPolicy::kConsistentSet;
  ConsensusSelector largest(Sensors(5), options);
  const ConsensusDecision d = Decide(largest, m.At(0));
  EXPECT_EQ(d.fused, (Names{"S3", "S1", "S2"})) << d.reason;  // by priority
  EXPECT_TRUE(d.excluded.empty()) << d.reason;
  EXPECT_TRUE(Contains(d.reason, "largest consistent set S3+S1+S2 (3 sensors; sum 0.210)"))
      << d.reason;
}

TEST(ConsensusSelectorLargestSet, ExcludesTheCrossAndFusesTheRest) {
  // Issue 16 (consistent_set): three healthy sensors are fused, the fourth, inconsistent
  // with all of them, is not.
  ConsensusOptions options;
  options.policy = ConsensusPolicy::kConsistentSet;
  ConsensusSelector selector(Sensors(4), options);
  const ConsensusDecision d = Decide(selector, Matrix(4).Row(4, 0.5).At(0));
  EXPECT_EQ(d.fused, (Names{"S1", "S2", "S3"})) << d.reason;
  EXPECT_EQ(d.excluded, Names{"S4"}) << d.reason;
  EXPECT_EQ(d.inconsistent, Names{"S4"}) << d.reason;
}

// ---- return to recovered sensors (issue 16) ----

// S1 is preferred but unavailable at first (e.g. its alignment not yet known): S2 of the
// pair S2-S3 is fused. When S1 comes back consistent, pair_member returns to it; the
// paper's rule (return_to_priority off) keeps S2 for as long as S2 stays consistent.
TEST(ConsensusSelectorReturn, ThePreferredSensorIsFusedAgainOnceItHasRecovered) {
  for (const bool return_to_priority : {true, false}) {
    SCOPED_TRACE(return_to_priority);
    ConsensusOptions options = WithPriority({"S1", "S2", "S3"});
    options.return_to_priority = return_to_priority;
    ConsensusSelector selector(Sensors(3), options);
    const ConsensusDecision first = Decide(selector, Matrix(3).Unavailable(1).At(0));
    EXPECT_EQ(first.fused, Names{"S2"}) << first.reason;
    const ConsensusDecision back = Decide(selector, Matrix(3).At(100));
    if (return_to_priority) {
      EXPECT_EQ(back.fused, Names{"S1"}) << back.reason;
      EXPECT_TRUE(Contains(back.reason, "returning to S1")) << back.reason;
    } else {
      EXPECT_EQ(back.fused, Names{"S2"}) << back.reason;
    }
  }
}

// The return waits for the dwell after the last change and needs a consistent partner.
TEST(ConsensusSelectorReturn, TheReturnRespectsTheDwellAndNeedsAConsistentPartner) {
  ConsensusOptions options = WithPriority({"S1", "S2", "S3"});
  options.min_dwell_ns = 1'000;
  ConsensusSelector selector(Sensors(3), options);
  EXPECT_EQ(Decide(selector, Matrix(3).Unavailable(1).At(0)).fused, Names{"S2"});
  // Back, but within the dwell of the first choice: S2 is held.
  EXPECT_EQ(Decide(selector, Matrix(3).At(500)).fused, Names{"S2"});
  // After the dwell, but S1 agrees with nobody (no cross: S2-S3 agree, and S1 has only
  // unknown values): no return.
  EXPECT_EQ(Decide(selector, Matrix(3).Pair(1, 2, std::nullopt).Pair(1, 3, std::nullopt).At(1'500))
                .fused,
            Names{"S2"});
  EXPECT_EQ(Decide(selector, Matrix(3).At(2'000)).fused, Names{"S1"});
}

// A sensor that is available but not fusable (its alignment is being re-estimated) is
// evidence, not a candidate: it still isolates a faulty sensor by the cross pattern.
TEST(ConsensusSelectorReturn, AnUnfusableSensorIsEvidenceButNotFused) {
  ConsensusInput input = Matrix(3).Row(3, 0.5).At(0);
  input.fusable = {false, true, true};
  ConsensusSelector selector(Sensors(3), WithPriority({"S1", "S2", "S3"}));
  const ConsensusDecision d = Decide(selector, input);
  EXPECT_EQ(d.fused, Names{"S2"}) << d.reason;
  EXPECT_EQ(d.inconsistent, Names{"S3"}) << d.reason;
  EXPECT_EQ(d.eligible, Names{"S2"}) << d.reason;
  input.fusable = {true, true};  // wrong size
  EXPECT_THROW(selector.Decide(input), std::invalid_argument);
}

// `inconsistent` lists what this decision found inconsistent, not a sensor that merely
// waits out its re-admission dwell.
TEST(ConsensusSelectorReturn, AWaitingSensorIsExcludedButNotInconsistent) {
  ConsensusOptions options = WithPriority({"S1", "S2", "S3"});
  options.min_dwell_ns = 1'000;
  ConsensusSelector selector(Sensors(3), options);
  const ConsensusDecision bad = Decide(selector, Matrix(3).Row(3, 0.5).At(0));
  EXPECT_EQ(bad.inconsistent, Names{"S3"}) << bad.reason;
  const ConsensusDecision waiting = Decide(selector, Matrix(3).At(100));
  EXPECT_EQ(waiting.excluded, Names{"S3"}) << waiting.reason;
  EXPECT_TRUE(waiting.inconsistent.empty()) << waiting.reason;
}

TEST(ConsensusSelectorLargestSet, TwoInconsistentSensorsUseTheLocalTieBreak) {
  ConsensusOptions options;
  options.policy = ConsensusPolicy::kConsistentSet;
  ConsensusSelector selector(Sensors(2), options);
  const ConsensusDecision d = Decide(selector, Matrix(2, 0.4).Local(1, 0.3).Local(2, 0.04).At(0));
  EXPECT_EQ(d.fused, Names{"S2"}) << d.reason;
  EXPECT_EQ(d.excluded, Names{"S1"}) << d.reason;
}

// ---- options and input checks ----

TEST(ConsensusSelector, PolicyNamesRoundTrip) {
  EXPECT_EQ(ConsensusPolicyName(ConsensusPolicy::kPairMember), "pair_member");
  EXPECT_EQ(ConsensusPolicyName(ConsensusPolicy::kConsistentSet), "consistent_set");
  EXPECT_EQ(ConsensusPolicyFromName("pair_member"), ConsensusPolicy::kPairMember);
  EXPECT_EQ(ConsensusPolicyFromName("consistent_set"), ConsensusPolicy::kConsistentSet);
  EXPECT_EQ(ConsensusPolicyFromName("Paper"), std::nullopt);
  EXPECT_EQ(ConsensusPolicyFromName(""), std::nullopt);
}

TEST(ConsensusSelector, InvalidOptionsAreRejectedWithTheBrokenConstraint) {
  auto why_invalid = [](const ConsensusOptions& options) {
    std::string why;
    EXPECT_FALSE(options.IsValid(&why));
    EXPECT_THROW(ConsensusSelector(Sensors(2), options), std::invalid_argument);
    return why;
  };
  EXPECT_TRUE(ConsensusOptions{}.IsValid());
  ConsensusOptions o;
  o.threshold = 0.0;
  EXPECT_TRUE(Contains(why_invalid(o), "threshold"));
  o.threshold = std::numeric_limits<double>::quiet_NaN();
  EXPECT_TRUE(Contains(why_invalid(o), "threshold"));
  o = {};
  o.leave_threshold = 0.05;
  EXPECT_TRUE(Contains(why_invalid(o), "leave_threshold"));
  o.leave_threshold = std::numeric_limits<double>::infinity();
  EXPECT_TRUE(Contains(why_invalid(o), "leave_threshold"));
  o = {};
  o.min_dwell_ns = -1;
  EXPECT_TRUE(Contains(why_invalid(o), "min_dwell_ns"));
  o = {};
  o.priority = {"S1", "S1"};
  EXPECT_TRUE(Contains(why_invalid(o), "twice"));
  o.priority = {""};
  EXPECT_TRUE(Contains(why_invalid(o), "priority"));
  // Valid options, but a priority name that is not a sensor.
  EXPECT_THROW(ConsensusSelector(Sensors(2), WithPriority({"S3"})), std::invalid_argument);
  // Sensor names.
  EXPECT_THROW(ConsensusSelector(Names{"S1", ""}), std::invalid_argument);
  EXPECT_THROW(ConsensusSelector(Names{"S1", "S2", "S1"}), std::invalid_argument);
  ConsensusOptions largest;
  largest.policy = ConsensusPolicy::kConsistentSet;
  EXPECT_THROW(ConsensusSelector(Sensors(ConsensusSelector::kMaxSensorsLargestSet + 1), largest),
               std::invalid_argument);
  EXPECT_NO_THROW(ConsensusSelector(Sensors(ConsensusSelector::kMaxSensorsLargestSet), largest));
}

TEST(ConsensusSelector, SizeMismatchAndTimeGoingBackThrow) {
  ConsensusSelector selector(Sensors(3));
  const ConsensusInput good = Matrix(3).At(kStep);
  ConsensusInput input = good;
  input.available.pop_back();
  EXPECT_THROW(selector.Decide(input), std::invalid_argument);
  input = good;
  input.pair.push_back(0.05);
  EXPECT_THROW(selector.Decide(input), std::invalid_argument);
  input = good;
  input.vs_local.pop_back();
  EXPECT_THROW(selector.Decide(input), std::invalid_argument);
  // Nothing was decided by the failed calls.
  EXPECT_TRUE(selector.fused().empty());
  EXPECT_NO_THROW(selector.Decide(good));
  EXPECT_THROW(selector.Decide(Matrix(3).At(0)), std::invalid_argument);
  EXPECT_NO_THROW(selector.Decide(good));  // same time again is fine
}

}  // namespace
}  // namespace tofu::estimator
