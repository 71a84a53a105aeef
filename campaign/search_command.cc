#include "campaign/search_command.h"

#include <fcntl.h>
#include <spawn.h>
#include <sys/wait.h>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <limits>
#include <map>
#include <regex>

#include <fmt/format.h>
#include <fmt/ranges.h>
#include <nlohmann/json.hpp>

#include "campaign/check_command.h"
#include "campaign/margin.h"
#include "campaign/run_pool.h"
#include "campaign/search.h"
#include "campaign/search_spec.h"
#include "core/cores.h"
#include "core/error.h"
#include "core/file_io.h"
#include "harness/shard.h"
#include "replay/file_io.h"

extern char** environ;

namespace tofu::campaign {

namespace {

namespace fs = std::filesystem;
using core::FormatDouble;

// Flies each request as `tofu run <out>/flights/<id>.yaml --out <out>/flights/<id>`. A
// passing flight's run directory and log are removed (its margin is in the journal); a
// failing flight's stay, for the failure's report and renders.
class PoolEvaluator : public FlightEvaluator {
 public:
  PoolEvaluator(const SearchSpec& spec, fs::path flights, std::string binary, int jobs)
      : spec_(spec), flights_(std::move(flights)), binary_(std::move(binary)), jobs_(jobs) {}

  std::vector<FlightMargin> Fly(const std::vector<FlightRequest>& requests) override {
    std::vector<RunRequest> runs(requests.size());
    std::vector<RunRequest*> queue;
    for (std::size_t i = 0; i < requests.size(); ++i) {
      const FlightRequest& r = requests[i];
      RunRequest& run = runs[i];
      run.scenario_path = (flights_ / (r.id + ".yaml")).string();
      replay::WriteFileAtomically(run.scenario_path, ScenarioYaml(spec_, r.setting, spec_.name + "_" + r.id, {},
                                                                  ScenarioScope::kObjective));
      run.label = r.id;
      run.run.seed = r.setting.seed;
      run.run.run_dir = (flights_ / r.id).string();
      run.run.log_path = run.run.run_dir + ".log";
      // A search's flights are read for their margins: no figures (a failure's flight is
      // rendered instead).
      run.extra_args = {"--no-plots"};
      queue.push_back(&run);
    }
    RunPool(binary_, queue, jobs_, /*quiet=*/true, "search");
    std::vector<FlightMargin> margins;
    for (RunRequest& run : runs) {
      ReadSummary(run.run);
      margins.push_back(MarginOfRun(run.run, spec_.objective_metrics));
      if (margins.back().margin >= 0.0) {
        std::error_code ec;
        fs::remove_all(run.run.run_dir, ec);
        fs::remove(run.run.log_path, ec);
      }
    }
    return margins;
  }

