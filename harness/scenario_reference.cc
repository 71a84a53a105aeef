#include "harness/scenario_reference.h"

#include <span>
#include <string_view>
#include <type_traits>
#include <vector>

#include <fmt/format.h>
#include <fmt/ranges.h>
#include <yaml-cpp/yaml.h>

#include "harness/option_fields_yaml.h"
#include "replay/estimation_config.h"
#include "sim/controller.h"
#include "sim/gnss.h"
#include "sim/imu.h"
#include "sim/lidar_odometry.h"
#include "sim/total_station.h"
#include "sim/vio.h"
#include "sim/wind.h"
#include "sim/world.h"

namespace tofu::harness {

namespace {

using replay::ConsensusConfig;
using replay::EstimationConfig;
using replay::EstimationProfile;

// A cell of a Markdown table: pipes escaped, so a doc line cannot split its row.
std::string Cell(std::string_view text) {
  std::string out;
  for (char c : text) {
    if (c == '|') out += '\\';
    out += c;
  }
  return out;
}

// The form a key's value takes in a file, from the member's type and the field's format.
template <typename Value>
std::string FormOf(const core::FieldFormat& format) {
  const std::string rule = format.rule.Describe();
  if constexpr (std::is_same_v<Value, double>) {
    return "number" + rule;
  } else if constexpr (std::is_same_v<Value, std::optional<double>>) {
    return "number" + rule + ", optional";
  } else if constexpr (std::is_same_v<Value, int>) {
    return fmt::format("integer in [{}, {}]", format.min_integer, format.max_integer);
  } else if constexpr (std::is_same_v<Value, bool>) {
    return "true or false";
  } else if constexpr (std::is_same_v<Value, std::string>) {
    return "a name ([a-z0-9_])";
  } else if constexpr (std::is_same_v<Value, Eigen::Vector3d>) {
    return "[x, y, z]" + rule + (format.scalar_for_vector ? ", or one number for all three" : "");
  } else if constexpr (std::is_same_v<Value, std::optional<Eigen::Vector3d>>) {
    return "[x, y, z]" + rule + ", optional";
  } else if constexpr (std::is_same_v<Value, std::array<double, 2>>) {
    return "[a, b]" + rule;
  } else if constexpr (std::is_same_v<Value, std::optional<Eigen::Quaterniond>>) {
    return "[roll, pitch, yaw] (deg), optional";
  } else {
    static_assert(std::is_same_v<Value, core::ChoiceValue>);
    return core::ChoiceList(format);
  }
}

// The value as the scenario writer writes it ("unset" for an optional left out).
template <typename Options>
std::string DefaultText(const Options& options, const core::OptionField<Options>& field) {
  YAML::Emitter out;
  out << YAML::Flow << YAML::BeginMap;
  core::VisitFieldValue(options, field,
                        [&](const auto& value) { internal::EmitFieldValue(out, field.format, value); });
  out << YAML::EndMap;
  std::string text = out.c_str();  // "{key: value}" or "{}"
  const std::string prefix = "{" + std::string(field.format.key) + ": ";
  if (text.rfind(prefix, 0) != 0) return "unset";
  return text.substr(prefix.size(), text.size() - prefix.size() - 1);
}

template <typename Options>
std::string Form(const core::OptionField<Options>& field) {
  return std::visit(
      [&](auto member) {
        if constexpr (std::is_same_v<decltype(member), core::ChoiceMember<Options>>) {
          return FormOf<core::ChoiceValue>(field.format);
        } else {
          return FormOf<core::MemberValue<decltype(member)>>(field.format);
        }
      },
      field.member);
}

// One table of keys with one default column.
template <typename Options>
void AppendTable(std::string& page, std::span<const core::OptionField<Options>> fields,
                 const Options& defaults) {
  page += "| key | form | default | what |\n|---|---|---|---|\n";
  for (const core::OptionField<Options>& field : fields) {
    page += fmt::format("| `{}` | {} | `{}` | {} |\n", field.format.key, Cell(Form(field)),
                        Cell(DefaultText(defaults, field)), Cell(field.format.doc));
  }
  page += "\n";
}

// One table of keys with a default per profile.
template <typename Options, typename Select>
void AppendProfileTable(std::string& page, std::span<const core::OptionField<Options>> fields,
                        Select select) {
  page += "| key | form |";
  std::string rule = "|---|---|";
  for (const EstimationProfile profile : replay::kEstimationProfiles) {
    page += fmt::format(" {} |", replay::EstimationProfileName(profile));
    rule += "---|";
  }
  page += " what |\n" + rule + "---|\n";
  for (const core::OptionField<Options>& field : fields) {
    page += fmt::format("| `{}` | {} |", field.format.key, Cell(Form(field)));
    for (const EstimationProfile profile : replay::kEstimationProfiles) {
      page += fmt::format(" `{}` |",
                          Cell(DefaultText(select(EstimationConfig::Defaults(profile)), field)));
    }
    page += fmt::format(" {} |\n", Cell(field.format.doc));
  }
  page += "\n";
}

// "cm 0.1 m/s and nis 3 (paper), ...": each profile's threshold per metric.
std::string ThresholdsPerProfile() {
  std::vector<std::string> parts;
  for (const EstimationProfile profile : replay::kEstimationProfiles) {
    parts.push_back(fmt::format(
        "cm {} m/s and nis {} ({})",
        core::FormatDouble(EstimationConfig::DefaultThreshold(profile, estimator::ConsistencyMetric::kCm)),
        core::FormatDouble(EstimationConfig::DefaultThreshold(profile, estimator::ConsistencyMetric::kNis)),
        replay::EstimationProfileName(profile)));
  }
  return fmt::format("{}", fmt::join(parts, ", "));
}

}  // namespace

std::string ScenarioReferenceMarkdown() {
  std::string page =
      "# Scenario option keys\n\n"
      "Generated by `tofu reference` from the option tables (`static Fields()` beside each "
      "options struct, `core/option_fields.h`): the scenario reader, its writer, the "
      "validation and `tofu estimate --set` use the same tables. Do not edit: ctest "
      "`reference_doc` fails when this page differs from `tofu reference`. The rest of a "
      "scenario (trajectory, faults, mission, control, expectations, render) is described in "
      "the README's scenario section.\n\n"
      "## `estimation:`\n\n"
      "`profile` gives the default of every other key (default: `" +
      std::string(replay::EstimationProfileName(EstimationConfig::kDefaultProfile)) +
      "`); a scenario writes a key only where that option is what it is about. Besides these "
      "keys: `methods` (a list of method names, required) and `consensus` (the map below). "
      "A run directory's `scenario.yaml` writes every key, resolved.\n\n";
  AppendProfileTable<EstimationConfig>(page, EstimationConfig::Fields(),
                                       [](const EstimationConfig& c) -> const EstimationConfig& {
                                         return c;
                                       });
  page +=
      "## `estimation.consensus:`\n\n"
      "Besides these keys: `priority` (a list of the scenario's non-IMU sensors, most "
      "preferred first). A block that names a `metric` without a `threshold` gets its "
      "profile's threshold for that metric: " +
      ThresholdsPerProfile() + ".\n\n";
  AppendProfileTable<ConsensusConfig>(page, ConsensusConfig::Fields(),
                                      [](const EstimationConfig& c) -> const ConsensusConfig& {
                                        return c.consensus;
                                      });
  page +=
      "## `sensors.<name>:`\n\n"
      "Each sensor is a map with `type:` (one of the sections below) and its model's "
      "options; a sensor also takes `mount`, `rate_hz` where its model has one, "
      "`calibration_error` and `conditions` as the README describes.\n\n";
  page += "### `type: imu`\n\n";
  AppendTable(page, sim::ImuOptions::Fields(), sim::ImuOptions{});
  page += "### `type: vio`\n\n";
  AppendTable(page, sim::VioOptions::Fields(), sim::VioOptions{});
  page += "### `type: lidar_odometry`\n\n";
  AppendTable(page, sim::LidarOdometryOptions::Fields(), sim::LidarOdometryOptions{});
  page += "### `type: total_station`\n\n";
  AppendTable(page, sim::TotalStationOptions::Fields(), sim::TotalStationOptions{});
  page += "### `type: gnss`\n\n";
  AppendTable(page, sim::GnssOptions::Fields(), sim::GnssOptions{});
  page +=
      "Each fix type's error model is a map of its own under the GNSS sensor: `rtk_fixed:`, "
      "`rtk_float:` and `single:`, with these keys (defaults of `rtk_fixed`):\n\n";
  AppendTable(page, sim::GnssFixErrorOptions::Fields(), sim::GnssOptions{}.rtk_fixed);
  page += "## `controller:`\n\n";
  AppendTable(page, sim::ControllerOptions::Fields(), sim::ControllerOptions{});
  page += "## `wind:`\n\n";
  AppendTable(page, sim::WindOptions::Fields(), sim::WindOptions{});
  page +=
      "## The world and the robot\n\n"
      "`world` and `robot` stand at the top of a scenario, the physics rate under "
      "`physics: {rate_hz: ...}`; `distance_horizon_m` is no scenario key.\n\n";
  sim::WorldOptions world;
  world.world = "arena";
  AppendTable(page, sim::WorldOptions::Fields(), world);
  return page;
}

}  // namespace tofu::harness
