// `tofu report` (report/html_report.h): the pure parts (escaping, base64, JSON inside a
// <script>) and the pages written from a real, short run directory: the expectation rows
// with their verdicts, the methods and the plot data, user text escaped, a malformed
// required or optional file rejected with file:line and nothing written, the output
// directory rules (never a directory of other files; an earlier report replaced), and a
// check directory's overview linking each run's page. The page in a browser (script
// errors, hover, screenshot): tests/report_check.sh with tests/node/check_report.mjs.

#include "report/html_report.h"

#include <filesystem>
#include <map>
#include <regex>
#include <string>

#include <fmt/format.h>
#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include "core/error.h"
#include "harness/run.h"
#include "harness/run_directory.h"
#include "harness/scenario.h"
#include "test_support.h"

namespace tofu {
namespace {

namespace fs = std::filesystem;
using test::ReadFile;
using test::WriteFile;

// 4 s with an IMU and a VIO that diverges from 2 s; consensus and the VIO alone run in the
// loop. One expectation holds, one fails (so both colours show), one names a window.
constexpr const char* kScenario = R"(
name: report_short
description: "A <short> run & its \"report\""
world: indoor_arena
duration_s: 4
seed: 5
trajectory:
  start: {position_m: [0, 0, 1.5]}
  segments:
    - hover: {duration_s: 1}
    - line: {to_m: [1.0, 0, 1.5]}
sensors:
  imu: {}
  vio: {}
faults:
  - {sensor: vio, kind: divergence, start_s: 2, axis: [1, 0, 0], initial_velocity_mps: 0.3, time_constant_s: 2}
estimation:
  methods: [consensus, "single:vio"]
expect:
  - {metric: collisions.count, max: 0}
  - {metric: tracking.position_rmse_m, max: 0.000001}
  - {metric: tracking.position_max_m, max: 0.5, window_s: [1, 3]}
)";

// One simulated run for the whole suite (a few seconds), copied by each test that edits it.
class ReportTest : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    root_ = fs::path(::testing::TempDir()) / fmt::format("report_test_{}", ::getpid());
    fs::remove_all(root_);
    fs::create_directories(root_);
    harness::RunRecord record =
        harness::Simulate(harness::ParseScenario(kScenario, "report_short.yaml"));
    ASSERT_FALSE(record.failure) << *record.failure;
    harness::RunOutputOptions output;
    output.plot = false;  // no python in a unit test; the figures are tested by the plot checks
    harness::WriteRun(record, (root_ / "run").string(), output);
  }
  static void TearDownTestSuite() {
    if (!::testing::UnitTest::GetInstance()->Failed()) fs::remove_all(root_);
  }
  static fs::path Run() { return root_ / "run"; }
  fs::path Dir(const std::string& name) const {
    const fs::path dir =
        root_ / (name + "_" + ::testing::UnitTest::GetInstance()->current_test_info()->name());
    fs::remove_all(dir);
    return dir;
  }
  fs::path CopyOfRun(const std::string& name) const {
    const fs::path dir = Dir(name);
    fs::copy(Run(), dir, fs::copy_options::recursive);
    return dir;
  }

  static inline fs::path root_;
};

// The error a call throws, as text ("" when it does not throw an InputError).
template <typename F>
std::string InputErrorOf(F&& f) {
  try {
    f();
  } catch (const core::InputError& e) {
    return e.what();
  }
  return "";
}

size_t Count(const std::string& text, const std::string& needle) {
  size_t n = 0;
  for (size_t p = text.find(needle); p != std::string::npos; p = text.find(needle, p + 1)) ++n;
  return n;
}

TEST(HtmlText, EscapesMarkupAndQuotesAndDropsControlCharacters) {
  EXPECT_EQ(report::HtmlEscape("a<b>&\"c\"'d'"), "a&lt;b&gt;&amp;&quot;c&quot;&#39;d&#39;");
  EXPECT_EQ(report::HtmlEscape("</script><img src=x onerror=alert(1)>"),
            "&lt;/script&gt;&lt;img src=x onerror=alert(1)&gt;");
  EXPECT_EQ(report::HtmlEscape(std::string("tab\tline\nnul\x01\x7f"
                                           "end")),
            "tab\tline\nnulend");
  EXPECT_EQ(report::HtmlEscape("Cramér-von Mises ±2 s"), "Cramér-von Mises ±2 s");  // UTF-8 kept
}

