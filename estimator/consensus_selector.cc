#include "estimator/consensus_selector.h"

#include <algorithm>
#include <bit>
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <cstdio>
#include <limits>
#include <stdexcept>
#include <utility>

#include "estimator/consistency_matrix.h"

namespace tofu::estimator {
namespace {

// What the values say about a pair of sensors.
enum class Relation : uint8_t { kUnknown, kConsistent, kInconsistent };
// What the value against the local estimate says about one sensor (order = preference).
enum class LocalTier : uint8_t { kConsistent = 0, kUnknown = 1, kInconsistent = 2 };

std::string Num(double value) {
  char buffer[32];
  std::snprintf(buffer, sizeof(buffer), "%.3f", value);
  return buffer;
}

std::string Seconds(core::Time t_ns) {
  char buffer[32];
  std::snprintf(buffer, sizeof(buffer), "%.2f", core::TimeToSeconds(t_ns));
  return buffer;
}

// One decision's input, judged once: values cleaned, pairs and local values classified.
struct Snapshot {
  int n = 0;
  std::vector<bool> available;
  std::vector<std::optional<double>> value;  // n*n, symmetric; nullopt also off-diagonal
  std::vector<Relation> rel;                 // n*n, by the pair rule (hysteresis applied)
  std::vector<bool> biased;                  // n*n: inconsistent whatever the value
  std::vector<std::optional<double>> local;  // n
  std::vector<LocalTier> tier;               // n

  const std::optional<double>& Value(int i, int j) const {
    return value[static_cast<std::size_t>(i * n + j)];
  }
  Relation Rel(int i, int j) const { return rel[static_cast<std::size_t>(i * n + j)]; }
  bool Biased(int i, int j) const { return biased[static_cast<std::size_t>(i * n + j)]; }
  bool Available(int i) const { return available[static_cast<std::size_t>(i)]; }
  LocalTier Tier(int i) const { return tier[static_cast<std::size_t>(i)]; }
  const std::optional<double>& Local(int i) const { return local[static_cast<std::size_t>(i)]; }
};

bool At(const std::vector<bool>& mask, int i) { return mask[static_cast<std::size_t>(i)]; }

// Cross pattern (paper Fig. "consensus"): peel off, worst first, sensors that are
// inconsistent with a strict majority of the remaining sensors with known values, while
// at least 3 remain; keep the exclusion only if what remains is mostly consistent.
std::vector<bool> CrossPattern(const Snapshot& s, const std::vector<int>& rank) {
  const int n = s.n;
  std::vector<bool> excluded(static_cast<std::size_t>(n), false);
  std::vector<bool> active = s.available;
  int active_count = static_cast<int>(std::count(active.begin(), active.end(), true));

  struct Score {
    int known = 0;
    int bad = 0;
    double local = -1.0;  // unknown ranks lowest
    double sum = 0.0;
    int rank = 0;
  };
  // True when a is the worse offender (peeled first).
  auto worse = [](const Score& a, const Score& b) {
    const int64_t lhs = int64_t{a.bad} * b.known;  // a.bad / a.known vs b.bad / b.known
    const int64_t rhs = int64_t{b.bad} * a.known;
    if (lhs != rhs) return lhs > rhs;
    if (a.bad != b.bad) return a.bad > b.bad;
    if (a.local != b.local) return a.local > b.local;
    if (a.sum != b.sum) return a.sum > b.sum;
    return a.rank > b.rank;
  };

  std::vector<int> peeled;
  while (active_count >= 3) {
    int worst = -1;
    Score worst_score;
    for (int i = 0; i < n; ++i) {
      if (!At(active, i)) continue;
      Score score;
      score.local = s.Local(i).value_or(-1.0);
      score.rank = rank[static_cast<std::size_t>(i)];
      for (int j = 0; j < n; ++j) {
        if (j == i || !At(active, j) || s.Rel(i, j) == Relation::kUnknown) continue;
        ++score.known;
        if (s.Rel(i, j) == Relation::kInconsistent) ++score.bad;
        score.sum += *s.Value(i, j);
      }
      if (score.known == 0 || 2 * score.bad <= score.known) continue;
      if (worst < 0 || worse(score, worst_score)) {
        worst = i;
        worst_score = score;
      }
    }
    if (worst < 0) break;
    active[static_cast<std::size_t>(worst)] = false;
    --active_count;
    peeled.push_back(worst);
  }
  if (peeled.empty()) return excluded;

  // The sensors left must agree among themselves, else there is no consensus to trust.
  int consistent = 0;
  int inconsistent = 0;
  for (int i = 0; i < n; ++i) {
    for (int j = i + 1; j < n; ++j) {
      if (!At(active, i) || !At(active, j)) continue;
      if (s.Rel(i, j) == Relation::kConsistent) ++consistent;
      if (s.Rel(i, j) == Relation::kInconsistent) ++inconsistent;
    }
  }
  if (consistent > inconsistent) {
    for (const int p : peeled) excluded[static_cast<std::size_t>(p)] = true;
  }
  return excluded;
}

struct Selection {
  std::vector<bool> fused;
  std::vector<bool> excluded;  // exclusions found by the selection itself
  std::vector<std::string> notes;
};

// Selection among the eligible sensors (available, not excluded); `evidence` = available
// and not cross-excluded (eligible plus those waiting for re-admission).
class Chooser {
 public:
  Chooser(const std::vector<std::string>& names, const std::vector<int>& rank,
          const ConsensusOptions& options, const Snapshot& s, const std::vector<bool>& current,
          const std::vector<bool>& eligible, const std::vector<bool>& evidence, bool hold,
          std::string dwell_note)
      : names_(names),
        rank_(rank),
        options_(options),
        s_(s),
        current_(current),
        eligible_(eligible),
        evidence_(evidence),
        hold_(hold),
        dwell_note_(std::move(dwell_note)) {}

