#include "interface/protocol.h"

#include <fmt/format.h>

#include <array>
#include <cmath>
#include <cstddef>
#include <cstring>
#include <limits>
#include <optional>
#include <stdexcept>
#include <utility>

#include "interface/message_value.h"

namespace tofu::interface {
namespace {

using nlohmann::json;

// ---------------------------------------------------------------------------------------
// Writers. Each message's schema is written once (the Write* templates below) for three
// writers: JSON text, MessagePack, and a nlohmann::json value. BeginObject/BeginArray take
// the number of members or elements, which MessagePack writes up front.

class JsonTextWriter {
 public:
  explicit JsonTextWriter(std::string* out) : out_(out) {}
  void BeginObject(std::size_t) { Open('{'); }
  void EndObject() { Close('}'); }
  void BeginArray(std::size_t) { Open('['); }
  void EndArray() { Close(']'); }
  void Key(std::string_view key) {  // keys are the schema's: plain ASCII
    Comma();
    out_->push_back('"');
    out_->append(key);
    out_->append("\":");
    comma_ = false;
  }
  void Int(std::int64_t value) {
    Comma();
    char text[24];
    const char* end = fmt::format_to_n(text, sizeof(text), "{}", value).out;
    out_->append(text, static_cast<std::size_t>(end - text));
    comma_ = true;
  }
  void Double(double value) {
    Comma();
    if (!std::isfinite(value)) {
      out_->append("null");  // JSON has no NaN or Infinity
    } else {
      // fmt's default for a double is the shortest text that reads back bit for bit. An
      // integral value prints without a point ("-0", "3"): the ".0" keeps it a double for
      // a JSON reader (nlohmann reads "-0" as the integer 0, which loses the sign).
      char text[40];
      const char* end = fmt::format_to_n(text, sizeof(text) - 2, "{}", value).out;
      out_->append(text, static_cast<std::size_t>(end - text));
      if (std::string_view(text, static_cast<std::size_t>(end - text)).find_first_of(".e") ==
          std::string_view::npos) {
        out_->append(".0");
      }
    }
    comma_ = true;
  }
  void Bool(bool value) {
    Comma();
    out_->append(value ? "true" : "false");
    comma_ = true;
  }
  void String(std::string_view text) {
    Comma();
    AppendJsonString(text, out_);
    comma_ = true;
  }

 private:
  void Comma() {
    if (comma_) out_->push_back(',');
  }
  void Open(char c) {
    Comma();
    out_->push_back(c);
    comma_ = false;
  }
  void Close(char c) {
    out_->push_back(c);
    comma_ = true;
  }
  std::string* out_;
  bool comma_ = false;
};

class MsgpackWriter {
 public:
  explicit MsgpackWriter(std::string* out) : stream_{out}, packer_(stream_) {}
  void BeginObject(std::size_t members) { packer_.pack_map(static_cast<std::uint32_t>(members)); }
  void EndObject() {}
  void BeginArray(std::size_t elements) { packer_.pack_array(static_cast<std::uint32_t>(elements)); }
  void EndArray() {}
  void Key(std::string_view key) { String(key); }
  void Int(std::int64_t value) { packer_.pack_int64(value); }
  // Always a float64. msgpack-c's pack_double writes an integral double as an integer,
  // which loses the sign of -0.0 (and makes 1.0 an integer to the client).
  void Double(double value) {
    std::uint64_t bits = 0;
    std::memcpy(&bits, &value, sizeof(bits));
    char bytes[9];
    bytes[0] = static_cast<char>(0xcb);
    for (int i = 0; i < 8; ++i) bytes[1 + i] = static_cast<char>(bits >> (56 - 8 * i));
    stream_.write(bytes, sizeof(bytes));
  }
  void Bool(bool value) { value ? packer_.pack_true() : packer_.pack_false(); }
  void String(std::string_view text) {
    packer_.pack_str(static_cast<std::uint32_t>(text.size()));
    packer_.pack_str_body(text.data(), static_cast<std::uint32_t>(text.size()));
  }

 private:
  MsgpackStringStream stream_;
  msgpack::packer<MsgpackStringStream> packer_;
};

class JsonValueWriter {
 public:
  json Take() { return std::move(root_); }
  void BeginObject(std::size_t) { stack_.push_back(Put(json::object())); }
  void EndObject() { stack_.pop_back(); }
  void BeginArray(std::size_t) { stack_.push_back(Put(json::array())); }
  void EndArray() { stack_.pop_back(); }
  void Key(std::string_view key) { key_.assign(key); }
  void Int(std::int64_t value) { Put(value); }
  void Double(double value) { Put(value); }
  void Bool(bool value) { Put(value); }
  void String(std::string_view text) { Put(std::string(text)); }