 private:
  const SearchSpec& spec_;
  fs::path flights_;
  std::string binary_;
  int jobs_;
};

nlohmann::json SettingJson(const SearchSpec& spec, const Setting& s) {
  nlohmann::json j;
  j["seed"] = s.seed;
  j["set"] = nlohmann::json::object();
  for (std::size_t i = 0; i < spec.set.size(); ++i) {
    j["set"][spec.set[i].path] = std::isnan(s.set_values[i]) ? nlohmann::json(nullptr) : nlohmann::json(s.set_values[i]);
  }
  j["faults"] = nlohmann::json::array();
  for (std::size_t k = 0; k < s.faults.size(); ++k) {
    const FaultSetting& f = s.faults[k];
    if (!f.present) {
      j["faults"].push_back(nullptr);
      continue;
    }
    const FaultSlot::Option& o = spec.faults[k].options[f.option];
    j["faults"].push_back({{"kind", sim::FaultKindName(o.kind)}, {"sensor", o.sensor}, {"onset_s", f.onset_s},
                           {"duration_s", f.duration_s}, {"magnitude", f.magnitude},
                           {"direction_z", f.direction_z}, {"direction_phi", f.direction_phi}});
  }
  return j;
}

std::string MarginText(double margin) { return std::isfinite(margin) ? fmt::format("{:.3g}", margin) : "none"; }

// Renders a failure's flight: `tofu render <run> --events` (its keyframes and clips in
// <run>/renders). A render that fails is a warning: the failure stands without pictures.
void RenderFlight(const std::string& binary, const fs::path& run_dir, bool quiet) {
  std::vector<std::string> args = {binary, "render", run_dir.string(), "--out", (run_dir / "renders").string()};
  std::vector<char*> argv;
  for (std::string& a : args) argv.push_back(a.data());
  argv.push_back(nullptr);
  posix_spawn_file_actions_t actions;
  posix_spawn_file_actions_init(&actions);
  const std::string log = (run_dir / "render.log").string();
  posix_spawn_file_actions_addopen(&actions, STDOUT_FILENO, log.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
  posix_spawn_file_actions_adddup2(&actions, STDOUT_FILENO, STDERR_FILENO);
  pid_t pid = -1;
  const int rc = posix_spawn(&pid, binary.c_str(), &actions, nullptr, argv.data(), environ);
  posix_spawn_file_actions_destroy(&actions);
  int status = 0;
  if (rc != 0 || ::waitpid(pid, &status, 0) != pid || !WIFEXITED(status) || WEXITSTATUS(status) != 0) {
    if (!quiet) fmt::print(stderr, "tofu search: warning: no renders of {} (see {})\n", run_dir.string(), log);
  }
}

std::string FailuresMarkdown(const SearchSpec& spec, const SearchOutcome& outcome) {
  std::string md = fmt::format("# tofu search {}: failures found\n\n", spec.name);
  md += fmt::format("Base `{}`; objective: the least margin of {}; {} search simulations ({} to confirm, {} to "
                    "shrink).\n\n",
                    spec.base_path.filename().string(), fmt::join(spec.objective_metrics, ", "),
                    outcome.evaluations.size(), outcome.confirm_flights, outcome.shrink_flights);
  if (outcome.failures.empty()) return md + "No flight failed.\n";
  md += "| rank | failure | expectation | confirmed | failure rate [95 % CI] | margin found | margin shrunk | "
        "found at simulation | shrunk change from the base |\n|---|---|---|---|---|---|---|---|---|\n";
  int rank = 0;
  for (const FoundFailure& f : outcome.failures) {
    const std::string change =
        f.confirmed ? fmt::format("{}", fmt::join(DescribeSetting(spec, f.shrunk), "; ")) : std::string("-");
    md += fmt::format("| {} | {} | {} | {} | {}/{} [{:.2f}, {:.2f}] | {} | {} | {} | {} |\n", ++rank, f.id, f.metric,
                      f.confirmed ? "yes" : "no", f.confirm_failures, f.confirm_flights, f.failure_rate_ci.low,
                      f.failure_rate_ci.high, MarginText(f.found_margin.margin),
                      f.confirmed ? MarginText(f.shrunk_margin.margin) : "-", f.first_simulation, change);
  }
  for (const FoundFailure& f : outcome.failures) {
    if (f.found_margin.cause.empty()) continue;
    md += fmt::format("\n{} ({}): {}\n", f.id, f.metric, f.found_margin.cause);
  }
  return md;
}

nlohmann::json SearchJson(const SearchSpec& spec, const SearchOutcome& outcome) {
  nlohmann::json j;
  j["format"] = "tofu-search-1";
  j["spec"] = spec.name;
  j["base"] = spec.base_path.filename().string();
  j["objective"] = spec.objective_metrics;
  j["optimizer"] = spec.optimizer;
  j["optimizer_seed"] = spec.optimizer_seed;
  j["budget"] = spec.budget;
  j["batch"] = spec.batch;
  j["dimensions"] = nlohmann::json::array();
  for (const SearchDimension& d : spec.dimensions) j["dimensions"].push_back({{"name", d.name}, {"choices", d.choices}});
  j["simulations"] = {{"search", outcome.evaluations.size()},
                      {"confirm", outcome.confirm_flights},
                      {"shrink", outcome.shrink_flights}};
  j["simulations_to_first_confirmed"] = outcome.simulations_to_first_confirmed
                                            ? nlohmann::json(*outcome.simulations_to_first_confirmed)
                                            : nlohmann::json(nullptr);
  nlohmann::json evaluations = nlohmann::json::array();
  for (const SearchEvaluation& e : outcome.evaluations) {
    nlohmann::json row = MarginToJson(e.margin);
    row["id"] = e.id;
    row["unit"] = e.unit;
    row["setting"] = SettingJson(spec, e.setting);
    evaluations.push_back(std::move(row));
  }
  j["evaluations"] = std::move(evaluations);
  nlohmann::json failures = nlohmann::json::array();
  for (const FoundFailure& f : outcome.failures) {
    nlohmann::json row;
    row["id"] = f.id;
    row["expectation"] = f.metric;
    row["confirmed"] = f.confirmed;
    row["confirm_failures"] = f.confirm_failures;
    row["confirm_flights"] = f.confirm_flights;
    row["failure_rate_ci95"] = {f.failure_rate_ci.low, f.failure_rate_ci.high};
    row["first_simulation"] = f.first_simulation;
    row["members"] = f.members;
    row["unit"] = f.unit;
    row["found"] = SettingJson(spec, f.found);
    row["found_flight"] = f.found_flight;
    row["found_margin"] = MarginToJson(f.found_margin);
    if (f.confirmed) {
      row["shrunk"] = SettingJson(spec, f.shrunk);
      row["shrunk_flight"] = f.shrunk_flight;
      row["run_dir"] = f.flights_dir + "/" + f.shrunk_flight;
      row["shrunk_margin"] = MarginToJson(f.shrunk_margin);
      row["shrunk_change"] = DescribeSetting(spec, f.shrunk);
    }
    failures.push_back(std::move(row));
  }
  j["failures"] = std::move(failures);
  return j;
}

// ---- across machines: shards of a search, and their merge ----

Setting SettingFromJson(const SearchSpec& spec, const nlohmann::json& j) {
  Setting s;
  s.seed = j.at("seed").get<uint64_t>();
  for (const SetKey& k : spec.set) {
    const nlohmann::json& v = j.at("set").at(k.path);
    s.set_values.push_back(v.is_null() ? std::numeric_limits<double>::quiet_NaN() : v.get<double>());
  }
  const nlohmann::json& faults = j.at("faults");
  if (faults.size() != spec.faults.size()) throw std::runtime_error("another number of fault slots");
  for (std::size_t k = 0; k < spec.faults.size(); ++k) {
    FaultSetting f;
    const nlohmann::json& fj = faults[k];
    if (fj.is_null()) {
      f.present = false;
      s.faults.push_back(f);
      continue;
    }
    const auto& options = spec.faults[k].options;
    const auto it = std::find_if(options.begin(), options.end(), [&](const FaultSlot::Option& o) {
      return sim::FaultKindName(o.kind) == fj.at("kind").get<std::string>() && o.sensor == fj.at("sensor").get<std::string>();
    });
    if (it == options.end()) throw std::runtime_error("a fault the spec's slot does not offer");
    f.option = static_cast<std::size_t>(it - options.begin());
    f.onset_s = fj.at("onset_s").get<double>();
    f.duration_s = fj.at("duration_s").get<double>();
    f.magnitude = fj.at("magnitude").get<double>();
    f.direction_z = fj.at("direction_z").get<double>();
    f.direction_phi = fj.at("direction_phi").get<double>();
    s.faults.push_back(f);
  }
  return s;
}

FoundFailure FailureFromJson(const SearchSpec& spec, const nlohmann::json& j, const std::string& stem) {
  FoundFailure f;
  f.id = j.at("id").get<std::string>();
  f.metric = j.at("expectation").get<std::string>();
  f.unit = j.at("unit").get<std::vector<double>>();
  f.found = SettingFromJson(spec, j.at("found"));
  f.found_margin = MarginFromJson(j.at("found_margin"));
  f.found_flight = stem + "/" + j.at("found_flight").get<std::string>();
  f.first_simulation = j.at("first_simulation").get<std::size_t>();
  f.members = j.at("members").get<std::size_t>();
  f.confirm_failures = j.at("confirm_failures").get<int>();
  f.confirm_flights = j.at("confirm_flights").get<int>();
  f.failure_rate_ci = {j.at("failure_rate_ci95").at(0).get<double>(), j.at("failure_rate_ci95").at(1).get<double>()};
  f.confirmed = j.at("confirmed").get<bool>();
  if (f.confirmed) {
    f.shrunk = SettingFromJson(spec, j.at("shrunk"));
    f.shrunk_margin = MarginFromJson(j.at("shrunk_margin"));
    f.shrunk_flight = j.at("shrunk_flight").get<std::string>();
    f.flights_dir = stem + "/flights";
  }
  return f;
}

// The shards' searches (<out>/shard_<I>_of_<N>/, each a whole search of its own) as one:
// their flights in shard order, their failures de-duplicated across shards (the spec's
// rule; the one found first, in shard order, stays) and ranked anew.
SearchOutcome MergeShards(const SearchSpec& spec, const fs::path& out, uint64_t& shard_count) {
  std::map<uint64_t, fs::path> shards;
  shard_count = 0;
  const std::regex name(R"(shard_(\d+)_of_(\d+))");
  for (const auto& entry : fs::directory_iterator(out)) {
    std::smatch m;
    const std::string file = entry.path().filename().string();
    if (!entry.is_directory() || !std::regex_match(file, m, name)) continue;
    const uint64_t count = std::stoull(m[2].str());
    if (shard_count != 0 && count != shard_count) {
      throw core::InputError({out.string()}, "--merge",
                             fmt::format("holds shards of {} and of {} machines: expected one search's", shard_count, count));
    }
    shard_count = count;
    shards[std::stoull(m[1].str())] = entry.path();
  }
  if (shard_count == 0) {
    throw core::InputError({out.string()}, "--merge", "holds no shard_<I>_of_<N> directory (expected the --out of the shards)");
  }
  std::vector<std::string> problems;
  for (uint64_t i = 0; i < shard_count; ++i) {
    const auto it = shards.find(i);
    const std::string stem = harness::ShardStem(harness::Shard(i, shard_count));
    if (it == shards.end()) {
      problems.push_back(fmt::format("shard {} of {} is missing ({})", i, shard_count, stem));
    } else if (!fs::exists(it->second / "search.json")) {
      problems.push_back(fmt::format("shard {} of {} has not finished (no {})", i, shard_count,
                                     (it->second / "search.json").string()));
    } else if (core::ReadWholeFile(it->second / "spec.yaml", "search spec", core::kMaxConfigFileBytes)
                   .rfind(spec.text, 0) != 0) {
      problems.push_back(fmt::format("shard {} of {} is a search of another spec", i, shard_count));
    }
  }
  if (!problems.empty()) {
    throw core::InputError({out.string()}, "--merge", fmt::format("{}", fmt::join(problems, "; ")));
  }
  SearchOutcome merged;
  for (uint64_t i = 0; i < shard_count; ++i) {
    const std::string stem = shards[i].filename().string();
    const nlohmann::json j = nlohmann::json::parse(core::ReadWholeFile(shards[i] / "search.json", "search record", 1ull << 30));
    for (const nlohmann::json& e : j.at("evaluations")) {
      merged.evaluations.push_back({stem + "/" + e.at("id").get<std::string>(), e.at("unit").get<std::vector<double>>(),
                                    SettingFromJson(spec, e.at("setting")), MarginFromJson(e)});
    }
    merged.confirm_flights += j.at("simulations").at("confirm").get<std::size_t>();
    merged.shrink_flights += j.at("simulations").at("shrink").get<std::size_t>();
    const nlohmann::json& first = j.at("simulations_to_first_confirmed");
    if (first.is_number()) {
      const auto n = first.get<std::size_t>();
      merged.simulations_to_first_confirmed =
          merged.simulations_to_first_confirmed ? std::min(*merged.simulations_to_first_confirmed, n) : n;
    }
    for (const nlohmann::json& fj : j.at("failures")) {
      FoundFailure f = FailureFromJson(spec, fj, stem);
      const bool seen = std::any_of(merged.failures.begin(), merged.failures.end(), [&](const FoundFailure& g) {
        return g.metric == f.metric && g.confirmed == f.confirmed && PointDistance(spec, g.unit, f.unit) <= spec.dedupe_distance;
      });
      if (!seen) merged.failures.push_back(std::move(f));
    }
  }
  RankFailures(merged.failures);
  for (std::size_t k = 0; k < merged.failures.size(); ++k) {
    // The shard's own id stays in the failure's flights; the merge numbers them anew.
    merged.failures[k].id = fmt::format("f{}", k + 1);
  }
  return merged;
}

// The out directory holds this spec's search, or nothing yet: a search of another spec
// is not resumed into (its journal would answer for other flights).
void ClaimOutDirectory(const SearchSpec& spec, const fs::path& out) {
  const fs::path marker = out / "spec.yaml";
  // The spec as flown: its text, and the optimiser when the command line overrode it.
  const std::string flown = spec.text + fmt::format("\n# flown with optimizer {}, seed {}\n", spec.optimizer,
                                                    spec.optimizer_seed);
  if (fs::exists(marker)) {
    const std::string held = core::ReadWholeFile(marker, "search spec", core::kMaxConfigFileBytes);
    if (held != flown) {
      throw core::InputError({spec.file, 0, 0}, "--out",
                             fmt::format("{} holds a search of another spec (its spec.yaml differs): choose "
                                         "another --out, or remove it",
                                         out.string()));
    }
    return;
  }
  if (fs::exists(out) && !fs::is_empty(out)) {
    throw core::InputError({spec.file, 0, 0}, "--out",
                           fmt::format("{} is not empty and holds no search: choose another --out", out.string()));
  }
  fs::create_directories(out / "flights");
  replay::WriteFileAtomically(marker, flown);
}

void WriteFailures(const SearchSpec& spec, const SearchOutcome& outcome, const fs::path& out,
                   const std::string& binary, const SearchCommandOptions& options) {
  for (const FoundFailure& f : outcome.failures) {
    const fs::path dir = out / "failures" / f.id;
    fs::create_directories(dir);
    replay::WriteFileAtomically(dir / "found.yaml", ScenarioYaml(spec, f.found, spec.name + "_" + f.id + "_found"));
    if (!f.confirmed) continue;
    replay::WriteFileAtomically(dir / "scenario.yaml", ScenarioYaml(spec, f.shrunk, spec.name + "_" + f.id));
    const fs::path run = out / f.flights_dir / f.shrunk_flight;
    if (options.renders && fs::is_directory(run) && !fs::exists(run / "renders")) {
      RenderFlight(binary, run, options.quiet);
    }
  }
}

void Promote(const SearchSpec& spec, const SearchOutcome& outcome, const fs::path& dir, bool quiet) {
  fs::create_directories(dir);
  for (const FoundFailure& f : outcome.failures) {
    if (!f.confirmed) continue;
    const std::string name = spec.name + "_" + f.id;
    // The violated expectation alone (all of the objective's for a flight that failed
    // without one): the scenario fails until the cause is fixed.
    const bool has_metric = f.shrunk_margin.outcome == "violated" || f.shrunk_margin.outcome == "not measurable";
    const std::vector<std::string> kept = has_metric ? std::vector<std::string>{f.metric} : spec.objective_metrics;
    const std::string header = fmt::format(
        "# Found by `tofu search {}` (failure {}: {}, margin {} after shrinking; failed at {}/{} other seeds, "
        "95 % CI [{:.2f}, {:.2f}]).\n# The change from the base {}: {}.\n# A regression scenario: it fails "
        "until the cause is fixed.\n",
        fs::path(spec.file).filename().string(), f.id, f.metric, MarginText(f.shrunk_margin.margin),
        f.confirm_failures, f.confirm_flights, f.failure_rate_ci.low, f.failure_rate_ci.high,
        spec.base_path.filename().string(), fmt::join(DescribeSetting(spec, f.shrunk), "; "));
    const fs::path path = dir / (name + ".yaml");
    replay::WriteFileAtomically(path, header + ScenarioYaml(spec, f.shrunk, name, kept));
    if (!quiet) fmt::print(stderr, "tofu search: promoted {} -> {}\n", f.id, path.string());
  }
}

}  // namespace

int RunSearchCommand(const SearchCommandOptions& options) {
  SearchSpec spec;
  const fs::path out = fs::absolute(options.out_dir).lexically_normal();
  const bool sharded = !options.shard.origin.empty();
  // A shard is a whole search of its own in <out>/shard_<I>_of_<N>/: a share of the budget,
  // the optimiser seeded apart from the other shards' (random: together one random search).
  const fs::path dir = sharded ? out / harness::ShardStem(options.shard) : out;
  try {
    if (options.jobs < 0) throw core::InputError({}, "--jobs", "expected a whole number >= 1 (0: every core)");
    if (sharded && options.merge) {
      throw core::InputError({}, "--merge", "a merge is no shard: give --merge without --shard");
    }
    if (sharded && options.promote_dir) {
      throw core::InputError({}, "--promote", "a shard promotes nothing: give --promote to the merge (--merge)");
    }
    spec = LoadSearchSpec(options.spec_path);
    if (options.optimizer) {
      const auto& known = SearchOptimizers();
      if (std::find(known.begin(), known.end(), *options.optimizer) == known.end()) {
        throw core::InputError({}, "--optimizer",
                               fmt::format("unknown optimizer '{}' (expected one of: {})", *options.optimizer,
                                           fmt::join(known, ", ")));
      }
      spec.optimizer = *options.optimizer;
    }
    if (options.optimizer_seed) spec.optimizer_seed = *options.optimizer_seed;
    harness::CheckScenarioModels(spec.base);
    CheckScenarioMinimalEffects(spec.base);
    if (sharded) {
      spec.budget = (spec.budget + options.shard.count - 1) / options.shard.count;
      spec.optimizer_seed += options.shard.index;
    }
    if (!options.merge) ClaimOutDirectory(spec, dir);
  } catch (const core::InputError& e) {
    fmt::print(stderr, "tofu: error: {}\n", e.what());
    return core::kExitBadInput;
  }
  const int jobs = options.jobs == 0 ? core::UsableCores() : options.jobs;
  const std::string binary = options.tofu_binary.empty() ? SelfExecutable() : options.tofu_binary;
  SearchOutcome outcome;
  uint64_t shard_count = 0;
  if (options.merge) {
    try {
      outcome = MergeShards(spec, out, shard_count);
    } catch (const core::InputError& e) {
      fmt::print(stderr, "tofu: error: {}\n", e.what());
      return core::kExitBadInput;
    }
  } else {
    if (!options.quiet) {
      fmt::print(stderr, "tofu search: {}{} over {} dimensions, {} simulations with {} (seed {}), batches of {}, {} flights at a time -> {}\n",
                 sharded ? fmt::format("shard {}/{} (from {}) of ", options.shard.index, options.shard.count,
                                       options.shard.origin)
                         : std::string(),
                 spec.name, spec.dimensions.size(), spec.budget, spec.optimizer, spec.optimizer_seed, spec.batch, jobs,
                 dir.string());
    }
    PoolEvaluator pool(spec, dir / "flights", binary, jobs);
    JournaledEvaluator journaled(spec, pool, dir / "evaluations.jsonl");
    const std::unique_ptr<Proposer> proposer = MakeProposer(spec, TOFU_SCRIPTS_DIR);
    const SearchProgress progress = [&](const std::string& line) {
      if (!options.quiet) fmt::print(stderr, "tofu search: {}\n", line);
    };
    outcome = RunSearch(spec, journaled, *proposer, progress);
    if (!options.quiet) {
      fmt::print(stderr, "tofu search: {} flights flown, {} taken from the journal\n", journaled.flown(),
                 journaled.reused());
    }
  }
  WriteFailures(spec, outcome, dir, binary, options);
  nlohmann::json record = SearchJson(spec, outcome);
  if (options.merge) record["shards"] = shard_count;
  replay::WriteFileAtomically(dir / "search.json", record.dump(1) + "\n");
  const std::string md = FailuresMarkdown(spec, outcome);
  replay::WriteFileAtomically(dir / "failures.md", md);
  if (options.promote_dir) Promote(spec, outcome, fs::absolute(*options.promote_dir), options.quiet);
  if (!options.quiet) fmt::print("{}", md);
  for (const FoundFailure& f : outcome.failures) {
    if (f.confirmed) return core::kExitExpectationFailed;
  }
  return core::kExitOk;
}

}  // namespace tofu::campaign
