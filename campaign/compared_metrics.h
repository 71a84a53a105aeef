#pragma once
// The metrics `tofu compare` tests, one table: what each is, which way is better, the
// smallest change that matters (the default minimal effect) and the version of its
// definition. A metric whose definition changes gets a new version, and a comparison
// across versions is refused.

#include <optional>
#include <string>
#include <string_view>
#include <vector>

namespace tofu::campaign {

/// How a metric's change is measured.
enum class EffectKind {
  kRatio,       ///< a scale (an error's size): new / base, tested on the log ratio
  kDifference,  ///< new - base, in the metric's unit
  kEvent,       ///< a yes/no outcome per flight (a failure): paired counts
};

struct ComparedMetric {
  /// The name under summary.json's method or flight entry ("ate_m"), or the event's name
  /// ("failed", "collided"), or an expectation's ("expectation").
  std::string key;
  /// "methods" (an open-loop method), "closed_loop" (a flight on a method) or "run".
  std::string scope;
  EffectKind kind = EffectKind::kRatio;
  bool higher_is_better = false;  ///< events: the event is bad, always false
  /// Ratio: the relative change (0.05: 5 %); difference: in the metric's unit; events: 0.
  double minimal_effect = 0.0;
  std::string unit;
  int version = 1;
  std::string doc;

  /// "methods.<method>.ate_m": the name as a cell holds it, with the method's placeholder.
  std::string Pattern() const;
};

/// Every comparable metric, in report order.
const std::vector<ComparedMetric>& ComparedMetrics();

/// The entry whose Pattern() is `pattern`, or nullptr.
const ComparedMetric* FindComparedMetric(std::string_view pattern);

/// A concrete name split into its entry and method: "methods.single:vio@clean.ate_m" ->
/// (ate_m's entry, "single:vio@clean"); "run.expectation.<label>" -> (expectation, label).
/// nullopt when it matches none.
struct ConcreteMetric {
  const ComparedMetric* metric = nullptr;
  std::string subject;  ///< the method, or the expectation's label
};
std::optional<ConcreteMetric> MatchComparedMetric(std::string_view name);

}  // namespace tofu::campaign
