// Users' estimators in a run (docs/INTERFACE.md), through the tofu binary:
//  - lossless: tofu's own consensus hosted behind the process protocol (tofu-estimator-host,
//    JSON lines and MessagePack) and behind the plug-in API (libtofu_builtin_plugin.so)
//    gives byte-identical estimate files to the in-process method, open loop and as the
//    estimator a closed-loop flight flies on (then the whole flight is identical too);
//  - `tofu estimate` replays a run with a client method as the loop ran it;
//  - a bad client (cannot start, exits early, hangs, malformed, NaN, time backwards, wrong
//    seq, another version, its own error) fails its method with the method, message and
//    field named and its last stderr lines in the run log, every other method is still
//    scored, the run exits 5 (a client failed; 3 is the simulation's own failure) and no
//    client process is left, also on SIGTERM, nor any process a client started when tofu
//    is killed with SIGKILL;
//  - a failed client is scored as a failure: its figures in summary.json are null (what it
//    measured up to the failure kept apart under `partial`), an expectation on it fails as
//    not measurable, the summary's top-level `failure` names it, and `tofu check` marks that
//    method alone (its table row, a JUnit test case) and exits 5.

#include <signal.h>
#include <sys/wait.h>

#include <algorithm>
#include <cerrno>
#include <cstdlib>
#include <filesystem>
#include <optional>
#include <thread>
#include <set>
#include <string>
#include <vector>

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include "tests/test_support.h"

