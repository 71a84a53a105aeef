#pragma once
// `tofu report`: one self-contained HTML page per run directory and per check directory,
// for an engineer reading CI results in a browser with no network: the scenario, the
// expectations (pass green, fail red), the methods' scores, the run's figures and failure
// renders, and an interactive plot of every method's position error over time (a small
// inline script, no library). Images are inlined as data URIs; video clips (too large to
// inline) are copied into media/ beside the page. Nothing is fetched at view time.
//
// Layout of the output directory (always all of it or nothing: written to a temporary
// sibling and renamed into place):
//   run report:    <out>/index.html, <out>/media/*.mp4
//   check report:  <out>/index.html (the table over scenarios and seeds), and each run's
//                  page at <out>/<scenario>/seed_<s>/index.html (linked relatively both
//                  ways), with its media/ and the run's log (run.log) beside it.
// Run directories are only read, never written: they stay byte-identical (golden_runs).

#include <filesystem>
#include <string>
#include <string_view>
#include <vector>

#include <nlohmann/json_fwd.hpp>

namespace tofu::report {

/// The file every report directory holds: `--out` replaces only a directory that has it.
inline constexpr const char* kReportMarkerFile = ".tofu-report";

enum class ReportInputKind {
  kRun,    ///< what `tofu run SCENARIO --out DIR` writes (.tofu-run, summary.json)
  kCheck,  ///< what `tofu check --out DIR` writes (<scenario>/seed_<s>/ run directories)
  kSearch,  ///< what `tofu search --out DIR` writes (search.json)
};

/// Which kind of directory `input` is. Throws core::InputError naming the path and both
/// expected forms when it is neither (or does not exist).
ReportInputKind DetectReportInput(const std::filesystem::path& input);

/// Whether a report may be written to `out_dir`: missing, empty, or an earlier report
/// (holds kReportMarkerFile), which is replaced. Throws core::InputError (exit 2) for a
/// file or a directory of other files (never touched).
void CheckReportOutputDirectory(const std::filesystem::path& out_dir);

/// Writes the report of the run directory `run_dir` into `out_dir` (index.html). Throws
/// core::InputError for a directory that is not a run or a malformed required file
/// (scenario.yaml, summary.json, groundtruth.csv, calibration.yaml, or an optional file
/// that is there but malformed), naming file:line; nothing is written then.
/// Returns the page's path.
std::filesystem::path WriteRunReport(const std::filesystem::path& run_dir,
                                     const std::filesystem::path& out_dir);

/// Writes the report of a check directory: the overview page and one page per run
/// (layout above). A run that failed or whose files are unreadable is a red row with the
/// reason and its log, not an error of the report. `only_scenarios` (names) limits the
/// report to the scenarios of one check when the directory holds older ones too (`tofu
/// check --report`); empty: every scenario folder. Returns the overview page's path.
std::filesystem::path WriteCheckReport(const std::filesystem::path& check_dir,
                                       const std::filesystem::path& out_dir,
                                       const std::vector<std::string>& only_scenarios = {});

/// Writes the report of a search directory: the margins over the search, the ranked
/// failures, and each confirmed failure's flight page under failures/<id>/.
std::filesystem::path WriteSearchReport(const std::filesystem::path& search_dir,
                                        const std::filesystem::path& out_dir);

/// DetectReportInput, then WriteRunReport, WriteCheckReport or WriteSearchReport.
std::filesystem::path WriteReport(const std::filesystem::path& input,
                                  const std::filesystem::path& out_dir);

/// Text made safe for HTML element content and quoted attribute values: & < > " ' as
/// character references, C0 control characters other than tab and line breaks dropped.
std::string HtmlEscape(std::string_view text);

/// Standard base64 (RFC 4648, with padding), for data URIs.
std::string Base64(std::string_view bytes);

/// `value` as JSON text safe inside a <script> element: '<', '>' and '&' as \u escapes
/// (JSON.parse reads them back, "</script>" cannot end the element), invalid UTF-8
/// replaced by U+FFFD.
std::string ScriptSafeJson(const nlohmann::json& value);

}  // namespace tofu::report
