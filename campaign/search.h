#pragma once
// The search for failures (docs/DESIGN.md, "Searching for failures"): an optimiser proposes
// points of a spec's space in batches, flights give back margins, a failing point is
// confirmed over other seeds and de-duplicated, and each confirmed failure is shrunk
// towards the base. Flights go through a FlightEvaluator (the command's flies `tofu run`
// subprocesses; tests give analytic margins) behind a journal, so a killed search resumes
// by replaying the same proposals with the recorded margins.

#include <cstdint>
#include <filesystem>
#include <functional>
#include <map>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "campaign/margin.h"
#include "campaign/search_spec.h"
#include "campaign/statistics.h"

namespace tofu::campaign {

/// One flight a search asks for: an id unique in the search ("e000012": the 13th search
/// evaluation; "f2_c3": failure 2's 3rd confirmation; "f2_s5": its 5th shrink step).
struct FlightRequest {
  std::string id;
  Setting setting;
};

class FlightEvaluator {
 public:
  virtual ~FlightEvaluator() = default;
  /// Flies every request (as many at once as it can); the margins in the requests' order.
  virtual std::vector<FlightMargin> Fly(const std::vector<FlightRequest>& requests) = 0;
};

/// Proposes points of the unit cube; told each batch's margins (clipped to [-10, 10]).
class Proposer {
 public:
  virtual ~Proposer() = default;
  virtual std::vector<std::vector<double>> Ask(std::size_t n) = 0;
  virtual void Tell(const std::vector<double>& margins) = 0;
};

/// The spec's optimiser: `random` in-process, `tpe` through scripts/search_proposer.py
/// (optuna) in `scripts_dir`. Seeded by the spec: the same spec proposes the same points.
std::unique_ptr<Proposer> MakeProposer(const SearchSpec& spec, const std::filesystem::path& scripts_dir);

/// A FlightEvaluator that records every flight in `journal` (JSON lines, one per flight,
/// written in request order once a batch is done) and answers from it the flights it
/// already holds (same id, same scenario text), so a search resumed after a kill flies
/// only what is new. A torn last line (a kill mid-write) is dropped.
class JournaledEvaluator : public FlightEvaluator {
 public:
  JournaledEvaluator(const SearchSpec& spec, FlightEvaluator& inner, std::filesystem::path journal);
  std::vector<FlightMargin> Fly(const std::vector<FlightRequest>& requests) override;
  std::size_t flown() const { return flown_; }    ///< flights the inner evaluator flew
  std::size_t reused() const { return reused_; }  ///< flights answered from the journal

 private:
  const SearchSpec& spec_;
  FlightEvaluator& inner_;
  std::filesystem::path journal_;
  std::map<std::string, std::pair<std::string, FlightMargin>> recorded_;  // id -> (key, margin)
  std::size_t flown_ = 0;
  std::size_t reused_ = 0;
};

/// A failure found: a cluster of failing search points of one failing expectation.
struct FoundFailure {
  std::string id;      ///< "f1", in the order found
  std::string metric;  ///< the failing expectation's metric, or the outcome ("client failed")
  std::vector<double> unit;  ///< the cluster's representative (least margin)
  Setting found;
  FlightMargin found_margin;
  std::string found_flight;  ///< the id of the search flight at `found`
  std::size_t first_simulation = 0;  ///< 1-based search simulation that found the cluster
  std::size_t members = 1;           ///< failing search points in the cluster
  int confirm_failures = 0;
  int confirm_flights = 0;
  Interval failure_rate_ci;  ///< Clopper-Pearson 95 %
  bool confirmed = false;
  Setting shrunk;  ///< the smallest change from the base that still fails (confirmed only)
  FlightMargin shrunk_margin;
  std::string shrunk_flight;  ///< the id of the flight at `shrunk`
  /// Where its flights' run directories are, relative to the search directory (a merged
  /// search's failures are in their shard's).
  std::string flights_dir = "flights";
};

struct SearchEvaluation {
  std::string id;
  std::vector<double> unit;
  Setting setting;
  FlightMargin margin;
};

struct SearchOutcome {
  std::vector<SearchEvaluation> evaluations;  ///< the search's own, in order
  std::vector<FoundFailure> failures;         ///< ranked: confirmed first, rate, margin
  std::size_t confirm_flights = 0;
  std::size_t shrink_flights = 0;
  /// Search simulations up to and including the batch whose failure was the first
  /// confirmed (ARCH-COMP's simulations to falsification); nullopt: none confirmed.
  std::optional<std::size_t> simulations_to_first_confirmed;
};

/// One line per event ("[12/200] best margin 0.21", "f1 confirmed 5/5"), for progress.
using SearchProgress = std::function<void(const std::string&)>;

/// Runs the search: batches of spec.batch points until the budget is spent (or, with
/// spec.stop_at_first, the first failure is confirmed), then shrinks each confirmed failure.
SearchOutcome RunSearch(const SearchSpec& spec, FlightEvaluator& evaluator, Proposer& proposer,
                        const SearchProgress& progress = {});

/// Max-norm distance of two points of the cube; a categorical coordinate counts 0 or 1
/// (the same choice or not). Two failures of one expectation within spec.dedupe_distance
/// are one.
double PointDistance(const SearchSpec& spec, const std::vector<double>& a, const std::vector<double>& b);

/// The ranking of failures: confirmed first, then by failure rate, then by margin (stable).
void RankFailures(std::vector<FoundFailure>& failures);

/// The seeds a failure found at `seed` is confirmed at: `count` seeds none of which is
/// `seed` (and, for a seed searched in a range, outside that range).
std::vector<uint64_t> ConfirmationSeeds(const SearchSpec& spec, uint64_t seed, int count);

}  // namespace tofu::campaign