namespace tofu {
namespace {

namespace fs = std::filesystem;

fs::path BuildDir() { return fs::path(TOFU_BINARY).parent_path(); }

// A short flight near the arena's east wall with the seed paper's sensors, the VIO
// diverging from 6 s. `clients` and `methods` are filled in per test.
std::string Scenario(const std::string& clients, const std::string& methods,
                     const std::string& control = "") {
  return R"(
name: client_short
world: indoor_arena
duration_s: 10
seed: 3
trajectory:
  start: {position_m: [2.0, -2.0, 1.5]}
  limits: {max_speed_mps: 0.6, max_acceleration_mps2: 0.6}
  segments:
    - hover: {duration_s: 1}
    - line: {to_m: [4.5, -2.0, 1.5]}
    - line: {to_m: [4.5, 1.0, 1.5]}
sensors:
  imu: {}
  vio: {}
  lio: {type: lidar_odometry}
  leica: {type: total_station}
faults:
  - {sensor: vio, kind: divergence, start_s: 6, end_s: 10, axis: [1, 0, 0], initial_velocity_mps: 0.3, time_constant_s: 8}
)" + clients + R"(
estimation:
  methods: )" + methods + R"(
  consensus: {threshold: 0.3, priority: [leica, lio, vio]}
  huber_delta: 3
)" + control;
}

std::string HostClients() {
  const std::string host = (BuildDir() / "tofu-estimator-host").string();
  const std::string plugin = (BuildDir() / "libtofu_builtin_plugin.so").string();
  return "external:\n"
         "  host: {command: [\"" + host + "\"], config: {method: consensus}}\n"
         "  host_mp: {command: [\"" + host + "\", --encoding, msgpack], config: {method: consensus}}\n"
         "plugins:\n"
         "  builtin: {library: \"" + plugin + "\", config: {method: consensus}}\n";
}

using Result = test::CommandResult;
using test::RunTofu;

void ExpectSameFile(const fs::path& a, const fs::path& b) {
  ASSERT_TRUE(fs::exists(a)) << a;
  ASSERT_TRUE(fs::exists(b)) << b;
  EXPECT_TRUE(test::ReadFile(a) == test::ReadFile(b)) << a << " and " << b << " differ";
}

TEST(ClientMethods, BuiltinConsensusThroughTheProtocolAndThePluginIsLossless) {
  const fs::path work = test::PerTestDirectory("client_lossless_");
  fs::create_directories(work);
  test::WriteFile(work / "s.yaml",
                  Scenario(HostClients(),
                           R"([consensus, "external:host", "external:host_mp", "plugin:builtin"])",
                           "control:\n  state_source: estimate\n  methods: [consensus, \"external:host\", "
                           "\"plugin:builtin\"]\n"));
  const Result run = RunTofu("run s.yaml --out R --quiet", work);
  ASSERT_EQ(run.exit_code, 0) << run.err;
  const fs::path r = work / "R";
  for (const std::string stem : {"external_host", "external_host_mp", "plugin_builtin"}) {
    for (const std::string ext : {".csv", ".tum", "_errors.csv"}) {
      ExpectSameFile(r / ("estimate_consensus" + ext), r / ("estimate_" + stem + ext));
    }
  }
  // Flying on the hosted estimator is the same flight as flying on the in-process one.
  for (const std::string stem : {"external_host", "plugin_builtin"}) {
    const fs::path flown = r / "closed_loop" / stem;
    ExpectSameFile(r / "closed_loop" / "consensus" / "estimate_consensus.csv",
                   flown / ("estimate_" + stem + ".csv"));
    for (const std::string file : {"groundtruth.csv", "control.csv", "tracking.csv"}) {
      ExpectSameFile(r / "closed_loop" / "consensus" / file, flown / file);
    }
  }
  // The client reported its fused sets: it is scored for detection as consensus is.
  const auto summary = nlohmann::json::parse(test::ReadFile(r / "summary.json"));
  EXPECT_EQ(summary["methods"]["external:host"]["faults_detected"],
            summary["methods"]["consensus"]["faults_detected"]);
  EXPECT_EQ(summary["methods"]["external:host"]["ate_m"], summary["methods"]["consensus"]["ate_m"]);

  // `tofu estimate` replays the recorded run through the client as the loop did.
  const Result estimate =
      RunTofu("estimate R --method external:host --method plugin:builtin --out E --quiet", work);
  ASSERT_EQ(estimate.exit_code, 0) << estimate.err;
  ExpectSameFile(r / "estimate_external_host.csv", work / "E" / "estimate_external_host.csv");
  ExpectSameFile(r / "estimate_plugin_builtin.csv", work / "E" / "estimate_plugin_builtin.csv");
  fs::remove_all(work);
}

// ---- bad clients ----

// A Python client that answers correctly until `misbehave` (Python statements, run when the
// measurement with seq == `at` arrives) and writes its pid to pid.txt first.
std::string MisbehavingClient(const std::string& misbehave, int at) {
  return R"(import json, os, sys
open('pid.txt', 'w').write(str(os.getpid()))
def send(m):
    sys.stdout.write(json.dumps(m) + '\n'); sys.stdout.flush()
for line in sys.stdin:
    m = json.loads(line)
    t = m['type']
    if t == 'hello': send({'type': 'hello', 'version': 2})
    elif t == 'setup': send({'type': 'ready'})
    elif t == 'measurement':
        seq = m['seq']
        if seq == )" + std::to_string(at) + R"(:
            sys.stderr.write('bad client about to misbehave\n'); sys.stderr.flush()
)" + misbehave + R"(
        est = {'t_ns': m['t_ns'], 'valid': True, 'p_LI_m': [0, 0, 0], 'q_LI_wxyz': [1, 0, 0, 0],
               'v_L_mps': [0, 0, 0], 'omega_I_radps': [0, 0, 0]}
        send({'type': 'estimates', 'seq': seq, 'estimates': [est] if m['kind'] == 'imu' else []})
    elif t == 'finish':
        send({'type': 'finished'}); break
)";
}

bool ProcessAlive(const fs::path& pid_file) {
  if (!fs::exists(pid_file)) return false;
  const int pid = std::stoi(test::ReadFile(pid_file));
  return ::kill(pid, 0) == 0 || errno != ESRCH;
}

