#include "campaign/compare.h"

#include <algorithm>
#include <cmath>
#include <set>

#include <fmt/format.h>

#include "core/error.h"
#include "core/hash.h"

namespace tofu::campaign {
namespace {

using core::InputError;

// The cells of a campaign by scenario, then seed, and the scenarios in campaign order.
struct Grid {
  std::vector<std::string> scenarios;
  std::map<std::string, std::map<uint64_t, const CellRecord*>> cells;
};

Grid GridOf(const CampaignRecord& campaign) {
  Grid grid;
  for (const CellRecord& c : campaign.cells) {
    if (!grid.cells.contains(c.scenario)) grid.scenarios.push_back(c.scenario);
    grid.cells[c.scenario][c.seed] = &c;
  }
  return grid;
}

std::string SeedList(const std::map<uint64_t, const CellRecord*>& cells) {
  std::string list;
  for (const auto& [seed, cell] : cells) list += fmt::format("{}{}", list.empty() ? "" : ", ", seed);
  return list;
}

// Refuses two campaigns that cannot be compared, naming the cell and what differs.
void RequireComparable(const CampaignRecord& base, const CampaignRecord& now, const Grid& b,
                       const Grid& n, const CompareOptions& options) {
  const std::string where = fmt::format("{} vs {}", base.source.string(), now.source.string());
  if (base.tofu_version != now.tofu_version) {
    throw InputError({where}, "tofu_version",
                     fmt::format("the base was made by tofu {} and the new by tofu {}: "
                                 "re-record the baseline with this tofu",
                                 base.tofu_version, now.tofu_version));
  }
  for (const auto& [metric, version] : base.metric_versions) {
    const auto it = now.metric_versions.find(metric);
    if (it != now.metric_versions.end() && it->second != version) {
      throw InputError({where}, metric,
                       fmt::format("defined by version {} in the base and {} in the new: the "
                                   "values measure different things; re-record the baseline",
                                   version, it->second));
    }
  }
  const std::set<std::string> base_set(b.scenarios.begin(), b.scenarios.end());
  const std::set<std::string> new_set(n.scenarios.begin(), n.scenarios.end());
  for (const std::string& s : base_set) {
    if (!new_set.contains(s)) {
      throw InputError({where}, s, "is in the base's grid and not in the new's (another grid)");
    }
  }
  for (const std::string& s : new_set) {
    if (!base_set.contains(s)) {
      throw InputError({where}, s, "is in the new's grid and not in the base's (another grid)");
    }
  }
  for (const std::string& s : b.scenarios) {
    const auto& bc = b.cells.at(s);
    const auto& nc = n.cells.at(s);
    const std::string& base_hash = bc.begin()->second->scenario_hash;
    const std::string& new_hash = nc.begin()->second->scenario_hash;
    if (base_hash != new_hash) {
      throw InputError({where}, s,
                       fmt::format("its scenario file changed (fnv1a64 {} in the base, {} in the "
                                   "new): the flights are of different scenarios",
                                   base_hash, new_hash));
    }
    if (options.unpaired) continue;
    if (SeedList(bc) != SeedList(nc)) {
      throw InputError({where}, s,
                       fmt::format("has seeds [{}] in the base and [{}] in the new: pairs need "
                                   "the same seeds (--unpaired compares other seed sets)",
                                   SeedList(bc), SeedList(nc)));
    }
  }
}

// The command line's (concrete name, then pattern), then the scenario's (likewise), then
// the table's.
double MinimalEffect(const CompareOptions& options, const std::map<std::string, double>& scenario,
                     const ComparedMetric& metric, const std::string& concrete) {
  for (const std::map<std::string, double>* effects : {&options.minimal_effects, &scenario}) {
    for (const std::string& name : {concrete, metric.Pattern()}) {
      if (const auto it = effects->find(name); it != effects->end()) return it->second;
    }
  }
  return metric.minimal_effect;
}

const std::map<std::string, double>& ScenarioEffects(const CampaignRecord& campaign,
                                                     const std::string& scenario) {
  static const std::map<std::string, double> kNone;
  const auto it = campaign.minimal_effects.find(scenario);
  return it == campaign.minimal_effects.end() ? kNone : it->second;
}

const FlightDigests& DigestsFor(const CellRecord& cell, const ComparedMetric& metric,
                                const std::string& method) {
  static const FlightDigests kNone;
  if (metric.scope == "closed_loop") {
    const auto it = cell.flight_digests.find(method);
    return it == cell.flight_digests.end() ? kNone : it->second;
  }
  return cell.digests;
}

Pairing PairingOf(const FlightDigests& a, const FlightDigests& b) {
  if (!a.samples.empty() && a.samples == b.samples && a.random_streams == b.random_streams) {
    return Pairing::kIdenticalSamples;
  }
  if (!a.random_streams.empty() && a.random_streams == b.random_streams) {
    return Pairing::kCommonRandomNumbers;
  }
  return Pairing::kUnpaired;
}

// One metric's observations, each side, by seed (for --unpaired the sides' own seeds).
struct Observations {
  std::vector<std::pair<uint64_t, const CellRecord*>> base;
  std::vector<std::pair<uint64_t, const CellRecord*>> now;
  bool paired = true;  // base[i] and now[i] are one seed
};

// The value of `name` in a cell on the scale the tests use (log for a ratio), nullopt
// when it has none (or a ratio's is not positive).
std::optional<double> Scaled(const CellRecord& cell, const std::string& name, EffectKind kind) {
  const auto it = cell.values.find(name);
  if (it == cell.values.end() || !std::isfinite(it->second)) return std::nullopt;
  if (kind == EffectKind::kRatio) {
    if (!(it->second > 0.0)) return std::nullopt;
    return std::log(it->second);
  }
  return it->second;
}

std::optional<bool> EventOf(const CellRecord& cell, const std::string& name) {
  const auto it = cell.events.find(name);
  if (it == cell.events.end()) return std::nullopt;
  return it->second;
}

std::optional<double> Raw(const CellRecord& cell, const std::string& name) {
  const auto it = cell.values.find(name);
  if (it == cell.values.end()) return std::nullopt;
  return it->second;
}

// Fills the statistics of a continuous metric. d > 0 means worse (the orientation).
void TestContinuous(CellComparison& c, const Observations& o, const CompareOptions& options) {
  const ComparedMetric& m = *c.metric;
  const bool ratio = m.kind == EffectKind::kRatio;
  const double delta = ratio ? std::log1p(c.minimal_effect) : c.minimal_effect;
  const double worse_sign = m.higher_is_better ? -1.0 : 1.0;
  const uint64_t seed = core::Fnv1a64(c.scenario + "\n" + c.base_name + "\n" + c.new_name);
  const auto back = [ratio](double v) { return ratio ? std::exp(v) : v; };
  std::vector<double> x, y, differences;
  for (const auto& [s, cell] : o.base) {
    if (const auto v = Scaled(*cell, c.base_name, m.kind)) x.push_back(*v);
  }
  for (const auto& [s, cell] : o.now) {
    if (const auto v = Scaled(*cell, c.new_name, m.kind)) y.push_back(*v);
  }
  c.base_count = static_cast<int>(x.size());
  c.new_count = static_cast<int>(y.size());
  if (o.paired) {
    for (size_t i = 0; i < o.base.size(); ++i) {
      const auto a = Scaled(*o.base[i].second, c.base_name, m.kind);
      const auto b = Scaled(*o.now[i].second, c.new_name, m.kind);
      if (a && b) differences.push_back(*b - *a);
    }
    c.pairs = static_cast<int>(differences.size());
    if (differences.empty()) {
      c.note = c.base_count == 0 && c.new_count == 0 ? "no values"
               : c.base_count == 0 || c.new_count == 0 ? "values on one side only"
                                                       : "no seed has a value on both sides";
      return;
    }
    c.effect = back(Median(differences));
    const Interval bootstrap = BootstrapMedianInterval(differences, options.confidence,
                                                       options.bootstrap_resamples, seed);
    c.interval = Interval{back(bootstrap.low), back(bootstrap.high)};
    if (std::all_of(differences.begin(), differences.end(), [](double d) { return d == 0.0; })) {
      c.p_equivalent = 0.0;
      c.note = "identical values";
      return;
    }
    std::vector<double> worse(differences.size()), shifted(differences.size());
    for (size_t i = 0; i < differences.size(); ++i) worse[i] = worse_sign * differences[i];
    const auto shift = [&](double by) {
      for (size_t i = 0; i < worse.size(); ++i) shifted[i] = worse[i] + by;
      return shifted;
    };
    c.p_regressed = WilcoxonSignedRankP(shift(-delta), Alternative::kGreater);
    c.p_improved = WilcoxonSignedRankP(shift(delta), Alternative::kLess);
    c.p_equivalent = std::max(WilcoxonSignedRankP(shift(-delta), Alternative::kLess),
                              WilcoxonSignedRankP(shift(delta), Alternative::kGreater));
    return;
  }
  if (x.empty() || y.empty()) {
    c.note = x.empty() && y.empty() ? "no values" : "values on one side only";
    return;
  }
  c.effect = back(Median(y) - Median(x));
  const Interval bootstrap = BootstrapMedianDifferenceInterval(x, y, options.confidence,
                                                               options.bootstrap_resamples, seed);
  c.interval = Interval{back(bootstrap.low), back(bootstrap.high)};
  // On the worse-is-positive scale: y' = sign * y, x' = sign * x.
  std::vector<double> xw = x, yw(y.size());
  for (double& v : xw) v *= worse_sign;
  const auto shifted = [&](double by) {
    for (size_t k = 0; k < y.size(); ++k) yw[k] = worse_sign * y[k] + by;
    return yw;
  };
  c.p_regressed = MannWhitneyP(xw, shifted(-delta), Alternative::kGreater);
  c.p_improved = MannWhitneyP(xw, shifted(delta), Alternative::kLess);
  c.p_equivalent = std::max(MannWhitneyP(xw, shifted(-delta), Alternative::kLess),
                            MannWhitneyP(xw, shifted(delta), Alternative::kGreater));
}

void TestEvent(CellComparison& c, const Observations& o) {
  for (const auto& [s, cell] : o.base) {
    if (const auto e = EventOf(*cell, c.base_name)) {
      ++c.base_count;
      c.base_events += *e ? 1 : 0;
    }
  }
  for (const auto& [s, cell] : o.now) {
    if (const auto e = EventOf(*cell, c.new_name)) {
      ++c.new_count;
      c.new_events += *e ? 1 : 0;
    }
  }
  if (o.paired) {
    for (size_t i = 0; i < o.base.size(); ++i) {
      const auto a = EventOf(*o.base[i].second, c.base_name);
      const auto b = EventOf(*o.now[i].second, c.new_name);
      if (!a || !b) continue;
      ++c.pairs;
      c.base_only += *a && !*b ? 1 : 0;
      c.new_only += !*a && *b ? 1 : 0;
    }
    if (c.pairs == 0) {
      c.note = "no seed has the outcome on both sides";
      return;
    }
    if (c.base_only + c.new_only == 0) {
      c.p_equivalent = 0.0;
      c.note = c.base_events == 0 ? "never happened" : "the same seeds on both sides";
      return;
    }
    c.p_regressed = McNemarExactP(c.base_only, c.new_only, Alternative::kGreater);
    c.p_improved = McNemarExactP(c.base_only, c.new_only, Alternative::kLess);
    return;
  }
  if (c.base_count == 0 || c.new_count == 0) {
    c.note = "outcome on one side only";
    return;
  }
  if (c.base_events == 0 && c.new_events == 0) {
    c.p_equivalent = 0.0;
    c.note = "never happened";
    return;
  }
  c.p_regressed = FisherExactP(c.base_events, c.base_count, c.new_events, c.new_count,
                               Alternative::kGreater);
  c.p_improved = FisherExactP(c.base_events, c.base_count, c.new_events, c.new_count,
                              Alternative::kLess);
}

void RecordSeeds(CellComparison& c, const Observations& o) {
  const bool event = c.metric->kind == EffectKind::kEvent;
  const auto value = [&](const CellRecord& cell, const std::string& name) -> std::optional<double> {
    if (!event) return Raw(cell, name);
    const auto e = EventOf(cell, name);
    return e ? std::optional<double>(*e ? 1.0 : 0.0) : std::nullopt;
  };
  if (o.paired) {
    for (size_t i = 0; i < o.base.size(); ++i) {
      c.seeds.push_back({o.base[i].first, value(*o.base[i].second, c.base_name),
                         value(*o.now[i].second, c.new_name)});
    }
    return;
  }
  for (const auto& [s, cell] : o.base) c.seeds.push_back({s, value(*cell, c.base_name), std::nullopt});
  for (const auto& [s, cell] : o.now) c.seeds.push_back({s, std::nullopt, value(*cell, c.new_name)});
}

// The verdicts, once every cell's tests are done: the directions' p-values (two-sided:
// twice the smaller one-sided one) adjusted over the grid, and the equivalence test at the
// same level for "unchanged". A cell whose test cannot reach any p-value below 1 (no values
// on a side, identical values, no discordant seed: its note says which) is left out of the
// family, as Tarone's rule for discrete tests allows: counting it would only dilute the
// others.
void Decide(Comparison& comparison) {
  std::vector<double> p;
  std::vector<size_t> tested;
  for (size_t i = 0; i < comparison.cells.size(); ++i) {
    const CellComparison& c = comparison.cells[i];
    if (!c.note.empty()) continue;
    tested.push_back(i);
    p.push_back(std::min(1.0, 2.0 * std::min(c.p_regressed, c.p_improved)));
  }
  const std::vector<double> adjusted =
      comparison.options.fdr_procedure == FdrProcedure::kBenjaminiHochberg ? BenjaminiHochberg(p)
                                                                           : BenjaminiYekutieli(p);
  for (size_t k = 0; k < tested.size(); ++k) comparison.cells[tested[k]].p_adjusted = adjusted[k];
  for (CellComparison& c : comparison.cells) {
    if (c.p_adjusted <= comparison.options.fdr) {
      c.verdict = c.p_regressed < c.p_improved ? Verdict::kRegressed : Verdict::kImproved;
    } else if (c.p_equivalent <= comparison.options.fdr) {
      c.verdict = Verdict::kUnchanged;
    } else {
      c.verdict = Verdict::kInconclusive;
    }
  }
}

// The cells of one scenario and metric entry over the subjects (methods or labels) the
// two sides have, seed-matched or not.
void AddCells(Comparison& comparison, const std::string& scenario,
              const std::map<std::string, double>& scenario_effects, const ComparedMetric& metric,
              const std::vector<std::pair<std::string, std::string>>& names,
              const std::string& subject, const Observations& o, Pairing pairing) {
  const auto& [base_name, new_name] = names.front();
  CellComparison c;
  c.scenario = scenario;
  c.metric = &metric;
  c.base_name = base_name;
  c.new_name = new_name;
  c.subject = subject;
  c.minimal_effect = MinimalEffect(comparison.options, scenario_effects, metric, base_name);
  c.pairing = pairing;
  if (metric.kind == EffectKind::kEvent) {
    TestEvent(c, o);
  } else {
    TestContinuous(c, o, comparison.options);
  }
  if (c.base_count == 0 && c.new_count == 0 && c.note == "no values") return;
  RecordSeeds(c, o);
  comparison.cells.push_back(std::move(c));
}

// Every concrete name of `metric` that some cell of either side holds, by subject.
std::set<std::string> SubjectsOf(const ComparedMetric& metric,
                                 const std::vector<const CellRecord*>& cells) {
  std::set<std::string> subjects;
  for (const CellRecord* cell : cells) {
    const auto collect = [&](const std::string& name) {
      if (const auto match = MatchComparedMetric(name); match && match->metric == &metric) {
        subjects.insert(match->subject);
      }
    };
    for (const auto& [name, v] : cell->values) collect(name);
    for (const auto& [name, v] : cell->events) collect(name);
  }
  return subjects;
}

std::string ConcreteName(const ComparedMetric& metric, const std::string& subject) {
  if (metric.scope == "run") return metric.key == "expectation" ? "run.expectation." + subject : "run." + metric.key;
  return metric.scope + "." + subject + "." + metric.key;
}

Pairing WeakestPairing(const Observations& o, const ComparedMetric& metric,
                       const std::string& base_method, const std::string& new_method) {
  if (!o.paired) return Pairing::kUnpaired;
  // Judged over the seeds whose runs both left a summary: a run that failed has no
  // digests, and no values either (its failure is an event, compared seed by seed). With
  // no such seed the pairing is not verified: unpaired.
  Pairing weakest = Pairing::kIdenticalSamples;
  bool verified = false;
  for (size_t i = 0; i < o.base.size(); ++i) {
    const CellRecord& base = *o.base[i].second;
    const CellRecord& now = *o.now[i].second;
    if (!base.error.empty() || !now.error.empty()) continue;
    verified = true;
    const Pairing p = PairingOf(DigestsFor(base, metric, base_method), DigestsFor(now, metric, new_method));
    weakest = std::max(weakest, p);
  }
  return verified ? weakest : Pairing::kUnpaired;
}

void RequireKnownEffects(const CompareOptions& options) {
  RequireKnownMinimalEffects(options.minimal_effects,
                             [](const std::string&) { return core::SourceLocation{"--min-effect", 0, 0}; },
                             "");
}

}  // namespace

void RequireKnownMinimalEffects(const std::map<std::string, double>& effects,
                                const std::function<core::SourceLocation(const std::string&)>& where,
                                const std::string& key_prefix) {
  for (const auto& [name, value] : effects) {
    const ComparedMetric* pattern = FindComparedMetric(name);
    const std::optional<ConcreteMetric> concrete = pattern ? std::nullopt : MatchComparedMetric(name);
    const ComparedMetric* metric = pattern ? pattern : concrete ? concrete->metric : nullptr;
    if (metric != nullptr && metric->kind == EffectKind::kEvent) {
      throw InputError(where(name), key_prefix + name,
                       "is a yes/no outcome: it has no size, so no minimal effect (every "
                       "change of it is tested)");
    }
    if (metric == nullptr) {
      std::string patterns;
      for (const ComparedMetric& m : ComparedMetrics()) {
        if (m.kind != EffectKind::kEvent) patterns += (patterns.empty() ? "" : ", ") + m.Pattern();
      }
      throw InputError(where(name), key_prefix + name,
                       fmt::format("is not a comparable metric; expected one of {} (or a "
                                   "method's own, such as methods.consensus.ate_m)",
                                   patterns));
    }
    if (!(value >= 0.0) || !std::isfinite(value)) {
      throw InputError(where(name), key_prefix + name,
                       fmt::format("expected a number >= 0, got {}", value));
    }
  }
}

const char* VerdictName(Verdict verdict) {
  switch (verdict) {
    case Verdict::kRegressed: return "regressed";
    case Verdict::kImproved: return "improved";
    case Verdict::kInconclusive: return "inconclusive";
    case Verdict::kUnchanged: return "unchanged";
  }
  return "?";
}

const char* PairingName(Pairing pairing) {
  switch (pairing) {
    case Pairing::kIdenticalSamples: return "identical samples";
    case Pairing::kCommonRandomNumbers: return "common random numbers";
    case Pairing::kUnpaired: return "unpaired";
  }
  return "?";
}

int Comparison::Count(Verdict verdict) const {
  return static_cast<int>(std::count_if(cells.begin(), cells.end(),
                                        [&](const CellComparison& c) { return c.verdict == verdict; }));
}

Comparison CompareCampaigns(const CampaignRecord& base, const CampaignRecord& now,
                            const CompareOptions& options) {
  RequireKnownEffects(options);
  const Grid b = GridOf(base);
  const Grid n = GridOf(now);
  RequireComparable(base, now, b, n, options);
  Comparison comparison;
  comparison.base_label = base.source.string();
  comparison.new_label = now.source.string();
  comparison.options = options;
  for (const std::string& scenario : b.scenarios) {
    Observations o;
    o.paired = !options.unpaired;
    for (const auto& [seed, cell] : b.cells.at(scenario)) o.base.emplace_back(seed, cell);
    for (const auto& [seed, cell] : n.cells.at(scenario)) o.now.emplace_back(seed, cell);
    std::vector<const CellRecord*> all;
    for (const auto& [s, cell] : o.base) all.push_back(cell);
    for (const auto& [s, cell] : o.now) all.push_back(cell);
    for (const ComparedMetric& metric : ComparedMetrics()) {
      for (const std::string& subject : SubjectsOf(metric, all)) {
        const std::string name = ConcreteName(metric, subject);
        const Pairing pairing = WeakestPairing(o, metric, subject, subject);
        // Seeds that no longer pair are independent samples: tested as such.
        Observations used = o;
        if (pairing == Pairing::kUnpaired) used.paired = false;
        AddCells(comparison, scenario, ScenarioEffects(now, scenario), metric, {{name, name}},
                 subject, used, pairing);
      }
    }
  }
  Decide(comparison);
  return comparison;
}

Comparison CompareMethods(const CampaignRecord& campaign, const std::string& base_method,
                          const std::string& new_method, const CompareOptions& options) {
  RequireKnownEffects(options);
  const Grid g = GridOf(campaign);
  for (const std::string& method : {base_method, new_method}) {
    bool found = false;
    for (const CellRecord& c : campaign.cells) {
      found = found || c.events.contains("methods." + method + ".failed") ||
              c.events.contains("closed_loop." + method + ".failed");
    }
    if (!found) {
      throw InputError({campaign.source.string()}, "--methods",
                       fmt::format("no run of the check has a method '{}'", method));
    }
  }
  Comparison comparison;
  comparison.base_label = base_method;
  comparison.new_label = new_method;
  comparison.options = options;
  for (const std::string& scenario : g.scenarios) {
    Observations o;
    for (const auto& [seed, cell] : g.cells.at(scenario)) {
      o.base.emplace_back(seed, cell);
      o.now.emplace_back(seed, cell);
    }
    for (const ComparedMetric& metric : ComparedMetrics()) {
      if (metric.scope == "run") continue;  // a run's outcomes are both methods'
      const std::string base_name = ConcreteName(metric, base_method);
      const std::string new_name = ConcreteName(metric, new_method);
      bool present = false;
      for (const auto& [s, cell] : o.base) {
        present = present || cell->values.contains(base_name) || cell->events.contains(base_name) ||
                  cell->values.contains(new_name) || cell->events.contains(new_name);
      }
      if (!present) continue;
      const Pairing pairing = WeakestPairing(o, metric, base_method, new_method);
      Observations used = o;
      if (pairing == Pairing::kUnpaired) used.paired = false;
      AddCells(comparison, scenario, ScenarioEffects(campaign, scenario), metric,
               {{base_name, new_name}},
               base_method + " -> " + new_method, used, pairing);
    }
  }
  Decide(comparison);
  return comparison;
}

// ---- what a person reads ----

namespace {

std::string EffectText(const CellComparison& c) {
  if (c.metric->kind == EffectKind::kEvent) {
    return fmt::format("{}/{} -> {}/{}", c.base_events, c.base_count, c.new_events, c.new_count);
  }
  if (!c.effect) return "-";
  if (c.metric->kind == EffectKind::kRatio) {
    return fmt::format("x{:.3f} [{:.3f}, {:.3f}]", *c.effect, c.interval->low, c.interval->high);
  }
  const std::string unit = c.metric->unit.empty() ? "" : " " + c.metric->unit;
  return fmt::format("{:+.4g}{} [{:+.4g}, {:+.4g}]", *c.effect, unit, c.interval->low,
                     c.interval->high);
}

std::string MinimalText(const CellComparison& c) {
  if (c.metric->kind == EffectKind::kEvent) return "-";
  if (c.metric->kind == EffectKind::kRatio) return fmt::format("{:g} %", 100.0 * c.minimal_effect);
  return fmt::format("{:g}{}", c.minimal_effect, c.metric->unit.empty() ? "" : " " + c.metric->unit);
}

int Rank(Verdict v) {
  switch (v) {
    case Verdict::kRegressed: return 0;
    case Verdict::kImproved: return 1;
    case Verdict::kInconclusive: return 2;
    case Verdict::kUnchanged: return 3;
  }
  return 4;
}

std::vector<const CellComparison*> ReadingOrder(const Comparison& comparison) {
  std::vector<const CellComparison*> order;
  for (const CellComparison& c : comparison.cells) order.push_back(&c);
  std::stable_sort(order.begin(), order.end(), [](const CellComparison* a, const CellComparison* b) {
    return Rank(a->verdict) < Rank(b->verdict);
  });
  return order;
}

std::string Summary(const Comparison& comparison) {
  return fmt::format(
      "{} cells: {} regressed, {} improved, {} inconclusive, {} unchanged (false-discovery rate "
      "{:g} by {}; {:g} % bootstrap intervals of the median)",
      comparison.cells.size(), comparison.Count(Verdict::kRegressed),
      comparison.Count(Verdict::kImproved), comparison.Count(Verdict::kInconclusive),
      comparison.Count(Verdict::kUnchanged), comparison.options.fdr,
      comparison.options.fdr_procedure == FdrProcedure::kBenjaminiHochberg ? "Benjamini-Hochberg"
                                                                           : "Benjamini-Yekutieli",
      100.0 * comparison.options.confidence);
}

std::string MetricText(const CellComparison& c) {
  return c.metric->key == "expectation" ? "expectation " + c.subject : c.metric->scope + "." + c.metric->key;
}

std::string SubjectText(const CellComparison& c) {
  return c.metric->key == "expectation" ? "-" : c.subject;
}

std::string NText(const CellComparison& c) {
  return c.pairing == Pairing::kUnpaired ? fmt::format("{}+{}", c.base_count, c.new_count)
                                         : std::to_string(c.pairs);
}

}  // namespace

std::string CellFigures(const CellComparison& cell) {
  const std::string n = cell.pairing == Pairing::kUnpaired
                            ? fmt::format("{} + {} seeds", cell.base_count, cell.new_count)
                            : fmt::format("{} pairs", cell.pairs);
  return fmt::format("{} {} over {} ({}), minimal {}, {}", cell.new_name, EffectText(cell), n,
                     PairingName(cell.pairing), MinimalText(cell),
                     cell.note.empty() ? fmt::format("p adj {:.3g}", cell.p_adjusted) : cell.note);
}

std::string ComparisonTable(const Comparison& comparison) {
  struct Row {
    std::string cells[9];
  };
  std::vector<Row> rows;
  rows.push_back({{"verdict", "scenario", "method", "metric", "n", "pairing", "effect [95 % CI]",
                   "minimal", "p adj"}});
  for (const CellComparison* c : ReadingOrder(comparison)) {
    std::string verdict = VerdictName(c->verdict);
    if (c->verdict == Verdict::kRegressed || c->verdict == Verdict::kImproved) {
      for (char& ch : verdict) ch = static_cast<char>(std::toupper(static_cast<unsigned char>(ch)));
    }
    rows.push_back({{verdict, c->scenario, SubjectText(*c), MetricText(*c), NText(*c),
                     PairingName(c->pairing), EffectText(*c), MinimalText(*c),
                     c->note.empty() ? fmt::format("{:.3g}", c->p_adjusted) : c->note}});
  }
  size_t width[9] = {};
  for (const Row& r : rows) {
    for (int i = 0; i < 9; ++i) width[i] = std::max(width[i], r.cells[i].size());
  }
  std::string out = fmt::format("tofu compare: base {} -> new {}\n", comparison.base_label,
                                comparison.new_label);
  for (const Row& r : rows) {
    for (int i = 0; i < 9; ++i) {
      out += fmt::format("{:<{}}{}", r.cells[i], i == 8 ? 0 : width[i], i == 8 ? "\n" : "  ");
    }
  }
  out += Summary(comparison) + "\n";
  return out;
}

std::string ComparisonMarkdown(const Comparison& comparison) {
  std::string out = fmt::format("### tofu compare: `{}` -> `{}`\n\n", comparison.base_label,
                                comparison.new_label);
  const int regressed = comparison.Count(Verdict::kRegressed);
  out += fmt::format("{}**{}**\n\n", regressed > 0 ? ":x: " : ":white_check_mark: ", Summary(comparison));
  out += "| verdict | scenario | method | metric | n | pairing | effect [95 % CI] | minimal | p adj |\n"
         "|---|---|---|---|---:|---|---|---:|---:|\n";
  int unchanged = 0;
  for (const CellComparison* c : ReadingOrder(comparison)) {
    if (c->verdict == Verdict::kUnchanged) {
      ++unchanged;
      continue;
    }
    const bool strong = c->verdict == Verdict::kRegressed || c->verdict == Verdict::kImproved;
    out += fmt::format("| {} | {} | {} | {} | {} | {} | {} | {} | {} |\n",
                       strong ? fmt::format("**{}**", VerdictName(c->verdict)) : VerdictName(c->verdict),
                       c->scenario, SubjectText(*c), MetricText(*c), NText(*c), PairingName(c->pairing),
                       EffectText(*c), MinimalText(*c),
                       c->note.empty() ? fmt::format("{:.3g}", c->p_adjusted) : c->note);
  }
  if (unchanged > 0) out += fmt::format("\n{} unchanged cells not listed.\n", unchanged);
  return out;
}

nlohmann::json ComparisonJson(const Comparison& comparison) {
  nlohmann::json cells = nlohmann::json::array();
  const auto optional = [](const std::optional<double>& v) {
    return v ? nlohmann::json(*v) : nlohmann::json(nullptr);
  };
  for (const CellComparison& c : comparison.cells) {
    nlohmann::json seeds = nlohmann::json::array();
    for (const CellComparison::SeedValue& s : c.seeds) {
      seeds.push_back({{"seed", s.seed}, {"base", optional(s.base)}, {"new", optional(s.now)}});
    }
    nlohmann::json j = {{"scenario", c.scenario},
                        {"metric", c.metric->Pattern()},
                        {"kind", c.metric->kind == EffectKind::kRatio        ? "ratio"
                                 : c.metric->kind == EffectKind::kDifference ? "difference"
                                                                              : "event"},
                        {"higher_is_better", c.metric->higher_is_better},
                        {"unit", c.metric->unit},
                        {"base_name", c.base_name},
                        {"new_name", c.new_name},
                        {"subject", c.subject},
                        {"minimal_effect", c.minimal_effect},
                        {"pairing", PairingName(c.pairing)},
                        {"base_count", c.base_count},
                        {"new_count", c.new_count},
                        {"pairs", c.pairs},
                        {"effect", optional(c.effect)},
                        {"interval", c.interval ? nlohmann::json{c.interval->low, c.interval->high}
                                                : nlohmann::json(nullptr)},
                        {"base_events", c.base_events},
                        {"new_events", c.new_events},
                        {"base_only", c.base_only},
                        {"new_only", c.new_only},
                        {"p_regressed", c.p_regressed},
                        {"p_improved", c.p_improved},
                        {"p_equivalent", c.p_equivalent},
                        {"p_adjusted", c.p_adjusted},
                        {"verdict", VerdictName(c.verdict)},
                        {"note", c.note},
                        {"seeds", seeds}};
    cells.push_back(std::move(j));
  }
  return {{"format", kCompareJsonFormat},
          {"version", 1},
          {"base", comparison.base_label},
          {"new", comparison.new_label},
          {"fdr", comparison.options.fdr},
          {"fdr_procedure", comparison.options.fdr_procedure == FdrProcedure::kBenjaminiHochberg
                                ? "benjamini-hochberg"
                                : "benjamini-yekutieli"},
          {"confidence", comparison.options.confidence},
          {"bootstrap_resamples", comparison.options.bootstrap_resamples},
          {"counts",
           {{"regressed", comparison.Count(Verdict::kRegressed)},
            {"improved", comparison.Count(Verdict::kImproved)},
            {"inconclusive", comparison.Count(Verdict::kInconclusive)},
            {"unchanged", comparison.Count(Verdict::kUnchanged)}}},
          {"cells", cells}};
}

}  // namespace tofu::campaign