 private:
  // The new value's slot: the root, the member key_ of the open object, or the next
  // element of the open array. Pointers to open containers stay valid: only the innermost
  // one grows.
  json* Put(json value) {
    if (stack_.empty()) {
      root_ = std::move(value);
      return &root_;
    }
    json& top = *stack_.back();
    if (top.is_object()) {
      json& slot = top[key_];
      slot = std::move(value);
      return &slot;
    }
    top.push_back(std::move(value));
    return &top.back();
  }
  json root_;
  std::vector<json*> stack_;
  std::string key_;
};

template <class W, std::size_t N>
void WriteArray(W& w, std::string_view key, const std::array<double, N>& values) {
  w.Key(key);
  w.BeginArray(N);
  for (const double v : values) w.Double(v);
  w.EndArray();
}

template <class W>
void WriteArray(W& w, std::string_view key, const std::vector<double>& values) {
  w.Key(key);
  w.BeginArray(values.size());
  for (const double v : values) w.Double(v);
  w.EndArray();
}

const api::SensorInfo& SensorOf(const api::EstimatorSetup& setup, const api::Measurement& m) {
  if (m.sensor >= setup.sensors.size()) {
    throw std::invalid_argument(fmt::format(
        "measurement at t_ns={}: sensor index {} is not one of the setup's {} sensors", m.t_ns,
        m.sensor, setup.sensors.size()));
  }
  return setup.sensors[m.sensor];
}

template <class W>
void WriteMeasurement(W& w, std::int64_t seq, const api::EstimatorSetup& setup,
                      const api::Measurement& m) {
  const api::SensorInfo& sensor = SensorOf(setup, m);
  std::size_t members = 7;
  switch (m.kind) {
    case api::SensorKind::kImu: members += 2; break;
    case api::SensorKind::kPose: members += m.pose.has_twist ? 4 : 3; break;
    case api::SensorKind::kPosition: members += 2; break;
  }
  w.BeginObject(members);
  w.Key("type");
  w.String("measurement");
  w.Key("seq");
  w.Int(seq);
  w.Key("t_ns");
  w.Int(m.t_ns);
  w.Key("arrival_ns");
  w.Int(m.arrival_ns);
  w.Key("sensor");
  w.String(sensor.name);
  w.Key("sensor_index");
  w.Int(static_cast<std::int64_t>(m.sensor));
  w.Key("kind");
  w.String(api::SensorKindName(m.kind));
  switch (m.kind) {
    case api::SensorKind::kImu:
      WriteArray(w, "acc_I_mps2", m.imu.acc_I_mps2);
      WriteArray(w, "gyro_I_radps", m.imu.gyro_I_radps);
      break;
    case api::SensorKind::kPose:
      WriteArray(w, "p_Ss_m", m.pose.T_Ss.p_m);
      WriteArray(w, "q_Ss_wxyz", m.pose.T_Ss.q_wxyz);
      WriteArray(w, "covariance", m.pose.covariance);
      if (m.pose.has_twist) {
        w.Key("twist");
        w.BeginObject(3);
        WriteArray(w, "v_s_mps", m.pose.v_s_mps);
        WriteArray(w, "omega_s_radps", m.pose.omega_s_radps);
        WriteArray(w, "covariance", m.pose.twist_covariance);
        w.EndObject();
      }
      break;
    case api::SensorKind::kPosition:
      WriteArray(w, "p_Ss_m", m.position.p_Ss_m);
      WriteArray(w, "covariance_m2", m.position.covariance_m2);
      break;
  }
  w.EndObject();
}

template <class W>
void WriteControl(W& w, std::int64_t seq, const api::ControlState& state,
                  const api::ControlReference& reference) {
  w.BeginObject(5);
  w.Key("type");
  w.String("control");
  w.Key("seq");
  w.Int(seq);
  w.Key("t_ns");
  w.Int(state.t_ns);
  w.Key("state");
  w.BeginObject(5);
  WriteArray(w, "p_WB_m", state.T_WB.p_m);
  WriteArray(w, "q_WB_wxyz", state.T_WB.q_wxyz);
  WriteArray(w, "v_W_mps", state.v_W_mps);
  WriteArray(w, "omega_B_radps", state.omega_B_radps);
  w.Key("from_estimate");
  w.Bool(state.from_estimate);
  w.EndObject();
  w.Key("reference");
  w.BeginObject(6);
  WriteArray(w, "p_WB_m", reference.T_WB.p_m);
  WriteArray(w, "q_WB_wxyz", reference.T_WB.q_wxyz);
  WriteArray(w, "v_W_mps", reference.v_W_mps);
  WriteArray(w, "a_W_mps2", reference.a_W_mps2);
  WriteArray(w, "omega_B_radps", reference.omega_B_radps);
  WriteArray(w, "alpha_B_radps2", reference.alpha_B_radps2);
  w.EndObject();
  w.EndObject();
}

template <class W>
void WriteEstimate(W& w, const api::Estimate& e) {
  w.BeginObject(9 + (e.position_covariance_m2 ? 1 : 0) + (e.fused ? 1 : 0) + (e.T_ML ? 2 : 0) +
                (e.T_ML_covariance ? 1 : 0));
  w.Key("t_ns");
  w.Int(e.t_ns);
  w.Key("valid");
  w.Bool(e.valid);
  w.Key("initialized");
  w.Bool(e.initialized);
  WriteArray(w, "p_LI_m", e.T_LI.p_m);
  WriteArray(w, "q_LI_wxyz", e.T_LI.q_wxyz);
  WriteArray(w, "v_L_mps", e.v_L_mps);
  WriteArray(w, "omega_I_radps", e.omega_I_radps);
  WriteArray(w, "bias_acc_mps2", e.bias_acc_mps2);
  WriteArray(w, "bias_gyro_radps", e.bias_gyro_radps);
  if (e.position_covariance_m2) WriteArray(w, "position_covariance_m2", *e.position_covariance_m2);
  if (e.fused) {
    w.Key("fused");
    w.BeginArray(e.fused->size());
    for (const std::string& name : *e.fused) w.String(name);
    w.EndArray();
  }
  if (e.T_ML) {
    WriteArray(w, "p_ML_m", e.T_ML->p_m);
    WriteArray(w, "q_ML_wxyz", e.T_ML->q_wxyz);
  }
  if (e.T_ML_covariance) WriteArray(w, "T_ML_covariance", *e.T_ML_covariance);
  w.EndObject();
}

template <class W>
void WriteEstimates(W& w, std::int64_t seq, const api::Estimate* estimates, std::size_t count) {
  w.BeginObject(3);
  w.Key("type");
  w.String("estimates");
  w.Key("seq");
  w.Int(seq);
  w.Key("estimates");
  w.BeginArray(count);
  for (std::size_t i = 0; i < count; ++i) WriteEstimate(w, estimates[i]);
  w.EndArray();
  w.EndObject();
}

template <class W>
void WriteCommand(W& w, std::int64_t seq, const api::ControlCommand& command) {
  w.BeginObject(4);
  w.Key("type");
  w.String("command");
  w.Key("seq");
  w.Int(seq);
  if (command.kind == api::ControlCommand::Kind::kWrench) {
    WriteArray(w, "force_B_N", command.force_B_N);
    WriteArray(w, "torque_B_Nm", command.torque_B_Nm);
  } else {
    WriteArray(w, "tilt_rad", command.tilt_rad);
    WriteArray(w, "rotor_thrust_N", command.rotor_thrust_N);
  }
  w.EndObject();
}

// Frames what `write(writer)` writes, in `encoding`, appended to *out; nothing is appended
// when it throws.
template <class WriteFn>
void AppendFramed(Encoding encoding, std::string* out, WriteFn&& write) {
  const std::size_t start = out->size();
  try {
    if (encoding == Encoding::kJson) {
      JsonTextWriter writer(out);
      write(writer);
      CheckMessageSize(out->size() - start);
      out->push_back('\n');
    } else {
      out->append(4, '\0');
      MsgpackWriter writer(out);
      write(writer);
      PatchMsgpackLength(start, out);
    }
  } catch (...) {
    out->resize(start);
    throw;
  }
}

template <class WriteFn>
json BuildJson(WriteFn&& write) {
  JsonValueWriter writer;
  write(writer);
  return writer.Take();
}

json PoseJson(const api::Pose& pose) { return {{"p_m", pose.p_m}, {"q_wxyz", pose.q_wxyz}}; }

// A JSON object given as text (a scenario's config:, a client's report).
json ParseObject(std::string_view text, std::string_view what) {
  json value;
  try {
    value = json::parse(text);
  } catch (const json::exception& e) {
    throw ProtocolError(fmt::format("{}: expected a JSON object, got text that is not JSON ({})",
                                    what, e.what()));
  }
  if (!value.is_object()) {
    throw ProtocolError(fmt::format("{}: expected a JSON object, got {}", what,
                                    Value(&value).Describe()));
  }
  return value;
}

// ---------------------------------------------------------------------------------------
// Decoding

// Where a value sits in its message, for errors: a chain of stack frames, turned into text
// (`estimates[2].q_LI_wxyz`) only when an error is thrown.
struct Path {
  const Path* parent = nullptr;
  std::string_view key;
  std::size_t index = 0;
  bool is_index = false;

