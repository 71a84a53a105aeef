#include "campaign/search.h"

#include <fcntl.h>
#include <spawn.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cmath>
#include <csignal>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <limits>
#include <stdexcept>

#include <fmt/format.h>
#include <nlohmann/json.hpp>

#include "core/hash.h"
#include "core/random.h"

extern char** environ;

namespace tofu::campaign {

namespace {

namespace fs = std::filesystem;

// What the optimiser is told of a flight: margins beyond +-10 (far from a bound, or none
// at all: -inf) carry no more information and would stretch its model.
constexpr double kMarginClip = 10.0;

double Clip(double margin) { return std::clamp(margin, -kMarginClip, kMarginClip); }

// ---- proposers ----

class RandomProposer : public Proposer {
 public:
  RandomProposer(std::size_t dimensions, uint64_t seed)
      : dimensions_(dimensions), random_(seed, "search.random") {}
  std::vector<std::vector<double>> Ask(std::size_t n) override {
    std::vector<std::vector<double>> points(n, std::vector<double>(dimensions_));
    for (auto& p : points) {
      for (double& u : p) u = random_.Uniform(0.0, 1.0);
    }
    return points;
  }
  void Tell(const std::vector<double>&) override {}

 private:
  std::size_t dimensions_;
  core::RandomStream random_;
};

// An optimiser in a process of its own (scripts/search_proposer.py), one JSON object per
// line each way: {"op": "ask", "n": k} -> {"points": [[...], ...]}, {"op": "tell",
// "values": [...]} -> {"ok": true}. Its stderr is tofu's.
class ProcessProposer : public Proposer {
 public:
  ProcessProposer(const std::vector<std::string>& command, const nlohmann::json& init) {
    int to_child[2];
    int from_child[2];
    if (::pipe2(to_child, O_CLOEXEC) != 0 || ::pipe2(from_child, O_CLOEXEC) != 0) {
      throw std::runtime_error(fmt::format("search: pipe: {}", std::strerror(errno)));
    }
    posix_spawn_file_actions_t actions;
    posix_spawn_file_actions_init(&actions);
    posix_spawn_file_actions_adddup2(&actions, to_child[0], STDIN_FILENO);
    posix_spawn_file_actions_adddup2(&actions, from_child[1], STDOUT_FILENO);
    std::vector<std::string> args = command;
    std::vector<char*> argv;
    for (std::string& a : args) argv.push_back(a.data());
    argv.push_back(nullptr);
    // Python's string hashing is salted per process; the optimiser must not depend on it.
    std::vector<std::string> env_text = {"PYTHONHASHSEED=0"};
    for (char** e = environ; *e != nullptr; ++e) {
      if (std::strncmp(*e, "PYTHONHASHSEED=", 15) != 0) env_text.emplace_back(*e);
    }
    std::vector<char*> env;
    for (std::string& e : env_text) env.push_back(e.data());
    env.push_back(nullptr);
    const int rc = posix_spawn(&pid_, args[0].c_str(), &actions, nullptr, argv.data(), env.data());
    posix_spawn_file_actions_destroy(&actions);
    ::close(to_child[0]);
    ::close(from_child[1]);
    if (rc != 0) {
      ::close(to_child[1]);
      ::close(from_child[0]);
      throw std::runtime_error(fmt::format("search: cannot start the optimiser {}: {}", args[0], std::strerror(rc)));
    }
    to_ = ::fdopen(to_child[1], "w");
    from_ = ::fdopen(from_child[0], "r");
    // A proposer that died must surface as an error here, not end tofu by SIGPIPE.
    std::signal(SIGPIPE, SIG_IGN);
    Request(init);
  }
  ~ProcessProposer() override {
    if (to_ != nullptr) std::fclose(to_);
    if (from_ != nullptr) std::fclose(from_);
    if (pid_ > 0) {
      int status = 0;
      ::waitpid(pid_, &status, 0);
    }
  }
  ProcessProposer(const ProcessProposer&) = delete;
  ProcessProposer& operator=(const ProcessProposer&) = delete;

