// harness/shard.h: where a shard comes from (--shard, then a Slurm array task, then a
// Kubernetes Indexed Job), what a bad one says (the source and the form I/N), and the
// round-robin rule that gives every item to exactly one shard.

#include <gtest/gtest.h>

#include <cstdint>
#include <cstdlib>
#include <optional>
#include <string>

#include "core/error.h"
#include "harness/shard.h"
#include "tests/test_support.h"

namespace tofu {
namespace {

using harness::ResolveShard;
using harness::Shard;

// The InputError's text for a shard, or "" when there is none.
std::string ShardError(const std::optional<std::string>& arg,
                       const std::optional<std::uint64_t>& count = std::nullopt) {
  try {
    ResolveShard(arg, count);
  } catch (const core::InputError& e) {
    return e.what();
  }
  return "";
}

TEST(Shard, ComesFromTheFlagThenSlurmThenKubernetes) {
  const Shard flag = ResolveShard(std::string("2/5"), std::nullopt);
  EXPECT_EQ(flag.index, 2u);
  EXPECT_EQ(flag.count, 5u);
  EXPECT_EQ(flag.origin, "--shard");
  ::setenv("SLURM_ARRAY_TASK_ID", "4", 1);
  ::setenv("SLURM_ARRAY_TASK_COUNT", "3", 1);
  ::setenv("SLURM_ARRAY_TASK_MIN", "3", 1);  // --array=3-5
  const Shard slurm = ResolveShard(std::nullopt, std::nullopt);
  EXPECT_EQ(slurm.index, 1u);
  EXPECT_EQ(slurm.count, 3u);
  EXPECT_EQ(ResolveShard(std::string("0/2"), std::nullopt).count, 2u) << "the flag wins";
  ::unsetenv("SLURM_ARRAY_TASK_ID");
  ::unsetenv("SLURM_ARRAY_TASK_COUNT");
  ::unsetenv("SLURM_ARRAY_TASK_MIN");
  ::setenv("JOB_COMPLETION_INDEX", "2", 1);
  EXPECT_CONTAINS(ShardError(std::nullopt), "--shard-count");
  EXPECT_EQ(ResolveShard(std::nullopt, 4).index, 2u);
  EXPECT_CONTAINS(ShardError(std::nullopt, 2), "JOB_COMPLETION_INDEX");  // 2 >= 2
  ::unsetenv("JOB_COMPLETION_INDEX");
  const Shard none = ResolveShard(std::nullopt, std::nullopt);
  EXPECT_EQ(none.count, 1u);
  EXPECT_TRUE(none.origin.empty());
}

TEST(Shard, BadValuesNameTheFlagAndTheExpectedForm) {
  for (const char* bad : {"0/0", "3/2", "2/2", "a/b", "1-4", "/2", "1/", "-1/2", ""}) {
    const std::string error = ShardError(std::string(bad));
    EXPECT_CONTAINS(error, "--shard");
    EXPECT_CONTAINS(error, "expected I/N");
    EXPECT_CONTAINS(error, "0 <= I < N");
  }
}

TEST(Shard, EveryItemBelongsToExactlyOneShardRoundRobin) {
  for (uint64_t item = 0; item < 10; ++item) {
    int owners = 0;
    for (uint64_t index = 0; index < 3; ++index) {
      owners += Shard(index, 3).Owns(item);
    }
    EXPECT_EQ(owners, 1) << item;
    EXPECT_TRUE(Shard(item % 3, 3).Owns(item));
  }
}

}  // namespace
}  // namespace tofu
