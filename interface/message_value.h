#pragma once
// Internal to interface/: what a Message holds, and a read-only view of a value in either
// encoding, so that every decoder of protocol.cc is written once for JSON and MessagePack.

// msgpack-cxx without Boost: tofu uses its core API only (pack, unpack, object).
#ifndef MSGPACK_NO_BOOST
#define MSGPACK_NO_BOOST
#endif
#include <msgpack.hpp>
#include <nlohmann/json.hpp>

#include <cstddef>
#include <cstdint>
#include <optional>
#include <string>
#include <string_view>

#include "interface/framing.h"

namespace tofu::interface {

struct Message::Impl {
  Encoding encoding = Encoding::kJson;
  nlohmann::json json;              ///< kJson
  msgpack::object_handle msgpack;   ///< kMsgpack: the object and the zone that holds it
  std::string_view type;            ///< points into json or into the zone
};

/// A value of a message, in either encoding: a view, valid while its Message lives.
class Value {
 public:
  enum class Kind { kNull, kBool, kInt, kFloat, kString, kArray, kObject, kOther };

  explicit Value(const nlohmann::json* json) : json_(json) {}
  explicit Value(const msgpack::object* msgpack) : msgpack_(msgpack) {}

  Kind kind() const;
  bool boolean() const;
  /// kInt: whether it fits an int64 (a MessagePack or JSON unsigned beyond INT64_MAX does not).
  bool FitsInt64() const;
  std::int64_t int64() const;
  /// kInt or kFloat as a double.
  double number() const;
  std::string_view string() const;
  /// kArray: elements; kObject: members.
  std::size_t size() const;
  Value operator[](std::size_t index) const;  ///< kArray
  /// kObject: the member `key` (the last one, when a MessagePack map repeats it, as
  /// nlohmann keeps the last of a JSON object's duplicates); nullopt when absent.
  std::optional<Value> Find(std::string_view key) const;
  /// kObject: the key and the value of member `index`; false when the key is no string
  /// (MessagePack allows any key).
  bool Member(std::size_t index, std::string_view* key, Value* value) const;

  /// The value as JSON (MessagePack converted; binary and extension types refused with a
  /// ProtocolError naming `where`).
  nlohmann::json ToJson(std::string_view where) const;
  /// A short rendering for error messages: JSON-like, cut after about `max_chars`.
  std::string Describe(std::size_t max_chars = 60) const;

 private:
  void Render(std::string* out, std::size_t max_chars) const;
  const nlohmann::json* json_ = nullptr;
  const msgpack::object* msgpack_ = nullptr;
};

/// Throws ProtocolError when a message of `bytes` exceeds kMaxMessageBytes.
void CheckMessageSize(std::size_t bytes);
/// JSON text of `value` as tofu writes it: one line, invalid UTF-8 replaced (never thrown).
std::string DumpJson(const nlohmann::json& value);
/// A MessagePack frame started at out[start] with 4 placeholder bytes and its message
/// packed after them: writes the big-endian length (ProtocolError beyond 16 MiB).
void PatchMsgpackLength(std::size_t start, std::string* out);
/// msgpack::packer's output stream: appends to a std::string.
struct MsgpackStringStream {
  std::string* out;
  void write(const char* data, std::size_t size) { out->append(data, size); }
};
/// Appends `text` as a JSON string (quoted, escaped).
void AppendJsonString(std::string_view text, std::string* out);

inline Value RootValue(const Message& message) {
  const Message::Impl& impl = message.impl();
  return impl.encoding == Encoding::kJson ? Value(&impl.json) : Value(&impl.msgpack.get());
}

}  // namespace tofu::interface
