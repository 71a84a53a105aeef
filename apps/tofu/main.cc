// tofu: the command line. Sub-commands map one to one onto harness functions; this file
// only parses arguments, draws progress and maps errors to exit codes (core::ExitCode).

#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <limits>
#include <map>
#include <memory>
#include <mutex>
#include <cstdio>
#include <filesystem>
#include <functional>
#include <iostream>
#include <optional>
#include <string>
#include <vector>

#include <CLI/CLI.hpp>
#include <fmt/format.h>

#include "core/cores.h"
#include "core/error.h"
#include "core/units.h"
#include "core/version.h"
#include "tofu/api.h"
#include "campaign/compare_command.h"
#include "campaign/search_command.h"
#include "corpus/corpus_command.h"
#include "campaign/check_command.h"
#include "harness/evaluation.h"
#include "harness/metrics.h"
#include "harness/run.h"
#include "harness/run_directory.h"
#include "harness/scenario.h"
#include "harness/scenario_reference.h"
#include "harness/shard.h"
#include "renders/render_command.h"
#include "replay/consistency_command.h"
#include "replay/file_io.h"
#include "interface/child_process.h"
#include "replay/interrupt.h"
#include "replay/replay.h"
#include "report/html_report.h"
#include "report/mcap_export.h"

namespace {

using tofu::core::ExitCode;

// A one-line progress bar on stderr, redrawn in place; only on a terminal.
class ProgressBar {
 public:
  explicit ProgressBar(std::string label) : label_(std::move(label)) {}
  void operator()(double fraction) {
    const int percent = static_cast<int>(fraction * 100.0);
    if (percent == last_percent_) return;
    last_percent_ = percent;
    constexpr int kWidth = 40;
    const int filled = static_cast<int>(fraction * kWidth);
    std::fprintf(stderr, "\r%s [%s%s] %3d%%", label_.c_str(), std::string(filled, '#').c_str(),
                 std::string(kWidth - filled, '.').c_str(), percent);
    if (percent >= 100) std::fprintf(stderr, "\n");
    std::fflush(stderr);
  }

