#pragma once
// Whole-file reads for every module that loads text (sim's robot MJCF, harness's logs and
// CSVs): one reader with one error message. Writers live in replay/file_io.h.

#include <cstddef>
#include <filesystem>
#include <string>
#include <string_view>

namespace tofu::core {

/// The whole file, bytes as they are. Throws core::InputError naming the file when it is a
/// directory, cannot be opened or cannot be read, or holds more than `max_bytes` (a device
/// such as /dev/zero, a log given where a configuration belongs: refused before memory
/// runs out); `what` names what was expected ("velocity CSV", "scenario file") in the
/// message.
std::string ReadWholeFile(const std::filesystem::path& path, std::string_view what = "file",
                          std::size_t max_bytes = static_cast<std::size_t>(-1));

/// The size limit of configuration files a user writes by hand (scenarios, calibration,
/// corpus specs, sensor.yaml): 16 MiB, a thousand times the largest the project has.
inline constexpr std::size_t kMaxConfigFileBytes = std::size_t{16} << 20;

}  // namespace tofu::core