  Selection PairMember() const {
    // The most consistent eligible pair; ties by the better priority of its sensors.
    int bi = -1;
    int bj = -1;
    double best = std::numeric_limits<double>::infinity();
    for (int i = 0; i < s_.n; ++i) {
      for (int j = i + 1; j < s_.n; ++j) {
        if (!At(eligible_, i) || !At(eligible_, j)) continue;
        if (s_.Rel(i, j) != Relation::kConsistent) continue;
        const double v = *s_.Value(i, j);
        if (bi < 0 || v < best || (v == best && PairRank(i, j) < PairRank(bi, bj))) {
          bi = i;
          bj = j;
          best = v;
        }
      }
    }
    if (bi < 0) return Fallback();

    Selection out = Empty();
    out.notes.push_back("most consistent pair " + Name(bi) + "-" + Name(bj) + " (" + Num(best) +
                        ")");
    // Return to the preferred sensor (beyond the paper): once a sensor earlier in the
    // priority list than the fused one is eligible again and confirmed by a consistent
    // partner, it replaces the fused one (outside the dwell). Without it, a sensor fused
    // while the preferred one was excluded or unaligned is kept for the rest of the flight
    // as long as it stays consistent, however much more accurate the preferred one is.
    if (options_.return_to_priority && !hold_ && CountOf(current_) > 0) {
      const std::vector<int> fused = ByRank(current_);
      for (const int p : ByRank(eligible_)) {
        if (Rank(p) >= Rank(fused.front())) break;
        const int partner = BestPartner(p);
        if (partner < 0) continue;
        Fuse(out, p);
        out.notes.push_back("returning to " + Name(p) + " (preferred; consistent with " +
                            Name(partner) + " " + Num(*s_.Value(p, partner)) + ")");
        return out;
      }
    }
    // Keep the fused sensor while it is in a consistent eligible pair (no needless switch).
    for (const int f : ByRank(current_)) {
      if (!At(eligible_, f)) continue;
      const int partner = BestPartner(f);
      if (partner < 0) continue;
      Fuse(out, f);
      out.notes.push_back("keeping " + Name(f) + " (consistent with " + Name(partner) + " " +
                          Num(*s_.Value(f, partner)) + ")");
      return out;
    }
    if (hold_) {
      for (const int f : ByRank(current_)) {
        if (!At(eligible_, f)) continue;
        Fuse(out, f);
        out.notes.push_back("holding " + Name(f) + " " + dwell_note_);
        return out;
      }
    }
    const int winner = Rank(bi) < Rank(bj) ? bi : bj;
    Fuse(out, winner);
    out.notes.push_back("fusing " + Name(winner) + " by priority");
    return out;
  }

