#include "harness/fault_config.h"

#include <cmath>
#include <optional>
#include <string>

#include <fmt/format.h>
#include <fmt/ranges.h>

#include "harness/config_io.h"

namespace tofu::harness::internal {

using namespace config;  // NOLINT: the small readers of config_io.h

namespace {

std::string KindList() {
  std::string out;
  for (const sim::FaultKind kind : sim::AllFaultKinds()) {
    if (!out.empty()) out += ", ";
    out += sim::FaultKindName(kind);
  }
  return out;
}

// The fault's map, opened with the keys of its kind (the unknown-key message then lists
// exactly those).
YamlMap OpenFaultMap(const YamlValue& value, sim::FaultKind kind) {
  switch (kind) {
    case sim::FaultKind::kMisalignment:
      return value.Map({"sensor", "kind", "start_s", "end_s", "rpy_deg", "translation_m"});
    case sim::FaultKind::kNonGaussianNoise:
      return value.Map({"sensor", "kind", "start_s", "end_s", "white_std_m",
                        "brown_std_m_per_sqrt_s", "brown_time_constant_s"});
    case sim::FaultKind::kDivergence:
      return value.Map({"sensor", "kind", "start_s", "end_s", "axis", "initial_velocity_mps",
                        "time_constant_s"});
    case sim::FaultKind::kDropout:
    case sim::FaultKind::kFreeze:
      return value.Map({"sensor", "kind", "start_s", "end_s"});
    case sim::FaultKind::kDelay:
      return value.Map({"sensor", "kind", "start_s", "end_s", "delay_s", "arrival_delay_s"});
    case sim::FaultKind::kJump:
      return value.Map({"sensor", "kind", "start_s", "end_s", "translation_m", "rpy_deg"});
    case sim::FaultKind::kOutliers:
      return value.Map({"sensor", "kind", "start_s", "end_s", "rate_hz", "scale_m",
                        "rotation_scale_deg", "acc_scale_mps2", "gyro_scale_degps",
                        "degrees_of_freedom"});
  }
  return value.Map({});
}

void ReadParameters(YamlMap& map, sim::FaultSpec* spec, double run_duration_s) {
  switch (spec->kind) {
    case sim::FaultKind::kMisalignment: {
      sim::MisalignmentParams& p = spec->misalignment;
      if (const auto q = ReadRpy(map)) p.q_FS = *q;
      ReadVector(map, "translation_m", NumberRule::Any("m"), false, &p.p_FS_m);
      return;
    }
    case sim::FaultKind::kNonGaussianNoise: {
      sim::NonGaussianNoiseParams& p = spec->noise;
      ReadNumber(map, "white_std_m", NumberRule::NonNegative("m"), &p.white_std_m);
      ReadNumber(map, "brown_std_m_per_sqrt_s", NumberRule::NonNegative("m/sqrt(s)"),
                 &p.brown_std_m_per_sqrt_s);
      ReadNumber(map, "brown_time_constant_s", NumberRule::Positive("s"),
                 &p.brown_time_constant_s);
      return;
    }
    case sim::FaultKind::kDivergence: {
      sim::DivergenceParams& p = spec->divergence;
      if (const auto axis = map.Optional("axis")) {
        p.axis_S = axis->Vector3(NumberRule::Any(""));
        if (!(p.axis_S.norm() > 0.0)) axis->FailExpected("a non-zero direction [x, y, z] in S");
      }
      ReadNumber(map, "initial_velocity_mps", NumberRule::Positive("m/s"),
                 &p.initial_velocity_mps);
      ReadNumber(map, "time_constant_s", NumberRule::Positive("s"), &p.time_constant_s);
      return;
    }
    case sim::FaultKind::kDropout:
    case sim::FaultKind::kFreeze:
      return;
    case sim::FaultKind::kDelay: {
      sim::DelayParams& p = spec->delay;
      ReadNumber(map, "delay_s", NumberRule::Between(0.0, run_duration_s, "s"), &p.delay_s);
      ReadNumber(map, "arrival_delay_s", NumberRule::Between(0.0, run_duration_s, "s"),
                 &p.arrival_delay_s);
      return;
    }
    case sim::FaultKind::kJump: {
      sim::JumpParams& p = spec->jump;
      ReadVector(map, "translation_m", NumberRule::Any("m"), false, &p.translation_S_m);
      if (const auto q = ReadRpy(map)) p.q_jump = *q;
      return;
    }
    case sim::FaultKind::kOutliers: {
      sim::OutlierParams& p = spec->outliers;
      ReadNumber(map, "rate_hz", NumberRule::Positive("Hz"), &p.rate_hz);
      ReadNumber(map, "scale_m", NumberRule::NonNegative("m"), &p.scale_m);
      ReadDegrees(map, "rotation_scale_deg", NumberRule::Between(0.0, 180.0, "deg"),
                  &p.rotation_scale_rad);
      ReadNumber(map, "acc_scale_mps2", NumberRule::NonNegative("m/s^2"), &p.acc_scale_mps2);
      ReadDegrees(map, "gyro_scale_degps", NumberRule::NonNegative("deg/s"),
                  &p.gyro_scale_radps);
      ReadInteger(map, "degrees_of_freedom", 1, 100, &p.degrees_of_freedom);
      return;
    }
  }
}

}  // namespace

sim::FaultSpec ReadFaultSpec(const YamlValue& value, double run_duration_s) {
  const std::string kinds = KindList();
  if (!value.node().IsMap()) {
    value.FailExpected("a map {sensor, kind, start_s, end_s, ...} (kinds: " + kinds + ")");
  }
  // The kind selects the allowed keys, so it is read before the map is opened.
  const std::optional<YamlValue> kind_value = value.Peek("kind");
  if (!kind_value) {
    value.FailAtKey(fmt::format("missing required key 'kind' (one of: {})", kinds));
  }
  const std::string kind_name = kind_value->String();
  const std::optional<sim::FaultKind> kind = sim::FaultKindFromName(kind_name);
  if (!kind) {
    std::vector<std::string> names;
    for (const sim::FaultKind k : sim::AllFaultKinds()) names.emplace_back(sim::FaultKindName(k));
    const std::string suggestion = ClosestMatch(kind_name, names);
    kind_value->Fail(fmt::format("unknown fault kind '{}'{}; expected one of: {}", kind_name,
                                 suggestion.empty() ? "" : " (did you mean '" + suggestion + "'?)",
                                 kinds));
  }

  sim::FaultSpec spec;
  spec.kind = *kind;
  YamlMap map = OpenFaultMap(value, *kind);
  (void)map.Required("kind");  // read above
  spec.sensor = map.Required("sensor").Identifier();

  // The window lies in the run: 0 <= start_s < end_s <= duration.
  const std::string run = fmt::format("s, within the run of {} s", FormatDouble(run_duration_s));
  NumberRule start_rule = NumberRule::Between(0.0, run_duration_s, run);
  start_rule.max_exclusive = true;
  ReadNumber(map, "start_s", start_rule, &spec.start_s);
  const std::string after_start =
      fmt::format("s, after start_s = {} and within the run of {} s", FormatDouble(spec.start_s),
                  FormatDouble(run_duration_s));
  NumberRule end_rule = NumberRule::Between(spec.start_s, run_duration_s, after_start);
  end_rule.min_exclusive = true;
  ReadNumber(map, "end_s", end_rule, &spec.end_s);

  ReadParameters(map, &spec, run_duration_s);
  map.Finish();
  return spec;
}

std::vector<sim::FaultSpec> ReadFaults(const YamlValue& list, double run_duration_s,
                                       const std::map<std::string, core::MeasurementKind>& sensors) {
  std::vector<sim::FaultSpec> specs;
  for (const YamlValue& item : list.List(/*non_empty=*/false)) {
    sim::FaultSpec spec = ReadFaultSpec(item, run_duration_s);
    const auto sensor = sensors.find(spec.sensor);
    if (sensor == sensors.end()) {
      std::vector<std::string> names;
      for (const auto& [name, type] : sensors) names.push_back(name);
      const std::string joined = fmt::format("{}", fmt::join(names, ", "));
      const std::string suggestion = ClosestMatch(spec.sensor, names);
      item.Peek("sensor")->Fail(fmt::format(
          "unknown sensor '{}'{}; the scenario's sensors: {}", spec.sensor,
          suggestion.empty() ? "" : " (did you mean '" + suggestion + "'?)",
          joined.empty() ? "(none)" : joined));
    }
    if (const auto reason = sim::CheckFaultApplies(spec, sensor->second)) {
      item.Peek("kind")->Fail(fmt::format("fault on sensor '{}' ({} measurements): {}",
                                          spec.sensor, core::MeasurementKindName(sensor->second),
                                          *reason));
    }
    specs.push_back(std::move(spec));
  }
  return specs;
}

void EmitFaultSpec(YAML::Emitter& out, const sim::FaultSpec& spec) {
  out << YAML::BeginMap;
  out << YAML::Key << "sensor" << YAML::Value << spec.sensor;
  out << YAML::Key << "kind" << YAML::Value << std::string(sim::FaultKindName(spec.kind));
  EmitNumber(out, "start_s", spec.start_s);
  if (std::isfinite(spec.end_s)) EmitNumber(out, "end_s", spec.end_s);
  switch (spec.kind) {
    case sim::FaultKind::kMisalignment:
      EmitVector(out, "rpy_deg", RpyDegFromQuat(spec.misalignment.q_FS));
      EmitVector(out, "translation_m", spec.misalignment.p_FS_m);
      break;
    case sim::FaultKind::kNonGaussianNoise:
      EmitNumber(out, "white_std_m", spec.noise.white_std_m);
      EmitNumber(out, "brown_std_m_per_sqrt_s", spec.noise.brown_std_m_per_sqrt_s);
      if (std::isfinite(spec.noise.brown_time_constant_s)) {
        EmitNumber(out, "brown_time_constant_s", spec.noise.brown_time_constant_s);
      }
      break;
    case sim::FaultKind::kDivergence:
      EmitVector(out, "axis", spec.divergence.axis_S);
      EmitNumber(out, "initial_velocity_mps", spec.divergence.initial_velocity_mps);
      EmitNumber(out, "time_constant_s", spec.divergence.time_constant_s);
      break;
    case sim::FaultKind::kDropout:
    case sim::FaultKind::kFreeze:
      break;
    case sim::FaultKind::kDelay:
      EmitNumber(out, "delay_s", spec.delay.delay_s);
      EmitNumber(out, "arrival_delay_s", spec.delay.arrival_delay_s);
      break;
    case sim::FaultKind::kJump:
      EmitVector(out, "translation_m", spec.jump.translation_S_m);
      EmitVector(out, "rpy_deg", RpyDegFromQuat(spec.jump.q_jump));
      break;
    case sim::FaultKind::kOutliers:
      EmitNumber(out, "rate_hz", spec.outliers.rate_hz);
      EmitNumber(out, "scale_m", spec.outliers.scale_m);
      EmitNumber(out, "rotation_scale_deg", spec.outliers.rotation_scale_rad * kDegPerRad);
      EmitNumber(out, "acc_scale_mps2", spec.outliers.acc_scale_mps2);
      EmitNumber(out, "gyro_scale_degps", spec.outliers.gyro_scale_radps * kDegPerRad);
      out << YAML::Key << "degrees_of_freedom" << YAML::Value << spec.outliers.degrees_of_freedom;
      break;
  }
  out << YAML::EndMap;
}

}  // namespace tofu::harness::internal
