#include "interface/framing.h"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <limits>
#include <utility>

#include "interface/message_value.h"

namespace tofu::interface {
namespace {

using nlohmann::json;

// What the start of a rejected message looks like, for the error.
std::string Excerpt(std::string_view bytes, std::size_t max_chars = 80) {
  std::string text;
  for (const char c : bytes.substr(0, max_chars)) {
    const auto u = static_cast<unsigned char>(c);
    text += (u >= 0x20 && u < 0x7f) ? std::string(1, c) : fmt::format("\\x{:02x}", u);
  }
  if (bytes.size() > max_chars) text += fmt::format("... ({} bytes)", bytes.size());
  return text;
}

// The message's "type", checked; `value` is its root.
std::string_view TypeOf(const Value& value) {
  if (value.kind() != Value::Kind::kObject) {
    throw ProtocolError(fmt::format("a message that is not an object: got {}", value.Describe()));
  }
  const std::optional<Value> type = value.Find("type");
  if (!type) {
    throw ProtocolError(
        fmt::format("a message without a \"type\" key: got {}", value.Describe()));
  }
  if (type->kind() != Value::Kind::kString) {
    throw ProtocolError(
        fmt::format("\"type\": expected a string, got {}", type->Describe()));
  }
  return type->string();
}

}  // namespace

// UTF-8 errors are replaced rather than thrown: a user's calibration.yaml may hold any
// bytes. dump() escapes newlines, so the text is one line.
std::string DumpJson(const json& value) {
  return value.dump(-1, ' ', false, json::error_handler_t::replace);
}

void AppendJsonString(std::string_view text, std::string* out) {
  // Sensor and method names are plain ASCII: no escaping, no allocation.
  const bool plain = std::all_of(text.begin(), text.end(), [](char c) {
    const auto u = static_cast<unsigned char>(c);
    return u >= 0x20 && u < 0x7f && c != '"' && c != '\\';
  });
  if (!plain) {
    out->append(DumpJson(json(std::string(text))));
    return;
  }
  out->push_back('"');
  out->append(text);
  out->push_back('"');
}

void CheckMessageSize(std::size_t bytes) {
  if (bytes > kMaxMessageBytes) {
    throw ProtocolError(fmt::format("a message of {} bytes: at most {} (16 MiB) are allowed",
                                    bytes, kMaxMessageBytes));
  }
}

const char* EncodingName(Encoding encoding) {
  return encoding == Encoding::kJson ? "json" : "msgpack";
}

void AppendFrame(const json& message, Encoding encoding, std::string* out) {
  const std::size_t start = out->size();
  try {
    if (encoding == Encoding::kJson) {
      out->append(DumpJson(message));
      CheckMessageSize(out->size() - start);
      out->push_back('\n');
      return;
    }
    out->append(4, '\0');
    json::to_msgpack(message, nlohmann::detail::output_adapter<char>(*out));
    PatchMsgpackLength(start, out);
  } catch (...) {
    out->resize(start);  // no half frame: the stream stays in step
    throw;
  }
}

void PatchMsgpackLength(std::size_t start, std::string* out) {
  const std::size_t size = out->size() - start - 4;
  CheckMessageSize(size);
  for (int i = 0; i < 4; ++i) {
    (*out)[start + i] = static_cast<char>((size >> (8 * (3 - i))) & 0xffu);
  }
}

std::string Frame(const json& message, Encoding encoding) {
  std::string out;
  AppendFrame(message, encoding, &out);
  return out;
}

// ---- Message ----

Message::Message(std::unique_ptr<Impl> impl) : impl_(std::move(impl)) {}
Message::Message(Message&&) noexcept = default;
Message& Message::operator=(Message&&) noexcept = default;
Message::~Message() = default;

Encoding Message::encoding() const { return impl_->encoding; }
std::string_view Message::type() const { return impl_->type; }

json Message::ToJson() const {
  if (impl_->encoding == Encoding::kJson) return impl_->json;
  return RootValue(*this).ToJson("message");
}

Message Message::FromJson(json value) {
  auto impl = std::make_unique<Impl>();
  impl->encoding = Encoding::kJson;
  impl->json = std::move(value);
  impl->type = TypeOf(Value(&impl->json));
  return Message(std::move(impl));
}

Message Message::Parse(std::string_view bytes, Encoding encoding) {
  CheckMessageSize(bytes.size());
  auto impl = std::make_unique<Impl>();
  impl->encoding = encoding;
  if (encoding == Encoding::kJson) {
    try {
      impl->json = json::parse(bytes.begin(), bytes.end());
    } catch (const json::exception& e) {
      std::string why = e.what();
      if (const std::size_t end = why.find("] "); why.rfind("[json.exception", 0) == 0 &&
                                                  end != std::string::npos) {
        why = why.substr(end + 2);
      }
      // Python's json.dumps writes NaN and Infinity, which JSON does not have.
      const bool non_finite = bytes.find("NaN") != std::string_view::npos ||
                              bytes.find("Infinity") != std::string_view::npos;
      throw ProtocolError(fmt::format(
          "a line that is not valid JSON ({}){}: {}", why,
          non_finite ? "; JSON has no NaN or Infinity, and every number must be finite" : "",
          Excerpt(bytes)));
    }
    impl->type = TypeOf(Value(&impl->json));
    return Message(std::move(impl));
  }
  std::size_t offset = 0;
  try {
    // Each element, member or byte of a string needs at least one byte of the frame: the
    // limits keep a forged length from allocating more than the frame could hold.
    const std::size_t n = bytes.size();
    const msgpack::unpack_limit limit(n, n, n, n, n, /*depth=*/64);
    impl->msgpack = msgpack::unpack(bytes.data(), bytes.size(), offset, nullptr, nullptr, limit);
  } catch (const std::exception& e) {
    throw ProtocolError(fmt::format("a frame that is not valid MessagePack ({}): {}", e.what(),
                                    Excerpt(bytes, 40)));
  }
  if (offset != bytes.size()) {
    throw ProtocolError(fmt::format(
        "a frame of {} bytes that holds more than one MessagePack value (the first ends at "
        "byte {})",
        bytes.size(), offset));
  }
  impl->type = TypeOf(Value(&impl->msgpack.get()));
  return Message(std::move(impl));
}

// ---- Value ----

Value::Kind Value::kind() const {
  if (json_ != nullptr) {
    switch (json_->type()) {
      case json::value_t::null: return Kind::kNull;
      case json::value_t::boolean: return Kind::kBool;
      case json::value_t::number_integer:
      case json::value_t::number_unsigned: return Kind::kInt;
      case json::value_t::number_float: return Kind::kFloat;
      case json::value_t::string: return Kind::kString;
      case json::value_t::array: return Kind::kArray;
      case json::value_t::object: return Kind::kObject;
      default: return Kind::kOther;
    }
  }
  switch (msgpack_->type) {
    case msgpack::type::NIL: return Kind::kNull;
    case msgpack::type::BOOLEAN: return Kind::kBool;
    case msgpack::type::POSITIVE_INTEGER:
    case msgpack::type::NEGATIVE_INTEGER: return Kind::kInt;
    case msgpack::type::FLOAT32:
    case msgpack::type::FLOAT64: return Kind::kFloat;
    case msgpack::type::STR: return Kind::kString;
    case msgpack::type::ARRAY: return Kind::kArray;
    case msgpack::type::MAP: return Kind::kObject;
    default: return Kind::kOther;
  }
}

bool Value::boolean() const { return json_ != nullptr ? json_->get<bool>() : msgpack_->via.boolean; }

bool Value::FitsInt64() const {
  constexpr auto kMax = static_cast<std::uint64_t>(std::numeric_limits<std::int64_t>::max());
  if (json_ != nullptr) return !json_->is_number_unsigned() || json_->get<std::uint64_t>() <= kMax;
  return msgpack_->type != msgpack::type::POSITIVE_INTEGER || msgpack_->via.u64 <= kMax;
}

std::int64_t Value::int64() const {
  if (json_ != nullptr) return json_->get<std::int64_t>();
  return msgpack_->type == msgpack::type::POSITIVE_INTEGER
             ? static_cast<std::int64_t>(msgpack_->via.u64)
             : msgpack_->via.i64;
}

double Value::number() const {
  if (json_ != nullptr) return json_->get<double>();
  switch (msgpack_->type) {
    case msgpack::type::POSITIVE_INTEGER: return static_cast<double>(msgpack_->via.u64);
    case msgpack::type::NEGATIVE_INTEGER: return static_cast<double>(msgpack_->via.i64);
    default: return msgpack_->via.f64;  // FLOAT32 too: msgpack-c widens it on unpacking
  }
}

std::string_view Value::string() const {
  if (json_ != nullptr) return json_->get_ref<const std::string&>();
  return {msgpack_->via.str.ptr, msgpack_->via.str.size};
}

std::size_t Value::size() const {
  if (json_ != nullptr) return json_->size();
  return msgpack_->type == msgpack::type::ARRAY ? msgpack_->via.array.size
                                                : msgpack_->via.map.size;
}

Value Value::operator[](std::size_t index) const {
  if (json_ != nullptr) return Value(&(*json_)[index]);
  return Value(&msgpack_->via.array.ptr[index]);
}

std::optional<Value> Value::Find(std::string_view key) const {
  if (json_ != nullptr) {
    const auto it = json_->find(key);
    if (it == json_->end()) return std::nullopt;
    return Value(&*it);
  }
  std::optional<Value> found;
  const msgpack::object_map& map = msgpack_->via.map;
  for (std::uint32_t i = 0; i < map.size; ++i) {
    const msgpack::object& k = map.ptr[i].key;
    if (k.type == msgpack::type::STR && std::string_view(k.via.str.ptr, k.via.str.size) == key) {
      found = Value(&map.ptr[i].val);
    }
  }
  return found;
}

bool Value::Member(std::size_t index, std::string_view* key, Value* value) const {
  if (json_ != nullptr) {
    auto it = json_->begin();
    std::advance(it, static_cast<std::ptrdiff_t>(index));
    *key = it.key();
    *value = Value(&it.value());
    return true;
  }
  const msgpack::object_kv& kv = msgpack_->via.map.ptr[index];
  *value = Value(&kv.val);
  if (kv.key.type != msgpack::type::STR) return false;
  *key = std::string_view(kv.key.via.str.ptr, kv.key.via.str.size);
  return true;
}

json Value::ToJson(std::string_view where) const {
  if (json_ != nullptr) return *json_;
  switch (kind()) {
    case Kind::kNull: return nullptr;
    case Kind::kBool: return boolean();
    case Kind::kInt:
      if (msgpack_->type == msgpack::type::POSITIVE_INTEGER) return msgpack_->via.u64;
      return msgpack_->via.i64;
    case Kind::kFloat: return msgpack_->via.f64;
    case Kind::kString: return std::string(string());
    case Kind::kArray: {
      json array = json::array();
      for (std::size_t i = 0; i < size(); ++i) {
        array.push_back((*this)[i].ToJson(fmt::format("{}[{}]", where, i)));
      }
      return array;
    }
    case Kind::kObject: {
      json object = json::object();
      for (std::size_t i = 0; i < size(); ++i) {
        std::string_view key;
        Value value(static_cast<const json*>(nullptr));
        if (!Member(i, &key, &value)) {
          throw ProtocolError(fmt::format("{}: a map key that is not a string", where));
        }
        object[std::string(key)] = value.ToJson(fmt::format("{}.{}", where, key));
      }
      return object;
    }
    case Kind::kOther: break;
  }
  throw ProtocolError(fmt::format(
      "{}: a MessagePack binary or extension value, which has no JSON form", where));
}

void Value::Render(std::string* out, std::size_t max_chars) const {
  if (out->size() > max_chars) return;
  switch (kind()) {
    case Kind::kNull: *out += "null"; return;
    case Kind::kBool: *out += boolean() ? "true" : "false"; return;
    case Kind::kInt:
      *out += FitsInt64() ? fmt::to_string(int64()) : fmt::to_string(msgpack_ != nullptr
                                                                          ? msgpack_->via.u64
                                                                          : json_->get<std::uint64_t>());
      return;
    case Kind::kFloat: {
      const double x = number();
      *out += std::isnan(x) ? "NaN" : std::isinf(x) ? (x > 0 ? "Infinity" : "-Infinity")
                                                    : fmt::format("{}", x);
      return;
    }
    case Kind::kString: {
      const std::string_view text = string();
      *out += DumpJson(json(std::string(text.substr(0, max_chars + 1))));
      return;
    }
    case Kind::kArray:
    case Kind::kObject: {
      const bool array = kind() == Kind::kArray;
      *out += array ? '[' : '{';
      for (std::size_t i = 0; i < size() && out->size() <= max_chars; ++i) {
        if (i > 0) *out += ',';
        if (array) {
          (*this)[i].Render(out, max_chars);
          continue;
        }
        std::string_view key;
        Value value(static_cast<const json*>(nullptr));
        if (Member(i, &key, &value)) {
          *out += DumpJson(json(std::string(key.substr(0, max_chars + 1))));
        } else {
          *out += "?";
        }
        *out += ':';
        value.Render(out, max_chars);
      }
      *out += array ? ']' : '}';
      return;
    }
    case Kind::kOther: *out += "<binary>"; return;
  }
}

std::string Value::Describe(std::size_t max_chars) const {
  std::string out;
  Render(&out, max_chars);
  if (out.size() > max_chars) {
    out.resize(max_chars);
    out += "...";
  }
  return out;
}

// ---- FrameReader ----

void FrameReader::Feed(std::string_view bytes) {
  if (consumed_ == buffer_.size()) {
    buffer_.clear();
    consumed_ = 0;
  } else if (consumed_ > (std::size_t{64} << 10) && consumed_ > buffer_.size() / 2) {
    buffer_.erase(0, consumed_);
    consumed_ = 0;
  }
  buffer_.append(bytes);
}

std::optional<Message> FrameReader::Next() {
  for (;;) {
    const std::string_view pending = std::string_view(buffer_).substr(consumed_);
    if (encoding_ == Encoding::kJson) {
      const std::size_t newline = pending.find('\n', scanned_);
      if (newline == std::string_view::npos) {
        scanned_ = pending.size();
        if (scanned_ > kMaxMessageBytes + 1) {
          throw ProtocolError(fmt::format(
              "a line longer than 16 MiB ({} bytes without a newline so far): {}", scanned_,
              Excerpt(pending, 40)));
        }
        return std::nullopt;
      }
      std::string_view line = pending.substr(0, newline);
      consumed_ += newline + 1;
      scanned_ = 0;
      if (!line.empty() && line.back() == '\r') line.remove_suffix(1);
      if (line.find_first_not_of(" \t") == std::string_view::npos) continue;  // blank line
      return Message::Parse(line, Encoding::kJson);
    }
    if (pending.size() < 4) return std::nullopt;
    std::size_t size = 0;
    for (int i = 0; i < 4; ++i) size = (size << 8) | static_cast<unsigned char>(pending[i]);
    if (size > kMaxMessageBytes) {
      throw ProtocolError(fmt::format(
          "a MessagePack frame of {} bytes: at most {} (16 MiB) are allowed (its 4-byte "
          "big-endian length prefix: {})",
          size, kMaxMessageBytes, Excerpt(pending.substr(0, 4))));
    }
    if (size == 0) throw ProtocolError("a MessagePack frame of 0 bytes (expected one map)");
    if (pending.size() < 4 + size) return std::nullopt;
    consumed_ += 4 + size;
    return Message::Parse(pending.substr(4, size), Encoding::kMsgpack);
  }
}

}  // namespace tofu::interface
