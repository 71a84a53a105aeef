#pragma once
// One flown episode into its HDF5 group (schema: docs/CORPUS.md): every sensor stream with
// per-sample fault and condition masks, the fault-event table (scheduled and physical),
// ground truth, each estimation method's outputs, its consensus decisions and consistency
// values (predictions, kept apart from the truth), and the episode's scenario as
// attributes. Also the episode's manifest row.

#include <cstdint>
#include <map>
#include <optional>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "corpus/corpus_spec.h"
#include "corpus/hdf5_file.h"
#include "harness/run.h"

namespace tofu::corpus {

/// One row of the manifest (manifest.csv / manifest.json).
struct ManifestRow {
  std::uint64_t index = 0;
  std::string id;
  std::uint64_t scenario_seed = 0;
  std::string world;
  std::string family;
  double duration_s = 0.0;
  std::size_t scheduled_faults = 0;   ///< fault events of the scheduled cause
  std::size_t physical_events = 0;    ///< condition events (occlusion, degeneracy, ...)
  std::size_t samples = 0;            ///< sensor samples of all streams
  std::size_t collisions = 0;
  std::map<std::string, double> ate_m;  ///< per estimation method (NaN: not scored)
  std::string content_hash;           ///< Hdf5Group::ContentHash of the episode, hex
  std::string shard;                  ///< "I/N" of the shard that holds it
};

/// Writes `record` (the flight of `plan`) as group `plan.id` of `parent`; `summary` is
/// the run's summary.json (scores of the methods). Returns the manifest row.
ManifestRow WriteEpisode(const Hdf5Group& parent, const EpisodePlan& plan,
                         const harness::RunRecord& record, const nlohmann::json& summary);

/// The manifest row stored in an episode group's attributes (written by WriteEpisode).
ManifestRow ReadManifestRow(const Hdf5Group& episode);

nlohmann::ordered_json ManifestJson(const ManifestRow& row);
/// CSV header and row (methods in `methods` order).
std::string ManifestCsvHeader(const std::vector<std::string>& methods);
std::string ManifestCsvRow(const ManifestRow& row, const std::vector<std::string>& methods);

}  // namespace tofu::corpus
