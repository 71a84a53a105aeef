#pragma once
// The run directory (DESIGN.md, "Run directory"): written to a temporary sibling and
// renamed into place when complete, so a reader never sees half a run. Every file but
// timing.json is a deterministic function of (scenario, seed, build).

#include <filesystem>
#include <functional>
#include <string>
#include <vector>

#include "harness/evaluation.h"
#include "harness/run.h"

namespace tofu::harness {

/// The file every run directory holds, written last (after every other file, before the
/// rename into place): `--out` replaces only a directory that has it, and only with
/// --force; a directory without it is not a complete run.
inline constexpr const char* kRunMarkerFile = ".tofu-run";

/// Whether `tofu run --out out_dir` may write there, checked before the flight: a missing
/// or empty directory, or an earlier run (marker file) with `force`. Throws
/// core::InputError (exit 2) for anything else (a file; a directory holding other files,
/// never touched; an earlier run without --force), saying why and what to do.
void CheckOutputDirectory(const std::filesystem::path& out_dir, bool force);

/// Writes scenario.yaml, groundtruth.csv/.tum, tracking.csv, calibration.yaml,
/// summary.json and timing.json into `out_dir`, replacing an existing directory.
/// Throws std::runtime_error on I/O failure (nothing is left behind). `finish` (may be
/// empty) runs on the complete staging directory before it is renamed into place: what
/// it adds or rewrites appears atomically with the rest. Interruption (interrupt.h):
/// throws Interrupted at the next file or before the rename, the staging directory
/// (<out>.tmp-<pid>) removed and `out_dir` untouched.
void WriteRunDirectory(const RunRecord& record, const Evaluation& evaluation,
                       const std::string& out_dir,
                       const std::function<void(const std::filesystem::path& staging)>& finish = {});

/// Creates the staging directory of `out_dir` (<out>.tmp-<pid>, emptied) for a run that
/// records its files while it flies (SimulateOptions::record_dir); WriteRun completes it
/// and renames it into place, or removes it when it fails. A caller whose flight throws
/// removes it (std::filesystem::remove_all).
std::filesystem::path CreateStagingDirectory(const std::string& out_dir);

struct RunOutputOptions {
  /// Draw consensus.png with scripts/plot_consensus.py (python3 + matplotlib); a missing
  /// interpreter or library is a warning, never a failure of the run.
  bool plot = true;
  /// Methods scored at once after the flight (EvaluateEstimation; `tofu run --threads`).
  int threads = 1;
};

/// calibration.yaml of a run: mounts (nominal and true), the sensors' options, the true
/// reference frames T_WS of record.sensors.
std::string CalibrationYamlText(const RunRecord& record);

/// What `tofu run` does after the simulation: writes the run directory (into the
/// directory a recorded run flew into, record.recorded_to); with an `estimation:` block,
/// scores the methods that ran in the loop (record.methods) and writes their estimates;
/// writes each closed-loop flight under closed_loop/<method>/; evaluates the
/// expectations including the methods' and the closed-loop metrics and draws
/// consensus.png and closed_loop.png, all before the directory is renamed into place.
/// Returns the final evaluation.
Evaluation WriteRun(RunRecord& record, const std::string& out_dir,
                    const RunOutputOptions& options = {});

/// Runs a program (argv[0]: its path) with stdin inherited and stdout and stderr
/// discarded, and returns its exit status, or -1 when it could not start or did not exit
/// normally. A check point of interruption (interrupt.h): on a signal the program is sent
/// SIGTERM, waited for, and Interrupted thrown. The figures of scripts/ are drawn so.
int RunQuietly(const std::vector<std::string>& argv);

}  // namespace tofu::harness
