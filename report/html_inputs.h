#pragma once
// Private to report/: what the pages are made from, read before anything is written: a
// run directory's files (RunInputs) and the folders of a check directory.

#include <cstddef>
#include <cstdint>
#include <filesystem>
#include <map>
#include <set>
#include <string>
#include <utility>
#include <vector>

#include <nlohmann/json.hpp>
#include <yaml-cpp/yaml.h>

#include "renders/run_data.h"

namespace tofu::report::html {

/// The two forms of input, for "expected ..." messages.
inline constexpr const char* kRunForm =
    "a tofu run directory (what `tofu run SCENARIO --out DIR` writes: .tofu-run, scenario.yaml, "
    "summary.json)";
inline constexpr const char* kCheckForm =
    "a check directory (what `tofu check --out DIR` writes: <scenario>/seed_<s>/ run "
    "directories)";
inline constexpr const char* kSearchForm = "a search directory (tofu search --out: search.json)";

// The scenario.yaml of a run: the resolved scenario, read tolerantly (the page shows what
// is there; harness validated it when the run was made).
struct ScenarioFile {
  std::string text;
  YAML::Node root;
};
/// Throws core::InputError (file:line:column) for YAML that does not parse or is no map.
ScenarioFile ReadScenarioFile(const std::filesystem::path& path);
/// The scalar `key` of a map as text; "" when it is missing or not a scalar.
std::string YamlScalar(const YAML::Node& map, const std::string& key);

/// A run directory: its marker file, or scenario.yaml and summary.json.
bool IsRunDirectory(const std::filesystem::path& dir);
/// The seeds a scenario folder of a check holds (a run directory or a log of one).
std::set<uint64_t> SeedsIn(const std::filesystem::path& scenario_dir);
/// The scenario folders of a check directory (those holding a seed), sorted.
std::vector<std::string> CheckScenarioFolders(const std::filesystem::path& check_dir);
/// The last lines of a log as it looks on a terminal (a progress bar redraws with '\r'),
/// a line each, each ended.
std::string LogTailText(const std::filesystem::path& path, std::size_t max_lines);

// Everything one run page shows, read before anything is written.
struct RunInputs {
  std::filesystem::path dir;
  ScenarioFile scenario;
  nlohmann::json summary;
  renders::RunData data;
  struct Series {
    std::vector<double> t_s, value;
  };
  Series tracking;  ///< tracking.csv position_error: the ground-truth flight
  /// closed_loop/<method>/control.csv per flight: tracking error, structure distance.
  std::map<std::string, std::pair<Series, Series>> closed_loop;
};
/// Reads every file a run page shows; throws core::InputError naming the file for a
/// directory that is not a run or a malformed file.
RunInputs ReadRunInputs(const std::filesystem::path& dir);

}  // namespace tofu::report::html