// Two client methods of one check compared seed by seed (tofu compare --methods): the
// plug-in and the process client both host consensus and saw the same samples, so they are
// unchanged; a process client hosting naive fusion is the regression.
TEST(ClientMethods, CompareTellsTwoClientMethodsApartOnTheSameSamples) {
  const fs::path work = test::PerTestDirectory("client_compare_");
  fs::create_directories(work);
  std::string clients = HostClients();
  const std::string host = (BuildDir() / "tofu-estimator-host").string();
  clients.replace(clients.find("plugins:"), 0,
                  "  host_naive: {command: [\"" + host + "\"], config: {method: naive}}\n");
  test::WriteFile(work / "s.yaml",
                  Scenario(clients, R"([consensus, "external:host", "external:host_naive", )"
                                    R"("plugin:builtin"])"));
  const Result check = RunTofu("check s.yaml --seeds 8 --jobs 2 --out A --quiet", work);
  ASSERT_EQ(check.exit_code, 0) << check.err;

  const Result same =
      RunTofu("compare A --methods plugin:builtin external:host --json same.json", work);
  EXPECT_EQ(same.exit_code, 0) << same.err;
  const auto s = nlohmann::json::parse(test::ReadFile(work / "same.json"));
  ASSERT_FALSE(s["cells"].empty());
  for (const auto& cell : s["cells"]) {
    EXPECT_EQ(cell["verdict"], "unchanged") << cell.dump();
    EXPECT_EQ(cell["pairing"], "identical samples") << cell.dump();
  }

  const Result worse =
      RunTofu("compare A --methods external:host external:host_naive --json worse.json", work);
  EXPECT_EQ(worse.exit_code, 1) << worse.err;
  const auto w = nlohmann::json::parse(test::ReadFile(work / "worse.json"));
  bool ate_regressed = false;
  for (const auto& cell : w["cells"]) {
    if (cell["metric"] == "methods.<method>.ate_m") ate_regressed = cell["verdict"] == "regressed";
  }
  EXPECT_TRUE(ate_regressed) << w.dump(1);
  fs::remove_all(work);
}

struct BadCase {
  std::string name;
  std::string script;           // the client's code ("" = a command that cannot start)
  std::string expected_message;  // a fragment of what tofu must say
  std::string options = "";      // more keys of the external: entry
};

class BadClient : public ::testing::TestWithParam<BadCase> {};

TEST_P(BadClient, FailsItsMethodScoresTheOthersExitsFiveAndLeavesNoProcess) {
  const BadCase& c = GetParam();
  const fs::path work = test::PerTestDirectory("bad_client_" + c.name + "_");
  fs::create_directories(work);
  const std::string command = "[/usr/bin/python3, bad.py]";
  test::WriteFile(work / "bad.py", c.script);
  const std::string clients =
      "external:\n  bad: {command: " + command + c.options + "}\n";
  test::WriteFile(work / "s.yaml",
                  Scenario(clients, R"([consensus, "external:bad"])") +
                      "expect:\n  - {metric: methods.external:bad.ate_m, max: 1000}\n"
                      "  - {metric: methods.consensus.ate_m, max: 1000}\n");
  const Result run = RunTofu("run s.yaml --out R --quiet", work);
  EXPECT_EQ(run.exit_code, 5) << run.err;
  EXPECT_CONTAINS(run.err, "external:bad");
  EXPECT_CONTAINS(run.err, c.expected_message);
  EXPECT_CONTAINS(run.err, "bad client about to misbehave");
  ASSERT_TRUE(fs::exists(work / "R" / "summary.json")) << run.err;
  const auto summary = nlohmann::json::parse(test::ReadFile(work / "R" / "summary.json"));
  EXPECT_TRUE(summary["methods"]["consensus"]["ate_m"].is_number());
  EXPECT_FALSE(summary["methods"]["consensus"].contains("failure"));
  ASSERT_TRUE(summary["methods"]["external:bad"].contains("failure"));
  EXPECT_CONTAINS(summary["methods"]["external:bad"]["failure"].get<std::string>(), c.expected_message);
  // No figure of the failed method looks healthy, and an expectation on it fails.
  EXPECT_TRUE(summary["methods"]["external:bad"]["ate_m"].is_null());
  EXPECT_TRUE(summary["methods"]["external:bad"]["valid_fraction"].is_null());
  EXPECT_TRUE(summary["methods"]["external:bad"]["partial"].is_object());
  EXPECT_EQ(summary["failure_kind"], "client");
  EXPECT_CONTAINS(summary["failure"].get<std::string>(), "external:bad");
  ASSERT_EQ(summary["expectations"].size(), 2u);
  EXPECT_FALSE(summary["expectations"][0]["passed"].get<bool>());
  EXPECT_CONTAINS(summary["expectations"][0]["not_measurable"].get<std::string>(),
                  "method external:bad failed");
  EXPECT_TRUE(summary["expectations"][1]["passed"].get<bool>());
  EXPECT_FALSE(summary["passed"].get<bool>());
  EXPECT_FALSE(ProcessAlive(work / "pid.txt")) << "the client is still running";
  // The report says so too: the badge, and the method's row with its cause, not figures.
  ASSERT_EQ(RunTofu("report R --out Rep", work).exit_code, 0);
  const std::string page = test::ReadFile(work / "Rep" / "index.html");
  EXPECT_CONTAINS(page, "CLIENT FAILED");
  EXPECT_CONTAINS(page, "<tr class=\"fail\"><td><code>external:bad</code></td><td class=\"result\" "
                        "colspan=\"10\">FAILED: ");
  fs::remove_all(work);
}

