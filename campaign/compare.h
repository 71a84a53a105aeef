#pragma once
// `tofu compare`: is the new campaign better or worse than the base, where, and by how
// much. Per scenario x method x metric over the seeds: the paired differences (or log
// ratios, for an error's scale) with their median and a bootstrap interval; a verdict
// against the metric's minimal effect from exact rank tests (Wilcoxon signed-rank when the
// seeds pair, Mann-Whitney when they do not), yes/no outcomes by exact McNemar (paired) or
// Fisher (unpaired) tests; the false-discovery rate controlled over the whole grid
// (Benjamini-Hochberg by default). Whether the seeds pair is read from the cells' digests,
// not assumed (docs/DESIGN.md "Comparing two campaigns").

#include <functional>
#include <map>
#include <optional>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "campaign/cell_record.h"
#include "core/error.h"
#include "campaign/compared_metrics.h"
#include "campaign/statistics.h"

namespace tofu::campaign {

enum class FdrProcedure { kBenjaminiHochberg, kBenjaminiYekutieli };

/// What `tofu check --baseline` writes into its --out (and `tofu report` reads): the
/// comparison as markdown and as ComparisonJson.
inline constexpr const char* kCompareMarkdownFile = "compare.md";
inline constexpr const char* kCompareJsonFile = "compare.json";
inline constexpr const char* kCompareJsonFormat = "tofu compare";  ///< ComparisonJson's "format"

struct CompareOptions {
  double fdr = 0.05;  ///< false-discovery rate of the improved/regressed verdicts; the
                      ///< level of the equivalence test behind "unchanged"
  FdrProcedure fdr_procedure = FdrProcedure::kBenjaminiHochberg;
  double confidence = 0.95;  ///< of the bootstrap interval
  int bootstrap_resamples = 2000;
  /// Compare the seed sets as independent samples (they need not be the same seeds).
  bool unpaired = false;
  /// Minimal effects by metric pattern ("methods.<method>.ate_m") or concrete name
  /// ("methods.consensus.ate_m"): a fraction for a ratio metric (0.05: 5 %), the metric's
  /// own unit for a difference. They win over the scenarios' own (`compare:
  /// {minimal_effects}`, CampaignRecord::minimal_effects), and those over the table's
  /// defaults; within each, a concrete name over a pattern.
  std::map<std::string, double> minimal_effects;
};

enum class Verdict { kRegressed, kImproved, kInconclusive, kUnchanged };
const char* VerdictName(Verdict verdict);

/// What ties the base's seeds to the new's, from the cells' digests (core/digest.h).
enum class Pairing {
  kIdenticalSamples,     ///< every pair's methods saw byte-identical samples
  kCommonRandomNumbers,  ///< different samples from the same random streams (closed loop)
  kUnpaired,             ///< other random streams (other seeds, another simulator): none
};
const char* PairingName(Pairing pairing);

/// One scenario x method x metric.
struct CellComparison {
  std::string scenario;
  const ComparedMetric* metric = nullptr;
  std::string base_name;  ///< concrete name in the base ("methods.consensus.ate_m")
  std::string new_name;   ///< and in the new (another method's with --methods)
  std::string subject;    ///< the method ("consensus", "a -> b") or the expectation
  double minimal_effect = 0.0;
  Pairing pairing = Pairing::kUnpaired;
  int base_count = 0;  ///< seeds with a value (events: with the outcome known)
  int new_count = 0;
  int pairs = 0;       ///< seeds with both (paired only)
  /// Ratio: new / base (the exp of the median log ratio, or of the medians' difference);
  /// difference: new - base; nullopt for events and without values on both sides.
  std::optional<double> effect;
  std::optional<Interval> interval;
  int base_events = 0;  ///< events: seeds with the event
  int new_events = 0;
  int base_only = 0;    ///< events, paired: discordant seeds
  int new_only = 0;
  double p_regressed = 1.0;  ///< one-sided, beyond the minimal effect
  double p_improved = 1.0;
  double p_equivalent = 1.0;  ///< two one-sided tests within the minimal effect
  double p_adjusted = 1.0;    ///< of the direction, over the grid
  Verdict verdict = Verdict::kInconclusive;
  std::string note;  ///< why it is unchanged or inconclusive, when that is not the tests
  /// Each seed's values (events: 1 or 0), for the pictures: base and new in seed order
  /// (with --unpaired each side's own seeds, unmatched).
  struct SeedValue {
    uint64_t seed = 0;
    std::optional<double> base;
    std::optional<double> now;
  };
  std::vector<SeedValue> seeds;
};

struct Comparison {
  std::string base_label;
  std::string new_label;
  CompareOptions options;
  std::vector<CellComparison> cells;  ///< scenario order, then the metric table's
  int Count(Verdict verdict) const;
};

/// Compares two campaigns of the same grid. Throws core::InputError (nothing compared)
/// naming the cell and what differs: another tofu version, another metric definition
/// version, another scenario set, a changed scenario file, a seed one side lacks (unless
/// options.unpaired), a minimal effect for a metric that does not exist.
Comparison CompareCampaigns(const CampaignRecord& base, const CampaignRecord& now,
                            const CompareOptions& options);

/// Two methods of one campaign, seed by seed (`base_method` as the base). Throws
/// core::InputError when a method is in no cell.
Comparison CompareMethods(const CampaignRecord& campaign, const std::string& base_method,
                          const std::string& new_method, const CompareOptions& options);

/// One cell's figures on one line, for a failure message: "methods.consensus.ate_m x1.231
/// [1.150, 1.304] over 8 pairs (identical samples), minimal 5 %, p adj 0.0039".
std::string CellFigures(const CellComparison& cell);

/// Refuses a minimal effect for a metric the table does not have (a pattern such as
/// "methods.<method>.ate_m" or a concrete name), or one that is negative or not finite:
/// core::InputError at where(name), key `key_prefix + name`. For --min-effect and a
/// scenario's `compare: {minimal_effects: ...}`.
void RequireKnownMinimalEffects(const std::map<std::string, double>& effects,
                                const std::function<core::SourceLocation(const std::string&)>& where,
                                const std::string& key_prefix);

/// The terminal table: regressions first, then improvements, inconclusive, unchanged.
std::string ComparisonTable(const Comparison& comparison);
/// The same as markdown, for a pull-request comment: a summary line and the table of
/// every cell that is not unchanged.
std::string ComparisonMarkdown(const Comparison& comparison);
/// Every cell with its statistics, for machines and plots (scripts/plot_compare.py).
nlohmann::json ComparisonJson(const Comparison& comparison);

}  // namespace tofu::campaign