  std::vector<std::vector<double>> Ask(std::size_t n) override {
    const nlohmann::json reply = Request({{"op", "ask"}, {"n", n}});
    auto points = reply.at("points").get<std::vector<std::vector<double>>>();
    if (points.size() != n) throw std::runtime_error("search: the optimiser answered another number of points");
    return points;
  }
  void Tell(const std::vector<double>& margins) override {
    std::vector<double> clipped;
    for (double m : margins) clipped.push_back(Clip(m));
    Request({{"op", "tell"}, {"values", clipped}});
  }

 private:
  nlohmann::json Request(const nlohmann::json& message) {
    const std::string line = message.dump() + "\n";
    if (std::fputs(line.c_str(), to_) == EOF || std::fflush(to_) != 0) {
      throw std::runtime_error("search: the optimiser's process is gone (its error is above)");
    }
    std::string reply;
    char buffer[4096];
    while (std::fgets(buffer, sizeof buffer, from_) != nullptr) {
      reply += buffer;
      if (!reply.empty() && reply.back() == '\n') break;
    }
    if (reply.empty()) throw std::runtime_error("search: the optimiser's process ended (its error is above)");
    nlohmann::json parsed = nlohmann::json::parse(reply, nullptr, false);
    if (parsed.is_discarded() || !parsed.is_object()) {
      throw std::runtime_error(fmt::format("search: the optimiser answered '{}', not a JSON object", reply));
    }
    if (parsed.contains("error")) {
      throw std::runtime_error(fmt::format("search: the optimiser: {}", parsed["error"].dump()));
    }
    return parsed;
  }

