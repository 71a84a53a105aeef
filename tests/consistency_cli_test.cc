// `tofu consistency` as a user meets it: two velocity CSVs in, one `t_ns,value` CSV out at
// the documented evaluation times; strict reading of the inputs (every kind of bad file
// is exit code 2 with file and line named, and no output file); and a run on a real log
// (EuRoC V1_02 ground truth: its velocity against its differentiated positions).

#include <sys/wait.h>
#include <unistd.h>

#include <gtest/gtest.h>
#include "tests/test_support.h"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <iterator>
#include <optional>
#include <set>
#include <sstream>
#include <string>
#include <vector>

namespace tofu {
namespace {

namespace fs = std::filesystem;
using test::ReadFile;
using test::WriteFile;
using test::Quote;


constexpr int64_t kSecond = 1'000'000'000;
constexpr double kPi = 3.14159265358979323846;
constexpr const char* kHeader = "#timestamp [ns],v_x [m/s],v_y [m/s],v_z [m/s]";

struct Velocity {
  double x = 0, y = 0, z = 0;
};

// The analytic motion both test sensors observe [m/s].
Velocity TrueVelocity(int64_t t_ns) {
  const double t = static_cast<double>(t_ns) * 1e-9;
  return {std::sin(2 * kPi * 0.5 * t), 0.8 * std::cos(2 * kPi * 0.5 * t),
          0.3 * std::sin(2 * kPi * 0.2 * t)};
}

struct Sample {
  int64_t t_ns = 0;
  Velocity v;
};

// `count` samples of TrueVelocity every `period_ns` from `start_ns`.
std::vector<Sample> Sampled(int64_t start_ns, int64_t period_ns, int count) {
  std::vector<Sample> samples;
  for (int i = 0; i < count; ++i) {
    const int64_t t = start_ns + i * period_ns;
    samples.push_back({t, TrueVelocity(t)});
  }
  return samples;
}

std::string VelocityCsv(const std::vector<Sample>& samples) {
  std::ostringstream csv;
  csv.precision(17);
  csv << kHeader << "\n";
  for (const Sample& s : samples)
    csv << s.t_ns << "," << s.v.x << "," << s.v.y << "," << s.v.z << "\n";
  return csv.str();
}

// One row of the command's output; value empty = unavailable.
struct Row {
  int64_t t_ns = 0;
  std::optional<double> value;
};

// Parses the output CSV, checking its header names the metric.
std::vector<Row> ParseOutput(const std::string& text, const std::string& metric) {
  std::istringstream in(text);
  std::string line;
  std::getline(in, line);
  EXPECT_EQ(line, "#timestamp [ns]," + metric);
  std::vector<Row> rows;
  while (std::getline(in, line)) {
    const size_t comma = line.find(',');
    EXPECT_NE(comma, std::string::npos) << line;
    if (comma == std::string::npos) continue;
    Row row;
    row.t_ns = std::stoll(line.substr(0, comma));
    const std::string value = line.substr(comma + 1);
    if (!value.empty()) row.value = std::stod(value);
    rows.push_back(row);
  }
  return rows;
}

double Median(std::vector<double> values) {
  std::sort(values.begin(), values.end());
  return values[values.size() / 2];
}

using Result = test::CommandResult;

// A fresh, empty working directory per test under the test temp dir; removed at the end.
class ConsistencyCliTest : public ::testing::Test {
 protected:
  void SetUp() override {
    root_ = test::PerTestDirectory("tofu_consistency_test_");
    work_ = root_ / "work";
    logs_ = root_ / "logs";
    fs::create_directories(work_);
    fs::create_directories(logs_);
  }
  void TearDown() override {
    if (!HasFailure()) fs::remove_all(root_);
  }

