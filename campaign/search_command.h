#pragma once
// `tofu search SPEC --out DIR`: looks for failures of a base scenario's expectations over a
// spec's space (campaign/search.h), flying each point as a `tofu run` of the campaign's run
// pool, and writes what it found: evaluations.jsonl (every flight's margin, the journal a
// killed search resumes from), search.json, failures.md, and per failure its runnable
// scenario (shrunk towards the base), the scenario where it was found and its flight's run
// directory with renders. `--promote DIR` writes each confirmed failure as a regression
// scenario that `tofu check` flies and that fails until the cause is fixed.

#include <cstdint>
#include <optional>
#include <string>

#include "harness/shard.h"

namespace tofu::campaign {

struct SearchCommandOptions {
  std::string spec_path;
  std::string out_dir;
  int jobs = 0;  ///< flights at once (never changes what is flown: the batch is the spec's); 0: every core
  bool quiet = false;
  std::optional<std::string> promote_dir;
  bool renders = true;  ///< `tofu render` each failure's flight
  /// The spec's optimizer and its seed, overridden (repeated trials of one problem, as the
  /// benchmark flies them).
  std::optional<std::string> optimizer;
  std::optional<uint64_t> optimizer_seed;
  /// The `tofu` executable to spawn for each flight; empty: this process's.
  std::string tofu_binary;
  /// This process's shard of a search spread over machines (harness/shard.h: --shard, a
  /// Slurm array task): an independent search of budget / N flights, its optimiser seeded
  /// seed + I, into <out>/shard_<I>_of_<N>/. An empty origin: the whole search.
  harness::Shard shard;
  /// Fly nothing: merge the finished shards in <out> into <out>'s search.json,
  /// failures.md and failures/ (failures de-duplicated across shards), and promote.
  bool merge = false;
};

/// kExitOk when the search found no confirmed failure, kExitExpectationFailed when it
/// did, kExitBadInput for a bad spec, base scenario or options, or an --out directory
/// holding a search of another spec (nothing flown, nothing written).
int RunSearchCommand(const SearchCommandOptions& options);

}  // namespace tofu::campaign
