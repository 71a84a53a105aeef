#pragma once
// An expectation's margin: its signed, normalised distance to its bounds, the one figure
// `tofu search` minimises (../shared/DESIGN.md: what check turns into pass/fail). For
// min <= value <= max, the margin is the smaller of (value - min) / s_min and
// (max - value) / s_max, with s = |bound|, or 1 for a bound of 0 (a count, in its own
// unit). Negative exactly when the expectation fails; 0 on the bound (which passes).

#include <optional>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "campaign/run_pool.h"

namespace tofu::campaign {

double ExpectationMargin(double value, const std::optional<double>& min, const std::optional<double>& max);

/// The objective of one flight: the least margin of the summary's expectations on
/// `metrics`. A flight with no margin to give (the simulation failed, a client failed, a
/// named expectation is not measurable or has no value) has margin -inf and says why.
struct FlightMargin {
  double margin = 0.0;
  std::string failing_metric;  ///< the expectation with the least margin; "" for a failed run
  /// "passed", "violated", "client failed", "simulation failed", "not measurable"
  std::string outcome;
  std::string cause;  ///< why a flight without a margin has none (a client's with its stderr)
};
FlightMargin MarginOfRun(const SeedRun& run, const std::vector<std::string>& metrics);

/// A flight's margin as JSON ({margin (null for -inf), outcome, failing_metric, cause}), the
/// form of a search's journal and search.json; and back (throws nlohmann::json's errors
/// for another form).
nlohmann::json MarginToJson(const FlightMargin& margin);
FlightMargin MarginFromJson(const nlohmann::json& j);

}  // namespace tofu::campaign
