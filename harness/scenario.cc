#include "harness/scenario.h"

#include <fmt/format.h>
#include <fmt/ranges.h>
#include <mujoco/mujoco.h>
#include <yaml-cpp/yaml.h>

#include <cassert>
#include <cerrno>
#include <algorithm>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <map>
#include <memory>
#include <fstream>
#include <sstream>
#include <type_traits>

#include "core/file_io.h"
#include "core/lie.h"
#include "harness/client_config.h"
#include "harness/config_io.h"
#include "harness/fault_config.h"
#include "harness/metrics.h"
#include "harness/option_fields_yaml.h"
#include "harness/sensor_config.h"
#include "harness/yaml_reader.h"
#include "replay/replay.h"
#include "replay/run_format.h"
#include "sim/world.h"

namespace tofu::harness {

using replay::CheckMethodName;
using replay::ConsensusConfig;
using replay::EstimationConfig;

namespace {

using internal::EmitFieldValue;
using internal::EmitOptionFields;
using internal::FieldFormatOf;
using internal::FinishOptionsMap;
using core::FormatDouble;
using core::NumberRule;
using internal::OptionKeys;
using internal::ReadFieldValue;
using internal::ReadOptionFields;
using namespace internal::config;

std::string SensorTypeList() { return fmt::format("{}", fmt::join(kSensorTypeNames, ", ")); }

// A sensor that measures its position in a surveyed frame (not an odometry, whose frame
// starts where it boots): what the mission frame can follow.
bool IsAbsoluteSensor(const SensorConfig& sensor) {
  const replay::SensorModel model = SensorModelOf(sensor.options);
  return model == replay::SensorModel::kTotalStation || model == replay::SensorModel::kGnss;
}

std::vector<SensorConfig> ReadSensors(const YamlValue& value) {
  std::vector<SensorConfig> sensors;
  for (const auto& [name, entry] : value.Entries()) {
    // `type` selects the model; a stream named after its type may leave it out.
    std::string type = name;
    if (const auto type_value = entry.Peek("type")) {
      type = type_value->Identifier();
      if (std::find(kSensorTypeNames.begin(), kSensorTypeNames.end(), type) ==
          kSensorTypeNames.end()) {
        type_value->Fail(fmt::format("unknown sensor type '{}'; expected one of: {}", type,
                                     SensorTypeList()));
      }
    } else if (std::find(kSensorTypeNames.begin(), kSensorTypeNames.end(), name) ==
               kSensorTypeNames.end()) {
      entry.FailAtKey(fmt::format(
          "sensor '{}' needs a 'type' (one of: {}); it may be left out only when the name "
          "is a type",
          name, SensorTypeList()));
    }
    const YamlValue options = entry.Without("type");
    SensorConfig config{name, internal::ReadSensorOptions(type, options.Without("calibration_error"))};
    if (const auto error = options.Peek("calibration_error")) {
      config.calibration_error = internal::ReadCalibrationError(*error);
    }
    sensors.push_back(std::move(config));
  }
  return sensors;
}

ConsistencyConfig ReadConsistency(const YamlValue& value) {
  ConsistencyConfig config;
  YamlMap map = value.Map({"rate_hz", "window_s", "metrics", "standardize", "kl_bandwidth_scale",
                           "alignment_window_s", "alignment_rate_hz",
                           "differentiation_window_s"});
  ReadNumber(map, "rate_hz", NumberRule::Between(0.1, 1000.0, "Hz"), &config.rate_hz);
  ReadNumber(map, "window_s", NumberRule::Between(0.05, 60.0, "s"), &config.window_s);
  if (const auto metrics = map.Optional("metrics")) {
    config.metrics.clear();
    for (const YamlValue& item : metrics->List(/*non_empty=*/true)) {
      const auto metric = estimator::MetricFromName(item.String());
      // nis needs the streams' stated covariances, which only the consensus carries.
      if (!metric || *metric == estimator::ConsistencyMetric::kNis) {
        item.FailExpected("one of mae, pcc, kl, cm");
      }
      config.metrics.push_back(*metric);
    }
  }
  ReadBool(map, "standardize", &config.standardize);
  ReadNumber(map, "kl_bandwidth_scale", NumberRule::Between(0.01, 100.0, ""),
             &config.kl_bandwidth_scale);
  ReadNumber(map, "alignment_window_s", NumberRule::Between(1.0, 3600.0, "s"),
             &config.alignment_window_s);
  ReadNumber(map, "alignment_rate_hz", NumberRule::Between(0.1, 100.0, "Hz"),
             &config.alignment_rate_hz);
  ReadNumber(map, "differentiation_window_s", NumberRule::Between(0.01, 5.0, "s"),
             &config.differentiation_window_s);
  map.Finish();
  return config;
}

// The value of the word `value` holds among `choices`; otherwise an error listing them
// ("a, b or c").
template <typename T>
T ChoiceOf(const YamlValue& value, std::initializer_list<std::pair<std::string_view, T>> choices) {
  const std::string word = value.String();
  std::string expected;
  std::size_t i = 0;
  for (const auto& [name, choice] : choices) {
    if (word == name) return choice;
    expected += (i == 0 ? "" : i + 1 == choices.size() ? " or " : ", ") + std::string(name);
    ++i;
  }
  value.FailExpected(expected);
}

// Each metric has its own threshold scale: a block (or --set) that changes the metric from
// `before` and gives no threshold gets its profile's threshold for the new metric, not the
// old metric's.
void KeepThresholdOnItsMetric(estimator::ConsistencyMetric before, bool threshold_given,
                              EstimationConfig* config) {
  if (config->consensus.metric == before || threshold_given) return;
  config->consensus.threshold =
      EstimationConfig::DefaultThreshold(config->profile, config->consensus.metric);
}

// `check_methods`: false for a block read on a client's side, which does not know the
// scenario's clients (its methods are not what it runs).
EstimationConfig ReadEstimation(const YamlValue& value, const std::vector<SensorConfig>& sensors,
                                const std::vector<replay::ClientSpec>& clients,
                                bool check_methods = true) {
  const auto fields = EstimationConfig::Fields();
  YamlMap map = value.Map(internal::OptionKeys(fields, {"methods", "consensus"}));
  // The profile first: it gives every other key's default.
  EstimationConfig profile_of;
  profile_of.profile = EstimationConfig::kDefaultProfile;
  if (const auto profile = map.Optional("profile")) {
    internal::ReadOptionField(*profile, fields.front(), &profile_of);
  }
  EstimationConfig config = EstimationConfig::Defaults(profile_of.profile);
  config.clients = clients;
  internal::ReadOptionFields(map, fields, &config);
  std::vector<std::string> sensor_names;
  bool has_imu = false;
  for (const SensorConfig& s : sensors) {
    if (std::holds_alternative<sim::ImuOptions>(s.options)) {
      has_imu = true;
    } else {
      sensor_names.push_back(s.name);
    }
  }
  // Found here rather than after the flight, when the estimators would have been set up
  // on a run without an IMU stream.
  if (!has_imu) {
    value.FailAtKey(fmt::format(
        "estimation needs an IMU among sensors: (every method propagates on it); the "
        "scenario's sensors: {}",
        sensor_names.empty() ? std::string("none") : fmt::format("{}", fmt::join(sensor_names, ", "))));
  }
  for (const YamlValue& item : map.Required("methods").List(/*non_empty=*/true)) {
    const std::string name = item.String();
    if (const auto error = CheckMethodName(name, sensor_names, clients); error && check_methods) {
      item.Fail(*error);
    }
    if (std::find(config.methods.begin(), config.methods.end(), name) != config.methods.end()) {
      item.Fail(fmt::format("method '{}' is listed twice", name));
    }
    config.methods.push_back(name);
  }
  if (const auto consensus = map.Optional("consensus")) {
    ConsensusConfig& c = config.consensus;
    const auto consensus_fields = ConsensusConfig::Fields();
    YamlMap cmap = consensus->Map(internal::OptionKeys(consensus_fields, {}, {"priority"}));
    const estimator::ConsistencyMetric profile_metric = c.metric;
    internal::ReadOptionFields(cmap, consensus_fields, &c);
    KeepThresholdOnItsMetric(profile_metric, cmap.Has("threshold"), &config);
    if (const auto priority = cmap.Optional("priority")) {
      for (const YamlValue& item : priority->List(/*non_empty=*/false)) {
        const std::string name = item.Identifier();
        if (std::find(sensor_names.begin(), sensor_names.end(), name) == sensor_names.end()) {
          item.Fail(fmt::format("priority names sensor '{}', which the scenario does not have "
                                "(its non-IMU sensors: {})",
                                name, fmt::join(sensor_names, ", ")));
        }
        c.priority.push_back(name);
      }
    }
    internal::FinishOptionsMap(cmap, c);
  }
  internal::FinishOptionsMap(map, config);
  return config;
}

// One `--set KEY=VALUE`, split.
struct EstimationSetting {
  std::string text;  ///< as given
  std::string key;
  std::string value;
};

EstimationSetting SplitSetting(const std::string& text) {
  const std::size_t equals = text.find('=');
  if (equals == std::string::npos || equals == 0 || equals + 1 == text.size()) {
    throw core::InputError({}, "--set",
                           fmt::format("expected KEY=VALUE (a key of the scenario's estimation: "
                                       "block, e.g. consensus.metric=nis), got '{}'",
                                       text));
  }
  return {text, text.substr(0, equals), text.substr(equals + 1)};
}

template <typename Options>
const core::OptionField<Options>* FindField(std::span<const core::OptionField<Options>> fields,
                                            std::string_view key) {
  for (const core::OptionField<Options>& field : fields) {
    if (field.format.key == key) return &field;
  }
  return nullptr;
}

std::string SettableKeys() {
  std::vector<std::string> keys;
  for (const auto& f : EstimationConfig::Fields()) keys.emplace_back(f.format.key);
  for (const auto& f : ConsensusConfig::Fields()) keys.push_back("consensus." + std::string(f.format.key));
  return fmt::format("{}", fmt::join(keys, ", "));
}

// `control:` (harness/closed_loop.h). Needs the scenario's sensors and `estimation:`
// block: a closed-loop method must be one of estimation.methods and needs an IMU.
MissionConfig ReadMission(const YamlValue& value, const std::vector<SensorConfig>& sensors) {
  MissionConfig mission;
  YamlMap map = value.Map({"launch_pad", "surveyed"});
  if (const auto pad = map.Optional("launch_pad")) {
    YamlMap pad_map = pad->Map({"position_m", "rpy_deg"});
    sim::Waypoint& pose = mission.launch_pad.emplace();
    pose.p_WB = pad_map.Required("position_m").Vector3(NumberRule::Any("m"));
    if (const auto q = ReadRpy(pad_map)) pose.q_WB = *q;
    pad_map.Finish();
  }
  if (const auto surveyed = map.Optional("surveyed")) {
    std::vector<std::string>& names = mission.surveyed.emplace();
    for (const YamlValue& item : surveyed->List(/*non_empty=*/false)) {
      const std::string name = item.String();
      const auto sensor = std::find_if(sensors.begin(), sensors.end(),
                                       [&](const SensorConfig& c) { return c.name == name; });
      if (sensor == sensors.end()) {
        item.Fail(fmt::format("'{}' is not a sensor of the scenario's sensors: block", name));
      }
      if (!IsAbsoluteSensor(*sensor)) {
        item.Fail(fmt::format("'{}' is a {} sensor; expected a {} or {} sensor (an absolute "
                              "sensor's frame is surveyed, an odometry's starts where it boots)",
                              name, SensorTypeName(sensor->options),
                              replay::SensorModelName(replay::SensorModel::kTotalStation),
                              replay::SensorModelName(replay::SensorModel::kGnss)));
      }
      if (std::find(names.begin(), names.end(), name) != names.end()) {
        item.Fail(fmt::format("'{}' is listed twice", name));
      }
      names.push_back(name);
    }
  }
  map.Finish();
  return mission;
}

void EmitMission(YAML::Emitter& out, const MissionConfig& mission) {
  if (!mission.launch_pad && !mission.surveyed) return;
  out << YAML::Key << "mission" << YAML::Value << YAML::BeginMap;
  if (mission.launch_pad) {
    out << YAML::Key << "launch_pad" << YAML::Value << YAML::BeginMap;
    EmitVector(out, "position_m", mission.launch_pad->p_WB);
    EmitRpyDeg(out, "rpy_deg", mission.launch_pad->q_WB);
    out << YAML::EndMap;
  }
  if (mission.surveyed) {
    out << YAML::Key << "surveyed" << YAML::Value << YAML::Flow << YAML::BeginSeq;
    for (const std::string& name : *mission.surveyed) out << name;
    out << YAML::EndSeq;
  }
  out << YAML::EndMap;
}

// control.methods: methods of the scenario's estimation: block, flown with an estimate.
std::vector<std::string> ReadControlMethods(const YamlValue& methods, bool estimate,
                                            const Scenario& scenario) {
  std::vector<std::string> flown;
  if (!estimate) {
    methods.Fail("methods are flown only with state_source: estimate (the ground-truth "
                  "flight runs every method of estimation: open loop)");
  }
  if (!scenario.estimation) {
    methods.Fail("a closed-loop method must be a method of the scenario's estimation: "
                  "block, and the scenario has none");
  }
  const std::vector<std::string>& known = scenario.estimation->methods;
  for (const YamlValue& item : methods.List(/*non_empty=*/true)) {
    const std::string name = item.String();
    if (std::find(known.begin(), known.end(), name) == known.end()) {
      item.Fail(fmt::format("method '{}' is not one of estimation.methods ({}): a closed-loop "
                            "flight flies on a method the scenario estimates",
                            name, fmt::join(known, ", ")));
    }
    if (name.starts_with("imu_only")) {
      item.Fail("imu_only has no position source and cannot fly the mission; expected a "
                "method that fuses a sensor");
    }
    if (std::find(flown.begin(), flown.end(), name) != flown.end()) {
      item.Fail(fmt::format("method '{}' is listed twice", name));
    }
    flown.push_back(name);
  }
  return flown;
}

// state_source: estimate needs methods to fly on and an IMU to propagate on; blamed on
// state_source when it is given, else on the control block.
void CheckEstimateSource(const YamlValue& value, const std::optional<YamlValue>& source,
                         const ControlConfig& config, const Scenario& scenario) {
  const auto fail = [&](const std::string& message) {
    if (source) source->Fail(message);
    value.Fail(message);
  };
  if (!scenario.estimation) {
    fail("state_source: estimate needs an estimation: block (the methods the controller can "
         "fly on)");
  }
  if (config.methods.empty()) {
    fail("state_source: estimate needs control.methods: the estimation methods to fly on, "
         "e.g. [consensus, naive]");
  }
  const bool has_imu = std::any_of(scenario.sensors.begin(), scenario.sensors.end(),
                                   [](const SensorConfig& s) {
                                     return std::holds_alternative<sim::ImuOptions>(s.options);
                                   });
  if (!has_imu) {
    fail("state_source: estimate needs an IMU among sensors: (the estimator propagates on "
         "it)");
  }
}

// control.failsafe.
FailsafeConfig ReadFailsafe(const YamlValue& failsafe) {
  FailsafeConfig f;
  YamlMap fmap = failsafe.Map({"hold_s", "descent_rate_mps", "land_z_m", "max_position_std_m"});
  ReadNumber(fmap, "hold_s", NumberRule::Between(0.0, 600.0, "s"), &f.hold_s);
  ReadNumber(fmap, "descent_rate_mps", NumberRule::Between(0.05, 5.0, "m/s"),
             &f.descent_rate_mps);
  ReadNumber(fmap, "land_z_m", NumberRule::Between(-100.0, 1000.0, "m"), &f.land_z_m);
  if (const auto bound = fmap.Optional("max_position_std_m")) {
    f.max_position_std_m = bound->Number(NumberRule::Between(1e-4, 100.0, "m"));
  }
  fmap.Finish();
  return f;
}

ControlConfig ReadControl(const YamlValue& value, const Scenario& scenario) {
  ControlConfig config;
  YamlMap map = value.Map({"state_source", "methods", "corridor_m", "failsafe", "controller"});
  if (const auto controller = map.Optional("controller")) {
    const std::string name = controller->String();
    if (name != kBuiltinControllerName) {
      if (FindClient(scenario.clients, name) == nullptr) {
        std::string known;
        for (const replay::ClientSpec& c : scenario.clients) known += ", " + c.Name();
        controller->Fail(fmt::format("controller '{}' is neither {} (tofu's own) nor a client of "
                                     "the scenario's external: or plugins: blocks (known: {}{})",
                                     name, kBuiltinControllerName, kBuiltinControllerName, known));
      }
      config.controller = name;
    }
  }
  const std::optional<YamlValue> source = map.Optional("state_source");
  if (source) {
    config.state_source =
        ChoiceOf<ControlConfig::StateSource>(*source, {{"ground_truth", ControlConfig::StateSource::kGroundTruth},
                           {"estimate", ControlConfig::StateSource::kEstimate}});
  }
  const bool estimate = config.state_source == ControlConfig::StateSource::kEstimate;
  if (const auto methods = map.Optional("methods")) {
    config.methods = ReadControlMethods(*methods, estimate, scenario);
  }
  if (estimate) CheckEstimateSource(value, source, config, scenario);
  ReadNumber(map, "corridor_m", NumberRule::Between(0.01, 100.0, "m"), &config.corridor_m);
  if (const auto failsafe = map.Optional("failsafe")) config.failsafe = ReadFailsafe(*failsafe);
  map.Finish();
  return config;
}

RenderRequest ReadRender(const YamlValue& value) {
  RenderRequest r;
  YamlMap map = value.Map({"when", "size", "fps", "camera", "clip_half_s", "error_bound_m"});
  if (const auto when = map.Optional("when")) {
    r.always = ChoiceOf<bool>(*when, {{"failure", false}, {"always", true}});
  }
  if (const auto size = map.Optional("size")) {
    const std::vector<double> wh = size->Numbers(2, NumberRule::Between(16.0, 7680.0, "px"));
    if (wh[0] != std::floor(wh[0]) || wh[1] != std::floor(wh[1])) {
      size->FailExpected("[width, height] in whole pixels");
    }
    r.width_px = static_cast<int>(wh[0]);
    r.height_px = static_cast<int>(wh[1]);
  }
  ReadInteger(map, "fps", 1, 240, &r.fps);
  if (const auto camera = map.Optional("camera")) r.camera = camera->Identifier();
  ReadNumber(map, "clip_half_s", NumberRule::Between(0.1, 60.0, "s"), &r.clip_half_s);
  ReadNumber(map, "error_bound_m", NumberRule::Between(1e-3, 1e3, "m"), &r.error_bound_m);
  map.Finish();
  return r;
}

// ---- sections ----

// The physics rate, a field of sim::WorldOptions (its table's key and limits). Also hands
// out the rate_hz value, which later checks of other rates may blame.
PhysicsOptions ReadPhysics(const YamlValue& value, std::optional<YamlValue>* rate_value) {
  const core::FieldFormat& rate = FieldFormatOf(sim::WorldOptions::Fields(), "rate_hz");
  PhysicsOptions physics;
  YamlMap map = value.Map({rate.key});
  *rate_value = map.Optional(rate.key);
  if (*rate_value) ReadFieldValue(**rate_value, rate, &physics.rate_hz);
  map.Finish();
  return physics;
}

sim::ControllerOptions ReadController(const YamlValue& value, double physics_rate_hz) {
  const auto fields = sim::ControllerOptions::Fields();
  YamlMap map = value.Map(OptionKeys(fields));
  // The controller runs on physics steps: its rate is at most the physics rate, which the
  // options struct does not know.
  if (const auto rate = map.Optional("rate_hz")) {
    (void)rate->Number(NumberRule::Between(1.0, physics_rate_hz, "Hz, at most physics.rate_hz"));
  }
  sim::ControllerOptions controller;
  ReadOptionFields(map, fields, &controller);
  FinishOptionsMap(map, controller);
  return controller;
}

sim::WindOptions ReadWind(const YamlValue& value) {
  const auto fields = sim::WindOptions::Fields();
  YamlMap map = value.Map(OptionKeys(fields));
  sim::WindOptions wind;
  ReadOptionFields(map, fields, &wind);
  FinishOptionsMap(map, wind);
  return wind;
}

InitialOffset ReadInitialOffset(const YamlValue& value) {
  InitialOffset offset;
  YamlMap map = value.Map({"position_m", "rpy_deg"});
  ReadVector(map, "position_m", NumberRule::Any("m"), false, &offset.position_W_m);
  if (const auto q = ReadRpy(map)) offset.q_offset = *q;
  map.Finish();
  return offset;
}

OutputOptions ReadOutput(const YamlValue& value, double physics_rate_hz) {
  OutputOptions output;
  YamlMap map = value.Map({"groundtruth_rate_hz"});
  ReadNumber(map, "groundtruth_rate_hz",
             NumberRule::PositiveAtMost(physics_rate_hz, "Hz, at most physics.rate_hz"),
             &output.groundtruth_rate_hz);
  map.Finish();
  return output;
}

constexpr std::string_view kSegmentKinds = "hover, line, waypoints, circle, figure_eight, approach";

sim::HoverSpec ReadHover(const YamlValue& value) {
  sim::HoverSpec hover;
  YamlMap map = value.Map({"duration_s"});
  hover.duration_s = map.Required("duration_s").Number(NumberRule::Positive("s"));
  map.Finish();
  return hover;
}

sim::LineSpec ReadLine(const YamlValue& value, Eigen::Quaterniond* attitude) {
  sim::LineSpec line;
  YamlMap map = value.Map({"to_m", "rpy_deg"});
  line.to_W = map.Required("to_m").Vector3(NumberRule::Any("m"));
  line.q_WB = ReadRpy(map);
  if (line.q_WB) *attitude = *line.q_WB;
  map.Finish();
  return line;
}

sim::WaypointsSpec ReadWaypoints(const YamlValue& value, Eigen::Quaterniond* attitude) {
  sim::WaypointsSpec spec;
  for (const YamlValue& item : value.List(/*non_empty=*/true)) {
    YamlMap map = item.Map({"position_m", "rpy_deg"});
    sim::Waypoint waypoint;
    waypoint.p_WB = map.Required("position_m").Vector3(NumberRule::Any("m"));
    // Without rpy_deg a waypoint keeps the attitude the robot has before it.
    waypoint.q_WB = ReadRpy(map).value_or(*attitude);
    *attitude = waypoint.q_WB;
    map.Finish();
    spec.waypoints.push_back(waypoint);
  }
  return spec;
}

sim::CircleSpec ReadCircle(const YamlValue& value) {
  sim::CircleSpec circle;
  YamlMap map = value.Map({"center_m", "radius_m", "speed_mps", "laps", "clockwise"});
  circle.center_W = map.Required("center_m").Vector3(NumberRule::Any("m"));
  circle.radius_m = map.Required("radius_m").Number(NumberRule::Positive("m"));
  ReadNumber(map, "speed_mps", NumberRule::Positive("m/s"), &circle.speed_mps);
  ReadNumber(map, "laps", NumberRule::Positive(""), &circle.laps);
  if (const auto clockwise = map.Optional("clockwise")) circle.clockwise = clockwise->Bool();
  map.Finish();
  return circle;
}

sim::FigureEightSpec ReadFigureEight(const YamlValue& value) {
  sim::FigureEightSpec figure;
  YamlMap map = value.Map({"center_m", "half_length_m", "half_width_m", "speed_mps", "laps"});
  figure.center_W = map.Required("center_m").Vector3(NumberRule::Any("m"));
  figure.half_length_m = map.Required("half_length_m").Number(NumberRule::Positive("m"));
  figure.half_width_m = map.Required("half_width_m").Number(NumberRule::Positive("m"));
  ReadNumber(map, "speed_mps", NumberRule::Positive("m/s"), &figure.speed_mps);
  ReadNumber(map, "laps", NumberRule::Positive(""), &figure.laps);
  map.Finish();
  return figure;
}

sim::ApproachSpec ReadApproach(const YamlValue& value) {
  sim::ApproachSpec approach;
  YamlMap map = value.Map({"direction", "standoff_m", "speed_mps"});
  const YamlValue direction = map.Required("direction");
  const Eigen::Vector3d d = direction.Vector3(NumberRule::Any(""));
  if (!(d.norm() > 1e-9)) {
    direction.FailExpected("a non-zero direction vector (list of 3 numbers)");
  }
  approach.direction_W = d.normalized();
  approach.standoff_m = map.Required("standoff_m").Number(NumberRule::NonNegative("m"));
  ReadNumber(map, "speed_mps", NumberRule::Positive("m/s"), &approach.speed_mps);
  map.Finish();
  return approach;
}

// One list item of trajectory.segments: a map with exactly one key naming the primitive.
sim::PrimitiveSpec ReadSegment(const YamlValue& item, Eigen::Quaterniond* attitude) {
  const std::string expected =
      fmt::format("a map with exactly one key naming the primitive (one of: {})", kSegmentKinds);
  if (!item.node().IsMap()) item.FailExpected(expected);
  YamlMap map = item.Map({"hover", "line", "waypoints", "circle", "figure_eight", "approach"});
  if (map.keys().empty()) item.FailExpected(expected);
  if (map.keys().size() > 1) {
    const YamlValue second = *map.Optional(map.keys()[1]);
    throw core::InputError(
        second.key_location(), item.path(),
        fmt::format("a segment has exactly one key naming its primitive, got {} ('{}', '{}'{}); "
                    "start each segment with its own '-'",
                    map.keys().size(), map.keys()[0], map.keys()[1],
                    map.keys().size() > 2 ? ", ..." : ""));
  }
  const std::string& kind = map.keys()[0];
  const YamlValue body = *map.Optional(kind);
  if (kind == "hover") return ReadHover(body);
  if (kind == "line") return ReadLine(body, attitude);
  if (kind == "waypoints") return ReadWaypoints(body, attitude);
  if (kind == "circle") return ReadCircle(body);
  if (kind == "figure_eight") return ReadFigureEight(body);
  return ReadApproach(body);  // the only kind left after Map()'s key check
}

sim::TrajectorySpec ReadTrajectory(const YamlValue& value) {
  sim::TrajectorySpec trajectory;
  YamlMap map = value.Map({"start", "limits", "segments"});

  YamlMap start = map.Required("start").Map({"position_m", "rpy_deg"});
  trajectory.start.p_WB = start.Required("position_m").Vector3(NumberRule::Any("m"));
  if (const auto q = ReadRpy(start)) trajectory.start.q_WB = *q;
  start.Finish();

  if (const auto limits_value = map.Optional("limits")) {
    sim::DynamicLimits& limits = trajectory.limits;
    YamlMap lim = limits_value->Map({"max_speed_mps", "max_acceleration_mps2",
                                     "max_angular_rate_degps", "max_angular_acceleration_degps2"});
    ReadNumber(lim, "max_speed_mps", NumberRule::Positive("m/s"), &limits.max_speed_mps);
    ReadNumber(lim, "max_acceleration_mps2", NumberRule::Positive("m/s^2"),
               &limits.max_acceleration_mps2);
    ReadDegrees(lim, "max_angular_rate_degps", NumberRule::Positive("deg/s"),
                &limits.max_angular_rate_radps);
    ReadDegrees(lim, "max_angular_acceleration_degps2", NumberRule::Positive("deg/s^2"),
                &limits.max_angular_acceleration_radps2);
    lim.Finish();
  }

  // The attitude the robot holds before each segment, for waypoints without rpy_deg.
  Eigen::Quaterniond attitude = trajectory.start.q_WB;
  for (const YamlValue& item : map.Required("segments").List(/*non_empty=*/true)) {
    trajectory.segments.push_back(ReadSegment(item, &attitude));
  }
  map.Finish();
  return trajectory;
}

std::string MetricNames(bool windowable_only) {
  std::string names;
  for (const MetricInfo& info : MetricCatalog()) {
    if (windowable_only && !info.windowable) continue;
    if (!names.empty()) names += ", ";
    names += info.name;
  }
  return names;
}

Expectation ReadExpectation(const YamlValue& item, const std::vector<SensorConfig>& sensors) {
  Expectation expectation;
  expectation.location = item.location();
  YamlMap map = item.Map({"metric", "min", "max", "window_s", "pass_fraction", "relative_to"});

  const YamlValue metric = map.Required("metric");
  expectation.metric = metric.String();
  const MetricInfo* info = FindMetric(expectation.metric);
  if (info == nullptr) {
    std::vector<std::string> names;
    for (const MetricInfo& known : MetricCatalog()) names.push_back(known.name);
    const std::string suggestion = ClosestMatch(expectation.metric, names);
    metric.Fail(
        fmt::format("unknown metric '{}'{}; known metrics: {}", expectation.metric,
                    suggestion.empty() ? "" : fmt::format(" (did you mean '{}'?)", suggestion),
                    MetricNames(false)));
  }

  // A per-sensor metric must name a sensor of the scenario.
  const MetricArguments args = MatchMetric(expectation.metric)->second;
  if (!args.sensor.empty() &&
      std::none_of(sensors.begin(), sensors.end(),
                   [&](const SensorConfig& c) { return c.name == args.sensor; })) {
    std::vector<std::string> names;
    for (const SensorConfig& c : sensors) names.push_back(c.name);
    metric.Fail(fmt::format("metric '{}' names sensor '{}', which the scenario does not have "
                            "(its sensors: {})",
                            expectation.metric, args.sensor,
                            names.empty() ? "none" : fmt::format("{}", fmt::join(names, ", "))));
  }

  const std::optional<YamlValue> min = map.Optional("min");
  const std::optional<YamlValue> max = map.Optional("max");
  if (min) expectation.min = min->Number(NumberRule::Any(info->unit));
  if (max) expectation.max = max->Number(NumberRule::Any(info->unit));
  if (!min && !max) {
    item.FailAtKey(
        fmt::format("expectation on '{}' needs at least one of 'min' and 'max'", info->name));
  }
  if (min && max && *expectation.min > *expectation.max) {
    max->Fail(fmt::format("expected max >= min ({}), got {}", FormatDouble(*expectation.min),
                          max->Describe()));
  }

  if (const auto window = map.Optional("window_s")) {
    if (!info->windowable) {
      window->FailAtKey(fmt::format(
          "metric '{}' cannot be restricted to a time window; window_s is allowed for: {}",
          info->name, MetricNames(true)));
    }
    const std::vector<double> from_to = window->Numbers(2, NumberRule::NonNegative("s"));
    if (!(from_to[0] < from_to[1])) {
      window->Fail(fmt::format("expected [from, to] with 0 <= from < to (s), got [{}, {}]",
                               FormatDouble(from_to[0]), FormatDouble(from_to[1])));
    }
    expectation.window_s = std::make_pair(from_to[0], from_to[1]);
  }
  // Share of the seeds of `tofu check --seeds N` in which the expectation must hold.
  if (const auto fraction = map.Optional("pass_fraction")) {
    expectation.pass_fraction = fraction->Number(NumberRule::PositiveAtMost(1.0, ""));
  }
  if (const auto relative = map.Optional("relative_to")) {
    const std::string name = relative->String();
    const MetricInfo* other = FindMetric(name);
    if (other == nullptr) {
      relative->Fail(fmt::format("unknown metric '{}'; known metrics: {}", name, MetricNames(false)));
    }
    if (other->unit != info->unit) {
      relative->Fail(fmt::format("relative_to needs a metric in the same unit as '{}' ({}), got '{}' ({})",
                                 expectation.metric, info->unit, name, other->unit));
    }
    if (expectation.window_s && !other->windowable) {
      relative->Fail(fmt::format("metric '{}' cannot be restricted to the window of this expectation",
                                 name));
    }
    expectation.relative_to = name;
  }
  map.Finish();
  return expectation;
}

// ---- emitting ----




void EmitSegment(YAML::Emitter& out, const sim::PrimitiveSpec& segment) {
  out << YAML::BeginMap;
  std::visit(
      [&out](const auto& spec) {
        using T = std::decay_t<decltype(spec)>;
        if constexpr (std::is_same_v<T, sim::HoverSpec>) {
          out << YAML::Key << "hover" << YAML::Value << YAML::BeginMap;
          EmitNumber(out, "duration_s", spec.duration_s);
          out << YAML::EndMap;
        } else if constexpr (std::is_same_v<T, sim::LineSpec>) {
          out << YAML::Key << "line" << YAML::Value << YAML::BeginMap;
          EmitVector(out, "to_m", spec.to_W);
          if (spec.q_WB) EmitRpyDeg(out, "rpy_deg", *spec.q_WB);
          out << YAML::EndMap;
        } else if constexpr (std::is_same_v<T, sim::WaypointsSpec>) {
          out << YAML::Key << "waypoints" << YAML::Value << YAML::BeginSeq;
          for (const sim::Waypoint& waypoint : spec.waypoints) {
            out << YAML::BeginMap;
            EmitVector(out, "position_m", waypoint.p_WB);
            EmitRpyDeg(out, "rpy_deg", waypoint.q_WB);
            out << YAML::EndMap;
          }
          out << YAML::EndSeq;
        } else if constexpr (std::is_same_v<T, sim::CircleSpec>) {
          out << YAML::Key << "circle" << YAML::Value << YAML::BeginMap;
          EmitVector(out, "center_m", spec.center_W);
          EmitNumber(out, "radius_m", spec.radius_m);
          EmitNumber(out, "speed_mps", spec.speed_mps);
          EmitNumber(out, "laps", spec.laps);
          out << YAML::Key << "clockwise" << YAML::Value << spec.clockwise;
          out << YAML::EndMap;
        } else if constexpr (std::is_same_v<T, sim::FigureEightSpec>) {
          out << YAML::Key << "figure_eight" << YAML::Value << YAML::BeginMap;
          EmitVector(out, "center_m", spec.center_W);
          EmitNumber(out, "half_length_m", spec.half_length_m);
          EmitNumber(out, "half_width_m", spec.half_width_m);
          EmitNumber(out, "speed_mps", spec.speed_mps);
          EmitNumber(out, "laps", spec.laps);
          out << YAML::EndMap;
        } else {
          static_assert(std::is_same_v<T, sim::ApproachSpec>, "unhandled primitive");
          out << YAML::Key << "approach" << YAML::Value << YAML::BeginMap;
          EmitVector(out, "direction", spec.direction_W);
          EmitNumber(out, "standoff_m", spec.standoff_m);
          EmitNumber(out, "speed_mps", spec.speed_mps);
          out << YAML::EndMap;
        }
      },
      segment);
  out << YAML::EndMap;
}

// The `trajectory` section of the resolved scenario: start pose, limits and segments.
void EmitTrajectory(YAML::Emitter& out, const sim::TrajectorySpec& t) {
  out << YAML::Key << "trajectory" << YAML::Value << YAML::BeginMap;
  out << YAML::Key << "start" << YAML::Value << YAML::BeginMap;
  EmitVector(out, "position_m", t.start.p_WB);
  EmitRpyDeg(out, "rpy_deg", t.start.q_WB);
  out << YAML::EndMap;
  out << YAML::Key << "limits" << YAML::Value << YAML::BeginMap;
  EmitNumber(out, "max_speed_mps", t.limits.max_speed_mps);
  EmitNumber(out, "max_acceleration_mps2", t.limits.max_acceleration_mps2);
  EmitDegrees(out, "max_angular_rate_degps", t.limits.max_angular_rate_radps);
  EmitDegrees(out, "max_angular_acceleration_degps2", t.limits.max_angular_acceleration_radps2);
  out << YAML::EndMap;
  out << YAML::Key << "segments" << YAML::Value << YAML::BeginSeq;
  for (const sim::PrimitiveSpec& segment : t.segments) EmitSegment(out, segment);
  out << YAML::EndSeq;
  out << YAML::EndMap;
}

void EmitSensors(YAML::Emitter& out, const std::vector<SensorConfig>& sensors) {
  out << YAML::Key << "sensors" << YAML::Value;
  if (sensors.empty()) {
    out << YAML::Flow << YAML::BeginMap << YAML::EndMap;
    return;
  }
  out << YAML::BeginMap;
  for (const SensorConfig& sensor : sensors) {
    out << YAML::Key << sensor.name << YAML::Value << YAML::BeginMap;
    out << YAML::Key << "type" << YAML::Value << std::string(SensorTypeName(sensor.options));
    internal::EmitSensorOptions(out, sensor.options);
    internal::EmitCalibrationError(out, sensor.calibration_error);
    out << YAML::EndMap;
  }
  out << YAML::EndMap;
}

void EmitFaults(YAML::Emitter& out, const std::vector<sim::FaultSpec>& faults) {
  out << YAML::Key << "faults" << YAML::Value;
  if (faults.empty()) {
    out << YAML::Flow << YAML::BeginSeq << YAML::EndSeq;
    return;
  }
  out << YAML::BeginSeq;
  for (const sim::FaultSpec& fault : faults) internal::EmitFaultSpec(out, fault);
  out << YAML::EndSeq;
}

void EmitConsistency(YAML::Emitter& out, const ConsistencyConfig& cc) {
  out << YAML::Key << "consistency" << YAML::Value << YAML::BeginMap;
  EmitNumber(out, "rate_hz", cc.rate_hz);
  EmitNumber(out, "window_s", cc.window_s);
  out << YAML::Key << "metrics" << YAML::Value << YAML::Flow << YAML::BeginSeq;
  for (const estimator::ConsistencyMetric m : cc.metrics) {
    out << std::string(estimator::MetricName(m));
  }
  out << YAML::EndSeq;
  out << YAML::Key << "standardize" << YAML::Value << cc.standardize;
  EmitNumber(out, "kl_bandwidth_scale", cc.kl_bandwidth_scale);
  EmitNumber(out, "alignment_window_s", cc.alignment_window_s);
  EmitNumber(out, "alignment_rate_hz", cc.alignment_rate_hz);
  EmitNumber(out, "differentiation_window_s", cc.differentiation_window_s);
  out << YAML::EndMap;
}

// Every option, resolved: a run directory's scenario configures its methods alike under
// any later profile's defaults. `profile` first, as a reader of the block takes it.
void EmitEstimation(YAML::Emitter& out, const EstimationConfig& ec) {
  const auto fields = EstimationConfig::Fields();
  out << YAML::Key << "estimation" << YAML::Value << YAML::BeginMap;
  internal::EmitOptionFields(out, fields.first(1), ec);
  out << YAML::Key << "methods" << YAML::Value << YAML::Flow << YAML::BeginSeq;
  for (const std::string& m : ec.methods) out << YAML::DoubleQuoted << m;
  out << YAML::EndSeq;
  out << YAML::Key << "consensus" << YAML::Value << YAML::BeginMap;
  internal::EmitOptionFields(out, ConsensusConfig::Fields(), ec.consensus);
  out << YAML::Key << "priority" << YAML::Value << YAML::Flow << YAML::BeginSeq;
  for (const std::string& p : ec.consensus.priority) out << p;
  out << YAML::EndSeq;
  out << YAML::EndMap;
  internal::EmitOptionFields(out, fields.subspan(1), ec);
  out << YAML::EndMap;
}

// What a client's setup carries: the block as the resolved scenario writes it.
std::string ResolvedEstimationYaml(const EstimationConfig& config) {
  YAML::Emitter block;
  block << YAML::BeginMap;
  EmitEstimation(block, config);
  block << YAML::EndMap;
  return std::string(block.c_str()) + "\n";
}

void EmitControl(YAML::Emitter& out, const ControlConfig& control) {
  out << YAML::Key << "control" << YAML::Value << YAML::BeginMap;
  out << YAML::Key << "state_source" << YAML::Value << StateSourceName(control.state_source);
  if (!control.methods.empty()) {
    out << YAML::Key << "methods" << YAML::Value << YAML::Flow << YAML::BeginSeq;
    for (const std::string& m : control.methods) out << YAML::DoubleQuoted << m;
    out << YAML::EndSeq;
  }
  EmitNumber(out, "corridor_m", control.corridor_m);
  if (control.controller) out << YAML::Key << "controller" << YAML::Value << *control.controller;
  out << YAML::Key << "failsafe" << YAML::Value << YAML::BeginMap;
  EmitNumber(out, "hold_s", control.failsafe.hold_s);
  EmitNumber(out, "descent_rate_mps", control.failsafe.descent_rate_mps);
  EmitNumber(out, "land_z_m", control.failsafe.land_z_m);
  if (control.failsafe.max_position_std_m) {
    EmitNumber(out, "max_position_std_m", *control.failsafe.max_position_std_m);
  }
  out << YAML::EndMap;
  out << YAML::EndMap;
}

void EmitRender(YAML::Emitter& out, const RenderRequest& r) {
  out << YAML::Key << "render" << YAML::Value << YAML::BeginMap;
  out << YAML::Key << "when" << YAML::Value << (r.always ? "always" : "failure");
  out << YAML::Key << "size" << YAML::Value << YAML::Flow << YAML::BeginSeq << r.width_px
      << r.height_px << YAML::EndSeq;
  out << YAML::Key << "fps" << YAML::Value << r.fps;
  out << YAML::Key << "camera" << YAML::Value << r.camera;
  EmitNumber(out, "clip_half_s", r.clip_half_s);
  EmitNumber(out, "error_bound_m", r.error_bound_m);
  out << YAML::EndMap;
}

void EmitExpectations(YAML::Emitter& out, const std::vector<Expectation>& expectations) {
  out << YAML::Key << "expect" << YAML::Value;
  if (expectations.empty()) {
    out << YAML::Flow << YAML::BeginSeq << YAML::EndSeq;
    return;
  }
  out << YAML::BeginSeq;
  for (const Expectation& e : expectations) {
    out << YAML::BeginMap;
    out << YAML::Key << "metric" << YAML::Value << e.metric;
    if (e.min) EmitNumber(out, "min", *e.min);
    if (e.max) EmitNumber(out, "max", *e.max);
    if (e.window_s) {
      out << YAML::Key << "window_s" << YAML::Value << YAML::Flow << YAML::BeginSeq
          << FormatDouble(e.window_s->first) << FormatDouble(e.window_s->second) << YAML::EndSeq;
    }
    EmitNumber(out, "pass_fraction", e.pass_fraction);
    if (e.relative_to) out << YAML::Key << "relative_to" << YAML::Value << *e.relative_to;
    out << YAML::EndMap;
  }
  out << YAML::EndSeq;
}

// A per-method metric must name a method of `estimation.methods`.
void CheckMethodOfMetric(const Scenario& scenario, const Expectation& expectation,
                         const std::string& metric, const std::string& key_path) {
  const MetricArguments args = MatchMetric(metric)->second;
  if (args.method.empty()) return;
  const bool closed_loop = metric.starts_with("closed_loop.");
  std::vector<std::string> methods;
  if (closed_loop && scenario.control) {
    methods = scenario.control->methods;
  } else if (!closed_loop && scenario.estimation) {
    methods = scenario.estimation->methods;
  }
  if (std::find(methods.begin(), methods.end(), args.method) != methods.end()) return;
  throw core::InputError(
      expectation.location, key_path,
      fmt::format("metric '{}' names method '{}', which {} does not list (listed: {})", metric,
                  args.method, closed_loop ? "control.methods" : "estimation.methods",
                  methods.empty() ? "none" : fmt::format("{}", fmt::join(methods, ", "))));
}

}  // namespace

void ApplyEstimationSettings(const std::vector<std::string>& settings,
                             EstimationConfig* config) {
  if (settings.empty()) return;
  std::vector<EstimationSetting> parsed;
  for (const std::string& text : settings) parsed.push_back(SplitSetting(text));
  // The value as the scenario would write it under its key ("--set:1:C: <key>: ...").
  const auto value_of = [](const EstimationSetting& s) {
    const YamlValue root = ParseDocument(fmt::format("{}: {}", s.key, s.value), "--set");
    YamlMap map = root.Map({s.key});
    const YamlValue value = map.Required(s.key);
    map.Finish();
    return value;
  };
  // The profile first, under the run's own choices: a key whose value differs from its
  // profile's default is one the scenario wrote, and keeps it; every other key takes the
  // new profile's value. The settings after it then change what they name.
  for (const EstimationSetting& s : parsed) {
    if (s.key != "profile") continue;
    EstimationConfig profile_of;
    internal::ReadOptionField(value_of(s), EstimationConfig::Fields().front(), &profile_of);
    const EstimationConfig own = EstimationConfig::Defaults(config->profile);
    EstimationConfig switched = EstimationConfig::Defaults(profile_of.profile);
    // `profile` itself never differs from `own`'s: it is switched.
    core::CopyFieldsThatDiffer(*config, own, &switched, EstimationConfig::Fields());
    core::CopyFieldsThatDiffer(config->consensus, own.consensus, &switched.consensus,
                               ConsensusConfig::Fields());
    switched.methods = config->methods;
    switched.clients = config->clients;
    switched.consensus.priority = config->consensus.priority;
    *config = std::move(switched);
  }
  const estimator::ConsistencyMetric metric_before = config->consensus.metric;
  bool threshold_set = false;
  for (const EstimationSetting& s : parsed) {
    if (s.key == "profile") continue;
    if (const auto* field = FindField(EstimationConfig::Fields(), s.key)) {
      internal::ReadOptionField(value_of(s), *field, config);
    } else if (const auto* consensus_field =
                   s.key.starts_with("consensus.")
                       ? FindField(ConsensusConfig::Fields(), std::string_view(s.key).substr(10))
                       : nullptr) {
      internal::ReadOptionField(value_of(s), *consensus_field, &config->consensus);
      threshold_set = threshold_set || s.key == "consensus.threshold";
    } else {
      throw core::InputError({}, "--set " + s.text,
                             fmt::format("no estimation key '{}'; expected one of {}", s.key,
                                         SettableKeys()));
    }
  }
  KeepThresholdOnItsMetric(metric_before, threshold_set, config);
  std::string why;
  if (!config->IsValid(&why)) {
    throw core::InputError({}, "--set", "the estimation settings break a rule: " + why);
  }
  config->resolved_yaml = ResolvedEstimationYaml(*config);
}

replay::EstimationConfig ParseEstimationBlock(const std::string& yaml_text,
                                              const std::string& file_label,
                                              const std::vector<std::string>& sensors,
                                              const std::string& imu) {
  const YamlValue root = ParseDocument(yaml_text, file_label);
  YamlMap map = root.Map({"estimation"});
  // The block's checks need only which stream is the IMU and the others' names.
  std::vector<SensorConfig> configs;
  for (const std::string& name : sensors) {
    SensorConfig c;
    c.name = name;
    if (name == imu) c.options = sim::ImuOptions{};
    else c.options = sim::VioOptions{};
    configs.push_back(std::move(c));
  }
  EstimationConfig config =
      ReadEstimation(map.Required("estimation"), configs, {}, /*check_methods=*/false);
  map.Finish();
  config.resolved_yaml = yaml_text;
  return config;
}

sim::Waypoint LaunchPad(const Scenario& scenario) {
  return scenario.mission.launch_pad.value_or(scenario.trajectory.start);
}

bool SurveyedInMission(const Scenario& scenario, const SensorConfig& sensor) {
  if (scenario.mission.surveyed) {
    const std::vector<std::string>& names = *scenario.mission.surveyed;
    return std::find(names.begin(), names.end(), sensor.name) != names.end();
  }
  return IsAbsoluteSensor(sensor);
}

namespace {

// The physics rate first: the controller and output rates are bounded by it.
void ReadRates(YamlMap& map, Scenario* scenario) {
  std::optional<YamlValue> physics_rate;
  if (const auto physics = map.Optional("physics")) {
    scenario->physics = ReadPhysics(*physics, &physics_rate);
  }
  const auto controller = map.Optional("controller");
  if (controller) scenario->controller = ReadController(*controller, scenario->physics.rate_hz);
  if (const auto wind = map.Optional("wind")) scenario->wind = ReadWind(*wind);
  const auto output = map.Optional("output");
  if (output) scenario->output = ReadOutput(*output, scenario->physics.rate_hz);
  // A default rate above a (given) physics rate: blame the physics rate, the only key written.
  for (const auto& [what, rate_hz] :
       {std::pair<const char*, double>{"controller.rate_hz", scenario->controller.rate_hz},
        std::pair<const char*, double>{"output.groundtruth_rate_hz",
                                       scenario->output.groundtruth_rate_hz}}) {
    if (rate_hz > scenario->physics.rate_hz) {
      assert(physics_rate.has_value());  // the default physics rate carries every default
      physics_rate->Fail(fmt::format(
          "expected at least the default {} of {} Hz, got {} (or set {} <= physics.rate_hz)", what,
          FormatDouble(rate_hz), physics_rate->Describe(), what));
    }
  }
}

// `expect:`, each metric's method checked against the scenario's methods.
void ReadExpectations(const YamlValue& expect, Scenario* scenario) {
  for (const YamlValue& item : expect.List(/*non_empty=*/false)) {
    scenario->expect.push_back(ReadExpectation(item, scenario->sensors));
    const Expectation& e = scenario->expect.back();
    CheckMethodOfMetric(*scenario, e, e.metric, item.path() + ".metric");
    if (e.relative_to) {
      CheckMethodOfMetric(*scenario, e, *e.relative_to, item.path() + ".relative_to");
    }
  }
}

}  // namespace

Scenario ParseScenario(const std::string& yaml_text, const std::string& file_label) {
  const YamlValue root = ParseDocument(yaml_text, file_label);
  YamlMap map = root.Map({"name", "description", "world", "robot", "duration_s", "seed", "physics",
                          "controller", "wind", "output", "trajectory", "initial_offset",
                          "sensors", "faults", "consistency", "external", "plugins",
                          "estimation", "control", "mission", "render", "compare", "expect"});
  Scenario scenario;
  scenario.source_file = file_label;
  scenario.name = map.Required("name").Identifier();
  if (const auto description = map.Optional("description")) {
    scenario.description = description->String();
  }
  // The world and the robot: fields of sim::WorldOptions, read with its table's forms.
  const auto world_fields = sim::WorldOptions::Fields();
  const YamlValue world = map.Required("world");
  ReadFieldValue(world, FieldFormatOf(world_fields, "world"), &scenario.world);
  scenario.key_locations["world"] = world.location();
  if (const auto robot = map.Optional("robot")) {
    ReadFieldValue(*robot, FieldFormatOf(world_fields, "robot"), &scenario.robot);
    scenario.key_locations["robot"] = robot->location();
  }
  scenario.duration_s = map.Required("duration_s").Number(NumberRule::PositiveAtMost(86400.0, "s"));
  if (const auto seed = map.Optional("seed")) scenario.seed = seed->UnsignedInteger();

  ReadRates(map, &scenario);

  const YamlValue trajectory = map.Required("trajectory");
  scenario.trajectory = ReadTrajectory(trajectory);
  scenario.key_locations["trajectory"] = trajectory.key_location();
  if (const auto offset = map.Optional("initial_offset")) {
    scenario.initial_offset = ReadInitialOffset(*offset);
  }
  if (const auto sensors = map.Optional("sensors")) {
    scenario.sensors = ReadSensors(*sensors);
    for (const auto& [name, entry] : sensors->Entries()) {
      scenario.key_locations["sensors." + name] = entry.key_location();
    }
  }
  if (const auto faults = map.Optional("faults")) {
    std::map<std::string, core::MeasurementKind> sensor_kinds;
    for (const SensorConfig& sensor : scenario.sensors) {
      sensor_kinds[sensor.name] = SensorMeasurementKind(sensor.options);
    }
    scenario.faults = internal::ReadFaults(*faults, scenario.duration_s, sensor_kinds);
  }
  if (const auto consistency = map.Optional("consistency")) {
    scenario.consistency = ReadConsistency(*consistency);
  }
  scenario.clients =
      ReadClients(map.Optional("external"), map.Optional("plugins"), file_label);
  if (const auto compare = map.Optional("compare")) {
    YamlMap compare_map = compare->Map({"minimal_effects"});
    if (const auto effects = compare_map.Optional("minimal_effects")) {
      for (const auto& [metric, value] : effects->StringEntries()) {
        scenario.compare_minimal_effects[metric] = value.Number(NumberRule::NonNegative(""));
        scenario.key_locations["compare.minimal_effects." + metric] = value.key_location();
      }
    }
    compare_map.Finish();
  }
  for (const char* block : {"external", "plugins"}) {
    if (const auto clients = map.Optional(block)) {
      for (const auto& [key, entry] : clients->Entries()) {
        scenario.key_locations[std::string(block) + "." + key] = entry.key_location();
      }
    }
  }
  if (const auto estimation = map.Optional("estimation")) {
    scenario.estimation = ReadEstimation(*estimation, scenario.sensors, scenario.clients);
    scenario.estimation->resolved_yaml = ResolvedEstimationYaml(*scenario.estimation);
  }
  if (const auto control = map.Optional("control")) {
    scenario.control = ReadControl(*control, scenario);
  }
  if (const auto mission = map.Optional("mission")) {
    scenario.mission = ReadMission(*mission, scenario.sensors);
  }
  if (const auto render = map.Optional("render")) {
    scenario.render = ReadRender(*render);
    if (const auto camera = render->Peek("camera")) {
      scenario.key_locations["render.camera"] = camera->location();
    }
  }
  if (const auto expect = map.Optional("expect")) ReadExpectations(*expect, &scenario);
  map.Finish();
  return scenario;
}

void CheckScenarioModels(const Scenario& scenario, const std::string& models_dir) {
  const auto where = [&](const std::string& key) {
    const auto it = scenario.key_locations.find(key);
    return it != scenario.key_locations.end() ? it->second
                                              : core::SourceLocation{scenario.source_file, 0, 0};
  };

  sim::WorldOptions options;
  if (!models_dir.empty()) options.models_dir = models_dir;
  options.world = scenario.world;
  options.robot = scenario.robot;
  options.physics_rate_hz = scenario.physics.rate_hz;
  std::unique_ptr<sim::World> world;
  try {
    world = std::make_unique<sim::World>(options);
  } catch (const core::InputError& e) {
    // The model's own error names the model file; the scenario's key says who asked.
    const std::string key = e.key_path() == "robot" ? "robot" : "world";
    throw core::InputError(where(key), key, fmt::format("{}: {}", e.location().file, e.message()));
  }

  const sim::MountSite* tool = world->robot().FindSite("tool_tip");
  if (tool == nullptr) {
    throw core::InputError(where("robot"), "robot",
                           fmt::format("the robot model '{}' has no site 'tool_tip' (the point "
                                       "approach segments and standoffs refer to)",
                                       scenario.robot));
  }
  sim::TrajectoryContext context;
  context.p_B_tool = tool->p_Bs;
  context.surface_distance = [&world](const Eigen::Vector3d& origin_W,
                                      const Eigen::Vector3d& direction_W) {
    return world->RayDistance(origin_W, direction_W);
  };
  try {
    sim::BuildTrajectory(scenario.trajectory, context);
  } catch (const std::invalid_argument& e) {
    throw core::InputError(where("trajectory"), "trajectory", e.what());
  } catch (const core::InputError&) {
    throw;
  } catch (const std::runtime_error& e) {  // a minimum-snap system without a solution
    throw core::InputError(where("trajectory"), "trajectory", e.what());
  }

  for (const SensorConfig& config : scenario.sensors) {
    try {
      MakeSensorModel(config, *world, scenario.seed);
    } catch (const std::invalid_argument& e) {
      throw core::InputError(where("sensors." + config.name), "sensors." + config.name, e.what());
    }
  }

  if (scenario.render) {
    const std::string& camera = scenario.render->camera;
    std::vector<std::string> cameras = {"chase", "overview"};
    const mjModel* model = world->model();
    for (int i = 0; i < model->ncam; ++i) {
      const char* name = mj_id2name(model, mjOBJ_CAMERA, i);
      if (name != nullptr && std::strcmp(name, "overview") != 0) cameras.emplace_back(name);
    }
    if (std::find(cameras.begin(), cameras.end(), camera) == cameras.end()) {
      throw core::InputError(where("render.camera"), "render.camera",
                             fmt::format("unknown camera '{}' in world '{}'; expected one of: {}",
                                         camera, scenario.world, fmt::join(cameras, ", ")));
    }
  }
  CheckClientsResolve(scenario.clients, where);
}

Scenario LoadScenario(const std::string& path) {
  std::error_code error;
  const std::filesystem::file_status status = std::filesystem::status(path, error);
  if (error || !std::filesystem::exists(status)) {
    throw core::InputError(
        {path, 0, 0}, "",
        "cannot read scenario file: " + (error ? error.message() : std::string("no such file")));
  }
  if (std::filesystem::is_directory(status)) {
    throw core::InputError({path, 0, 0}, "",
                           "cannot read scenario file: it is a directory, expected a YAML file");
  }
  return ParseScenario(core::ReadWholeFile(path, "scenario file", core::kMaxConfigFileBytes), path);
}

std::string ResolvedScenarioYaml(const Scenario& scenario) {
  YAML::Emitter out;
  out << YAML::BeginMap;
  out << YAML::Key << "name" << YAML::Value << scenario.name;
  out << YAML::Key << "description" << YAML::Value << scenario.description;
  const auto world_fields = sim::WorldOptions::Fields();
  EmitFieldValue(out, FieldFormatOf(world_fields, "world"), scenario.world);
  EmitFieldValue(out, FieldFormatOf(world_fields, "robot"), scenario.robot);
  EmitNumber(out, "duration_s", scenario.duration_s);
  out << YAML::Key << "seed" << YAML::Value << scenario.seed;

  out << YAML::Key << "physics" << YAML::Value << YAML::BeginMap;
  EmitFieldValue(out, FieldFormatOf(world_fields, "rate_hz"), scenario.physics.rate_hz);
  out << YAML::EndMap;

  out << YAML::Key << "controller" << YAML::Value << YAML::BeginMap;
  EmitOptionFields(out, sim::ControllerOptions::Fields(), scenario.controller);
  out << YAML::EndMap;

  out << YAML::Key << "wind" << YAML::Value << YAML::BeginMap;
  EmitOptionFields(out, sim::WindOptions::Fields(), scenario.wind);
  out << YAML::EndMap;

  out << YAML::Key << "output" << YAML::Value << YAML::BeginMap;
  EmitNumber(out, "groundtruth_rate_hz", scenario.output.groundtruth_rate_hz);
  out << YAML::EndMap;

  EmitTrajectory(out, scenario.trajectory);

  out << YAML::Key << "initial_offset" << YAML::Value << YAML::BeginMap;
  EmitVector(out, "position_m", scenario.initial_offset.position_W_m);
  EmitRpyDeg(out, "rpy_deg", scenario.initial_offset.q_offset);
  out << YAML::EndMap;

  EmitSensors(out, scenario.sensors);
  EmitFaults(out, scenario.faults);
  if (scenario.consistency) EmitConsistency(out, *scenario.consistency);
  EmitClients(out, scenario.clients);
  if (scenario.estimation) EmitEstimation(out, *scenario.estimation);
  if (scenario.control) EmitControl(out, *scenario.control);
  EmitMission(out, scenario.mission);
  if (scenario.render) EmitRender(out, *scenario.render);
  if (!scenario.compare_minimal_effects.empty()) {
    out << YAML::Key << "compare" << YAML::Value << YAML::BeginMap << YAML::Key
        << "minimal_effects" << YAML::Value << YAML::BeginMap;
    for (const auto& [metric, effect] : scenario.compare_minimal_effects) {
      EmitNumber(out, metric, effect);
    }
    out << YAML::EndMap << YAML::EndMap;
  }
  EmitExpectations(out, scenario.expect);
  out << YAML::EndMap;
  assert(out.good());
  return std::string(out.c_str()) + "\n";
}

}  // namespace tofu::harness
