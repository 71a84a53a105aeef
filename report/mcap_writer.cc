#include "report/mcap_writer.h"

#include <zlib.h>
#include <zstd.h>

#include <algorithm>
#include <limits>
#include <utility>

#include <fmt/format.h>

#include "core/error.h"

namespace tofu::report {
namespace {

// Opcodes of the records written (MCAP spec, "Records").
enum Opcode : std::uint8_t {
  kHeader = 0x01,
  kFooter = 0x02,
  kSchema = 0x03,
  kChannel = 0x04,
  kMessage = 0x05,
  kChunk = 0x06,
  kMessageIndex = 0x07,
  kChunkIndex = 0x08,
  kStatistics = 0x0B,
  kMetadata = 0x0C,
  kMetadataIndex = 0x0D,
  kSummaryOffset = 0x0E,
  kDataEnd = 0x0F,
};

constexpr char kMagic[] = {'\x89', 'M', 'C', 'A', 'P', '0', '\r', '\n'};

// Little-endian serialisation of the spec's primitive types into a byte buffer.
class Buffer {
 public:
  void U8(std::uint8_t v) { bytes_.push_back(static_cast<char>(v)); }
  void U16(std::uint16_t v) { Le(v, 2); }
  void U32(std::uint32_t v) { Le(v, 4); }
  void U64(std::uint64_t v) { Le(v, 8); }
  /// uint32 length prefix, then the bytes (the spec's String and uint32-prefixed Bytes).
  void Str(const std::string& s) {
    U32(Narrow32(s.size()));
    bytes_ += s;
  }
  void Raw(const std::string& s) { bytes_ += s; }
  /// Map<string, string>: uint32 byte length of the entries, then the entries.
  void StrMap(const std::map<std::string, std::string>& m) {
    Buffer entries;
    for (const auto& [k, v] : m) {
      entries.Str(k);
      entries.Str(v);
    }
    U32(Narrow32(entries.size()));
    bytes_ += entries.bytes();
  }
  std::size_t size() const { return bytes_.size(); }
  const std::string& bytes() const { return bytes_; }
  std::string& bytes() { return bytes_; }
  void clear() { bytes_.clear(); }

  static std::uint32_t Narrow32(std::size_t n) {
    if (n > std::numeric_limits<std::uint32_t>::max()) {
      throw core::IoError(fmt::format("MCAP field of {} bytes exceeds the 4 GiB limit", n));
    }
    return static_cast<std::uint32_t>(n);
  }

 private:
  void Le(std::uint64_t v, int n) {
    char le[8];
    for (int i = 0; i < n; ++i) le[i] = static_cast<char>((v >> (8 * i)) & 0xFF);
    bytes_.append(le, static_cast<std::size_t>(n));
  }
  std::string bytes_;
};

// A record: opcode, uint64 length of the content, the content.
void AppendRecord(Buffer& out, std::uint8_t opcode, const Buffer& content) {
  out.U8(opcode);
  out.U64(content.size());
  out.Raw(content.bytes());
}

}  // namespace

std::uint32_t Crc32(const void* data, std::size_t size, std::uint32_t crc) {
  // zlib's crc32 is the CRC-32 MCAP specifies; it takes at most uInt bytes per call.
  const auto* bytes = static_cast<const Bytef*>(data);
  uLong value = crc;
  while (size > 0) {
    const uInt step = static_cast<uInt>(std::min<std::size_t>(size, 1u << 30));
    value = crc32(value, bytes, step);
    bytes += step;
    size -= step;
  }
  return static_cast<std::uint32_t>(value);
}

struct McapWriter::Impl {
  std::filesystem::path path;
  McapWriterOptions options;
  std::ofstream file;
  std::uint64_t offset = 0;      // bytes written to the file
  std::uint32_t data_crc = 0;    // CRC-32 of everything written before Data End
  bool closed = false;

  struct SchemaRecord {
    std::uint16_t id;
    std::string name, encoding, data;
  };
  struct ChannelRecord {
    std::uint16_t id, schema_id;
    std::string topic, encoding;
    std::map<std::string, std::string> metadata;
  };
  std::vector<SchemaRecord> schemas;
  std::vector<ChannelRecord> channels;
  std::vector<std::uint32_t> sequence;  // next sequence number per channel

