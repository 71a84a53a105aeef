#include "report/html_inputs.h"

#include <algorithm>
#include <system_error>

#include <fmt/format.h>

#include "core/error.h"
#include "core/file_io.h"
#include "harness/run_directory.h"
#include "replay/csv_reader.h"
#include "report/html_report.h"

namespace tofu::report::html {

namespace fs = std::filesystem;
using core::InputError;
using nlohmann::json;

ScenarioFile ReadScenarioFile(const fs::path& path) {
  ScenarioFile file;
  file.text = core::ReadWholeFile(path, "scenario.yaml of a tofu run directory");
  try {
    file.root = YAML::Load(file.text);
  } catch (const YAML::Exception& e) {
    throw InputError({path.string(), e.mark.line + 1, e.mark.column + 1}, "", e.msg);
  }
  if (!file.root.IsMap()) {
    throw InputError({path.string(), 1, 1}, "", "expected a mapping (the resolved scenario)");
  }
  return file;
}

std::string YamlScalar(const YAML::Node& map, const std::string& key) {
  if (!map.IsMap()) return {};
  const YAML::Node node = map[key];
  return node && node.IsScalar() ? node.as<std::string>() : std::string();
}

bool IsRunDirectory(const fs::path& dir) {
  std::error_code ec;
  if (!fs::is_directory(dir, ec)) return false;
  return fs::exists(dir / harness::kRunMarkerFile, ec) ||
         (fs::is_regular_file(dir / "scenario.yaml", ec) &&
          fs::is_regular_file(dir / "summary.json", ec));
}

namespace {

// "seed_<digits>" (or "seed_<digits>.log" when `log`): the seed, else nullopt.
std::optional<uint64_t> SeedOfName(std::string name, bool log) {
  if (log) {
    if (!name.ends_with(".log")) return std::nullopt;
    name.resize(name.size() - 4);
  }
  if (!name.starts_with("seed_") || name.size() == 5 || name.size() > 25) return std::nullopt;
  uint64_t seed = 0;
  for (size_t i = 5; i < name.size(); ++i) {
    if (name[i] < '0' || name[i] > '9') return std::nullopt;
    seed = seed * 10 + static_cast<uint64_t>(name[i] - '0');
  }
  return seed;
}

}  // namespace

// The seeds a scenario folder of a check holds (a run directory or a log of one).
std::set<uint64_t> SeedsIn(const fs::path& scenario_dir) {
  std::set<uint64_t> seeds;
  std::error_code ec;
  if (!fs::is_directory(scenario_dir, ec) || fs::exists(scenario_dir / kReportMarkerFile, ec)) {
    return seeds;
  }
  for (const auto& entry : fs::directory_iterator(scenario_dir, ec)) {
    const std::string name = entry.path().filename().string();
    if (const auto s = SeedOfName(name, false); s && IsRunDirectory(entry.path())) seeds.insert(*s);
    if (const auto s = SeedOfName(name, true); s && entry.is_regular_file()) seeds.insert(*s);
  }
  return seeds;
}

std::vector<std::string> CheckScenarioFolders(const fs::path& check_dir) {
  std::vector<std::string> names;
  std::error_code ec;
  for (const auto& entry : fs::directory_iterator(check_dir, ec)) {
    if (entry.is_directory() && !SeedsIn(entry.path()).empty()) {
      names.push_back(entry.path().filename().string());
    }
  }
  std::sort(names.begin(), names.end());
  return names;
}

std::string LogTailText(const fs::path& path, std::size_t max_lines) {
  std::string tail;
  for (const std::string& line : core::LogTail(path, max_lines)) tail += line + "\n";
  return tail;
}

namespace {

RunInputs::Series ReadColumn(const replay::CsvTable& csv, const char* column) {
  RunInputs::Series out;
  const int t = csv.Require("timestamp");
  const int c = csv.Require(column);
  for (size_t r = 0; r < csv.rows(); ++r) {
    const double v = csv.Double(r, c, true);
    out.t_s.push_back(static_cast<double>(csv.Int(r, t)) * 1e-9);
    out.value.push_back(v);
  }
  return out;
}

}  // namespace

RunInputs ReadRunInputs(const fs::path& dir) {
  if (!IsRunDirectory(dir)) {
    throw InputError({dir.string()}, "", fmt::format("not a run directory: expected {}", kRunForm));
  }
  RunInputs in;
  in.dir = dir;
  in.scenario = ReadScenarioFile(dir / "scenario.yaml");
  in.summary = renders::ReadRunJson(dir / "summary.json");
  if (!in.summary.is_object()) {
    throw InputError({(dir / "summary.json").string(), 1, 1}, "",
                     "expected a JSON object (the run's metrics and expectations)");
  }
  if (in.summary.contains("expectations") && !in.summary["expectations"].is_array()) {
    throw InputError({(dir / "summary.json").string()}, "expectations", "expected an array");
  }
  in.data = renders::ReadRunData(dir);
  if (fs::exists(dir / "tracking.csv")) {
    const replay::CsvTable csv(
        dir / "tracking.csv",
        "#timestamp [ns],p_ref_x [m],...,position_error [m],attitude_error [deg]");
    in.tracking = ReadColumn(csv, "position_error");
  }
  std::error_code ec;
  if (fs::is_directory(dir / "closed_loop", ec)) {
    for (const auto& entry : fs::directory_iterator(dir / "closed_loop")) {
      const fs::path control = entry.path() / "control.csv";
      if (!entry.is_directory() || !fs::exists(control)) continue;
      const replay::CsvTable csv(control,
                                  "#timestamp [ns],mode,...,tracking_error [m],"
                                  "estimate_error [m],structure_distance [m]");
      in.closed_loop[entry.path().filename().string()] = {ReadColumn(csv, "tracking_error"),
                                                          ReadColumn(csv, "structure_distance")};
    }
  }
  return in;
}

}  // namespace tofu::report::html
