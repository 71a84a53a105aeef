// `tofu check` across machines: bad shard options are exit 2 before anything runs; a
// 2 scenario x 2 seed grid run on one machine and as three shards (two sharing an --out,
// as on a cluster's shared file system) whose merge writes the same JUnit, method tables
// and report, with the same exit code; and the merge's refusals: a missing shard (naming
// its runs), a shard given twice, shards of another grid or partition.

#include <sys/wait.h>

#include <gtest/gtest.h>

#include <cstdlib>
#include <filesystem>
#include <string>
#include <utility>

#include <fmt/format.h>
#include <nlohmann/json.hpp>

#include "tests/test_support.h"

namespace tofu {
namespace {

namespace fs = std::filesystem;
using test::Quote;
using test::ReadFile;
using test::WriteFile;

class CheckShardTest : public ::testing::Test {
 protected:
  void SetUp() override {
    root_ = test::PerTestDirectory("tofu_check_shard_test_");
    fs::create_directories(root_);
    scenarios_ = Quote(SourcePath("tests/data/check_shard/a_hover_methods.yaml")) + " " +
                 Quote(SourcePath("tests/data/check_shard/b_hover_strict.yaml"));
  }
  void TearDown() override {
    if (!HasFailure()) fs::remove_all(root_);
  }

  static std::string SourcePath(const std::string& relative) {
    return (fs::path(TOFU_SOURCE_DIR) / relative).string();
  }

  // Runs `command` in the test's directory, capturing stdout and stderr.
  test::CommandResult Run(const std::string& command) {
    const fs::path out = root_ / "stdout.txt";
    const fs::path err = root_ / "stderr.txt";
    const std::string line = "cd " + Quote(root_.string()) + " && " + command + " >" +
                             Quote(out.string()) + " 2>" + Quote(err.string());
    const int status = std::system(line.c_str());
    test::CommandResult r;
    EXPECT_TRUE(WIFEXITED(status)) << line;
    r.exit_code = WIFEXITED(status) ? WEXITSTATUS(status) : -1;
    r.out = ReadFile(out);
    r.err = ReadFile(err);
    return r;
  }

  // `tofu check` of the test grid (2 scenarios x 2 seeds) with `args`.
  test::CommandResult Check(const std::string& args) {
    return Run(Quote(TOFU_BINARY) + " check " + scenarios_ + " --seeds 2 --quiet " + args);
  }