// What a failed client answered before failing is kept, all of it, and is the same on
// every run: tofu reads answers in batches while up to 256 measurements are in flight, and
// the batch that holds the failing message holds answers before it too. The client here
// writes its answers in bursts of 50 and a malformed line at seq 1500; it counts the
// estimates it gave before that line, and the partial estimate file has exactly those,
// byte-identical over three runs.
TEST(ClientMethods, AFailedClientsPartialOutputIsAllItAnsweredAndTheSameOnEveryRun) {
  const fs::path work = test::PerTestDirectory("client_partial_");
  fs::create_directories(work);
  test::WriteFile(work / "bad.py", R"(import json, sys
given = 0
def send(m, flush=True):
    sys.stdout.write(json.dumps(m) + '\n')
    if flush: sys.stdout.flush()
for line in sys.stdin:
    m = json.loads(line)
    t = m['type']
    if t == 'hello': send({'type': 'hello', 'version': 2})
    elif t == 'setup': send({'type': 'ready'})
    elif t == 'measurement':
        seq = m['seq']
        if seq == 1500:
            open('given.txt', 'w').write(str(given))
            sys.stdout.write('{not json\n'); sys.stdout.flush()
            continue
        est = {'t_ns': m['t_ns'], 'valid': True, 'p_LI_m': [0, 0, 0], 'q_LI_wxyz': [1, 0, 0, 0],
               'v_L_mps': [0, 0, 0], 'omega_I_radps': [0, 0, 0]}
        answer = [est] if m['kind'] == 'imu' else []
        given += len(answer)
        send({'type': 'estimates', 'seq': seq, 'estimates': answer}, flush=seq % 50 == 49)
    elif t == 'finish':
        send({'type': 'finished'}); break
)");
  test::WriteFile(work / "s.yaml", Scenario("external:\n  bad: {command: [/usr/bin/python3, bad.py]}\n",
                                            R"([consensus, "external:bad"])"));
  std::vector<std::string> estimates, partials;
  for (const std::string out : {"R1", "R2", "R3"}) {
    const Result run = RunTofu("run s.yaml --out " + out + " --quiet", work);
    ASSERT_EQ(run.exit_code, 5) << run.err;
    EXPECT_CONTAINS(run.err, "seq=1500");
    estimates.push_back(test::ReadFile(work / out / "estimate_external_bad.csv"));
    const auto summary = nlohmann::json::parse(test::ReadFile(work / out / "summary.json"));
    partials.push_back(summary["methods"]["external:bad"]["partial"].dump());
  }
  const long given = std::stol(test::ReadFile(work / "given.txt"));
  ASSERT_GT(given, 100);
  // The estimate file: a header line, then one line per estimate.
  EXPECT_EQ(std::count(estimates[0].begin(), estimates[0].end(), '\n'), given + 1);
  for (size_t i = 1; i < estimates.size(); ++i) {
    EXPECT_TRUE(estimates[i] == estimates[0]) << "run " << i + 1 << "'s partial estimates differ";
    EXPECT_EQ(partials[i], partials[0]);
  }
  fs::remove_all(work);
}

// A client command relative to the scenario's directory, the scenario named without a
// directory ("s.yaml"): the run directory's resolved scenario names the directory, so
// `tofu estimate --method external:NAME` on the run, from elsewhere, starts the client.
TEST(ClientMethods, EstimateOnARunFindsARelativeClientCommand) {
  const fs::path work = test::PerTestDirectory("client_relative_");
  fs::create_directories(work / "sub");
  fs::create_directories(work / "elsewhere");
  fs::copy_file(BuildDir() / "tofu-estimator-host", work / "sub" / "host");
  test::WriteFile(work / "s.yaml",
                  Scenario("external:\n  h: {command: [./sub/host], config: {method: consensus}}\n",
                           R"([consensus, "external:h"])"));
  const Result run = RunTofu("run s.yaml --out R --quiet", work);
  ASSERT_EQ(run.exit_code, 0) << run.err;
  const Result estimate =
      RunTofu("estimate ../R --method external:h --out ../E --quiet", work / "elsewhere");
  EXPECT_EQ(estimate.exit_code, 0) << estimate.err;
  EXPECT_TRUE(fs::exists(work / "E" / "estimate_external_h.csv"));
  fs::remove_all(work);
}

