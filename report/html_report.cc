#include "report/html_report.h"

#include <unistd.h>

#include <functional>
#include <set>
#include <vector>

#include <fmt/format.h>

#include "core/error.h"
#include "replay/file_io.h"
#include "report/html_check_page.h"
#include "report/html_search_page.h"
#include "report/html_inputs.h"
#include "report/html_run_page.h"

namespace tofu::report {

namespace fs = std::filesystem;
using core::InputError;
using html::CheckScenario;
using html::CheckScenarioFolders;
using html::IsRunDirectory;
using html::kCheckForm;
using html::kRunForm;
using html::kSearchForm;
using html::PageContext;
using html::ReadCheckScenario;
using html::ReadRunInputs;
using html::RunInputs;
using html::WriteCheckPages;
using html::WriteRunPage;

namespace {

// Writes a report into a staging sibling of `out_dir` with `fill`, then swaps it in: old
// aside, new in, old gone. On any failure the staging directory is removed and an
// earlier report stays as it was.
void WriteReportDirectory(const fs::path& out_dir,
                          const std::function<void(const fs::path&)>& fill) {
  CheckReportOutputDirectory(out_dir);
  const fs::path out = fs::absolute(out_dir).lexically_normal();
  const fs::path target = out.filename().empty() ? out.parent_path() : out;
  const fs::path parent = target.parent_path();
  fs::create_directories(parent);
  const fs::path staging =
      parent / (target.filename().string() + fmt::format(".tmp-{}", ::getpid()));
  const fs::path old = parent / (target.filename().string() + fmt::format(".old-{}", ::getpid()));
  fs::remove_all(staging);
  try {
    fs::create_directories(staging);
    replay::WriteFileAtomically(staging / kReportMarkerFile,
                                 "a tofu report: `tofu report --out` replaces this directory\n");
    fill(staging);
    fs::remove_all(old);
    if (fs::exists(target)) fs::rename(target, old);
    fs::rename(staging, target);
    fs::remove_all(old);
  } catch (...) {
    std::error_code ignored;
    fs::remove_all(staging, ignored);
    throw;
  }
}

}  // namespace

ReportInputKind DetectReportInput(const fs::path& input) {
  std::error_code ec;
  if (!fs::exists(input, ec)) {
    throw InputError({input.string()}, "",
                     fmt::format("no such directory: expected {}, {} or {}", kRunForm, kCheckForm, kSearchForm));
  }
  if (!fs::is_directory(input, ec)) {
    throw InputError({input.string()}, "",
                     fmt::format("not a directory: expected {}, {} or {}", kRunForm, kCheckForm, kSearchForm));
  }
  if (IsRunDirectory(input)) return ReportInputKind::kRun;
  if (html::IsSearchDirectory(input)) return ReportInputKind::kSearch;
  if (!CheckScenarioFolders(input).empty()) return ReportInputKind::kCheck;
  throw InputError({input.string()}, "",
                   fmt::format("neither {}, {} nor {}", kRunForm, kCheckForm, kSearchForm));
}

void CheckReportOutputDirectory(const fs::path& out_dir) {
  if (out_dir.empty()) throw InputError({"--out"}, "", "expected a directory, got ''");
  std::error_code ec;
  const fs::file_status status = fs::status(out_dir, ec);
  if (ec || !fs::exists(status)) return;
  if (!fs::is_directory(status)) {
    throw InputError({out_dir.string()}, "--out",
                     "exists and is not a directory: expected a new or empty directory, or an "
                     "earlier tofu report");
  }
  if (fs::is_empty(out_dir, ec)) return;
  if (!fs::exists(out_dir / kReportMarkerFile)) {
    throw InputError({out_dir.string()}, "--out",
                     fmt::format("holds files that are not a tofu report (no {}): refusing to "
                                 "replace it; choose a new or empty directory",
                                 kReportMarkerFile));
  }
}

fs::path WriteRunReport(const fs::path& run_dir, const fs::path& out_dir) {
  CheckReportOutputDirectory(out_dir);
  // Everything is read (and every malformed file found) before anything is written.
  const RunInputs inputs = ReadRunInputs(run_dir);
  WriteReportDirectory(out_dir, [&](const fs::path& staging) {
    WriteRunPage(inputs, PageContext{staging, "", ""});
  });
  return fs::absolute(out_dir).lexically_normal() / "index.html";
}

fs::path WriteCheckReport(const fs::path& check_dir, const fs::path& out_dir,
                          const std::vector<std::string>& only_scenarios) {
  CheckReportOutputDirectory(out_dir);
  if (DetectReportInput(check_dir) != ReportInputKind::kCheck) {
    throw InputError({check_dir.string()}, "",
                     fmt::format("not a check directory: expected {}", kCheckForm));
  }
  std::vector<std::string> names = CheckScenarioFolders(check_dir);
  if (!only_scenarios.empty()) {
    const std::set<std::string> wanted(only_scenarios.begin(), only_scenarios.end());
    std::erase_if(names, [&](const std::string& n) { return !wanted.contains(n); });
  }
  std::vector<CheckScenario> scenarios;
  for (const std::string& name : names) scenarios.push_back(ReadCheckScenario(check_dir, name));
  WriteReportDirectory(out_dir, [&](const fs::path& staging) {
    for (CheckScenario& sc : scenarios) WriteCheckPages(sc, staging);
    replay::WriteFileAtomically(staging / "index.html", CheckPageHtml(check_dir, scenarios));
  });
  return fs::absolute(out_dir).lexically_normal() / "index.html";
}

fs::path WriteSearchReport(const fs::path& search_dir, const fs::path& out_dir) {
  CheckReportOutputDirectory(out_dir);
  if (DetectReportInput(search_dir) != ReportInputKind::kSearch) {
    throw InputError({search_dir.string()}, "", fmt::format("not a search directory: expected {}", kSearchForm));
  }
  WriteReportDirectory(out_dir, [&](const fs::path& staging) { html::WriteSearchPages(search_dir, staging); });
  return fs::absolute(out_dir).lexically_normal() / "index.html";
}

fs::path WriteReport(const fs::path& input, const fs::path& out_dir) {
  CheckReportOutputDirectory(out_dir);
  switch (DetectReportInput(input)) {
    case ReportInputKind::kRun:
      return WriteRunReport(input, out_dir);
    case ReportInputKind::kCheck:
      return WriteCheckReport(input, out_dir);
    case ReportInputKind::kSearch:
      return WriteSearchReport(input, out_dir);
  }
  throw std::logic_error("WriteReport: unknown input kind");
}

}  // namespace tofu::report
