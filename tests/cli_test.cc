// The `tofu` command line as a user meets it: run directories that are byte-identical
// across runs of the same seed, their files and formats, exit codes (0 pass, 1 failed
// expectation, 2 bad input or misuse), and bad input that leaves nothing behind.

#include <sys/wait.h>
#include <unistd.h>

#include <gtest/gtest.h>

#include <algorithm>
#include <cerrno>
#include <chrono>
#include <csignal>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <set>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include <nlohmann/json.hpp>

#include "harness/scenario.h"
#include "tests/test_support.h"

namespace tofu {
namespace {

namespace fs = std::filesystem;
using test::FilesIn;
using test::ReadFile;
using test::WriteFile;
using test::Quote;


std::string SourcePath(const std::string& relative) {
  return std::string(TOFU_SOURCE_DIR) + "/" + relative;
}

using Result = test::CommandResult;

// A fresh, empty directory per test under the test temp dir; removed at the end.
class CliTest : public ::testing::Test {
 protected:
  void SetUp() override {
    root_ = test::PerTestDirectory("tofu_cli_test_");
    work_ = root_ / "work";
    logs_ = root_ / "logs";
    fs::create_directories(work_);
    fs::create_directories(logs_);
  }
  void TearDown() override {
    if (!HasFailure()) fs::remove_all(root_);
  }

  // Runs `tofu <args>` with the working directory work_, capturing stdout and stderr.
  Result Tofu(const std::string& args) {
    const fs::path out = logs_ / "stdout.txt";
    const fs::path err = logs_ / "stderr.txt";
    const std::string command = "cd " + Quote(work_.string()) + " && " + Quote(TOFU_BINARY) +
                                " " + args + " >" + Quote(out.string()) + " 2>" +
                                Quote(err.string());
    const int status = std::system(command.c_str());
    Result r;
    EXPECT_TRUE(WIFEXITED(status)) << command;
    r.exit_code = WIFEXITED(status) ? WEXITSTATUS(status) : -1;
    r.out = ReadFile(out);
    r.err = ReadFile(err);
    return r;
  }

  // Names of the entries of the working directory (what a failed run left behind).
  std::set<std::string> WorkEntries() const {
    std::set<std::string> names;
    for (const auto& entry : fs::directory_iterator(work_)) {
      names.insert(entry.path().filename().string());
    }
    return names;
  }

