#include "corpus/corpus_spec.h"

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <sstream>

#include <fmt/format.h>
#include <fmt/ranges.h>
#include <Eigen/Geometry>
#include <yaml-cpp/yaml.h>

#include "core/error.h"
#include "core/file_io.h"
#include "core/random.h"
#include "core/units.h"
#include "harness/client_config.h"
#include "harness/scenario.h"
#include "harness/yaml_reader.h"
#include "replay/file_io.h"

namespace tofu::corpus {

double Round4(double v) { return std::round(v * 1e4) / 1e4 + 0.0; }  // + 0.0: no "-0"

namespace {

namespace fs = std::filesystem;

using core::FormatDouble;
using core::NumberRule;
using harness::YamlMap;
using harness::YamlValue;

using core::kPi;

}  // namespace

Range ReadRange(const YamlValue& value, const NumberRule& rule) {
  if (value.node().IsScalar()) {
    const double v = value.Number(rule);
    return {v, v};
  }
  const std::vector<double> v = value.Numbers(2, rule);
  if (v[0] > v[1]) value.Fail(fmt::format("expected a range [lo, hi] with lo <= hi, got [{}, {}]",
                                          FormatDouble(v[0]), FormatDouble(v[1])));
  return {v[0], v[1]};
}

namespace {

Eigen::Vector2d ReadXY(const YamlValue& value) {
  const std::vector<double> v = value.Numbers(2, NumberRule::Any("m"));
  return {v[0], v[1]};
}

// The YAML text of a node, block style (a verbatim copy of a spec's block).
std::string EmitNode(const YAML::Node& node) {
  YAML::Emitter out;
  out << node;
  return out.c_str();
}

std::string Indent(const std::string& text, const std::string& prefix) {
  std::istringstream in(text);
  std::string line, out;
  while (std::getline(in, line)) out += prefix + line + "\n";
  return out;
}

double Draw(core::RandomStream& random, const Range& r) {
  // Always one draw, constant or not, so that a spec's other draws do not shift when a
  // range is narrowed to a constant.
  const double u = random.Uniform(0.0, 1.0);
  return r.lo + u * (r.hi - r.lo);
}

std::size_t DrawIndex(core::RandomStream& random, std::size_t n) {
  const double u = random.Uniform(0.0, 1.0);
  return std::min(n - 1, static_cast<std::size_t>(u * static_cast<double>(n)));
}

// A unit vector uniformly on the sphere (a fault's direction).
Eigen::Vector3d DrawDirection(core::RandomStream& random) {
  const double z = random.Uniform(-1.0, 1.0);
  const double phi = random.Uniform(0.0, 2.0 * kPi);
  return UnitDirection(z, phi);
}

std::string Vec(const Eigen::Vector3d& v) {
  return fmt::format("[{}, {}, {}]", FormatDouble(v.x()), FormatDouble(v.y()), FormatDouble(v.z()));
}


}  // namespace

Eigen::Vector3d UnitDirection(double z, double phi_rad) {
  const double r = std::sqrt(std::max(0.0, 1.0 - z * z));
  return {r * std::cos(phi_rad), r * std::sin(phi_rad), z};
}

std::string FaultYaml(const PlannedFault& fault, const Eigen::Vector3d& direction) {
  const Eigen::Vector3d d = direction;
  const double magnitude = fault.magnitude;
  const std::string head = fmt::format("{{sensor: {}, kind: {}, start_s: {}, end_s: {}", fault.sensor,
                                       sim::FaultKindName(fault.kind), FormatDouble(fault.start_s),
                                       FormatDouble(fault.end_s));
  switch (fault.kind) {
    case sim::FaultKind::kDivergence:
      return head + fmt::format(", axis: {}, initial_velocity_mps: {}, time_constant_s: 8}}",
                                Vec(d.unaryExpr(&Round4)), FormatDouble(magnitude));
    case sim::FaultKind::kJump:
      return head + fmt::format(", translation_m: {}}}", Vec((magnitude * d).unaryExpr(&Round4)));
    case sim::FaultKind::kNonGaussianNoise:
      return head + fmt::format(", white_std_m: {}, brown_std_m_per_sqrt_s: {}}}", FormatDouble(magnitude),
                                FormatDouble(Round4(magnitude / 3.0)));
    case sim::FaultKind::kOutliers:
      return head + fmt::format(", rate_hz: 1, scale_m: {}}}", FormatDouble(magnitude));
    case sim::FaultKind::kDelay:
      return head + fmt::format(", delay_s: {}}}", FormatDouble(magnitude));
    case sim::FaultKind::kMisalignment:
      return head + fmt::format(", rpy_deg: {}}}", Vec((magnitude * d).unaryExpr(&Round4)));
    case sim::FaultKind::kDropout:
    case sim::FaultKind::kFreeze:
      break;
  }
  return head + "}";
}

namespace {

// A circle's centripetal acceleration v^2 / r stays within this limit [m/s^2], the
// episodes' max_acceleration_mps2.
constexpr double kMaxAcceleration = 1.5;

// The flight after the initial hover: where it starts, its yaw, and its one segment (YAML
// lines of `trajectory.segments`).
struct PlannedPath {
  Eigen::Vector3d start_W_m;
  double yaw_deg = 0.0;
  std::string segment_yaml;
};

// The trajectory: hover, then the family's segment, flown for the whole episode. A circle
// may lower `plan.speed_mps`.
PlannedPath PlanPath(const CorpusSpec& spec, const WorldChoice& world, double tilt_sign,
                     EpisodePlan& plan) {
  const double cx = world.center_xy_m.x(), cy = world.center_xy_m.y(), h = plan.height_m;
  PlannedPath path;
  path.start_W_m = Eigen::Vector3d(cx, cy, h);
  if (plan.family == "circle") {
    plan.speed_mps = Round4(std::min(plan.speed_mps, std::sqrt(0.8 * kMaxAcceleration * plan.size_m)));
    const double laps = std::ceil(spec.duration_s * plan.speed_mps / (2.0 * kPi * plan.size_m)) + 1.0;
    path.segment_yaml = fmt::format("    - circle: {{center_m: {}, radius_m: {}, speed_mps: {}, laps: {}}}\n",
                                    Vec({cx, cy, h}), FormatDouble(plan.size_m), FormatDouble(plan.speed_mps),
                                    FormatDouble(laps));
  } else if (plan.family == "figure_eight") {
    // A lap of the lemniscate is ~4.6 half-lengths long at half_width = 0.6 half_length.
    const double laps = std::ceil(spec.duration_s * plan.speed_mps / (4.6 * plan.size_m)) + 1.0;
    path.segment_yaml = fmt::format(
        "    - figure_eight: {{center_m: {}, half_length_m: {}, half_width_m: {}, speed_mps: {}, laps: {}}}\n",
        Vec({cx, cy, h}), FormatDouble(plan.size_m), FormatDouble(Round4(0.6 * plan.size_m)),
        FormatDouble(plan.speed_mps), FormatDouble(laps));
  } else {
    // wall_pass: back and forth along the facade at structure_distance_m from it, facing it.
    const Eigen::Vector2d n = *world.wall_normal_xy;
    const Eigen::Vector2d tangent(-n.y(), n.x());
    const Eigen::Vector2d mid = *world.wall_point_xy_m + plan.structure_distance_m * n;
    const Eigen::Vector2d a = mid - plan.size_m * tangent, b = mid + plan.size_m * tangent;
    path.yaw_deg = Round4(std::atan2(-n.y(), -n.x()) * 180.0 / kPi);
    path.start_W_m = Eigen::Vector3d(a.x(), a.y(), h);
    const double pass_s = 2.0 * plan.size_m / plan.speed_mps + 2.0;
    const int passes = std::max(1, static_cast<int>(std::ceil(spec.duration_s / pass_s)));
    path.segment_yaml = "    - waypoints:\n";
    for (int i = 0; i < passes; ++i) {
      const Eigen::Vector2d p = i % 2 == 0 ? b : a;
      path.segment_yaml += fmt::format("        - {{position_m: {}, rpy_deg: [{}, 0, {}]}}\n",
                                       Vec(Eigen::Vector3d(p.x(), p.y(), h).unaryExpr(&Round4)),
                                       FormatDouble(tilt_sign * plan.tilt_deg), FormatDouble(path.yaw_deg));
    }
  }
  return path;
}

// Faults: how many, which kinds (by weight), on which sensor, when and how big. Appends
// them to `plan.faults` and returns their lines of the scenario's `faults:`.
std::string PlanFaults(const CorpusSpec& spec, core::RandomStream& random, EpisodePlan& plan) {
  const int count = static_cast<int>(std::floor(Draw(random, {spec.fault_count.lo, spec.fault_count.hi + 0.999999})));
  double total_weight = 0.0;
  for (const FaultChoice& f : spec.faults) total_weight += f.weight;
  std::string faults_yaml;
  for (int k = 0; k < count && !spec.faults.empty(); ++k) {
    double u = random.Uniform(0.0, total_weight);
    std::size_t which = 0;
    while (which + 1 < spec.faults.size() && u >= spec.faults[which].weight) u -= spec.faults[which++].weight;
    const FaultChoice& choice = spec.faults[which];
    PlannedFault fault;
    fault.kind = choice.kind;
    fault.sensor = choice.sensors[DrawIndex(random, choice.sensors.size())];
    fault.start_s = Round4(std::min(Draw(random, spec.fault_onset_s), spec.duration_s - 1.0));
    fault.end_s = Round4(std::min(fault.start_s + Draw(random, spec.fault_duration_s), spec.duration_s));
    fault.magnitude = Round4(Draw(random, choice.magnitude));
    faults_yaml += "  - " + FaultYaml(fault, DrawDirection(random)) + "\n";
    plan.faults.push_back(fault);
  }
  return faults_yaml;
}

}  // namespace

const std::vector<std::string>& TrajectoryFamilies() {
  static const std::vector<std::string> families = {"figure_eight", "circle", "wall_pass"};
  return families;
}

namespace {

// An item of `worlds:`: the world, where its flights centre, and its wall (for wall_pass).
WorldChoice ReadWorldChoice(const YamlValue& item) {
  YamlMap w = item.Map({"world", "center_m", "wall"});
  WorldChoice choice;
  choice.world = w.Required("world").String();
  if (auto c = w.Optional("center_m")) choice.center_xy_m = ReadXY(*c);
  if (auto wall = w.Optional("wall")) {
    YamlMap wm = wall->Map({"point_m", "normal"});
    choice.wall_point_xy_m = ReadXY(wm.Required("point_m"));
    const YamlValue normal = wm.Required("normal");
    const Eigen::Vector2d n = ReadXY(normal);
    if (n.norm() < 1e-6) normal.Fail("expected a non-zero horizontal normal [nx, ny]");
    choice.wall_normal_xy = n.normalized();
    wm.Finish();
  }
  w.Finish();
  return choice;
}

// `trajectory:` the families and the ranges their size, speed and pose are drawn from.
// After `worlds:`: wall_pass needs every world to have a wall.
void ReadTrajectoryRanges(const YamlValue& value, CorpusSpec& spec) {
  YamlMap t = value.Map(
      {"families", "speed_mps", "size_m", "height_m", "structure_distance_m", "tilt_deg"});
  const YamlValue families = t.Required("families");
  for (const YamlValue& f : families.List(true)) {
    const std::string name = f.String();
    const auto& known = TrajectoryFamilies();
    if (std::find(known.begin(), known.end(), name) == known.end()) {
      f.Fail(fmt::format("unknown trajectory family '{}' (expected one of figure_eight, circle, wall_pass)", name));
    }
    if (name == "wall_pass") {
      for (const WorldChoice& w : spec.worlds) {
        if (!w.wall_point_xy_m) {
          f.Fail(fmt::format("wall_pass needs every world to have a `wall:` (world '{}' has none)", w.world));
        }
      }
    }
    spec.families.push_back(name);
  }
  spec.speed_mps = ReadRange(t.Required("speed_mps"), NumberRule::PositiveAtMost(3.0, "m/s"));
  spec.size_m = ReadRange(t.Required("size_m"), NumberRule::Between(0.3, 20.0, "m"));
  spec.height_m = ReadRange(t.Required("height_m"), NumberRule::Between(0.5, 50.0, "m"));
  if (auto d = t.Optional("structure_distance_m")) {
    spec.structure_distance_m = ReadRange(*d, NumberRule::Between(0.3, 50.0, "m"));
  } else {
    spec.structure_distance_m = {1.0, 1.0};
  }
  if (auto d = t.Optional("tilt_deg")) spec.tilt_deg = ReadRange(*d, NumberRule::Between(0.0, 45.0, "deg"));
  t.Finish();
}

}  // namespace

FaultChoice ReadFaultChoice(const YamlValue& item, const std::vector<std::string>& sensor_names) {
  YamlMap k = item.Map({"kind", "sensors", "weight", "magnitude"});
  FaultChoice choice;
  const YamlValue kind = k.Required("kind");
  const auto parsed = sim::FaultKindFromName(kind.String());
  if (!parsed) {
    kind.Fail(fmt::format("unknown fault kind '{}' (expected misalignment, non_gaussian_noise, "
                          "divergence, dropout, freeze, delay, jump or outliers)", kind.String()));
  }
  choice.kind = *parsed;
  for (const YamlValue& s : k.Required("sensors").List(true)) {
    const std::string name = s.String();
    if (std::find(sensor_names.begin(), sensor_names.end(), name) == sensor_names.end()) {
      s.Fail(fmt::format("'{}' is not a sensor of the spec's sensors: block", name));
    }
    choice.sensors.push_back(name);
  }
  if (auto w = k.Optional("weight")) choice.weight = w->Number(NumberRule::Positive(""));
  const bool sized = choice.kind != sim::FaultKind::kDropout && choice.kind != sim::FaultKind::kFreeze;
  if (auto m = k.Optional("magnitude")) {
    if (!sized) m->Fail(fmt::format("{} has no magnitude", sim::FaultKindName(choice.kind)));
    choice.magnitude = ReadRange(*m, NumberRule::Positive(""));
  } else if (sized) {
    k.self().Fail(fmt::format("missing required key 'magnitude' for a {} fault",
                              sim::FaultKindName(choice.kind)));
  }
  k.Finish();
  return choice;
}

namespace {

// `faults:` how many per episode, when, how long, and of which kinds. After `sensors:`
// and `duration_s`, which it is checked against.
void ReadFaultRanges(const YamlValue& value, CorpusSpec& spec) {
  YamlMap fm = value.Map({"count", "onset_s", "duration_s", "kinds"});
  const YamlValue count = fm.Required("count");
  spec.fault_count = ReadRange(count, NumberRule::Between(0.0, 20.0, ""));
  if (spec.fault_count.lo != std::floor(spec.fault_count.lo) || spec.fault_count.hi != std::floor(spec.fault_count.hi)) {
    count.Fail("expected whole numbers [min, max] of faults per episode");
  }
  spec.fault_onset_s = ReadRange(fm.Required("onset_s"), NumberRule::Between(0.0, 3600.0, "s"));
  spec.fault_duration_s = ReadRange(fm.Required("duration_s"), NumberRule::Between(0.1, 3600.0, "s"));
  if (spec.fault_onset_s.lo >= spec.duration_s) {
    fm.self().Fail(fmt::format("onset_s starts at or after the episode's end ({} s)", FormatDouble(spec.duration_s)));
  }
  const YamlValue kinds = fm.Required("kinds");
  for (const YamlValue& item : kinds.List(spec.fault_count.hi > 0)) {
    spec.faults.push_back(ReadFaultChoice(item, spec.sensor_names));
  }
  fm.Finish();
}

}  // namespace

namespace {

// What every episode flies on: the spec's users' clients, estimation methods and closed
// loop (YAML lines of a scenario).
std::string MethodsYaml(const CorpusSpec& spec) {
  std::string yaml = spec.clients_yaml;
  if (!spec.estimation_yaml.empty()) yaml += "estimation:\n" + Indent(spec.estimation_yaml, "  ");
  if (!spec.closed_loop_methods.empty()) {
    std::string methods;
    for (const std::string& m : spec.closed_loop_methods) methods += (methods.empty() ? "\"" : ", \"") + m + "\"";
    yaml += fmt::format("control: {{state_source: estimate, methods: [{}]{}}}\n", methods,
                        spec.controller.empty() ? "" : ", controller: \"" + spec.controller + "\"");
  }
  return yaml;
}

// The size a corpus gives a fault of each kind (docs/CORPUS.md), read back from a scenario's.
double FaultMagnitude(const sim::FaultSpec& f) {
  switch (f.kind) {
    case sim::FaultKind::kDivergence:
      return f.divergence.initial_velocity_mps;
    case sim::FaultKind::kJump:
      return f.jump.translation_S_m.norm();
    case sim::FaultKind::kNonGaussianNoise:
      return f.noise.white_std_m;
    case sim::FaultKind::kOutliers:
      return f.outliers.scale_m;
    case sim::FaultKind::kDelay:
      return f.delay.delay_s;
    case sim::FaultKind::kMisalignment:
      return Eigen::AngleAxisd(f.misalignment.q_FS).angle() * 180.0 / kPi;
    case sim::FaultKind::kDropout:
    case sim::FaultKind::kFreeze:
      break;
  }
  return 0.0;
}

EpisodePlan PlanIncluded(const CorpusSpec& spec, std::uint64_t index) {
  const IncludedEpisode& e = spec.included.at(index - spec.sampled_episodes);
  EpisodePlan plan;
  plan.index = index;
  plan.id = fmt::format("{}_e{:06d}", spec.name, index);
  plan.scenario_seed = e.seed;
  plan.world = e.world;
  plan.family = "included";
  plan.duration_s = e.duration_s;
  plan.faults = e.faults;
  plan.scenario_yaml = fmt::format("# Episode {} of corpus '{}': {}, included.\nname: {}\n", index, spec.name,
                                   e.file, plan.id) +
                       e.scenario_body_yaml + MethodsYaml(spec);
  return plan;
}

// `include:` scenario files (a directory: its *.yaml, sorted), each an episode of its own.
// The name an include entry has under a corpus directory's included/: its last component.
std::string CopyName(const std::string& entry) {
  fs::path p = fs::path(entry).lexically_normal();
  if (p.filename().empty()) p = p.parent_path();
  return p.filename().string();
}

void ReadIncluded(const YamlValue& value, const std::string& file_label,
                  const std::optional<fs::path>& included_copies, CorpusSpec& spec) {
  const fs::path base = fs::absolute(fs::path(file_label).parent_path());
  std::vector<std::string> copy_names;
  for (const YamlValue& item : value.List(true)) {
    const std::string copy_name = CopyName(item.String());
    if (copy_name.empty() || copy_name == "." || copy_name == "..") {
      item.FailExpected("a scenario file or directory, named by a path that ends in its name");
    }
    if (std::find(copy_names.begin(), copy_names.end(), copy_name) != copy_names.end()) {
      item.Fail(fmt::format("a second include named '{}' (expected distinct last names: a corpus directory "
                            "keeps each under included/<name>)", copy_name));
    }
    copy_names.push_back(copy_name);
    const fs::path named = included_copies ? *included_copies / copy_name : base / item.String();
    std::vector<fs::path> files;
    std::error_code status_error;  // a name the file system refuses (too long, ...) is none
    if (fs::is_directory(named, status_error)) {
      for (const auto& entry : fs::directory_iterator(named)) {
        if (entry.path().extension() == ".yaml") files.push_back(entry.path());
      }
      std::sort(files.begin(), files.end());
      if (files.empty()) item.Fail(fmt::format("{} holds no *.yaml scenario", named.string()));
    } else if (fs::is_regular_file(named, status_error)) {
      files.push_back(named);
    } else {
      item.Fail(fmt::format("no scenario file or directory {} (expected paths relative to the spec)", named.string()));
    }
    for (const fs::path& file : files) {
      IncludedEpisode e;
      e.file = file.lexically_normal().string();
      e.copy_name = files.size() > 1 || file != named ? (fs::path(copy_name) / file.filename()).string() : copy_name;
      const std::string text = core::ReadWholeFile(file, "scenario", core::kMaxConfigFileBytes);
      e.text = text;
      harness::Scenario scenario;
      try {
        scenario = harness::ParseScenario(text, e.file);
      } catch (const core::InputError& error) {
        item.Fail(fmt::format("the included scenario does not load: {}", error.what()));
      }
      std::vector<std::string> names;
      for (const harness::SensorConfig& c : scenario.sensors) names.push_back(c.name);
      std::vector<std::string> expected = spec.sensor_names;
      std::sort(names.begin(), names.end());
      std::sort(expected.begin(), expected.end());
      if (names != expected) {
        item.Fail(fmt::format("{} has the sensors [{}], the spec [{}]: an episode's streams are the corpus's",
                              e.file, fmt::join(names, ", "), fmt::join(expected, ", ")));
      }
      e.world = scenario.world;
      e.seed = scenario.seed;
      e.duration_s = scenario.duration_s;
      for (const sim::FaultSpec& f : scenario.faults) {
        e.faults.push_back({f.sensor, f.kind, f.start_s, std::min(f.end_s, scenario.duration_s), Round4(FaultMagnitude(f))});
      }
      YAML::Node root = YAML::Load(text);
      for (const char* key : {"name", "description", "expect", "estimation", "control", "external", "plugins",
                              "render", "compare"}) {
        root.remove(key);
      }
      e.scenario_body_yaml = EmitNode(root) + "\n";
      spec.included.push_back(std::move(e));
    }
  }
}

}  // namespace

CorpusSpec ParseCorpusSpec(const std::string& text, const std::string& file_label,
                           const std::optional<fs::path>& included_copies) {
  CorpusSpec spec;
  spec.file = file_label;
  spec.text = text;
  const YamlValue root = harness::ParseDocument(text, file_label);
  YamlMap top = root.Map({"name", "description", "seed", "episodes", "duration_s", "worlds",
                          "trajectory", "sensors", "wind", "faults", "external", "plugins",
                          "estimation", "closed_loop", "include"});
  spec.name = top.Required("name").Identifier();
  if (auto d = top.Optional("description")) spec.description = d->String();
  spec.seed = top.Required("seed").UnsignedInteger();
  const YamlValue episodes = top.Required("episodes");
  spec.sampled_episodes = episodes.UnsignedInteger();
  if ((spec.sampled_episodes == 0 && !top.Has("include")) || spec.sampled_episodes > 10'000'000) {
    episodes.Fail("expected a whole number of episodes in [1, 10000000] (0 only with include:)");
  }
  spec.duration_s = top.Required("duration_s").Number(NumberRule::Between(2.0, 3600.0, "s"));

  for (const YamlValue& item : top.Required("worlds").List(true)) {
    spec.worlds.push_back(ReadWorldChoice(item));
  }
  ReadTrajectoryRanges(top.Required("trajectory"), spec);

  const YamlValue sensors = top.Required("sensors");
  for (const auto& [name, value] : sensors.Entries()) spec.sensor_names.push_back(name);
  if (spec.sensor_names.empty()) sensors.Fail("expected at least one sensor (a scenario's sensors: block)");
  spec.sensors_yaml = EmitNode(sensors.node());

  if (auto w = top.Optional("wind")) {
    YamlMap wm = w->Map({"gust_std_mps", "mean_speed_mps"});
    if (auto g = wm.Optional("gust_std_mps")) spec.gust_std_mps = ReadRange(*g, NumberRule::Between(0.0, 10.0, "m/s"));
    if (auto m = wm.Optional("mean_speed_mps")) spec.mean_wind_mps = ReadRange(*m, NumberRule::Between(0.0, 20.0, "m/s"));
    wm.Finish();
  }

  if (auto f = top.Optional("faults")) ReadFaultRanges(*f, spec);

  // Users' estimators: their paths made absolute against the spec's directory, so every
  // episode's scenario (written anywhere) names the same programs and libraries.
  const auto external = top.Optional("external");
  const auto plugins = top.Optional("plugins");
  if (external || plugins) {
    YAML::Emitter clients;
    clients << YAML::BeginMap;
    harness::EmitClients(clients,
                                   harness::ReadClients(external, plugins, file_label));
    clients << YAML::EndMap;
    spec.clients_yaml = std::string(clients.c_str()) + "\n";
  }
  if (auto e = top.Optional("estimation")) spec.estimation_yaml = EmitNode(e->node());
  if (auto c = top.Optional("closed_loop")) {
    YamlMap cm = c->Map({"methods", "controller"});
    for (const YamlValue& m : cm.Required("methods").List(true)) spec.closed_loop_methods.push_back(m.String());
    if (auto controller = cm.Optional("controller")) spec.controller = controller->String();
    if (spec.estimation_yaml.empty()) c->Fail("closed_loop needs an estimation: block (its methods fly)");
    cm.Finish();
  }
  if (auto i = top.Optional("include")) ReadIncluded(*i, file_label, included_copies, spec);
  spec.episodes = spec.sampled_episodes + spec.included.size();
  top.Finish();

  // A spec that loads plans scenarios that load: check episode 0 and every included one
  // (and report their errors against the spec, since their YAML is the spec's doing).
  std::vector<std::uint64_t> checked = {0};
  for (std::uint64_t i = std::max<std::uint64_t>(1, spec.sampled_episodes); i < spec.episodes; ++i) checked.push_back(i);
  for (const std::uint64_t index : checked) {
    const EpisodePlan plan = PlanEpisode(spec, index);
    try {
      harness::ParseScenario(plan.scenario_yaml, fmt::format("{} (episode {} as planned)", file_label, index));
    } catch (const core::InputError& e) {
      throw core::InputError({file_label}, "", fmt::format("the spec plans an invalid scenario: {}", e.what()));
    }
  }
  return spec;
}

CorpusSpec LoadCorpusSpec(const std::filesystem::path& path) {
  return ParseCorpusSpec(core::ReadWholeFile(path, "corpus spec", core::kMaxConfigFileBytes),
                         path.string());
}

void CopyIncluded(const CorpusSpec& spec, const fs::path& dir) {
  for (const IncludedEpisode& e : spec.included) {
    const fs::path copy = dir / e.copy_name;
    if (fs::exists(copy)) {
      if (core::ReadWholeFile(copy, "scenario", core::kMaxConfigFileBytes) != e.text) {
        throw core::InputError({e.file}, "include",
                               fmt::format("changed since the corpus directory was made (its copy {} differs): "
                                           "use another directory", copy.string()));
      }
      continue;
    }
    fs::create_directories(copy.parent_path());
    replay::WriteFileAtomically(copy, e.text);  // concurrent shards write the same bytes
  }
}

EpisodePlan PlanEpisode(const CorpusSpec& spec, std::uint64_t index) {
  if (index >= spec.sampled_episodes) return PlanIncluded(spec, index);
  EpisodePlan plan;
  plan.index = index;
  plan.id = fmt::format("{}_e{:06d}", spec.name, index);
  plan.duration_s = spec.duration_s;
  plan.scenario_seed = core::StreamSeed(spec.seed, fmt::format("corpus/episode/{}/scenario", index)) >> 1;
  core::RandomStream random(spec.seed, fmt::format("corpus/episode/{}", index));

  const WorldChoice& world = spec.worlds[DrawIndex(random, spec.worlds.size())];
  plan.world = world.world;
  plan.family = spec.families[DrawIndex(random, spec.families.size())];
  plan.speed_mps = Round4(Draw(random, spec.speed_mps));
  plan.size_m = Round4(Draw(random, spec.size_m));
  plan.height_m = Round4(Draw(random, spec.height_m));
  plan.structure_distance_m = Round4(Draw(random, spec.structure_distance_m));
  plan.tilt_deg = Round4(Draw(random, spec.tilt_deg));
  plan.gust_std_mps = Round4(Draw(random, spec.gust_std_mps));
  plan.mean_wind_mps = Round4(Draw(random, spec.mean_wind_mps));
  const double wind_heading = random.Uniform(0.0, 2.0 * kPi);
  const double tilt_sign = random.Uniform(0.0, 1.0) < 0.5 ? -1.0 : 1.0;

  const PlannedPath path = PlanPath(spec, world, tilt_sign, plan);
  const std::string faults_yaml = PlanFaults(spec, random, plan);

  std::string yaml = fmt::format(
      "# Episode {} of corpus '{}' (seed {}): `tofu run` on this file reproduces it.\n"
      "name: {}\n"
      "description: \"{} episode {}: {} in {}\"\n"
      "world: {}\n"
      "duration_s: {}\n"
      "seed: {}\n",
      index, spec.name, spec.seed, plan.id, spec.name, index, plan.family, plan.world, plan.world,
      FormatDouble(spec.duration_s), plan.scenario_seed);
  if (plan.gust_std_mps > 0.0 || plan.mean_wind_mps > 0.0) {
    const Eigen::Vector3d mean(plan.mean_wind_mps * std::cos(wind_heading), plan.mean_wind_mps * std::sin(wind_heading), 0.0);
    yaml += fmt::format("wind: {{mean_velocity_mps: {}, gust_std_mps: {}, gust_correlation_time_s: 1.5}}\n",
                        Vec(mean.unaryExpr(&Round4)), FormatDouble(plan.gust_std_mps));
  }
  yaml += fmt::format(
      "trajectory:\n"
      "  start: {{position_m: {}, rpy_deg: [{}, 0, {}]}}\n"
      "  limits: {{max_speed_mps: {}, max_acceleration_mps2: {}}}\n"
      "  segments:\n"
      "    - hover: {{duration_s: 2}}\n{}",
      Vec(path.start_W_m.unaryExpr(&Round4)), FormatDouble(tilt_sign * plan.tilt_deg),
      FormatDouble(path.yaw_deg), FormatDouble(Round4(plan.speed_mps * 1.3 + 0.2)),
      FormatDouble(kMaxAcceleration), path.segment_yaml);
  yaml += "sensors:\n" + Indent(spec.sensors_yaml, "  ");
  if (!faults_yaml.empty()) yaml += "faults:\n" + faults_yaml;
  plan.scenario_yaml = yaml + MethodsYaml(spec);
  return plan;
}

}  // namespace tofu::corpus
