#include "report/json_text.h"

#include <charconv>
#include <cmath>

#include <fmt/format.h>

namespace tofu::report {

void JsonText::Separator() {
  if (has_member_.empty()) return;
  if (has_member_.back()) text_ += ',';
  has_member_.back() = true;
}

void JsonText::Begin() {
  // Inside an array a value needs its separator; after Key() it has one already.
  if (!text_.empty() && text_.back() != ':') Separator();
  text_ += '{';
  has_member_.push_back(false);
}

void JsonText::End() {
  text_ += '}';
  has_member_.pop_back();
}

void JsonText::BeginArray() {
  if (!text_.empty() && text_.back() != ':') Separator();
  text_ += '[';
  has_member_.push_back(false);
}

void JsonText::EndArray() {
  text_ += ']';
  has_member_.pop_back();
}

void JsonText::Key(std::string_view key) {
  Separator();
  AppendString(key);
  text_ += ':';
}

void JsonText::AppendString(std::string_view s) {
  text_ += '"';
  for (const char c : s) {
    switch (c) {
      case '"': text_ += "\\\""; break;
      case '\\': text_ += "\\\\"; break;
      case '\n': text_ += "\\n"; break;
      case '\r': text_ += "\\r"; break;
      case '\t': text_ += "\\t"; break;
      default:
        if (static_cast<unsigned char>(c) < 0x20) {
          text_ += fmt::format("\\u{:04x}", static_cast<unsigned>(c));
        } else {
          text_ += c;
        }
    }
  }
  text_ += '"';
}

void JsonText::AppendNumber(double value) {
  if (!std::isfinite(value)) {
    text_ += "null";
    return;
  }
  char buffer[32];
  const auto [end, ec] = std::to_chars(buffer, buffer + sizeof(buffer), value);
  text_.append(buffer, ec == std::errc() ? end : buffer);
}

void JsonText::Number(std::string_view key, double value) {
  Key(key);
  AppendNumber(value);
}

void JsonText::Int(std::string_view key, std::int64_t value) {
  Key(key);
  char buffer[24];
  const auto [end, ec] = std::to_chars(buffer, buffer + sizeof(buffer), value);
  text_.append(buffer, ec == std::errc() ? end : buffer);
}

void JsonText::Bool(std::string_view key, bool value) {
  Key(key);
  text_ += value ? "true" : "false";
}

void JsonText::String(std::string_view key, std::string_view value) {
  Key(key);
  AppendString(value);
}

void JsonText::Strings(std::string_view key, const std::vector<std::string>& values) {
  Key(key);
  text_ += '[';
  for (std::size_t i = 0; i < values.size(); ++i) {
    if (i > 0) text_ += ',';
    AppendString(values[i]);
  }
  text_ += ']';
}

void JsonText::Numbers(std::string_view key, const std::vector<double>& values) {
  Key(key);
  text_ += '[';
  for (std::size_t i = 0; i < values.size(); ++i) {
    if (i > 0) text_ += ',';
    AppendNumber(values[i]);
  }
  text_ += ']';
}

void JsonText::Raw(std::string_view key, std::string_view json) {
  Key(key);
  text_ += json;
}

void JsonText::Time(std::string_view key, core::Time t_ns) {
  const core::Time t = t_ns < 0 ? 0 : t_ns;
  Key(key);
  text_ += fmt::format("{{\"sec\":{},\"nsec\":{}}}", t / 1'000'000'000, t % 1'000'000'000);
}

void JsonText::Vector(std::string_view key, const Eigen::Vector3d& v) {
  Key(key);
  text_ += "{\"x\":";
  AppendNumber(v.x());
  text_ += ",\"y\":";
  AppendNumber(v.y());
  text_ += ",\"z\":";
  AppendNumber(v.z());
  text_ += '}';
}

void JsonText::Quaternion(std::string_view key, const Eigen::Quaterniond& q) {
  Key(key);
  text_ += "{\"x\":";
  AppendNumber(q.x());
  text_ += ",\"y\":";
  AppendNumber(q.y());
  text_ += ",\"z\":";
  AppendNumber(q.z());
  text_ += ",\"w\":";
  AppendNumber(q.w());
  text_ += '}';
}

void JsonText::Pose(std::string_view key, const Eigen::Vector3d& p, const Eigen::Quaterniond& q) {
  Key(key);
  text_ += '{';
  has_member_.push_back(false);
  Vector("position", p);
  Quaternion("orientation", q);
  has_member_.pop_back();
  text_ += '}';
}

void JsonText::Color(std::string_view key, const std::array<float, 4>& rgba) {
  Key(key);
  text_ += "{\"r\":";
  AppendNumber(rgba[0]);
  text_ += ",\"g\":";
  AppendNumber(rgba[1]);
  text_ += ",\"b\":";
  AppendNumber(rgba[2]);
  text_ += ",\"a\":";
  AppendNumber(rgba[3]);
  text_ += '}';
}

}  // namespace tofu::report