  fs::path root_, work_, logs_;
};


// ---- determinism ----

TEST_F(CliTest, SameScenarioTwiceGivesByteIdenticalRunDirectories) {
  const std::string scenario = Quote(SourcePath("scenarios/hover_arena.yaml"));
  const Result a = Tofu("run " + scenario + " --out A --quiet");
  ASSERT_EQ(a.exit_code, 0) << a.out << a.err;
  const Result b = Tofu("run " + scenario + " --out B --quiet");
  ASSERT_EQ(b.exit_code, 0) << b.out << b.err;
  EXPECT_EQ(a.out, "");  // --quiet
  EXPECT_EQ(a.err, "");

  const std::set<std::string> files = FilesIn(work_ / "A");
  EXPECT_EQ(files, FilesIn(work_ / "B"));
  EXPECT_TRUE(files.count("timing.json"));
  for (const std::string& name : files) {
    if (name == "timing.json") continue;
    EXPECT_TRUE(ReadFile(work_ / "A" / name) == ReadFile(work_ / "B" / name))
        << name << " differs between two runs of the same scenario and seed";
  }
  // Only the two run directories: no staging or backup siblings remain.
  EXPECT_EQ(WorkEntries(), (std::set<std::string>{"A", "B"}));
}

TEST_F(CliTest, SeedOptionChangesTheGroundTruthOfAGustyScenario) {
  const std::string scenario = Quote(SourcePath("tests/data/scenarios/gusty_hover_short.yaml"));
  const Result a = Tofu("run " + scenario + " --out A --quiet");
  const Result b = Tofu("run " + scenario + " --out B --quiet --seed 1");
  const Result c = Tofu("run " + scenario + " --out C --quiet --seed 2");
  ASSERT_EQ(a.exit_code, 0) << a.err;
  ASSERT_EQ(b.exit_code, 0) << b.err;
  ASSERT_EQ(c.exit_code, 0) << c.err;
  const std::string truth_a = ReadFile(work_ / "A" / "groundtruth.csv");
  // The scenario's own seed is 1: --seed 1 changes nothing, --seed 2 changes the gusts.
  EXPECT_TRUE(truth_a == ReadFile(work_ / "B" / "groundtruth.csv"));
  EXPECT_FALSE(truth_a == ReadFile(work_ / "C" / "groundtruth.csv"));
  EXPECT_EQ(nlohmann::json::parse(ReadFile(work_ / "C" / "summary.json"))["seed"], 2);
  // The resolved scenario records the effective seed.
  EXPECT_EQ(harness::LoadScenario((work_ / "C" / "scenario.yaml").string()).seed, 2u);
}

// ---- the run directory ----

TEST_F(CliTest, RunDirectoryHasTheDocumentedFilesAndFormats) {
  const std::string input = SourcePath("scenarios/hover_arena.yaml");
  const Result r = Tofu("run " + Quote(input) + " --out run");
  ASSERT_EQ(r.exit_code, 0) << r.out << r.err;
  EXPECT_CONTAINS(r.out, "PASSED");
  const fs::path run = work_ / "run";
  for (const char* name : {"scenario.yaml", "groundtruth.csv", "groundtruth.tum", "tracking.csv",
                           "calibration.yaml", "summary.json", "timing.json"}) {
    EXPECT_TRUE(fs::is_regular_file(run / name)) << name;
    EXPECT_GT(fs::file_size(run / name), 0u) << name;
  }

  // groundtruth.csv: EuRoC-style header, then one row per sample at 200 Hz for 10 s.
  std::istringstream csv(ReadFile(run / "groundtruth.csv"));
  std::string header, row;
  std::getline(csv, header);
  EXPECT_EQ(header.rfind("#timestamp [ns],", 0), 0u) << header;
  EXPECT_CONTAINS(header, "p_WB_x [m]");
  EXPECT_CONTAINS(header, "q_WB_w []");
  size_t rows = 0;
  long long last_t = -1;
  while (std::getline(csv, row)) {
    ++rows;
    const long long t = std::stoll(row.substr(0, row.find(',')));
    EXPECT_GT(t, last_t);
    last_t = t;
    EXPECT_EQ(std::count(row.begin(), row.end(), ','),
              std::count(header.begin(), header.end(), ','));
  }
  EXPECT_NEAR(static_cast<double>(rows), 2000.0, 2.0);

  // groundtruth.tum: "t x y z qx qy qz qw", as many rows, no header.
  std::istringstream tum(ReadFile(run / "groundtruth.tum"));
  std::getline(tum, row);
  std::istringstream fields(row);
  std::vector<double> values{std::istream_iterator<double>(fields), std::istream_iterator<double>()};
  EXPECT_EQ(values.size(), 8u) << row;
  size_t tum_rows = 1;
  while (std::getline(tum, row)) ++tum_rows;
  EXPECT_EQ(tum_rows, rows);

  EXPECT_EQ(ReadFile(run / "tracking.csv").rfind("#timestamp [ns],", 0), 0u);
  const std::string calibration = ReadFile(run / "calibration.yaml");
  for (const char* site : {"imu", "vio_camera", "lidar", "prism", "gnss_antenna", "tool_tip"}) {
    EXPECT_CONTAINS(calibration, std::string("  ") + site + ":\n");
  }

  const nlohmann::json summary = nlohmann::json::parse(ReadFile(run / "summary.json"));
  for (const char* key : {"passed", "metrics", "expectations", "collisions"}) {
    EXPECT_TRUE(summary.contains(key)) << key;
  }
  EXPECT_EQ(summary["passed"], true);
  EXPECT_EQ(summary["scenario"], "hover_arena");
  EXPECT_TRUE(summary["collisions"].is_array());
  EXPECT_TRUE(summary["collisions"].empty());
  EXPECT_TRUE(summary["metrics"].contains("tracking.position_rmse_m"));
  ASSERT_EQ(summary["expectations"].size(), 3u);
  for (const auto& e : summary["expectations"]) {
    EXPECT_EQ(e["passed"], true) << e.dump();
    EXPECT_CONTAINS(e["where"].get<std::string>(), "hover_arena.yaml:");
  }
  const nlohmann::json timing = nlohmann::json::parse(ReadFile(run / "timing.json"));
  EXPECT_TRUE(timing.contains("wall_time_s"));
  // One entry per whole simulated minute (scripts/soak.py): none in a 10 s flight.
  ASSERT_TRUE(timing["minutes"].is_array());
  EXPECT_EQ(timing["minutes"].size(),
            static_cast<size_t>(timing["simulated_s"].get<double>() / 60.0));

  // The resolved scenario loads again, equals the input, and spells out the defaults.
  const std::string resolved = ReadFile(run / "scenario.yaml");
  EXPECT_EQ(ReadFile(input).find("controller:"), std::string::npos);
  EXPECT_CONTAINS(resolved, "controller:");
  EXPECT_CONTAINS(resolved, "physics:");
  const harness::Scenario original = harness::LoadScenario(input);
  const harness::Scenario reloaded = harness::LoadScenario((run / "scenario.yaml").string());
  EXPECT_EQ(reloaded.name, original.name);
  EXPECT_EQ(reloaded.world, original.world);
  EXPECT_EQ(reloaded.seed, original.seed);
  EXPECT_EQ(reloaded.duration_s, original.duration_s);
  EXPECT_EQ(reloaded.expect.size(), original.expect.size());
  EXPECT_EQ(reloaded.controller.rate_hz, original.controller.rate_hz);
  EXPECT_EQ(reloaded.controller.position_gain_per_s2, original.controller.position_gain_per_s2);
  EXPECT_EQ(reloaded.wind.gust_std_mps, original.wind.gust_std_mps);
  EXPECT_EQ(reloaded.trajectory.start.p_WB, original.trajectory.start.p_WB);
  EXPECT_EQ(reloaded.trajectory.segments.size(), original.trajectory.segments.size());
  EXPECT_EQ(reloaded.initial_offset.position_W_m, original.initial_offset.position_W_m);
  // Attitudes pass through degrees: equal to rounding (the text is not a bitwise fixed point).
  EXPECT_LT(reloaded.initial_offset.q_offset.angularDistance(original.initial_offset.q_offset),
            1e-12);
}

// One exit code for outputs the machine will not take (issue 19, finding 9: permission
// denied was 3, a full disk 2, `--out ""` 3): 4, naming the path; an empty --out is the
// user's input (2).
TEST_F(CliTest, OutputsThatCannotBeWrittenExitFourAndAnEmptyOutTwo) {
  WriteFile(work_ / "s.yaml", ReadFile(SourcePath("tests/data/scenarios/gusty_hover_short.yaml")));
  const Result proc = Tofu("run s.yaml --out /proc/tofu_cannot_write_here --quiet");
  EXPECT_EQ(proc.exit_code, 4) << proc.err;
  EXPECT_CONTAINS(proc.err, "/proc/tofu_cannot_write_here");
  const Result empty = Tofu("run s.yaml --out \"\" --quiet");
  EXPECT_EQ(empty.exit_code, 2) << empty.err;
  EXPECT_CONTAINS(empty.err, "--out");
}

// --out never destroys what is not a tofu run (issue 19, finding 1: a directory holding
// the user's notes and the scenario itself was emptied with exit 0), and replaces an
// earlier run only with --force, atomically.
TEST_F(CliTest, OutRefusesADirectoryOfOtherFilesAndReplacesAnEarlierRunOnlyWithForce) {
  const fs::path scenario_file = work_ / "notes" / "my.yaml";
  fs::create_directories(work_ / "notes");
  WriteFile(scenario_file, ReadFile(SourcePath("tests/data/scenarios/gusty_hover_short.yaml")));
  WriteFile(work_ / "notes" / "notes.txt", "my notes");
  const Result refused = Tofu("run notes/my.yaml --out notes --quiet --force");
  EXPECT_EQ(refused.exit_code, 2);
  EXPECT_CONTAINS(refused.err, "not a tofu run directory");
  EXPECT_EQ(ReadFile(work_ / "notes" / "notes.txt"), "my notes");
  EXPECT_TRUE(fs::exists(scenario_file));
  EXPECT_EQ(WorkEntries(), (std::set<std::string>{"notes"}));

  // A file where the directory should be.
  WriteFile(work_ / "afile", "x");
  EXPECT_EQ(Tofu("run notes/my.yaml --out afile --quiet").exit_code, 2);
  EXPECT_EQ(ReadFile(work_ / "afile"), "x");

  // An earlier run: refused without --force, replaced with it.
  ASSERT_EQ(Tofu("run notes/my.yaml --out run --quiet").exit_code, 0);
  EXPECT_TRUE(fs::exists(work_ / "run" / ".tofu-run"));
  WriteFile(work_ / "run" / "stale.txt", "from an older run");
  const Result again = Tofu("run notes/my.yaml --out run --quiet");
  EXPECT_EQ(again.exit_code, 2);
  EXPECT_CONTAINS(again.err, "--force replaces it");
  EXPECT_TRUE(fs::exists(work_ / "run" / "stale.txt"));
  const Result forced = Tofu("run notes/my.yaml --out run --quiet --force");
  ASSERT_EQ(forced.exit_code, 0) << forced.err;
  EXPECT_FALSE(fs::exists(work_ / "run" / "stale.txt"));
  EXPECT_TRUE(fs::exists(work_ / "run" / "summary.json"));
  EXPECT_EQ(WorkEntries(), (std::set<std::string>{"notes", "afile", "run"}));
  // An empty directory is fine.
  fs::create_directories(work_ / "empty");
  EXPECT_EQ(Tofu("run notes/my.yaml --out empty --quiet").exit_code, 0);
}

TEST_F(CliTest, DefaultRunDirectoryIsRunsSlashScenarioName) {
  const Result r =
      Tofu("run " + Quote(SourcePath("tests/data/scenarios/gusty_hover_short.yaml")) + " --quiet");
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_TRUE(fs::is_regular_file(work_ / "runs" / "gusty_hover_short" / "summary.json"));
}

// ---- failing runs ----

TEST_F(CliTest, CrashExitsOneAndTheSummaryListsTheCollision) {
  const Result r =
      Tofu("run " + Quote(SourcePath("tests/data/scenarios/crash_into_wall.yaml")) + " --out crash");
  EXPECT_EQ(r.exit_code, 1) << r.out << r.err;
  EXPECT_CONTAINS(r.out, "FAILED");
  EXPECT_CONTAINS(r.out, "hit wall_east");
  const nlohmann::json summary = nlohmann::json::parse(ReadFile(work_ / "crash" / "summary.json"));
  EXPECT_EQ(summary["passed"], false);
  ASSERT_TRUE(summary["collisions"].is_array());
  ASSERT_FALSE(summary["collisions"].empty());
  const nlohmann::json& first = summary["collisions"][0];
  EXPECT_EQ(first["robot_geom"], "tool");
  EXPECT_EQ(first["structure_geom"], "wall_east");
  EXPECT_GT(first["start_s"].get<double>(), 2.0);
  EXPECT_LT(first["start_s"].get<double>(), 8.0);
  EXPECT_GE(summary["metrics"]["collisions.count"].get<double>(), 1.0);
  ASSERT_EQ(summary["expectations"].size(), 1u);
  EXPECT_EQ(summary["expectations"][0]["passed"], false);
}

// ---- bad input ----

TEST_F(CliTest, UnknownKeyExitsTwoNamingFileLineAndKeyAndLeavesNothing) {
  const fs::path bad = root_ / "unknown_key.yaml";
  WriteFile(bad,
            "name: bad_key\n"
            "world: indoor_arena\n"
            "duration_s: 2\n"
            "trajectory:\n"
            "  start: {position_m: [0, 0, 1]}\n"
            "  segments:\n"
            "    - hover: {duration_s: 1}\n"
            "wobble_amplitude_m: 3\n");
  const Result r = Tofu("run " + Quote(bad.string()) + " --out run --quiet");
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_CONTAINS(r.err, bad.string() + ":8:");
  EXPECT_CONTAINS(r.err, "wobble_amplitude_m");
  EXPECT_EQ(r.out, "");
  // Neither the run directory, nor the default runs/, nor a staging sibling.
  EXPECT_TRUE(WorkEntries().empty());

  const Result v = Tofu("validate " + Quote(bad.string()));
  EXPECT_EQ(v.exit_code, 2);
  EXPECT_CONTAINS(v.err, bad.string() + ":8:");
  EXPECT_CONTAINS(v.err, "wobble_amplitude_m");
  // One bad file among good ones still fails the whole validation.
  const Result mixed = Tofu("validate " + Quote(SourcePath("scenarios/hover_arena.yaml")) + " " +
                            Quote(bad.string()));
  EXPECT_EQ(mixed.exit_code, 2);
  EXPECT_CONTAINS(mixed.out, "hover_arena.yaml: ok");
}

TEST_F(CliTest, ValidateAcceptsEveryShippedScenario) {
  std::string args = "validate";
  int count = 0;
  for (const auto& entry : fs::directory_iterator(SourcePath("scenarios"))) {
    if (entry.path().extension() != ".yaml") continue;
    args.append(" ").append(Quote(entry.path().string()));
    ++count;
  }
  ASSERT_GE(count, 6);
  const Result r = Tofu(args);
  EXPECT_EQ(r.exit_code, 0) << r.err;
  EXPECT_EQ(static_cast<int>(std::count(r.out.begin(), r.out.end(), '\n')), count) << r.out;
  EXPECT_TRUE(WorkEntries().empty());
}

TEST_F(CliTest, UnknownWorldExitsTwoListingTheWorldsAndLeavesNothing) {
  const fs::path bad = root_ / "nowhere.yaml";
  WriteFile(bad,
            "name: nowhere_hover\n"
            "world: nowhere\n"
            "duration_s: 2\n"
            "trajectory:\n"
            "  start: {position_m: [0, 0, 1]}\n"
            "  segments:\n"
            "    - hover: {duration_s: 1}\n");
  const Result r = Tofu("run " + Quote(bad.string()) + " --out run");
  EXPECT_EQ(r.exit_code, 2) << r.out << r.err;
  EXPECT_CONTAINS(r.err, "nowhere");
  for (const char* world : {"bridge", "building_window", "indoor_arena", "inspection_wall"}) {
    EXPECT_CONTAINS(r.err, world);
  }
  EXPECT_CONTAINS(r.err, bad.string());
  EXPECT_TRUE(WorkEntries().empty());
}

TEST_F(CliTest, MissingScenarioFileExitsTwo) {
  const Result r = Tofu("run does_not_exist.yaml --out run");
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_CONTAINS(r.err, "does_not_exist.yaml");
  EXPECT_TRUE(WorkEntries().empty());
}

TEST_F(CliTest, MisuseExitsTwo) {
  EXPECT_EQ(Tofu("").exit_code, 2);
  EXPECT_EQ(Tofu("run").exit_code, 2);
  EXPECT_EQ(Tofu("frobnicate").exit_code, 2);
  EXPECT_EQ(Tofu("validate").exit_code, 2);
  const std::string scenario = Quote(SourcePath("scenarios/hover_arena.yaml"));
  EXPECT_EQ(Tofu("run " + scenario + " --seed minus_one").exit_code, 2);
  EXPECT_EQ(Tofu("run " + scenario + " --frobnicate").exit_code, 2);
  EXPECT_TRUE(WorkEntries().empty());
  // Help is not misuse.
  const Result help = Tofu("--help");
  EXPECT_EQ(help.exit_code, 0);
  EXPECT_CONTAINS(help.out, "run");
}

// Every numeric option of `tofu estimate`, `tofu consistency` and the seeds and counts of
// `tofu run` and `tofu check` is checked against its range before anything runs (before
// these checks: exit 0 with a nonsense estimate, an internal error, minutes of work or
// bad_alloc, and --seed -1 silently became 2^64 - 1).
TEST_F(CliTest, OutOfRangeNumericOptionsExitTwoNamingTheOptionAndItsRange) {
  const struct {
    std::string args;
    std::string expected;
  } cases[] = {
      {"estimate log --window -1", "--window: expected a number in (0, 60] s, got -1"},
      {"estimate log --window nan", "--window: expected a number in (0, 60] s, got nan"},
      {"estimate log --set huber_delta=nan", "huber_delta': expected a number in [0, 100] (sigma)"},
      {"estimate log --set huber=3", "no estimation key 'huber'"},
      {"estimate log --imu-noise-scale -1", "--imu-noise-scale: expected a number in (0, 1000]"},
      {"estimate log --imu-noise-scale 0", "--imu-noise-scale: expected a number in (0, 1000]"},
      {"estimate log --keyframe-rate 0", "--keyframe-rate: expected a number in [0.1, 1000] Hz"},
      {"estimate log --set consensus.metric=nis --set consensus.threshold=0.1",
       "consensus.threshold: expected a number in [1, 100] for metric nis"},
      {"estimate log --between-position-std inf", "--between-position-std: expected a number"},
      {"consistency --metric cm --rate 1e6 a.csv b.csv", "--rate: expected a number in (0, 1000] Hz"},
      {"run s.yaml --seed -1", "--seed: expected a whole number in [0, 18446744073709551615], got -1"},
      {"check s.yaml --seeds -2", "--seeds: expected a whole number in [1, 100000]"},
      {"check s.yaml --jobs 1.5", "--jobs: expected a whole number in [0, 256]"},
  };
  for (const auto& c : cases) {
    const Result r = Tofu(c.args);
    EXPECT_EQ(r.exit_code, 2) << c.args;
    EXPECT_CONTAINS(r.err, c.expected);
    EXPECT_EQ(WorkEntries(), std::set<std::string>{}) << c.args << " left something behind";
  }
  // In range is accepted (the command then fails on its missing input, not on the option).
  const Result ok = Tofu("estimate log --window 0.5 --set huber_delta=0 --keyframe-rate 30");
  EXPECT_EQ(ok.exit_code, 2);
  EXPECT_EQ(ok.err.find("expected a number"), std::string::npos) << ok.err;
}

// A flag value inside its own range can still make the estimator's options invalid
// (--window 1e-12 s is 0 ns of fixed lag): that is bad input too, exit 2 naming the
// options and the limit, before anything is written (before: the estimator's
// std::invalid_argument, exit 3, after the output directory was made).
TEST_F(CliTest, EstimatorOptionsOutsideTheirLimitsExitTwoBeforeWriting) {
  // A short flight with an IMU and a total station gives the log to replay.
  const Result run =
      Tofu("run " + Quote(SourcePath("scenarios/estimator_arena.yaml")) + " --out run --quiet");
  ASSERT_EQ(run.exit_code, 0) << run.err;
  const Result r = Tofu("estimate run --window 1e-12 --out est --quiet");
  EXPECT_EQ(r.exit_code, 2) << r.err;
  EXPECT_CONTAINS(r.err, "tofu estimate (--window");
  EXPECT_CONTAINS(r.err, "the estimator's options are invalid: local.window_ns");
  EXPECT_EQ(WorkEntries(), std::set<std::string>{"run"});
}

// ---- everything `tofu validate` can know without simulating (issue 19, finding 8) ----

// Each passed validate before, and failed only in `tofu run` (the estimation without an
// IMU only after the whole flight, naming the temporary directory).
TEST_F(CliTest, ValidateRunsEveryCheckThatNeedsNoSimulation) {
  const std::string head =
      "duration_s: 2\n"
      "trajectory:\n"
      "  start: {position_m: [0, 0, 1.5]}\n"
      "  segments:\n"
      "    - hover: {duration_s: 2}\n";
  const struct {
    std::string file;
    std::string text;
    std::string where;  // file:line: of the key
    std::string key;
    std::string message;
  } cases[] = {
      {"no_world.yaml", "name: a\nworld: nowhere\n" + head, "no_world.yaml:2:", "key 'world'",
       "model file not found"},
      {"no_robot.yaml", "name: b\nworld: indoor_arena\nrobot: nobody\n" + head,
       "no_robot.yaml:3:", "key 'robot'", "model file not found"},
      {"no_imu.yaml",
       "name: c\nworld: indoor_arena\n" + head +
           "sensors:\n  vio: {}\n  lio: {type: lidar_odometry}\nestimation:\n  methods: [consensus]\n",
       "no_imu.yaml:11:", "key 'estimation'", "needs an IMU"},
      {"no_site.yaml", "name: d\nworld: indoor_arena\n" + head + "sensors:\n  vio: {site: nowhere}\n",
       "no_site.yaml:9:", "key 'sensors.vio'", "no site 'nowhere'"},
      {"no_camera.yaml", "name: e\nworld: indoor_arena\n" + head + "render: {camera: nocam}\n",
       "no_camera.yaml:8:", "key 'render.camera'", "unknown camera 'nocam'"},
  };
  for (const auto& c : cases) {
    WriteFile(root_ / c.file, c.text);
    const std::string path = (root_ / c.file).string();
    const Result v = Tofu("validate " + Quote(path));
    EXPECT_EQ(v.exit_code, 2) << c.file << ": " << v.out << v.err;
    EXPECT_CONTAINS(v.err, path + c.where.substr(c.file.size()));
    EXPECT_CONTAINS(v.err, c.key);
    EXPECT_CONTAINS(v.err, c.message);
    // `tofu run` refuses it the same way, before flying: nothing written, no temporary.
    const Result r = Tofu("run " + Quote(path) + " --out run --quiet");
    EXPECT_EQ(r.exit_code, 2) << c.file << ": " << r.err;
    EXPECT_CONTAINS(r.err, path + c.where.substr(c.file.size()));
    EXPECT_EQ(r.err.find(".tmp-"), std::string::npos) << r.err;
    EXPECT_TRUE(WorkEntries().empty()) << c.file;
  }
}

// ---- interruption (issue 19, finding 7) ----

// A 60 s hover with three sensors: ~4 s of flight, then ~0.7 s writing ~35 MB into the
// staging directory <out>.tmp-<pid> (on an idle machine), the window a signal is sent in.
std::string LongHover(double duration_s) {
  return "name: long_hover\n"
         "world: indoor_arena\n"
         "duration_s: " + std::to_string(duration_s) + "\n"
         "trajectory:\n"
         "  start: {position_m: [0, 0, 1.5]}\n"
         "  segments:\n"
         "    - hover: {duration_s: 1}\n"
         "sensors:\n"
         "  imu: {}\n"
         "  vio: {}\n"
         "  lio: {type: lidar_odometry}\n";
}

// SIGINT, SIGTERM and SIGHUP while a run flies, recording its streams into its staging
// directory (run_recorder.h): before, the process died and left the 35 MB staging
// directory; now it removes it, writes no run directory and exits 128 + signal.
TEST_F(CliTest, InterruptedRunRemovesItsStagingDirectoryAndExits128PlusTheSignal) {
  WriteFile(work_ / "long.yaml", LongHover(60));
  for (const int signal : {SIGINT, SIGTERM, SIGHUP}) {
    SCOPED_TRACE(strsignal(signal));
    fs::remove(logs_ / "run.log");
    test::ChildProcess run({TOFU_BINARY, "run", "long.yaml", "--out", "run", "--quiet"}, work_,
                           logs_ / "run.log");
    const fs::path staging = work_ / ("run.tmp-" + std::to_string(run.pid()));
    // Once it handles the signal (a slow start, e.g. under ASan, must not meet the default
    // action) and records: the IMU's rows go to their file while it flies.
    const fs::path recording = staging / "sensors" / ("imu.csv.tmp-" + std::to_string(run.pid()));
    ASSERT_TRUE(test::WaitUntil(
        [&] {
          return (test::CatchesSignal(run.pid(), signal) && fs::exists(recording)) ||
                 run.Exited();
        },
        std::chrono::minutes(5)));
    ASSERT_FALSE(run.Exited()) << "ended before it was seen recording: "
                               << ReadFile(logs_ / "run.log");
    ASSERT_FALSE(fs::exists(staging / "summary.json")) << "the flight was too short";
    ASSERT_EQ(::kill(run.pid(), signal), 0);
    const std::optional<int> status = run.Wait(std::chrono::minutes(2));
    ASSERT_TRUE(status.has_value()) << "still running 2 min after the signal";
    ASSERT_TRUE(WIFEXITED(*status)) << "ended by signal " << WTERMSIG(*status)
                                    << " instead of exiting after its cleanup";
    EXPECT_EQ(WEXITSTATUS(*status), 128 + signal);
    // Neither the staging directory nor anything that looks like a run.
    EXPECT_EQ(WorkEntries(), std::set<std::string>{"long.yaml"});
    EXPECT_CONTAINS(ReadFile(logs_ / "run.log"), "interrupted by");
  }
}

// The figure scripts start while the run is scored and wait to be told to draw
// (run_directory.cc, Figures). A run interrupted while one lives (importing matplotlib,
// waiting or drawing) ends it too: no script outlives the run, and no run directory.
TEST_F(CliTest, AnInterruptedRunLeavesNoFigureScriptBehind) {
  WriteFile(work_ / "est.yaml", LongHover(20) + "estimation:\n  methods: [consensus]\n");
  test::ChildProcess run({TOFU_BINARY, "run", "est.yaml", "--out", "run", "--quiet"}, work_,
                         logs_ / "run.log");
  std::vector<pid_t> scripts;
  ASSERT_TRUE(test::WaitUntil(
      [&] {
        scripts.clear();
        for (const pid_t child : test::ChildrenOf(run.pid())) {
          const std::string argv = ReadFile(fs::path("/proc") / std::to_string(child) / "cmdline");
          if (argv.find("--when-ready") != std::string::npos) scripts.push_back(child);
        }
        return !scripts.empty() || run.Exited();
      },
      std::chrono::minutes(5)));
  ASSERT_FALSE(run.Exited()) << "ended before a figure script was seen: "
                             << ReadFile(logs_ / "run.log");
  ASSERT_EQ(::kill(run.pid(), SIGTERM), 0);
  const std::optional<int> status = run.Wait(std::chrono::minutes(2));
  ASSERT_TRUE(status.has_value()) << "still running 2 min after the signal";
  ASSERT_TRUE(WIFEXITED(*status)) << "ended by signal " << WTERMSIG(*status);
  EXPECT_EQ(WEXITSTATUS(*status), 128 + SIGTERM) << ReadFile(logs_ / "run.log");
  for (const pid_t script : scripts) {
    EXPECT_FALSE(test::ProcessExists(script)) << "figure script " << script << " outlived the run";
  }
  EXPECT_EQ(WorkEntries(), std::set<std::string>{"est.yaml"});
}

// A staging directory that a killed run left (SIGKILL, a power cut) is removed by the next
// run to the same --out when its process is gone or its pid now belongs to another
// program; never while a tofu process that may still write it is alive.
TEST_F(CliTest, StaleStagingDirectoriesAreSweptByTheNextRunButNeverALiveOne) {
  WriteFile(work_ / "s.yaml", ReadFile(SourcePath("tests/data/scenarios/gusty_hover_short.yaml")));
  WriteFile(work_ / "endless.yaml", LongHover(3600));
  pid_t gone = 999999;
  while (test::ProcessExists(gone)) --gone;
  const std::string dead_staging = "run.tmp-" + std::to_string(gone);
  fs::create_directories(work_ / dead_staging / "sensors");
  WriteFile(work_ / dead_staging / "sensors" / "imu.csv", "half a file");
  // This test is alive but not tofu: a reused pid.
  const std::string reused_staging = "run.tmp-" + std::to_string(::getpid());
  fs::create_directories(work_ / reused_staging);
  // Another output's staging is not this run's to judge.
  const std::string other_output = "run2.tmp-" + std::to_string(gone);
  fs::create_directories(work_ / other_output);
  // A live tofu process (flying an hour-long scenario into another directory).
  test::ChildProcess live({TOFU_BINARY, "run", "endless.yaml", "--out", "elsewhere", "--quiet"},
                          work_, logs_ / "live.log");
  const std::string live_staging = "run.tmp-" + std::to_string(live.pid());
  fs::create_directories(work_ / live_staging);
  // Until the child has become tofu (between fork and exec it is a copy of this test).
  const fs::path live_comm = fs::path("/proc") / std::to_string(live.pid()) / "comm";
  ASSERT_TRUE(test::WaitUntil([&] { return ReadFile(live_comm) == "tofu\n"; },
                              std::chrono::seconds(30)));
  // ... and records into its own staging directory while it flies.
  const std::string live_recording = "elsewhere.tmp-" + std::to_string(live.pid());
  ASSERT_TRUE(test::WaitUntil([&] { return fs::exists(work_ / live_recording); },
                              std::chrono::seconds(60)));

  // (A trailing slash names the same directory: its staging siblings are the same.)
  const Result r = Tofu("run s.yaml --out run/ --quiet");
  ASSERT_EQ(r.exit_code, 0) << r.err;
  ASSERT_FALSE(live.Exited()) << ReadFile(logs_ / "live.log");
  EXPECT_CONTAINS(r.err, dead_staging);
  EXPECT_CONTAINS(r.err, reused_staging);
  EXPECT_EQ(r.err.find(live_staging), std::string::npos) << r.err;
  EXPECT_EQ(WorkEntries(), (std::set<std::string>{"s.yaml", "endless.yaml", "run", other_output,
                                                  live_staging, live_recording}));
  EXPECT_TRUE(fs::exists(work_ / "run" / ".tofu-run"));
  ::kill(live.pid(), SIGTERM);
  EXPECT_TRUE(live.Wait(std::chrono::minutes(2)).has_value());
  EXPECT_FALSE(fs::exists(work_ / live_recording)) << "an interrupted run removes its staging";
}

TEST_F(CliTest, MetricsListsTheCatalogue) {
  const Result r = Tofu("metrics");
  EXPECT_EQ(r.exit_code, 0);
  for (const char* name : {"tracking.position_rmse_m", "collisions.count",
                           "approach.max_standoff_error_m", "structure.min_distance_m"}) {
    EXPECT_CONTAINS(r.out, name);
  }
}

}  // namespace
}  // namespace tofu