TEST(HtmlText, Base64MatchesRfc4648) {
  EXPECT_EQ(report::Base64(""), "");
  EXPECT_EQ(report::Base64("f"), "Zg==");
  EXPECT_EQ(report::Base64("fo"), "Zm8=");
  EXPECT_EQ(report::Base64("foo"), "Zm9v");
  EXPECT_EQ(report::Base64("foobar"), "Zm9vYmFy");
  EXPECT_EQ(report::Base64(std::string("\x89PNG\r\n\x1a\n", 8)), "iVBORw0KGgo=");
}

TEST(HtmlText, JsonInAScriptCannotCloseItAndReadsBack) {
  const nlohmann::json value = {{"name", "</script><b>&"}, {"t", {0.5, 1.25}}};
  const std::string text = report::ScriptSafeJson(value);
  EXPECT_EQ(text.find('<'), std::string::npos) << text;
  EXPECT_EQ(text.find('>'), std::string::npos) << text;
  EXPECT_EQ(text.find('&'), std::string::npos) << text;
  EXPECT_EQ(nlohmann::json::parse(text), value);
  // Invalid UTF-8 (a file's bytes) becomes U+FFFD instead of an exception.
  EXPECT_NO_THROW(report::ScriptSafeJson(nlohmann::json(std::string("bad \xff byte"))));
}

TEST_F(ReportTest, RunPageHasEveryExpectationRowWithItsVerdict) {
  const fs::path out = Dir("report");
  const fs::path page = report::WriteRunReport(Run(), out);
  EXPECT_EQ(page, fs::absolute(out) / "index.html");
  const std::string html = ReadFile(page);
  EXPECT_TRUE(html.starts_with("<!DOCTYPE html>"));
  EXPECT_CONTAINS(html, "<title>report_short — tofu run report</title>");
  // Three rows: two held, one failed; the run as a whole failed.
  const std::regex row(R"re(<tr class="(pass|fail)"><td><code>([^<]*)</code></td>)re");
  std::map<std::string, std::string> verdicts;
  const std::string expectations = html.substr(html.find("id=\"expectations\""));
  for (auto it = std::sregex_iterator(expectations.begin(), expectations.end(), row);
       it != std::sregex_iterator() && verdicts.size() < 3; ++it) {
    verdicts[(*it)[2]] = (*it)[1];
  }
  EXPECT_EQ(verdicts["collisions.count"], "pass");
  EXPECT_EQ(verdicts["tracking.position_rmse_m"], "fail");
  EXPECT_EQ(verdicts["tracking.position_max_m [1, 3] s"], "pass");
  EXPECT_CONTAINS(html, "2 of 3 expectations held.");
  EXPECT_CONTAINS(html, "<span class=\"badge fail\">FAILED</span>");
  EXPECT_CONTAINS(html, "report_short.yaml:");  // where each expectation was written
  // The methods and their plot data, fault window included.
  EXPECT_CONTAINS(html, "<td><code>consensus</code></td>");
  EXPECT_CONTAINS(html, "<td><code>single:vio</code></td>");
  EXPECT_CONTAINS(html, "id=\"plot-position-error\"");
  EXPECT_CONTAINS(html, "id=\"plot-tracking-error\"");
  EXPECT_CONTAINS(html, "\"label\":\"vio: divergence\"");
  EXPECT_CONTAINS(html, "<script>\n");  // the plot script, inline
  // Self-contained: nothing is loaded from elsewhere.
  EXPECT_EQ(html.find("http://"), std::string::npos);
  EXPECT_EQ(html.find("https://"), std::string::npos);
  EXPECT_EQ(html.find("<link"), std::string::npos);
  // The scenario's own text is escaped wherever it appears (description, YAML).
  EXPECT_CONTAINS(html, "A &lt;short&gt; run &amp; its &quot;report&quot;");
  EXPECT_EQ(html.find("<short>"), std::string::npos);
  EXPECT_TRUE(fs::exists(out / report::kReportMarkerFile));
}

