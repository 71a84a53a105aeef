#pragma once
// A campaign's cells as typed records: what one flight of a scenario at one seed measured
// (from its summary.json, through the comparable metrics' table), what it was flown from
// (the scenario file's hash, tofu's version) and the digests that say whether two cells'
// methods saw the same samples. `tofu compare` reads these, never the text of a table.

#include <cstdint>
#include <filesystem>
#include <map>
#include <optional>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

namespace tofu::campaign {

/// A check directory's record of its grid and runs (`tofu check --out DIR`): its file name
/// and its "format".
inline constexpr const char* kCheckRecordFile = "check.json";
inline constexpr const char* kCheckRecordFormat = "tofu check";

/// Digests of one flight (core/digest.h), hex; empty when the run recorded none.
struct FlightDigests {
  std::string samples;
  std::string random_streams;
};

/// One cell: a scenario flown at one seed.
struct CellRecord {
  std::string scenario;
  uint64_t seed = 0;
  std::string scenario_hash;  ///< FNV-1a of the scenario file's text (hex)
  int exit_code = -1;         ///< tofu run's (core::ExitCode)
  std::string error;          ///< why the run has no usable summary; empty if it has one
  FlightDigests digests;      ///< the ground-truth flight's: every open-loop method saw these
  /// Each closed-loop flight's own, by the method flown on.
  std::map<std::string, FlightDigests> flight_digests;
  /// Concrete metric name ("methods.consensus.ate_m") -> value; a metric with no value is
  /// absent.
  std::map<std::string, double> values;
  /// Concrete event name ("methods.external:ekf.failed") -> whether it happened. An event
  /// of a method the cell has is always present (false when it did not happen).
  std::map<std::string, bool> events;
};

/// The cells of one campaign (a check directory or a baseline file).
struct CampaignRecord {
  std::filesystem::path source;  ///< where it was read from, for messages
  std::string tofu_version;
  std::string tofu_commit;
  /// Definition version of each comparable metric when the cells were scored.
  std::map<std::string, int> metric_versions;
  /// Each scenario's own minimal effects (its `compare: {minimal_effects: ...}`), by
  /// scenario; scenarios without any are absent.
  std::map<std::string, std::map<std::string, double>> minimal_effects;
  std::vector<CellRecord> cells;  ///< by scenario (in check order), then seed
};

/// Each comparable metric's definition version in this tofu, by pattern
/// ("methods.<method>.ate_m"): what a campaign flown now records.
std::map<std::string, int> CurrentMetricVersions();

/// A JSON file of a campaign (check.json, summary.json, a baseline, compare.json), parsed.
/// Throws core::InputError naming the file: unreadable, or not JSON.
nlohmann::json ReadJsonRecord(const std::filesystem::path& file);

/// The typed record of one run: its summary.json (null when the run has none) read through
/// the table of comparable metrics.
CellRecord CellFromSummary(const std::string& scenario, uint64_t seed,
                           const std::string& scenario_hash, int exit_code,
                           const std::string& error, const nlohmann::json& summary);

/// A check directory (`tofu check --out DIR`): its record check.json and every run's
/// summary.json. Throws core::InputError naming the file and what is wrong (no check.json:
/// not a check directory, or a check from before it was written).
CampaignRecord ReadCheckDirectory(const std::filesystem::path& dir);

/// The baseline file of a campaign: compact JSON of every cell's values, events, digests,
/// the scenario hashes, tofu's version and the metric definitions' versions.
std::string BaselineJson(const CampaignRecord& campaign);
/// Reads a baseline file. Throws core::InputError naming the file, key and expected form.
CampaignRecord ReadBaselineFile(const std::filesystem::path& file);

/// A check directory or a baseline file, whichever `path` is.
CampaignRecord ReadCampaign(const std::filesystem::path& path);

}  // namespace tofu::campaign