  // The open chunk: its records uncompressed, the schemas and channels it has written
  // (each chunk that holds a channel's messages repeats the channel, so a reader that
  // seeks to one chunk can decode it), and per channel (log time, offset in the chunk).
  Buffer chunk;
  std::uint64_t chunk_start = 0, chunk_end = 0;
  bool chunk_has_messages = false;
  std::vector<bool> schema_in_chunk, channel_in_chunk;
  std::map<std::uint16_t, std::vector<std::pair<std::uint64_t, std::uint64_t>>> chunk_index;

  Buffer chunk_indexes;  // the summary's Chunk Index records
  struct MetadataEntry {
    std::uint64_t offset, length;
    std::string name;
  };
  std::vector<MetadataEntry> metadata;

  void Write(const std::string& bytes, bool in_data_section = true) {
    file.write(bytes.data(), static_cast<std::streamsize>(bytes.size()));
    if (!file) throw core::IoError(fmt::format("cannot write {}", path.string()));
    if (in_data_section) data_crc = Crc32(bytes.data(), bytes.size(), data_crc);
    offset += bytes.size();
  }

  void SchemaContent(Buffer& b, const SchemaRecord& s) const {
    b.U16(s.id);
    b.Str(s.name);
    b.Str(s.encoding);
    b.Str(s.data);
  }
  void ChannelContent(Buffer& b, const ChannelRecord& c) const {
    b.U16(c.id);
    b.U16(c.schema_id);
    b.Str(c.topic);
    b.Str(c.encoding);
    b.StrMap(c.metadata);
  }

  void EnsureInChunk(std::uint16_t channel_id) {
    if (channel_in_chunk[channel_id]) return;
    const ChannelRecord& c = channels[channel_id];
    if (c.schema_id != 0 && !schema_in_chunk[c.schema_id - 1]) {
      Buffer content;
      SchemaContent(content, schemas[c.schema_id - 1]);
      AppendRecord(chunk, kSchema, content);
      schema_in_chunk[c.schema_id - 1] = true;
    }
    Buffer content;
    ChannelContent(content, c);
    AppendRecord(chunk, kChannel, content);
    channel_in_chunk[channel_id] = true;
  }

