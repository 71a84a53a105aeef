#pragma once
// Whole-file reads for every module that loads text (sim's robot MJCF, harness's logs and
// CSVs): one reader with one error message. Writers live in harness/file_io.h.

#include <filesystem>
#include <string>
#include <string_view>

namespace tofu::core {

/// The whole file, bytes as they are. Throws core::InputError naming the file when it is a
/// directory, cannot be opened or cannot be read; `what` names what was expected
/// ("velocity CSV", "scenario file") in the message.
std::string ReadWholeFile(const std::filesystem::path& path, std::string_view what = "file");

}  // namespace tofu::core