  Path Member(std::string_view member) const { return Path{this, member, 0, false}; }
  Path Element(std::size_t i) const { return Path{this, {}, i, true}; }
  std::string ToString() const {
    std::string text = parent != nullptr ? parent->ToString() : std::string();
    if (is_index) return text + fmt::format("[{}]", index);
    if (key.empty()) return text;
    return text.empty() ? std::string(key) : text + "." + std::string(key);
  }
};

// The message itself: every path starts here (a Path refers to its parent, so the root
// must outlive them all).
const Path kRoot;

constexpr const char* kFiniteNumber = "a finite number";

// Reads one message of an expected type; every failure names it ("estimates seq=7").
class Reader {
 public:
  // `seq`: the seq it must carry (its answers), or nullopt (messages without one, or whose
  // seq is read by the caller).
  Reader(const Message& message, std::string_view type, std::optional<std::int64_t> seq = {})
      : root_(RootValue(message)), type_(type), expected_seq_(seq) {
    if (message.type() != type) {
      if (message.type() == "error") {
        throw ProtocolError(fmt::format("{}: got an error message instead: {}", type,
                                        DecodeErrorMessage(message)));
      }
      Fail(kRoot.Member("type"), fmt::format("\"{}\"", type), *root_.Find("type"));
    }
    if (expected_seq_) {
      const std::int64_t seq_value = Int(Member(root_, kRoot, "seq", "an integer"),
                                         kRoot.Member("seq"));
      if (seq_value != *expected_seq_) {
        Fail(kRoot.Member("seq"),
             fmt::format("{} (one answer per message, in order)", *expected_seq_),
             *root_.Find("seq"));
      }
    }
  }

  Value root() const { return root_; }

  [[noreturn]] void FailText(const Path& path, const std::string& text) const {
    const std::string where = path.ToString();
    throw ProtocolError(fmt::format("{}: {}{}", Label(), where.empty() ? "" : where + ": ", text));
  }
  [[noreturn]] void Fail(const Path& path, std::string_view expected, const Value& got) const {
    FailText(path, fmt::format("expected {}, got {}", expected, got.Describe()));
  }

  /// The required member `key` of the object `object` (at `path`).
  Value Member(const Value& object, const Path& path, std::string_view key,
               std::string_view expected) const {
    std::optional<Value> value = object.Find(key);
    if (!value) FailText(path.Member(key), fmt::format("missing; expected {}", expected));
    return *value;
  }
  /// The optional member `key`: absent and null alike are nullopt.
  std::optional<Value> Optional(const Value& object, std::string_view key) const {
    std::optional<Value> value = object.Find(key);
    if (value && value->kind() == Value::Kind::kNull) return std::nullopt;
    return value;
  }

