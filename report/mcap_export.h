#pragma once
// A run directory as one MCAP file for Foxglove Studio (`tofu export RUN --mcap FILE`,
// `tofu run ... --mcap FILE`). JSON messages; every topic is listed in docs/MCAP.md with
// its schema and what one message is. In short, stamped at the sample's time of validity
// (log_time; publish_time = arrival for sensor samples):
//   /tf, /groundtruth                 ground truth T_WB (foxglove.FrameTransform,
//                                     foxglove.PoseInFrame): one per groundtruth.csv row
//   /sensors/<name>                   every row of sensors/<name>.csv with its covariance,
//                                     conditions and faults (tofu.ImuSample,
//                                     tofu.PoseMeasurement, tofu.PositionMeasurement)
//   /sensors/<name>/world             the measurement mapped into W (foxglove.PoseInFrame)
//   /estimates/<method>               every row of estimate_<m>.csv (tofu.Estimate)
//   /estimates/<method>/world         its valid rows as T_WB (foxglove.PoseInFrame)
//   /errors/<method>                  errors after alignment (tofu.EstimateError)
//   /consensus/decisions              decisions.csv (tofu.ConsensusDecision)
//   /consensus/consistency/<method>   the consistency matrix per evaluation
//                                     (tofu.ConsistencyMatrix)
//   /labels                           labels.csv transitions (foxglove.Log)
//   /events                           the failure events renders choose (foxglove.Log)
//   /closed_loop/<method>/groundtruth a closed-loop flight's true path (foxglove.PoseInFrame)
//   /closed_loop/<method>/events      its mode changes (foxglove.Log)
//   /scene                            the world's and the robot's geometry
//                                     (foxglove.SceneUpdate; the robot in base_link)
// and Metadata records "scenario" (the resolved YAML) and "tofu" (version, run).

#include <cstdint>
#include <filesystem>
#include <map>
#include <string>

#include "report/mcap_writer.h"

namespace tofu::report {

struct McapExportOptions {
  McapCompression compression = McapCompression::kZstd;
};

struct McapExportResult {
  std::map<std::string, std::uint64_t> messages_per_topic;
  std::uint64_t messages = 0;
  std::uint64_t bytes = 0;  ///< size of the written file
};

/// Writes `run_dir` (a tofu run directory) as `mcap_file`, atomically (a temporary file
/// beside it, renamed when complete). Throws core::InputError for a directory that is not
/// a run or malformed content (naming file, line, column), core::IoError when the file
/// cannot be written.
McapExportResult ExportRunToMcap(const std::filesystem::path& run_dir,
                                 const std::filesystem::path& mcap_file,
                                 const McapExportOptions& options = {});

}  // namespace tofu::report
