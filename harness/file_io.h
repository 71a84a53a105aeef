#pragma once
// All-or-nothing writes, one place for every writer of the harness (run directories,
// estimates, JUnit): DESIGN.md's "no half-written output" is this module's job. Reads:
// core/file_io.h.

#include <filesystem>
#include <string>
#include <string_view>

namespace tofu::harness {

/// Writes `text` to `path` whole or not at all: into a temporary sibling
/// (<name>.tmp-<pid>) renamed into place, so a reader never sees a partial file. Creates
/// missing parent directories. Throws core::IoError (exit 4) naming the file (and `key`,
/// e.g. "--out", when given) on failure, leaving neither the temporary nor a partial file.
void WriteFileAtomically(const std::filesystem::path& path, std::string_view text,
                         std::string_view key = "");

}  // namespace tofu::harness
