#pragma once
// Private to report/: the page of a check directory: one row per scenario over its seeds,
// the expectation matrix (expectations by seeds) and each run's page linked.

#include <filesystem>
#include <optional>
#include <string>
#include <vector>

#include "campaign/check_command.h"
#include "report/html_inputs.h"

namespace tofu::report::html {

struct CheckRun {
  campaign::SeedRun run;
  std::optional<ScenarioFile> scenario;  ///< its scenario.yaml (pass_fraction), when readable
  bool has_page = false;                 ///< its page was written
  std::string read_error;                ///< why the run has no page
  std::string log_tail;
};

struct CheckScenario {
  std::string name;
  std::vector<CheckRun> runs;
  campaign::ScenarioCheck check;
};

/// The runs of one scenario folder, their summaries read (a check may hold thousands of
/// runs: their pages are written one at a time, WriteCheckPages).
CheckScenario ReadCheckScenario(const std::filesystem::path& check_dir, const std::string& name);
/// Writes each run's page (and log) under <staging>/<scenario>/seed_<s>/, reading one run
/// at a time; a run whose files are malformed gets no page but a red row saying why. Then
/// aggregates the scenario as `tofu check` does.
void WriteCheckPages(CheckScenario& sc, const std::filesystem::path& staging);
/// The overview page of the check.
std::string CheckPageHtml(const std::filesystem::path& check_dir,
                          const std::vector<CheckScenario>& scenarios);

}  // namespace tofu::report::html