  Value Object(const Value& value, const Path& path, std::string_view what = "an object") const {
    if (value.kind() != Value::Kind::kObject) Fail(path, what, value);
    return value;
  }
  std::int64_t Int(const Value& value, const Path& path) const {
    if (value.kind() != Value::Kind::kInt || !value.FitsInt64()) {
      Fail(path, "an integer (int64)", value);
    }
    return value.int64();
  }
  bool Bool(const Value& value, const Path& path) const {
    if (value.kind() != Value::Kind::kBool) Fail(path, "a boolean (true or false)", value);
    return value.boolean();
  }
  std::string_view String(const Value& value, const Path& path) const {
    if (value.kind() != Value::Kind::kString) Fail(path, "a string", value);
    return value.string();
  }
  double Finite(const Value& value, const Path& path) const {
    const Value::Kind kind = value.kind();
    if (kind == Value::Kind::kInt || kind == Value::Kind::kFloat) {
      const double x = value.number();
      if (std::isfinite(x)) return x;
    }
    Fail(path, kFiniteNumber, value);
  }
  /// Numbers of tofu's messages may be NaN (a sensor fault): null in JSON.
  double NumberOrNaN(const Value& value, const Path& path) const {
    const Value::Kind kind = value.kind();
    if (kind == Value::Kind::kNull) return std::numeric_limits<double>::quiet_NaN();
    if (kind == Value::Kind::kInt || kind == Value::Kind::kFloat) return value.number();
    Fail(path, "a number (null for NaN)", value);
  }

  /// An array of exactly `count` numbers into out[0..count): finite ones, or (`finite`
  /// false) any number or null (NaN). The expected form is only formatted for an error.
  void Numbers(const Value& value, const Path& path, double* out, std::size_t count, bool finite,
               std::string_view note = {}) const {
    if (value.kind() != Value::Kind::kArray || value.size() != count) {
      Fail(path, ArrayForm(count, finite, note), value);
    }
    for (std::size_t i = 0; i < count; ++i) {
      const Value element = value[i];
      const Value::Kind kind = element.kind();
      if (kind == Value::Kind::kInt || kind == Value::Kind::kFloat) {
        out[i] = element.number();
        if (!finite || std::isfinite(out[i])) continue;
      } else if (!finite && kind == Value::Kind::kNull) {
        out[i] = std::numeric_limits<double>::quiet_NaN();
        continue;
      }
      FailText(path, fmt::format("expected {}, got {} (element {} is {})",
                                 ArrayForm(count, finite, note), value.Describe(), i,
                                 element.Describe(20)));
    }
  }
  /// The required member `key` of `object`, an array of `count` numbers (as Numbers).
  void NumbersAt(const Value& object, const Path& path, std::string_view key, double* out,
                 std::size_t count, bool finite, std::string_view note = {}) const {
    const std::optional<Value> value = object.Find(key);
    if (!value) {
      FailText(path.Member(key), "missing; expected " + ArrayForm(count, finite, note));
    }
    Numbers(*value, path.Member(key), out, count, finite, note);
  }
  template <std::size_t N>
  void Finite(const Value& object, const Path& path, std::string_view key,
              std::array<double, N>* out) const {
    NumbersAt(object, path, key, out->data(), N, true);
  }
  template <std::size_t N>
  void Nanable(const Value& object, const Path& path, std::string_view key,
               std::array<double, N>* out) const {
    NumbersAt(object, path, key, out->data(), N, false);
  }

 private:
  static std::string ArrayForm(std::size_t count, bool finite, std::string_view note) {
    return fmt::format("an array of {} {}{}", count,
                       finite ? "finite numbers" : "numbers (null for NaN)", note);
  }

  std::string Label() const {
    std::optional<std::int64_t> seq = expected_seq_;
    if (const std::optional<Value> value = root_.Find("seq");
        value && value->kind() == Value::Kind::kInt && value->FitsInt64()) {
      seq = value->int64();
    }
    return seq ? fmt::format("{} seq={}", type_, *seq) : std::string(type_);
  }