  pid_t pid_ = -1;
  FILE* to_ = nullptr;
  FILE* from_ = nullptr;
};

// ---- journal ----

std::string SettingKey(const SearchSpec& spec, const FlightRequest& r) {
  return fmt::format("{:016x}", core::Fnv1a64(ScenarioYaml(spec, r.setting, spec.name + "_" + r.id)));
}

// ---- failures ----

// What makes two failures the same failure: the expectation that failed, or how the
// flight failed when it has no margin.
std::string FailureKey(const FlightMargin& m) {
  if (m.outcome == "violated" || m.outcome == "not measurable") return m.failing_metric;
  return m.outcome;
}

bool Fails(const FlightMargin& m) { return m.margin < 0.0; }

}  // namespace

double PointDistance(const SearchSpec& spec, const std::vector<double>& a, const std::vector<double>& b) {
  double d = 0.0;
  for (std::size_t i = 0; i < a.size(); ++i) {
    const int n = spec.dimensions[i].choices;
    if (n > 0) {
      const auto ca = std::min<long>(n - 1, static_cast<long>(a[i] * n));
      const auto cb = std::min<long>(n - 1, static_cast<long>(b[i] * n));
      d = std::max(d, ca == cb ? 0.0 : 1.0);
    } else {
      d = std::max(d, std::abs(a[i] - b[i]));
    }
  }
  return d;
}

void RankFailures(std::vector<FoundFailure>& failures) {
  std::stable_sort(failures.begin(), failures.end(), [](const FoundFailure& a, const FoundFailure& b) {
    if (a.confirmed != b.confirmed) return a.confirmed;
    const double ra = static_cast<double>(a.confirm_failures) / std::max(1, a.confirm_flights);
    const double rb = static_cast<double>(b.confirm_failures) / std::max(1, b.confirm_flights);
    if (ra != rb) return ra > rb;
    return a.found_margin.margin < b.found_margin.margin;
  });
}

namespace {

struct Cluster {
  FoundFailure failure;
  bool refuted = false;
};

void Confirm(const SearchSpec& spec, FlightEvaluator& evaluator, std::vector<Cluster*>& candidates,
             SearchOutcome& out, const SearchProgress& progress) {
  if (candidates.empty()) return;
  std::vector<FlightRequest> requests;
  for (Cluster* c : candidates) {
    const std::vector<uint64_t> seeds = ConfirmationSeeds(spec, c->failure.found.seed, spec.confirm.seeds);
    for (std::size_t j = 0; j < seeds.size(); ++j) {
      Setting s = c->failure.found;
      s.seed = seeds[j];
      requests.push_back({fmt::format("{}_c{}", c->failure.id, j + 1), s});
    }
  }
  const std::vector<FlightMargin> margins = evaluator.Fly(requests);
  out.confirm_flights += margins.size();
  std::size_t k = 0;
  for (Cluster* c : candidates) {
    FoundFailure& f = c->failure;
    f.confirm_flights = spec.confirm.seeds;
    f.confirm_failures = 0;
    for (int j = 0; j < spec.confirm.seeds; ++j, ++k) {
      if (Fails(margins[k]) && FailureKey(margins[k]) == f.metric) ++f.confirm_failures;
    }
    f.failure_rate_ci = ClopperPearsonInterval(f.confirm_failures, f.confirm_flights, 0.95);
    const double rate = static_cast<double>(f.confirm_failures) / f.confirm_flights;
    f.confirmed = rate >= spec.confirm.min_failure_rate;
    c->refuted = !f.confirmed;
    if (progress) {
      progress(fmt::format("{} ({}, margin {:.3g}): {} in {}/{} other seeds, {}", f.id, f.metric,
                           f.found_margin.margin, f.confirmed ? "confirmed" : "not confirmed",
                           f.confirm_failures, f.confirm_flights, f.confirmed ? "kept" : "dropped"));
    }
  }
}

// Moves each parameter of a confirmed failure back towards the base while the flight
// still fails the same way (docs/DESIGN.md, "Searching for failures").
void Shrink(const SearchSpec& spec, FlightEvaluator& evaluator, Cluster& cluster, SearchOutcome& out) {
  FoundFailure& f = cluster.failure;
  f.shrunk = f.found;
  f.shrunk_margin = f.found_margin;
  f.shrunk_flight = f.found_flight;
  int step = 0;
  const auto still_fails = [&](const Setting& s) {
    const std::string id = fmt::format("{}_s{}", f.id, ++step);
    const FlightMargin m = evaluator.Fly({{id, s}}).front();
    ++out.shrink_flights;
    if (!Fails(m) || FailureKey(m) != f.metric) return false;
    f.shrunk = s;
    f.shrunk_margin = m;
    f.shrunk_flight = id;
    return true;
  };
  // Bisection of one value between where it passes (lo) and where it fails (hi).
  const auto bisect = [&](double lo, double hi, const std::function<void(Setting&, double)>& set) {
    for (int i = 0; i < spec.shrink_steps; ++i) {
      const double mid = corpus::Round4(0.5 * (lo + hi));
      if (mid == lo || mid == hi) break;
      Setting t = f.shrunk;
      set(t, mid);
      if (still_fails(t)) {
        hi = mid;
      } else {
        lo = mid;
      }
    }
  };
  const Setting base = BaseSetting(spec);
  for (std::size_t i = 0; i < spec.set.size(); ++i) {
    const double found = f.shrunk.set_values[i];
    const double home = base.set_values[i];
    if (found == home) continue;
    Setting t = f.shrunk;
    t.set_values[i] = home;
    if (still_fails(t)) continue;
    bisect(std::isnan(home) ? spec.set[i].range.lo : home, found,
           [i](Setting& s, double v) { s.set_values[i] = v; });
  }
  if (spec.seed_range && f.shrunk.seed != base.seed) {
    Setting t = f.shrunk;
    t.seed = base.seed;
    still_fails(t);
  }
  for (std::size_t k = 0; k < spec.faults.size(); ++k) {
    if (!f.shrunk.faults[k].present) continue;
    Setting t = f.shrunk;
    t.faults[k].present = false;
    if (still_fails(t)) continue;
    const FaultSlot::Option& option = spec.faults[k].options[f.shrunk.faults[k].option];
    if (option.magnitude.hi > 0.0) {
      bisect(0.0, f.shrunk.faults[k].magnitude, [k](Setting& s, double v) { s.faults[k].magnitude = v; });
    }
    bisect(0.0, f.shrunk.faults[k].duration_s, [k](Setting& s, double v) { s.faults[k].duration_s = v; });
  }
}

}  // namespace

std::vector<uint64_t> ConfirmationSeeds(const SearchSpec& spec, uint64_t seed, int count) {
  const uint64_t first = spec.seed_range ? static_cast<uint64_t>(spec.seed_range->hi) + 1 : seed + 1;
  std::vector<uint64_t> seeds;
  for (uint64_t s = first; seeds.size() < static_cast<std::size_t>(count); ++s) {
    if (s != seed) seeds.push_back(s);
  }
  return seeds;
}

std::unique_ptr<Proposer> MakeProposer(const SearchSpec& spec, const fs::path& scripts_dir) {
  if (spec.optimizer == "random") {
    return std::make_unique<RandomProposer>(spec.dimensions.size(), spec.optimizer_seed);
  }
  nlohmann::json init;
  init["op"] = "init";
  init["sampler"] = spec.optimizer;
  init["seed"] = spec.optimizer_seed;
  init["dimensions"] = nlohmann::json::array();
  for (const SearchDimension& d : spec.dimensions) {
    init["dimensions"].push_back({{"name", d.name}, {"choices", d.choices}});
  }
  return std::make_unique<ProcessProposer>(
      std::vector<std::string>{"/usr/bin/python3", (scripts_dir / "search_proposer.py").string()}, init);
}

JournaledEvaluator::JournaledEvaluator(const SearchSpec& spec, FlightEvaluator& inner, fs::path journal)
    : spec_(spec), inner_(inner), journal_(std::move(journal)) {
  std::ifstream in(journal_);
  if (!in) return;
  std::string line;
  std::string kept;
  while (std::getline(in, line)) {
    const nlohmann::json j = nlohmann::json::parse(line, nullptr, false);
    if (j.is_discarded() || !j.is_object() || !j.contains("id") || !j.contains("key")) break;  // torn
    try {
      recorded_[j.at("id").get<std::string>()] = {j.at("key").get<std::string>(), MarginFromJson(j)};
    } catch (const std::exception&) {
      break;
    }
    kept += line + "\n";
  }
  in.close();
  std::ofstream rewrite(journal_, std::ios::trunc);
  rewrite << kept;
}

std::vector<FlightMargin> JournaledEvaluator::Fly(const std::vector<FlightRequest>& requests) {
  std::vector<FlightMargin> margins(requests.size());
  std::vector<std::string> keys(requests.size());
  std::vector<FlightRequest> missing;
  std::vector<std::size_t> missing_at;
  for (std::size_t i = 0; i < requests.size(); ++i) {
    keys[i] = SettingKey(spec_, requests[i]);
    const auto it = recorded_.find(requests[i].id);
    if (it != recorded_.end() && it->second.first == keys[i]) {
      margins[i] = it->second.second;
      ++reused_;
    } else {
      missing.push_back(requests[i]);
      missing_at.push_back(i);
    }
  }
  if (missing.empty()) return margins;
  const std::vector<FlightMargin> flown = inner_.Fly(missing);
  flown_ += flown.size();
  std::ofstream out(journal_, std::ios::app);
  for (std::size_t m = 0; m < missing.size(); ++m) {
    const std::size_t i = missing_at[m];
    margins[i] = flown[m];
    recorded_[requests[i].id] = {keys[i], flown[m]};
    nlohmann::json j = MarginToJson(flown[m]);
    j["id"] = requests[i].id;
    j["key"] = keys[i];
    out << j.dump() << "\n";
  }
  out.flush();
  if (!out) throw std::runtime_error(fmt::format("search: cannot write {}", journal_.string()));
  return margins;
}

SearchOutcome RunSearch(const SearchSpec& spec, FlightEvaluator& evaluator, Proposer& proposer,
                        const SearchProgress& progress) {
  SearchOutcome out;
  std::vector<Cluster> clusters;
  clusters.reserve(spec.budget);  // Confirm keeps pointers into it
  double best = std::numeric_limits<double>::infinity();
  std::size_t done = 0;
  const std::size_t batch = std::max<std::size_t>(1, spec.batch);
  bool stop = false;
  while (done < spec.budget && !stop) {
    const std::size_t n = std::min<std::size_t>(batch, spec.budget - done);
    const std::vector<std::vector<double>> units = proposer.Ask(n);
    std::vector<FlightRequest> requests;
    for (std::size_t i = 0; i < n; ++i) {
      requests.push_back({fmt::format("e{:06d}", done + i), DecodePoint(spec, units[i])});
    }
    const std::vector<FlightMargin> margins = evaluator.Fly(requests);
    std::vector<double> values;
    for (const FlightMargin& m : margins) values.push_back(m.margin);
    proposer.Tell(values);

    std::vector<Cluster*> candidates;
    for (std::size_t i = 0; i < n; ++i) {
      out.evaluations.push_back({requests[i].id, units[i], requests[i].setting, margins[i]});
      best = std::min(best, margins[i].margin);
      if (!Fails(margins[i])) continue;
      const std::string key = FailureKey(margins[i]);
      Cluster* near = nullptr;
      for (Cluster& c : clusters) {
        if (c.failure.metric == key && PointDistance(spec, c.failure.unit, units[i]) <= spec.dedupe_distance) {
          near = &c;
          break;
        }
      }
      if (near != nullptr) {
        ++near->failure.members;
        // A refuted failure comes back when a worse point of it is found: confirmed anew.
        if (near->refuted && margins[i].margin < near->failure.found_margin.margin) {
          near->refuted = false;
          near->failure.unit = units[i];
          near->failure.found = requests[i].setting;
          near->failure.found_margin = margins[i];
          near->failure.found_flight = requests[i].id;
          candidates.push_back(near);
        } else if (!near->failure.confirmed && margins[i].margin < near->failure.found_margin.margin &&
                   std::find(candidates.begin(), candidates.end(), near) != candidates.end()) {
          near->failure.unit = units[i];
          near->failure.found = requests[i].setting;
          near->failure.found_margin = margins[i];
          near->failure.found_flight = requests[i].id;
        }
        continue;
      }
      Cluster c;
      c.failure.id = fmt::format("f{}", clusters.size() + 1);
      c.failure.metric = key;
      c.failure.unit = units[i];
      c.failure.found = requests[i].setting;
      c.failure.found_margin = margins[i];
      c.failure.first_simulation = done + i + 1;
      c.failure.found_flight = requests[i].id;
      clusters.push_back(std::move(c));
      candidates.push_back(&clusters.back());
    }
    done += n;
    if (progress) progress(fmt::format("[{}/{}] best margin {:.3g}", done, spec.budget, best));
    Confirm(spec, evaluator, candidates, out, progress);
    for (const Cluster* c : candidates) {
      if (!c->failure.confirmed) continue;
      if (!out.simulations_to_first_confirmed) out.simulations_to_first_confirmed = done;
      if (spec.stop_at_first) stop = true;
    }
  }
  for (Cluster& c : clusters) {
    if (!c.failure.confirmed) continue;
    if (progress) progress(fmt::format("{}: shrinking towards the base", c.failure.id));
    Shrink(spec, evaluator, c, out);
  }
  for (Cluster& c : clusters) out.failures.push_back(std::move(c.failure));
  RankFailures(out.failures);
  return out;
}

}  // namespace tofu::campaign