 private:
  std::string label_;
  int last_percent_ = -1;
};

// A number option's range, checked on the text before CLI11 converts it: finite (NaN and
// inf are not numbers of any range), in [min, max] or (min, max]; the message names the
// range and the unit, and the option is exit 2 like any misuse.
CLI::Validator FiniteIn(double min, double max, const std::string& unit, bool min_exclusive) {
  const std::string range =
      fmt::format("{}{:g}, {:g}]{}{}", min_exclusive ? "(" : "[", min, max, unit.empty() ? "" : " ", unit);
  return CLI::Validator(
      [=](std::string& text) -> std::string {
        double value = 0.0;
        try {
          std::size_t used = 0;
          value = std::stod(text, &used);
          if (used != text.size()) return "expected a number in " + range + ", got " + text;
        } catch (const std::exception&) {
          return "expected a number in " + range + ", got " + text;
        }
        const bool above_min = min_exclusive ? value > min : value >= min;
        if (!std::isfinite(value) || !above_min || value > max) {
          return "expected a number in " + range + ", got " + text;
        }
        return std::string();
      },
      range);
}

// A count or seed: digits only (CLI11 would turn "-1" into 2^64 - 1 for an unsigned).
CLI::Validator WholeNumber(std::uint64_t min, std::uint64_t max) {
  const std::string range = fmt::format("a whole number in [{}, {}]", min, max);
  return CLI::Validator(
      [=](std::string& text) -> std::string {
        if (text.empty() || text.size() > 20 ||
            text.find_first_not_of("0123456789") != std::string::npos) {
          return "expected " + range + ", got " + text;
        }
        const unsigned long long value = std::stoull(text);
        if (value < min || value > max) return "expected " + range + ", got " + text;
        return std::string();
      },
      range);
}

std::string FormatValue(const std::optional<double>& v) {
  return v ? fmt::format("{:.4g}", *v) : std::string("n/a");
}

std::string FirstLine(const std::string& text) { return text.substr(0, text.find('\n')); }

void PrintReport(const tofu::harness::RunRecord& record,
                 const tofu::harness::Evaluation& evaluation, const std::string& out_dir) {
  fmt::print("run directory: {}\n", out_dir);
  fmt::print("simulated {:.1f} s in {:.2f} s wall ({:.0f}x real time)\n",
             record.physics_steps / record.scenario.physics.rate_hz, record.wall_time_s,
             record.wall_time_s > 0 ? record.physics_steps / record.scenario.physics.rate_hz /
                                          record.wall_time_s
                                    : 0.0);
  if (record.failure) fmt::print("SIMULATION FAILED: {}\n", *record.failure);
  for (const auto& c : record.collisions) {
    fmt::print("collision at {:.3f} s: {} hit {} (penetration {:.3f} m)\n",
               tofu::core::TimeToSeconds(c.start_ns), c.robot_geom, c.structure_geom,
               c.max_penetration_m);
  }
  if (!record.methods.empty()) {
    fmt::print("{:<24} {:>9} {:>9} {:>7} {:>10} {:>9} {:>9}\n", "method", "ATE [m]", "rot [deg]",
               "NEES", "detected", "switches", "x RT");
    for (const tofu::harness::MethodEvaluation& m : record.methods) {
      if (m.failure) {
        // A failed method's partial figures would look healthy: its row says why instead.
        fmt::print("{:<24} FAILED: {}\n", m.method, FirstLine(*m.failure));
        continue;
      }
      const std::string detected =
          m.consensus ? fmt::format("{}/{}", m.detections.size() - m.missed_faults(),
                                    m.detections.size())
                      : "-";
      fmt::print("{:<24} {:>9} {:>9} {:>7} {:>10} {:>9} {:>9.0f}\n", m.method, FormatValue(m.ate_m),
                 FormatValue(m.rotation_rmse_deg), FormatValue(m.nees_position_mean), detected,
                 m.consensus ? std::to_string(m.switches) : "-",
                 m.wall_time_s > 0 ? m.run_duration_s / m.wall_time_s : 0.0);
    }
  }
  if (!record.closed_loop_flights.empty()) {
    fmt::print("closed loop (the controller flying on each method's estimate, judged against "
               "ground truth):\n");
    fmt::print("{:<20} {:>9} {:>9} {:>9} {:>5} {:>9} {:>5} {:>8} {:>11} {:>6}\n", "flown on",
               "trk [m]", "max [m]", "est [m]", "hits", "dist [m]", "fail", "handover",
               "upd p99 ms", "x RT");
    for (const tofu::harness::RunRecord& flight : record.closed_loop_flights) {
      if (const std::optional<std::string> failure = tofu::harness::ClosedLoopFlightFailure(flight)) {
        fmt::print("{:<20} FAILED: {}\n", flight.closed_loop->method, FirstLine(*failure));
        continue;
      }
      const tofu::harness::ClosedLoopMetrics m = tofu::harness::ComputeClosedLoopMetrics(flight);
      std::vector<double> solve_ms;
      if (!flight.in_loop.empty()) {
        for (const double t : flight.in_loop.front().solver.solve_time_s) solve_ms.push_back(t * 1e3);
      }
      std::sort(solve_ms.begin(), solve_ms.end());
      const std::optional<double> p99 =
          solve_ms.empty() ? std::nullopt
                           : std::optional<double>(solve_ms[(solve_ms.size() * 99) / 100]);
      const double flown_s = flight.physics_steps / flight.scenario.physics.rate_hz;
      fmt::print("{:<20} {:>9} {:>9} {:>9} {:>5} {:>9} {:>5} {:>8} {:>11} {:>6.0f}\n",
                 flight.closed_loop->method, FormatValue(m.tracking_rmse_m),
                 FormatValue(m.tracking_max_m), FormatValue(m.estimate_ate_m), m.collisions,
                 FormatValue(m.min_structure_distance_m), m.failsafe_events,
                 FormatValue(m.handover_s), FormatValue(p99),
                 flight.wall_time_s > 0 ? flown_s / flight.wall_time_s : 0.0);
    }
  }
  if (!evaluation.expectations.empty()) {
    size_t width = 12;
    for (const auto& r : evaluation.expectations) {
      width = std::max(width, r.expectation.metric.size() + (r.expectation.window_s ? 16 : 0) +
                                  (r.expectation.relative_to ? r.expectation.relative_to->size() + 3 : 0));
    }
    fmt::print("{:<{}} {:>10} {:>10} {:>10}  {}\n", "expectation", width, "value", "min", "max",
               "result");
    for (const auto& r : evaluation.expectations) {
      std::string metric = r.expectation.metric;
      if (r.expectation.relative_to) metric += " / " + *r.expectation.relative_to;
      if (r.expectation.window_s) {
        metric += fmt::format(" [{:g},{:g}]s", r.expectation.window_s->first,
                              r.expectation.window_s->second);
      }
      fmt::print("{:<{}} {:>10} {:>10} {:>10}  {}\n", metric, width, FormatValue(r.value),
                 FormatValue(r.expectation.min), FormatValue(r.expectation.max),
                 r.passed                ? std::string("pass")
                 : r.not_measurable ? "FAIL (not measurable: " + FirstLine(*r.not_measurable) + ")"
                                    : std::string("FAIL"));
    }
  }
  fmt::print("{}\n", evaluation.passed ? "PASSED" : "FAILED");
}

// `tofu export RUN --mcap FILE` and `tofu run --mcap FILE`: the run as one MCAP file.
void ExportMcap(const std::string& run_dir, const std::string& mcap_file, bool compress, bool quiet) {
  tofu::report::McapExportOptions options;
  options.compression =
      compress ? tofu::report::McapCompression::kZstd : tofu::report::McapCompression::kNone;
  const tofu::report::McapExportResult result =
      tofu::report::ExportRunToMcap(run_dir, mcap_file, options);
  if (!quiet) {
    fmt::print("wrote {} ({} messages on {} topics, {:.1f} MB)\n", mcap_file, result.messages,
               result.messages_per_topic.size(), static_cast<double>(result.bytes) / 1e6);
  }
}

// `render:` the failure events of the run written to `out` (renders/ is written and
// renamed on its own, so a render problem never touches the run's files). Returns the
// run's `status`, or kExitBadInput when the machine cannot render.
int RenderScenarioEvents(const tofu::harness::RenderRequest& request, const std::string& out,
                         bool quiet, int status) {
  tofu::renders::RenderEventsOptions render;
  render.render.width_px = request.width_px;
  render.render.height_px = request.height_px;
  render.fps = request.fps;
  render.camera = request.camera;
  render.clip_half_s = request.clip_half_s;
  render.events.error_bound_m = request.error_bound_m;
  std::optional<ProgressBar> render_bar;
  if (!quiet && ::isatty(STDERR_FILENO)) render_bar.emplace("  render");
  // A check point of interruption too: renders/ removes its staging when it unwinds.
  render.progress = [&render_bar](double f) {
    tofu::replay::ThrowIfInterrupted();
    if (render_bar) (*render_bar)(f);
  };
  tofu::replay::ThrowIfInterrupted();
  try {
    const tofu::renders::RenderEventsResult rendered = tofu::renders::RenderRunEvents(out, render);
    if (!quiet) {
      fmt::print("rendered {} events into {} ({})\n", rendered.events.size(),
                 rendered.out_dir.string(), rendered.gl_description);
    }
  } catch (const tofu::renders::RenderUnavailableError& e) {
    // The run is written and scored; the machine cannot render: say how to fix it.
    fmt::print(stderr, "tofu: error: {}\n", e.what());
    return tofu::core::kExitBadInput;
  }
  return status;
}

int RunCommand(const std::string& scenario_path, std::optional<std::string> out_dir,
               std::optional<uint64_t> seed, bool quiet, bool force,
               const std::optional<std::string>& mcap_file, int threads, bool plots) {
  tofu::harness::Scenario scenario = tofu::harness::LoadScenario(scenario_path);
  if (seed) scenario.seed = *seed;
  const std::string out = out_dir.value_or("runs/" + scenario.name);
  // Before the flight: a run never ends by refusing its directory, or its models.
  tofu::harness::CheckOutputDirectory(out, force);
  tofu::harness::CheckScenarioModels(scenario);
  tofu::campaign::CheckScenarioMinimalEffects(scenario);
  // What killed runs to the same directory left (interrupt.h: a live run's is kept).
  for (const std::filesystem::path& stale : tofu::replay::SweepStaleStaging(out)) {
    fmt::print(stderr, "tofu: removed {}, left by an earlier run that was killed\n",
               stale.string());
  }

  tofu::harness::SimulateOptions options;
  options.threads = threads;
  std::optional<ProgressBar> bar;
  std::optional<ProgressBar> flight_bar;
  const bool draw = !quiet && ::isatty(STDERR_FILENO);
  if (draw) bar.emplace(scenario.name);
  // Set even when nothing is drawn: the progress callbacks are the simulation's check
  // points of interruption (interrupt.h).
  options.progress = [&bar](double f) {
    tofu::replay::ThrowIfInterrupted();
    if (bar) (*bar)(f);
  };
  // One bar for the closed-loop flights, the mean of their fractions: with --threads they
  // fly at once and report from their threads.
  std::mutex flight_bar_mutex;
  std::map<std::string, double> flight_fraction;
  if (scenario.control) {
    for (const std::string& method : scenario.control->methods) flight_fraction[method] = 0.0;
  }
  options.closed_loop_progress = [&](const std::string& method, double f) {
    tofu::replay::ThrowIfInterrupted();
    if (!draw || flight_fraction.empty()) return;
    const std::lock_guard lock(flight_bar_mutex);
    if (!flight_bar) {
      std::string methods;
      for (const auto& [name, fraction] : flight_fraction) methods += (methods.empty() ? "" : ", ") + name;
      flight_bar.emplace("  closed loop: " + methods);
    }
    flight_fraction[method] = f;
    double sum = 0.0;
    for (const auto& [name, fraction] : flight_fraction) sum += fraction;
    (*flight_bar)(sum / static_cast<double>(flight_fraction.size()));
  };
  // The run's files are written while it flies, into the staging directory that becomes
  // `out` when the run is complete (memory stays flat with flight time, issue 19).
  const std::filesystem::path staging = tofu::harness::CreateStagingDirectory(out);
  options.record_dir = staging;
  tofu::harness::RunRecord record;
  try {
    record = tofu::harness::Simulate(scenario, options);
    tofu::replay::ThrowIfInterrupted();
  } catch (...) {
    std::error_code ignored;
    std::filesystem::remove_all(staging, ignored);
    throw;
  }
  tofu::harness::RunOutputOptions output;
  output.threads = threads;
  output.plot = plots;
  const tofu::harness::Evaluation evaluation = tofu::harness::WriteRun(record, out, output);
  if (!quiet) PrintReport(record, evaluation, out);
  tofu::replay::ThrowIfInterrupted();
  if (mcap_file) ExportMcap(out, *mcap_file, true, quiet);
  // A user's estimator or controller that failed is printed even when quiet: the run log
  // is where `tofu check` users look for the client's last words.
  for (const std::string& failure : evaluation.client_failures) {
    fmt::print(stderr, "tofu: CLIENT FAILED: {}\n", failure);
  }
  // So is the simulation's own failure (the report above says it when not quiet): a flying
  // controller client's, with its last lines of standard error, lands here.
  if (quiet && record.failure) fmt::print(stderr, "tofu: SIMULATION FAILED: {}\n", *record.failure);
  const int status = record.failure                        ? tofu::core::kExitSimulationError
                     : !evaluation.client_failures.empty() ? tofu::core::kExitClientFailed
                     : evaluation.passed                   ? tofu::core::kExitOk
                                                           : tofu::core::kExitExpectationFailed;
  // `render:` the failure events, after the run directory is complete.
  if (scenario.render && (scenario.render->always || status != tofu::core::kExitOk)) {
    return RenderScenarioEvents(*scenario.render, out, quiet, status);
  }
  return status;
}

int ValidateCommand(const std::vector<std::string>& paths) {
  int status = tofu::core::kExitOk;
  for (const std::string& path : paths) {
    try {
      // Every check that does not need the simulation: the file, then its models.
      const tofu::harness::Scenario scenario = tofu::harness::LoadScenario(path);
      tofu::harness::CheckScenarioModels(scenario);
      tofu::campaign::CheckScenarioMinimalEffects(scenario);
      fmt::print("{}: ok ({}, {} segments, {} expectations)\n", path, scenario.name,
                 scenario.trajectory.segments.size(), scenario.expect.size());
    } catch (const tofu::core::InputError& e) {
      fmt::print(stderr, "tofu: error: {}\n", e.what());
      status = tofu::core::kExitBadInput;
    }
  }
  return status;
}

// ---- sub-commands ----
// Each Add*Command declares one sub-command's arguments on `parent` and returns what runs
// it once parsed; the options live in the returned closure.

struct Command {
  CLI::App* app = nullptr;
  /// Writes outputs: stops cleanly on SIGINT, SIGTERM and SIGHUP (replay/interrupt.h).
  bool interruptible = false;
  std::function<int()> run;
};

Command AddRunCommand(CLI::App& parent) {
  struct Options {
    std::string scenario_path;
    std::optional<std::string> out_dir;
    std::optional<uint64_t> seed;
    bool quiet = false;
    bool force = false;
    std::optional<std::string> mcap;
    int threads = tofu::core::UsableCores();
    bool no_plots = false;
  };
  auto o = std::make_shared<Options>();
  CLI::App* run = parent.add_subcommand("run", "Fly a scenario and write its run directory");
  run->add_option("scenario", o->scenario_path, "Scenario YAML file")->required();
  run->add_option("--out", o->out_dir, "Run directory (default: runs/<scenario name>)");
  run->add_option("--seed", o->seed, "Seed overriding the scenario's")
      ->check(WholeNumber(0, std::numeric_limits<std::uint64_t>::max()));
  run->add_flag("--quiet", o->quiet, "No progress bar and no report");
  run->add_flag("--force", o->force,
                "Replace an earlier run directory at --out (never a directory of other files)");
  run->add_option("--mcap", o->mcap, "Also write the run as an MCAP file (Foxglove Studio)");
  run->add_option("--threads", o->threads,
                  "Threads for the in-loop estimation methods, the closed-loop flights and the scoring "
                  "(default: the cores this process may run on); the output is the same for any number")
      ->check(WholeNumber(1, 256));
  run->add_flag("--no-plots", o->no_plots,
                "Draw no figures (consensus.png, closed_loop.png): a campaign's many flights (tofu search)");
  return {run, true, [o] {
            return RunCommand(o->scenario_path, o->out_dir, o->seed, o->quiet, o->force, o->mcap,
                              o->threads, !o->no_plots);
          }};
}

Command AddExportCommand(CLI::App& parent) {
  struct Options {
    std::string run_dir;
    std::string mcap;
    bool uncompressed = false;
    bool quiet = false;
  };
  auto o = std::make_shared<Options>();
  CLI::App* cmd =
      parent.add_subcommand("export", "Write a run directory as one MCAP file (Foxglove Studio)");
  cmd->add_option("run", o->run_dir, "Run directory")->required()->check(CLI::ExistingDirectory);
  cmd->add_option("--mcap", o->mcap, "MCAP file to write (replaced atomically)")->required();
  cmd->add_flag("--uncompressed", o->uncompressed, "Store chunks without zstd");
  cmd->add_flag("--quiet", o->quiet, "No summary line");
  cmd->footer("Topics and schemas: docs/MCAP.md. Layout for Foxglove: docs/foxglove_layout.json.");
  return {cmd, false, [o] {
            ExportMcap(o->run_dir, o->mcap, !o->uncompressed, o->quiet);
            return static_cast<int>(tofu::core::kExitOk);
          }};
}

// `tofu corpus plan|generate|verify`: three commands under one parent.
std::vector<Command> AddCorpusCommands(CLI::App& parent) {
  struct Options {
    std::string spec;
    std::string out;
    bool quiet = false;
    std::optional<std::string> shard;
    std::optional<std::uint64_t> shard_count;
  };
  auto o = std::make_shared<Options>();
  CLI::App* corpus = parent.add_subcommand(
      "corpus", "Failure corpora: sampled scenarios into labelled HDF5 shards (docs/CORPUS.md)");
  corpus->require_subcommand(1);
  CLI::App* plan =
      corpus->add_subcommand("plan", "Write each episode's scenario and the planned label counts");
  plan->add_option("spec", o->spec, "Corpus spec (corpora/*.yaml)")->required();
  plan->add_option("--out", o->out, "Plan directory")->required();
  plan->add_flag("--quiet", o->quiet, "No listing");
  CLI::App* generate = corpus->add_subcommand(
      "generate", "Fly one shard's episodes into <out>/shard_<I>_of_<N>.h5 (resumes a killed shard)");
  generate->add_option("spec", o->spec, "Corpus spec (corpora/*.yaml)")->required();
  generate->add_option("--out", o->out, "Corpus directory")->required();
  generate->add_option("--shard", o->shard,
                       "I/N: this process generates episodes i with i % N == I (default: from "
                       "SLURM_ARRAY_TASK_ID/COUNT or JOB_COMPLETION_INDEX, else 0/1)");
  generate->add_option("--shard-count", o->shard_count,
                       "N, with JOB_COMPLETION_INDEX (a Kubernetes Indexed Job's completions)")
      ->check(WholeNumber(1, 1000000));
  generate->add_flag("--quiet", o->quiet, "No per-episode lines");
  CLI::App* verify = corpus->add_subcommand(
      "verify", "Check a corpus directory; write manifest.csv/.json and CARD.md (exit 1 on a problem)");
  verify->add_option("dir", o->out, "Corpus directory")->required();
  verify->add_flag("--quiet", o->quiet, "Only problems");

  // generate keeps the default signal actions: a killed shard resumes by design.
  return {
      {plan, false, [o] { return tofu::corpus::RunCorpusPlan(o->spec, o->out, o->quiet); }},
      {generate, false,
       [o] {
         tofu::corpus::GenerateOptions options;
         options.spec = o->spec;
         options.out_dir = o->out;
         options.shard = tofu::harness::ResolveShard(o->shard, o->shard_count);
         options.quiet = o->quiet;
         std::optional<ProgressBar> bar;
         if (!o->quiet && ::isatty(STDERR_FILENO)) {
           bar.emplace("corpus");
           options.progress = [&bar](std::uint64_t done, std::uint64_t total, double) {
             (*bar)(static_cast<double>(done) /
                    static_cast<double>(std::max<std::uint64_t>(total, 1)));
           };
         }
         return tofu::corpus::RunCorpusGenerate(options);
       }},
      {verify, false, [o] { return tofu::corpus::RunCorpusVerify(o->out, o->quiet); }},
  };
}

Command AddValidateCommand(CLI::App& parent) {
  auto paths = std::make_shared<std::vector<std::string>>();
  CLI::App* validate = parent.add_subcommand("validate", "Check scenario files without running");
  validate->add_option("scenarios", *paths, "Scenario YAML files")->required();
  return {validate, false, [paths] { return ValidateCommand(*paths); }};
}

Command AddMetricsCommand(CLI::App& parent) {
  CLI::App* metrics = parent.add_subcommand("metrics", "List the metrics expectations can use");
  return {metrics, false, [] {
            for (const auto& m : tofu::harness::MetricCatalog()) {
              fmt::print("{:<36} [{}]{} {}\n", m.name, m.unit, m.windowable ? " (window_s)" : "",
                         m.description);
            }
            return static_cast<int>(tofu::core::kExitOk);
          }};
}

Command AddReferenceCommand(CLI::App& parent) {
  CLI::App* reference = parent.add_subcommand(
      "reference", "Print the reference of the scenario's option keys (docs/REFERENCE.md)");
  return {reference, false, [] {
            fmt::print("{}", tofu::harness::ScenarioReferenceMarkdown());
            return static_cast<int>(tofu::core::kExitOk);
          }};
}

Command AddCompareCommand(CLI::App& parent) {
  auto o = std::make_shared<tofu::campaign::CompareCommandOptions>();
  CLI::App* compare = parent.add_subcommand(
      "compare",
      "Better or worse, and by how much: paired statistics between two checks (or baselines) "
      "of the same scenarios and seeds, or between two methods of one check");
  compare->add_option("inputs", o->inputs,
                      "BASE NEW: check directories (tofu check --out) or baseline files "
                      "(tofu baseline); with --methods, one check directory")
      ->required();
  compare->add_option("--methods", o->methods, "BASE_METHOD NEW_METHOD within one check")
      ->expected(2);
  compare->add_option("--markdown", o->markdown_path, "Write the summary as markdown (a pull-request comment)");
  compare->add_option("--json", o->json_path, "Write every cell's statistics and seeds as JSON");
  compare->add_option("--min-effect", o->min_effects,
                      "NAME=VALUE: the smallest change that counts for a metric pattern "
                      "(methods.<method>.ate_m=0.1: 10 %) or a concrete metric; repeatable");
  compare->add_option("--fdr", o->fdr, "False-discovery rate of the improved/regressed verdicts")
      ->capture_default_str();
  compare->add_option("--fdr-procedure", o->fdr_procedure,
                      "bh (Benjamini-Hochberg: positively dependent tests) or by "
                      "(Benjamini-Yekutieli: any dependence)")
      ->capture_default_str();
  compare->add_flag("--unpaired", o->unpaired,
                    "Compare the seed sets as independent samples (other seeds on each side)");
  compare->add_flag("--quiet", o->quiet, "No table");
  compare->footer("Exit 0: nothing regressed; 1: a cell regressed; 2: the inputs cannot be compared "
                  "(another grid, scenario file, seed set, tofu or metric version), nothing written.");
  return {compare, false, [o] { return tofu::campaign::RunCompareCommand(*o); }};
}

Command AddSearchCommand(CLI::App& parent) {
  auto o = std::make_shared<tofu::campaign::SearchCommandOptions>();
  CLI::App* search = parent.add_subcommand(
      "search",
      "Find where it breaks: search a spec's space of faults and settings for flights that fail "
      "the base scenario's expectations; confirm, shrink and keep them as tests");
  search->add_option("spec", o->spec_path, "Search spec YAML (searches/*.yaml, docs/SEARCH.md)")->required();
  search->add_option("--out", o->out_dir, "Output directory; a search killed there resumes with the same result")
      ->required();
  search->add_option("--jobs", o->jobs,
                     "Flights at once (default: the cores this process may run on); the flights are the same for any number")
      ->check(WholeNumber(0, 256));
  search->add_option("--promote", o->promote_dir,
                     "DIR: write each confirmed failure as a regression scenario there (its violated "
                     "expectation, so tofu check fails until the cause is fixed)");
  search->add_option("--optimizer", o->optimizer, "Override the spec's optimizer: random or tpe");
  search->add_option("--optimizer-seed", o->optimizer_seed, "Override the spec's optimizer seed")
      ->check(WholeNumber(0, std::numeric_limits<std::uint64_t>::max()));
  search->add_flag("--no-renders", [o](std::int64_t) { o->renders = false; }, "Do not render the failures' flights");
  search->add_flag("--quiet", o->quiet, "No progress and no table");
  auto shard = std::make_shared<std::optional<std::string>>();
  auto shard_count = std::make_shared<std::optional<std::uint64_t>>();
  search->add_option("--shard", *shard,
                     "I/N: fly shard I of a search spread over N machines: an independent search of "
                     "budget/N flights seeded seed + I into <out>/shard_<I>_of_<N>/. Default: from "
                     "SLURM_ARRAY_TASK_ID/COUNT or JOB_COMPLETION_INDEX, else the whole search");
  search->add_option("--shard-count", *shard_count, "N, with JOB_COMPLETION_INDEX")->check(WholeNumber(1, 1000000));
  search->add_flag("--merge", o->merge,
                   "Fly nothing: merge the finished shards in --out (failures de-duplicated across them), "
                   "write its search.json, failures and report inputs, and promote");
  search->footer("Exit 0: no confirmed failure; 1: a confirmed failure was found; 2: bad spec or options, "
                 "or --out holds a search of another spec (nothing flown). Across machines: "
                 "scripts/search.sbatch (an array of shards, then the merge).");
  return {search, true, [o, shard, shard_count] {
            if (!o->merge || *shard) o->shard = tofu::harness::ResolveShard(*shard, *shard_count);
            return tofu::campaign::RunSearchCommand(*o);
          }};
}

Command AddBaselineCommand(CLI::App& parent) {
  struct Options {
    std::string check_dir;
    std::string out;
    bool quiet = false;
  };
  auto o = std::make_shared<Options>();
  CLI::App* baseline = parent.add_subcommand(
      "baseline", "Write a check's cells (metrics, digests, scenario hashes, versions) as a "
                  "baseline file for tofu compare");
  baseline->add_option("check", o->check_dir, "A check directory (tofu check --out)")->required();
  baseline->add_option("--out", o->out, "The baseline file")->required();
  baseline->add_flag("--quiet", o->quiet, "Print nothing");
  return {baseline, false,
          [o] { return tofu::campaign::RunBaselineCommand(o->check_dir, o->out, o->quiet); }};
}

// `tofu check ... --report DIR`: the check, then the HTML report of this check's runs.
int CheckWithReport(const tofu::campaign::CheckCommandOptions& options,
                    const std::string& report_dir) {
  // A bad --report is bad input found before anything runs, like every other option.
  tofu::report::CheckReportOutputDirectory(report_dir);
  const int status = tofu::campaign::RunCheckCommand(options);
  // The report covers this check's scenarios only (the directory may hold older ones).
  std::vector<std::string> names;
  try {
    for (const std::string& path : tofu::campaign::ExpandScenarioInputs(
             options.inputs.empty() ? std::vector<std::string>{"scenarios"} : options.inputs)) {
      names.push_back(tofu::harness::LoadScenario(path).name);
    }
    if (tofu::report::DetectReportInput(options.out_dir) != tofu::report::ReportInputKind::kCheck) {
      throw tofu::core::InputError({options.out_dir}, "--out", "holds no runs");
    }
  } catch (const tofu::core::InputError& e) {
    // The check refused its input (already said why) and ran nothing: no report.
    fmt::print(stderr, "tofu: no report: the check ran nothing ({})\n", e.what());
    return status != tofu::core::kExitOk ? status : tofu::core::kExitBadInput;
  }
  try {
    tofu::replay::SweepStaleStaging(report_dir);
    const auto page = tofu::report::WriteCheckReport(options.out_dir, report_dir, names);
    if (!options.quiet) fmt::print("HTML report: {}\n", page.string());
  } catch (const tofu::core::InputError& e) {
    fmt::print(stderr, "tofu: error: report: {}\n", e.what());
    return status != tofu::core::kExitOk ? status : tofu::core::kExitBadInput;
  }
  return status;
}

Command AddCheckCommand(CLI::App& parent) {
  struct Options {
    tofu::campaign::CheckCommandOptions check;
    std::optional<std::string> report;
    std::optional<std::string> shard;
    std::optional<std::uint64_t> shard_count;
  };
  auto o = std::make_shared<Options>();
  CLI::App* check = parent.add_subcommand(
      "check",
      "Run scenarios over seeds as CI: table, JUnit XML, exit code; across machines, "
      "--shard I/N runs one part of the scenario x seed grid and --merge DIR... writes "
      "what one machine would");
  check->add_option("scenarios", o->check.inputs,
                    "Scenario files or directories of *.yaml (default: scenarios)");
  check->add_option("--junit", o->check.junit_path, "Write JUnit XML to this file");
  check->add_option("--jobs", o->check.jobs, "Parallel runs (default: the cores this process may run on)")
      ->check(WholeNumber(0, 256));
  check->add_option("--seeds", o->check.seeds,
                    "Seeds per scenario: its seed + 0..N-1 (pass_fraction applies)")
      ->capture_default_str()
      ->check(WholeNumber(1, 100000));
  check->add_option("--out", o->check.out_dir, "Output directory: <out>/<scenario>/seed_<s>")
      ->capture_default_str();
  check->add_flag("--quiet", o->check.quiet, "No progress and no table (failures still)");
  check->add_option("--report", o->report,
                    "After the check, write its HTML report (tofu report) to this directory");
  check->add_option("--shard", o->shard,
                    "I/N: run only the cells c of the scenario x seed grid (c = scenario index "
                    "x seeds + seed offset) with c % N == I, and record them in "
                    "<out>/check_shard_<I>_of_<N>.json; no JUnit, table or report (the merge "
                    "writes them). Default: from SLURM_ARRAY_TASK_ID/COUNT or "
                    "JOB_COMPLETION_INDEX, else the whole grid");
  check->add_option("--shard-count", o->shard_count,
                    "N, with JOB_COMPLETION_INDEX (a Kubernetes Indexed Job's completions)")
      ->check(WholeNumber(1, 1000000));
  check->add_option("--merge", o->check.merge_dirs,
                    "DIR...: run nothing; merge the --out directories of shards 0..N-1 of this "
                    "same check (same scenarios and --seeds) into --out and write the JUnit, "
                    "table, method tables and report one machine would, with its exit code");
  check->add_option("--baseline", o->check.baseline_path,
                    "FILE|DIR: compare with a baseline (tofu baseline's file, or a check "
                    "directory) of the same scenarios and seeds; a regressed cell fails its "
                    "scenario's JUnit case \"compared with the baseline\" and the check (exit 1); "
                    "<out>/compare.md and compare.json hold the comparison");
  check->footer(
      "Across machines (README, `tofu check`): run `tofu check SCENARIOS --seeds S --out "
      "DIR_I --shard I/N` for I = 0..N-1 (or as a Slurm array / Kubernetes Indexed Job: "
      "scripts/check.sbatch), then `tofu check SCENARIOS --seeds S --out OUT --junit FILE "
      "--report DIR --merge DIR_0 ... DIR_N-1`. Shards may share one --out on a shared file "
      "system. A shard exits 0 once its runs are recorded; the merge exits as one machine's "
      "check would.");
  return {check, true, [o] {
            // A merge is no shard, even when it runs inside an array task's environment.
            if (o->check.merge_dirs.empty() || o->shard) {
              o->check.shard = tofu::harness::ResolveShard(o->shard, o->shard_count);
            }
            if (o->report && !o->check.shard.origin.empty()) {
              throw tofu::core::InputError(
                  {}, "--report",
                  fmt::format("shard {}/{} (from {}) writes no report: give --report to the "
                              "merge (tofu check ... --merge DIR...), which has every seed",
                              o->check.shard.index, o->check.shard.count, o->check.shard.origin));
            }
            if (o->report) return CheckWithReport(o->check, *o->report);
            return tofu::campaign::RunCheckCommand(o->check);
          }};
}

Command AddConsistencyCommand(CLI::App& parent) {
  auto o = std::make_shared<tofu::replay::ConsistencyCommandOptions>();
  CLI::App* consistency = parent.add_subcommand(
      "consistency", "Consistency metric between two velocity CSVs over a sliding window");
  consistency->add_option("--metric", o->metric, "mae, pcc, kl or cm")->required();
  consistency->add_option("--window", o->window_s, "Window length [s]")
      ->capture_default_str()
      ->check(FiniteIn(0.0, 3600.0, "s", true));
  // Velocity streams come at most at a few kHz: a faster evaluation only repeats windows
  // (1e6 Hz ran for minutes, 1e7 Hz ran out of memory).
  consistency->add_option("--rate", o->rate_hz, "Evaluation rate [Hz]")
      ->capture_default_str()
      ->check(FiniteIn(0.0, 1000.0, "Hz", true));
  consistency->add_flag("--standardize", o->standardize, "Pooled standardization per axis");
  consistency->add_option("--kl-bandwidth-scale", o->kl_bandwidth_scale,
                          "KL only: factor on the Silverman bandwidth")
      ->capture_default_str()
      ->check(FiniteIn(0.0, 100.0, "", true));
  consistency->add_option("A", o->path_a, "Velocity CSV of stream A")->required();
  consistency->add_option("B", o->path_b, "Velocity CSV of stream B")->required();
  consistency->add_option("--out", o->out_path, "Output CSV (default: stdout)");
  consistency->footer(tofu::replay::kConsistencyHelp);
  return {consistency, false, [o] {
            tofu::replay::RunConsistencyCommand(*o);
            return static_cast<int>(tofu::core::kExitOk);
          }};
}

Command AddEstimateCommand(CLI::App& parent) {
  struct Options {
    tofu::replay::EstimateCommandOptions est;
    std::optional<std::string> out;
    std::vector<std::string> settings;
  };
  auto o = std::make_shared<Options>();
  tofu::replay::EstimateCommandOptions& est = o->est;
  CLI::App* estimate = parent.add_subcommand(
      "estimate", "Run the multi-graph estimator on recorded streams (run directory or real log)");
  estimate->add_option("log", est.log_dir,
                       "A tofu run directory (sensors/, calibration.yaml) or a real log "
                       "(mav0/imu0/data.csv + *.tum pose streams)")
      ->required();
  estimate->add_option("--method", est.methods,
                       "single:<sensor>, fuse:<a>+<b> or imu_only; repeatable "
                       "(default: single:<s> for every sensor)");
  estimate->add_option("--out", o->out, "Output directory (default: the log's)");
  estimate->add_flag("--clean", est.use_clean_streams,
                     "Replay the un-faulted streams (sensors/clean/) of a run directory");
  estimate->add_flag("--quiet", est.quiet, "No progress bar and no table");
  estimate->add_option("--window", est.window_s, "Fixed lag of the local graph [s] (0.5)")
      ->check(FiniteIn(0.0, 60.0, "s", true));
  estimate->add_option("--keyframe-rate", est.keyframe_rate_hz, "Keyframes per sensor [Hz] (30)")
      ->check(FiniteIn(0.1, 1000.0, "Hz", false));
  estimate->add_option("--between-position-std", est.between_position_std_m,
                       "Pose sensors: std of one relative position [m] (0.01)")
      ->check(FiniteIn(0.0, 100.0, "m", true));
  estimate->add_option("--between-rotation-std", est.between_rotation_std_rad,
                       "Pose sensors: std of one relative rotation [rad] (0.01)")
      ->check(FiniteIn(0.0, tofu::core::kPi, "rad", true));
  estimate->add_option("--imu-noise-scale", est.imu_noise_scale,
                       "Factor on the IMU white-noise densities")
      ->check(FiniteIn(0.0, 1000.0, "", true));
  estimate->add_option("--set", o->settings,
                       "KEY=VALUE: a key of the scenario's estimation: block over the run's "
                       "own (a real log: over the default profile's), e.g. profile=paper (the "
                       "keys the run set otherwise than its profile kept), huber_delta=3, "
                       "consensus.metric=nis; repeatable (docs/REFERENCE.md)");
  estimate->add_option("--position-in-reference", est.between_position_in_reference,
                       "Pose sensors: relative position in the sensor's frame (true/false)");
  return {estimate, true, [o] {
            tofu::replay::EstimateCommandOptions& options = o->est;
            if (o->out) options.out_dir = *o->out;
            std::optional<ProgressBar> bar;
            std::string bar_method;
            const bool draw = !options.quiet && isatty(STDERR_FILENO);
            // Set even when nothing is drawn: the check point of interruption of the replay.
            options.progress = [&](const std::string& method, double f) {
              tofu::replay::ThrowIfInterrupted();
              if (!draw) return;
              if (method != bar_method) {
                bar.emplace("estimate " + method);
                bar_method = method;
              }
              (*bar)(f);
            };
            // A tofu run directory's own scenario configures the methods as in its flight.
            options.read_estimation_config = [](const std::filesystem::path& scenario_yaml) {
              return tofu::harness::LoadScenario(scenario_yaml.string()).estimation;
            };
            options.apply_settings = [o](tofu::replay::EstimationConfig* config) {
              tofu::harness::ApplyEstimationSettings(o->settings, config);
            };
            // Keys and values are checked before the log is read (a rule between a setting
            // and the run's own block is checked once that is read).
            tofu::replay::EstimationConfig probe = tofu::replay::EstimationConfig::Defaults(
                tofu::replay::EstimationConfig::kDefaultProfile);
            options.apply_settings(&probe);
            return tofu::replay::RunEstimateCommand(options);
          }};
}

Command AddRenderCommand(CLI::App& parent) {
  auto o = std::make_shared<tofu::renders::RenderCommandOptions>();
  tofu::renders::RenderCommandOptions& rend = *o;
  CLI::App* render = parent.add_subcommand(
      "render", "Render a run off-screen (EGL): its failure events, or one instant");
  render->add_option("run_dir", rend.run_dir, "A tofu run directory")->required();
  CLI::Option* render_events =
      render->add_flag("--events", rend.events, "Keyframe + clip of every failure event (default)");
  render->add_option("--at", rend.at_s, "One PNG of this instant [s]")->excludes(render_events);
  render->add_option("--size", rend.size, "Frame size WxH [px]")->capture_default_str();
  render->add_option("--fps", rend.fps, "Clip frame rate")->capture_default_str();
  render->add_option("--camera", rend.camera, "chase, overview or a model camera")
      ->capture_default_str();
  render->add_option("--out", rend.out, "Output directory (--events) or PNG (--at)");
  render->add_option("--method", rend.methods, "Ghost of this method; repeatable (default: all)");
  render->add_option("--metric", rend.metric, "Consistency metric shown (default: the first)");
  render->add_option("--error-bound", rend.error_bound_m, "Position error event bound [m]")
      ->capture_default_str();
  render->add_option("--clip-half", rend.clip_half_s, "Clip span around an event [s]")
      ->capture_default_str();
  render->add_flag("--shadows", rend.shadows, "Shadow maps (slower on a CPU)");
  render->add_flag("--reflections", rend.reflections, "Floor reflections (slower on a CPU)");
  render->add_option("--msaa", rend.msaa, "Multisamples (-1: 4 on a GPU, 0 on a CPU)")
      ->capture_default_str();
  render->add_flag("--lidar", rend.lidar_hits, "Draw the LiDAR's hits");
  render->add_flag("--sky", rend.gnss_sky, "Draw the GNSS satellite rays");
  render->add_flag("--no-clips", rend.no_clips, "Keyframes only");
  render->add_option("--egl-platform", rend.egl_platform, "auto, surfaceless or device");
  render->add_flag("--quiet", rend.quiet, "No progress and no listing");
  render->footer(tofu::renders::kRenderHelp);
  return {render, false, [o] {
            std::optional<ProgressBar> bar;
            if (!o->quiet && isatty(STDERR_FILENO)) {
              bar.emplace("render");
              o->progress = [&bar](double f) { (*bar)(f); };
            }
            try {
              return tofu::renders::RunRenderCommand(*o);
            } catch (const tofu::renders::RenderUnavailableError& e) {
              // Not the user's files but the machine: still bad input to fix, not a failed run.
              fmt::print(stderr, "tofu: error: {}\n", e.what());
              return static_cast<int>(tofu::core::kExitBadInput);
            }
          }};
}

Command AddReportCommand(CLI::App& parent) {
  struct Options {
    std::string input;
    std::string out;
  };
  auto o = std::make_shared<Options>();
  CLI::App* report = parent.add_subcommand(
      "report", "A self-contained HTML report of a run, a check or a search directory");
  report->add_option("input", o->input,
                     "A run directory (tofu run --out), a check directory (tofu check --out) or a "
                     "search directory (tofu search --out)")
      ->required();
  report->add_option("--out", o->out,
                     "Report directory: index.html (+ media/; a check: <scenario>/seed_<s>/ "
                     "pages; a search: failures/<id>/ pages); new, empty or an earlier report, "
                     "which is replaced")
      ->required();
  return {report, true, [o] {
            // The report directory is staged as <out>.tmp-<pid> too: sweep what killed
            // reports left.
            if (!o->out.empty()) tofu::replay::SweepStaleStaging(o->out);
            const auto page = tofu::report::WriteReport(o->input, o->out);
            fmt::print("report: {}\n", page.string());
            return static_cast<int>(tofu::core::kExitOk);
          }};
}

// Runs the parsed command, mapping what it throws to an exit code (core::ExitCode).
int RunMapped(const Command& command) {
  try {
    return command.run();
  } catch (const tofu::replay::Interrupted& e) {
    // Unwinding removed the staging directories and waited for the children.
    fmt::print(stderr, "tofu: interrupted by {}: stopped, temporary files removed\n",
               tofu::replay::InterruptSignalName(e.signal));
    return tofu::replay::InterruptExitCode(e.signal);
  } catch (const tofu::core::InputError& e) {
    fmt::print(stderr, "tofu: error: {}\n", e.what());
    return tofu::core::kExitBadInput;
  } catch (const tofu::core::IoError& e) {
    fmt::print(stderr, "tofu: error: {}\n", e.what());
    return tofu::core::kExitIoError;
  } catch (const std::filesystem::filesystem_error& e) {
    // A directory or file the machine would not let tofu make, move or list: I/O.
    fmt::print(stderr, "tofu: error: {}\n", e.what());
    return tofu::core::kExitIoError;
  } catch (const std::exception& e) {
    fmt::print(stderr, "tofu: error: {}\n", e.what());
    return tofu::core::kExitSimulationError;
  }
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"tofu: simulation-in-the-loop test harness for multi-sensor state estimation"};
  app.set_version_flag("--version", fmt::format("tofu {} (commit {}, tofu/api.h version {})",
                                                tofu::core::TofuVersion(), tofu::core::TofuCommit(),
                                                TOFU_API_VERSION));
  app.require_subcommand(1);
  // In the order of `tofu --help`.
  std::vector<Command> commands;
  commands.push_back(AddRunCommand(app));
  commands.push_back(AddExportCommand(app));
  for (Command& c : AddCorpusCommands(app)) commands.push_back(std::move(c));
  commands.push_back(AddValidateCommand(app));
  commands.push_back(AddMetricsCommand(app));
  commands.push_back(AddReferenceCommand(app));
  commands.push_back(AddCheckCommand(app));
  commands.push_back(AddCompareCommand(app));
  commands.push_back(AddBaselineCommand(app));
  commands.push_back(AddSearchCommand(app));
  commands.push_back(AddConsistencyCommand(app));
  commands.push_back(AddEstimateCommand(app));
  commands.push_back(AddRenderCommand(app));
  commands.push_back(AddReportCommand(app));

  try {
    app.parse(argc, argv);
  } catch (const CLI::CallForHelp& e) {
    return app.exit(e);
  } catch (const CLI::CallForVersion& e) {
    return app.exit(e);
  } catch (const CLI::ParseError& e) {
    app.exit(e);
    return tofu::core::kExitBadInput;
  }

  for (const Command& command : commands) {
    if (!command.app->parsed()) continue;
    // The commands that write outputs stop cleanly on SIGINT, SIGTERM and SIGHUP: staging
    // removed, children stopped, exit 128 + signal (replay/interrupt.h). The others keep
    // the default action (`tofu corpus generate` resumes a killed shard by design).
    if (command.interruptible) {
      tofu::replay::InstallInterruptHandlers();
      // A wait for a user's estimator or controller is a check point too.
      tofu::interface::SetInterruptCheck(&tofu::replay::ThrowIfInterrupted,
                                         tofu::replay::InterruptWakeFd());
    }
    return RunMapped(command);
  }
  return tofu::core::kExitOk;
}
