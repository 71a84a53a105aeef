#include "harness/run_directory.h"

#include <fcntl.h>
#include <spawn.h>
#include <sys/wait.h>
#include <unistd.h>

#include <cerrno>
#include <chrono>
#include <charconv>
#include <cmath>
#include <csignal>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <stdexcept>
#include <string_view>

#include <fmt/format.h>
#include <yaml-cpp/yaml.h>

#include "core/error.h"
#include "core/lie.h"
#include "harness/estimation.h"
#include "harness/run_recorder.h"
#include "harness/sensor_config.h"
#include "interface/child_process.h"
#include "replay/file_io.h"
#include "replay/interrupt.h"
#include "replay/replay.h"
#include "sim/faults.h"
#include "sim/sensor.h"

namespace tofu::harness {

using replay::EstimationConfig;
using replay::LabelEvent;
using replay::MethodFileStem;
using replay::StagingPath;
using replay::ThrowIfInterrupted;
using replay::WaitForInterrupt;
using replay::WriteFileAtomically;

namespace {

namespace fs = std::filesystem;


void EmitPose(YAML::Emitter& out, const std::string& key, const Eigen::Vector3d& p,
              const Eigen::Quaterniond& q_in) {
  const Eigen::Quaterniond q = core::CanonicalQuat(q_in.normalized());
  out << YAML::Key << key << YAML::Value << YAML::BeginMap;
  out << YAML::Key << "p_m" << YAML::Value << YAML::Flow << YAML::BeginSeq;
  for (int k = 0; k < 3; ++k) out << fmt::format("{:.6f}", p(k));
  out << YAML::EndSeq;
  out << YAML::Key << "q_wxyz" << YAML::Value << YAML::Flow << YAML::BeginSeq
      << fmt::format("{:.9f}", q.w()) << fmt::format("{:.9f}", q.x())
      << fmt::format("{:.9f}", q.y()) << fmt::format("{:.9f}", q.z()) << YAML::EndSeq;
  out << YAML::EndMap;
}

// What an estimator is given about the robot (mass properties, nominal mount extrinsics,
// each sensor's nominal noise parameters), and, marked true_*, what it is not given but
// scoring needs: the true extrinsics where a calibration error was configured and the
// true pose of each sensor's reference frame in W.
std::string CalibrationYaml(const RunRecord& record) {
  const sim::RobotDescription& robot = record.robot;
  YAML::Emitter out;
  out << YAML::Comment("tofu calibration. T_B_s: pose of mount frame s in body frame B; "
                       "T_WS: sensor reference frame S in W; quaternions [w, x, y, z].");
  out << YAML::BeginMap;
  out << YAML::Key << "robot" << YAML::Value << record.scenario.robot;
  out << YAML::Key << "mass_kg" << YAML::Value << fmt::format("{:.6f}", robot.rigid_body.mass_kg);
  out << YAML::Key << "inertia_B_kgm2" << YAML::Value << YAML::Flow << YAML::BeginSeq;
  for (int r = 0; r < 3; ++r) {
    out << YAML::Flow << YAML::BeginSeq;
    for (int c = 0; c < 3; ++c) out << fmt::format("{:.6f}", robot.rigid_body.inertia_B_kgm2(r, c));
    out << YAML::EndSeq;
  }
  out << YAML::EndSeq;
  out << YAML::Key << "p_B_CoM_m" << YAML::Value << YAML::Flow << YAML::BeginSeq;
  for (int k = 0; k < 3; ++k) out << fmt::format("{:.6f}", robot.p_B_CoM(k));
  out << YAML::EndSeq;

  out << YAML::Key << "mounts" << YAML::Value << YAML::BeginMap;
  for (const sim::MountSite& site : robot.sites) EmitPose(out, site.name, site.p_Bs, site.q_Bs);
  out << YAML::EndMap;

  out << YAML::Key << "sensors" << YAML::Value << YAML::BeginMap;
  for (size_t i = 0; i < record.sensors.size(); ++i) {
    const SensorStream& stream = record.sensors[i];
    const SensorConfig& config = record.scenario.sensors[i];
    out << YAML::Key << stream.name << YAML::Value << YAML::BeginMap;
    out << YAML::Key << "type" << YAML::Value << stream.type;
    out << YAML::Key << "site" << YAML::Value << stream.site;
    if (const sim::MountSite* site = robot.FindSite(stream.site)) {
      Eigen::Isometry3d T_Bs_true = Eigen::Isometry3d::Identity();
      T_Bs_true.linear() = site->q_Bs.toRotationMatrix();
      T_Bs_true.translation() = site->p_Bs;
      const Eigen::Isometry3d T_Bs = T_Bs_true * config.calibration_error;
      EmitPose(out, "T_B_s", T_Bs.translation(), Eigen::Quaterniond(T_Bs.linear()));
      if (config.calibration_error.matrix() != Eigen::Matrix4d::Identity()) {
        EmitPose(out, "true_T_B_s", site->p_Bs, site->q_Bs);
      }
    }
    EmitPose(out, "true_T_WS", stream.T_WS.translation(), Eigen::Quaterniond(stream.T_WS.linear()));
    if (!stream.sky_directions_S.empty()) {
      // Shortest round-trip decimals: a reader gets the very directions the run used.
      out << YAML::Key << "sky_directions_S" << YAML::Value << YAML::Flow << YAML::BeginSeq;
      for (const Eigen::Vector3d& d : stream.sky_directions_S) {
        out << YAML::Flow << YAML::BeginSeq << fmt::format("{}", d.x()) << fmt::format("{}", d.y())
            << fmt::format("{}", d.z()) << YAML::EndSeq;
      }
      out << YAML::EndSeq;
    }
    out << YAML::Key << "options" << YAML::Value << YAML::BeginMap;
    internal::EmitSensorOptions(out, config.options);
    out << YAML::EndMap;
    out << YAML::EndMap;
  }
  out << YAML::EndMap;

  // What the operator knows of the mission frame M (= W): told to every estimator.
  const sim::Waypoint launch_pad = LaunchPad(record.scenario);
  out << YAML::Key << "mission" << YAML::Value << YAML::BeginMap;
  EmitPose(out, "T_MB_launch", launch_pad.p_WB, launch_pad.q_WB);
  out << YAML::Key << "T_MS" << YAML::Value << YAML::BeginMap;
  for (size_t i = 0; i < record.sensors.size(); ++i) {
    const SensorStream& stream = record.sensors[i];
    if (!SurveyedInMission(record.scenario, record.scenario.sensors[i])) continue;
    EmitPose(out, stream.name, stream.T_WS.translation(), Eigen::Quaterniond(stream.T_WS.linear()));
  }
  out << YAML::EndMap;
  out << YAML::EndMap;
  out << YAML::EndMap;
  return std::string(out.c_str()) + "\n";
}

std::string LabelsCsv(const RunRecord& record) {
  fmt::memory_buffer out;
  fmt::format_to(std::back_inserter(out), "#timestamp [ns],sensor,label,source,active\n");
  for (const LabelEvent& l : record.labels) {
    fmt::format_to(std::back_inserter(out), "{},{},{},{},{}\n", l.t_ns, l.sensor, l.label,
                   l.source, l.active ? 1 : 0);
  }
  return fmt::to_string(out);
}

std::string ConsistencyCsv(const ConsistencyEvaluation& eval) {
  fmt::memory_buffer out;
  fmt::format_to(std::back_inserter(out), "#timestamp [ns],pair,metric,value\n");
  for (const ConsistencyRow& row : eval.rows) {
    fmt::format_to(std::back_inserter(out), "{},{},{},", row.t_ns, row.pair,
                   estimator::MetricName(row.metric));
    if (row.value) fmt::format_to(std::back_inserter(out), "{:.6g}", *row.value);
    fmt::format_to(std::back_inserter(out), "\n");
  }
  return fmt::to_string(out);
}

std::string AlignmentCsv(const ConsistencyEvaluation& eval) {
  fmt::memory_buffer out;
  fmt::format_to(std::back_inserter(out),
                 "#timestamp [ns],sensor,rotation_error [deg],observable_rotation_dofs,"
                 "rms_residual [m]\n");
  for (const AlignmentRow& row : eval.alignment) {
    fmt::format_to(std::back_inserter(out), "{},{},{:.4f},{},{:.5f}\n", row.t_ns, row.sensor,
                   row.rotation_error_deg, row.observable_rotation_dofs, row.rms_residual_m);
  }
  return fmt::to_string(out);
}

std::string TimingJson(const RunRecord& record) {
  const double simulated_s = record.scenario.physics.rate_hz > 0.0
                                 ? static_cast<double>(record.physics_steps) /
                                       record.scenario.physics.rate_hz
                                 : 0.0;
  nlohmann::json j = {
      {"wall_time_s", record.wall_time_s},
      {"simulated_s", simulated_s},
      {"real_time_factor", record.wall_time_s > 0.0 ? simulated_s / record.wall_time_s : 0.0},
      {"physics_steps_per_s",
       record.wall_time_s > 0.0 ? static_cast<double>(record.physics_steps) / record.wall_time_s
                                : 0.0},
      {"note", "wall-clock figures: the only file of the run that differs between two runs"}};
  // One entry per simulated minute: its real-time factor and the resident set at its end
  // (a long run's memory must stay flat; scripts/soak.py reads these).
  nlohmann::json minutes = nlohmann::json::array();
  double previous_wall_s = 0.0;
  for (size_t i = 0; i < record.minutes.size(); ++i) {
    const RunRecord::MinuteMark& m = record.minutes[i];
    const double wall_s = m.wall_time_s - previous_wall_s;
    minutes.push_back({{"minute", i + 1},
                       {"real_time_factor", wall_s > 0.0 ? 60.0 / wall_s : 0.0},
                       {"resident_mb", m.resident_mb}});
    previous_wall_s = m.wall_time_s;
  }
  j["minutes"] = std::move(minutes);
  return j.dump(2) + "\n";
}

}  // namespace

// Declared in run_directory.h.
int RunQuietly(const std::vector<std::string>& argv) {
  posix_spawn_file_actions_t actions;
  posix_spawn_file_actions_init(&actions);
  posix_spawn_file_actions_addopen(&actions, STDOUT_FILENO, "/dev/null", O_WRONLY, 0);
  posix_spawn_file_actions_addopen(&actions, STDERR_FILENO, "/dev/null", O_WRONLY, 0);
  std::vector<char*> args;
  for (const std::string& a : argv) args.push_back(const_cast<char*>(a.c_str()));
  args.push_back(nullptr);
  pid_t pid = 0;
  const int spawned = posix_spawn(&pid, args[0], &actions, nullptr, args.data(), environ);
  posix_spawn_file_actions_destroy(&actions);
  if (spawned != 0) return -1;
  // Waited for in slices, so that an interruption neither waits for the program nor
  // leaves it drawing into a staging directory that is about to be removed.
  int status = 0;
  for (;;) {
    const pid_t done = waitpid(pid, &status, WNOHANG);
    if (done == pid) break;
    if (done < 0 && errno != EINTR) return -1;
    if (WaitForInterrupt(50)) {
      ::kill(pid, SIGTERM);
      while (waitpid(pid, &status, 0) < 0 && errno == EINTR) {
      }
      ThrowIfInterrupted();
    }
  }
  return WIFEXITED(status) ? WEXITSTATUS(status) : -1;
}

namespace {

std::string EventsCsv(const ClosedLoopFlight& flight) {
  fmt::memory_buffer out;
  fmt::format_to(std::back_inserter(out), "#timestamp [ns],event,detail\n");
  for (const FlightEvent& e : flight.events) {
    fmt::format_to(std::back_inserter(out), "{},{},\"{}\"\n", e.t_ns, e.event, e.detail);
  }
  return fmt::to_string(out);
}

// Every file of a run (no estimation files) into `dir`, which exists.
// The per-sample files of a run kept in memory, through the recorder that writes them
// while a recorded run flies (run_recorder.h): the same bytes either way.
void WriteRecordedFiles(const RunRecord& record, const fs::path& dir) {
  RunRecorder recorder(dir, RecorderLayoutOf(record, record.closed_loop.has_value()));
  const std::size_t outputs = std::min({record.groundtruth.size(), record.references.size(),
                                        record.tracking.size()});
  for (std::size_t k = 0; k < outputs; ++k) {
    const ClosedLoopSample* control = nullptr;
    if (record.closed_loop && k < record.closed_loop->samples.size()) {
      control = &record.closed_loop->samples[k];
    }
    recorder.AddGroundTruth(record.groundtruth[k], record.references[k], record.tracking[k],
                            control);
  }
  for (std::size_t i = 0; i < record.sensors.size(); ++i) {
    const SensorStream& stream = record.sensors[i];
    for (std::size_t k = 0; k < stream.clean.size(); ++k) {
      recorder.AddClean(i, stream.clean[k],
                        k < stream.imu_biases.size() ? &stream.imu_biases[k] : nullptr);
    }
    for (std::size_t k = 0; k < stream.delivered.size(); ++k) {
      recorder.AddDelivered(i, stream.delivered[k],
                            k < stream.delivered_faults.size() ? stream.delivered_faults[k] : 0u);
    }
  }
  recorder.Close();
}

// Every file of a run (no estimation files) into `dir`, which exists: the per-sample
// files unless the run recorded them there while it flew.
void WriteRunFiles(const RunRecord& record, const Evaluation& evaluation, const fs::path& dir) {
  ThrowIfInterrupted();
  if (!record.recorded_to) WriteRecordedFiles(record, dir);
  WriteFileAtomically(dir / "scenario.yaml", ResolvedScenarioYaml(record.scenario));
  WriteFileAtomically(dir / "calibration.yaml", CalibrationYaml(record));
  WriteFileAtomically(dir / "summary.json", evaluation.summary.dump(2) + "\n");
  WriteFileAtomically(dir / "timing.json", TimingJson(record));
  if (!record.sensors.empty()) {
    WriteFileAtomically(dir / "labels.csv", LabelsCsv(record));
    if (record.consistency) {
      WriteFileAtomically(dir / "consistency.csv", ConsistencyCsv(*record.consistency));
      WriteFileAtomically(dir / "alignment.csv", AlignmentCsv(*record.consistency));
    }
  }
  if (record.closed_loop) {
    WriteFileAtomically(dir / "events.csv", EventsCsv(*record.closed_loop));
  }
}

}  // namespace

void CheckOutputDirectory(const fs::path& out_dir, bool force) {
  if (out_dir.empty()) {
    throw core::InputError({}, "--out", "expected a directory path, got an empty string");
  }
  std::error_code ec;
  const fs::file_status status = fs::status(out_dir, ec);
  if (ec || !fs::exists(status)) return;
  if (!fs::is_directory(status)) {
    throw core::InputError({out_dir.string()}, "--out",
                           "exists and is not a directory: expected a new or empty directory, "
                           "or an earlier tofu run directory with --force");
  }
  if (fs::is_empty(out_dir, ec)) return;
  if (!fs::exists(out_dir / kRunMarkerFile)) {
    throw core::InputError(
        {out_dir.string()}, "--out",
        fmt::format("holds files that are not a tofu run directory (no {}): refusing to replace "
                    "it; choose a new or empty directory",
                    kRunMarkerFile));
  }
  if (!force) {
    throw core::InputError({out_dir.string()}, "--out",
                           "holds an earlier tofu run: --force replaces it (atomically: the old "
                           "run stays until the new one is complete)");
  }
}

namespace {

fs::path NormalOutputPath(const std::string& out_dir) {
  fs::path out = fs::absolute(out_dir).lexically_normal();
  // "run/" names the directory run: its siblings, not its children, are the staging.
  if (out.filename().empty()) out = out.parent_path();
  return out;
}

}  // namespace

fs::path CreateStagingDirectory(const std::string& out_dir) {
  const fs::path staging = StagingPath(NormalOutputPath(out_dir));
  fs::remove_all(staging);
  fs::create_directories(staging);
  return staging;
}

void WriteRunDirectory(const RunRecord& record, const Evaluation& evaluation,
                       const std::string& out_dir,
                       const std::function<void(const std::filesystem::path& staging)>& finish) {
  const fs::path out = NormalOutputPath(out_dir);
  const fs::path parent = out.parent_path();
  fs::create_directories(parent);
  // A recorded run's files are in its staging directory already (CreateStagingDirectory).
  const fs::path staging = record.recorded_to ? *record.recorded_to : StagingPath(out);
  if (!record.recorded_to) fs::remove_all(staging);
  try {
    fs::create_directories(staging);
    WriteRunFiles(record, evaluation, staging);
    if (finish) finish(staging);
    // The marker last: only a complete directory holds it, never one that an interruption
    // or a SIGKILL cut short.
    WriteFileAtomically(staging / kRunMarkerFile,
                        "a tofu run directory: `tofu run --out` replaces it only with --force\n");
    // The last check point: after it the run is complete and goes into place.
    ThrowIfInterrupted();
    // Replace atomically from a reader's point of view: old aside, new in, old gone.
    const fs::path old = parent / (out.filename().string() + fmt::format(".old-{}", ::getpid()));
    if (fs::exists(out)) fs::rename(out, old);
    fs::rename(staging, out);
    fs::remove_all(old);
  } catch (...) {
    std::error_code ignored;
    fs::remove_all(staging, ignored);
    throw;
  }
}

namespace {

double SimulatedSeconds(const RunRecord& record) {
  return core::TimeToSeconds(record.physics_steps *
                             core::PeriodFromRate(record.scenario.physics.rate_hz));
}

// The run's figures (a script of scripts/ each, drawing a PNG into the run's directory),
// started before the files they read are written: a script imports matplotlib, a third
// of its time, while the run is scored, then waits for a line "go" on its standard input
// (--when-ready), which Draw() sends to all at once once the files are there. A script
// that cannot start or fails (no python3-matplotlib) is a warning. One never told to
// draw (the run failed or was interrupted first) reads the end of its input and ends
// without drawing; ChildProcess ends it if it does not.
class Figures {
 public:
  Figures(const std::vector<std::pair<std::string, fs::path>>& figures, const fs::path& dir) {
    for (const auto& [script_name, png] : figures) {
      Figure& figure = figures_.emplace_back();
      figure.script = fs::path(TOFU_SCRIPTS_DIR) / script_name;
      figure.png = png;
      if (!fs::exists(figure.script)) continue;
      try {
        figure.process = std::make_unique<interface::ChildProcess>(
            std::vector<std::string>{figure.script.string(), dir.string(), "--out", png.string(),
                                     "--when-ready"},
            fs::path());
      } catch (const std::runtime_error&) {
        // Not started (no interpreter): the warning below.
      }
    }
  }

