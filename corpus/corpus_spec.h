#pragma once
// A corpus spec (corpora/*.yaml, docs/CORPUS.md): the distribution that failure episodes
// are drawn from (worlds, trajectory families with ranges, the sensor set, wind, fault
// distributions, open or closed loop, duration) and how many, under one corpus seed.
// Episode i is a scenario drawn from (corpus seed, i) alone: never from how the corpus is
// sharded, so any shard layout yields the same episodes, and each episode's scenario YAML
// reproduces it alone with `tofu run`.

#include <cstdint>
#include <filesystem>
#include <optional>
#include <string>
#include <vector>

#include <Eigen/Core>

#include "harness/yaml_reader.h"
#include "sim/faults.h"

namespace tofu::corpus {

/// A closed interval [lo, hi] sampled uniformly (lo == hi: a constant).
struct Range {
  double lo = 0.0;
  double hi = 0.0;
};

/// A base world and where in it the episodes fly.
struct WorldChoice {
  std::string world;                                  ///< models/worlds/<world>.xml
  Eigen::Vector2d center_xy_m = Eigen::Vector2d::Zero();  ///< free-space centre of the flights
  /// The facade the wall_pass family flies along: a point on its face and the face's
  /// normal into free space (horizontal).
  std::optional<Eigen::Vector2d> wall_point_xy_m;
  std::optional<Eigen::Vector2d> wall_normal_xy;
};

/// One kind of scheduled fault the episodes may carry.
struct FaultChoice {
  sim::FaultKind kind = sim::FaultKind::kDropout;
  std::vector<std::string> sensors;  ///< drawn uniformly; names of the spec's sensors
  double weight = 1.0;               ///< relative probability among the kinds
  /// The fault's size, per kind (docs/CORPUS.md): divergence initial velocity [m/s], jump
  /// translation [m], non-Gaussian white noise std [m], outlier scale [m], delay [s],
  /// misalignment rotation [deg]; unused by dropout and freeze.
  Range magnitude{0.0, 0.0};
};

/// A scenario file a spec includes as an episode of its own (`include:`): a hard case, such
/// as a failure `tofu search --promote` kept. It flies as written (world, trajectory,
/// sensors' options, faults, seed, duration), with the spec's methods (estimation,
/// clients, closed loop) in place of its own, so that every episode predicts alike.
struct IncludedEpisode;

struct CorpusSpec {
  std::string file;  ///< where it was read from (messages)
  std::string text;  ///< the file's text (stored with the corpus)
  std::string name;  ///< [a-z0-9_]+
  std::string description;
  std::uint64_t seed = 0;
  /// Every episode: the sampled ones (`episodes:`), then the included ones (`include:`).
  std::uint64_t episodes = 0;
  std::uint64_t sampled_episodes = 0;
  double duration_s = 0.0;  ///< of a sampled episode
  std::vector<WorldChoice> worlds;
  std::vector<std::string> families;  ///< figure_eight, circle, wall_pass
  Range speed_mps, size_m, height_m, structure_distance_m, tilt_deg;
  Range gust_std_mps{0.0, 0.0};
  Range mean_wind_mps{0.0, 0.0};  ///< horizontal, in a direction drawn uniformly
  /// The episode's `sensors:` and `estimation:` blocks, as YAML text (verbatim copies).
  std::string sensors_yaml;
  std::vector<std::string> sensor_names;
  std::string estimation_yaml;
  /// `external:` and `plugins:` (users' estimators), resolved: YAML text, "" without.
  std::string clients_yaml;
  Range fault_count{0.0, 0.0};  ///< whole numbers
  Range fault_onset_s, fault_duration_s;
  std::vector<FaultChoice> faults;
  /// Closed loop: each episode also flies on these estimation methods (`control:`).
  std::vector<std::string> closed_loop_methods;
  /// `closed_loop.controller`: who flies every flight of every episode (a client of the
  /// spec's external:/plugins:); "" = tofu's SE(3) controller.
  std::string controller;
  /// `include:` the scenario files flown as episodes sampled_episodes.. (in order).
  std::vector<IncludedEpisode> included;
};

/// A fault as planned for one episode (the severity that the fault-event table reports).
struct PlannedFault {
  std::string sensor;
  sim::FaultKind kind = sim::FaultKind::kDropout;
  double start_s = 0.0;
  double end_s = 0.0;
  double magnitude = 0.0;
};

struct IncludedEpisode {
  std::string file;  ///< absolute
  std::string copy_name;  ///< its path under a corpus directory's included/ (CopyIncluded)
  std::string text;       ///< the file's text
  std::string world;
  std::uint64_t seed = 0;
  double duration_s = 0.0;
  std::vector<PlannedFault> faults;
  /// The file's scenario without its name, expect:, estimation:, control:, external:,
  /// plugins:, render: and compare: (the plan adds the episode's name and the spec's methods).
  std::string scenario_body_yaml;
};

struct EpisodePlan {
  std::uint64_t index = 0;
  std::string id;               ///< "<corpus>_e000042"
  std::uint64_t scenario_seed = 0;
  std::string world;
  std::string family;  ///< a trajectory family, or "included"
  double duration_s = 0.0;
  double speed_mps = 0.0, size_m = 0.0, height_m = 0.0, structure_distance_m = 0.0,
         tilt_deg = 0.0, gust_std_mps = 0.0, mean_wind_mps = 0.0;
  std::vector<PlannedFault> faults;
  std::string scenario_yaml;  ///< `tofu run` on it reproduces the episode
};

/// Reads and validates a spec (strict: unknown keys, empty or inverted ranges, unknown
/// fault kinds or sensors, a wall_pass family with a world without a wall, an included
/// scenario that does not load or whose sensors are not the spec's are core::InputError
/// naming file:line, the key and the expected form). Episode 0 is
/// planned and its scenario validated, so a spec that loads plans valid scenarios.
CorpusSpec LoadCorpusSpec(const std::filesystem::path& path);
/// `included_copies`: where the included scenarios are read from instead of the paths the
/// spec names (a corpus directory's included/, CopyIncluded: the directory stands alone).
CorpusSpec ParseCorpusSpec(const std::string& text, const std::string& file_label,
                           const std::optional<std::filesystem::path>& included_copies = std::nullopt);

/// Copies the spec's included scenarios into `dir` (a corpus directory's included/), or,
/// when they are there already, checks that they are the same: a changed one is a
/// core::InputError (the corpus's episodes would no longer be its own).
void CopyIncluded(const CorpusSpec& spec, const std::filesystem::path& dir);

/// Episode `index` of the spec: a function of (spec, index) only.
EpisodePlan PlanEpisode(const CorpusSpec& spec, std::uint64_t index);

// The space's vocabulary, shared with `tofu search` (campaign/search_spec.h).

/// A planned value as a scenario file states it: rounded to 1e-4 (0.1 mm, 0.1 ms, 1e-4 of
/// a degree or a magnitude), so the file says exactly what was flown.
double Round4(double v);

/// [lo, hi] or a single number (a constant), each in `rule`; lo <= hi.
Range ReadRange(const harness::YamlValue& value, const core::NumberRule& rule);
/// An item of a `faults.kinds:` list ({kind, sensors, weight, magnitude}); its sensors must
/// be among `sensor_names`; a sized kind needs a magnitude, dropout and freeze have none.
FaultChoice ReadFaultChoice(const harness::YamlValue& item,
                            const std::vector<std::string>& sensor_names);
/// The unit vector of height z in [-1, 1] and azimuth phi: uniform on the sphere for
/// uniform (z, phi).
Eigen::Vector3d UnitDirection(double z, double phi_rad);
/// A fault of a scenario's `faults:` list as a YAML flow map: the magnitude turned into
/// the kind's own keys (docs/CORPUS.md), along `direction` for the kinds that have one
/// (divergence axis, jump translation, misalignment rotation).
std::string FaultYaml(const PlannedFault& fault, const Eigen::Vector3d& direction);

/// "figure_eight", ...: the trajectory families a spec may name.
const std::vector<std::string>& TrajectoryFamilies();

}  // namespace tofu::corpus