  // Long by design: the consistent-set rule (dwell, eligibility, agreement, the set and its
  // tie-breaks) as the seed paper states it, one decision.
  Selection ConsistentSet() const {
    // Within the dwell: keep what is still eligible and still agrees.
    if (hold_) {
      std::vector<int> keep;
      for (int i = 0; i < s_.n; ++i) {
        if (At(current_, i) && At(eligible_, i)) keep.push_back(i);
      }
      bool agree = !keep.empty();
      for (const int a : keep) {
        for (const int b : keep) {
          if (a != b && s_.Rel(a, b) == Relation::kInconsistent) agree = false;
        }
      }
      if (agree) {
        Selection out = Empty();
        for (const int i : keep) Fuse(out, i);
        out.notes.push_back("holding " + JoinNames(keep) + " " + dwell_note_);
        return out;
      }
    }

    // Enumerate subsets of the eligible sensors with bit masks over `ids`.
    std::vector<int> ids;
    for (int i = 0; i < s_.n; ++i) {
      if (At(eligible_, i)) ids.push_back(i);
    }
    const int m = static_cast<int>(ids.size());
    std::vector<uint32_t> agrees(static_cast<std::size_t>(m), 0);
    std::vector<uint32_t> disagrees(static_cast<std::size_t>(m), 0);
    for (int a = 0; a < m; ++a) {
      for (int b = 0; b < m; ++b) {
        if (a == b) continue;
        const Relation r = EnterRelation(ids[static_cast<std::size_t>(a)],
                                         ids[static_cast<std::size_t>(b)]);
        if (r == Relation::kConsistent) agrees[static_cast<std::size_t>(a)] |= 1u << b;
        if (r == Relation::kInconsistent) disagrees[static_cast<std::size_t>(a)] |= 1u << b;
      }
    }
    uint32_t best_mask = 0;
    int best_size = 0;
    double best_sum = 0.0;
    std::vector<int> best_ranks;
    for (uint32_t mask = 1; m > 0 && mask < (1u << m); ++mask) {
      const int size = std::popcount(mask);
      if (size < 2 || size < best_size) continue;
      bool valid = true;
      for (int a = 0; a < m && valid; ++a) {
        if ((mask & (1u << a)) == 0) continue;
        valid = (disagrees[static_cast<std::size_t>(a)] & mask) == 0 &&
                (agrees[static_cast<std::size_t>(a)] & mask) != 0;
      }
      if (!valid) continue;
      double sum = 0.0;
      std::vector<int> ranks;
      for (int a = 0; a < m; ++a) {
        if ((mask & (1u << a)) == 0) continue;
        ranks.push_back(Rank(ids[static_cast<std::size_t>(a)]));
        for (int b = a + 1; b < m; ++b) {
          if ((mask & (1u << b)) == 0) continue;
          const auto& v =
              s_.Value(ids[static_cast<std::size_t>(a)], ids[static_cast<std::size_t>(b)]);
          if (v) sum += *v;
        }
      }
      std::sort(ranks.begin(), ranks.end());
      const bool better = size > best_size || sum < best_sum ||
                          (sum == best_sum && ranks < best_ranks);
      if (better) {
        best_mask = mask;
        best_size = size;
        best_sum = sum;
        best_ranks = std::move(ranks);
      }
    }
    if (best_size < 2) return Fallback();

    Selection out = Empty();
    std::vector<int> members;
    for (int a = 0; a < m; ++a) {
      if ((best_mask & (1u << a)) != 0) members.push_back(ids[static_cast<std::size_t>(a)]);
    }
    for (const int i : members) Fuse(out, i);
    out.notes.push_back("largest consistent set " + JoinNames(members) + " (" +
                        std::to_string(best_size) + " sensors; sum " + Num(best_sum) + ")");
    return out;
  }

 private:
  // No consistent eligible pair (or set): the degenerate case if some pair is known,
  // else each sensor alone against the local estimate.
  Selection Fallback() const {
    for (int i = 0; i < s_.n; ++i) {
      if (!At(eligible_, i)) continue;
      for (int j = 0; j < s_.n; ++j) {
        if (j != i && At(evidence_, j) && s_.Rel(i, j) != Relation::kUnknown) {
          return AgainstLocal();
        }
      }
    }
    return PerSensor();
  }

