#include "campaign/margin.h"

#include <algorithm>
#include <cmath>
#include <limits>

#include <fmt/format.h>

#include "core/error.h"

namespace tofu::campaign {

namespace {

double Scale(double bound) { return bound == 0.0 ? 1.0 : std::abs(bound); }

std::optional<double> OptionalNumber(const nlohmann::json& entry, const char* key) {
  const auto it = entry.find(key);
  if (it == entry.end() || !it->is_number()) return std::nullopt;
  return it->get<double>();
}

}  // namespace

double ExpectationMargin(double value, const std::optional<double>& min, const std::optional<double>& max) {
  double margin = std::numeric_limits<double>::infinity();
  if (min) margin = std::min(margin, (value - *min) / Scale(*min));
  if (max) margin = std::min(margin, (*max - value) / Scale(*max));
  return margin;
}

FlightMargin MarginOfRun(const SeedRun& run, const std::vector<std::string>& metrics) {
  constexpr double kNone = -std::numeric_limits<double>::infinity();
  FlightMargin out;
  if (!run.error.empty() || !run.summary.is_object()) {
    out.margin = kNone;
    out.outcome = "simulation failed";
    out.cause = run.error.empty() ? std::string("no summary") : run.error;
    return out;
  }
  out.margin = std::numeric_limits<double>::infinity();
  const auto expectations = run.summary.find("expectations");
  if (expectations != run.summary.end() && expectations->is_array()) {
    for (const nlohmann::json& e : *expectations) {
      const std::string metric = e.value("metric", std::string());
      if (std::find(metrics.begin(), metrics.end(), metric) == metrics.end()) continue;
      const std::optional<double> value = OptionalNumber(e, "value");
      double margin = kNone;
      if (value) margin = ExpectationMargin(*value, OptionalNumber(e, "min"), OptionalNumber(e, "max"));
      if (margin < out.margin) {
        out.margin = margin;
        out.failing_metric = metric;
        if (!value) {
          const auto why = e.find("not_measurable");
          out.cause = why != e.end() && why->is_string() ? why->get<std::string>()
                                                           : std::string("the metric has no value");
        }
      }
    }
  }
  if (!run.client_failure.empty()) {
    // A user's estimator or controller that crashed or hung here is a failure found, whatever
    // the margins of the methods that kept going.
    out.margin = kNone;
    out.outcome = "client failed";
    out.cause = run.client_failure;  // with the client's last lines of standard error
    return out;
  }
  if (std::isinf(out.margin) && out.margin > 0.0) {
    out.margin = kNone;
    out.outcome = "not measurable";
    out.cause = "the summary holds none of the objective's expectations";
  } else if (std::isinf(out.margin)) {
    out.outcome = "not measurable";
  } else {
    out.outcome = out.margin < 0.0 ? "violated" : "passed";
  }
  return out;
}

nlohmann::json MarginToJson(const FlightMargin& m) {
  return {{"margin", std::isfinite(m.margin) ? nlohmann::json(m.margin) : nlohmann::json(nullptr)},
          {"outcome", m.outcome},
          {"failing_metric", m.failing_metric},
          {"cause", m.cause}};
}

FlightMargin MarginFromJson(const nlohmann::json& j) {
  FlightMargin m;
  m.margin = j.at("margin").is_null() ? -std::numeric_limits<double>::infinity() : j.at("margin").get<double>();
  m.outcome = j.at("outcome").get<std::string>();
  m.failing_metric = j.at("failing_metric").get<std::string>();
  m.cause = j.at("cause").get<std::string>();
  return m;
}

}  // namespace tofu::campaign