// A controller client that fails: the error names it and shows the last 20 lines of its
// standard error, as a failed estimator's does (not only the last one).
TEST(ClientMethods, AFailedControllerShowsItsLastTwentyLinesOfStandardError) {
  const fs::path work = test::PerTestDirectory("client_controller_fails_");
  fs::create_directories(work);
  test::WriteFile(work / "bad.py", R"(import json, sys
def send(m):
    sys.stdout.write(json.dumps(m) + '\n'); sys.stdout.flush()
for line in sys.stdin:
    m = json.loads(line)
    if m['type'] == 'hello': send({'type': 'hello', 'version': 2})
    elif m['type'] == 'setup': send({'type': 'ready'})
    elif m['type'] == 'control':
        for i in range(25): sys.stderr.write('controller line %d\n' % i)
        sys.stderr.flush()
        sys.exit(4)
)");
  test::WriteFile(work / "s.yaml",
                  Scenario("external:\n  bad: {command: [/usr/bin/python3, bad.py]}\n", "[consensus]",
                           "control:\n  controller: \"external:bad\"\n"));
  const Result run = RunTofu("run s.yaml --out R --quiet", work);
  EXPECT_NE(run.exit_code, 0) << run.err;
  EXPECT_CONTAINS(run.err, "external:bad");
  EXPECT_CONTAINS(run.err, "last lines of external:bad's standard error:");
  EXPECT_CONTAINS(run.err, "controller line 5\n");
  EXPECT_CONTAINS(run.err, "controller line 24");
  EXPECT_EQ(run.err.find("controller line 4\n"), std::string::npos) << run.err;
  fs::remove_all(work);
}

// A client that cannot start is found before anything flies: tofu validate, run and
// check refuse it (exit 2) naming the scenario's key and the problem, start no client and
// write nothing.
TEST(ClientMethods, ValidateRefusesEveryClientThatCannotStartBeforeAnythingFlies) {
  const fs::path work = test::PerTestDirectory("client_validate_");
  fs::create_directories(work);
  test::WriteFile(work / "not_executable.py", "print('hi')\n");
  struct Case {
    std::string clients;
    std::string method;
    std::string expected;
  };
  const std::vector<Case> cases = {
      {"external:\n  bad: {command: [no_such_program_of_tofu]}\n", "external:bad",
       "`no_such_program_of_tofu`: command not found"},
      {"external:\n  bad: {command: [./no_such_client.py]}\n", "external:bad",
       "`./no_such_client.py`: cannot execute: No such file or directory"},
      {"external:\n  bad: {command: [./not_executable.py]}\n", "external:bad",
       "cannot execute: Permission denied"},
      {"external:\n  bad: {command: [/usr/bin/python3, c.py], working_dir: no_such_dir}\n",
       "external:bad", "cannot enter the working directory"},
      {"plugins:\n  bad: {library: no_such_plugin.so}\n", "plugin:bad", "cannot load it"},
      {std::string("plugins:\n  bad: {library: \"") + TOFU_TEST_PLUGIN_WRONG_VERSION + "\"}\n",
       "plugin:bad", "this tofu speaks version"},
  };
  for (const Case& c : cases) {
    SCOPED_TRACE(c.expected);
    test::WriteFile(work / "s.yaml",
                    Scenario(c.clients, "[consensus, \"" + c.method + "\"]"));
    for (const std::string command : {"validate s.yaml", "run s.yaml --out R --quiet",
                                      "check s.yaml --out C --quiet"}) {
      const Result r = RunTofu(command, work);
      EXPECT_EQ(r.exit_code, 2) << command << ": " << r.err;
      EXPECT_CONTAINS(r.err, "s.yaml:");
      EXPECT_CONTAINS(r.err, c.method.starts_with("plugin") ? "plugins.bad" : "external.bad");
      EXPECT_CONTAINS(r.err, c.expected);
    }
    EXPECT_FALSE(fs::exists(work / "R"));
    EXPECT_FALSE(fs::exists(work / "C"));
  }
  fs::remove_all(work);
}