  // Paper: "A faulty sensor will corrupt the local estimate when fused, resulting in both
  // sensors being inconsistent compared to the local estimate. Conversely, when a healthy
  // sensor is fused, it will remain consistent with the local estimate."
  Selection AgainstLocal() const {
    Selection out = Empty();
    out.notes.push_back(DescribeDisagreement());

    auto local_less = [this](int a, int b) {  // smaller local value, then priority
      const double va = s_.Local(a).value_or(std::numeric_limits<double>::infinity());
      const double vb = s_.Local(b).value_or(std::numeric_limits<double>::infinity());
      if (va != vb) return va < vb;
      return Rank(a) < Rank(b);
    };
    auto best_of = [&](auto&& keep_if) {
      int best = -1;
      for (int i = 0; i < s_.n; ++i) {
        if (!At(eligible_, i) || !keep_if(i)) continue;
        if (best < 0 || s_.Tier(i) < s_.Tier(best) ||
            (s_.Tier(i) == s_.Tier(best) && local_less(i, best))) {
          best = i;
        }
      }
      return best;
    };
    const int fused_now = best_of([this](int i) { return At(current_, i); });

    int winner = -1;
    std::string why;
    if (const int f = best_of([this](int i) {
          return At(current_, i) && s_.Tier(i) != LocalTier::kInconsistent;
        });
        f >= 0) {
      // 1. The fused sensor still agrees with the local estimate (or nothing says not).
      winner = f;
      why = "keeping " + Name(f) + " (" + LocalText(f) + OthersLocalText(f) + ")";
    } else if (const int c =
                   best_of([this](int i) { return s_.Tier(i) == LocalTier::kConsistent; });
               c >= 0) {
      // 2. Another sensor agrees with the local estimate: switch at once (safety).
      winner = c;
      why = (fused_now >= 0 ? "switching to " : "fusing ") + Name(c) + " (" + LocalText(c) +
            OthersLocalText(c) + ")";
    } else if (hold_ && fused_now >= 0) {
      // 3. Nobody agrees with the local estimate: within the dwell keep the fused one.
      winner = fused_now;
      why = "holding " + Name(fused_now) + " " + dwell_note_ + " (" + LocalText(fused_now) + ")";
    } else if (const int u = [&] {
                 int best = -1;
                 for (int i = 0; i < s_.n; ++i) {
                   if (At(eligible_, i) && s_.Tier(i) == LocalTier::kUnknown &&
                       (best < 0 || Rank(i) < Rank(best))) {
                     best = i;
                   }
                 }
                 return best;
               }();
               u >= 0) {
      // 4. No local value: priority.
      winner = u;
      why = "fusing " + Name(u) + " by priority (vs local unknown)";
    } else if (const int w = best_of([](int) { return true; }); w >= 0) {
      // 5. All inconsistent with local: the closest one.
      winner = w;
      why = "all inconsistent with local: fusing " + Name(w) + " as the closest (" +
            LocalText(w) + OthersLocalText(w) + ")";
    }
    if (winner < 0) {
      out.notes.push_back("no eligible sensor: IMU only");
      return out;
    }
    Fuse(out, winner);
    out.notes.push_back(why);
    for (int j = 0; j < s_.n; ++j) {
      if (j != winner && At(eligible_, j) && s_.Rel(winner, j) == Relation::kInconsistent) {
        out.excluded[static_cast<std::size_t>(j)] = true;
      }
    }
    return out;
  }

  // No pair evidence: each sensor is judged against the local estimate alone.
  Selection PerSensor() const {
    Selection out = Empty();
    int eligible_count = 0;
    for (int i = 0; i < s_.n; ++i) {
      if (!At(eligible_, i)) continue;
      ++eligible_count;
      if (s_.Tier(i) == LocalTier::kInconsistent) {
        out.excluded[static_cast<std::size_t>(i)] = true;
        out.notes.push_back(Name(i) + " inconsistent with local (" + Num(*s_.Local(i)) + ")");
      }
    }
    auto usable = [&](int i) { return At(eligible_, i) && !At(out.excluded, i); };
    int winner = -1;
    for (const int f : ByRank(current_)) {
      if (usable(f)) {
        winner = f;
        break;
      }
    }
    const bool keeping = winner >= 0;
    for (const LocalTier tier : {LocalTier::kConsistent, LocalTier::kUnknown}) {
      if (winner >= 0) break;
      for (int i = 0; i < s_.n; ++i) {
        if (usable(i) && s_.Tier(i) == tier && (winner < 0 || Rank(i) < Rank(winner))) {
          winner = i;
        }
      }
    }
    if (winner < 0) {
      out.notes.push_back(eligible_count == 0 ? "no eligible sensor: IMU only" : "IMU only");
      return out;
    }
    Fuse(out, winner);
    const std::string context = eligible_count == 1 && CountOf(evidence_) == 1
                                    ? "only available sensor"
                                    : "no pair values";
    out.notes.push_back((keeping ? "keeping " : "fusing ") + Name(winner) + " (" + context +
                        "; " + LocalText(winner) + ")");
    return out;
  }

  // "S1-S2 inconsistent (0.300)" for one known pair, else a count.
  std::string DescribeDisagreement() const {
    int known = 0;
    int last_i = -1;
    int last_j = -1;
    int sensors = 0;
    for (int i = 0; i < s_.n; ++i) {
      if (!At(evidence_, i)) continue;
      ++sensors;
      for (int j = i + 1; j < s_.n; ++j) {
        if (!At(evidence_, j) || s_.Rel(i, j) == Relation::kUnknown) continue;
        ++known;
        last_i = i;
        last_j = j;
      }
    }
    if (known == 1) {
      return Name(last_i) + "-" + Name(last_j) +
             (s_.Rel(last_i, last_j) == Relation::kInconsistent ? " inconsistent (" :
                                                                   " consistent (") +
             Num(*s_.Value(last_i, last_j)) + ")";
    }
    return "no consistent eligible pair among " + std::to_string(sensors) + " sensors";
  }

