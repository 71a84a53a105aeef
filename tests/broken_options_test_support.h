#pragma once
// Test support for options that validate themselves (IsValid, Ceres style): a list of
// ways to break an options struct, each with the field its message must name, and the
// check over the list. Shared by the estimator's options tests.

#include <gtest/gtest.h>

#include <functional>
#include <limits>
#include <string>
#include <utility>
#include <vector>

namespace tofu::test {

template <typename Options>
class BrokenOptions {
 public:
  using Break = std::function<void(Options&)>;

  static constexpr double kNan = std::numeric_limits<double>::quiet_NaN();
  static constexpr double kInf = std::numeric_limits<double>::infinity();

  /// One way to break the defaults; IsValid's message must contain `field`.
  void Add(std::string field, Break set) { cases_.emplace_back(std::move(field), std::move(set)); }

  /// 0, -1, NaN and inf in a member that must be positive and finite.
  void AddNotPositiveFinite(const std::string& field, double Options::*member) {
    for (const double bad : {0.0, -1.0, kNan, kInf}) {
      Add(field, [member, bad](Options& o) { o.*member = bad; });
    }
  }

  /// Each case breaks IsValid with a message naming its field; `also(field, options, why)`
  /// checks more of it (that a constructor throws, say).
  void ExpectEachRejected(
      const std::function<void(const std::string&, const Options&, const std::string&)>& also =
          {}) const {
    for (const auto& [field, set] : cases_) {
      Options options;
      set(options);
      std::string why;
      EXPECT_FALSE(options.IsValid(&why)) << field;
      EXPECT_NE(why.find(field), std::string::npos) << field << ": " << why;
      if (also) also(field, options, why);
    }
  }

 private:
  std::vector<std::pair<std::string, Break>> cases_;
};

}  // namespace tofu::test
