#pragma once
// A scenario: the typed, validated form of scenarios/*.yaml. Loading is strict: unknown
// keys, missing required keys, wrong types, non-finite and out-of-range values are
// InputErrors that name file:line:column, the key path and the expected form.

#include <cstdint>
#include <map>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "core/error.h"
#include "harness/closed_loop.h"
#include "harness/consistency_eval.h"
#include "harness/estimation.h"
#include "harness/sensor_suite.h"
#include "sim/faults.h"
#include "sim/controller.h"
#include "sim/trajectory.h"
#include "sim/wind.h"

namespace tofu::harness {

struct PhysicsOptions {
  double rate_hz = 1000.0;  ///< MuJoCo timestep = 1 / rate_hz; 100 .. 10000
};

struct OutputOptions {
  double groundtruth_rate_hz = 200.0;  ///< rate of groundtruth.csv/.tum; <= physics rate
};

/// One assertion on a summary metric: min <= value <= max (at least one bound given).
struct Expectation {
  std::string metric;  ///< a name of MetricCatalog()
  std::optional<double> min;
  std::optional<double> max;
  /// [from, to] in seconds of run time, only for windowable metrics.
  std::optional<std::pair<double, double>> window_s;
  /// `tofu check --seeds N`: the expectation passes when it held in at least
  /// ceil(pass_fraction * N) seeds; in (0, 1]. One `tofu run` (one seed) needs it to hold.
  double pass_fraction = 1.0;
  /// The asserted value is metric / relative_to (same window), e.g. consensus ATE over
  /// naive ATE ("at most a third of naive's": relative_to methods.naive.ate_m, max 0.333).
  std::optional<std::string> relative_to;
  core::SourceLocation location;  ///< where it was written, for reports
};

/// The robot starts displaced from the trajectory's start pose (at rest), so that the
/// controller has to settle: p_WB(0) = p_start + position_W_m, q_WB(0) = q_start * q_offset.
struct InitialOffset {
  Eigen::Vector3d position_W_m = Eigen::Vector3d::Zero();
  Eigen::Quaterniond q_offset = Eigen::Quaterniond::Identity();
};

/// `mission:` what the operator knows of the mission frame M before the flight. M is the
/// simulator's world W: the survey the trajectory, the structure and the scoring are in.
/// The estimator is told the launch pad's pose (the robot waits there until the closed
/// loop hands over to it) and the surveyed reference frames of absolute sensors (their
/// true T_WS: a total station set up on surveyed points, a GNSS ENU frame tied to the
/// site), never the robot's true pose.
struct MissionConfig {
  /// `launch_pad: {position_m, rpy_deg}`: the body's pose on the pad; unset: the
  /// trajectory's start pose (where the robot is placed, initial_offset aside).
  std::optional<sim::Waypoint> launch_pad;
  /// `surveyed: [names]`: the total_station and gnss sensors whose frames are surveyed;
  /// unset: all of them.
  std::optional<std::vector<std::string>> surveyed;
};

/// `render:` what `tofu run` renders of the run (renders/, off-screen EGL) after writing
/// it: the failure events (fault onset, detection, switch, error above a bound,
/// collision) as keyframe PNGs and clips in <out>/renders/. Plain data: harness never
/// includes renders; the CLI maps it onto renders::RenderEventsOptions.
struct RenderRequest {
  bool always = false;  ///< `when: always`; default `failure`: only when an expectation failed
  int width_px = 640;
  int height_px = 480;
  int fps = 30;
  std::string camera = "chase";  ///< chase, overview or a camera of the world model
  double clip_half_s = 2.0;
  double error_bound_m = 0.5;
};

struct Scenario {
  std::string name;         ///< required; [a-z0-9_]+
  std::string description;  ///< optional free text
  std::string source_file;  ///< path it was loaded from
  std::string world;        ///< models/worlds/<world>.xml, required
  std::string robot = "omav";  ///< models/robots/<robot>.xml
  double duration_s = 0.0;  ///< required, > 0; may exceed the trajectory (holds the end)
  uint64_t seed = 0;        ///< default 0; `tofu run --seed` overrides
  PhysicsOptions physics;
  sim::ControllerOptions controller;
  sim::TrajectorySpec trajectory;
  InitialOffset initial_offset;
  sim::WindOptions wind;
  OutputOptions output;
  /// `sensors:` a map of stream name -> options; `type:` selects the model and may be
  /// left out when the name is a type (imu, vio, lidar_odometry, total_station, gnss).
  std::vector<SensorConfig> sensors;
  /// `faults:` scheduled faults, each on one sensor of `sensors`.
  std::vector<sim::FaultSpec> faults;
  /// `consistency:` evaluate the consistency of the sensors' body velocities (off when
  /// absent).
  std::optional<ConsistencyConfig> consistency;
  /// `estimation:` the estimation methods `tofu run` replays on the run's streams and
  /// scores (harness/estimation.h); none when absent.
  /// Users' estimators and controllers (`external:`, `plugins:`; harness/client_config.h).
  std::vector<replay::ClientSpec> clients;
  std::optional<replay::EstimationConfig> estimation;
  /// `control:` where the controller gets its state: ground truth (default), or each
  /// listed estimation method in a closed-loop flight of its own (harness/closed_loop.h).
  std::optional<ControlConfig> control;
  MissionConfig mission;
  std::optional<RenderRequest> render;
  /// `compare: {minimal_effects: {<metric>: <effect>}}`: this scenario's minimal effects
  /// for `tofu compare` (campaign/compared_metrics.h: a pattern such as
  /// "methods.<method>.ate_m" or a concrete name such as "methods.consensus.ate_m"; the
  /// names are checked by the campaign layer, campaign::CheckScenarioMinimalEffects). Their
  /// key locations: "compare.minimal_effects.<metric>".
  std::map<std::string, double> compare_minimal_effects;
  std::vector<Expectation> expect;
  /// Where keys were written, for the errors found after parsing (CheckScenarioModels):
  /// "world", "robot", "trajectory", "sensors.<name>", "render.camera". Missing when the
  /// key was left to its default.
  std::map<std::string, core::SourceLocation> key_locations;
};

/// The launch pad's pose of B in M (mission.launch_pad, else the trajectory's start).
sim::Waypoint LaunchPad(const Scenario& scenario);
/// Whether `sensor`'s reference frame is surveyed in M (mission.surveyed, else every
/// total_station and gnss sensor).
bool SurveyedInMission(const Scenario& scenario, const SensorConfig& sensor);

/// Reads and validates a scenario file. Throws core::InputError on any problem.
Scenario LoadScenario(const std::string& path);

/// Same, from YAML text; `file_label` is used in error messages.
Scenario ParseScenario(const std::string& yaml_text, const std::string& file_label);

/// `tofu estimate --set KEY=VALUE`: each setting of a key of the `estimation:` block
/// (`profile`, `huber_delta`, ..., `consensus.<key>`; replay::EstimationConfig::Fields and
/// ConsensusConfig::Fields) applied to *config, VALUE in the scenario's form. `profile`
/// applies first: every option the run left at its own profile's default takes the new
/// profile's, every option it set otherwise keeps its value (methods, clients and the
/// priority kept); a metric set without a threshold takes the profile's threshold for it,
/// as in a scenario. Throws core::InputError naming the setting for an unknown key, a
/// value outside its limits or a rule between fields broken.
void ApplyEstimationSettings(const std::vector<std::string>& settings,
                             replay::EstimationConfig* config);

/// A resolved `estimation:` block alone ({estimation: {...}}, as a client's setup carries
/// it: replay::EstimationConfig::resolved_yaml), for the streams `sensors` of which `imu`
/// is the IMU. Its method names are not checked (the client's side does not know the
/// scenario's clients, and runs one method of its own choosing).
replay::EstimationConfig ParseEstimationBlock(const std::string& yaml_text,
                                              const std::string& file_label,
                                              const std::vector<std::string>& sensors,
                                              const std::string& imu);

/// The checks of a loaded scenario that need its models but not the simulation (`tofu
/// validate`; `tofu check` and `tofu run` before anything flies): the world and robot
/// model files exist and MuJoCo loads them, the robot has the tool_tip site the harness
/// needs, the trajectory can be built in that world (an approach segment finds its
/// surface), every sensor's model can be set up on this robot in this world (its mount
/// site, the total station's tripod), render.camera is chase, overview or a camera of
/// the world, and every user's client can start: its command resolves to an executable
/// file, its plug-in library loads and speaks this API version (CheckClientsResolve; no
/// client is started). Throws core::InputError naming the scenario file, the key and the
/// problem (exit 2). One model load: about 10-50 ms. `models_dir` empty:
/// sim::DefaultModelsDir().
void CheckScenarioModels(const Scenario& scenario, const std::string& models_dir = "");

/// The scenario as YAML with every default filled in; loading it back yields an equal
/// scenario. Deterministic text (fixed key order, round-trip float formatting).
std::string ResolvedScenarioYaml(const Scenario& scenario);

}  // namespace tofu::harness
