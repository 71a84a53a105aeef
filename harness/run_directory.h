#pragma once
// The run directory (DESIGN.md, "Run directory"): written to a temporary sibling and
// renamed into place when complete, so a reader never sees half a run. Every file but
// timing.json is a deterministic function of (scenario, seed, build).

#include <string>

#include "harness/evaluation.h"
#include "harness/run.h"

namespace tofu::harness {

/// Writes scenario.yaml, groundtruth.csv/.tum, tracking.csv, calibration.yaml,
/// summary.json and timing.json into `out_dir`, replacing an existing directory.
/// Throws std::runtime_error on I/O failure (nothing is left behind).
void WriteRunDirectory(const RunRecord& record, const Evaluation& evaluation,
                       const std::string& out_dir);

}  // namespace tofu::harness
