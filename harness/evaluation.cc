#include "harness/evaluation.h"

#include <algorithm>
#include <cmath>
#include <deque>
#include <map>
#include <set>
#include <stdexcept>
#include <tuple>

#include <fmt/format.h>

#include "core/hash.h"
#include "core/units.h"
#include "harness/metrics.h"
#include "replay/json_field.h"
#include "replay/method_evaluation.h"

namespace tofu::harness {

using replay::LabelEvent;

namespace {

using core::kDegPerRad;

bool InWindow(core::Time t_ns, const std::optional<std::pair<double, double>>& window_s) {
  if (!window_s) return true;
  const double t_s = core::TimeToSeconds(t_ns);
  return t_s >= window_s->first && t_s <= window_s->second;
}

struct Stats {
  size_t count = 0;
  double sum_squares = 0.0;
  double max = 0.0;
  std::optional<double> rmse() const {
    if (count == 0) return std::nullopt;
    return std::sqrt(sum_squares / static_cast<double>(count));
  }
  std::optional<double> maximum() const {
    if (count == 0) return std::nullopt;
    return max;
  }
};

template <typename Getter>
Stats TrackingStats(const RunRecord& record,
                    const std::optional<std::pair<double, double>>& window_s, Getter get) {
  Stats s;
  for (const TrackingSample& sample : record.tracking) {
    if (!InWindow(sample.t_ns, window_s)) continue;
    const double e = get(sample);
    ++s.count;
    s.sum_squares += e * e;
    s.max = std::max(s.max, e);
  }
  return s;
}

using replay::FailedFiguresJson;
using replay::NumberOrNull;

// Time the labels of `sensor` say any of `labels` ("a+b": condition names joined by '+';
// source "condition") was active inside the window [from, to].
double ConditionActiveSeconds(const RunRecord& record, const std::string& sensor,
                              const std::string& labels, double from_s, double to_s) {
  std::set<std::string> wanted;
  for (size_t begin = 0;;) {
    const size_t plus = labels.find('+', begin);
    wanted.insert(labels.substr(begin, plus == std::string::npos ? plus : plus - begin));
    if (plus == std::string::npos) break;
    begin = plus + 1;
  }
  // Labels are recorded in time order; the union is active while any wanted label is.
  std::set<std::string> active;
  double active_s = 0.0;
  double since_s = 0.0;
  for (const LabelEvent& l : record.labels) {
    if (l.sensor != sensor || l.source != "condition" || wanted.count(l.label) == 0) continue;
    const double t_s = core::TimeToSeconds(l.t_ns);
    const bool was_active = !active.empty();
    if (l.active) {
      active.insert(l.label);
    } else {
      active.erase(l.label);
    }
    if (!was_active && !active.empty()) {
      since_s = t_s;
    } else if (was_active && active.empty()) {
      active_s += std::max(0.0, std::min(t_s, to_s) - std::max(since_s, from_s));
    }
  }
  if (!active.empty()) active_s += std::max(0.0, to_s - std::max(since_s, from_s));
  return active_s;
}

std::optional<double> SensorMetricValue(const RunRecord& record, const std::string& pattern,
                                        const MetricArguments& args,
                                        const std::optional<std::pair<double, double>>& window_s) {
  const auto stream = std::find_if(record.sensors.begin(), record.sensors.end(),
                                   [&](const SensorStream& s) { return s.name == args.sensor; });
  if (stream == record.sensors.end()) return std::nullopt;
  const double run_s = core::TimeToSeconds(record.physics_steps *
                                           core::PeriodFromRate(record.scenario.physics.rate_hz));
  const double from_s = window_s ? window_s->first : 0.0;
  const double to_s = window_s ? std::min(window_s->second, run_s) : run_s;
  if (pattern == "sensors.<sensor>.delivered_samples") {
    size_t count = 0;
    for (const core::Time t_ns : stream->delivered_t_ns) count += InWindow(t_ns, window_s);
    return static_cast<double>(count);
  }
  if (pattern == "sensors.<sensor>.condition.<condition>") {
    if (to_s <= from_s) return std::nullopt;
    return ConditionActiveSeconds(record, args.sensor, args.condition, from_s, to_s) /
           (to_s - from_s);
  }
  if (pattern == "sensors.<sensor>.position_error_rms_m") {
    // The digest holds an error per delivered sample of a position or pose stream; an
    // IMU has no position.
    if (stream->delivered_position_error_m2.size() != stream->delivered_t_ns.size()) {
      return std::nullopt;
    }
    double sum_squares = 0.0;
    size_t count = 0;
    for (size_t k = 0; k < stream->delivered_t_ns.size(); ++k) {
      if (!InWindow(stream->delivered_t_ns[k], window_s)) continue;
      sum_squares += stream->delivered_position_error_m2[k];
      ++count;
    }
    if (count == 0) return std::nullopt;
    return std::sqrt(sum_squares / static_cast<double>(count));
  }
  return std::nullopt;
}

const MethodEvaluation* FindMethod(const RunRecord& record, const std::string& method) {
  for (const MethodEvaluation& m : record.methods) {
    if (m.method == method) return &m;
  }
  return nullptr;
}

std::optional<double> MethodMetricValue(const RunRecord& record, const std::string& pattern,
                                        const MetricArguments& args) {
  const MethodEvaluation* m = FindMethod(record, args.method);
  // A failed client's figures cover part of the flight at most: none of them is a value.
  if (m == nullptr || m->failure) return std::nullopt;
  if (pattern == "methods.<method>.ate_m") return m->ate_m;
  if (pattern == "methods.<method>.ate_max_m") return m->ate_max_m;
  if (pattern == "methods.<method>.rotation_rmse_deg") return m->rotation_rmse_deg;
  if (pattern == "methods.<method>.rpe_m") return m->rpe_m;
  if (pattern == "methods.<method>.position_step_max_m") return m->position_step_max_m;
  if (pattern == "methods.<method>.nees_position_mean") return m->nees_position_mean;
  if (pattern == "methods.<method>.nees_position_median") return m->nees_position_median;
  if (pattern == "methods.<method>.position_containment_95") return m->position_containment_95;
  if (pattern == "methods.<method>.valid_fraction") return m->valid_fraction;
  if (!m->consensus) return std::nullopt;  // selection metrics only mean something there
  if (pattern == "methods.<method>.switches") return static_cast<double>(m->switches);
  if (pattern == "methods.<method>.missed_faults") return static_cast<double>(m->missed_faults());
  if (pattern == "methods.<method>.max_detection_delay_s") return m->max_detection_delay_s();
  if (pattern == "methods.<method>.detection_delay_s.<fault>") {
    return m->max_detection_delay_s(args.fault);
  }
  if (pattern == "methods.<method>.false_exclusion_fraction") return m->false_exclusion_fraction();
  if (pattern == "methods.<method>.max_readmission_delay_s") return m->max_readmission_delay_s();
  return std::nullopt;
}

// A failed method's or flight's figures: every figure null beside its `failure`, what was
// measured up to the failure kept apart under `partial` (it would read as a healthy value).
// The digests that say whether two runs' methods saw the same samples (core/digest.h).
nlohmann::json DigestsJson(const RunRecord& record) {
  return {{"samples", record.samples_digest ? nlohmann::json(core::HexDigest(*record.samples_digest))
                                            : nlohmann::json(nullptr)},
          {"random_streams", core::HexDigest(record.random_streams_digest)}};
}

nlohmann::json MethodsJson(const RunRecord& record) {
  nlohmann::json methods = nlohmann::json::object();
  for (const MethodEvaluation& m : record.methods) methods[m.method] = replay::MethodEvaluationJson(m);
  return methods;
}

const RunRecord* FindClosedLoopFlight(const RunRecord& record, const std::string& method) {
  for (const RunRecord& flight : record.closed_loop_flights) {
    if (flight.closed_loop && flight.closed_loop->method == method) return &flight;
  }
  return nullptr;
}

std::optional<double> ClosedLoopMetricValue(const RunRecord& record, const std::string& pattern,
                                            const MetricArguments& args,
                                            const std::optional<std::pair<double, double>>& window_s) {
  const RunRecord* flight = FindClosedLoopFlight(record, args.method);
  if (flight == nullptr || ClosedLoopFlightFailure(*flight)) return std::nullopt;
  if (window_s) {
    // Tracking over part of the flight (e.g. while an absolute sensor is in view).
    const auto position = [](const TrackingSample& s) { return s.position_error_m; };
    const Stats stats = TrackingStats(*flight, window_s, position);
    if (pattern == "closed_loop.<method>.tracking_rmse_m") return stats.rmse();
    if (pattern == "closed_loop.<method>.tracking_max_m") return stats.maximum();
  }
  const ClosedLoopMetrics m = ComputeClosedLoopMetrics(*flight);
  if (pattern == "closed_loop.<method>.tracking_rmse_m") return m.tracking_rmse_m;
  if (pattern == "closed_loop.<method>.tracking_max_m") return m.tracking_max_m;
  if (pattern == "closed_loop.<method>.estimate_ate_m") return m.estimate_ate_m;
  if (pattern == "closed_loop.<method>.collisions") return static_cast<double>(m.collisions);
  if (pattern == "closed_loop.<method>.min_structure_distance_m") {
    return m.min_structure_distance_m;
  }
  if (pattern == "closed_loop.<method>.time_to_first_collision_s") {
    return m.time_to_first_collision_s;
  }
  if (pattern == "closed_loop.<method>.failsafe_events") {
    return static_cast<double>(m.failsafe_events);
  }
  if (pattern == "closed_loop.<method>.diverged") return m.diverged ? 1.0 : 0.0;
  if (pattern == "closed_loop.<method>.handover_s") return m.handover_s;
  return std::nullopt;
}

}  // namespace

ClosedLoopMetrics ComputeClosedLoopMetrics(const RunRecord& flight) {
  ClosedLoopMetrics m;
  if (!flight.closed_loop) return m;
  const ClosedLoopFlight& cl = *flight.closed_loop;
  double sum = 0.0;
  for (const TrackingSample& t : flight.tracking) {
    sum += t.position_error_m * t.position_error_m;
    m.tracking_max_m = std::max(m.tracking_max_m.value_or(0.0), t.position_error_m);
  }
  if (!flight.tracking.empty()) {
    m.tracking_rmse_m = std::sqrt(sum / static_cast<double>(flight.tracking.size()));
  }
  // The estimate the controller flew on against the truth at the same output instants.
  double est_sum = 0.0;
  std::size_t est_count = 0;
  for (const ClosedLoopSample& s : cl.samples) {
    if (!s.estimate_squared_error_m2 || s.mode == FlightMode::kTruth) continue;
    est_sum += *s.estimate_squared_error_m2;
    ++est_count;
  }
  if (est_count > 0) m.estimate_ate_m = std::sqrt(est_sum / static_cast<double>(est_count));
  m.collisions = flight.collisions.size();
  m.min_structure_distance_m = flight.closest_structure
                                   ? flight.closest_structure->proximity.distance_m
                                   : flight.distance_horizon_m;
  if (!flight.collisions.empty()) {
    m.time_to_first_collision_s = core::TimeToSeconds(flight.collisions.front().start_ns);
  }
  for (const FlightEvent& e : cl.events) m.failsafe_events += e.event == "failsafe_start" ? 1 : 0;
  m.diverged = m.tracking_max_m.value_or(0.0) > cl.control.corridor_m;
  if (cl.handover_ns) m.handover_s = core::TimeToSeconds(*cl.handover_ns);
  return m;
}

// The user's estimators and controllers that failed in this run: the open-loop methods,
// and the closed-loop flights of a client method (a flight on tofu's own methods that fails
// is the simulation's failure, reported as such).
std::vector<std::string> ClientFailures(const RunRecord& record) {
  std::vector<std::string> failures;
  for (const MethodEvaluation& m : record.methods) {
    if (m.failure) failures.push_back(*m.failure);
  }
  for (const RunRecord& flight : record.closed_loop_flights) {
    const std::string& method = flight.closed_loop->method;
    if (flight.failure && (method.starts_with("external:") || method.starts_with("plugin:") ||
                           flight.scenario.control->controller)) {
      failures.push_back(fmt::format("closed-loop flight on {}: {}", method, *flight.failure));
    }
    // The flight ended, but its estimator failed at the end (finish, exit status).
    for (const MethodEvaluation& m : flight.methods) {
      if (m.failure) failures.push_back(fmt::format("closed-loop flight on {}: {}", method, *m.failure));
    }
  }
  return failures;
}

std::optional<std::string> ClosedLoopFlightFailure(const RunRecord& flight) {
  if (flight.failure) return flight.failure;
  for (const MethodEvaluation& m : flight.methods) {
    if (m.failure) return m.failure;
  }
  return std::nullopt;
}

nlohmann::json ClosedLoopJson(const RunRecord& flight) {
  const ClosedLoopMetrics m = ComputeClosedLoopMetrics(flight);
  nlohmann::json events = nlohmann::json::array();
  if (flight.closed_loop) {
    for (const FlightEvent& e : flight.closed_loop->events) {
      events.push_back({{"t_s", core::TimeToSeconds(e.t_ns)}, {"event", e.event},
                        {"detail", e.detail}});
    }
  }
  nlohmann::json j = {{"tracking_rmse_m", NumberOrNull(m.tracking_rmse_m)},
          {"tracking_max_m", NumberOrNull(m.tracking_max_m)},
          {"estimate_ate_m", NumberOrNull(m.estimate_ate_m)},
          {"collisions", m.collisions},
          {"min_structure_distance_m", NumberOrNull(m.min_structure_distance_m)},
          {"time_to_first_collision_s", NumberOrNull(m.time_to_first_collision_s)},
          {"failsafe_events", m.failsafe_events},
          {"diverged", m.diverged},
          {"handover_s", NumberOrNull(m.handover_s)},
          {"corridor_m", flight.closed_loop ? flight.closed_loop->control.corridor_m : 0.0},
          {"digests", DigestsJson(flight)}};
  if (const std::optional<std::string> failure = ClosedLoopFlightFailure(flight)) {
    j = FailedFiguresJson(std::move(j), *failure);
  } else {
    j["failure"] = nullptr;
  }
  // What the pilot did is an account of the flight, not a figure: kept as it is.
  j["events"] = std::move(events);
  return j;
}

std::optional<double> MetricValue(const RunRecord& record, const std::string& metric,
                                  const std::optional<std::pair<double, double>>& window_s) {
  const auto position = [](const TrackingSample& s) { return s.position_error_m; };
  const auto attitude = [](const TrackingSample& s) { return s.attitude_error_rad * kDegPerRad; };
  if (metric == "tracking.position_rmse_m") return TrackingStats(record, window_s, position).rmse();
  if (metric == "tracking.position_max_m") {
    return TrackingStats(record, window_s, position).maximum();
  }
  if (metric == "tracking.attitude_rmse_deg") {
    return TrackingStats(record, window_s, attitude).rmse();
  }
  if (metric == "tracking.attitude_max_deg") {
    return TrackingStats(record, window_s, attitude).maximum();
  }
  if (metric == "tracking.final_position_error_m") {
    if (record.tracking.empty()) return std::nullopt;
    return record.tracking.back().position_error_m;
  }
  if (metric == "collisions.count") return static_cast<double>(record.collisions.size());
  if (metric == "structure.min_distance_m") {
    // Beyond the horizon nothing is measured; the horizon is then a lower bound.
    return record.closest_structure ? record.closest_structure->proximity.distance_m
                                    : record.distance_horizon_m;
  }
  if (metric == "allocation.saturation_fraction") {
    size_t count = 0;
    size_t saturated = 0;
    for (const auto& [t_ns, is_saturated] : record.saturation) {
      if (!InWindow(t_ns, window_s)) continue;
      ++count;
      saturated += is_saturated ? 1 : 0;
    }
    if (count == 0) return std::nullopt;
    return static_cast<double>(saturated) / static_cast<double>(count);
  }
  if (metric == "approach.max_standoff_error_m") {
    std::optional<double> worst;
    for (const ApproachResult& a : record.approaches) {
      if (!a.distance_m) return std::nullopt;
      const double error = std::abs(*a.distance_m - a.standoff_m);
      worst = std::max(worst.value_or(0.0), error);
    }
    return worst;
  }
  if (const auto match = MatchMetric(metric); match && !match->second.sensor.empty()) {
    return SensorMetricValue(record, match->first->name, match->second, window_s);
  }
  if (const auto match = MatchMetric(metric); match && !match->second.method.empty()) {
    if (metric.starts_with("closed_loop.")) {
      return ClosedLoopMetricValue(record, match->first->name, match->second, window_s);
    }
    return MethodMetricValue(record, match->first->name, match->second);
  }
  throw std::invalid_argument("unknown metric '" + metric + "'");
}

namespace {

nlohmann::json CollisionsJson(const RunRecord& record) {
  nlohmann::json collisions = nlohmann::json::array();
  for (const CollisionEvent& e : record.collisions) {
    collisions.push_back({{"start_s", core::TimeToSeconds(e.start_ns)},
                          {"end_s", core::TimeToSeconds(e.end_ns)},
                          {"robot_geom", e.robot_geom},
                          {"structure_geom", e.structure_geom},
                          {"max_penetration_m", e.max_penetration_m}});
  }
  return collisions;
}

nlohmann::json ClosestStructureJson(const RunRecord& record) {
  if (!record.closest_structure) {
    return {{"distance_m", nullptr}, {"horizon_m", record.distance_horizon_m}};
  }
  const ProximityRecord& p = *record.closest_structure;
  return {{"distance_m", p.proximity.distance_m},
          {"t_s", core::TimeToSeconds(p.t_ns)},
          {"horizon_m", record.distance_horizon_m}};
}

nlohmann::json ApproachesJson(const RunRecord& record) {
  nlohmann::json approaches = nlohmann::json::array();
  for (const ApproachResult& a : record.approaches) {
    approaches.push_back({{"segment", a.segment_index},
                          {"t_s", core::TimeToSeconds(a.t_ns)},
                          {"standoff_m", a.standoff_m},
                          {"tool_tip_distance_m", NumberOrNull(a.distance_m)}});
  }
  return approaches;
}

// Per stream: samples produced and delivered, and the time share of each condition over
// the `run_s` seconds simulated.
nlohmann::json SensorsJson(const RunRecord& record, double run_s) {
  nlohmann::json sensors = nlohmann::json::object();
  for (const SensorStream& stream : record.sensors) {
    nlohmann::json conditions = nlohmann::json::object();
    for (const sim::Condition c : sim::AllConditions()) {
      const std::string name(sim::ConditionName(c));
      const double active_s = ConditionActiveSeconds(record, stream.name, name, 0.0, run_s);
      if (active_s > 0.0 && run_s > 0.0) conditions[name] = active_s / run_s;
    }
    MetricArguments stream_args;
    stream_args.sensor = stream.name;
    sensors[stream.name] = {
        {"type", stream.type},
        {"site", stream.site},
        {"samples", stream.produced_count},
        {"delivered", stream.delivered_count},
        {"condition_time_fraction", conditions},
        {"position_error_rms_m",
         NumberOrNull(SensorMetricValue(record, "sensors.<sensor>.position_error_rms_m",
                                          stream_args, std::nullopt))}};
  }
  return sensors;
}

// The expectation's metric (relative to its `relative_to` metric, if any) and whether it
// is within [min, max].
// Why `metric` has no value to judge in `record`: the simulation failed, or the metric is
// a failed method's or closed-loop flight's. nullopt when it is measurable.
std::optional<std::string> NotMeasurable(const RunRecord& record, const std::string& metric) {
  if (record.failure) return "the simulation failed: " + *record.failure;
  const auto match = MatchMetric(metric);
  if (!match || match->second.method.empty()) return std::nullopt;
  const std::string& method = match->second.method;
  if (metric.starts_with("closed_loop.")) {
    const RunRecord* flight = FindClosedLoopFlight(record, method);
    const std::optional<std::string> failure =
        flight != nullptr ? ClosedLoopFlightFailure(*flight) : std::nullopt;
    if (failure) return fmt::format("the closed-loop flight on {} failed: {}", method, *failure);
    return std::nullopt;
  }
  const MethodEvaluation* m = FindMethod(record, method);
  if (m != nullptr && m->failure) return fmt::format("method {} failed: {}", method, *m->failure);
  return std::nullopt;
}

ExpectationResult CheckExpectation(const RunRecord& record, const Expectation& e) {
  ExpectationResult r{e, MetricValue(record, e.metric, e.window_s), false, std::nullopt};
  r.not_measurable = NotMeasurable(record, e.metric);
  if (!r.not_measurable && e.relative_to) r.not_measurable = NotMeasurable(record, *e.relative_to);
  if (r.not_measurable) {
    r.value = std::nullopt;
    return r;
  }
  if (e.relative_to) {
    const std::optional<double> base = MetricValue(record, *e.relative_to, e.window_s);
    r.value = r.value && base && *base > 0.0 ? std::optional<double>(*r.value / *base)
                                             : std::nullopt;
  }
  r.passed = r.value.has_value() && (!e.min || *r.value >= *e.min) &&
             (!e.max || *r.value <= *e.max);
  return r;
}

nlohmann::json ExpectationJson(const Expectation& e, const ExpectationResult& r) {
  nlohmann::json je = {{"metric", e.metric},
                       {"min", NumberOrNull(e.min)},
                       {"max", NumberOrNull(e.max)},
                       {"value", NumberOrNull(r.value)},
                       {"passed", r.passed},
                       {"where", e.location.file + ":" + std::to_string(e.location.line)}};
  if (r.not_measurable) je["not_measurable"] = *r.not_measurable;
  if (e.window_s) je["window_s"] = {e.window_s->first, e.window_s->second};
  if (e.relative_to) je["relative_to"] = *e.relative_to;
  return je;
}

}  // namespace

Evaluation Evaluate(const RunRecord& record) {
  Evaluation eval;
  const Scenario& sc = record.scenario;
  nlohmann::json& j = eval.summary;
  j["scenario"] = sc.name;
  j["world"] = sc.world;
  j["robot"] = sc.robot;
  j["seed"] = sc.seed;
  j["duration_s"] = sc.duration_s;
  j["physics_steps"] = record.physics_steps;
  j["simulated_s"] = core::TimeToSeconds(record.physics_steps *
                                         core::PeriodFromRate(sc.physics.rate_hz));
  j["digests"] = DigestsJson(record);

  nlohmann::json metrics = nlohmann::json::object();
  for (const MetricInfo& info : MetricCatalog()) {
    if (info.name.find('<') != std::string::npos) continue;  // per sensor: see "sensors"
    metrics[info.name] = NumberOrNull(MetricValue(record, info.name, std::nullopt));
  }
  j["metrics"] = metrics;
  j["collisions"] = CollisionsJson(record);
  j["closest_structure"] = ClosestStructureJson(record);
  j["approaches"] = ApproachesJson(record);
  const double run_s = core::TimeToSeconds(record.physics_steps *
                                           core::PeriodFromRate(sc.physics.rate_hz));
  j["sensors"] = SensorsJson(record, run_s);
  size_t fault_labels = 0;
  for (const LabelEvent& l : record.labels) fault_labels += l.source == "fault" && l.active ? 1 : 0;
  j["faults_scheduled"] = fault_labels;
  if (sc.estimation) j["methods"] = MethodsJson(record);
  if (record.closed_loop) j["closed_loop_flight"] = ClosedLoopJson(record);
  if (!record.closed_loop_flights.empty()) {
    nlohmann::json closed_loop = nlohmann::json::object();
    for (const RunRecord& flight : record.closed_loop_flights) {
      closed_loop[flight.closed_loop->method] = ClosedLoopJson(flight);
    }
    j["closed_loop"] = closed_loop;
  }

  bool all_passed = !record.failure.has_value();
  for (const RunRecord& flight : record.closed_loop_flights) {
    all_passed = all_passed && !flight.failure.has_value();
  }
  eval.client_failures = ClientFailures(record);
  all_passed = all_passed && eval.client_failures.empty();
  // One place for what failed: the simulation, else the first client (each failed method
  // and flight says its own beside its figures).
  if (record.failure) {
    j["failure"] = *record.failure;
    j["failure_kind"] = "simulation";
  } else if (!eval.client_failures.empty()) {
    j["failure"] = eval.client_failures.front();
    j["failure_kind"] = "client";
  } else {
    j["failure"] = nullptr;
    j["failure_kind"] = nullptr;
  }
  nlohmann::json expectations = nlohmann::json::array();
  for (const Expectation& e : sc.expect) {
    const ExpectationResult r = CheckExpectation(record, e);
    all_passed = all_passed && r.passed;
    expectations.push_back(ExpectationJson(e, r));
    eval.expectations.push_back(r);
  }
  j["expectations"] = expectations;
  j["passed"] = all_passed;
  eval.passed = all_passed;
  return eval;
}

}  // namespace tofu::harness
