// The MCAP writer's framing, walked record by record here (the reference reader's checks
// are tests/mcap_check.sh), and the JSON text writer.
#include "report/mcap_writer.h"

#include <cmath>
#include <cstring>
#include <unistd.h>
#include <filesystem>
#include <fstream>
#include <string>

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include "core/error.h"
#include "report/json_text.h"
#include "report/mcap_schemas.h"

namespace tofu::report {
namespace {

namespace fs = std::filesystem;

std::string ReadAll(const fs::path& path) {
  std::ifstream in(path, std::ios::binary);
  return std::string(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
}

std::uint64_t U64(const std::string& b, std::size_t at) {
  std::uint64_t v = 0;
  for (int i = 7; i >= 0; --i) v = (v << 8) | static_cast<unsigned char>(b[at + i]);
  return v;
}
std::uint32_t U32(const std::string& b, std::size_t at) {
  return static_cast<std::uint32_t>(U64(b + std::string(8, '\0'), at) & 0xFFFFFFFFu);
}

const std::string kMagic("\x89MCAP0\r\n", 8);

fs::path TempFile(const std::string& name) {
  return fs::temp_directory_path() / (name + "_" + std::to_string(::getpid()) + ".mcap");
}

TEST(McapWriter, FramingOffsetsAndCrcsHold) {
  const fs::path path = TempFile("framing");
  {
    McapWriterOptions options;
    options.compression = McapCompression::kNone;
    options.chunk_size_bytes = 64;  // several chunks
    McapWriter writer(path, options);
    const std::uint16_t schema = writer.AddSchema("tofu.Test", "jsonschema", "{}");
    const std::uint16_t a = writer.AddChannel(schema, "/a", "json");
    const std::uint16_t b = writer.AddChannel(schema, "/b", "json");
    for (int i = 0; i < 10; ++i) {
      writer.AddMessage(i % 2 ? a : b, 1000 + i, 1000 + i, "{\"i\":" + std::to_string(i) + "}");
    }
    writer.AddMetadata("scenario", {{"name", "x"}});
    writer.Close();
    EXPECT_EQ(writer.statistics().message_count, 10u);
    EXPECT_EQ(writer.statistics().channel_message_counts.at(a), 5u);
    EXPECT_GE(writer.statistics().chunk_count, 2u);
  }
  const std::string f = ReadAll(path);
  ASSERT_GT(f.size(), 2 * kMagic.size() + 29);
  EXPECT_EQ(f.substr(0, 8), kMagic);
  EXPECT_EQ(f.substr(f.size() - 8), kMagic);

  // Footer: opcode 0x02, length 20, summary_start, summary_offset_start, summary_crc.
  const std::size_t footer = f.size() - 8 - 29;
  ASSERT_EQ(static_cast<unsigned char>(f[footer]), 0x02);
  EXPECT_EQ(U64(f, footer + 1), 20u);
  const std::uint64_t summary_start = U64(f, footer + 9);
  const std::uint64_t summary_offset_start = U64(f, footer + 17);
  ASSERT_LT(summary_start, summary_offset_start);
  ASSERT_LT(summary_offset_start, footer);
  EXPECT_EQ(static_cast<unsigned char>(f[summary_start]), 0x03) << "summary starts with the schemas";
  EXPECT_EQ(static_cast<unsigned char>(f[summary_offset_start]), 0x0E);
  const std::uint32_t summary_crc = Crc32(f.data() + summary_start, footer + 1 + 8 + 16 - summary_start);
  EXPECT_EQ(U32(f, footer + 25), summary_crc);

  // Data End right before the summary: CRC of everything from the magic to it.
  const std::size_t data_end = summary_start - (1 + 8 + 4);
  ASSERT_EQ(static_cast<unsigned char>(f[data_end]), 0x0F);
  EXPECT_EQ(U32(f, data_end + 9), Crc32(f.data(), data_end));

  // Walk the data section: every record's length lands on the next opcode; the chunks
  // hold every message (stored, so the JSON is there as written).
  std::size_t at = 8;
  int chunks = 0, indexes = 0, metadata = 0;
  while (at < data_end) {
    const unsigned char op = static_cast<unsigned char>(f[at]);
    const std::uint64_t length = U64(f, at + 1);
    if (op == 0x06) ++chunks;
    if (op == 0x07) ++indexes;
    if (op == 0x0C) ++metadata;
    at += 9 + length;
  }
  EXPECT_EQ(at, data_end) << "record lengths do not chain to Data End";
  EXPECT_GE(chunks, 2);
  EXPECT_GE(indexes, chunks);
  EXPECT_EQ(metadata, 1);
  for (int i = 0; i < 10; ++i) {
    EXPECT_NE(f.find("{\"i\":" + std::to_string(i) + "}"), std::string::npos) << i;
  }
  fs::remove(path);
}

TEST(McapWriter, CompressedIsSmallerAndRejectsUnknownChannel) {
  const fs::path stored = TempFile("stored");
  const fs::path zstd = TempFile("zstd");
  for (const auto& [path, compression] : {std::pair{stored, McapCompression::kNone},
                                          std::pair{zstd, McapCompression::kZstd}}) {
    McapWriterOptions options;
    options.compression = compression;
    McapWriter writer(path, options);
    const std::uint16_t c = writer.AddChannel(0, "/x", "json");
    for (int i = 0; i < 2000; ++i) writer.AddMessage(c, i, i, "{\"value\":1.25,\"name\":\"same\"}");
    EXPECT_THROW(writer.AddMessage(7, 0, 0, "{}"), core::IoError);
    writer.Close();
  }
  // The message indexes (16 bytes a message) stay uncompressed: 3x at least on this data.
  EXPECT_LT(fs::file_size(zstd) * 3, fs::file_size(stored));
  fs::remove(stored);
  fs::remove(zstd);
}

TEST(McapWriter, UnwritablePathIsAnIoError) {
  EXPECT_THROW(McapWriter("/nonexistent-dir/x.mcap"), core::IoError);
}

TEST(Crc32, MatchesTheStandardCheckValue) {
  // The CRC-32 check value of "123456789" (IEEE 802.3).
  EXPECT_EQ(Crc32("123456789", 9), 0xCBF43926u);
  EXPECT_EQ(Crc32("56789", 5, Crc32("1234", 4)), 0xCBF43926u);
}

TEST(JsonText, WritesValidJsonWithNullForNonFiniteAndEscapes) {
  JsonText j;
  j.Begin();
  j.Number("nan", std::nan(""));
  j.Number("x", 0.1);
  j.Int("big", 1'234'567'890'123LL);
  j.String("text", "a \"quote\", a \\ and a\nnewline\x01");
  j.Time("t", 3'000'000'005);
  j.Pose("pose", Eigen::Vector3d(1, 2, 3), Eigen::Quaterniond(1, 0, 0, 0));
  j.Key("list");
  j.BeginArray();
  j.Begin();
  j.Bool("b", true);
  j.End();
  j.Begin();
  j.Strings("s", {"p", "q"});
  j.End();
  j.EndArray();
  j.End();
  const nlohmann::json parsed = nlohmann::json::parse(j.str());
  EXPECT_TRUE(parsed["nan"].is_null());
  EXPECT_EQ(parsed["x"].get<double>(), 0.1);
  EXPECT_EQ(parsed["big"].get<std::int64_t>(), 1'234'567'890'123LL);
  EXPECT_EQ(parsed["text"], "a \"quote\", a \\ and a\nnewline\x01");
  EXPECT_EQ(parsed["t"]["sec"], 3);
  EXPECT_EQ(parsed["t"]["nsec"], 5);
  EXPECT_EQ(parsed["pose"]["position"]["z"], 3.0);
  EXPECT_EQ(parsed["pose"]["orientation"]["w"], 1.0);
  EXPECT_EQ(parsed["list"][1]["s"][1], "q");
}

TEST(McapSchemas, EverySchemaIsJsonAndNamesItsTitle) {
  for (const char* name : {"foxglove.PoseInFrame", "foxglove.FrameTransform", "foxglove.Log",
                           "foxglove.SceneUpdate", "tofu.ImuSample", "tofu.PoseMeasurement",
                           "tofu.PositionMeasurement", "tofu.Estimate", "tofu.EstimateError",
                           "tofu.ConsensusDecision", "tofu.ConsistencyMatrix"}) {
    const nlohmann::json schema = nlohmann::json::parse(JsonSchemaText(name));
    EXPECT_EQ(schema["title"], name);
    EXPECT_EQ(schema["type"], "object");
  }
  EXPECT_THROW(JsonSchemaText("foxglove.Nothing"), std::out_of_range);
}

}  // namespace
}  // namespace tofu::report