  Value root_;
  std::string_view type_;
  std::optional<std::int64_t> expected_seq_;
};

// A quaternion tofu can normalise: non-zero, finite norm.
void RequireRotation(const Reader& r, const Value& object, const Path& path, std::string_view key,
                     const api::Quat& q) {
  const double norm2 = q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3];
  if (!(norm2 > 0.0) || !std::isfinite(norm2)) {
    r.Fail(path.Member(key), "a quaternion [w, x, y, z] of non-zero, finite norm (tofu normalises it)",
           *object.Find(key));
  }
}

// One estimate of an `estimates` or `finished` message.
api::Estimate ReadEstimate(const Reader& r, const Value& value, const Path& path) {
  const Value object = r.Object(value, path, "an object (an estimate)");
  api::Estimate e;
  e.t_ns = r.Int(r.Member(object, path, "t_ns", "an integer"), path.Member("t_ns"));
  e.valid = r.Bool(r.Member(object, path, "valid", "a boolean"), path.Member("valid"));
  r.Finite(object, path, "p_LI_m", &e.T_LI.p_m);
  r.Finite(object, path, "q_LI_wxyz", &e.T_LI.q_wxyz);
  RequireRotation(r, object, path, "q_LI_wxyz", e.T_LI.q_wxyz);
  r.Finite(object, path, "v_L_mps", &e.v_L_mps);
  r.Finite(object, path, "omega_I_radps", &e.omega_I_radps);
  e.initialized = e.valid;
  if (const auto initialized = r.Optional(object, "initialized")) {
    e.initialized = r.Bool(*initialized, path.Member("initialized"));
  }
  if (r.Optional(object, "bias_acc_mps2")) r.Finite(object, path, "bias_acc_mps2", &e.bias_acc_mps2);
  if (r.Optional(object, "bias_gyro_radps")) {
    r.Finite(object, path, "bias_gyro_radps", &e.bias_gyro_radps);
  }
  if (r.Optional(object, "position_covariance_m2")) {
    r.Finite(object, path, "position_covariance_m2", &e.position_covariance_m2.emplace());
  }
  if (const auto fused = r.Optional(object, "fused")) {
    const Path fused_path = path.Member("fused");
    if (fused->kind() != Value::Kind::kArray) r.Fail(fused_path, "an array of strings", *fused);
    std::vector<std::string>& names = e.fused.emplace();
    names.reserve(fused->size());
    for (std::size_t i = 0; i < fused->size(); ++i) {
      names.emplace_back(r.String((*fused)[i], fused_path.Element(i)));
    }
  }
  const bool has_p_ML = r.Optional(object, "p_ML_m").has_value();
  const bool has_q_ML = r.Optional(object, "q_ML_wxyz").has_value();
  if (has_p_ML != has_q_ML) {
    const char* missing = has_p_ML ? "q_ML_wxyz" : "p_ML_m";
    r.Fail(path.Member(missing),
           "present with its other half (T_ML is p_ML_m and q_ML_wxyz, both or neither)",
           *object.Find(has_p_ML ? "p_ML_m" : "q_ML_wxyz"));
  }
  if (has_p_ML) {
    api::Pose& T_ML = e.T_ML.emplace();
    r.Finite(object, path, "p_ML_m", &T_ML.p_m);
    r.Finite(object, path, "q_ML_wxyz", &T_ML.q_wxyz);
    RequireRotation(r, object, path, "q_ML_wxyz", T_ML.q_wxyz);
  }
  if (r.Optional(object, "T_ML_covariance")) {
    r.Finite(object, path, "T_ML_covariance", &e.T_ML_covariance.emplace());
  }
  return e;
}

void ReadEstimateArray(const Reader& r, const Value& array, const Path& path,
                       std::vector<api::Estimate>* out) {
  if (array.kind() != Value::Kind::kArray) {
    r.Fail(path, "an array of estimates (objects)", array);
  }
  for (std::size_t i = 0; i < array.size(); ++i) {
    out->push_back(ReadEstimate(r, array[i], path.Element(i)));
  }
}

// A pose object {"p_m": [3], "q_wxyz": [4]} at `path`.
api::Pose ReadPoseObject(const Reader& r, const Value& value, const Path& path) {
  const Value object = r.Object(value, path, "a pose {\"p_m\": [3], \"q_wxyz\": [4]}");
  api::Pose pose;
  r.Finite(object, path, "p_m", &pose.p_m);
  r.Finite(object, path, "q_wxyz", &pose.q_wxyz);
  RequireRotation(r, object, path, "q_wxyz", pose.q_wxyz);
  return pose;
}

std::string ConfigText(const Reader& r, const Value& root) {
  const Path path = kRoot.Member("config");
  const Value config = r.Object(r.Member(root, kRoot, "config", "an object"), path);
  return DumpJson(config.ToJson("config"));
}

// An index into an array of `count`, at `path`.
std::size_t Index(const Reader& r, const Value& value, const Path& path, std::size_t count,
                  std::string_view of) {
  const std::int64_t index = r.Int(value, path);
  if (index < 0 || static_cast<std::uint64_t>(index) >= count) {
    r.Fail(path,
           count == 0 ? fmt::format("an index into {} (which is empty)", of)
                      : fmt::format("an index into {} (0 to {})", of, count - 1),
           value);
  }
  return static_cast<std::size_t>(index);
}

}  // namespace

// ---------------------------------------------------------------------------------------
// tofu → client

json HelloMessage(std::string_view role, std::string_view name) {
  return {{"type", "hello"},
          {"protocol", "tofu"},
          {"version", api::kApiVersion},
          {"role", role},
          {"name", name},
          {"encodings", {"json", "msgpack"}}};
}

json SetupMessage(const api::EstimatorSetup& setup) {
  json sensors = json::array();
  for (const api::SensorInfo& s : setup.sensors) {
    json sensor = {{"name", s.name},
                   {"kind", api::SensorKindName(s.kind)},
                   {"T_Is", PoseJson(s.T_Is)},
                   {"covariance_stated", s.covariance_stated}};
    if (s.T_MS) sensor["T_MS"] = PoseJson(*s.T_MS);
    sensors.push_back(std::move(sensor));
  }
  json message = {{"type", "setup"},
          {"method", setup.method},
          {"imu", setup.imu},
          {"sensors", std::move(sensors)},
          {"gravity_mps2", setup.gravity_mps2},
          {"config", ParseObject(setup.config_json, "setup: config")},
          {"calibration_yaml", setup.calibration_yaml},
          {"estimation_yaml", setup.estimation_yaml}};
  if (setup.T_MI_launch) message["T_MI_launch"] = PoseJson(*setup.T_MI_launch);
  return message;
}

json SetupMessage(const api::ControllerSetup& setup) {
  return {{"type", "setup"},
          {"name", setup.name},
          {"rate_hz", setup.rate_hz},
          {"mass_kg", setup.mass_kg},
          {"inertia_B_kgm2", setup.inertia_B_kgm2},
          {"gravity_mps2", setup.gravity_mps2},
          {"arm_count", setup.arm_count},
          {"max_rotor_thrust_N", setup.max_rotor_thrust_N},
          {"config", ParseObject(setup.config_json, "setup: config")}};
}

json MeasurementMessage(std::int64_t seq, const api::EstimatorSetup& setup,
                        const api::Measurement& measurement) {
  return BuildJson([&](auto& w) { WriteMeasurement(w, seq, setup, measurement); });
}

void AppendMeasurementFrame(std::int64_t seq, const api::EstimatorSetup& setup,
                            const api::Measurement& measurement, Encoding encoding,
                            std::string* out) {
  AppendFramed(encoding, out, [&](auto& w) { WriteMeasurement(w, seq, setup, measurement); });
}