TEST_F(ReportTest, RunDirectoryIsOnlyRead) {
  const auto before = test::FilesIn(Run());
  report::WriteRunReport(Run(), Dir("report"));
  EXPECT_EQ(test::FilesIn(Run()), before);
}

TEST_F(ReportTest, MalformedFilesAreInputErrorsNamingFileAndLineAndNothingIsWritten) {
  const fs::path out = Dir("report");
  {
    const fs::path run = CopyOfRun("bad_summary");
    WriteFile(run / "summary.json", "{\n  \"scenario\": \"report_short\",\n  \"passed\": tru\n}\n");
    const std::string error = InputErrorOf([&] { report::WriteRunReport(run, out); });
    EXPECT_CONTAINS(error, (run / "summary.json").string() + ":3:");
    EXPECT_CONTAINS(error, "malformed JSON");
    EXPECT_FALSE(fs::exists(out));
  }
  {
    const fs::path run = CopyOfRun("bad_errors");
    std::string errors = ReadFile(run / "errors.csv");
    const int lines = static_cast<int>(Count(errors, "\n"));
    WriteFile(run / "errors.csv", errors + "100000000,consensus,oops,1.0,1,\n");
    const std::string error = InputErrorOf([&] { report::WriteRunReport(run, out); });
    EXPECT_CONTAINS(error, fmt::format("errors.csv:{}:", lines + 1));
    EXPECT_CONTAINS(error, "position_error");
    EXPECT_FALSE(fs::exists(out));
  }
  {
    const fs::path run = CopyOfRun("bad_yaml");
    WriteFile(run / "scenario.yaml", "name: report_short\nworld: [indoor_arena\n");
    EXPECT_CONTAINS(InputErrorOf([&] { report::WriteRunReport(run, out); }), "scenario.yaml:");
    EXPECT_FALSE(fs::exists(out));
  }
  {
    const fs::path run = CopyOfRun("no_groundtruth");
    fs::remove(run / "groundtruth.csv");
    EXPECT_CONTAINS(InputErrorOf([&] { report::WriteRunReport(run, out); }), "groundtruth.csv");
    EXPECT_FALSE(fs::exists(out));
  }
}

TEST_F(ReportTest, InputMustBeARunOrACheckDirectory) {
  EXPECT_EQ(report::DetectReportInput(Run()), report::ReportInputKind::kRun);
  const fs::path empty = Dir("empty");
  fs::create_directories(empty);
  const std::string error = InputErrorOf([&] { report::DetectReportInput(empty); });
  EXPECT_CONTAINS(error, empty.string());
  EXPECT_CONTAINS(error, "tofu run SCENARIO --out DIR");
  EXPECT_CONTAINS(error, "tofu check --out DIR");
  EXPECT_CONTAINS(InputErrorOf([&] { report::DetectReportInput(root_ / "missing"); }),
                  "no such directory");
  EXPECT_CONTAINS(InputErrorOf([&] { report::WriteReport(empty, Dir("out")); }), "neither");
}

TEST_F(ReportTest, OutputIsNeverADirectoryOfOtherFilesButAnEarlierReportIsReplaced) {
  const fs::path other = Dir("other");
  fs::create_directories(other);
  WriteFile(other / "notes.txt", "mine");
  const std::string error = InputErrorOf([&] { report::WriteRunReport(Run(), other); });
  EXPECT_CONTAINS(error, "not a tofu report");
  EXPECT_EQ(test::FilesIn(other), std::set<std::string>{"notes.txt"});

  const fs::path file = Dir("file");
  WriteFile(file, "x");
  EXPECT_CONTAINS(InputErrorOf([&] { report::WriteRunReport(Run(), file); }), "not a directory");

  const fs::path out = Dir("report");
  report::WriteRunReport(Run(), out);
  WriteFile(out / "stale.html", "old");
  report::WriteRunReport(Run(), out);  // an earlier report: replaced whole
  EXPECT_FALSE(fs::exists(out / "stale.html"));
  EXPECT_TRUE(fs::exists(out / "index.html"));
  // No staging directory is left beside it.
  for (const auto& entry : fs::directory_iterator(out.parent_path())) {
    EXPECT_EQ(entry.path().filename().string().find(".tmp-"), std::string::npos) << entry.path();
  }
}

