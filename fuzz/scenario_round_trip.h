#pragma once
// The round-trip property of scenario.h ("the scenario as YAML with every default filled
// in; loading it back yields an equal scenario"), as fuzz_scenario and
// tests/fuzz_regression_test.cc check it: the resolved YAML of a scenario loads back and
// resolves to the same text up to floating-point noise in numbers (relative 1e-12, or
// 1e-9 absolute near zero: attitudes pass through quaternions, as in the project's own
// ScenarioResolvedYaml tests, which compare attitudes to a tolerance). Attitudes are a
// fixed point since finding 5 was fixed (docs/FUZZING.md); the tolerance stays because
// other derived numbers (degrees from radians at 12 significant digits) are not proven
// to be.

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <string>
#include <string_view>
#include <vector>

namespace tofu::fuzz {

/// YAML text split at whitespace and flow punctuation.
inline std::vector<std::string_view> Tokens(std::string_view text) {
  std::vector<std::string_view> tokens;
  size_t start = std::string_view::npos;
  for (size_t i = 0; i <= text.size(); ++i) {
    const bool separator = i == text.size() || text[i] == ' ' || text[i] == '\n' ||
                           text[i] == ',' || text[i] == '[' || text[i] == ']' ||
                           text[i] == '{' || text[i] == '}';
    if (separator) {
      if (start != std::string_view::npos) tokens.push_back(text.substr(start, i - start));
      start = std::string_view::npos;
    } else if (start == std::string_view::npos) {
      start = i;
    }
  }
  return tokens;
}

/// The token as a finite number, or NaN.
inline double NumberToken(std::string_view token) {
  const std::string s(token);
  char* end = nullptr;
  const double value = std::strtod(s.c_str(), &end);
  if (s.empty() || end != s.c_str() + s.size() || !std::isfinite(value)) return std::nan("");
  return value;
}

/// Empty if `a` and `b` are the same text up to number noise, else the first difference.
inline std::string RoundTripDifference(std::string_view a, std::string_view b) {
  const std::vector<std::string_view> ta = Tokens(a);
  const std::vector<std::string_view> tb = Tokens(b);
  for (size_t i = 0; i < std::min(ta.size(), tb.size()); ++i) {
    if (ta[i] == tb[i]) continue;
    const double x = NumberToken(ta[i]);
    const double y = NumberToken(tb[i]);
    const double tolerance = std::max(1e-9, 1e-12 * std::max(std::abs(x), std::abs(y)));
    if (std::isfinite(x) && std::isfinite(y) && std::abs(x - y) <= tolerance) continue;
    return "token " + std::to_string(i) + ": '" + std::string(ta[i]) + "' became '" +
           std::string(tb[i]) + "'";
  }
  if (ta.size() != tb.size()) {
    return "the texts have " + std::to_string(ta.size()) + " and " + std::to_string(tb.size()) +
           " tokens";
  }
  return "";
}

}  // namespace tofu::fuzz