INSTANTIATE_TEST_SUITE_P(
    Cases, BadClient,
    ::testing::Values(
        BadCase{"exits_early", MisbehavingClient("            sys.exit(5)", 500), "exit"},
        BadCase{"hangs", MisbehavingClient("            import time; time.sleep(60)", 500), "timeout",
                ", timeout_s: 0.5"},
        BadCase{"malformed", MisbehavingClient("            sys.stdout.write('{not json\\n'); sys.stdout.flush()", 500),
                "JSON"},
        BadCase{"missing_field",
                MisbehavingClient("            send({'type': 'estimates', 'seq': seq, 'estimates': [{'t_ns': m['t_ns']}]}); continue", 500),
                "valid"},
        BadCase{"nan",
                MisbehavingClient("            sys.stdout.write('{\"type\":\"estimates\",\"seq\":%d,\"estimates\":[{\"t_ns\":%d,\"valid\":true,\"p_LI_m\":[NaN,0,0],\"q_LI_wxyz\":[1,0,0,0],\"v_L_mps\":[0,0,0],\"omega_I_radps\":[0,0,0]}]}\\n' % (seq, m['t_ns'])); sys.stdout.flush(); continue", 500),
                "p_LI_m"},
        BadCase{"time_backwards",
                MisbehavingClient("            send({'type': 'estimates', 'seq': seq, 'estimates': [{'t_ns': 0, 'valid': True, 'p_LI_m': [0,0,0], 'q_LI_wxyz': [1,0,0,0], 'v_L_mps': [0,0,0], 'omega_I_radps': [0,0,0]}]}); continue", 500),
                "t_ns"},
        BadCase{"wrong_seq",
                MisbehavingClient("            send({'type': 'estimates', 'seq': seq + 7, 'estimates': []}); continue", 500),
                "seq"},
        BadCase{"own_error",
                MisbehavingClient("            send({'type': 'error', 'message': 'filter diverged'}); continue", 500),
                "filter diverged"},
        BadCase{"other_version",
                "import json, os, sys\nopen('pid.txt', 'w').write(str(os.getpid()))\n"
                "sys.stderr.write('bad client about to misbehave\\n')\n"
                "line = sys.stdin.readline()\n"
                "sys.stdout.write(json.dumps({'type': 'hello', 'version': 7}) + '\\n')\n"
                "sys.stdout.flush()\nsys.stdin.read()\n",
                "version 7"}),
    [](const ::testing::TestParamInfo<BadCase>& param) { return param.param.name; });

// A closed-loop flight whose estimator fails only at the end (exits 1 after finished):
// its figures are null (kept under `partial`), the failure is the run's (exit 5), in its
// closed_loop entry; an expectation on the flight fails.
TEST(ClientMethods, AClientFailingAfterAClosedLoopFlightFailsTheRun) {
  const fs::path work = test::PerTestDirectory("client_closed_loop_finish_");
  fs::create_directories(work);
  std::string script = MisbehavingClient("            pass", 0);
  script.replace(script.find("send({'type': 'finished'}); break"),
                 std::string("send({'type': 'finished'}); break").size(),
                 "send({'type': 'finished'}); sys.exit(1)");
  // Never valid: the pilot flies on ground truth throughout, the flight itself is sound.
  const std::string valid = "'valid': True";
  script.replace(script.find(valid), valid.size(), "'valid': False");
  test::WriteFile(work / "bad.py", script);
  test::WriteFile(work / "s.yaml",
                  Scenario("external:\n  bad: {command: [/usr/bin/python3, bad.py]}\n",
                           R"([consensus, "external:bad"])",
                           "control:\n  state_source: estimate\n  methods: [\"external:bad\"]\n"
                           "expect:\n  - {metric: closed_loop.external:bad.collisions, max: 0}\n"));
  const Result run = RunTofu("run s.yaml --out R --quiet", work);
  EXPECT_EQ(run.exit_code, 5) << run.err;
  EXPECT_CONTAINS(run.err, "closed-loop flight on external:bad");
  EXPECT_CONTAINS(run.err, "exited with status 1");
  const auto summary = nlohmann::json::parse(test::ReadFile(work / "R" / "summary.json"));
  EXPECT_TRUE(summary["closed_loop"]["external:bad"]["failure"].is_string());
  EXPECT_TRUE(summary["closed_loop"]["external:bad"]["tracking_rmse_m"].is_null());
  EXPECT_TRUE(summary["closed_loop"]["external:bad"]["partial"]["tracking_rmse_m"].is_number());
  EXPECT_FALSE(summary["expectations"][0]["passed"].get<bool>());
  EXPECT_CONTAINS(summary["expectations"][0]["not_measurable"].get<std::string>(),
                  "closed-loop flight on external:bad failed");
  EXPECT_FALSE(summary["passed"].get<bool>());
  fs::remove_all(work);
}