  void FlushChunk(McapStatistics& statistics) {
    if (!chunk_has_messages) return;
    const std::string& raw = chunk.bytes();
    std::string stored;
    std::string compression;
    if (options.compression == McapCompression::kZstd) {
      stored.resize(ZSTD_compressBound(raw.size()));
      const std::size_t n =
          ZSTD_compress(stored.data(), stored.size(), raw.data(), raw.size(), options.zstd_level);
      if (ZSTD_isError(n)) {
        throw core::IoError(fmt::format("zstd compression failed: {}", ZSTD_getErrorName(n)));
      }
      stored.resize(n);
      compression = "zstd";
    } else {
      stored = raw;
    }
    Buffer content;
    content.U64(chunk_start);
    content.U64(chunk_end);
    content.U64(raw.size());
    content.U32(Crc32(raw.data(), raw.size()));
    content.Str(compression);
    content.U64(stored.size());
    content.Raw(stored);
    Buffer record;
    AppendRecord(record, kChunk, content);
    const std::uint64_t chunk_offset = offset;
    Write(record.bytes());

    // Message Index records, one per channel of the chunk, right after it.
    const std::uint64_t index_start = offset;
    std::map<std::uint16_t, std::uint64_t> index_offsets;
    Buffer indexes;
    for (auto& [channel_id, entries] : chunk_index) {
      // Readers expect the entries sorted by log time (stable: file order among ties).
      std::stable_sort(entries.begin(), entries.end(),
                       [](const auto& a, const auto& b) { return a.first < b.first; });
      Buffer c;
      c.U16(channel_id);
      c.U32(Buffer::Narrow32(entries.size() * 16));
      for (const auto& [t, at] : entries) {
        c.U64(t);
        c.U64(at);
      }
      index_offsets[channel_id] = index_start + indexes.size();
      AppendRecord(indexes, kMessageIndex, c);
    }
    Write(indexes.bytes());

    Buffer ci;
    ci.U64(chunk_start);
    ci.U64(chunk_end);
    ci.U64(chunk_offset);
    ci.U64(record.size());
    ci.U32(Buffer::Narrow32(index_offsets.size() * 10));
    for (const auto& [channel_id, at] : index_offsets) {
      ci.U16(channel_id);
      ci.U64(at);
    }
    ci.U64(indexes.size());
    ci.Str(compression);
    ci.U64(stored.size());
    ci.U64(raw.size());
    AppendRecord(chunk_indexes, kChunkIndex, ci);

    ++statistics.chunk_count;
    chunk.clear();
    chunk_has_messages = false;
    std::fill(schema_in_chunk.begin(), schema_in_chunk.end(), false);
    std::fill(channel_in_chunk.begin(), channel_in_chunk.end(), false);
    chunk_index.clear();
  }
};

McapWriter::McapWriter(const std::filesystem::path& path, McapWriterOptions options)
    : impl_(std::make_unique<Impl>()) {
  impl_->path = path;
  impl_->options = std::move(options);
  impl_->file.open(path, std::ios::binary | std::ios::trunc);
  if (!impl_->file) throw core::IoError(fmt::format("cannot open {} for writing", path.string()));
  Buffer start;
  start.Raw(std::string(kMagic, sizeof(kMagic)));
  Buffer header;
  header.Str(impl_->options.profile);
  header.Str(fmt::format("tofu {}", TOFU_VERSION_STRING));
  AppendRecord(start, kHeader, header);
  impl_->Write(start.bytes());
}

McapWriter::~McapWriter() {
  if (impl_ && !impl_->closed) {
    try {
      Close();
    } catch (const std::exception&) {
      // A destructor must not throw; Close() called explicitly reports the failure.
    }
  }
}

std::uint16_t McapWriter::AddSchema(const std::string& name, const std::string& encoding,
                                    const std::string& data) {
  if (impl_->schemas.size() >= std::numeric_limits<std::uint16_t>::max()) {
    throw core::IoError("MCAP: more than 65535 schemas");
  }
  const auto id = static_cast<std::uint16_t>(impl_->schemas.size() + 1);
  impl_->schemas.push_back({id, name, encoding, data});
  impl_->schema_in_chunk.push_back(false);
  ++statistics_.schema_count;
  return id;
}

std::uint16_t McapWriter::AddChannel(std::uint16_t schema_id, const std::string& topic,
                                     const std::string& message_encoding,
                                     const std::map<std::string, std::string>& metadata) {
  if (schema_id > impl_->schemas.size()) {
    throw core::IoError(fmt::format("MCAP: channel {} names unknown schema {}", topic, schema_id));
  }
  if (impl_->channels.size() >= std::numeric_limits<std::uint16_t>::max()) {
    throw core::IoError("MCAP: more than 65535 channels");
  }
  const auto id = static_cast<std::uint16_t>(impl_->channels.size());
  impl_->channels.push_back({id, schema_id, topic, message_encoding, metadata});
  impl_->channel_in_chunk.push_back(false);
  impl_->sequence.push_back(0);
  ++statistics_.channel_count;
  return id;
}

void McapWriter::AddMessage(std::uint16_t channel_id, std::uint64_t log_time_ns,
                            std::uint64_t publish_time_ns, const std::string& data) {
  Impl& d = *impl_;
  if (d.closed) throw core::IoError(fmt::format("MCAP {}: message after Close()", d.path.string()));
  if (channel_id >= d.channels.size()) {
    throw core::IoError(fmt::format("MCAP: message on unknown channel {}", channel_id));
  }
  d.EnsureInChunk(channel_id);
  // The Message record straight into the chunk (no intermediate copy: a run is ~10^5
  // messages).
  d.chunk_index[channel_id].emplace_back(log_time_ns, d.chunk.size());
  if (d.chunk.size() == 0) d.chunk.bytes().reserve(d.options.chunk_size_bytes + (64 << 10));
  d.chunk.U8(kMessage);
  d.chunk.U64(2 + 4 + 8 + 8 + data.size());
  d.chunk.U16(channel_id);
  d.chunk.U32(d.sequence[channel_id]++);
  d.chunk.U64(log_time_ns);
  d.chunk.U64(publish_time_ns);
  d.chunk.Raw(data);
  if (!d.chunk_has_messages) {
    d.chunk_start = d.chunk_end = log_time_ns;
    d.chunk_has_messages = true;
  }
  d.chunk_start = std::min(d.chunk_start, log_time_ns);
  d.chunk_end = std::max(d.chunk_end, log_time_ns);

  if (statistics_.message_count == 0) {
    statistics_.message_start_time = statistics_.message_end_time = log_time_ns;
  }
  statistics_.message_start_time = std::min(statistics_.message_start_time, log_time_ns);
  statistics_.message_end_time = std::max(statistics_.message_end_time, log_time_ns);
  ++statistics_.message_count;
  ++statistics_.channel_message_counts[channel_id];

  if (d.chunk.size() >= d.options.chunk_size_bytes) d.FlushChunk(statistics_);
}

void McapWriter::AddMetadata(const std::string& name,
                             const std::map<std::string, std::string>& values) {
  Impl& d = *impl_;
  // Metadata records live outside chunks: close the open one so the file stays in order.
  d.FlushChunk(statistics_);
  Buffer content;
  content.Str(name);
  content.StrMap(values);
  Buffer record;
  AppendRecord(record, kMetadata, content);
  d.metadata.push_back({d.offset, record.size(), name});
  d.Write(record.bytes());
  ++statistics_.metadata_count;
}

// Long by design: the summary section and the footer in the order the MCAP spec lays them
// out, with one CRC running across them.
void McapWriter::Close() {
  Impl& d = *impl_;
  if (d.closed) return;
  d.closed = true;
  d.FlushChunk(statistics_);

  Buffer data_end_content;
  data_end_content.U32(d.data_crc);
  Buffer data_end;
  AppendRecord(data_end, kDataEnd, data_end_content);
  d.Write(data_end.bytes(), false);

  // The summary section: groups of records of one opcode each, and where each group is.
  const std::uint64_t summary_start = d.offset;
  Buffer summary;
  struct Group {
    std::uint8_t opcode;
    std::uint64_t start, length;
  };
  std::vector<Group> groups;
  const auto group = [&](std::uint8_t opcode, const Buffer& records) {
    if (records.size() == 0) return;
    groups.push_back({opcode, summary_start + summary.size(), records.size()});
    summary.Raw(records.bytes());
  };
  Buffer schema_records, channel_records, statistics_record, metadata_indexes;
  for (const auto& s : d.schemas) {
    Buffer c;
    d.SchemaContent(c, s);
    AppendRecord(schema_records, kSchema, c);
  }
  for (const auto& ch : d.channels) {
    Buffer c;
    d.ChannelContent(c, ch);
    AppendRecord(channel_records, kChannel, c);
  }
  {
    Buffer c;
    c.U64(statistics_.message_count);
    c.U16(statistics_.schema_count);
    c.U32(statistics_.channel_count);
    c.U32(0);  // attachments
    c.U32(statistics_.metadata_count);
    c.U32(statistics_.chunk_count);
    c.U64(statistics_.message_start_time);
    c.U64(statistics_.message_end_time);
    c.U32(Buffer::Narrow32(statistics_.channel_message_counts.size() * 10));
    for (const auto& [channel_id, count] : statistics_.channel_message_counts) {
      c.U16(channel_id);
      c.U64(count);
    }
    AppendRecord(statistics_record, kStatistics, c);
  }
  for (const auto& m : d.metadata) {
    Buffer c;
    c.U64(m.offset);
    c.U64(m.length);
    c.Str(m.name);
    AppendRecord(metadata_indexes, kMetadataIndex, c);
  }
  group(kSchema, schema_records);
  group(kChannel, channel_records);
  group(kStatistics, statistics_record);
  group(kChunkIndex, d.chunk_indexes);
  group(kMetadataIndex, metadata_indexes);

  const std::uint64_t summary_offset_start = summary_start + summary.size();
  for (const Group& g : groups) {
    Buffer c;
    c.U8(g.opcode);
    c.U64(g.start);
    c.U64(g.length);
    AppendRecord(summary, kSummaryOffset, c);
  }

  // Footer: the summary CRC covers the summary section, the offsets and the Footer's own
  // fields up to the CRC (opcode, length, summary_start, summary_offset_start).
  Buffer footer;
  footer.U8(kFooter);
  footer.U64(8 + 8 + 4);
  footer.U64(groups.empty() && summary.size() == 0 ? 0 : summary_start);
  footer.U64(groups.empty() ? 0 : summary_offset_start);
  std::uint32_t summary_crc = Crc32(summary.bytes().data(), summary.size());
  summary_crc = Crc32(footer.bytes().data(), footer.size(), summary_crc);
  footer.U32(summary_crc);
  d.Write(summary.bytes(), false);
  d.Write(footer.bytes(), false);
  d.Write(std::string(kMagic, sizeof(kMagic)), false);
  d.file.close();
  if (!d.file) throw core::IoError(fmt::format("cannot write {}", d.path.string()));
}

}  // namespace tofu::report