json ControlMessage(std::int64_t seq, const api::ControlState& state,
                    const api::ControlReference& reference) {
  return BuildJson([&](auto& w) { WriteControl(w, seq, state, reference); });
}

void AppendControlFrame(std::int64_t seq, const api::ControlState& state,
                        const api::ControlReference& reference, Encoding encoding,
                        std::string* out) {
  AppendFramed(encoding, out, [&](auto& w) { WriteControl(w, seq, state, reference); });
}

json FinishMessage() { return {{"type", "finish"}}; }

// ---- client → tofu, decoded by tofu ----

ClientHello DecodeClientHello(const Message& message) {
  const Reader r(message, "hello");
  const Path root;
  ClientHello hello;
  const Value version = r.Member(r.root(), root, "version", "an integer");
  const std::int64_t v = r.Int(version, root.Member("version"));
  if (v != api::kApiVersion) {
    r.FailText(root.Member("version"),
               fmt::format("the client speaks protocol version {}, this tofu speaks version {} "
                           "(docs/INTERFACE.md)",
                           v, api::kApiVersion));
  }
  hello.version = static_cast<int>(v);
  if (const auto encoding = r.Optional(r.root(), "encoding")) {
    const std::string_view name = r.String(*encoding, root.Member("encoding"));
    if (name == "json") {
      hello.encoding = Encoding::kJson;
    } else if (name == "msgpack") {
      hello.encoding = Encoding::kMsgpack;
    } else {
      r.Fail(root.Member("encoding"), "\"json\" or \"msgpack\"", *encoding);
    }
  }
  return hello;
}

void DecodeReady(const Message& message) { (void)Reader(message, "ready"); }

void DecodeEstimates(const Message& message, std::int64_t expected_seq,
                     std::vector<api::Estimate>* out) {
  const Reader r(message, "estimates", expected_seq);
  const Path path = kRoot.Member("estimates");
  ReadEstimateArray(r, r.Member(r.root(), kRoot, "estimates", "an array of estimates"), path,
                    out);
}

std::vector<api::Estimate> DecodeEstimates(const Message& message, std::int64_t expected_seq) {
  std::vector<api::Estimate> estimates;
  DecodeEstimates(message, expected_seq, &estimates);
  return estimates;
}

api::ControlCommand DecodeCommand(const Message& message, std::int64_t expected_seq,
                                  int arm_count) {
  const Reader r(message, "command", expected_seq);
  const Path root;
  const Value object = r.root();
  const bool wrench = object.Find("force_B_N") || object.Find("torque_B_Nm");
  const bool actuators = object.Find("tilt_rad") || object.Find("rotor_thrust_N");
  if (wrench == actuators) {
    r.FailText(root, wrench ? "holds both a wrench (force_B_N, torque_B_Nm) and actuator "
                              "commands (tilt_rad, rotor_thrust_N); expected one of them"
                            : "expected force_B_N and torque_B_Nm (a wrench) or tilt_rad and "
                              "rotor_thrust_N (actuator commands), got neither");
  }
  api::ControlCommand command;
  if (wrench) {
    command.kind = api::ControlCommand::Kind::kWrench;
    r.Finite(object, root, "force_B_N", &command.force_B_N);
    r.Finite(object, root, "torque_B_Nm", &command.torque_B_Nm);
    return command;
  }
  command.kind = api::ControlCommand::Kind::kActuators;
  const auto count = static_cast<std::size_t>(std::max(arm_count, 0));
  for (const auto& [key, values] : {std::pair{"tilt_rad", &command.tilt_rad},
                                    std::pair{"rotor_thrust_N", &command.rotor_thrust_N}}) {
    values->resize(count);
    r.NumbersAt(object, root, key, values->data(), count, true, " (one per arm)");
  }
  return command;
}

Finished DecodeFinished(const Message& message) {
  const Reader r(message, "finished");
  Finished finished;
  if (const auto estimates = r.Optional(r.root(), "estimates")) {
    ReadEstimateArray(r, *estimates, kRoot.Member("estimates"), &finished.estimates);
  }
  if (const auto report = r.Optional(r.root(), "report")) {
    const Path path = kRoot.Member("report");
    r.Object(*report, path, "an object (stored as client_report)");
    finished.report_json = DumpJson(report->ToJson("finished: report"));
  }
  return finished;
}

std::string DecodeErrorMessage(const Message& message) {
  const Value root = RootValue(message);
  const std::optional<Value> text = root.Find("message");
  if (!text) return "(an error message without \"message\")";
  if (text->kind() == Value::Kind::kString) return std::string(text->string());
  return text->Describe(200);
}

ClientHello DecodeClientHello(const json& message) {
  return DecodeClientHello(Message::FromJson(message));
}
std::vector<api::Estimate> DecodeEstimates(const json& message, std::int64_t expected_seq) {
  return DecodeEstimates(Message::FromJson(message), expected_seq);
}
api::ControlCommand DecodeCommand(const json& message, std::int64_t expected_seq,
                                  int arm_count) {
  return DecodeCommand(Message::FromJson(message), expected_seq, arm_count);
}
Finished DecodeFinished(const json& message) { return DecodeFinished(Message::FromJson(message)); }

// ---------------------------------------------------------------------------------------
// client → tofu, built by a C++ client

json ClientHelloMessage(Encoding encoding) {
  return {{"type", "hello"}, {"version", api::kApiVersion}, {"encoding", EncodingName(encoding)}};
}

json ReadyMessage() { return {{"type", "ready"}}; }

json EstimatesMessage(std::int64_t seq, const std::vector<api::Estimate>& estimates) {
  return BuildJson([&](auto& w) { WriteEstimates(w, seq, estimates.data(), estimates.size()); });
}