// `tofu check` over a run whose client exits early: only that method is marked failed, in
// the table, the method table and a JUnit test case of its own; the check exits 5 and
// names the cause, not "simulation failed".
TEST(ClientMethods, ACheckMarksTheFailedClientAloneAndExitsFive) {
  const fs::path work = test::PerTestDirectory("client_check_");
  fs::create_directories(work);
  test::WriteFile(work / "bad.py", MisbehavingClient("            sys.exit(5)", 500));
  test::WriteFile(work / "s.yaml",
                  Scenario("external:\n  bad: {command: [/usr/bin/python3, bad.py]}\n",
                           R"([consensus, "external:bad"])") +
                      "expect:\n  - {metric: methods.consensus.ate_m, max: 1000}\n");
  const Result check = RunTofu("check s.yaml --out C --junit junit.xml", work);
  EXPECT_EQ(check.exit_code, 5) << check.err;
  const std::string table = test::ReadFile(work / "stdout.txt");
  EXPECT_CONTAINS(table, "FAILED in 1/1 seeds: external:bad");
  EXPECT_CONTAINS(table, "failed clients:");
  const std::string junit = test::ReadFile(work / "junit.xml");
  EXPECT_CONTAINS(junit, "name=\"method external:bad\"");
  EXPECT_CONTAINS(junit, "type=\"client\"");
  EXPECT_EQ(junit.find("simulation failed"), std::string::npos) << junit;
  EXPECT_CONTAINS(test::ReadFile(work / "C" / "methods.md"), "external:bad **FAILED in 1 of 1 seeds");
  const auto record = nlohmann::json::parse(test::ReadFile(work / "C" / "check.json"));
  EXPECT_EQ(record["runs"][0]["exit_code"], 5);
  EXPECT_CONTAINS(record["runs"][0]["client_failure"].get<std::string>(), "external:bad");
  fs::remove_all(work);
}

// A client that answers every measurement 2 ms late (a run is still flying when a test's
// signal comes), writing its pid to the file the Python expression `pid_file` names, and
// s.yaml flying it beside consensus.
void WriteSlowClientScenario(const fs::path& work, const std::string& pid_file) {
  std::string script = MisbehavingClient("            pass", 0);
  const std::string pid = "open('pid.txt', 'w')";
  script.replace(script.find(pid), pid.size(), "open(" + pid_file + ", 'w')");
  const std::string marker = "        seq = m['seq']\n";
  script.insert(script.find(marker) + marker.size(), "        import time; time.sleep(0.002)\n");
  test::WriteFile(work / "slow.py", script);
  test::WriteFile(work / "s.yaml",
                  Scenario("external:\n  slow: {command: [/usr/bin/python3, slow.py]}\n",
                           R"([consensus, "external:slow"])"));
}

TEST(ClientMethods, SigtermDuringARunLeavesNoClientProcess) {
  const fs::path work = test::PerTestDirectory("client_sigterm_");
  fs::create_directories(work);
  // A client that answers slowly: the run is still flying when the signal comes.
  WriteSlowClientScenario(work, "'pid.txt'");
  test::ChildProcess tofu({TOFU_BINARY, "run", "s.yaml", "--out", "R", "--quiet"}, work,
                          work / "log.txt");
  ASSERT_TRUE(test::WaitUntil([&] { return fs::exists(work / "pid.txt"); },
                              std::chrono::seconds(30)));
  std::this_thread::sleep_for(std::chrono::milliseconds(500));
  ::kill(tofu.pid(), SIGTERM);
  const std::optional<int> status = tofu.Wait(std::chrono::seconds(30));
  ASSERT_TRUE(status.has_value());
  EXPECT_TRUE(WIFEXITED(*status) && WEXITSTATUS(*status) == 128 + SIGTERM)
      << test::ReadFile(work / "log.txt");
  EXPECT_FALSE(fs::exists(work / "R"));
  EXPECT_TRUE(test::WaitUntil([&] { return !ProcessAlive(work / "pid.txt"); },
                              std::chrono::seconds(5)))
      << "the client outlived tofu";
  fs::remove_all(work);
}

