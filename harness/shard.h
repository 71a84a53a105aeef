#pragma once
// Work split across machines: which part of a deterministic list of work items this
// process does. One rule for every sharded command (`tofu corpus generate`, `tofu check`):
// shard I of N does the items i with i % N == I (round-robin over the list's order, so
// that each shard gets a share of every part of the list), and the shard comes from
// `--shard I/N`, a Slurm array task or a Kubernetes Indexed Job, in that order.

#include <cstdint>
#include <optional>
#include <string>
#include <utility>

namespace tofu::harness {

struct Shard {
  // A constructor rather than an aggregate: `{1, 4}` leaves the origin empty without a
  // missing-initializer warning.
  Shard(std::uint64_t shard_index = 0, std::uint64_t shard_count = 1, std::string source = {})
      : index(shard_index), count(shard_count), origin(std::move(source)) {}

  std::uint64_t index = 0;
  std::uint64_t count = 1;
  /// Where the shard came from ("--shard", "SLURM_ARRAY_TASK_ID/SLURM_ARRAY_TASK_COUNT",
  /// "JOB_COMPLETION_INDEX"); empty when none was given (the whole list, 0/1).
  std::string origin;

  /// Whether item `item` of the list is this shard's.
  bool Owns(std::uint64_t item) const { return item % count == index; }
};

/// The shard of this process: `--shard I/N` if given, else SLURM_ARRAY_TASK_ID and
/// SLURM_ARRAY_TASK_COUNT (a Slurm array job; SLURM_ARRAY_TASK_MIN is shard 0), else
/// JOB_COMPLETION_INDEX (a Kubernetes Indexed Job) with `shard_count`, else 0/1 with an
/// empty origin. Throws core::InputError for a malformed or out-of-range shard, naming
/// where it came from and the expected form.
Shard ResolveShard(const std::optional<std::string>& shard_arg,
                   const std::optional<std::uint64_t>& shard_count);

/// "shard_0001_of_0004": the stem of a shard's files.
std::string ShardStem(const Shard& shard);

}  // namespace tofu::harness