  // Runs `tofu <args>` in work_, capturing stdout and stderr.
  Result Tofu(const std::string& args) {
    const fs::path out = logs_ / "stdout.txt";
    const fs::path err = logs_ / "stderr.txt";
    const std::string command = "cd " + Quote(work_.string()) + " && " + Quote(TOFU_BINARY) + " " +
                                args + " >" + Quote(out.string()) + " 2>" + Quote(err.string());
    const int status = std::system(command.c_str());
    Result r;
    EXPECT_TRUE(WIFEXITED(status)) << command;
    r.exit_code = WIFEXITED(status) ? WEXITSTATUS(status) : -1;
    r.out = ReadFile(out);
    r.err = ReadFile(err);
    return r;
  }

  std::set<std::string> WorkEntries() const {
    std::set<std::string> names;
    for (const auto& entry : fs::directory_iterator(work_)) {
      names.insert(entry.path().filename().string());
    }
    return names;
  }

  // Writes a.csv (good, 200 Hz) and b.csv with `b_text`, runs cm with --out out.csv and
  // checks what every bad input must give: exit 2, one "tofu: error:" line naming
  // `where` (file:line), nothing on stdout, no output file and no temporary left behind.
  Result ExpectBadB(const std::string& b_text, const std::string& where) {
    WriteFile(work_ / "a.csv", VelocityCsv(Sampled(kSecond, 5'000'000, 2001)));
    WriteFile(work_ / "b.csv", b_text);
    const Result r = Tofu("consistency --metric cm a.csv b.csv --out out.csv");
    EXPECT_EQ(r.exit_code, 2) << r.out << r.err;
    EXPECT_EQ(r.err.rfind("tofu: error: " + where, 0), 0u) << r.err;
    EXPECT_EQ(std::count(r.err.begin(), r.err.end(), '\n'), 1) << r.err;
    EXPECT_EQ(r.out, "");
    EXPECT_EQ(WorkEntries(), (std::set<std::string>{"a.csv", "b.csv"}));
    return r;
  }