TEST_F(ReportTest, CheckPageTablesEverySeedAndLinksEachRunsPage) {
  // A check directory as `tofu check --out` leaves it: seeds 5 and 6, one of which failed an
  // expectation the other held, seed 7 that never produced a run directory, and seed 8.
  const fs::path check = Dir("check");
  fs::create_directories(check / "report_short");
  fs::copy(Run(), check / "report_short" / "seed_5", fs::copy_options::recursive);
  fs::copy(Run(), check / "report_short" / "seed_6", fs::copy_options::recursive);
  WriteFile(check / "report_short" / "seed_7.log", "tofu: error: something <odd>\n");
  // A run directory with a malformed file: a red row naming file:line, not a failed report.
  fs::copy(Run(), check / "report_short" / "seed_8", fs::copy_options::recursive);
  WriteFile(check / "report_short" / "seed_8" / "errors.csv",
            "#timestamp [ns],method,position_error [m],rotation_error [deg],valid,nees\n"
            "0,consensus,oops,1.0,1,\n");
  nlohmann::json summary =
      nlohmann::json::parse(ReadFile(check / "report_short" / "seed_6" / "summary.json"));
  summary["seed"] = 6;
  summary["expectations"][0]["passed"] = false;
  summary["expectations"][0]["value"] = 2;
  WriteFile(check / "report_short" / "seed_6" / "summary.json", summary.dump(2));
  EXPECT_EQ(report::DetectReportInput(check), report::ReportInputKind::kCheck);

  const fs::path out = Dir("report");
  const fs::path page = report::WriteCheckReport(check, out);
  const std::string html = ReadFile(page);
  EXPECT_CONTAINS(html, "<a href=\"report_short/seed_5/index.html\">seed 5</a>");
  EXPECT_CONTAINS(html, "<a href=\"report_short/seed_6/index.html\">seed 6</a>");
  EXPECT_TRUE(fs::exists(out / "report_short" / "seed_5" / "index.html"));
  EXPECT_TRUE(fs::exists(out / "report_short" / "seed_6" / "index.html"));
  EXPECT_FALSE(fs::exists(out / "report_short" / "seed_7" / "index.html"));
  EXPECT_TRUE(fs::exists(out / "report_short" / "seed_7" / "run.log"));
  // collisions.count held in seed 5, not in 6: failed over the seeds (pass_fraction 1).
  EXPECT_CONTAINS(html, "<td class=\"cell num pass\">0 ✔</td><td class=\"cell num fail\">2 ✘</td>");
  EXPECT_CONTAINS(html, "FAIL 2/4");  // seed 8's summary is readable and held
  EXPECT_CONTAINS(html, "unreadable run directory: " +
                            (check / "report_short" / "seed_8" / "errors.csv").string() + ":2:");
  EXPECT_FALSE(fs::exists(out / "report_short" / "seed_8" / "index.html"));
  EXPECT_CONTAINS(html, "no run directory");
  EXPECT_CONTAINS(html, "tofu: error: something &lt;odd&gt;");
  // Each run page links back to the overview.
  EXPECT_CONTAINS(ReadFile(out / "report_short" / "seed_5" / "index.html"),
                  "<a href=\"../../index.html\">");
  // Only the named scenarios when asked (tofu check --report).
  const std::string none = ReadFile(report::WriteCheckReport(check, out, {"another"}));
  EXPECT_EQ(none.find("report_short"), std::string::npos);
}

}  // namespace
}  // namespace tofu
