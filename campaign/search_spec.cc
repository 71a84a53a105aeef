#include "campaign/search_spec.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <set>

#include <fmt/format.h>
#include <fmt/ranges.h>
#include <yaml-cpp/yaml.h>

#include "core/error.h"
#include "core/file_io.h"
#include "core/units.h"
#include "harness/client_config.h"
#include "harness/yaml_reader.h"

namespace tofu::campaign {

namespace {

namespace fs = std::filesystem;
using core::FormatDouble;
using core::InputError;
using core::NumberRule;
using harness::YamlMap;
using harness::YamlValue;

using corpus::Round4;

// A search range: two numbers in `rule` with lo < hi (a range of no width searches
// nothing: say the value in the base instead).
corpus::Range ReadSearchRange(const YamlValue& value, const NumberRule& rule) {
  if (!value.node().IsSequence()) value.FailExpected("a range [lo, hi] with lo < hi");
  const std::vector<double> v = value.Numbers(2, rule);
  if (!(v[0] < v[1])) {
    value.Fail(fmt::format("empty range [{}, {}]: expected [lo, hi] with lo < hi", FormatDouble(v[0]),
                           FormatDouble(v[1])));
  }
  return {v[0], v[1]};
}

std::string Emit(const YAML::Node& node) {
  YAML::Emitter out;
  out << node;
  return std::string(out.c_str()) + "\n";
}

// "a.b[2].c" as steps: a map key, or a list index.
struct PathStep {
  std::string key;
  std::optional<std::size_t> index;
};

std::optional<std::vector<PathStep>> SplitPath(const std::string& path) {
  std::vector<PathStep> steps;
  std::size_t i = 0;
  while (i < path.size()) {
    if (path[i] == '[') {
      const std::size_t close = path.find(']', i);
      if (close == std::string::npos || close == i + 1) return std::nullopt;
      const std::string digits = path.substr(i + 1, close - i - 1);
      if (!std::all_of(digits.begin(), digits.end(), [](char c) { return c >= '0' && c <= '9'; })) {
        return std::nullopt;
      }
      steps.push_back({"", static_cast<std::size_t>(std::stoul(digits))});
      i = close + 1;
      if (i < path.size() && path[i] == '.') ++i;
      continue;
    }
    std::size_t end = path.find_first_of(".[", i);
    if (end == std::string::npos) end = path.size();
    if (end == i) return std::nullopt;
    steps.push_back({path.substr(i, end - i), std::nullopt});
    i = end;
    if (i < path.size() && path[i] == '.') ++i;
  }
  if (steps.empty()) return std::nullopt;
  return steps;
}

// The node at `steps` below `root`, and whether its parent exists (a map, for a missing
// last key). yaml-cpp nodes are handles: reset() rebinds, assignment would overwrite.
struct Located {
  bool found = false;
  YAML::Node node;
  bool parent_is_map = false;
};

Located Locate(const YAML::Node& root, const std::vector<PathStep>& steps) {
  YAML::Node cur;
  cur.reset(root);
  Located result;
  for (std::size_t i = 0; i < steps.size(); ++i) {
    const PathStep& s = steps[i];
    const YAML::Node& here = cur;  // const lookups: a missing key is not inserted
    YAML::Node next;
    if (s.index) {
      if (!here.IsSequence() || *s.index >= here.size()) return result;
      next.reset(here[*s.index]);
    } else {
      if (!here.IsMap()) return result;
      if (i + 1 == steps.size()) result.parent_is_map = true;
      if (!here[s.key]) return result;
      next.reset(here[s.key]);
    }
    cur.reset(next);
  }
  result.found = true;
  result.node.reset(cur);
  return result;
}

void SetAt(YAML::Node& root, const std::vector<PathStep>& steps, const std::optional<std::string>& text) {
  YAML::Node cur;
  cur.reset(root);
  for (std::size_t i = 0; i + 1 < steps.size(); ++i) {
    YAML::Node next;
    if (steps[i].index) {
      next.reset(cur[*steps[i].index]);
    } else {
      next.reset(cur[steps[i].key]);
    }
    cur.reset(next);
  }
  const PathStep& last = steps.back();
  if (last.index) {
    cur[*last.index] = *text;
  } else if (text) {
    cur[last.key] = *text;
  } else {
    cur.remove(last.key);
  }
}

std::vector<PathStep> StepsOf(const std::string& path) {
  auto steps = SplitPath(path);
  if (!steps) throw std::logic_error("search: an unchecked set path: " + path);
  return *steps;
}

void ReadSetKeys(const YamlValue& value, const YAML::Node& base_root, SearchSpec& spec) {
  for (const auto& [path, range_value] : value.StringEntries()) {
    const auto steps = SplitPath(path);
    if (!steps) {
      range_value.FailAtKey(fmt::format("'{}' is not a key path (expected keys joined by '.', list "
                                        "indices as [i], e.g. trajectory.segments[1].circle.speed_mps)",
                                        path));
    }
    SetKey key;
    key.path = path;
    key.range = ReadSearchRange(range_value, NumberRule::Any(""));
    const Located at = Locate(base_root, *steps);
    if (at.found) {
      double v = 0.0;
      if (!at.node.IsScalar() || !YAML::convert<double>::decode(at.node, v)) {
        range_value.FailAtKey(fmt::format("'{}' is not a number in the base scenario (expected the path "
                                          "of a numeric key)", path));
      }
      key.base_value = v;
    } else if (!at.parent_is_map) {
      range_value.FailAtKey(fmt::format("'{}' names no key of the base scenario (expected the path of a "
                                        "numeric key, or a key of one of its maps)", path));
    } else {
      // A key the base leaves to its default: the scenario format must take it there.
      YAML::Node trial = YAML::Clone(base_root);
      SetAt(trial, *steps, FormatDouble(key.range.lo));
      try {
        harness::ParseScenario(Emit(trial), spec.base_path.string());
      } catch (const InputError& e) {
        range_value.FailAtKey(fmt::format("'{}' is not a key the base scenario takes: {}", path, e.what()));
      }
    }
    spec.set.push_back(std::move(key));
  }
}

FaultSlot ReadFaultSlot(const YamlValue& value, const std::vector<std::string>& sensor_names,
                        double base_duration_s) {
  YamlMap m = value.Map({"kinds", "onset_s", "duration_s"});
  FaultSlot slot;
  for (const YamlValue& item : m.Required("kinds").List(true)) {
    const corpus::FaultChoice choice = corpus::ReadFaultChoice(item, sensor_names);
    for (const std::string& sensor : choice.sensors) {
      slot.options.push_back({choice.kind, sensor, choice.magnitude});
    }
  }
  const YamlValue onset = m.Required("onset_s");
  slot.onset_s = ReadSearchRange(onset, NumberRule::Between(0.0, 3600.0, "s"));
  if (slot.onset_s.hi >= base_duration_s) {
    onset.Fail(fmt::format("onset_s reaches the base's end ({} s): expected a range [lo, hi] with hi < {}",
                           FormatDouble(base_duration_s), FormatDouble(base_duration_s)));
  }
  slot.duration_s = ReadSearchRange(m.Required("duration_s"), NumberRule::Between(0.01, 3600.0, "s"));
  m.Finish();
  for (const FaultSlot::Option& o : slot.options) {
    slot.searches_magnitude = slot.searches_magnitude || o.magnitude.hi > o.magnitude.lo;
    slot.searches_direction = slot.searches_direction || o.kind == sim::FaultKind::kDivergence ||
                              o.kind == sim::FaultKind::kJump || o.kind == sim::FaultKind::kMisalignment;
  }
  return slot;
}

void ReadSpace(const YamlValue& value, const YAML::Node& base_root, SearchSpec& spec) {
  YamlMap m = value.Map({"seed", "set", "faults"});
  if (auto s = m.Optional("seed")) {
    spec.seed_range = ReadSearchRange(*s, NumberRule::Between(0.0, 9.0e15, ""));
    if (spec.seed_range->lo != std::floor(spec.seed_range->lo) ||
        spec.seed_range->hi != std::floor(spec.seed_range->hi)) {
      s->Fail("expected whole numbers [lo, hi] of seeds");
    }
  }
  if (auto s = m.Optional("set")) ReadSetKeys(*s, base_root, spec);
  std::vector<std::string> sensors;
  for (const harness::SensorConfig& sensor : spec.base.sensors) sensors.push_back(sensor.name);
  if (auto f = m.Optional("faults")) {
    for (const YamlValue& item : f->List(false)) spec.faults.push_back(ReadFaultSlot(item, sensors, spec.base.duration_s));
  }
  m.Finish();
  if (!spec.seed_range && spec.set.empty() && spec.faults.empty()) {
    m.self().Fail("the space is empty (expected at least one of seed, set, faults)");
  }
}

void ReadObjective(const YamlValue& value, SearchSpec& spec) {
  YamlMap m = value.Map({"expectations"});
  const YamlValue list = m.Required("expectations");
  std::vector<std::string> known;
  for (const harness::Expectation& e : spec.base.expect) known.push_back(e.metric);
  for (const YamlValue& item : list.List(true)) {
    const std::string metric = item.String();
    if (std::find(known.begin(), known.end(), metric) == known.end()) {
      const std::string near = harness::ClosestMatch(metric, known);
      item.Fail(fmt::format("'{}' names no expectation of the base scenario {}{} (expected the metric of one "
                            "of its expect: entries{})",
                            metric, spec.base_path.string(), near.empty() ? "" : fmt::format("; did you mean '{}'?", near),
                            known.empty() ? ", and it has none" : fmt::format(": {}", fmt::join(known, ", "))));
    }
    spec.objective_metrics.push_back(metric);
  }
  m.Finish();
}

void MakeDimensions(SearchSpec& spec) {
  if (spec.seed_range) spec.dimensions.push_back({"seed", 0});
  for (const SetKey& k : spec.set) spec.dimensions.push_back({"set." + k.path, 0});
  for (std::size_t i = 0; i < spec.faults.size(); ++i) {
    const std::string p = fmt::format("faults[{}].", i);
    const FaultSlot& slot = spec.faults[i];
    spec.dimensions.push_back({p + "option", static_cast<int>(slot.options.size())});
    spec.dimensions.push_back({p + "onset_s", 0});
    spec.dimensions.push_back({p + "duration_s", 0});
    if (slot.searches_magnitude) spec.dimensions.push_back({p + "magnitude", 0});
    if (slot.searches_direction) {
      spec.dimensions.push_back({p + "direction_z", 0});
      spec.dimensions.push_back({p + "direction_phi", 0});
    }
  }
}

double Lerp(const corpus::Range& r, double u) { return r.lo + std::clamp(u, 0.0, 1.0) * (r.hi - r.lo); }

std::size_t Choice(double u, std::size_t n) {
  return std::min(n - 1, static_cast<std::size_t>(std::max(0.0, u) * static_cast<double>(n)));
}

// The corners of the cube (all 0, all 1) and its centre, parsed as scenarios: a spec
// whose ranges leave the scenario format's limits is refused at load, not mid-search.
void CheckCorners(const SearchSpec& spec, const YamlValue& root) {
  for (const double u : {0.0, 0.5, 1.0}) {
    const std::vector<double> unit(spec.dimensions.size(), u);
    const std::string yaml = ScenarioYaml(spec, DecodePoint(spec, unit), spec.base.name);
    try {
      harness::ParseScenario(yaml, fmt::format("{} (the base with every parameter at {} of its range)",
                                               spec.base_path.string(), FormatDouble(u)));
    } catch (const InputError& e) {
      root.Fail(fmt::format("the space leaves the scenario format: {}", e.what()));
    }
  }
}

}  // namespace

const std::vector<std::string>& SearchOptimizers() {
  static const std::vector<std::string> names = {"random", "tpe"};
  return names;
}

SearchSpec ParseSearchSpec(const std::string& text, const std::string& file_label,
                           const fs::path& spec_dir) {
  SearchSpec spec;
  spec.file = file_label;
  spec.text = text;
  const YamlValue root = harness::ParseDocument(text, file_label);
  YamlMap top = root.Map({"name", "description", "base", "objective", "space", "budget", "optimizer",
                          "confirm", "dedupe", "shrink", "stop_at_first"});
  spec.name = top.Required("name").Identifier();
  if (auto d = top.Optional("description")) spec.description = d->String();
  const YamlValue base = top.Required("base");
  spec.base_path = fs::absolute(spec_dir / base.String()).lexically_normal();
  std::error_code status_error;  // a name the file system refuses (too long, ...) is no file
  if (!fs::is_regular_file(spec.base_path, status_error)) {
    base.Fail(fmt::format("cannot read the base scenario {} (expected a scenario file, relative to the "
                          "spec's directory)", spec.base_path.string()));
  }
  spec.base_text = core::ReadWholeFile(spec.base_path, "scenario", core::kMaxConfigFileBytes);
  spec.base = harness::ParseScenario(spec.base_text, spec.base_path.string());
  const YAML::Node base_root = YAML::Load(spec.base_text);

  ReadObjective(top.Required("objective"), spec);
  ReadSpace(top.Required("space"), base_root, spec);
  {
    YamlMap b = top.Required("budget").Map({"simulations", "batch"});
    const YamlValue sims = b.Required("simulations");
    spec.budget = sims.UnsignedInteger();
    if (spec.budget == 0 || spec.budget > 1'000'000) {
      sims.Fail(fmt::format("a budget of {} simulations (expected a whole number in [1, 1000000])", spec.budget));
    }
    if (auto batch = b.Optional("batch")) {
      spec.batch = batch->UnsignedInteger();
      if (spec.batch == 0 || spec.batch > 256) {
        batch->Fail(fmt::format("a batch of {} (expected a whole number in [1, 256])", spec.batch));
      }
    }
    b.Finish();
  }
  if (auto o = top.Optional("optimizer")) {
    YamlMap om = o->Map({"name", "seed"});
    const YamlValue name = om.Required("name");
    spec.optimizer = name.String();
    const auto& known = SearchOptimizers();
    if (std::find(known.begin(), known.end(), spec.optimizer) == known.end()) {
      name.Fail(fmt::format("unknown optimizer '{}' (expected one of: {})", spec.optimizer, fmt::join(known, ", ")));
    }
    if (auto s = om.Optional("seed")) spec.optimizer_seed = s->UnsignedInteger();
    om.Finish();
  }
  if (auto c = top.Optional("confirm")) {
    YamlMap cm = c->Map({"seeds", "min_failure_rate"});
    if (auto s = cm.Optional("seeds")) {
      spec.confirm.seeds = static_cast<int>(s->Number(NumberRule::Between(1.0, 1000.0, "")));
      if (spec.confirm.seeds != s->Number(NumberRule::Any(""))) s->FailExpected("a whole number in [1, 1000]");
    }
    if (auto r = cm.Optional("min_failure_rate")) {
      spec.confirm.min_failure_rate = r->Number(NumberRule::Between(0.0, 1.0, ""));
      if (spec.confirm.min_failure_rate <= 0.0) r->FailExpected("a rate in (0, 1]");
    }
    cm.Finish();
  }
  if (auto d = top.Optional("dedupe")) {
    YamlMap dm = d->Map({"distance"});
    spec.dedupe_distance = dm.Required("distance").Number(NumberRule::Between(0.0, 1.0, ""));
    dm.Finish();
  }
  if (auto s = top.Optional("shrink")) {
    YamlMap sm = s->Map({"steps"});
    const YamlValue steps = sm.Required("steps");
    spec.shrink_steps = static_cast<int>(steps.Number(NumberRule::Between(0.0, 20.0, "")));
    if (spec.shrink_steps != steps.Number(NumberRule::Any(""))) steps.FailExpected("a whole number in [0, 20]");
    sm.Finish();
  }
  if (auto s = top.Optional("stop_at_first")) spec.stop_at_first = s->Bool();
  top.Finish();
  MakeDimensions(spec);
  CheckCorners(spec, root);
  return spec;
}

SearchSpec LoadSearchSpec(const fs::path& path) {
  return ParseSearchSpec(core::ReadWholeFile(path, "search spec", core::kMaxConfigFileBytes), path.string(),
                         fs::absolute(path).parent_path());
}

Setting DecodePoint(const SearchSpec& spec, const std::vector<double>& unit) {
  if (unit.size() != spec.dimensions.size()) {
    throw std::invalid_argument(fmt::format("search: a point of {} coordinates in a space of {}", unit.size(),
                                            spec.dimensions.size()));
  }
  Setting s;
  std::size_t d = 0;
  s.seed = spec.base.seed;
  if (spec.seed_range) {
    const auto lo = static_cast<uint64_t>(spec.seed_range->lo);
    const auto count = static_cast<std::size_t>(spec.seed_range->hi - spec.seed_range->lo) + 1;
    s.seed = lo + Choice(unit[d++], count);
  }
  for (const SetKey& k : spec.set) s.set_values.push_back(Round4(Lerp(k.range, unit[d++])));
  for (const FaultSlot& slot : spec.faults) {
    FaultSetting f;
    f.option = Choice(unit[d++], slot.options.size());
    f.onset_s = Round4(Lerp(slot.onset_s, unit[d++]));
    f.duration_s = Round4(Lerp(slot.duration_s, unit[d++]));
    // Without a coordinate: the middle of the magnitude range; the direction +x.
    const double u_magnitude = slot.searches_magnitude ? unit[d++] : 0.5;
    f.magnitude = Round4(Lerp(slot.options[f.option].magnitude, u_magnitude));
    const double u_z = slot.searches_direction ? unit[d++] : 0.5;
    const double u_phi = slot.searches_direction ? unit[d++] : 0.0;
    f.direction_z = Round4(2.0 * std::clamp(u_z, 0.0, 1.0) - 1.0);
    f.direction_phi = Round4(2.0 * core::kPi * std::clamp(u_phi, 0.0, 1.0));
    s.faults.push_back(f);
  }
  return s;
}

Setting BaseSetting(const SearchSpec& spec) {
  Setting s;
  s.seed = spec.base.seed;
  for (const SetKey& k : spec.set) {
    s.set_values.push_back(k.base_value ? *k.base_value : std::numeric_limits<double>::quiet_NaN());
  }
  s.faults.assign(spec.faults.size(), FaultSetting{});
  for (FaultSetting& f : s.faults) f.present = false;
  return s;
}

namespace {

// The method a metric reads: "methods.<method>.…" or "closed_loop.<method>.…".
std::optional<std::string> MethodOf(const std::string& metric, const std::string& prefix) {
  if (!metric.starts_with(prefix)) return std::nullopt;
  const std::size_t end = metric.find('.', prefix.size());
  return metric.substr(prefix.size(), end == std::string::npos ? std::string::npos : end - prefix.size());
}

// Only what the objective reads (ScenarioScope::kObjective).
void KeepObjectiveOnly(const SearchSpec& spec, YAML::Node& root) {
  std::vector<std::string> metrics;
  for (const harness::Expectation& e : spec.base.expect) {
    if (std::find(spec.objective_metrics.begin(), spec.objective_metrics.end(), e.metric) == spec.objective_metrics.end()) {
      continue;
    }
    metrics.push_back(e.metric);
    if (e.relative_to) metrics.push_back(*e.relative_to);
  }
  std::set<std::string> methods, flights;
  for (const std::string& m : metrics) {
    if (auto method = MethodOf(m, "methods.")) methods.insert(*method);
    if (auto flight = MethodOf(m, "closed_loop.")) flights.insert(*flight);
  }
  methods.insert(flights.begin(), flights.end());  // a closed loop flies one of the methods
  if (YAML::Node control = root["control"]; control && control["methods"]) {
    YAML::Node kept(YAML::NodeType::Sequence);
    for (const YAML::Node& m : control["methods"]) {
      if (flights.count(m.as<std::string>())) kept.push_back(m);
    }
    if (kept.size() == 0) {
      root.remove("control");
    } else {
      root["control"]["methods"] = kept;
    }
  }
  if (YAML::Node estimation = root["estimation"]; estimation && estimation["methods"]) {
    YAML::Node kept(YAML::NodeType::Sequence);
    for (const YAML::Node& m : estimation["methods"]) {
      if (methods.count(m.as<std::string>())) kept.push_back(m);
    }
    if (kept.size() == 0 && !root["control"]) {
      root.remove("estimation");
    } else {
      root["estimation"]["methods"] = kept;
    }
  }
  root.remove("render");
}

}  // namespace

std::string ScenarioYaml(const SearchSpec& spec, const Setting& setting, const std::string& name,
                         const std::vector<std::string>& expect_metrics, ScenarioScope scope) {
  YAML::Node root = YAML::Clone(YAML::Load(spec.base_text));
  if (scope == ScenarioScope::kObjective) KeepObjectiveOnly(spec, root);
  const std::vector<std::string>& kept_metrics = scope == ScenarioScope::kObjective ? spec.objective_metrics : expect_metrics;
  root["name"] = name;
  root["seed"] = std::to_string(setting.seed);
  for (std::size_t i = 0; i < spec.set.size(); ++i) {
    const double v = setting.set_values.at(i);
    SetAt(root, StepsOf(spec.set[i].path),
          std::isnan(v) ? std::nullopt : std::optional<std::string>(FormatDouble(v)));
  }
  bool any_fault = false;
  for (const FaultSetting& f : setting.faults) any_fault = any_fault || f.present;
  if (any_fault) {
    YAML::Node faults = root["faults"];
    if (!faults.IsSequence()) {
      root["faults"] = YAML::Node(YAML::NodeType::Sequence);
    }
    for (std::size_t k = 0; k < setting.faults.size(); ++k) {
      const FaultSetting& f = setting.faults[k];
      if (!f.present) continue;
      const FaultSlot::Option& option = spec.faults.at(k).options.at(f.option);
      corpus::PlannedFault planned;
      planned.sensor = option.sensor;
      planned.kind = option.kind;
      planned.start_s = f.onset_s;
      // A fault lasting past the flight ends with it (the scenario format's limit).
      planned.end_s = std::min(Round4(f.onset_s + f.duration_s), spec.base.duration_s);
      planned.magnitude = f.magnitude;
      YAML::Node fault = YAML::Load(corpus::FaultYaml(planned, corpus::UnitDirection(f.direction_z, f.direction_phi)));
      fault.SetStyle(YAML::EmitterStyle::Flow);
      root["faults"].push_back(fault);
    }
  }
  if (!kept_metrics.empty() && root["expect"]) {
    YAML::Node kept(YAML::NodeType::Sequence);
    for (const YAML::Node& e : root["expect"]) {
      const std::string metric = e["metric"] ? e["metric"].as<std::string>() : std::string();
      if (std::find(kept_metrics.begin(), kept_metrics.end(), metric) != kept_metrics.end()) {
        kept.push_back(e);
      }
    }
    root["expect"] = kept;
  }
  // Users' clients with absolute paths: the file is written away from the base.
  if (!spec.base.clients.empty()) {
    root.remove("external");
    root.remove("plugins");
    YAML::Emitter clients;
    clients << YAML::BeginMap;
    harness::EmitClients(clients, spec.base.clients);
    clients << YAML::EndMap;
    const YAML::Node resolved = YAML::Load(clients.c_str());
    for (const auto& entry : resolved) root[entry.first.as<std::string>()] = entry.second;
  }
  return Emit(root);
}

std::vector<std::string> DescribeSetting(const SearchSpec& spec, const Setting& setting) {
  std::vector<std::string> lines;
  if (spec.seed_range) lines.push_back(fmt::format("seed: {}", setting.seed));
  for (std::size_t i = 0; i < spec.set.size(); ++i) {
    const double v = setting.set_values[i];
    lines.push_back(fmt::format("{}: {}", spec.set[i].path, std::isnan(v) ? "(as the base)" : FormatDouble(v)));
  }
  for (std::size_t k = 0; k < setting.faults.size(); ++k) {
    const FaultSetting& f = setting.faults[k];
    if (!f.present) {
      lines.push_back(fmt::format("faults[{}]: none", k));
      continue;
    }
    const FaultSlot::Option& o = spec.faults[k].options[f.option];
    const bool sized = o.magnitude.hi > 0.0;
    lines.push_back(fmt::format("faults[{}]: {} on {}, {}-{} s{}", k, sim::FaultKindName(o.kind), o.sensor,
                                FormatDouble(f.onset_s),
                                FormatDouble(std::min(Round4(f.onset_s + f.duration_s), spec.base.duration_s)),
                                sized ? fmt::format(", magnitude {}", FormatDouble(f.magnitude)) : ""));
  }
  return lines;
}

}  // namespace tofu::campaign
