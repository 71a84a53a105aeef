#pragma once
// All-or-nothing writes, one place for every writer of the harness (run directories,
// estimates, JUnit): DESIGN.md's "no half-written output" is this module's job. Reads:
// core/file_io.h.

#include <filesystem>
#include <string>
#include <string_view>
#include <vector>

namespace tofu::replay {

/// Writes `text` to `path` whole or not at all: into a temporary sibling
/// (<name>.tmp-<pid>) renamed into place, so a reader never sees a partial file. Creates
/// missing parent directories. Throws core::IoError (exit 4) naming the file (and `key`,
/// e.g. "--out", when given) on failure, leaving neither the temporary nor a partial file.
/// A check point of interruption (replay/interrupt.h): throws Interrupted, leaving no
/// temporary, once a signal was received.
void WriteFileAtomically(const std::filesystem::path& path, std::string_view text,
                         std::string_view key = "");

/// The staging sibling of `path` owned by this process: <path>.tmp-<pid>. Every
/// all-or-nothing writer (files here, run and report directories) stages there.
std::filesystem::path StagingPath(const std::filesystem::path& path);

/// Removes the staging siblings of `path` (<path>.tmp-<pid>, files or directories) that a
/// killed or crashed process left behind: those whose process is gone, or whose pid now
/// belongs to a process that is not tofu. A live tofu process's staging is never touched.
/// Returns what was removed. Errors while removing are ignored (the next run tries again).
std::vector<std::filesystem::path> SweepStaleStaging(const std::filesystem::path& path);

}  // namespace tofu::replay