  void Draw() {
    using Clock = interface::ChildProcess::Clock;
    std::string ignored;
    for (Figure& figure : figures_) {
      if (!figure.process) continue;
      figure.process->Communicate("go\n", &ignored, Clock::now());
      figure.process->CloseStdin();
    }
    for (Figure& figure : figures_) {
      bool drawn = false;
      if (figure.process) {
        std::optional<int> status;
        // Its output read as it comes, so that a chatty matplotlib never fills a pipe.
        while (!(status = figure.process->WaitForExit(Clock::now() + std::chrono::milliseconds(20)))) {
          figure.process->Communicate("", &ignored, Clock::now());
          ignored.clear();
        }
        drawn = WIFEXITED(*status) && WEXITSTATUS(*status) == 0;
      }
      if (!drawn) {
        fmt::print(stderr, "tofu: warning: no {} ({} failed; needs python3-matplotlib)\n",
                   figure.png.filename().string(), figure.script.string());
      }
    }
  }

 private:
  struct Figure {
    fs::path script;
    fs::path png;
    std::unique_ptr<interface::ChildProcess> process;
  };
  std::vector<Figure> figures_;
};

// A closed-loop flight into <staging>/closed_loop/<method>/: its own run files, and the
// estimate of the method that flew, scored like an open-loop method.
void WriteClosedLoopFlight(RunRecord& flight, const fs::path& dir) {
  fs::create_directories(dir);
  if (flight.scenario.estimation && !flight.failure) {
    EstimationConfig config = *flight.scenario.estimation;
    config.methods = {flight.closed_loop->method};
    WriteRunFiles(flight, Evaluate(flight), dir);
    flight.methods = EvaluateEstimation(dir, config, flight.labels, SimulatedSeconds(flight),
                                        flight.in_loop);
  }
  WriteRunFiles(flight, Evaluate(flight), dir);
}

}  // namespace

Evaluation WriteRun(RunRecord& record, const std::string& out_dir,
                    const RunOutputOptions& options) {
  Evaluation evaluation = Evaluate(record);
  const bool estimation = record.scenario.estimation && !record.failure;
  if (!estimation && record.closed_loop_flights.empty()) {
    WriteRunDirectory(record, evaluation, out_dir);
    return evaluation;
  }
  WriteRunDirectory(record, evaluation, out_dir, [&](const fs::path& staging) {
    std::vector<std::pair<std::string, fs::path>> figures;
    if (options.plot && estimation) figures.emplace_back("plot_consensus.py", staging / "consensus.png");
    if (options.plot && !record.closed_loop_flights.empty()) {
      figures.emplace_back("plot_closed_loop.py", staging / "closed_loop.png");
    }
    Figures drawing(figures, staging);
    if (estimation) {
      record.methods = EvaluateEstimation(staging, *record.scenario.estimation, record.labels,
                                          SimulatedSeconds(record), record.in_loop,
                                          options.threads);
    }
    for (RunRecord& flight : record.closed_loop_flights) {
      WriteClosedLoopFlight(flight,
                            staging / "closed_loop" / MethodFileStem(flight.closed_loop->method));
    }
    evaluation = Evaluate(record);
    WriteFileAtomically(staging / "summary.json", evaluation.summary.dump(2) + "\n");
    drawing.Draw();
  });
  return evaluation;
}

std::string CalibrationYamlText(const RunRecord& record) { return CalibrationYaml(record); }

}  // namespace tofu::harness
