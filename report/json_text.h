#pragma once
// A small streaming writer of JSON objects for the MCAP exporter: a 120 s run is ~10^5
// messages, and building each as an nlohmann::json tree costs more than the whole export
// may (docs/BENCHMARKS.md). Numbers are written with the shortest text that reads back
// to the same double; a non-finite number is null (JSON has no NaN). Keys and strings
// are escaped per RFC 8259.

#include <array>
#include <cstdint>
#include <string>
#include <string_view>
#include <vector>

#include <Eigen/Core>
#include <Eigen/Geometry>

#include "core/time.h"

namespace tofu::report {

class JsonText {
 public:
  JsonText() { text_.reserve(512); }
  /// '{' (after a separator when inside an array) / '}'.
  void Begin();
  void End();
  /// '[' / ']' (after a separator when inside an array).
  void BeginArray();
  void EndArray();
  /// "key": (the next value follows).
  void Key(std::string_view key);

  void Number(std::string_view key, double value);
  void Int(std::string_view key, std::int64_t value);
  void Bool(std::string_view key, bool value);
  void String(std::string_view key, std::string_view value);
  void Strings(std::string_view key, const std::vector<std::string>& values);
  void Numbers(std::string_view key, const std::vector<double>& values);
  /// A value that is already JSON text.
  void Raw(std::string_view key, std::string_view json);
  /// {"sec": t / 1e9, "nsec": t % 1e9} (Foxglove's time; t < 0 clamps to 0).
  void Time(std::string_view key, core::Time t_ns);
  /// {"x", "y", "z"}.
  void Vector(std::string_view key, const Eigen::Vector3d& v);
  /// {"x", "y", "z", "w"} (Foxglove's order).
  void Quaternion(std::string_view key, const Eigen::Quaterniond& q);
  /// {"position": Vector, "orientation": Quaternion}.
  void Pose(std::string_view key, const Eigen::Vector3d& p, const Eigen::Quaterniond& q);
  /// {"r", "g", "b", "a"}.
  void Color(std::string_view key, const std::array<float, 4>& rgba);

  const std::string& str() const { return text_; }

 private:
  void Separator();
  void AppendString(std::string_view s);
  void AppendNumber(double value);
  std::string text_;
  // Per open container: whether a first member has been written (for the commas).
  std::vector<bool> has_member_;
};

}  // namespace tofu::report