void AppendEstimatesFrame(std::int64_t seq, const api::Estimate* estimates, std::size_t count,
                          Encoding encoding, std::string* out) {
  AppendFramed(encoding, out, [&](auto& w) { WriteEstimates(w, seq, estimates, count); });
}

json CommandMessage(std::int64_t seq, const api::ControlCommand& command) {
  return BuildJson([&](auto& w) { WriteCommand(w, seq, command); });
}

void AppendCommandFrame(std::int64_t seq, const api::ControlCommand& command, Encoding encoding,
                        std::string* out) {
  AppendFramed(encoding, out, [&](auto& w) { WriteCommand(w, seq, command); });
}

json FinishedMessage(const std::vector<api::Estimate>& estimates, std::string_view report_json) {
  json message = {{"type", "finished"}};
  message["estimates"] = EstimatesMessage(0, estimates)["estimates"];
  message["report"] = ParseObject(report_json, "finished: report");
  return message;
}

json ErrorMessage(std::string_view text) { return {{"type", "error"}, {"message", text}}; }

// ---- tofu → client, decoded by a C++ client ----

TofuHello DecodeTofuHello(const Message& message) {
  const Reader r(message, "hello");
  const Path root;
  const Value object = r.root();
  const Value protocol = r.Member(object, root, "protocol", "\"tofu\"");
  if (protocol.kind() != Value::Kind::kString || protocol.string() != "tofu") {
    r.Fail(root.Member("protocol"), "\"tofu\"", protocol);
  }
  TofuHello hello;
  const std::int64_t version =
      r.Int(r.Member(object, root, "version", "an integer"), root.Member("version"));
  if (version < std::numeric_limits<int>::min() || version > std::numeric_limits<int>::max()) {
    r.Fail(root.Member("version"), "a protocol version", *object.Find("version"));
  }
  hello.version = static_cast<int>(version);
  hello.role = r.String(r.Member(object, root, "role", "a string"), root.Member("role"));
  hello.name = r.String(r.Member(object, root, "name", "a string"), root.Member("name"));
  if (const auto encodings = r.Optional(object, "encodings")) {
    const Path path = root.Member("encodings");
    if (encodings->kind() != Value::Kind::kArray) r.Fail(path, "an array of strings", *encodings);
    for (std::size_t i = 0; i < encodings->size(); ++i) {
      hello.encodings.emplace_back(r.String((*encodings)[i], path.Element(i)));
    }
  }
  return hello;
}

api::EstimatorSetup DecodeSetup(const Message& message) {
  const Reader r(message, "setup");
  const Path root;
  const Value object = r.root();
  api::EstimatorSetup setup;
  setup.method = r.String(r.Member(object, root, "method", "a string"), root.Member("method"));
  const Path sensors_path = root.Member("sensors");
  const Value sensors = r.Member(object, root, "sensors", "an array of sensors (objects)");
  if (sensors.kind() != Value::Kind::kArray) {
    r.Fail(sensors_path, "an array of sensors (objects)", sensors);
  }
  for (std::size_t i = 0; i < sensors.size(); ++i) {
    const Path path = sensors_path.Element(i);
    const Value sensor = r.Object(sensors[i], path, "an object (a sensor)");
    api::SensorInfo& info = setup.sensors.emplace_back();
    info.name = r.String(r.Member(sensor, path, "name", "a string"), path.Member("name"));
    const Value kind = r.Member(sensor, path, "kind", "\"imu\", \"pose\" or \"position\"");
    const std::string_view kind_name = r.String(kind, path.Member("kind"));
    // The wire names are the api's (api::SensorKindName), the ones SetupMessage writes.
    bool known_kind = false;
    for (const api::SensorKind k :
         {api::SensorKind::kImu, api::SensorKind::kPose, api::SensorKind::kPosition}) {
      if (kind_name != api::SensorKindName(k)) continue;
      info.kind = k;
      known_kind = true;
    }
    if (!known_kind) r.Fail(path.Member("kind"), "\"imu\", \"pose\" or \"position\"", kind);
    info.T_Is = ReadPoseObject(r, r.Member(sensor, path, "T_Is", "a pose"), path.Member("T_Is"));
    info.covariance_stated = r.Bool(r.Member(sensor, path, "covariance_stated", "a boolean"),
                                    path.Member("covariance_stated"));
    if (const auto T_MS = r.Optional(sensor, "T_MS")) {
      info.T_MS = ReadPoseObject(r, *T_MS, path.Member("T_MS"));
    }
  }
  setup.imu = Index(r, r.Member(object, root, "imu", "an index into sensors"), root.Member("imu"),
                    setup.sensors.size(), "sensors");
  setup.gravity_mps2 =
      r.Finite(r.Member(object, root, "gravity_mps2", kFiniteNumber), root.Member("gravity_mps2"));
  setup.config_json = ConfigText(r, object);
  setup.calibration_yaml = r.String(r.Member(object, root, "calibration_yaml", "a string"),
                                    root.Member("calibration_yaml"));
  setup.estimation_yaml = r.String(r.Member(object, root, "estimation_yaml", "a string"),
                                   root.Member("estimation_yaml"));
  if (const auto T_MI_launch = r.Optional(object, "T_MI_launch")) {
    setup.T_MI_launch = ReadPoseObject(r, *T_MI_launch, root.Member("T_MI_launch"));
  }
  return setup;
}

