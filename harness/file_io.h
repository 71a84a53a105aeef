#pragma once
// Whole-file reads and all-or-nothing writes, one place for every reader and writer of
// the harness (run directories, estimates, CSV inputs, JUnit): DESIGN.md's "no
// half-written output" is this module's job.

#include <filesystem>
#include <string>
#include <string_view>

namespace tofu::harness {

/// The whole file, bytes as they are. Throws core::InputError naming the file when it is a
/// directory, cannot be opened or cannot be read; `what` names what was expected
/// ("velocity CSV", "scenario file") in the message.
std::string ReadWholeFile(const std::filesystem::path& path, std::string_view what = "file");

/// Writes `text` to `path` whole or not at all: into a temporary sibling
/// (<name>.tmp-<pid>) renamed into place, so a reader never sees a partial file. Creates
/// missing parent directories. Throws core::InputError naming the file (and `key`, e.g.
/// "--out", when given) on failure, leaving neither the temporary nor a partial file.
void WriteFileAtomically(const std::filesystem::path& path, std::string_view text,
                         std::string_view key = "");

}  // namespace tofu::harness
