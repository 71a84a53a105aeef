#pragma once
// Framing of the process protocol (docs/INTERFACE.md, "Encoding"): the conversation starts
// in JSON lines (one object per line, ended by '\n'); the client's hello chooses the
// encoding of every later message in both directions, JSON lines or MessagePack (a 4-byte
// big-endian length, then one map of that many bytes). A message is at most 16 MiB.
//
// A received message is decoded once, into a Message (a JSON value or a MessagePack object
// in its own zone), which protocol.h's decoders read without converting it.

#include <cstddef>
#include <memory>
#include <optional>
#include <stdexcept>
#include <string>
#include <string_view>

#include <nlohmann/json_fwd.hpp>

namespace tofu::interface {

/// A message that breaks the protocol: not valid JSON/MessagePack, not an object with a
/// string "type", too long, of the wrong type, a missing key or a value of the wrong form.
/// what() names the message (type and seq when known), the offending field and the
/// expected form, e.g. "estimates seq=7: estimates[2].q_LI_wxyz: expected an array of 4
/// finite numbers, got [1,0,0]".
class ProtocolError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

enum class Encoding { kJson, kMsgpack };

/// "json" or "msgpack", as the hello messages spell them.
const char* EncodingName(Encoding encoding);

/// The largest message either side accepts (its bytes, without the frame's length or '\n').
inline constexpr std::size_t kMaxMessageBytes = std::size_t{16} << 20;

/// The bytes of `message` (an object) as one frame: a JSON line (doubles in shortest
/// round-trip form) or a length-prefixed MessagePack map.
std::string Frame(const nlohmann::json& message, Encoding encoding);
/// Frame() appended to *out.
void AppendFrame(const nlohmann::json& message, Encoding encoding, std::string* out);

/// One received message: an object with a string "type", held in the encoding it came in.
class Message {
 public:
  struct Impl;  // interface/message_value.h: what the decoders read

  /// A JSON value as a message (tests, and C++ code that builds messages as JSON).
  /// Throws ProtocolError unless it is an object with a string "type".
  static Message FromJson(nlohmann::json value);
  /// `bytes` (one message without its frame) decoded as `encoding`. Throws ProtocolError.
  static Message Parse(std::string_view bytes, Encoding encoding);

  Message(Message&&) noexcept;
  Message& operator=(Message&&) noexcept;
  ~Message();

  Encoding encoding() const;
  /// The value of its "type" key.
  std::string_view type() const;
  /// The message as a JSON value (a MessagePack message converted).
  nlohmann::json ToJson() const;
  const Impl& impl() const { return *impl_; }

 private:
  explicit Message(std::unique_ptr<Impl> impl);
  std::unique_ptr<Impl> impl_;
};

/// Splits a byte stream into messages, incrementally. Feed() what arrived, then call Next()
/// until it returns nullopt. The encoding may change between two messages (after the hello
/// exchange): bytes already fed but not yet returned are read in the new one.
class FrameReader {
 public:
  explicit FrameReader(Encoding encoding = Encoding::kJson) : encoding_(encoding) {}

  void SetEncoding(Encoding encoding) { encoding_ = encoding; }
  Encoding encoding() const { return encoding_; }

  void Feed(std::string_view bytes);
  /// The next complete message; nullopt when the bytes fed so far hold none. Throws
  /// ProtocolError for a message longer than kMaxMessageBytes, a line that is not a JSON
  /// object with a string "type", or a frame that is not one MessagePack map with one.
  /// After a throw the reader is unusable (the stream cannot be resynchronised).
  std::optional<Message> Next();

  /// Bytes fed and not yet returned as a message (part of a message still arriving).
  std::size_t buffered() const { return buffer_.size() - consumed_; }

 private:
  Encoding encoding_;
  std::string buffer_;
  std::size_t consumed_ = 0;  ///< bytes of buffer_ already returned
  std::size_t scanned_ = 0;   ///< JSON: bytes after consumed_ known to hold no '\n'
};

}  // namespace tofu::interface
