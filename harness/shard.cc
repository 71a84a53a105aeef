#include "harness/shard.h"

#include <algorithm>
#include <charconv>
#include <cstdlib>
#include <string_view>
#include <system_error>

#include <fmt/format.h>

#include "core/error.h"

namespace tofu::harness {
namespace {

std::optional<std::uint64_t> ParseWhole(std::string_view text) {
  std::uint64_t v = 0;
  const auto [end, ec] = std::from_chars(text.data(), text.data() + text.size(), v);
  if (ec != std::errc() || end != text.data() + text.size() || text.empty()) return std::nullopt;
  return v;
}

}  // namespace

Shard ResolveShard(const std::optional<std::string>& shard_arg,
                   const std::optional<std::uint64_t>& shard_count) {
  Shard shard;
  if (shard_arg) {
    shard.origin = "--shard";
    const std::size_t slash = shard_arg->find('/');
    const std::string_view text(*shard_arg);
    const auto index = slash == std::string::npos ? std::nullopt : ParseWhole(text.substr(0, slash));
    const auto count = slash == std::string::npos ? std::nullopt : ParseWhole(text.substr(slash + 1));
    if (!index || !count) {
      throw core::InputError({}, shard.origin,
                             fmt::format("expected I/N with whole numbers 0 <= I < N (e.g. 0/4), "
                                         "got '{}'",
                                         *shard_arg));
    }
    shard.index = *index;
    shard.count = *count;
  } else if (const char* id = std::getenv("SLURM_ARRAY_TASK_ID")) {
    shard.origin = "SLURM_ARRAY_TASK_ID/SLURM_ARRAY_TASK_COUNT";
    const char* count = std::getenv("SLURM_ARRAY_TASK_COUNT");
    const auto i = ParseWhole(id);
    const auto n = count ? ParseWhole(count) : std::nullopt;
    if (!i || !n) {
      throw core::InputError({}, shard.origin,
                             fmt::format("expected whole numbers, got '{}' and '{}'", id,
                                         count ? count : "(unset)"));
    }
    // `sbatch --array=A-B` numbers tasks from A; shards are counted from 0.
    const char* min = std::getenv("SLURM_ARRAY_TASK_MIN");
    const auto lo = min ? ParseWhole(min) : std::optional<std::uint64_t>(0);
    shard.index = *i - std::min(*i, lo.value_or(0));
    shard.count = *n;
  } else if (const char* k8s = std::getenv("JOB_COMPLETION_INDEX")) {
    shard.origin = "JOB_COMPLETION_INDEX";
    const auto i = ParseWhole(k8s);
    if (!i) {
      throw core::InputError({}, shard.origin,
                             fmt::format("expected a whole number, got '{}'", k8s));
    }
    if (!shard_count) {
      throw core::InputError({}, "--shard-count",
                             "JOB_COMPLETION_INDEX is set: give the job's completions as "
                             "--shard-count N");
    }
    shard.index = *i;
    shard.count = *shard_count;
  } else {
    return shard;
  }
  if (shard.count == 0 || shard.index >= shard.count) {
    throw core::InputError({}, shard.origin,
                           fmt::format("shard {}/{} is out of range: expected I/N with 0 <= I < N "
                                       "(e.g. 0/4)",
                                       shard.index, shard.count));
  }
  return shard;
}

std::string ShardStem(const Shard& shard) {
  return fmt::format("shard_{:04d}_of_{:04d}", shard.index, shard.count);
}

}  // namespace tofu::harness
