#pragma once
// A writer of MCAP files (https://mcap.dev/spec, format version 0): the container of
// ROS 2 bags and Foxglove Studio. No C++ MCAP library is packaged for Debian, and the
// format is small and fully specified, so tofu writes it itself; tests read every file it
// writes back with the reference reader (@mcap/core, tests/node/check_mcap.mjs).
//
// Layout written: magic, Header, then Chunks (each holding Schema, Channel and Message
// records, compressed with zstd or stored), each followed by its Message Index records;
// Data End (with the data section's CRC-32); the summary section (Schemas, Channels,
// Statistics, Chunk Indexes) and its Summary Offsets; Footer (with the summary's CRC-32);
// magic. A viewer seeks through the chunk and message indexes without reading the file.
//
// Messages must be added in non-decreasing log time per channel for a viewer's playback,
// but the format allows any order and the writer does not reorder.

#include <cstdint>
#include <filesystem>
#include <fstream>
#include <map>
#include <memory>
#include <string>
#include <vector>

namespace tofu::report {

enum class McapCompression { kNone, kZstd };

struct McapWriterOptions {
  std::string profile;  ///< Header.profile: "" (none) or e.g. "ros2"
  McapCompression compression = McapCompression::kZstd;
  /// A chunk is closed once its uncompressed records reach this size [bytes].
  std::size_t chunk_size_bytes = 1 << 20;
  int zstd_level = 1;
};

/// Counts of what was written (also in the file's Statistics record).
struct McapStatistics {
  std::uint64_t message_count = 0;
  std::uint16_t schema_count = 0;
  std::uint32_t channel_count = 0;
  std::uint32_t chunk_count = 0;
  std::uint32_t metadata_count = 0;
  std::uint64_t message_start_time = 0;
  std::uint64_t message_end_time = 0;
  std::map<std::uint16_t, std::uint64_t> channel_message_counts;
};

class McapWriter {
 public:
  /// Opens `path` for writing (truncated) and writes the magic and the Header. Throws
  /// core::IoError when the file cannot be opened.
  McapWriter(const std::filesystem::path& path, McapWriterOptions options = {});
  ~McapWriter();
  McapWriter(const McapWriter&) = delete;
  McapWriter& operator=(const McapWriter&) = delete;

  /// Registers a schema; returns its id (1, 2, ...). `encoding`: "jsonschema" for JSON
  /// messages; `data`: the schema text.
  std::uint16_t AddSchema(const std::string& name, const std::string& encoding,
                          const std::string& data);
  /// Registers a channel on `schema_id` (0: no schema); returns its id (0, 1, ...).
  std::uint16_t AddChannel(std::uint16_t schema_id, const std::string& topic,
                           const std::string& message_encoding,
                           const std::map<std::string, std::string>& metadata = {});
  /// Appends one message. log_time and publish_time are ns since the epoch of the
  /// recording (tofu: the run's clock). The sequence number is per channel, from 0.
  void AddMessage(std::uint16_t channel_id, std::uint64_t log_time_ns,
                  std::uint64_t publish_time_ns, const std::string& data);
  /// A Metadata record (name -> key/value map), indexed in the summary.
  void AddMetadata(const std::string& name, const std::map<std::string, std::string>& values);

  /// Flushes the open chunk and writes Data End, the summary section and the Footer.
  /// Called by the destructor if not called; throws core::IoError on a write failure.
  void Close();

  const McapStatistics& statistics() const { return statistics_; }

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
  McapStatistics statistics_;
};

/// CRC-32 (IEEE 802.3, reflected, the one of zlib and of MCAP) of `size` bytes, continuing
/// from `crc` (0 to start).
std::uint32_t Crc32(const void* data, std::size_t size, std::uint32_t crc = 0);

}  // namespace tofu::report
