// The fuzz targets' oracle, kept by the normal build (docs/FUZZING.md): the committed seeds
// of fuzz/seeds/<target>/ and the findings of tests/data/fuzz_regressions/<target>/ go
// through the reader their target fuzzes, in the same file layout, and the reader either
// returns or throws core::InputError naming the file; nothing else (another exception, a
// crash, a hang) is acceptable. Each input runs in a child process with a time and memory
// limit, so that a reader that hangs or crashes fails its test instead of the suite.
// Seeds are valid inputs and must parse; each finding has its own test asserting the
// documented error. Every finding so far is fixed and its test enabled; a future finding
// whose fix must wait may be committed as a DISABLED_ test that fails until the fix.

#include <signal.h>
#include <sys/resource.h>
#include <sys/wait.h>
#include <unistd.h>

#include <gtest/gtest.h>

#include <algorithm>
#include <chrono>
#include <exception>
#include <filesystem>
#include <functional>
#include <string>
#include <tuple>
#include <thread>
#include <utility>
#include <vector>

#include "core/error.h"
#include "campaign/search_spec.h"
#include "corpus/corpus_spec.h"
#include "fuzz/client_messages.h"
#include "fuzz/recorded_log_layouts.h"
#include "fuzz/scenario_round_trip.h"
#include "harness/scenario.h"
#include "replay/recorded_log.h"
#include "replay/trajectory_metrics.h"
#include "replay/velocity_csv.h"
#include "tests/test_support.h"

namespace tofu {
namespace {

namespace fs = std::filesystem;

const fs::path kSourceDir = TOFU_SOURCE_DIR;

// A reader applied to `bytes` in its target's layout under the (empty, existing) `dir`.
using Reader = std::function<void(const std::string& bytes, const fs::path& dir)>;

// What a reader did with an input, run in a child process.
struct Outcome {
  enum Kind { kParsed, kInputError, kOtherException, kCrashed, kHung } kind = kCrashed;
  std::string text;  ///< kInputError: what(); kOtherException: what(); else a description
  std::string file;  ///< kInputError: location().file
  int line = 0;      ///< kInputError: location().line

