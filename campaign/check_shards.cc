#include "campaign/check_shards.h"

#include <algorithm>
#include <optional>
#include <set>
#include <string_view>
#include <system_error>

#include <fmt/format.h>
#include <nlohmann/json.hpp>

#include "core/error.h"
#include "core/file_io.h"
#include "core/hash.h"
#include "replay/file_io.h"
#include "replay/json_field.h"
#include "replay/interrupt.h"

namespace tofu::campaign {
namespace {

namespace fs = std::filesystem;
using core::InputError;
using nlohmann::json;

constexpr const char* kRecordFormat = "tofu check shard";
constexpr int kRecordVersion = 1;
constexpr const char* kRecordForm =
    "check_shard_<I>_of_<N>.json, what `tofu check --shard I/N --out DIR` writes once its "
    "runs are done";

// One shard's record as read back, with where it was found.
struct ShardRecord {
  fs::path file;
  fs::path dir;
  harness::Shard shard;
  int seeds = 0;
  std::vector<CheckGrid::Entry> scenarios;
  std::map<uint64_t, RecordedRun> runs;  // by cell
};

std::string ScenarioList(const std::vector<CheckGrid::Entry>& scenarios) {
  std::string list;
  for (const CheckGrid::Entry& e : scenarios) list += (list.empty() ? "" : ", ") + e.name;
  return "[" + list + "]";
}

// "a seed 2, b seed 1": the runs of `cells`, for an error message (the first 20).
std::string RunList(const CheckGrid& grid, const std::vector<uint64_t>& cells) {
  std::string list;
  for (size_t i = 0; i < cells.size() && i < 20; ++i) {
    list += fmt::format("{}{} seed {}", i == 0 ? "" : ", ", grid.ScenarioOf(cells[i]).name,
                        grid.SeedOf(cells[i]));
  }
  if (cells.size() > 20) list += fmt::format(" and {} more", cells.size() - 20);
  return list;
}

std::vector<uint64_t> CellsOf(const CheckGrid& grid, const harness::Shard& shard) {
  std::vector<uint64_t> cells;
  for (uint64_t c = 0; c < grid.Cells(); ++c) {
    if (shard.Owns(c)) cells.push_back(c);
  }
  return cells;
}

// A field of a record, with the record's name and the key when it is missing or of the
// wrong type.
template <typename T>
T Field(const json& object, const char* key, const fs::path& file, const char* expected) {
  return replay::JsonField<T>(object, key, file, fmt::format("{} ({})", expected, kRecordForm));
}

// The record's runs by cell; each must be a cell of `grid` that the record's shard owns.
std::map<uint64_t, RecordedRun> ReadRecordRuns(const json& runs, const ShardRecord& record,
                                               const CheckGrid& grid) {
  std::map<std::string, size_t> index_of;
  for (size_t i = 0; i < grid.scenarios.size(); ++i) index_of[grid.scenarios[i].name] = i;
  std::map<uint64_t, RecordedRun> out;
  for (const json& r : runs) {
    if (!r.is_object()) {
      throw InputError({record.file.string()}, "runs", "expected an array of objects");
    }
    const auto name = Field<std::string>(r, "scenario", record.file, "a scenario name");
    const auto seed = Field<uint64_t>(r, "seed", record.file, "a whole number");
    const auto it = index_of.find(name);
    const uint64_t first = it == index_of.end() ? 0 : grid.scenarios[it->second].first_seed;
    if (it == index_of.end() || seed < first || seed - first >= static_cast<uint64_t>(grid.seeds)) {
      throw InputError({record.file.string()}, "runs",
                       fmt::format("holds {} seed {}, which is not a run of this check's grid",
                                   name, seed));
    }
    const uint64_t cell = it->second * static_cast<uint64_t>(grid.seeds) + (seed - first);
    if (!record.shard.Owns(cell)) {
      throw InputError({record.file.string()}, "runs",
                       fmt::format("holds {} seed {}, which is shard {}/{}'s, not {}/{}'s", name,
                                   seed, cell % record.shard.count, record.shard.count,
                                   record.shard.index, record.shard.count));
    }
    RecordedRun run;
    run.exit_code = Field<int>(r, "exit_code", record.file, "an exit code");
    run.error = Field<std::string>(r, "error", record.file, "a string");
    run.wall_time_s = Field<double>(r, "wall_time_s", record.file, "a number of seconds");
    if (!out.emplace(cell, std::move(run)).second) {
      throw InputError({record.file.string()}, "runs",
                       fmt::format("holds {} seed {} twice", name, seed));
    }
  }
  return out;
}

// Whether the record was made for `grid`; else an InputError saying how it differs.
void RequireSameGrid(const ShardRecord& record, const CheckGrid& grid) {
  const std::string foreign =
      "a shard of another check: the merge must be given the scenarios and --seeds the "
      "shards ran with, and the --out of that check's shards only";
  if (record.seeds != grid.seeds) {
    throw InputError({record.file.string()}, "seeds",
                     fmt::format("the shard ran --seeds {}, this merge has --seeds {}: {}",
                                 record.seeds, grid.seeds, foreign));
  }
  const auto same_name = [](const CheckGrid::Entry& a, const CheckGrid::Entry& b) {
    return a.name == b.name;
  };
  if (!std::equal(record.scenarios.begin(), record.scenarios.end(), grid.scenarios.begin(),
                  grid.scenarios.end(), same_name)) {
    throw InputError({record.file.string()}, "scenarios",
                     fmt::format("the shard ran {}, this merge has {}: {}",
                                 ScenarioList(record.scenarios), ScenarioList(grid.scenarios),
                                 foreign));
  }
  for (size_t i = 0; i < grid.scenarios.size(); ++i) {
    const CheckGrid::Entry& mine = grid.scenarios[i];
    const CheckGrid::Entry& theirs = record.scenarios[i];
    if (mine.fnv1a64 != theirs.fnv1a64 || mine.first_seed != theirs.first_seed) {
      throw InputError({record.file.string()}, "scenarios",
                       fmt::format("scenario '{}' is not the file the shard ran (its text "
                                   "changed since): {}",
                                   mine.name, foreign));
    }
  }
}

ShardRecord ReadShardRecord(const fs::path& file, const CheckGrid& grid) {
  ShardRecord record;
  record.file = file;
  record.dir = file.parent_path();
  json doc;
  try {
    doc = json::parse(core::ReadWholeFile(file, "shard record"));
  } catch (const json::exception& e) {
    throw InputError({file.string()}, "", fmt::format("not JSON ({}): expected {}", e.what(),
                                                      kRecordForm));
  }
  if (!doc.is_object() || doc.value("format", "") != kRecordFormat ||
      doc.value("version", 0) != kRecordVersion) {
    throw InputError({file.string()}, "format",
                     fmt::format("expected \"{}\" version {} ({})", kRecordFormat, kRecordVersion,
                                 kRecordForm));
  }
  record.shard.index = Field<uint64_t>(doc, "shard_index", file, "a whole number");
  record.shard.count = Field<uint64_t>(doc, "shard_count", file, "a whole number");
  if (record.shard.count == 0 || record.shard.index >= record.shard.count) {
    throw InputError({file.string()}, "shard_index",
                     fmt::format("shard {}/{} is out of range (expected 0 <= I < N)",
                                 record.shard.index, record.shard.count));
  }
  record.seeds = Field<int>(doc, "seeds", file, "a whole number");
  for (const json& s : Field<json>(doc, "scenarios", file, "an array")) {
    if (!s.is_object()) throw InputError({file.string()}, "scenarios", "expected objects");
    record.scenarios.push_back({Field<std::string>(s, "name", file, "a scenario name"),
                                Field<uint64_t>(s, "first_seed", file, "a whole number"),
                                Field<std::string>(s, "fnv1a64", file, "a hash")});
  }
  RequireSameGrid(record, grid);
  const json runs = Field<json>(doc, "runs", file, "an array");
  if (!runs.is_array()) throw InputError({file.string()}, "runs", "expected an array");
  record.runs = ReadRecordRuns(runs, record, grid);
  return record;
}

// Every record in the given directories (a directory named twice is read once), each one
// a distinct shard of one partition of `grid`.
std::vector<ShardRecord> ReadShardRecords(const std::vector<std::string>& dirs,
                                          const CheckGrid& grid) {
  std::vector<ShardRecord> records;
  std::set<fs::path> seen;
  for (const std::string& dir : dirs) {
    std::error_code ec;
    if (!fs::is_directory(dir, ec)) {
      throw InputError({dir}, "--merge",
                       "no such directory: expected the --out of a `tofu check --shard I/N`");
    }
    if (!seen.insert(fs::canonical(dir)).second) continue;
    std::vector<fs::path> files;
    for (const auto& entry : fs::directory_iterator(dir)) {
      const std::string name = entry.path().filename().string();
      if (name.starts_with("check_shard_") && name.ends_with(".json")) files.push_back(entry.path());
    }
    if (files.empty()) {
      throw InputError({dir}, "--merge",
                       fmt::format("holds no shard record: expected {}; a shard that did not "
                                   "finish has none",
                                   kRecordForm));
    }
    std::sort(files.begin(), files.end());
    for (const fs::path& file : files) records.push_back(ReadShardRecord(file, grid));
  }
  std::map<uint64_t, const ShardRecord*> by_index;
  for (const ShardRecord& r : records) {
    if (r.shard.count != records.front().shard.count) {
      throw InputError({r.file.string()}, "shard_count",
                       fmt::format("shard {}/{} and {} (shard {}/{}) split the grid in different "
                                   "ways: give the shards of one partition",
                                   r.shard.index, r.shard.count, records.front().file.string(),
                                   records.front().shard.index, records.front().shard.count));
    }
    const auto [it, inserted] = by_index.emplace(r.shard.index, &r);
    if (!inserted) {
      throw InputError({r.file.string()}, "shard_index",
                       fmt::format("shard {}/{} is also {}: each shard must be merged once",
                                   r.shard.index, r.shard.count, it->second->file.string()));
    }
  }
  return records;
}

// An InputError listing the shards of the partition that no record holds and the runs
// they would have held, and the runs a present record lacks; nothing when all are there.
void RequireEveryRun(const std::vector<ShardRecord>& records, const CheckGrid& grid,
                     const std::vector<std::string>& dirs) {
  const uint64_t count = records.front().shard.count;
  std::map<uint64_t, const ShardRecord*> by_index;
  for (const ShardRecord& r : records) by_index[r.shard.index] = &r;
  std::string problems;
  for (uint64_t index = 0; index < count; ++index) {
    const harness::Shard shard(index, count);
    const auto it = by_index.find(index);
    std::vector<uint64_t> missing;
    for (const uint64_t cell : CellsOf(grid, shard)) {
      if (it == by_index.end() || !it->second->runs.contains(cell)) missing.push_back(cell);
    }
    if (missing.empty()) continue;
    std::string dir_list;
    for (const std::string& d : dirs) dir_list += (dir_list.empty() ? "" : ", ") + d;
    problems += it == by_index.end()
                    ? fmt::format("\n  shard {}/{}: no {} in {} (did it finish?): missing {}",
                                  index, count, ShardRecordName(shard), dir_list,
                                  RunList(grid, missing))
                    : fmt::format("\n  shard {}/{} ({}): its record lacks {}", index, count,
                                  it->second->file.string(), RunList(grid, missing));
  }
  if (!problems.empty()) {
    throw InputError({}, "--merge",
                     "runs of the grid are missing, expected every shard 0..N-1 of one "
                     "partition:" + problems);
  }
}

// `from` (a directory or a file) at `to`, hard-linked when the file system allows it
// (runs are never written after they end), else copied; staged, so that `to` is whole or
// absent. An earlier `to` is replaced.
void PlaceCopy(const fs::path& from, const fs::path& to) {
  const fs::path staging = replay::StagingPath(to);
  fs::remove_all(staging);
  const auto options = fs::copy_options::recursive | fs::copy_options::copy_symlinks;
  std::error_code ec;
  fs::copy(from, staging, options | fs::copy_options::create_hard_links, ec);
  if (ec) {
    fs::remove_all(staging);
    fs::copy(from, staging, options);
  }
  fs::remove_all(to);
  fs::rename(staging, to);
}

}  // namespace

fs::path CheckGrid::RunDirectory(const fs::path& out, uint64_t cell) const {
  return out / ScenarioOf(cell).name / fmt::format("seed_{}", SeedOf(cell));
}

CheckGrid MakeCheckGrid(const std::vector<harness::Scenario>& scenarios, int seeds) {
  CheckGrid grid;
  grid.seeds = seeds;
  for (const harness::Scenario& s : scenarios) {
    const std::string text = core::ReadWholeFile(s.source_file, "scenario file");
    grid.scenarios.push_back({s.name, s.seed, fmt::format("{:016x}", core::Fnv1a64(text))});
  }
  return grid;
}

std::string ShardRecordName(const harness::Shard& shard) {
  return "check_" + harness::ShardStem(shard) + ".json";
}

void WriteShardRecord(const fs::path& out, const harness::Shard& shard, const CheckGrid& grid,
                      const std::map<uint64_t, RecordedRun>& runs) {
  // In reading order, for the person who opens it.
  using ordered = nlohmann::ordered_json;
  ordered doc = {{"format", kRecordFormat},    {"version", kRecordVersion},
                 {"shard_index", shard.index}, {"shard_count", shard.count},
                 {"seeds", grid.seeds},        {"scenarios", ordered::array()},
                 {"runs", ordered::array()}};
  for (const CheckGrid::Entry& e : grid.scenarios) {
    doc["scenarios"].push_back(
        {{"name", e.name}, {"first_seed", e.first_seed}, {"fnv1a64", e.fnv1a64}});
  }
  for (const auto& [cell, run] : runs) {
    doc["runs"].push_back({{"scenario", grid.ScenarioOf(cell).name},
                           {"seed", grid.SeedOf(cell)},
                           {"exit_code", run.exit_code},
                           {"error", run.error},
                           {"wall_time_s", run.wall_time_s}});
  }
  replay::WriteFileAtomically(out / ShardRecordName(shard), doc.dump(2) + "\n", "--out");
}

void RemoveShardRecords(const fs::path& out, const harness::Shard& shard) {
  std::error_code ec;
  const std::string own = ShardRecordName(shard);
  const std::string same_count = fmt::format("_of_{:04d}.json", shard.count);
  std::vector<fs::path> stale;
  for (fs::directory_iterator it(out, ec), end; !ec && it != end; it.increment(ec)) {
    const std::string name = it->path().filename().string();
    if (!name.starts_with("check_shard_") || !name.ends_with(".json")) continue;
    // Shards of this partition running beside this one keep theirs.
    if (!shard.origin.empty() && name != own && name.ends_with(same_count)) continue;
    stale.push_back(it->path());
  }
  for (const fs::path& path : stale) fs::remove(path);
}

void RemoveStaleRuns(const fs::path& scenario_dir, const std::function<bool(uint64_t)>& stale) {
  std::error_code ec;
  if (!fs::is_directory(scenario_dir, ec)) return;
  // seed_<n>, seed_<n>.log, seed_<n>.tmp-<pid>: the seed, or nothing for any other name.
  const auto seed_of = [](std::string_view name) -> std::optional<uint64_t> {
    if (!name.starts_with("seed_")) return std::nullopt;
    name.remove_prefix(5);
    if (const size_t tmp = name.find(".tmp-"); tmp != std::string_view::npos) {
      name = name.substr(0, tmp);
    } else if (name.ends_with(".log")) {
      name.remove_suffix(4);
    }
    if (name.empty() || name.size() > 19 ||
        !std::all_of(name.begin(), name.end(), [](char c) { return c >= '0' && c <= '9'; })) {
      return std::nullopt;
    }
    return std::stoull(std::string(name));
  };
  std::vector<fs::path> runs;  // collected first: no removal while the directory is read
  std::set<fs::path> staged;
  for (const auto& entry : fs::directory_iterator(scenario_dir)) {
    const std::string name = entry.path().filename().string();
    const auto seed = seed_of(name);
    if (!seed || !stale(*seed)) continue;
    if (const size_t tmp = name.find(".tmp-"); tmp != std::string::npos) {
      staged.insert(scenario_dir / name.substr(0, tmp));
    } else {
      runs.push_back(entry.path());
    }
  }
  for (const fs::path& path : runs) fs::remove_all(path);
  for (const fs::path& run : staged) replay::SweepStaleStaging(run);
}

std::map<uint64_t, RecordedRun> MergeShards(const std::vector<std::string>& dirs,
                                            const CheckGrid& grid, const fs::path& out) {
  const std::vector<ShardRecord> records = ReadShardRecords(dirs, grid);
  RequireEveryRun(records, grid, dirs);
  // Every recorded run's files must be there before anything is copied. A run always has
  // its log (the check opens it before the run starts); its directory only if it made one.
  for (const ShardRecord& r : records) {
    for (const auto& [cell, run] : r.runs) {
      const fs::path log = grid.RunDirectory(r.dir, cell).string() + ".log";
      if (!fs::is_regular_file(log)) {
        throw InputError({r.file.string()}, "runs",
                         fmt::format("records {} seed {}, but its log {} is gone (a partial copy "
                                     "of the shard's --out?)",
                                     grid.ScenarioOf(cell).name, grid.SeedOf(cell), log.string()));
      }
    }
  }
  std::map<uint64_t, RecordedRun> runs;
  std::error_code ec;
  const fs::path out_key = fs::weakly_canonical(out, ec);
  for (const ShardRecord& r : records) {
    const bool in_place = fs::weakly_canonical(r.dir, ec) == out_key;
    for (const auto& [cell, run] : r.runs) {
      replay::ThrowIfInterrupted();
      if (!in_place) {
        const fs::path from = grid.RunDirectory(r.dir, cell);
        const fs::path to = grid.RunDirectory(out, cell);
        fs::create_directories(to.parent_path());
        fs::remove_all(to);
        if (fs::exists(from)) PlaceCopy(from, to);
        PlaceCopy(from.string() + ".log", to.string() + ".log");
      }
      runs.emplace(cell, run);
    }
  }
  // Seeds of an earlier, larger check in the same folders would show in the report.
  for (const CheckGrid::Entry& e : grid.scenarios) {
    RemoveStaleRuns(out / e.name, [&](uint64_t seed) {
      return seed < e.first_seed || seed - e.first_seed >= static_cast<uint64_t>(grid.seeds);
    });
  }
  return runs;
}

}  // namespace tofu::campaign