  // "consistent with local 0.040" / "inconsistent with local 0.250" / "vs local unknown".
  std::string LocalText(int i) const {
    switch (s_.Tier(i)) {
      case LocalTier::kConsistent:
        return "consistent with local " + Num(*s_.Local(i));
      case LocalTier::kInconsistent:
        return "inconsistent with local " + Num(*s_.Local(i));
      case LocalTier::kUnknown:
        break;
    }
    return "vs local unknown";
  }

  // " / S2 inconsistent with local 0.250" for the other eligible sensors.
  std::string OthersLocalText(int winner) const {
    std::string text;
    for (int j = 0; j < s_.n; ++j) {
      if (j == winner || !At(eligible_, j)) continue;
      text += " / " + Name(j) + " " + LocalText(j);
    }
    return text;
  }

  // Pair judgement for joining a fused set: leave_threshold only between two sensors
  // that are both fused now; a newcomer must get below `threshold`.
  Relation EnterRelation(int i, int j) const {
    const auto& v = s_.Value(i, j);
    if (!v) return Relation::kUnknown;
    const bool both_fused = At(current_, i) && At(current_, j);
    const double limit = options_.leave_threshold && both_fused ? *options_.leave_threshold
                                                                : options_.threshold;
    return *v < limit && !s_.Biased(i, j) ? Relation::kConsistent : Relation::kInconsistent;
  }

  // The eligible sensor consistent with f with the smallest value, or -1.
  int BestPartner(int f) const {
    int partner = -1;
    for (int j = 0; j < s_.n; ++j) {
      if (j == f || !At(eligible_, j) || s_.Rel(f, j) != Relation::kConsistent) continue;
      if (partner < 0 || *s_.Value(f, j) < *s_.Value(f, partner)) partner = j;
    }
    return partner;
  }

  Selection Empty() const {
    Selection out;
    out.fused.assign(static_cast<std::size_t>(s_.n), false);
    out.excluded.assign(static_cast<std::size_t>(s_.n), false);
    return out;
  }
  static void Fuse(Selection& out, int i) { out.fused[static_cast<std::size_t>(i)] = true; }
  static int CountOf(const std::vector<bool>& mask) {
    return static_cast<int>(std::count(mask.begin(), mask.end(), true));
  }
  std::vector<int> ByRank(const std::vector<bool>& mask) const {
    std::vector<int> members;
    for (int i = 0; i < s_.n; ++i) {
      if (At(mask, i)) members.push_back(i);
    }
    std::sort(members.begin(), members.end(), [this](int a, int b) { return Rank(a) < Rank(b); });
    return members;
  }
  std::string JoinNames(std::vector<int> members) const {
    std::sort(members.begin(), members.end(), [this](int a, int b) { return Rank(a) < Rank(b); });
    std::string text;
    for (const int i : members) text += (text.empty() ? "" : "+") + Name(i);
    return text;
  }
  int Rank(int i) const { return rank_[static_cast<std::size_t>(i)]; }
  int PairRank(int i, int j) const { return std::min(Rank(i), Rank(j)); }
  const std::string& Name(int i) const { return names_[static_cast<std::size_t>(i)]; }