  std::string Describe() const {
    static const char* const kNames[] = {"parsed", "InputError", "another exception",
                                         "crashed", "did not finish within 20 s"};
    return std::string(kNames[kind]) + (text.empty() ? "" : ": " + text);
  }
};

// Runs `read` on `bytes` in a child (at most 4 GiB of address space, 20 s): a hang or a
// crash of the reader is an outcome, not the end of the test binary. Under ASan
// (TOFU_SANITIZE) the address space is its shadow's: the time limit alone bounds a hang.
Outcome RunIsolated(const Reader& read, const std::string& bytes, const fs::path& dir) {
  fs::create_directories(dir);
  const fs::path report = dir / "outcome.txt";
  const pid_t pid = ::fork();
  if (pid == 0) {
#if !defined(__SANITIZE_ADDRESS__)
    rlimit limit{};
    if (::getrlimit(RLIMIT_AS, &limit) == 0) {
      limit.rlim_cur = std::min<rlim_t>(limit.rlim_max, rlim_t{4} << 30);
      ::setrlimit(RLIMIT_AS, &limit);
    }
#endif
    int code = 0;
    std::string text;
    try {
      read(bytes, dir);
      code = Outcome::kParsed;
    } catch (const core::InputError& e) {
      code = Outcome::kInputError;
      text = e.location().file + "\n" + std::to_string(e.location().line) + "\n" + e.what();
    } catch (const std::exception& e) {
      code = Outcome::kOtherException;
      text = e.what();
    } catch (...) {
      code = Outcome::kOtherException;
      text = "an exception not derived from std::exception";
    }
    fuzz::WriteFile(report, text);
    ::_exit(code);
  }
  Outcome outcome;
  if (pid < 0) {
    outcome.text = "fork failed";
    return outcome;
  }
  int status = 0;
  const auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(20);
  while (::waitpid(pid, &status, WNOHANG) != pid) {
    if (std::chrono::steady_clock::now() > deadline) {
      ::kill(pid, SIGKILL);
      ::waitpid(pid, &status, 0);
      outcome.kind = Outcome::kHung;
      return outcome;
    }
    std::this_thread::sleep_for(std::chrono::milliseconds(2));
  }
  if (!WIFEXITED(status) || WEXITSTATUS(status) > Outcome::kOtherException) {
    outcome.text = WIFSIGNALED(status) ? "signal " + std::to_string(WTERMSIG(status))
                                       : "exit " + std::to_string(WEXITSTATUS(status));
    return outcome;
  }
  outcome.kind = static_cast<Outcome::Kind>(WEXITSTATUS(status));
  std::string text = test::ReadFile(report);
  if (outcome.kind == Outcome::kInputError) {
    const size_t a = text.find('\n');
    const size_t b = text.find('\n', a + 1);
    outcome.file = text.substr(0, a);
    outcome.line = std::stoi(text.substr(a + 1, b - a - 1));
    text = text.substr(b + 1);
  }
  outcome.text = text;
  return outcome;
}

// The readers, one per fuzz target (fuzz/fuzz_<target>.cc), in the same layouts.
void ReadScenario(const std::string& bytes, const fs::path&) {
  const harness::Scenario s = harness::ParseScenario(bytes, "fuzz_scenario.yaml");
  // The resolved YAML loads back (scenario.h), to the same text up to number noise.
  const std::string resolved = harness::ResolvedScenarioYaml(s);
  const std::string again =
      harness::ResolvedScenarioYaml(harness::ParseScenario(resolved, "resolved_scenario.yaml"));
  const std::string difference = fuzz::RoundTripDifference(resolved, again);
  if (!difference.empty()) throw std::logic_error("round trip: " + difference);
}

void ReadCalibration(const std::string& bytes, const fs::path&) {
  (void)replay::DescribeRunStreams({{"imu", core::MeasurementKind::kImu},
                                     {"vio", core::MeasurementKind::kPose},
                                     {"lio", core::MeasurementKind::kPose},
                                     {"leica", core::MeasurementKind::kPosition}},
                                    bytes, "fuzz_run");
}

const std::vector<std::pair<std::string, Reader>>& Readers() {
  static const std::vector<std::pair<std::string, Reader>> readers = {
      {"fuzz_scenario", ReadScenario},
      {"fuzz_calibration", ReadCalibration},
      {"fuzz_run_directory",
       [](const std::string& bytes, const fs::path& dir) {
         fuzz::WriteRunDirectory(dir);
         fuzz::WriteFile(dir / "sensors" / "fuzz.csv", bytes);
         (void)replay::ReadRecordedLog(dir);
       }},
      {"fuzz_euroc_imu",
       [](const std::string& bytes, const fs::path& dir) {
         fuzz::WriteEurocDirectory(dir, fuzz::kEurocImu);
         fuzz::WriteFile(dir / fuzz::kEurocImu, bytes);
         (void)replay::ReadRecordedLog(dir);
       }},
      {"fuzz_euroc_groundtruth",
       [](const std::string& bytes, const fs::path& dir) {
         fuzz::WriteEurocDirectory(dir, fuzz::kEurocGroundTruth);
         fuzz::WriteFile(dir / fuzz::kEurocGroundTruth, bytes);
         (void)replay::ReadRecordedLog(dir);
       }},
      {"fuzz_tum",
       [](const std::string& bytes, const fs::path& dir) {
         fuzz::WriteFile(dir / "stream.tum", bytes);
         (void)replay::ReadTumTrajectory(dir / "stream.tum");
       }},
      {"fuzz_velocity_csv",
       [](const std::string& bytes, const fs::path&) {
         (void)replay::ParseVelocityCsv(bytes, "fuzz_velocity.csv");
       }},
      {"fuzz_corpus_spec",
       [](const std::string& bytes, const fs::path&) {
         (void)corpus::ParseCorpusSpec(bytes, "fuzz_corpus.yaml");
       }},
      {"fuzz_search_spec",
       [](const std::string& bytes, const fs::path&) {
         (void)campaign::ParseSearchSpec(bytes, "fuzz_search.yaml",
                                         fs::path(TOFU_SOURCE_DIR) / "tests" / "data" / "search");
       }},
      // The protocol's oracle is its own (fuzz/client_messages.h): ProtocolError is
      // absorbed, anything else escapes. A seed must hold a message that decodes.
      {"fuzz_client_message",
       [](const std::string& bytes, const fs::path&) {
         if (fuzz::DecodeClientMessages(bytes) == 0) {
           throw std::logic_error("no message of the input decodes");
         }
       }},
  };
  return readers;
}

const Reader& ReaderOf(const std::string& target) {
  for (const auto& [name, reader] : Readers()) {
    if (name == target) return reader;
  }
  ADD_FAILURE() << "no reader for " << target;
  static const Reader none = [](const std::string&, const fs::path&) {};
  return none;
}

// The finding tests/data/fuzz_regressions/<target>/<name> through its target's reader.
Outcome Replay(const std::string& target, const std::string& name) {
  const fs::path file = kSourceDir / "tests" / "data" / "fuzz_regressions" / target / name;
  EXPECT_TRUE(fs::is_regular_file(file)) << file;
  return RunIsolated(ReaderOf(target), test::ReadFile(file), test::PerTestDirectory("fuzz_"));
}

TEST(FuzzSeeds, EverySeedOfEveryTargetParses) {
  const fs::path base = test::PerTestDirectory("fuzz_");
  int seeds = 0;
  for (const auto& [target, reader] : Readers()) {
    const fs::path dir = kSourceDir / "fuzz" / "seeds" / target;
    ASSERT_TRUE(fs::is_directory(dir)) << dir;
    for (const auto& entry : fs::directory_iterator(dir)) {
      const Outcome outcome =
          RunIsolated(reader, test::ReadFile(entry.path()), base / target / entry.path().filename());
      EXPECT_EQ(outcome.kind, Outcome::kParsed) << entry.path() << ": " << outcome.Describe();
      ++seeds;
    }
  }
  EXPECT_GE(seeds, 8);
}

// ---- findings (docs/FUZZING.md, "Findings") ----

// Finding 1: a line that is just ',' made yaml-cpp's LoadAll hand out empty documents
// forever (no return, memory growing without bound): `tofu validate` / `tofu run` /
// `tofu corpus` hung on such a file. Fixed in harness/yaml_reader.cc (ParseDocument).
TEST(FuzzRegressions, StrayCommaInAScenarioIsASyntaxErrorNotAHang) {
  const Outcome outcome = Replay("fuzz_scenario", "stray_comma.yaml");
  ASSERT_EQ(outcome.kind, Outcome::kInputError) << outcome.Describe();
  EXPECT_EQ(outcome.file, "fuzz_scenario.yaml");
  EXPECT_EQ(outcome.line, 2);
  EXPECT_CONTAINS(outcome.text, "YAML syntax error: unexpected ','");
}

TEST(FuzzRegressions, StrayCommaInACorpusSpecIsASyntaxErrorNotAHang) {
  const Outcome outcome = Replay("fuzz_corpus_spec", "stray_comma.yaml");
  ASSERT_EQ(outcome.kind, Outcome::kInputError) << outcome.Describe();
  EXPECT_EQ(outcome.file, "fuzz_corpus.yaml");
  EXPECT_EQ(outcome.line, 1);
  EXPECT_CONTAINS(outcome.text, "fuzz_corpus.yaml:1:1: YAML syntax error: unexpected ','");
}

// Finding 7 (campaign/search_spec.cc, ParseSearchSpec; the same in a corpus spec's include:
// entries): a `base:` whose quoted value runs over many lines named a path longer than the
// file system takes, and std::filesystem::is_regular_file threw filesystem_error ("File
// name too long"), exit 3, instead of the missing-base input error.
TEST(FuzzRegressions, ASearchBaseNameTooLongIsAnInputError) {
  const Outcome outcome = Replay("fuzz_search_spec", "base_name_too_long.yaml");
  ASSERT_EQ(outcome.kind, Outcome::kInputError) << outcome.Describe();
  EXPECT_EQ(outcome.file, "fuzz_search.yaml");
  EXPECT_CONTAINS(outcome.text, "cannot read the base scenario");
}

// Finding 2 (replay/recorded_log.cc, ParseCalibration): a sensor of calibration.yaml
// without an `options` key threw YAML::InvalidNode (`s.options = node["options"]` assigned
// a missing node), so `tofu estimate` on a real log whose calibration.yaml gives only a
// mount exited 3 with "invalid node; this may result from using a map iterator as a
// sequence iterator" instead of reading it.
TEST(FuzzRegressions, CalibrationSensorWithoutOptionsIsRead) {
  const Outcome outcome = Replay("fuzz_calibration", "sensor_without_options.yaml");
  EXPECT_EQ(outcome.kind, Outcome::kParsed) << outcome.Describe();
}

// Finding 3 (replay/recorded_log.cc, ParseCalibration): a sensor name of calibration.yaml
// that is not a scalar ("[imu]: {}") threw YAML::TypedBadConversion
// (`entry.first.as<std::string>()`) instead of an InputError naming the file and line.
TEST(FuzzRegressions, CalibrationSensorNameThatIsAListIsAnInputError) {
  const Outcome outcome = Replay("fuzz_calibration", "sensor_name_is_a_list.yaml");
  ASSERT_EQ(outcome.kind, Outcome::kInputError) << outcome.Describe();
  EXPECT_EQ(outcome.file, "fuzz_run/calibration.yaml");
  EXPECT_EQ(outcome.line, 3);
  EXPECT_CONTAINS(outcome.text, "sensors");
}

// Finding (harness/client_config.cc, ReadConfig): a client's `config:` map with a key
// that is not valid UTF-8 reached nlohmann's dump(), whose type_error.316 ("invalid UTF-8
// byte") ended `tofu run` and `tofu corpus` with exit 3 and no file or line. The config
// travels to the client as JSON (UTF-8 only): an input error at the config's line.
TEST(FuzzRegressions, ClientConfigKeyThatIsNotUtf8IsAnInputError) {
  for (const auto& [target, file, line] :
       {std::tuple<std::string, std::string, int>{"fuzz_scenario", "fuzz_scenario.yaml", 13},
        std::tuple<std::string, std::string, int>{"fuzz_corpus_spec", "fuzz_corpus.yaml", 31}}) {
    const Outcome outcome = Replay(target, "config_key_not_utf8.yaml");
    ASSERT_EQ(outcome.kind, Outcome::kInputError) << target << ": " << outcome.Describe();
    EXPECT_EQ(outcome.file, file);
    EXPECT_EQ(outcome.line, line) << outcome.Describe();
    EXPECT_CONTAINS(outcome.text, "not valid UTF-8");
  }
}

// The resolved YAML of the scenario tests/data/fuzz_regressions/fuzz_scenario/<name>
// and that YAML resolved again.
std::pair<std::string, std::string> ResolveTwice(const std::string& name) {
  const std::string text = test::ReadFile(kSourceDir / "tests" / "data" / "fuzz_regressions" /
                                          "fuzz_scenario" / name);
  const std::string resolved =
      harness::ResolvedScenarioYaml(harness::ParseScenario(text, "fuzz_scenario.yaml"));
  return {resolved,
          harness::ResolvedScenarioYaml(harness::ParseScenario(resolved, "resolved.yaml"))};
}

// Finding 4 (harness/config_io.cc, EmitRpyDeg): the resolved YAML of a scenario did not
// resolve to itself: an attitude's roll/pitch/yaw go through a quaternion, and a zero
// angle came back as -1.2e-15 deg, then -2.0e-15 deg, ... (12 significant digits kept
// the noise), so the resolved scenario.yaml of a run directory was not a fixed point
// (scenario.h: "loading it back yields an equal scenario").
TEST(FuzzRegressions, ResolvedScenarioYamlIsAFixedPoint) {
  const auto [resolved, again] = ResolveTwice("waypoint_attitude_round_trip.yaml");
  EXPECT_EQ(again, resolved);
}

// Finding 5 (harness/config_io.cc, EmitRpyDeg): near gimbal lock a roll of -180 deg
// resolved to 180 and back to -180: the resolved YAML alternated between two texts.
// 12 significant digits did not reproduce such an attitude to the 1e-14 rad that
// EmitRpyDeg asked of its rounding, so it wrote the unrounded angles, and atan2 put the
// roll on either side of the branch cut. Angles are now rounded to nano-degrees.
TEST(FuzzRegressions, ResolvedScenarioYamlIsAFixedPointAtRoll180) {
  const auto [resolved, again] = ResolveTwice("roll_180_near_gimbal_lock.yaml");
  EXPECT_EQ(again, resolved);
}

// ... while the tolerant round trip the fuzz target checks holds for it.
TEST(FuzzRegressions, ResolvedScenarioYamlRoundTripsUpToNumberNoise) {
  const Outcome outcome = Replay("fuzz_scenario", "waypoint_attitude_round_trip.yaml");
  EXPECT_EQ(outcome.kind, Outcome::kParsed) << outcome.Describe();
}

}  // namespace
}  // namespace tofu