api::ControllerSetup DecodeControllerSetup(const Message& message) {
  const Reader r(message, "setup");
  const Path root;
  const Value object = r.root();
  api::ControllerSetup setup;
  setup.name = r.String(r.Member(object, root, "name", "a string"), root.Member("name"));
  const auto finite = [&](std::string_view key) {
    return r.Finite(r.Member(object, root, key, kFiniteNumber), root.Member(key));
  };
  setup.rate_hz = finite("rate_hz");
  setup.mass_kg = finite("mass_kg");
  r.Finite(object, root, "inertia_B_kgm2", &setup.inertia_B_kgm2);
  setup.gravity_mps2 = finite("gravity_mps2");
  const Value arms = r.Member(object, root, "arm_count", "a positive integer");
  const std::int64_t arm_count = r.Int(arms, root.Member("arm_count"));
  if (arm_count < 1 || arm_count > 1000) r.Fail(root.Member("arm_count"), "a positive integer", arms);
  setup.arm_count = static_cast<int>(arm_count);
  setup.max_rotor_thrust_N = finite("max_rotor_thrust_N");
  setup.config_json = ConfigText(r, object);
  return setup;
}

api::Measurement DecodeMeasurement(const Message& message, const api::EstimatorSetup& setup,
                                   std::int64_t* seq) {
  const Reader r(message, "measurement");
  const Path root;
  const Value object = r.root();
  const std::int64_t seq_value =
      r.Int(r.Member(object, root, "seq", "an integer"), root.Member("seq"));
  if (seq != nullptr) *seq = seq_value;
  api::Measurement m;
  m.t_ns = r.Int(r.Member(object, root, "t_ns", "an integer"), root.Member("t_ns"));
  m.arrival_ns = r.Int(r.Member(object, root, "arrival_ns", "an integer"), root.Member("arrival_ns"));
  m.sensor = Index(r, r.Member(object, root, "sensor_index", "an index into the setup's sensors"),
                   root.Member("sensor_index"), setup.sensors.size(), "the setup's sensors");
  const api::SensorInfo& sensor = setup.sensors[m.sensor];
  const Value name = r.Member(object, root, "sensor", "a string");
  if (r.String(name, root.Member("sensor")) != sensor.name) {
    r.Fail(root.Member("sensor"),
           fmt::format("\"{}\" (the name of sensor_index {})", sensor.name, m.sensor), name);
  }
  m.kind = sensor.kind;
  const Value kind = r.Member(object, root, "kind", "a string");
  if (r.String(kind, root.Member("kind")) != api::SensorKindName(sensor.kind)) {
    r.Fail(root.Member("kind"),
           fmt::format("\"{}\" (the kind of sensor \"{}\")", api::SensorKindName(sensor.kind),
                       sensor.name),
           kind);
  }
  switch (m.kind) {
    case api::SensorKind::kImu:
      r.Nanable(object, root, "acc_I_mps2", &m.imu.acc_I_mps2);
      r.Nanable(object, root, "gyro_I_radps", &m.imu.gyro_I_radps);
      break;
    case api::SensorKind::kPose: {
      r.Nanable(object, root, "p_Ss_m", &m.pose.T_Ss.p_m);
      r.Nanable(object, root, "q_Ss_wxyz", &m.pose.T_Ss.q_wxyz);
      r.Nanable(object, root, "covariance", &m.pose.covariance);
      if (const auto twist = r.Optional(object, "twist")) {
        const Path path = root.Member("twist");
        r.Object(*twist, path, "an object (v_s_mps, omega_s_radps, covariance)");
        m.pose.has_twist = true;
        r.Nanable(*twist, path, "v_s_mps", &m.pose.v_s_mps);
        r.Nanable(*twist, path, "omega_s_radps", &m.pose.omega_s_radps);
        r.Nanable(*twist, path, "covariance", &m.pose.twist_covariance);
      }
      break;
    }
    case api::SensorKind::kPosition:
      r.Nanable(object, root, "p_Ss_m", &m.position.p_Ss_m);
      r.Nanable(object, root, "covariance_m2", &m.position.covariance_m2);
      break;
  }
  return m;
}

ControlRequest DecodeControl(const Message& message) {
  const Reader r(message, "control");
  const Path root;
  const Value object = r.root();
  ControlRequest request;
  request.seq = r.Int(r.Member(object, root, "seq", "an integer"), root.Member("seq"));
  request.state.t_ns = r.Int(r.Member(object, root, "t_ns", "an integer"), root.Member("t_ns"));
  const Path state_path = root.Member("state");
  const Value state = r.Object(r.Member(object, root, "state", "an object"), state_path);
  r.Nanable(state, state_path, "p_WB_m", &request.state.T_WB.p_m);
  r.Nanable(state, state_path, "q_WB_wxyz", &request.state.T_WB.q_wxyz);
  r.Nanable(state, state_path, "v_W_mps", &request.state.v_W_mps);
  r.Nanable(state, state_path, "omega_B_radps", &request.state.omega_B_radps);
  request.state.from_estimate =
      r.Bool(r.Member(state, state_path, "from_estimate", "a boolean"),
             state_path.Member("from_estimate"));
  const Path ref_path = root.Member("reference");
  const Value ref = r.Object(r.Member(object, root, "reference", "an object"), ref_path);
  r.Nanable(ref, ref_path, "p_WB_m", &request.reference.T_WB.p_m);
  r.Nanable(ref, ref_path, "q_WB_wxyz", &request.reference.T_WB.q_wxyz);
  r.Nanable(ref, ref_path, "v_W_mps", &request.reference.v_W_mps);
  r.Nanable(ref, ref_path, "a_W_mps2", &request.reference.a_W_mps2);
  r.Nanable(ref, ref_path, "omega_B_radps", &request.reference.omega_B_radps);
  r.Nanable(ref, ref_path, "alpha_B_radps2", &request.reference.alpha_B_radps2);
  return request;
}

void DecodeFinish(const Message& message) { (void)Reader(message, "finish"); }

}  // namespace tofu::interface
