#pragma once
// A search spec (searches/*.yaml, docs/SEARCH.md): a base scenario, the space of changes to
// it (fault slots in the corpus spec's vocabulary, numeric keys of the base by path, the
// seed), the objective (some of the base's expectations), a budget, the optimiser and how
// failures are confirmed. A point of the space is a vector in the unit cube; a Setting is
// what it means in the base's units; ScenarioYaml writes the base scenario with a
// setting applied, a file that reproduces the evaluation alone with `tofu run`.

#include <cstdint>
#include <filesystem>
#include <optional>
#include <string>
#include <vector>

#include "corpus/corpus_spec.h"
#include "harness/scenario.h"

namespace tofu::campaign {

/// A fault that may be added to the base: one of `options` (a kind and a sensor, from the
/// corpus vocabulary `{kind, sensors, magnitude}`), an onset and a duration in ranges.
struct FaultSlot {
  struct Option {
    sim::FaultKind kind = sim::FaultKind::kDropout;
    std::string sensor;
    corpus::Range magnitude{0.0, 0.0};  ///< {0, 0}: a kind without magnitude
  };
  std::vector<Option> options;  ///< every (kind, sensor) pair of the slot's `kinds:`
  corpus::Range onset_s{0.0, 0.0};
  corpus::Range duration_s{0.0, 0.0};
  /// Whether the slot's point has a magnitude coordinate (an option's magnitude is a
  /// range) and direction coordinates (an option is a divergence, jump or misalignment).
  bool searches_magnitude = false;
  bool searches_direction = false;
};

/// A numeric key of the base scenario, by path ("trajectory.segments[1].circle.speed_mps").
struct SetKey {
  std::string path;
  corpus::Range range;
  /// The base's value, when the base has the key (the value a shrink moves back to); a
  /// key the base leaves out is removed again by a shrink.
  std::optional<double> base_value;
};

/// One dimension of the unit cube.
struct SearchDimension {
  std::string name;  ///< "seed", "set.<path>", "faults[k].option", "faults[k].onset_s", ...
  int choices = 0;   ///< categorical with this many choices; 0: continuous
};

/// What a point means: the seed, each set key's value and each fault slot's fault.
struct FaultSetting {
  bool present = true;
  std::size_t option = 0;
  double onset_s = 0.0;
  double duration_s = 0.0;
  double magnitude = 0.0;
  double direction_z = 0.0;    ///< in [-1, 1]
  double direction_phi = 0.0;  ///< [rad]
  bool operator==(const FaultSetting&) const = default;
};
struct Setting {
  uint64_t seed = 0;
  std::vector<double> set_values;  ///< per SearchSpec::set; NaN: the key as the base has it
  std::vector<FaultSetting> faults;
  bool operator==(const Setting&) const = default;
};

struct ConfirmOptions {
  int seeds = 5;                  ///< flights at other seeds per failure found
  double min_failure_rate = 0.5;  ///< confirmed at or above this rate over those seeds
};

struct SearchSpec {
  std::string file;  ///< where it was read from (messages)
  std::string text;  ///< the file's text
  std::string name;  ///< [a-z0-9_]+
  std::string description;
  std::filesystem::path base_path;  ///< absolute
  std::string base_text;            ///< the base scenario file's text
  harness::Scenario base;
  /// `objective.expectations`: metric names of the base's `expect:` entries; the search
  /// minimises the least margin of the entries with these metrics.
  std::vector<std::string> objective_metrics;
  std::optional<corpus::Range> seed_range;  ///< whole numbers
  std::vector<SetKey> set;
  std::vector<FaultSlot> faults;
  uint64_t budget = 0;               ///< search simulations (confirmation and shrinking aside)
  /// Points the optimiser proposes at once (`budget.batch`): a property of the search, not
  /// of the machine, so that any --jobs (or Slurm's CPUs) flies the same points.
  uint64_t batch = 2;
  std::string optimizer = "random";  ///< random, tpe
  uint64_t optimizer_seed = 1;
  ConfirmOptions confirm;
  double dedupe_distance = 0.2;  ///< max norm in the unit cube
  int shrink_steps = 4;          ///< bisection steps per parameter
  bool stop_at_first = false;    ///< stop at the first confirmed failure (benchmarks)
  std::vector<SearchDimension> dimensions;
};

/// Reads and validates a spec: unknown keys, empty or inverted ranges, a set key that is
/// not a number of the base scenario (nor a key the scenario format takes there), an
/// objective that names no expectation of the base, a budget of 0, an unknown optimiser
/// or fault kind, a sensor the base lacks: core::InputError naming file:line, the key and
/// the expected form. The corners of the space are decoded and parsed as scenarios.
SearchSpec LoadSearchSpec(const std::filesystem::path& path);
SearchSpec ParseSearchSpec(const std::string& text, const std::string& file_label,
                           const std::filesystem::path& spec_dir);

/// The optimisers a spec may name.
const std::vector<std::string>& SearchOptimizers();

/// The setting of a point of the unit cube (one coordinate per SearchSpec::dimensions, each
/// in [0, 1]), rounded as the corpus rounds (corpus::Round4).
Setting DecodePoint(const SearchSpec& spec, const std::vector<double>& unit);

/// The base itself: its seed, its set keys' values, no added fault.
Setting BaseSetting(const SearchSpec& spec);

/// What ScenarioYaml keeps of the base besides the setting.
enum class ScenarioScope {
  kWhole,  ///< every method, flight and expectation: the scenario a user runs
  /// The flight a search flies: the objective's expectations alone, and only the
  /// estimation methods and closed-loop flights their metrics (and relative_to) read.
  /// Methods are independent consumers of one stream and each closed loop flies alone,
  /// so the objective's values are those of the whole scenario (tests/search_test.cc).
  kObjective,
};

/// The base scenario's YAML with `setting` applied and the scenario renamed `name`; users'
/// clients named with absolute paths (the file may be written anywhere). `expect_metrics`
/// non-empty: only the expectations on those metrics are kept.
std::string ScenarioYaml(const SearchSpec& spec, const Setting& setting, const std::string& name,
                         const std::vector<std::string>& expect_metrics = {},
                         ScenarioScope scope = ScenarioScope::kWhole);

/// One line per parameter of a setting, "faults[0]: divergence on vio, 12.3-15.0 s, 0.4" ...
std::vector<std::string> DescribeSetting(const SearchSpec& spec, const Setting& setting);

}  // namespace tofu::campaign
