#include "corpus/corpus_command.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <fstream>
#include <map>
#include <set>
#include <system_error>

#include <fmt/format.h>
#include <nlohmann/json.hpp>

#include "core/error.h"
#include "core/file_io.h"
#include "core/version.h"
#include "corpus/corpus_spec.h"
#include "corpus/episode_writer.h"
#include "corpus/hdf5_file.h"
#include "harness/run.h"
#include "harness/scenario.h"
#include "replay/file_io.h"
#include "replay/replay.h"
#include "replay/trajectory_metrics.h"
#include "sim/faults.h"
#include "sim/sensor.h"

namespace tofu::corpus {
namespace {

namespace fs = std::filesystem;

constexpr const char* kSpecFile = "corpus.yaml";
// The included scenarios (corpus_spec.h), copied: the directory stands alone.
constexpr const char* kIncludedDir = "included";
constexpr int kSchemaVersion = 1;

// The corpus directory for `spec`: created with corpus.yaml, or an existing one made
// from the very same spec text. Anything else is refused (exit 2), untouched.
void PrepareCorpusDirectory(const CorpusSpec& spec, const fs::path& dir) {
  const fs::path spec_copy = dir / kSpecFile;
  if (fs::exists(dir) && !fs::is_directory(dir)) {
    throw core::InputError({dir.string()}, "--out", "exists and is not a directory");
  }
  if (fs::exists(spec_copy)) {
    if (core::ReadWholeFile(spec_copy, "corpus spec") != spec.text) {
      throw core::InputError({dir.string()}, "--out",
                             fmt::format("holds the shards of another spec ({} differs from {}); "
                                         "use another directory", spec_copy.string(), spec.file));
    }
    CopyIncluded(spec, dir / kIncludedDir);
    return;
  }
  // The shards of one array job start together: another may be writing corpus.yaml right
  // now (its corpus.yaml.partial<pid>, WriteAtomically) or the included copies before it,
  // which are no foreign content.
  const std::string spec_partial = std::string(kSpecFile) + ".partial";
  const auto holds_foreign_files = [&] {
    for (const fs::directory_entry& entry : fs::directory_iterator(dir)) {
      const std::string name = entry.path().filename().string();
      if (!name.starts_with(spec_partial) && name != kIncludedDir) return true;
    }
    return false;
  };
  if (fs::exists(dir) && holds_foreign_files()) {
    throw core::InputError({dir.string()}, "--out",
                           "is not empty and not a corpus directory (no corpus.yaml): refused, untouched");
  }
  fs::create_directories(dir);
  CopyIncluded(spec, dir / kIncludedDir);
  replay::WriteFileAtomically(spec_copy, spec.text);  // concurrent shards write the same bytes
}

std::vector<std::uint64_t> ShardEpisodes(const CorpusSpec& spec, const Shard& shard) {
  std::vector<std::uint64_t> episodes;
  for (std::uint64_t i = 0; i < spec.episodes; ++i) {
    if (shard.Owns(i)) episodes.push_back(i);
  }
  return episodes;
}

std::string FormatDuration(double s) {
  if (!std::isfinite(s) || s < 0) return "?";
  const int total = static_cast<int>(std::lround(s));
  return total >= 3600 ? fmt::format("{}h{:02d}m", total / 3600, (total / 60) % 60)
                       : fmt::format("{}m{:02d}s", total / 60, total % 60);
}

std::vector<std::string> MethodsOf(const std::vector<ManifestRow>& rows) {
  std::set<std::string> methods;
  for (const ManifestRow& r : rows) {
    for (const auto& [m, v] : r.ate_m) methods.insert(m);
  }
  return {methods.begin(), methods.end()};
}

// The manifest's scores, in memory: each in-loop method's ATE after SE(3) alignment
// against the exact ground truth of the IMU frame (T_WI = T_WB T_BI at the IMU's true
// mount), by the functions `tofu run` scores with. Writing the run directory to score it
// would cost more than the flight (docs/BENCHMARKS.md, "Corpora").
nlohmann::json ScoreMethods(const harness::RunRecord& record) {
  Eigen::Isometry3d T_BI = Eigen::Isometry3d::Identity();
  for (const harness::SensorStream& s : record.sensors) {
    if (s.kind != core::MeasurementKind::kImu) continue;
    if (const sim::MountSite* site = record.robot.FindSite(s.site)) {
      T_BI.linear() = site->q_Bs.toRotationMatrix();
      T_BI.translation() = site->p_Bs;
    }
    break;
  }
  std::vector<replay::PoseSample> truth;
  for (const sim::TruthState& g : record.groundtruth) {
    Eigen::Isometry3d T_WB = Eigen::Isometry3d::Identity();
    T_WB.linear() = g.q_WB.toRotationMatrix();
    T_WB.translation() = g.p_WB;
    const Eigen::Isometry3d T_WI = T_WB * T_BI;
    truth.push_back({g.t_ns, T_WI.translation(), Eigen::Quaterniond(T_WI.linear()).normalized()});
  }
  nlohmann::json methods = nlohmann::json::object();
  for (const replay::ReplayResult& r : record.in_loop) {
    const std::vector<replay::PoseSample> estimate = replay::OutputTrajectory(r);
    nlohmann::json m = nlohmann::json::object();
    if (estimate.size() > 10 && truth.size() > 10) {
      m["ate_m"] = replay::EvaluateTrajectory(estimate, truth).ate_position_rmse_m;
    }
    methods[r.method.name] = m;
  }
  return {{"methods", methods}};
}

// Flies one episode and commits it as its own HDF5 file.
ManifestRow GenerateEpisode(const CorpusSpec& spec, const EpisodePlan& plan, const fs::path& work) {
  const harness::Scenario scenario =
      harness::ParseScenario(plan.scenario_yaml, fmt::format("{} episode {}", spec.file, plan.index));
  const harness::RunRecord record = harness::Simulate(scenario);
  if (record.failure) {
    throw core::SimulationError(fmt::format("episode {} ({}): {}", plan.index, plan.id, *record.failure));
  }
  const nlohmann::json summary = ScoreMethods(record);

  const fs::path partial = work / (plan.id + ".h5.partial");
  const fs::path committed = work / (plan.id + ".h5");
  ManifestRow row;
  {
    Hdf5File file = Hdf5File::Create(partial);
    const Hdf5Group episodes = file.root().CreateGroup("episodes");
    row = WriteEpisode(episodes, plan, record, summary);
    file.Close();
  }
  std::error_code ec;
  fs::rename(partial, committed, ec);
  if (ec) throw core::IoError(fmt::format("cannot commit {}: {}", committed.string(), ec.message()));
  return row;
}

void SetCorpusAttributes(const Hdf5Group& root, const CorpusSpec& spec, const Shard& shard) {
  root.SetAttribute("corpus", spec.name);
  root.SetAttribute("corpus_seed", std::to_string(spec.seed));
  root.SetAttribute("episodes_planned", static_cast<std::int64_t>(spec.episodes));
  root.SetAttribute("spec_yaml", spec.text);
  root.SetAttribute("shard_index", static_cast<std::int64_t>(shard.index));
  root.SetAttribute("shard_count", static_cast<std::int64_t>(shard.count));
  root.SetAttribute("schema_version", static_cast<std::int64_t>(kSchemaVersion));
  root.SetAttribute("tofu_version", core::TofuVersion());
  root.SetAttribute("tofu_commit", core::TofuCommit());
}

}  // namespace

int RunCorpusPlan(const fs::path& spec_path, const fs::path& out_dir, bool quiet) {
  const CorpusSpec spec = LoadCorpusSpec(spec_path);
  if (fs::exists(out_dir) && !fs::is_empty(out_dir) && !fs::exists(out_dir / "plan.json")) {
    throw core::InputError({out_dir.string()}, "--out", "is not empty and not a corpus plan (no plan.json): refused, untouched");
  }
  const fs::path staging = out_dir.string() + ".partial";
  fs::remove_all(staging);
  fs::create_directories(staging / "episodes");
  // Planned label counts: fault kind x sensor (scheduled faults; physical ones happen in
  // flight and are counted by `generate`).
  std::map<std::string, std::map<std::string, int>> counts;
  std::map<std::string, int> families, worlds;
  double flight_s = 0.0;
  for (std::uint64_t i = 0; i < spec.episodes; ++i) {
    const EpisodePlan plan = PlanEpisode(spec, i);
    flight_s += plan.duration_s;
    harness::ParseScenario(plan.scenario_yaml, fmt::format("{} episode {}", spec.file, i));
    std::ofstream(staging / "episodes" / (plan.id + ".yaml"), std::ios::binary) << plan.scenario_yaml;
    for (const PlannedFault& f : plan.faults) ++counts[std::string(sim::FaultKindName(f.kind))][f.sensor];
    ++families[plan.family];
    ++worlds[plan.world];
  }
  nlohmann::ordered_json j = {{"corpus", spec.name},
                              {"seed", spec.seed},
                              {"episodes", spec.episodes},
                              {"flight_hours", flight_s / 3600.0},
                              {"scheduled_faults", counts},
                              {"families", families},
                              {"worlds", worlds}};
  std::ofstream(staging / "plan.json") << j.dump(2) << "\n";
  fs::remove_all(out_dir);
  fs::rename(staging, out_dir);
  if (!quiet) {
    fmt::print("planned {} episodes of '{}' into {}/episodes ({:.2f} h of flight)\n", spec.episodes, spec.name,
               out_dir.string(), j["flight_hours"].get<double>());
    for (const auto& [kind, per_sensor] : counts) {
      for (const auto& [sensor, n] : per_sensor) fmt::print("  {:<20} {:<10} {}\n", kind, sensor, n);
    }
  }
  return core::kExitOk;
}

int RunCorpusGenerate(const GenerateOptions& options) {
  const CorpusSpec spec = LoadCorpusSpec(options.spec);
  PrepareCorpusDirectory(spec, options.out_dir);
  const Shard shard = options.shard;
  const std::string stem = harness::ShardStem(shard);
  const fs::path shard_file = options.out_dir / (stem + ".h5");
  const fs::path manifest_part = options.out_dir / (stem + ".manifest.json");
  // Another layout's shards in the same directory would hold the same episodes twice.
  for (const auto& entry : fs::directory_iterator(options.out_dir)) {
    const std::string name = entry.path().filename().string();
    if (name.rfind("shard_", 0) == 0 && name.ends_with(".h5") && name.find(fmt::format("_of_{:04d}", shard.count)) == std::string::npos) {
      throw core::InputError({options.out_dir.string()}, "--shard",
                             fmt::format("the directory holds {} of another shard count than {}: use one layout per directory",
                                         name, shard.count));
    }
  }
  if (fs::exists(shard_file) && fs::exists(manifest_part)) {
    if (!options.quiet) fmt::print("{}: already complete ({})\n", stem, shard_file.string());
    return core::kExitOk;
  }
  const fs::path work = options.out_dir / ("." + stem);
  fs::create_directories(work);
  // Leftovers of a killed run: half-written episodes.
  for (const auto& entry : fs::directory_iterator(work)) {
    const std::string name = entry.path().filename().string();
    if (name.ends_with(".partial")) fs::remove_all(entry.path());
  }

  const std::vector<std::uint64_t> episodes = ShardEpisodes(spec, shard);
  std::uint64_t done = 0, resumed = 0, committed_now = 0;
  const auto t0 = std::chrono::steady_clock::now();
  for (const std::uint64_t i : episodes) {
    const EpisodePlan plan = PlanEpisode(spec, i);
    if (fs::exists(work / (plan.id + ".h5"))) {
      ++done;
      ++resumed;
      continue;
    }
    const ManifestRow row = GenerateEpisode(spec, plan, work);
    ++done;
    ++committed_now;
    const double elapsed = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    if (options.progress) options.progress(done, episodes.size(), elapsed);
    if (!options.quiet) {
      const double rate = static_cast<double>(committed_now) / std::max(elapsed, 1e-9);
      const double eta = static_cast<double>(episodes.size() - done) / std::max(rate, 1e-9);
      fmt::print("{} {}/{} {} ({}, {}, {} faults, {} physical events) {:.1f} episodes/min, ETA {}\n", stem, done,
                 episodes.size(), plan.id, plan.world, plan.family, row.scheduled_faults, row.physical_events,
                 rate * 60.0, FormatDuration(eta));
      std::fflush(stdout);
    }
  }

  // Assemble the shard: every committed episode copied into one file, renamed into place.
  const fs::path partial = shard_file.string() + ".partial";
  nlohmann::ordered_json rows = nlohmann::ordered_json::array();
  {
    Hdf5File file = Hdf5File::Create(partial);
    SetCorpusAttributes(file.root(), spec, shard);
    file.root().CreateGroup("episodes");
    for (const std::uint64_t i : episodes) {
      const EpisodePlan plan = PlanEpisode(spec, i);
      Hdf5File episode = Hdf5File::OpenReadOnly(work / (plan.id + ".h5"));
      file.CopyFrom(episode, "/episodes/" + plan.id, "/episodes/" + plan.id);
      ManifestRow row = ReadManifestRow(episode.root().OpenGroup("episodes").OpenGroup(plan.id));
      row.shard = fmt::format("{}/{}", shard.index, shard.count);
      rows.push_back(ManifestJson(row));
    }
    file.Close();
  }
  std::error_code ec;
  fs::rename(partial, shard_file, ec);
  if (ec) throw core::IoError(fmt::format("cannot write {}: {}", shard_file.string(), ec.message()));
  replay::WriteFileAtomically(manifest_part, rows.dump(1) + "\n");
  fs::remove_all(work);
  if (!options.quiet) {
    fmt::print("{}: {} episodes ({} resumed) in {}\n", stem, episodes.size(), resumed, shard_file.string());
  }
  return core::kExitOk;
}

namespace {

// The events of an episode must agree with its per-sample masks: every sample inside a
// (sensor, kind) event window carries the bit, every sample carrying it lies in one.
std::vector<std::string> CheckEventsAgainstMasks(const Hdf5Group& episode) {
  std::vector<std::string> problems;
  const Hdf5Group events = episode.OpenGroup("events");
  const std::vector<std::string> sensor = events.ReadStrings("sensor");
  const std::vector<std::string> kind = events.ReadStrings("kind");
  const std::vector<std::string> cause = events.ReadStrings("cause");
  const std::vector<std::int64_t> onset = events.ReadInt64("onset_ns");
  const std::vector<std::int64_t> offset = events.ReadInt64("offset_ns");
  const std::vector<std::uint8_t> open = events.ReadUInt8("open");
  const Hdf5Group sensors = episode.OpenGroup("sensors");
  for (const std::string& name : sensors.Children()) {
    const Hdf5Group s = sensors.OpenGroup(name);
    const std::vector<std::int64_t> t = s.ReadInt64("t_ns");
    const std::vector<std::uint32_t> faults = s.ReadUInt32("fault_mask");
    const std::vector<std::uint32_t> conditions = s.ReadUInt32("condition_mask");
    const auto check = [&](const std::string& label, std::uint32_t bit, bool is_fault) {
      const std::vector<std::uint32_t>& mask = is_fault ? faults : conditions;
      std::size_t outside = 0, missing = 0;
      for (std::size_t k = 0; k < t.size(); ++k) {
        bool inside = false;
        for (std::size_t e = 0; e < sensor.size(); ++e) {
          if (sensor[e] != name || kind[e] != label || (cause[e] == "scheduled") != is_fault) continue;
          if (t[k] >= onset[e] && (t[k] < offset[e] || open[e])) inside = true;
        }
        const bool set = (mask[k] & bit) != 0;
        if (set && !inside) ++outside;
        if (!set && inside) ++missing;
      }
      if (outside + missing > 0) {
        problems.push_back(fmt::format("{}: sensor {} {} '{}': {} samples flagged outside its events, {} inside unflagged",
                                       episode.path(), name, is_fault ? "fault" : "condition", label, outside, missing));
      }
    };
    for (const sim::FaultKind k : sim::AllFaultKinds()) check(std::string(sim::FaultKindName(k)), sim::FaultBit(k), true);
    for (const sim::Condition c : sim::AllConditions()) check(std::string(sim::ConditionName(c)), c, false);
  }
  return problems;
}

std::string CardText(const CorpusSpec& spec, const std::vector<ManifestRow>& rows,
                     const std::map<std::tuple<std::string, std::string, std::string>, int>& events,
                     const std::map<std::string, std::pair<std::uint64_t, std::uint64_t>>& balance,
                     const std::string& version, const std::string& commit) {
  double hours = 0.0;
  std::size_t samples = 0, collisions = 0;
  for (const ManifestRow& r : rows) {
    hours += r.duration_s / 3600.0;
    samples += r.samples;
    collisions += r.collisions;
  }
  std::string card = fmt::format(
      "# {} — a tofu failure corpus\n\n{}\n\n"
      "| | |\n|---|---|\n| episodes | {} |\n| flight | {:.2f} h |\n| sensor samples | {} |\n"
      "| collisions | {} |\n| corpus seed | {} |\n| made by | tofu {} (commit {}) |\n\n",
      spec.name, spec.description.empty() ? "(no description)" : spec.description, rows.size(), hours, samples,
      collisions, spec.seed, version, commit);
  card += "## Fault and condition events (fault kind or condition × sensor × cause)\n\n"
          "| kind | sensor | cause | events |\n|---|---|---|---|\n";
  for (const auto& [key, n] : events) {
    card += fmt::format("| {} | {} | {} | {} |\n", std::get<0>(key), std::get<1>(key), std::get<2>(key), n);
  }
  card += "\n## Class balance (samples with a fault or condition active)\n\n"
          "| sensor | anomalous samples | all samples | fraction |\n|---|---|---|---|\n";
  for (const auto& [sensor, counts] : balance) {
    card += fmt::format("| {} | {} | {} | {:.3f} |\n", sensor, counts.first, counts.second,
                        counts.second > 0 ? static_cast<double>(counts.first) / static_cast<double>(counts.second) : 0.0);
  }
  card += fmt::format(
      "\n## How it was made\n\n"
      "`tofu corpus generate corpus.yaml --out DIR --shard I/N` for each shard, then `tofu corpus verify DIR`. "
      "Episode i is drawn from (corpus seed {}, i) alone: its scenario is the attribute `scenario_yaml` of "
      "`/episodes/<id>` and `tofu run` on it reproduces the episode. Labels (fault masks, condition masks, the "
      "event table) are ground truth from the simulator; `methods/*/decisions` are the estimator's predictions. "
      "Schema: docs/CORPUS.md of tofu.\n",
      spec.seed);
  return card;
}

}  // namespace

namespace {

// What verify gathers from the shards for the manifest and CARD.md.
struct CorpusTally {
  std::map<std::uint64_t, int> seen;  ///< episode index -> how many shards hold it
  std::vector<ManifestRow> rows;
  std::map<std::tuple<std::string, std::string, std::string>, int> events;
  std::map<std::string, std::pair<std::uint64_t, std::uint64_t>> balance;
  std::string version = "?", commit = "?";
};

// The shard_*.h5 files of `dir`, by name; a shard that did not finish is a problem.
std::vector<fs::path> ShardFiles(const fs::path& dir, std::vector<std::string>& problems) {
  std::vector<fs::path> shards;
  for (const auto& entry : fs::directory_iterator(dir)) {
    const std::string name = entry.path().filename().string();
    if (name.rfind("shard_", 0) == 0 && name.ends_with(".h5")) shards.push_back(entry.path());
    if (name.rfind(".shard_", 0) == 0) problems.push_back(fmt::format("{}: a shard that did not finish (run it again to resume)", name));
  }
  std::sort(shards.begin(), shards.end());
  if (shards.empty()) problems.push_back("no shard_*.h5 file");
  return shards;
}

// The manifest part: what the generator recorded of each episode (id -> content hash).
std::map<std::string, std::string> RecordedContentHashes(const fs::path& shard,
                                                         std::vector<std::string>& problems) {
  std::map<std::string, std::string> recorded_hash;
  const fs::path part = shard.parent_path() / (shard.stem().string() + ".manifest.json");
  if (!fs::exists(part)) {
    problems.push_back(fmt::format("{}: missing", part.filename().string()));
  } else {
    for (const auto& row : nlohmann::json::parse(core::ReadWholeFile(part, "shard manifest"))) {
      recorded_hash[row.at("id").get<std::string>()] = row.at("content_hash").get<std::string>();
    }
  }
  return recorded_hash;
}

// Episode `id` of the shard at `shard` against its manifest row, the spec's plan and its
// own masks; counts it, its events and its samples into `tally`.
void VerifyEpisode(const CorpusSpec& spec, const fs::path& shard, const Hdf5File& file,
                   const std::string& id, const Hdf5Group& episode,
                   const std::map<std::string, std::string>& recorded_hash, CorpusTally& tally,
                   std::vector<std::string>& problems) {
  ManifestRow row = ReadManifestRow(episode);
  row.shard = fmt::format("{}/{}", file.root().Int64Attribute("shard_index"), file.root().Int64Attribute("shard_count"));
  ++tally.seen[row.index];
  const std::string hash = fmt::format("{:016x}", episode.ContentHash());
  const auto recorded = recorded_hash.find(id);
  if (recorded == recorded_hash.end()) {
    problems.push_back(fmt::format("{}: episode {} is not in the shard's manifest", shard.filename().string(), id));
  } else if (recorded->second != hash || row.content_hash != hash) {
    problems.push_back(fmt::format("{}: episode {}: content hash {} does not match its manifest row ({})",
                                   shard.filename().string(), id, hash, recorded->second));
  }
  if (PlanEpisode(spec, row.index).id != id) {
    problems.push_back(fmt::format("{}: episode {} is not episode {} of the spec", shard.filename().string(), id, row.index));
  }
  for (const std::string& p : CheckEventsAgainstMasks(episode)) problems.push_back(p);
  const Hdf5Group table = episode.OpenGroup("events");
  const auto sensor = table.ReadStrings("sensor");
  const auto kind = table.ReadStrings("kind");
  const auto cause = table.ReadStrings("cause");
  // Every scheduled fault has its row (a dropout leaves no flagged sample to check).
  const std::size_t scheduled = static_cast<std::size_t>(std::count(cause.begin(), cause.end(), "scheduled"));
  std::size_t planned = 0;
  const EpisodePlan plan = PlanEpisode(spec, row.index);
  for (const PlannedFault& f : plan.faults) planned += f.start_s < plan.duration_s;
  if (scheduled != planned) {
    problems.push_back(fmt::format("{}: episode {}: {} scheduled fault events, the plan has {} faults",
                                   shard.filename().string(), id, scheduled, planned));
  }
  for (std::size_t e = 0; e < sensor.size(); ++e) ++tally.events[{kind[e], sensor[e], cause[e]}];
  const Hdf5Group sensors = episode.OpenGroup("sensors");
  for (const std::string& s : sensors.Children()) {
    const auto anomaly = sensors.OpenGroup(s).ReadUInt8("anomaly");
    tally.balance[s].first += static_cast<std::uint64_t>(std::count(anomaly.begin(), anomaly.end(), 1));
    tally.balance[s].second += anomaly.size();
  }
  tally.rows.push_back(row);
}

void VerifyShard(const CorpusSpec& spec, const fs::path& path, CorpusTally& tally,
                 std::vector<std::string>& problems) {
  const Hdf5File file = Hdf5File::OpenReadOnly(path);
  tally.version = file.root().StringAttribute("tofu_version");
  tally.commit = file.root().StringAttribute("tofu_commit");
  if (file.root().StringAttribute("spec_yaml") != spec.text) {
    problems.push_back(fmt::format("{}: made from another spec than {}", path.filename().string(), kSpecFile));
  }
  const std::map<std::string, std::string> recorded_hash = RecordedContentHashes(path, problems);
  const Hdf5Group episodes = file.root().OpenGroup("episodes");
  for (const std::string& id : episodes.Children()) {
    VerifyEpisode(spec, path, file, id, episodes.OpenGroup(id), recorded_hash, tally, problems);
  }
}

// Every planned episode once, and no other.
void CheckEpisodeCoverage(const CorpusSpec& spec, std::map<std::uint64_t, int>& seen,
                          std::vector<std::string>& problems) {
  for (std::uint64_t i = 0; i < spec.episodes; ++i) {
    const int n = seen.count(i) ? seen[i] : 0;
    if (n != 1) problems.push_back(fmt::format("episode {} ({}) is present {} times (expected once)", i, PlanEpisode(spec, i).id, n));
  }
  for (const auto& [i, n] : seen) {
    if (i >= spec.episodes) problems.push_back(fmt::format("episode {} is not planned (the spec has {})", i, spec.episodes));
  }
}

// manifest.csv, manifest.json and CARD.md of the corpus, the rows by episode index.
void WriteManifests(const fs::path& dir, const CorpusSpec& spec, CorpusTally& tally) {
  std::vector<ManifestRow>& rows = tally.rows;
  std::sort(rows.begin(), rows.end(), [](const ManifestRow& a, const ManifestRow& b) { return a.index < b.index; });
  const std::vector<std::string> methods = MethodsOf(rows);
  std::string csv = ManifestCsvHeader(methods);
  nlohmann::ordered_json json = nlohmann::ordered_json::array();
  for (const ManifestRow& r : rows) {
    csv += ManifestCsvRow(r, methods);
    json.push_back(ManifestJson(r));
  }
  replay::WriteFileAtomically(dir / "manifest.csv", csv);
  replay::WriteFileAtomically(dir / "manifest.json", json.dump(1) + "\n");
  replay::WriteFileAtomically(dir / "CARD.md", CardText(spec, rows, tally.events, tally.balance, tally.version, tally.commit));
}

}  // namespace

int RunCorpusVerify(const fs::path& dir, bool quiet) {
  if (!fs::is_directory(dir) || !fs::exists(dir / kSpecFile)) {
    throw core::InputError({dir.string()}, "", "not a corpus directory (expected corpus.yaml and shard_*.h5)");
  }
  const CorpusSpec spec = ParseCorpusSpec(core::ReadWholeFile(dir / kSpecFile, "corpus spec", core::kMaxConfigFileBytes),
                                          (dir / kSpecFile).string(), dir / kIncludedDir);
  std::vector<std::string> problems;
  const std::vector<fs::path> shards = ShardFiles(dir, problems);
  CorpusTally tally;
  for (const fs::path& path : shards) VerifyShard(spec, path, tally, problems);
  CheckEpisodeCoverage(spec, tally.seen, problems);
  WriteManifests(dir, spec, tally);

  if (!problems.empty()) {
    fmt::print(stderr, "tofu corpus verify: {}: {} problem(s)\n", dir.string(), problems.size());
    for (const std::string& p : problems) fmt::print(stderr, "  {}\n", p);
    return core::kExitExpectationFailed;
  }
  if (!quiet) {
    fmt::print("{}: {} episodes in {} shard(s), every planned episode once, content hashes and event tables "
               "agree; wrote manifest.csv, manifest.json, CARD.md\n", dir.string(), tally.rows.size(), shards.size());
  }
  return core::kExitOk;
}

}  // namespace tofu::corpus