  fs::path root_, work_, logs_;
};

// Stream A: 200 Hz over [1 s, 11 s]. Stream B: 20 Hz from 1.012 s, 200 samples (last at
// 10.962 s), offset so that no B sample sits on a window boundary.
constexpr int64_t kStartA = kSecond;
constexpr int64_t kPeriodA = 5'000'000;
constexpr int kCountA = 2001;
constexpr int64_t kStartB = 1'012'000'000;
constexpr int64_t kPeriodB = 50'000'000;
constexpr int kCountB = 200;

// ---- good input ----

TEST_F(ConsistencyCliTest, IdenticalStreamsGiveZeroCramerVonMisesAtTheDocumentedTimes) {
  const std::string a = VelocityCsv(Sampled(kStartA, kPeriodA, kCountA));
  WriteFile(work_ / "a.csv", a);
  WriteFile(work_ / "a_copy.csv", a);
  const Result r = Tofu("consistency --metric cm a.csv a_copy.csv --out out.csv");
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_EQ(r.out, "");
  EXPECT_EQ(r.err, "");
  EXPECT_EQ(WorkEntries(), (std::set<std::string>{"a.csv", "a_copy.csv", "out.csv"}));

  // From 1 s + 1 s window to 11 s every 0.1 s: 2.0, 2.1, ..., 11.0 s.
  const std::vector<Row> rows = ParseOutput(ReadFile(work_ / "out.csv"), "cm");
  ASSERT_EQ(rows.size(), 91u);
  for (size_t k = 0; k < rows.size(); ++k) {
    EXPECT_EQ(rows[k].t_ns, 2 * kSecond + static_cast<int64_t>(k) * 100'000'000);
    ASSERT_TRUE(rows[k].value) << rows[k].t_ns;
    EXPECT_NEAR(*rows[k].value, 0.0, 1e-12) << rows[k].t_ns;
  }
}

TEST_F(ConsistencyCliTest, SameMotionAtTwoRatesIsConsistentUntilAnOffsetStarts) {
  // B observes the same motion at 20 Hz; from 6 s on its v_x reads 1 m/s too high.
  constexpr int64_t kOffsetStart = 6 * kSecond;
  constexpr double kOffset = 1.0;
  std::vector<Sample> b = Sampled(kStartB, kPeriodB, kCountB);
  for (Sample& s : b) {
    if (s.t_ns >= kOffsetStart) s.v.x += kOffset;
  }
  WriteFile(work_ / "a.csv", VelocityCsv(Sampled(kStartA, kPeriodA, kCountA)));
  WriteFile(work_ / "b.csv", VelocityCsv(b));
  const Result r = Tofu("consistency --metric cm a.csv b.csv --out out.csv");
  ASSERT_EQ(r.exit_code, 0) << r.err;

  // Times: max(1, 1.012) + 1 = 2.012 s, every 0.1 s, up to min(11, 10.962) s.
  const std::vector<Row> rows = ParseOutput(ReadFile(work_ / "out.csv"), "cm");
  ASSERT_EQ(rows.size(), 90u);
  EXPECT_EQ(rows.front().t_ns, 2'012'000'000);
  EXPECT_EQ(rows.back().t_ns, 10'912'000'000);
  double max_before = 0.0, min_after = 1e9;
  for (const Row& row : rows) {
    ASSERT_TRUE(row.value) << row.t_ns;
    if (row.t_ns < kOffsetStart) max_before = std::max(max_before, *row.value);
    if (row.t_ns - kSecond >= kOffsetStart) min_after = std::min(min_after, *row.value);
  }
  // Bounds from D = (2 ∫ (F_A − F_B)² dx)^½ per axis, summed. In a 1 s window every axis
  // has at most one extremum, so its sublevel sets are at most 2 intervals of time and an
  // evenly sampled empirical CDF is within 2/n of the continuous one: |F_A − F_B| ≤
  // 2/200 + 2/20 = 0.11 over the axis' range R (x ≤ 2, y ≤ 1.6, z ≤ 0.36 m/s), so
  // D ≤ 0.11 Σ √(2R) ≈ 0.51 before the offset.
  EXPECT_LT(max_before, 0.52);
  // After it, on x: |Δmean| = |∫ (F_A − F_B) dx| ≤ √(L ∫ (F_A − F_B)² dx) with support
  // L ≤ R + 1 = 3, and Δmean ≥ 1 − 0.11·2 (the sampling error above), so D ≥ √(2/3)·0.78.
  EXPECT_GT(min_after, 0.63);
}

TEST_F(ConsistencyCliTest, GapLongerThanTheWindowGivesEmptyValues) {
  // B loses its samples in (4.5 s, 7.0 s): 2.5 s, longer than the 1 s window.
  std::vector<Sample> b;
  for (const Sample& s : Sampled(kStartB, kPeriodB, kCountB)) {
    if (s.t_ns <= 4'500'000'000 || s.t_ns >= 7'000'000'000) b.push_back(s);
  }
  WriteFile(work_ / "a.csv", VelocityCsv(Sampled(kStartA, kPeriodA, kCountA)));
  WriteFile(work_ / "b.csv", VelocityCsv(b));
  const Result r = Tofu("consistency --metric cm a.csv b.csv --out out.csv");
  ASSERT_EQ(r.exit_code, 0) << r.err;
  const std::string text = ReadFile(work_ / "out.csv");
  const std::vector<Row> rows = ParseOutput(text, "cm");
  ASSERT_EQ(rows.size(), 90u);

  // Unavailable exactly where B has fewer than 3 samples in (t - 1 s, t]: its last sample
  // before the gap is at 4.462 s, its first after at 7.012 s, so for t = 5.412 .. 7.012 s.
  int empty = 0;
  for (const Row& row : rows) {
    const int in_window = static_cast<int>(std::count_if(b.begin(), b.end(), [&](const Sample& s) {
      return s.t_ns > row.t_ns - kSecond && s.t_ns <= row.t_ns;
    }));
    EXPECT_EQ(row.value.has_value(), in_window >= 3) << row.t_ns;
    if (!row.value) ++empty;
  }
  EXPECT_EQ(empty, 17);
  // An unavailable value is an empty field, not "nan" or "n/a".
  EXPECT_CONTAINS(text, "\n5412000000,\n");
  EXPECT_CONTAINS(text, "\n7012000000,\n");
}

TEST_F(ConsistencyCliTest, WindowAndRateOptionsSetTheEvaluationTimesAndStdoutIsTheDefault) {
  WriteFile(work_ / "a.csv", VelocityCsv(Sampled(kStartA, kPeriodA, kCountA)));
  WriteFile(work_ / "b.csv", VelocityCsv(Sampled(kStartB, kPeriodB, kCountB)));
  const Result r = Tofu("consistency --metric cm --window 0.5 --rate 4 a.csv b.csv");
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_EQ(r.err, "");
  EXPECT_EQ(WorkEntries(), (std::set<std::string>{"a.csv", "b.csv"}));

  // 1.012 s + 0.5 s, every 0.25 s, up to 10.962 s: 1.512 .. 10.762 s, 38 rows.
  const std::vector<Row> rows = ParseOutput(r.out, "cm");
  ASSERT_EQ(rows.size(), 38u);
  for (size_t k = 0; k < rows.size(); ++k) {
    EXPECT_EQ(rows[k].t_ns, 1'512'000'000 + static_cast<int64_t>(k) * 250'000'000);
    EXPECT_TRUE(rows[k].value) << rows[k].t_ns;
  }
}

TEST_F(ConsistencyCliTest, EveryMetricAndOptionRuns) {
  WriteFile(work_ / "a.csv", VelocityCsv(Sampled(kStartA, kPeriodA, kCountA)));
  WriteFile(work_ / "b.csv", VelocityCsv(Sampled(kStartB, kPeriodB, kCountB)));
  for (const std::string metric : {"mae", "pcc", "kl", "cm"}) {
    for (const std::string extra : {"", " --standardize", " --kl-bandwidth-scale 2"}) {
      SCOPED_TRACE(metric + extra);
      const Result r = Tofu("consistency a.csv b.csv --metric " + metric + extra);
      ASSERT_EQ(r.exit_code, 0) << r.err;
      const std::vector<Row> rows = ParseOutput(r.out, metric);
      ASSERT_EQ(rows.size(), 90u);
      for (const Row& row : rows) {
        ASSERT_TRUE(row.value) << row.t_ns;
        EXPECT_TRUE(std::isfinite(*row.value)) << row.t_ns;
      }
    }
  }
}

TEST_F(ConsistencyCliTest, AcceptsCrLfTheEurocTimestampHeaderAndTrailingBlankLines) {
  std::string b = VelocityCsv(Sampled(kStartB, kPeriodB, kCountB));
  b.replace(0, std::string(kHeader).size(), "#timestamp, v_x [m/s], v_y [m/s], v_z [m/s]");
  std::string crlf;
  for (const char c : b) crlf += c == '\n' ? std::string("\r\n") : std::string(1, c);
  WriteFile(work_ / "a.csv", VelocityCsv(Sampled(kStartA, kPeriodA, kCountA)) + "\n  \n");
  WriteFile(work_ / "b.csv", crlf + "\r\n");
  const Result r = Tofu("consistency --metric mae a.csv b.csv");
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_EQ(ParseOutput(r.out, "mae").size(), 90u);
}

// ---- bad input: exit 2, file and line named, no output file ----

TEST_F(ConsistencyCliTest, MissingFileIsBadInput) {
  WriteFile(work_ / "a.csv", VelocityCsv(Sampled(kStartA, kPeriodA, kCountA)));
  const Result r = Tofu("consistency --metric cm a.csv missing.csv --out out.csv");
  EXPECT_EQ(r.exit_code, 2) << r.err;
  EXPECT_EQ(r.err.rfind("tofu: error: missing.csv: ", 0), 0u) << r.err;
  EXPECT_CONTAINS(r.err, "No such file");
  EXPECT_EQ(WorkEntries(), (std::set<std::string>{"a.csv"}));
}

TEST_F(ConsistencyCliTest, BadHeaderIsBadInput) {
  const Result r = ExpectBadB("#t,vx,vy,vz\n1000000000,0,0,0\n", "b.csv:1:");
  EXPECT_CONTAINS(r.err, kHeader);
  EXPECT_CONTAINS(r.err, "'#t'");
}

TEST_F(ConsistencyCliTest, WrongFieldCountIsBadInput) {
  std::string b = VelocityCsv(Sampled(kStartB, kPeriodB, 5));  // lines 1..6
  b += "1300000000,0.1,0.2\n";                                 // line 7
  const Result r = ExpectBadB(b, "b.csv:7:");
  EXPECT_CONTAINS(r.err, "expected 4 comma-separated fields as in the header, got 3");
  EXPECT_CONTAINS(r.err, "column 4 'v_z [m/s]' and later are missing");
}

TEST_F(ConsistencyCliTest, UnparsableNumberIsBadInput) {
  const std::string b = std::string(kHeader) +
                        "\n1000000000,0,0,0\n1050000000,0,0,0\n1100000000,0,0,0\n"
                        "1150000000,0.1,0.2x,0.3\n";
  const Result r = ExpectBadB(b, "b.csv:5:16:");
  EXPECT_CONTAINS(r.err, "v_y [m/s]");
  EXPECT_CONTAINS(r.err, "'0.2x'");
}

TEST_F(ConsistencyCliTest, NonIntegerTimestampIsBadInput) {
  const std::string b = std::string(kHeader) + "\n1000000000,0,0,0\n1.05e9,0,0,0\n";
  const Result r = ExpectBadB(b, "b.csv:3:1:");
  EXPECT_CONTAINS(r.err, "integer timestamp in ns");
}

TEST_F(ConsistencyCliTest, NonMonotonicTimestampsAreBadInput) {
  const std::string b = std::string(kHeader) +
                        "\n1000000000,0,0,0\n1050000000,0,0,0\n1100000000,0,0,0\n"
                        "1150000000,0,0,0\n1120000000,0,0,0\n";
  const Result r = ExpectBadB(b, "b.csv:6:");
  EXPECT_CONTAINS(r.err, "1120000000");
  EXPECT_CONTAINS(r.err, "1150000000");
  EXPECT_CONTAINS(r.err, "line 5");
}

TEST_F(ConsistencyCliTest, RepeatedTimestampIsBadInput) {
  const std::string b =
      std::string(kHeader) + "\n1000000000,0,0,0\n1050000000,0,0,0\n1050000000,0,0,0\n";
  ExpectBadB(b, "b.csv:4:");
}

TEST_F(ConsistencyCliTest, NanIsBadInput) {
  const std::string b =
      std::string(kHeader) + "\n1000000000,0,0,0\n1050000000,0,0,0\n1100000000,nan,0,0\n";
  const Result r = ExpectBadB(b, "b.csv:4:12:");
  EXPECT_CONTAINS(r.err, "NaN");
}

TEST_F(ConsistencyCliTest, InfIsBadInput) {
  const std::string b = std::string(kHeader) + "\n1000000000,0,0,-inf\n";
  ExpectBadB(b, "b.csv:2:");
}

TEST_F(ConsistencyCliTest, EmptyFileIsBadInput) {
  const Result r = ExpectBadB("", "b.csv:1:");
  EXPECT_CONTAINS(r.err, "empty");
  EXPECT_CONTAINS(r.err, kHeader);
}

TEST_F(ConsistencyCliTest, HeaderOnlyFileIsBadInput) {
  const Result r = ExpectBadB(std::string(kHeader) + "\n", "b.csv:2:");
  EXPECT_CONTAINS(r.err, "no samples");
}

TEST_F(ConsistencyCliTest, BlankLineInsideTheDataIsBadInput) {
  const std::string b = std::string(kHeader) + "\n1000000000,0,0,0\n\n1100000000,0,0,0\n";
  ExpectBadB(b, "b.csv:3:");
}

TEST_F(ConsistencyCliTest, BadFirstFileIsNamed) {
  WriteFile(work_ / "a.csv", std::string(kHeader) + "\n1000000000,0,0\n");
  WriteFile(work_ / "b.csv", VelocityCsv(Sampled(kStartB, kPeriodB, kCountB)));
  const Result r = Tofu("consistency --metric cm a.csv b.csv --out out.csv");
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_EQ(r.err.rfind("tofu: error: a.csv:2:", 0), 0u) << r.err;
  EXPECT_FALSE(fs::exists(work_ / "out.csv"));
}

TEST_F(ConsistencyCliTest, StreamsThatDoNotOverlapByAWindowAreBadInput) {
  WriteFile(work_ / "a.csv", VelocityCsv(Sampled(kStartA, kPeriodA, 100)));  // 1 .. 1.495 s
  WriteFile(work_ / "b.csv", VelocityCsv(Sampled(20 * kSecond, kPeriodB, kCountB)));  // from 20 s
  const Result r = Tofu("consistency --metric cm a.csv b.csv --out out.csv");
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_EQ(r.err.rfind("tofu: error: a.csv: overlaps b.csv by less than one window", 0), 0u)
      << r.err;
  EXPECT_FALSE(fs::exists(work_ / "out.csv"));
}

TEST_F(ConsistencyCliTest, UnknownMetricIsBadInputAndListsTheMetrics) {
  WriteFile(work_ / "a.csv", VelocityCsv(Sampled(kStartA, kPeriodA, kCountA)));
  const Result r = Tofu("consistency --metric foo a.csv a.csv --out out.csv");
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_CONTAINS(r.err, "unknown metric 'foo'");
  EXPECT_CONTAINS(r.err, "mae, pcc, kl, cm");
  EXPECT_FALSE(fs::exists(work_ / "out.csv"));
}

TEST_F(ConsistencyCliTest, NonPositiveWindowRateOrBandwidthIsBadInput) {
  WriteFile(work_ / "a.csv", VelocityCsv(Sampled(kStartA, kPeriodA, kCountA)));
  for (const std::string bad :
       {"--window 0", "--window -1", "--rate 0", "--rate nan", "--kl-bandwidth-scale 0"}) {
    const Result r = Tofu("consistency --metric kl a.csv a.csv --out out.csv " + bad);
    EXPECT_EQ(r.exit_code, 2) << bad;
    EXPECT_CONTAINS(r.err, bad.substr(0, bad.find(' ')));
    EXPECT_FALSE(fs::exists(work_ / "out.csv")) << bad;
  }
}

// ---- a real log ----

// EuRoC V1_02 ground truth (200 Hz, Vicon): stream A is its velocity v_RS_R, stream B the
// central differences of its positions p_RS_R subsampled to 20 Hz. Both describe the same
// flight in the same frame, so the Cramér-von Mises distance stays small; a 0.3 m/s bias
// on B's v_x raises it at every evaluation time.
TEST_F(ConsistencyCliTest, EurocGroundTruthVelocityMatchesItsDifferentiatedPositions) {
  const fs::path source = fs::path(TOFU_SOURCE_DIR) /
                          "../shared/data/euroc_v1_02/mav0/state_groundtruth_estimate0/data.csv";
  if (!fs::exists(source)) {
    GTEST_SKIP() << "real data not found at " << source
                 << " (the EuRoC excerpt lives in ../shared/data beside the clone)";
  }
  std::ifstream in(source);
  std::string line;
  std::getline(in, line);  // header
  struct State {
    int64_t t_ns;
    double p[3], v[3];
  };
  std::vector<State> states;
  while (std::getline(in, line)) {
    if (line.empty() || line == "\r") continue;
    std::vector<std::string> fields;
    std::stringstream ss(line);
    for (std::string f; std::getline(ss, f, ',');) fields.push_back(f);
    ASSERT_GE(fields.size(), 11u) << line;
    // Columns: t, p_RS_R xyz (1-3), q_RS wxyz (4-7), v_RS_R xyz (8-10), biases.
    states.push_back({std::stoll(fields[0]),
                      {std::stod(fields[1]), std::stod(fields[2]), std::stod(fields[3])},
                      {std::stod(fields[8]), std::stod(fields[9]), std::stod(fields[10])}});
  }
  ASSERT_GT(states.size(), 10'000u);

  // A: the ground-truth velocity at 200 Hz.
  std::ostringstream a;
  a.precision(10);
  a << kHeader << "\n";
  for (const State& s : states)
    a << s.t_ns << "," << s.v[0] << "," << s.v[1] << "," << s.v[2] << "\n";
  // B: every 10th sample (20 Hz), velocity by central differences of those positions;
  // B_biased: the same with 0.3 m/s added to v_x (a biased velocity sensor).
  std::vector<const State*> sub;
  for (size_t i = 0; i < states.size(); i += 10) sub.push_back(&states[i]);
  std::ostringstream b, b_biased;
  for (std::ostringstream* out : {&b, &b_biased}) {
    out->precision(10);
    *out << kHeader << "\n";
  }
  for (size_t i = 1; i + 1 < sub.size(); ++i) {
    const double dt = static_cast<double>(sub[i + 1]->t_ns - sub[i - 1]->t_ns) * 1e-9;
    b << sub[i]->t_ns;
    b_biased << sub[i]->t_ns;
    for (int axis = 0; axis < 3; ++axis) {
      const double v = (sub[i + 1]->p[axis] - sub[i - 1]->p[axis]) / dt;
      b << "," << v;
      b_biased << "," << (axis == 0 ? v + 0.3 : v);
    }
    b << "\n";
    b_biased << "\n";
  }
  WriteFile(work_ / "a.csv", a.str());
  WriteFile(work_ / "b.csv", b.str());
  WriteFile(work_ / "b_biased.csv", b_biased.str());

  const Result r = Tofu("consistency --metric cm a.csv b.csv --out cm.csv");
  ASSERT_EQ(r.exit_code, 0) << r.err;
  const Result biased = Tofu("consistency --metric cm a.csv b_biased.csv --out cm_biased.csv");
  ASSERT_EQ(biased.exit_code, 0) << biased.err;
  const std::vector<Row> rows = ParseOutput(ReadFile(work_ / "cm.csv"), "cm");
  const std::vector<Row> biased_rows = ParseOutput(ReadFile(work_ / "cm_biased.csv"), "cm");
  // About 83 s of overlap less the first window, at 10 Hz.
  ASSERT_GT(rows.size(), 800u);
  ASSERT_EQ(biased_rows.size(), rows.size());
  std::vector<double> values, biased_values;
  for (size_t k = 0; k < rows.size(); ++k) {
    ASSERT_TRUE(rows[k].value) << "no gap in this log, yet unavailable at " << rows[k].t_ns;
    ASSERT_TRUE(biased_rows[k].value) << biased_rows[k].t_ns;
    values.push_back(*rows[k].value);
    biased_values.push_back(*biased_rows[k].value);
    // The bias shows at every evaluation time, not only on average.
    EXPECT_GT(*biased_rows[k].value, *rows[k].value) << rows[k].t_ns;
  }
  const double healthy = Median(values);
  EXPECT_LT(healthy, 0.1);
  EXPECT_GT(Median(biased_values), 3.0 * healthy);
  std::cout << "EuRoC V1_02, cm of v_RS_R against differentiated p_RS_R: median " << healthy
            << ", max " << *std::max_element(values.begin(), values.end())
            << "; with a 0.3 m/s bias on v_x: median " << Median(biased_values) << "\n";
}

}  // namespace
}  // namespace tofu