// Whether `pid` is a live process: a zombie (exited, not yet reaped by whoever adopted
// it) is not.
bool ProcessRunning(int pid) {
  std::string stat;
  try {
    stat = test::ReadFile(fs::path("/proc") / std::to_string(pid) / "stat");
  } catch (const std::exception&) {
    return false;
  }
  const size_t paren = stat.rfind(')');
  if (stat.empty() || paren == std::string::npos || paren + 2 >= stat.size()) return false;
  const char state = stat[paren + 2];
  return state != 'Z' && state != 'X';
}

// SIGKILL: no destructor runs in tofu. The client's own child (a grandchild of tofu, which
// PR_SET_PDEATHSIG alone does not reach) must end with the client's whole group.
TEST(ClientMethods, SigkillOfTofuLeavesNoClientProcessNorItsChildren) {
  const fs::path work = test::PerTestDirectory("client_sigkill_");
  fs::create_directories(work);
  WriteSlowClientScenario(work, "'pid.txt'");
  std::string script = test::ReadFile(work / "slow.py");
  script.insert(script.find("def send"),
                "import subprocess\n"
                "child = subprocess.Popen(['sleep', '300'])\n"
                "open('child_pid.txt', 'w').write(str(child.pid))\n");
  test::WriteFile(work / "slow.py", script);
  test::ChildProcess tofu({TOFU_BINARY, "run", "s.yaml", "--out", "R", "--quiet"}, work,
                          work / "log.txt");
  ASSERT_TRUE(test::WaitUntil(
      [&] { return fs::exists(work / "pid.txt") && fs::exists(work / "child_pid.txt"); },
      std::chrono::seconds(30)));
  std::this_thread::sleep_for(std::chrono::milliseconds(500));
  const int client = std::stoi(test::ReadFile(work / "pid.txt"));
  const int grandchild = std::stoi(test::ReadFile(work / "child_pid.txt"));
  ASSERT_TRUE(ProcessRunning(client));
  ASSERT_TRUE(ProcessRunning(grandchild));
  ::kill(tofu.pid(), SIGKILL);
  ASSERT_TRUE(tofu.Wait(std::chrono::seconds(30)).has_value());
  EXPECT_TRUE(test::WaitUntil([&] { return !ProcessRunning(client); }, std::chrono::seconds(5)))
      << "the client outlived tofu";
  EXPECT_TRUE(test::WaitUntil([&] { return !ProcessRunning(grandchild); }, std::chrono::seconds(5)))
      << "the client's own child outlived tofu";
  if (ProcessRunning(grandchild)) ::kill(grandchild, SIGKILL);
  fs::remove_all(work);
}

TEST(ClientMethods, SigintToACheckWithJobsLeavesNoClientProcess) {
  const fs::path work = test::PerTestDirectory("client_check_sigint_");
  fs::create_directories(work);
  // Slow clients, each writing pid_<pid>.txt: two seeds fly at once (--jobs 2).
  WriteSlowClientScenario(work, "'pid_%d.txt' % os.getpid()");
  test::ChildProcess check({TOFU_BINARY, "check", "s.yaml", "--seeds", "2", "--jobs", "2",
                            "--out", "C", "--quiet"},
                           work, work / "log.txt");
  const auto pid_files = [&] {
    std::vector<fs::path> files;
    for (const auto& e : fs::directory_iterator(work)) {
      if (e.path().filename().string().starts_with("pid_")) files.push_back(e.path());
    }
    return files;
  };
  ASSERT_TRUE(test::WaitUntil([&] { return pid_files().size() >= 2; }, std::chrono::seconds(60)))
      << test::ReadFile(work / "log.txt");
  std::this_thread::sleep_for(std::chrono::milliseconds(300));
  ::kill(check.pid(), SIGINT);
  const std::optional<int> status = check.Wait(std::chrono::seconds(60));
  ASSERT_TRUE(status.has_value());
  EXPECT_TRUE(WIFEXITED(*status) && WEXITSTATUS(*status) == 128 + SIGINT)
      << test::ReadFile(work / "log.txt");
  for (const fs::path& file : pid_files()) {
    EXPECT_TRUE(test::WaitUntil([&] { return !ProcessAlive(file); }, std::chrono::seconds(5)))
        << file << ": the client outlived tofu check";
  }
  fs::remove_all(work);
}

}  // namespace
}  // namespace tofu
