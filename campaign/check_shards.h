#pragma once
// `tofu check` across machines. A check's grid is its scenarios (in check order) x its
// seeds; cell c is scenario c / seeds at seed (its seed + c % seeds), and shard I of N
// runs the cells with c % N == I (harness/shard.h). A shard writes its runs where one
// machine would (<out>/<scenario>/seed_<s>/ and seed_<s>.log) and, once every one of them
// has ended, its record <out>/check_shard_<I>_of_<N>.json: the grid (scenario names,
// content hashes, seeds) and each run's exit code, error and wall time, which the run
// directory alone does not hold. The merge reads the records of shards 0..N-1, gathers
// their runs into the merge's --out and hands back what one machine's pool would have
// left: the same runs with the same exit codes, so JUnit, method tables and report are
// one machine's.

#include <cstdint>
#include <filesystem>
#include <functional>
#include <map>
#include <string>
#include <vector>

#include "campaign/check_command.h"
#include "harness/scenario.h"
#include "harness/shard.h"

namespace tofu::campaign {

/// What one machine would run: two checks with equal grids give the same JUnit, method
/// tables and report (wall clock aside).
struct CheckGrid {
  struct Entry {
    std::string name;         ///< the scenario's name: its folder under --out
    uint64_t first_seed = 0;  ///< the scenario's seed; seeds first_seed + 0..seeds-1
    std::string fnv1a64;      ///< of the scenario file's text (hex): a changed file is another grid
  };
  std::vector<Entry> scenarios;
  int seeds = 1;

  uint64_t Cells() const { return scenarios.size() * static_cast<uint64_t>(seeds); }
  const Entry& ScenarioOf(uint64_t cell) const { return scenarios[cell / seeds]; }
  uint64_t SeedOf(uint64_t cell) const { return ScenarioOf(cell).first_seed + cell % seeds; }
  /// <out>/<scenario>/seed_<s>: where the run of `cell` lives (its log: + ".log").
  std::filesystem::path RunDirectory(const std::filesystem::path& out, uint64_t cell) const;
};

/// The grid of `scenarios` (loaded from their files, in check order) over `seeds`. Throws
/// core::InputError when a scenario file cannot be read again.
CheckGrid MakeCheckGrid(const std::vector<harness::Scenario>& scenarios, int seeds);

/// "check_shard_0001_of_0004.json": a shard's record, in its --out.
std::string ShardRecordName(const harness::Shard& shard);

/// What the pool learnt of a run that its directory does not say.
struct RecordedRun {
  int exit_code = -1;
  std::string error;  ///< before the summary was read (ReadSummary completes it)
  double wall_time_s = 0.0;
};

/// Writes <out>/ShardRecordName(shard) atomically: `grid` and `runs` (by cell; exactly
/// the shard's cells). Throws core::IoError when it cannot be written.
void WriteShardRecord(const std::filesystem::path& out, const harness::Shard& shard, const CheckGrid& grid,
                      const std::map<uint64_t, RecordedRun>& runs);

/// Before a shard runs: removes its own record (it describes an earlier attempt; only a
/// shard that finishes has one) and the records of other shard counts (another
/// partition, never part of this check). Without a shard (one machine): every record.
void RemoveShardRecords(const std::filesystem::path& out, const harness::Shard& shard);

/// Removes from a scenario's folder of a check the runs (seed_<s>/, seed_<s>.log) of the
/// seeds `stale` selects, and their staging directories that killed runs left
/// (seed_<s>.tmp-<pid> of a process that is gone). Touches nothing else: shards sharing
/// an --out each remove only their own seeds.
void RemoveStaleRuns(const std::filesystem::path& scenario_dir,
                     const std::function<bool(uint64_t seed)>& stale);

/// The merge: reads every record in `dirs` (each a shard's --out; one directory may hold
/// several shards' records when they shared it), checks that they are shards 0..N-1 of
/// `grid`, each exactly once, with every cell's run present, then copies (hard links when
/// it can) each run and its log into <out> where one machine would have written it
/// (nothing to copy when a dir is `out` itself) and removes runs of seeds outside the
/// grid from the grid's scenario folders. Returns every cell's RecordedRun. Throws
/// core::InputError (exit 2, nothing copied) naming the record or directory and the
/// problem: a missing shard (with the scenario/seed runs it would have held), a shard
/// found twice, a record of another grid or partition, a malformed record, a recorded run
/// whose files are gone.
std::map<uint64_t, RecordedRun> MergeShards(const std::vector<std::string>& dirs,
                                            const CheckGrid& grid,
                                            const std::filesystem::path& out);

}  // namespace tofu::campaign
