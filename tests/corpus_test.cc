// Failure corpora (corpus/): the spec is strict, episodes depend on (seed, index) only,
// shards are invariant to the layout, a killed shard resumes, verify catches tampering.
#include <signal.h>
#include <spawn.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <string>
#include <thread>

#include <fmt/format.h>
#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include "core/error.h"
#include "corpus/corpus_command.h"
#include "corpus/corpus_spec.h"
#include "corpus/episode_writer.h"
#include "corpus/hdf5_file.h"

extern char** environ;

namespace tofu::corpus {
namespace {

namespace fs = std::filesystem;

const std::string kSmokeSpec = TOFU_SOURCE_DIR "/corpora/smoke.yaml";

fs::path TempDir(const std::string& name) {
  const fs::path dir = fs::temp_directory_path() / fmt::format("tofu_corpus_{}_{}", name, ::getpid());
  fs::remove_all(dir);
  return dir;
}

std::string ReadText(const fs::path& path) {
  std::ifstream in(path);
  return std::string(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
}

// The spec's text with `from` replaced by `to` (the first occurrence).
std::string SmokeWith(const std::string& from, const std::string& to) {
  std::string text = ReadText(kSmokeSpec);
  const std::size_t at = text.find(from);
  EXPECT_NE(at, std::string::npos) << from;
  return text.replace(at, from.size(), to);
}

void ExpectRejected(const std::string& text, const std::string& where, const std::string& what) {
  try {
    ParseCorpusSpec(text, "spec.yaml");
    ADD_FAILURE() << "accepted a spec expected to fail with " << what;
  } catch (const core::InputError& e) {
    EXPECT_NE(std::string(e.what()).find(where), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find(what), std::string::npos) << e.what();
  }
}

TEST(CorpusSpec, RejectsUnknownKeysEmptyRangesAndUnknownNames) {
  ExpectRejected(SmokeWith("episodes: 4", "episodes: 4\nepisode_count: 3"), "spec.yaml:", "episode_count");
  ExpectRejected(SmokeWith("speed_mps: [0.4, 1.0]", "speed_mps: [1.0, 0.4]"), "spec.yaml:16", "lo <= hi");
  ExpectRejected(SmokeWith("kind: freeze", "kind: melt"), "spec.yaml:", "unknown fault kind 'melt'");
  ExpectRejected(SmokeWith("sensors: [vio, lio, leica]}", "sensors: [vio, gnss]}"), "spec.yaml:", "'gnss' is not a sensor");
  ExpectRejected(SmokeWith("families: [figure_eight, circle, wall_pass]", "families: [spiral]"), "spec.yaml:", "spiral");
  ExpectRejected(SmokeWith("episodes: 4", "episodes: 0"), "spec.yaml:", "episodes");
  ExpectRejected(SmokeWith("    wall: {point_m: [6, 0], normal: [-1, 0]}   # inner face of the +x wall\n", ""),
                 "spec.yaml:", "wall_pass needs every world to have a `wall:`");
}

TEST(CorpusSpec, EpisodeDependsOnlyOnSeedAndIndex) {
  const CorpusSpec spec = LoadCorpusSpec(kSmokeSpec);
  const EpisodePlan a = PlanEpisode(spec, 3);
  const EpisodePlan b = PlanEpisode(spec, 3);
  EXPECT_EQ(a.scenario_yaml, b.scenario_yaml);
  EXPECT_NE(PlanEpisode(spec, 2).scenario_yaml, a.scenario_yaml);
  // More episodes in the spec do not change episode 3.
  const CorpusSpec bigger = ParseCorpusSpec(SmokeWith("episodes: 4", "episodes: 400"), "big.yaml");
  EXPECT_EQ(PlanEpisode(bigger, 3).scenario_yaml, a.scenario_yaml);
  // Another corpus seed does.
  const CorpusSpec reseeded = ParseCorpusSpec(SmokeWith("seed: 7", "seed: 8"), "seed.yaml");
  EXPECT_NE(PlanEpisode(reseeded, 3).scenario_yaml, a.scenario_yaml);
}

TEST(CorpusEpisode, OverlappingFaultsOfOneKindKeepOneEventEach) {
  // Two dropouts of the VIO overlap: labels read start, start, end, end.
  harness::RunRecord record;
  record.scenario.duration_s = 2.0;
  for (core::Time t = 0; t <= 2'000'000'000; t += 500'000'000) record.groundtruth.push_back({.t_ns = t});
  record.labels = {{500'000'000, "vio", "dropout", "fault", true},
                   {800'000'000, "vio", "dropout", "fault", true},
                   {1'000'000'000, "vio", "dropout", "fault", false},
                   {1'500'000'000, "vio", "dropout", "fault", false},
                   {1'200'000'000, "vio", "jump", "fault", true}};
  EpisodePlan plan;
  plan.id = "test_e000000";
  plan.faults = {{"vio", sim::FaultKind::kDropout, 0.5, 1.0, 0.0},
                 {"vio", sim::FaultKind::kDropout, 0.8, 1.5, 0.0},
                 {"vio", sim::FaultKind::kJump, 1.2, 2.0, 0.25}};
  const fs::path path = TempDir("overlap").string() + ".h5";
  {
    Hdf5File file = Hdf5File::Create(path);
    const ManifestRow row = WriteEpisode(file.root(), plan, record, nlohmann::json::object());
    EXPECT_EQ(row.scheduled_faults, 3u);
    file.Close();
  }
  const Hdf5File file = Hdf5File::OpenReadOnly(path);
  const Hdf5Group events = file.root().OpenGroup(plan.id).OpenGroup("events");
  EXPECT_EQ(events.ReadInt64("onset_ns"), (std::vector<std::int64_t>{500'000'000, 800'000'000, 1'200'000'000}));
  EXPECT_EQ(events.ReadInt64("offset_ns"), (std::vector<std::int64_t>{1'000'000'000, 1'500'000'000, 2'000'000'000}));
  EXPECT_EQ(events.ReadUInt8("open"), (std::vector<std::uint8_t>{0, 0, 1}));
  const std::vector<double> severity = events.ReadDouble("severity");
  EXPECT_TRUE(std::isnan(severity[0]) && std::isnan(severity[1]));  // a dropout has no size
  EXPECT_EQ(severity[2], 0.25);
  fs::remove(path);
}

// Every dataset of an episode group, by path: shape and values (as the hash sees them).
std::uint64_t EpisodeHash(const fs::path& shard_file, const std::string& id) {
  const Hdf5File file = Hdf5File::OpenReadOnly(shard_file);
  return file.root().OpenGroup("episodes").OpenGroup(id).ContentHash();
}

TEST(CorpusGenerate, ShardLayoutDoesNotChangeAnEpisode) {
  const fs::path one = TempDir("layout_1_1");
  const fs::path four = TempDir("layout_3_4");
  GenerateOptions options;
  options.spec = kSmokeSpec;
  options.quiet = true;
  options.out_dir = one;
  options.shard = {0, 1};
  ASSERT_EQ(RunCorpusGenerate(options), 0);
  options.out_dir = four;
  options.shard = {3, 4};
  ASSERT_EQ(RunCorpusGenerate(options), 0);
  const std::string id = PlanEpisode(LoadCorpusSpec(kSmokeSpec), 3).id;
  const std::uint64_t a = EpisodeHash(one / "shard_0000_of_0001.h5", id);
  const std::uint64_t b = EpisodeHash(four / "shard_0003_of_0004.h5", id);
  EXPECT_EQ(a, b) << "episode 3 differs between shard layouts 1/1 and 3/4";
  // And the arrays themselves, one by one for a few of them.
  const Hdf5File fa = Hdf5File::OpenReadOnly(one / "shard_0000_of_0001.h5");
  const Hdf5File fb = Hdf5File::OpenReadOnly(four / "shard_0003_of_0004.h5");
  const Hdf5Group ea = fa.root().OpenGroup("episodes").OpenGroup(id);
  const Hdf5Group eb = fb.root().OpenGroup("episodes").OpenGroup(id);
  EXPECT_EQ(ea.OpenGroup("sensors").OpenGroup("vio").ReadDouble("values"),
            eb.OpenGroup("sensors").OpenGroup("vio").ReadDouble("values"));
  EXPECT_EQ(ea.OpenGroup("methods").OpenGroup("consensus").ReadDouble("p_LI_m"),
            eb.OpenGroup("methods").OpenGroup("consensus").ReadDouble("p_LI_m"));
  EXPECT_EQ(ea.StringAttribute("scenario_yaml"), eb.StringAttribute("scenario_yaml"));
  // A different episode hashes differently (the hash sees the data).
  EXPECT_NE(a, EpisodeHash(one / "shard_0000_of_0001.h5", PlanEpisode(LoadCorpusSpec(kSmokeSpec), 2).id));
  EXPECT_EQ(RunCorpusVerify(one, true), 0);
  fs::remove_all(one);
  fs::remove_all(four);
}

TEST(CorpusGenerate, KilledShardKeepsItsEpisodesAndResumes) {
  const fs::path dir = TempDir("kill");
  const std::string tofu = TOFU_BINARY;
  const std::string out = dir.string();
  std::vector<std::string> args = {tofu, "corpus", "generate", kSmokeSpec, "--out", out, "--shard", "0/1", "--quiet"};
  std::vector<char*> argv;
  for (std::string& a : args) argv.push_back(a.data());
  argv.push_back(nullptr);
  pid_t pid = 0;
  ASSERT_EQ(posix_spawn(&pid, tofu.c_str(), nullptr, nullptr, argv.data(), environ), 0);
  // Kill it (SIGKILL: no handler, no clean-up) once its first episode is committed.
  const fs::path work = dir / ".shard_0000_of_0001";
  const auto committed = [&] {
    std::size_t n = 0;
    if (fs::is_directory(work)) {
      for (const auto& e : fs::directory_iterator(work)) n += e.path().extension() == ".h5";
    }
    return n;
  };
  const auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(120);
  while (committed() < 1 && std::chrono::steady_clock::now() < deadline) {
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
  }
  ::kill(pid, SIGKILL);
  int status = 0;
  ::waitpid(pid, &status, 0);
  const std::size_t kept = committed();
  ASSERT_GE(kept, 1u) << "no episode was committed before the kill";
  if (kept >= 4) GTEST_SKIP() << "the shard finished before it could be killed";
  EXPECT_FALSE(fs::exists(dir / "shard_0000_of_0001.h5")) << "a shard file appeared from a killed run";
  // What was committed is readable as it is.
  for (const auto& e : fs::directory_iterator(work)) {
    if (e.path().extension() != ".h5") continue;
    EXPECT_NO_THROW(Hdf5File::OpenReadOnly(e.path()).root().OpenGroup("episodes").Children()) << e.path();
  }
  EXPECT_EQ(RunCorpusVerify(dir, true), 1) << "verify passed an unfinished corpus";

  // The same shard again: only the missing episodes are flown.
  GenerateOptions options;
  options.spec = kSmokeSpec;
  options.out_dir = dir;
  options.quiet = true;
  std::size_t flown = 0;
  options.progress = [&](std::uint64_t, std::uint64_t, double) { ++flown; };
  ASSERT_EQ(RunCorpusGenerate(options), 0);
  EXPECT_EQ(flown, 4 - kept);
  EXPECT_EQ(RunCorpusVerify(dir, true), 0);
  // A resumed corpus equals one made in one go (the same episodes, bit for bit).
  const fs::path fresh = TempDir("fresh");
  options.out_dir = fresh;
  options.progress = nullptr;
  ASSERT_EQ(RunCorpusGenerate(options), 0);
  EXPECT_EQ(ReadText(dir / "manifest.csv").empty(), false);
  ASSERT_EQ(RunCorpusVerify(fresh, true), 0);
  EXPECT_EQ(ReadText(dir / "manifest.csv"), ReadText(fresh / "manifest.csv"));
  fs::remove_all(dir);
  fs::remove_all(fresh);
}

TEST(CorpusGenerate, ClosedLoopEpisodesStoreTheFlightFlownOnTheEstimate) {
  const fs::path dir = TempDir("closed");
  const fs::path spec = dir.string() + ".yaml";
  std::ofstream(spec) << SmokeWith("episodes: 4", "episodes: 1") << "closed_loop: {methods: [consensus]}\n";
  GenerateOptions options;
  options.spec = spec;
  options.out_dir = dir;
  options.quiet = true;
  ASSERT_EQ(RunCorpusGenerate(options), 0);
  ASSERT_EQ(RunCorpusVerify(dir, true), 0);
  const Hdf5File file = Hdf5File::OpenReadOnly(dir / "shard_0000_of_0001.h5");
  const Hdf5Group episode = file.root().OpenGroup("episodes").OpenGroup("smoke_e000000");
  EXPECT_NE(episode.StringAttribute("scenario_yaml").find("control: {state_source: estimate"), std::string::npos);
  const Hdf5Group flight = episode.OpenGroup("closed_loop").OpenGroup("consensus");
  EXPECT_EQ(flight.StringAttribute("method"), "consensus");
  const std::vector<double> flown = flight.OpenGroup("groundtruth").ReadDouble("p_WB_m");
  const std::vector<double> truth_flight = episode.OpenGroup("groundtruth").ReadDouble("p_WB_m");
  ASSERT_EQ(flown.size(), truth_flight.size());
  EXPECT_NE(flown, truth_flight) << "the flight on the estimate cannot be the ground-truth flight";
  fs::remove_all(dir);
  fs::remove(spec);
}

TEST(CorpusGenerate, RefusesAnotherSpecsDirectoryAndVerifyCatchesTampering) {
  const fs::path dir = TempDir("refuse");
  GenerateOptions options;
  options.spec = kSmokeSpec;
  options.out_dir = dir;
  options.quiet = true;
  options.shard = {1, 2};
  ASSERT_EQ(RunCorpusGenerate(options), 0);
  // Only half the corpus: verify names the missing episodes.
  EXPECT_EQ(RunCorpusVerify(dir, true), 1);

  // Another spec into the same directory: refused, nothing touched.
  const fs::path other = dir.string() + "_other.yaml";
  std::ofstream(other) << SmokeWith("seed: 7", "seed: 9");
  const auto before = fs::last_write_time(dir / "shard_0001_of_0002.h5");
  options.spec = other;
  EXPECT_THROW(RunCorpusGenerate(options), core::InputError);
  EXPECT_EQ(fs::last_write_time(dir / "shard_0001_of_0002.h5"), before);
  // Another shard count into the same directory: refused.
  options.spec = kSmokeSpec;
  options.shard = {0, 3};
  EXPECT_THROW(RunCorpusGenerate(options), core::InputError);

  // Complete it, then change one manifest row's hash: verify fails.
  options.shard = {0, 2};
  ASSERT_EQ(RunCorpusGenerate(options), 0);
  ASSERT_EQ(RunCorpusVerify(dir, true), 0);
  const fs::path part = dir / "shard_0000_of_0002.manifest.json";
  std::string text = ReadText(part);
  const std::size_t at = text.find("\"content_hash\": \"") + 17;
  text[at] = text[at] == '0' ? '1' : '0';
  std::ofstream(part) << text;
  EXPECT_EQ(RunCorpusVerify(dir, true), 1);
  fs::remove_all(dir);
  fs::remove(other);
}

}  // namespace
}  // namespace tofu::corpus