  const std::vector<std::string>& names_;
  const std::vector<int>& rank_;
  const ConsensusOptions& options_;
  const Snapshot& s_;
  const std::vector<bool>& current_;
  const std::vector<bool>& eligible_;
  const std::vector<bool>& evidence_;
  bool hold_;
  std::string dwell_note_;
};

// The reason goes into a CSV cell: one line, no commas.
std::string Sanitize(std::string text) {
  for (char& c : text) {
    if (c == ',' || c == '\n' || c == '\r') c = ' ';
  }
  return text;
}

}  // namespace

std::string_view ConsensusPolicyName(ConsensusPolicy policy) {
  switch (policy) {
    case ConsensusPolicy::kPairMember:
      return "pair_member";
    case ConsensusPolicy::kConsistentSet:
      return "consistent_set";
  }
  return "unknown";
}

std::optional<ConsensusPolicy> ConsensusPolicyFromName(std::string_view name) {
  for (const ConsensusPolicy policy :
       {ConsensusPolicy::kPairMember, ConsensusPolicy::kConsistentSet}) {
    if (name == ConsensusPolicyName(policy)) return policy;
  }
  return std::nullopt;
}

bool ConsensusOptions::IsValid(std::string* why) const {
  auto fail = [why](std::string message) {
    if (why != nullptr) *why = std::move(message);
    return false;
  };
  if (!std::isfinite(threshold) || !(threshold > 0.0)) {
    return fail("threshold must be positive and finite");
  }
  if (leave_threshold && (!std::isfinite(*leave_threshold) || *leave_threshold < threshold)) {
    return fail("leave_threshold must be finite and >= threshold");
  }
  if (min_dwell_ns < 0) return fail("min_dwell_ns must be >= 0");
  if (policy != ConsensusPolicy::kPairMember && policy != ConsensusPolicy::kConsistentSet) {
    return fail("policy is not a known ConsensusPolicy");
  }
  for (std::size_t k = 0; k < priority.size(); ++k) {
    if (priority[k].empty()) return fail("priority names must not be empty");
    for (std::size_t r = 0; r < k; ++r) {
      if (priority[r] == priority[k]) return fail("priority lists '" + priority[k] + "' twice");
    }
  }
  return true;
}

ConsensusSelector::ConsensusSelector(std::vector<std::string> sensors, ConsensusOptions options)
    : sensors_(std::move(sensors)), options_(std::move(options)) {
  std::string why;
  if (!options_.IsValid(&why)) throw std::invalid_argument("ConsensusOptions: " + why);
  const std::size_t n = sensors_.size();
  for (std::size_t s = 0; s < n; ++s) {
    if (sensors_[s].empty()) throw std::invalid_argument("ConsensusSelector: empty sensor name");
    for (std::size_t r = 0; r < s; ++r) {
      if (sensors_[r] == sensors_[s]) {
        throw std::invalid_argument("ConsensusSelector: repeated sensor name '" + sensors_[s] +
                                    "'");
      }
    }
  }
  if (options_.policy == ConsensusPolicy::kConsistentSet &&
      n > static_cast<std::size_t>(kMaxSensorsLargestSet)) {
    throw std::invalid_argument("ConsensusSelector: the consistent_set policy takes at most " +
                                std::to_string(kMaxSensorsLargestSet) + " sensors");
  }
  // Priority ranks: listed names first, the rest in constructor order.
  rank_.assign(n, -1);
  int next = 0;
  for (const std::string& name : options_.priority) {
    const auto it = std::find(sensors_.begin(), sensors_.end(), name);
    if (it == sensors_.end()) {
      throw std::invalid_argument("ConsensusOptions: priority name '" + name +
                                  "' is not a sensor");
    }
    rank_[static_cast<std::size_t>(it - sensors_.begin())] = next++;
  }
  for (int& r : rank_) {
    if (r < 0) r = next++;
  }
  fused_mask_.assign(n, false);
  quarantined_.assign(n, false);
  clean_since_ns_.assign(n, std::nullopt);
}

namespace {

void CheckDecideInput(const ConsensusInput& input, int n) {
  const auto un = static_cast<std::size_t>(n);
  if (input.available.size() != un || input.vs_local.size() != un ||
      (!input.fusable.empty() && input.fusable.size() != un) ||
      input.pair.size() != un * (un - (n > 0 ? 1 : 0)) / 2 ||
      (!input.pair_biased.empty() && input.pair_biased.size() != input.pair.size())) {
    throw std::invalid_argument("ConsensusSelector::Decide: " + std::to_string(n) +
                                " sensors need available[" + std::to_string(n) + "] pair[" +
                                std::to_string(n * (n - 1) / 2) + "] vs_local[" +
                                std::to_string(n) + "]; got " +
                                std::to_string(input.available.size()) + " " +
                                std::to_string(input.pair.size()) + " " +
                                std::to_string(input.vs_local.size()));
  }
}

// Every value judged once against the thresholds, with hysteresis: a pair with a fused
// member, or a fused sensor against the local graph, is judged against `leave` (the
// paper's single threshold when leave_threshold is unset). A NaN, infinite or negative
// value counts as unknown (and in `ignored_values`).
Snapshot Judge(const ConsensusInput& input, const std::vector<bool>& fused_mask, double enter,
               double leave, int64_t* ignored_values) {
  const int n = static_cast<int>(input.available.size());
  const auto un = static_cast<std::size_t>(n);
  const auto clean = [&](const std::optional<double>& v) -> std::optional<double> {
    if (!v) return std::nullopt;
    if (!std::isfinite(*v) || *v < 0.0) {
      ++*ignored_values;
      return std::nullopt;
    }
    return v;
  };
  Snapshot s;
  s.n = n;
  s.available = input.available;
  s.value.assign(un * un, std::nullopt);
  s.rel.assign(un * un, Relation::kUnknown);
  s.biased.assign(un * un, false);
  s.local.assign(un, std::nullopt);
  s.tier.assign(un, LocalTier::kUnknown);
  for (int i = 0; i < n; ++i) {
    const auto ui = static_cast<std::size_t>(i);
    for (int j = i + 1; j < n; ++j) {
      const auto uj = static_cast<std::size_t>(j);
      const auto pair = static_cast<std::size_t>(ConsistencyMatrix::PairIndex(i, j, n));
      const auto v = clean(input.pair[pair]);
      if (!v || !s.available[ui] || !s.available[uj]) continue;
      const bool biased = !input.pair_biased.empty() && input.pair_biased[pair];
      const double limit = fused_mask[ui] || fused_mask[uj] ? leave : enter;
      const Relation r =
          *v < limit && !biased ? Relation::kConsistent : Relation::kInconsistent;
      s.value[ui * un + uj] = s.value[uj * un + ui] = v;
      s.rel[ui * un + uj] = s.rel[uj * un + ui] = r;
      s.biased[ui * un + uj] = s.biased[uj * un + ui] = biased;
    }
    const auto v = clean(input.vs_local[ui]);
    if (!v || !s.available[ui]) continue;
    s.local[ui] = v;
    s.tier[ui] = *v < (fused_mask[ui] ? leave : enter) ? LocalTier::kConsistent
                                                       : LocalTier::kInconsistent;
  }
  return s;
}

// "<sensor> inconsistent with k of m (cross pattern)" for each sensor the cross pattern
// marks (>= 3 available).
void NoteCrossPattern(const Snapshot& s, const std::vector<bool>& cross,
                      const std::vector<std::string>& sensors, std::vector<std::string>& notes) {
  for (int i = 0; i < s.n; ++i) {
    if (!At(cross, i)) continue;
    int known = 0;
    int bad = 0;
    for (int j = 0; j < s.n; ++j) {
      if (j == i || !s.Available(j) || s.Rel(i, j) == Relation::kUnknown) continue;
      ++known;
      if (s.Rel(i, j) == Relation::kInconsistent) ++bad;
    }
    notes.push_back(sensors[static_cast<std::size_t>(i)] + " inconsistent with " +
                    std::to_string(bad) + " of " + std::to_string(known) + " (cross pattern)");
  }
}

// Re-admission dwell: excluded (quarantined) sensors wait for min_dwell of positive
// evidence: consistent with the local graph, or below the entry threshold with an available
// sensor outside the cross pattern. Returns the sensors still waiting.
std::vector<bool> AdvanceReadmission(const Snapshot& s, const std::vector<bool>& cross,
                                     core::Time t, const ConsensusOptions& options,
                                     const std::vector<std::string>& sensors,
                                     std::vector<bool>& quarantined,
                                     std::vector<std::optional<core::Time>>& clean_since_ns,
                                     std::vector<std::string>& notes) {
  const std::size_t un = sensors.size();
  std::vector<bool> waiting(un, false);
  for (int i = 0; i < s.n; ++i) {
    const auto ui = static_cast<std::size_t>(i);
    if (!quarantined[ui]) continue;
    bool evidence = false;
    if (s.Available(i) && !cross[ui]) {
      evidence = s.Tier(i) == LocalTier::kConsistent;
      for (int j = 0; j < s.n && !evidence; ++j) {
        evidence = j != i && s.Available(j) && !At(cross, j) && s.Value(i, j) &&
                   *s.Value(i, j) < options.threshold && !s.Biased(i, j);
      }
    }
    if (!evidence) {
      clean_since_ns[ui].reset();
    } else if (!clean_since_ns[ui]) {
      clean_since_ns[ui] = t;
    }
    if (evidence && t - *clean_since_ns[ui] >= options.min_dwell_ns) {
      quarantined[ui] = false;
      clean_since_ns[ui].reset();
      notes.push_back(sensors[ui] + " re-admitted");
    } else if (s.Available(i) && !cross[ui]) {
      waiting[ui] = true;
      const std::string progress =
          evidence ? "consistent " + Seconds(t - *clean_since_ns[ui]) : "not consistent";
      notes.push_back(sensors[ui] + " awaiting re-admission (" + progress + " of " +
                      Seconds(options.min_dwell_ns) + " s)");
    }
  }
  return waiting;
}

}  // namespace

ConsensusDecision ConsensusSelector::Decide(const ConsensusInput& input) {
  const int n = static_cast<int>(sensors_.size());
  const auto un = static_cast<std::size_t>(n);
  CheckDecideInput(input, n);
  if (last_t_ns_ && input.t_ns < *last_t_ns_) {
    throw std::invalid_argument("ConsensusSelector::Decide: t_ns " + std::to_string(input.t_ns) +
                                " is before the previous decision's " +
                                std::to_string(*last_t_ns_));
  }
  const core::Time t = input.t_ns;
  const bool dwell = options_.min_dwell_ns > 0;
  const Snapshot s = Judge(input, fused_mask_, options_.threshold,
                           options_.leave_threshold.value_or(options_.threshold),
                           &ignored_values_);

  ConsensusDecision decision;
  decision.t_ns = t;
  std::vector<std::string> notes;
  for (int i = 0; i < n; ++i) {
    if (fused_mask_[static_cast<std::size_t>(i)] && !s.Available(i)) {
      notes.push_back(sensors_[static_cast<std::size_t>(i)] + " unavailable");
    }
  }
  const std::vector<bool> cross = CrossPattern(s, rank_);
  NoteCrossPattern(s, cross, sensors_, notes);
  const std::vector<bool> waiting =
      dwell ? AdvanceReadmission(s, cross, t, options_, sensors_, quarantined_, clean_since_ns_,
                                 notes)
            : std::vector<bool>(un, false);

  // ---- selection among the eligible sensors ----
  std::vector<bool> eligible(un, false);
  std::vector<bool> evidence(un, false);
  for (std::size_t i = 0; i < un; ++i) {
    evidence[i] = s.available[i] && !cross[i];
    eligible[i] = evidence[i] && !waiting[i] && (input.fusable.empty() || input.fusable[i]);
  }
  const bool any_fused = std::count(fused_mask_.begin(), fused_mask_.end(), true) > 0;
  const bool hold = dwell && any_fused && last_change_ns_ &&
                    t - *last_change_ns_ < options_.min_dwell_ns;
  const std::string dwell_note =
      hold ? "(dwell " + Seconds(t - *last_change_ns_) + " of " + Seconds(options_.min_dwell_ns) +
                 " s)"
           : "";
  const Chooser chooser(sensors_, rank_, options_, s, fused_mask_, eligible, evidence, hold,
                        dwell_note);
  Selection selection;
  if (std::count(s.available.begin(), s.available.end(), true) == 0) {
    selection.fused.assign(un, false);
    selection.excluded.assign(un, false);
    notes.assign({"all sensors unavailable"});
  } else {
    selection = options_.policy == ConsensusPolicy::kPairMember ? chooser.PairMember()
                                                           : chooser.ConsistentSet();
    for (std::string& note : selection.notes) notes.push_back(std::move(note));
  }
  Conclude(s.available, cross, waiting, eligible, selection.fused, selection.excluded, decision);

  std::string reason;
  for (const std::string& note : notes) reason += (reason.empty() ? "" : "; ") + note;
  decision.reason = Sanitize(reason.empty() ? "no decision" : reason);
  return decision;
}

void ConsensusSelector::Conclude(const std::vector<bool>& available, const std::vector<bool>& cross,
                                 const std::vector<bool>& waiting,
                                 const std::vector<bool>& eligible,
                                 const std::vector<bool>& fused,
                                 const std::vector<bool>& excluded, ConsensusDecision& decision) {
  // The decision's lists, and the state it leaves: quarantine, the fused set, switches.
  const bool dwell = options_.min_dwell_ns > 0;
  std::vector<int> fused_ids;
  for (int i = 0; i < static_cast<int>(sensors_.size()); ++i) {
    const auto ui = static_cast<std::size_t>(i);
    if (fused[ui]) fused_ids.push_back(i);
    if (eligible[ui] && !excluded[ui]) decision.eligible.push_back(sensors_[ui]);
    if (!available[ui]) {
      decision.unavailable.push_back(sensors_[ui]);
    } else if (cross[ui] || waiting[ui] || excluded[ui]) {
      decision.excluded.push_back(sensors_[ui]);
      if (cross[ui] || excluded[ui]) decision.inconsistent.push_back(sensors_[ui]);
      if (dwell && (cross[ui] || excluded[ui])) {
        quarantined_[ui] = true;
        clean_since_ns_[ui].reset();
      }
    }
  }
  std::sort(fused_ids.begin(), fused_ids.end(), [this](int a, int b) {
    return rank_[static_cast<std::size_t>(a)] < rank_[static_cast<std::size_t>(b)];
  });
  for (const int i : fused_ids) decision.fused.push_back(sensors_[static_cast<std::size_t>(i)]);

  decision.changed = fused != fused_mask_;
  if (decision.changed) {
    if (had_fused_) ++switches_;
    last_change_ns_ = decision.t_ns;
  }
  if (!fused_ids.empty()) had_fused_ = true;
  fused_mask_ = fused;
  fused_ = decision.fused;
  last_t_ns_ = decision.t_ns;
}

}  // namespace tofu::estimator