  fs::path root_;
  std::string scenarios_;
};

TEST_F(CheckShardTest, BadShardOptionsAreBadInputBeforeAnythingRuns) {
  for (const char* bad : {"0/0", "3/2", "a/b", "2/2"}) {
    const auto r = Check(std::string("--out out --shard ") + bad);
    EXPECT_EQ(r.exit_code, 2) << bad << r.err;
    EXPECT_CONTAINS(r.err, "--shard");
    EXPECT_CONTAINS(r.err, "expected I/N");
  }
  EXPECT_CONTAINS(Check("--out out --shard 0/2 --junit j.xml").err, "--junit");
  EXPECT_CONTAINS(Check("--out out --shard 0/2 --report r").err, "--report");
  EXPECT_CONTAINS(Check("--out out --shard 0/2 --merge out").err, "--merge");
  const auto slurm = Run("SLURM_ARRAY_TASK_ID=x SLURM_ARRAY_TASK_COUNT=2 " + Quote(TOFU_BINARY) +
                         " check " + scenarios_ + " --out out");
  EXPECT_EQ(slurm.exit_code, 2);
  EXPECT_CONTAINS(slurm.err, "SLURM_ARRAY_TASK_ID");
  EXPECT_FALSE(fs::exists(root_ / "out")) << "nothing is written on bad input";
}

TEST_F(CheckShardTest, ThreeShardsMergedWriteWhatOneMachineWrites) {
  // One machine. Its --out is then moved aside so that the merge writes to the same path:
  // the JUnit and the report name run directories by their absolute paths.
  const auto one = Check("--jobs 2 --out out --junit one.xml --report one_report");
  ASSERT_EQ(one.exit_code, 1) << "b_hover_strict fails in every seed\n" << one.err;
  fs::rename(root_ / "out", root_ / "one_out");

  // Shard 0 alone; shards 1 and 2 side by side in one --out, as on a shared file system.
  for (const auto& [shard, dir] :
       {std::pair{"0/3", "s0"}, std::pair{"1/3", "s12"}, std::pair{"2/3", "s12"}}) {
    const auto r = Check(fmt::format("--jobs 1 --out {} --shard {}", dir, shard));
    ASSERT_EQ(r.exit_code, 0) << shard << ": a shard's runs ended and are recorded\n" << r.err;
  }
  const auto record = nlohmann::json::parse(ReadFile(root_ / "s0/check_shard_0000_of_0003.json"));
  ASSERT_EQ(record["runs"].size(), 2u) << record.dump(2);  // cells 0 and 3 of 4
  EXPECT_EQ(record["runs"][0]["scenario"], "a_hover_methods");
  EXPECT_EQ(record["runs"][1]["scenario"], "b_hover_strict");
  EXPECT_FALSE(fs::exists(root_ / "s0/a_hover_methods/seed_2")) << "cell 1 is shard 1's";

  const auto merged =
      Check("--out out --junit merged.xml --report merged_report --merge s0 s12");
  EXPECT_EQ(merged.exit_code, one.exit_code) << merged.err;
  const std::string compare = "/usr/bin/python3 " +
                              Quote(SourcePath("tests/check_merge_compare.py")) +
                              " --junit one.xml merged.xml --out one_out out"
                              " --report one_report merged_report";
  const auto same = Run(compare);
  EXPECT_EQ(same.exit_code, 0) << same.out << same.err;
  EXPECT_CONTAINS(same.out, "merge equals one machine");
  EXPECT_TRUE(fs::is_regular_file(root_ / "out/methods.csv"));
  EXPECT_CONTAINS(ReadFile(root_ / "merged.xml"), "b_hover_strict/seed_2");

  // The comparison can fail: a run's value changed in the merged JUnit.
  std::string altered = ReadFile(root_ / "merged.xml");
  altered.replace(altered.find("seed 1: "), 8, "seed 1:  ");
  WriteFile(root_ / "merged.xml", altered);
  EXPECT_EQ(Run(compare).exit_code, 1);
}

TEST_F(CheckShardTest, MergeRefusesMissingRepeatedAndForeignShards) {
  // Two of three shards ran; no run is flown by the refusals below.
  ASSERT_EQ(Check("--jobs 1 --out s0 --shard 0/3").exit_code, 0);
  ASSERT_EQ(Check("--jobs 1 --out s1 --shard 1/3").exit_code, 0);

  const auto missing = Check("--out out --junit j.xml --merge s0 s1");
  EXPECT_EQ(missing.exit_code, 2) << missing.err;
  EXPECT_CONTAINS(missing.err, "shard 2/3: no check_shard_0002_of_0003.json");
  EXPECT_CONTAINS(missing.err, "missing b_hover_strict seed 1");
  EXPECT_FALSE(fs::exists(root_ / "j.xml"));
  EXPECT_FALSE(fs::exists(root_ / "out/a_hover_methods")) << "nothing copied";

  fs::copy(root_ / "s0", root_ / "s0_again", fs::copy_options::recursive);
  const auto twice = Check("--out out --merge s0 s0_again s1");
  EXPECT_EQ(twice.exit_code, 2);
  EXPECT_CONTAINS(twice.err, "shard 0/3 is also");

  const auto other_seeds = Run(Quote(TOFU_BINARY) + " check " + scenarios_ +
                               " --seeds 3 --out out --merge s0 s1");
  EXPECT_EQ(other_seeds.exit_code, 2);
  EXPECT_CONTAINS(other_seeds.err, "the shard ran --seeds 2, this merge has --seeds 3");

  const auto other_scenarios =
      Run(Quote(TOFU_BINARY) + " check " +
          Quote(SourcePath("tests/data/check_shard/a_hover_methods.yaml")) +
          " --seeds 2 --out out --merge s0");
  EXPECT_EQ(other_scenarios.exit_code, 2);
  EXPECT_CONTAINS(other_scenarios.err, "the shard ran [a_hover_methods, b_hover_strict]");

  // A shard of another partition (2-way) beside the 3-way ones.
  nlohmann::json record = nlohmann::json::parse(ReadFile(root_ / "s1/check_shard_0001_of_0003.json"));
  record["shard_count"] = 2;
  record["runs"] = nlohmann::json::array();
  fs::create_directories(root_ / "two_way");
  WriteFile(root_ / "two_way/check_shard_0001_of_0002.json", record.dump());
  const auto partitions = Check("--out out --merge s0 two_way");
  EXPECT_EQ(partitions.exit_code, 2);
  EXPECT_CONTAINS(partitions.err, "split the grid in different ways");
}

}  // namespace
}  // namespace tofu
