#include "campaign/cell_record.h"

#include <fstream>
#include <set>

#include <fmt/format.h>

#include "campaign/compared_metrics.h"
#include "core/error.h"
#include "core/file_io.h"
#include "core/version.h"
#include "replay/json_field.h"

namespace tofu::campaign {
namespace {

namespace fs = std::filesystem;
using core::InputError;
using nlohmann::json;

constexpr const char* kBaselineFormat = "tofu baseline";
constexpr int kBaselineVersion = 1;

std::optional<double> Number(const json& object, const std::string& key) {
  const auto it = object.find(key);
  if (it == object.end() || !it->is_number()) return std::nullopt;
  return it->get<double>();
}

bool IsString(const json& object, const std::string& key) {
  const auto it = object.find(key);
  return it != object.end() && it->is_string();
}

FlightDigests DigestsOf(const json& entry) {
  FlightDigests d;
  const auto it = entry.find("digests");
  if (it == entry.end() || !it->is_object()) return d;
  if (IsString(*it, "samples")) d.samples = (*it)["samples"].get<std::string>();
  if (IsString(*it, "random_streams")) d.random_streams = (*it)["random_streams"].get<std::string>();
  return d;
}

// A sensor that stayed out after its fault ended, within the flight (summary.json's
// `detections`: detected, ended before the run did, no re-admission).
bool NeverReadmitted(const json& method, double simulated_s) {
  const auto detections = method.find("detections");
  if (detections == method.end() || !detections->is_array()) return false;
  for (const json& d : *detections) {
    if (!d.is_object() || !d.value("detected", false)) continue;
    const std::optional<double> end_s = Number(d, "end_s");
    if (end_s && *end_s < simulated_s && !Number(d, "readmission_delay_s")) return true;
  }
  return false;
}

void ReadMethod(const std::string& name, const json& m, double simulated_s, CellRecord& cell) {
  const std::string prefix = "methods." + name + ".";
  for (const ComparedMetric& metric : ComparedMetrics()) {
    if (metric.scope != "methods" || metric.kind == EffectKind::kEvent) continue;
    if (const auto v = Number(m, metric.key)) cell.values[prefix + metric.key] = *v;
  }
  const auto faults = Number(m, "faults");
  const auto detected = Number(m, "faults_detected");
  cell.events[prefix + "failed"] = IsString(m, "failure");
  cell.events[prefix + "missed_fault"] = faults && detected && *detected < *faults;
  cell.events[prefix + "never_readmitted"] = NeverReadmitted(m, simulated_s);
}

void ReadFlight(const std::string& name, const json& f, CellRecord& cell) {
  const std::string prefix = "closed_loop." + name + ".";
  for (const ComparedMetric& metric : ComparedMetrics()) {
    if (metric.scope != "closed_loop" || metric.kind == EffectKind::kEvent) continue;
    if (const auto v = Number(f, metric.key)) cell.values[prefix + metric.key] = *v;
  }
  const bool failed = IsString(f, "failure");
  cell.events[prefix + "failed"] = failed;
  cell.events[prefix + "collided"] = Number(f, "collisions").value_or(0.0) > 0.0;
  cell.events[prefix + "diverged"] = f.value("diverged", false) == true;
  cell.events[prefix + "failsafe"] = Number(f, "failsafe_events").value_or(0.0) > 0.0;
  cell.flight_digests[name] = DigestsOf(f);
}

template <typename T>
T Field(const json& object, const char* key, const fs::path& file, const char* expected) {
  return replay::JsonField<T>(object, key, file, expected);
}

}  // namespace

json ReadJsonRecord(const fs::path& file) {
  std::ifstream in(file);
  if (!in) throw InputError({file.string()}, "", "cannot be read");
  try {
    return json::parse(in);
  } catch (const json::exception& e) {
    throw InputError({file.string()}, "", fmt::format("is not JSON: {}", e.what()));
  }
}

std::map<std::string, int> CurrentMetricVersions() {
  std::map<std::string, int> versions;
  for (const ComparedMetric& m : ComparedMetrics()) versions[m.Pattern()] = m.version;
  return versions;
}

CellRecord CellFromSummary(const std::string& scenario, uint64_t seed,
                           const std::string& scenario_hash, int exit_code,
                           const std::string& error, const json& summary) {
  CellRecord cell;
  cell.scenario = scenario;
  cell.seed = seed;
  cell.scenario_hash = scenario_hash;
  cell.exit_code = exit_code;
  cell.error = error;
  const bool usable = summary.is_object() && error.empty() &&
                      (exit_code == core::kExitOk || exit_code == core::kExitExpectationFailed ||
                       exit_code == core::kExitClientFailed);
  cell.events["run.failed"] = !usable;
  if (!usable) {
    if (cell.error.empty()) cell.error = fmt::format("exit {} without a usable summary", exit_code);
    return cell;
  }
  cell.digests = DigestsOf(summary);
  const double simulated_s = Number(summary, "simulated_s").value_or(0.0);
  if (const auto methods = summary.find("methods"); methods != summary.end() && methods->is_object()) {
    for (const auto& [name, m] : methods->items()) {
      if (m.is_object()) ReadMethod(name, m, simulated_s, cell);
    }
  }
  if (const auto flights = summary.find("closed_loop"); flights != summary.end() && flights->is_object()) {
    for (const auto& [name, f] : flights->items()) {
      if (f.is_object()) ReadFlight(name, f, cell);
    }
  }
  if (const auto expectations = summary.find("expectations");
      expectations != summary.end() && expectations->is_array()) {
    // Labelled as `tofu check` labels them: metric (/ relative_to) and where it is written,
    // so two expectations on one metric stay apart.
    for (const json& e : *expectations) {
      if (!e.is_object() || !IsString(e, "metric")) continue;
      std::string label = e["metric"].get<std::string>();
      if (IsString(e, "relative_to")) label += " / " + e["relative_to"].get<std::string>();
      if (IsString(e, "where")) label += " @" + e["where"].get<std::string>();
      cell.events["run.expectation." + label] = !e.value("passed", false);
    }
  }
  return cell;
}

CampaignRecord ReadCheckDirectory(const fs::path& dir) {
  const fs::path file = dir / kCheckRecordFile;
  if (!fs::exists(file)) {
    throw InputError({dir.string()}, "",
                     fmt::format("is not a check directory: it has no {} (what `tofu check "
                                 "--out DIR` writes when its runs are done)",
                                 kCheckRecordFile));
  }
  const json record = ReadJsonRecord(file);
  if (!record.is_object() || record.value("format", "") != kCheckRecordFormat) {
    throw InputError({file.string()}, "format", fmt::format("expected \"{}\"", kCheckRecordFormat));
  }
  CampaignRecord campaign;
  campaign.source = dir;
  campaign.tofu_version = Field<std::string>(record, "tofu_version", file, "a version");
  campaign.tofu_commit = Field<std::string>(record, "tofu_commit", file, "a commit");
  campaign.metric_versions = CurrentMetricVersions();
  std::map<std::string, std::string> hash_of;
  for (const json& s : Field<json>(record, "scenarios", file, "an array of scenarios")) {
    const auto name = Field<std::string>(s, "name", file, "a scenario name");
    hash_of[name] = Field<std::string>(s, "fnv1a64", file, "a hex hash");
    if (s.contains("minimal_effects")) {
      campaign.minimal_effects[name] = Field<std::map<std::string, double>>(
          s, "minimal_effects", file, "an object of numbers");
    }
  }
  for (const json& r : Field<json>(record, "runs", file, "an array of runs")) {
    const auto scenario = Field<std::string>(r, "scenario", file, "a scenario name");
    const auto seed = Field<uint64_t>(r, "seed", file, "a whole number");
    const auto exit_code = Field<int>(r, "exit_code", file, "an exit code");
    const auto error = Field<std::string>(r, "error", file, "a string");
    json summary = nullptr;
    const fs::path summary_file = dir / scenario / fmt::format("seed_{}", seed) / "summary.json";
    if (fs::exists(summary_file)) summary = ReadJsonRecord(summary_file);
    campaign.cells.push_back(
        CellFromSummary(scenario, seed, hash_of[scenario], exit_code, error, summary));
  }
  return campaign;
}

std::string BaselineJson(const CampaignRecord& campaign) {
  json cells = json::array();
  for (const CellRecord& c : campaign.cells) {
    json flights = json::object();
    for (const auto& [method, d] : c.flight_digests) {
      flights[method] = {{"samples", d.samples}, {"random_streams", d.random_streams}};
    }
    cells.push_back({{"scenario", c.scenario},
                     {"seed", c.seed},
                     {"scenario_hash", c.scenario_hash},
                     {"exit_code", c.exit_code},
                     {"error", c.error},
                     {"digests", {{"samples", c.digests.samples}, {"random_streams", c.digests.random_streams}}},
                     {"flight_digests", flights},
                     {"values", c.values},
                     {"events", c.events}});
  }
  json baseline = {{"format", kBaselineFormat},
                   {"version", kBaselineVersion},
                   {"tofu_version", campaign.tofu_version},
                   {"tofu_commit", campaign.tofu_commit},
                   {"metric_versions", campaign.metric_versions},
                   {"cells", cells}};
  if (!campaign.minimal_effects.empty()) baseline["minimal_effects"] = campaign.minimal_effects;
  return baseline.dump(1) + "\n";
}

CampaignRecord ReadBaselineFile(const fs::path& file) {
  const json b = ReadJsonRecord(file);
  if (!b.is_object() || b.value("format", "") != kBaselineFormat) {
    throw InputError({file.string()}, "format", fmt::format("expected \"{}\"", kBaselineFormat));
  }
  if (Field<int>(b, "version", file, "a whole number") != kBaselineVersion) {
    throw InputError({file.string()}, "version",
                     fmt::format("expected {} (a baseline file of another format)", kBaselineVersion));
  }
  CampaignRecord campaign;
  campaign.source = file;
  campaign.tofu_version = Field<std::string>(b, "tofu_version", file, "a version");
  campaign.tofu_commit = Field<std::string>(b, "tofu_commit", file, "a commit");
  campaign.metric_versions =
      Field<std::map<std::string, int>>(b, "metric_versions", file, "an object of versions");
  if (b.contains("minimal_effects")) {
    campaign.minimal_effects = Field<std::map<std::string, std::map<std::string, double>>>(
        b, "minimal_effects", file, "an object of scenarios' minimal effects");
  }
  for (const json& c : Field<json>(b, "cells", file, "an array of cells")) {
    CellRecord cell;
    cell.scenario = Field<std::string>(c, "scenario", file, "a scenario name");
    cell.seed = Field<uint64_t>(c, "seed", file, "a whole number");
    cell.scenario_hash = Field<std::string>(c, "scenario_hash", file, "a hex hash");
    cell.exit_code = Field<int>(c, "exit_code", file, "an exit code");
    cell.error = Field<std::string>(c, "error", file, "a string");
    cell.digests = DigestsOf(c);
    for (const auto& [method, d] : Field<json>(c, "flight_digests", file, "an object").items()) {
      cell.flight_digests[method] = DigestsOf(json{{"digests", d}});
    }
    cell.values = Field<std::map<std::string, double>>(c, "values", file, "an object of numbers");
    cell.events = Field<std::map<std::string, bool>>(c, "events", file, "an object of booleans");
    campaign.cells.push_back(std::move(cell));
  }
  return campaign;
}

CampaignRecord ReadCampaign(const fs::path& path) {
  if (fs::is_directory(path)) return ReadCheckDirectory(path);
  if (!fs::exists(path)) {
    throw InputError({path.string()}, "", "does not exist (expected a check directory or a baseline file)");
  }
  return ReadBaselineFile(path);
}

}  // namespace tofu::campaign
