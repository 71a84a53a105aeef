// The scenario example in README.md is a valid scenario: documentation cannot drift
// from the format.

#include <fstream>
#include <sstream>
#include <string>

#include <gtest/gtest.h>

#include "harness/scenario.h"

namespace tofu::harness {
namespace {

std::string ReadmeYamlExample() {
  std::ifstream in(std::string(TOFU_SOURCE_DIR) + "/README.md");
  std::stringstream text;
  text << in.rdbuf();
  const std::string readme = text.str();
  const std::string open = "```yaml\n";
  const size_t begin = readme.find(open);
  if (begin == std::string::npos) return {};
  const size_t end = readme.find("```", begin + open.size());
  return readme.substr(begin + open.size(), end - begin - open.size());
}

TEST(Readme, ScenarioExampleIsValid) {
  const std::string yaml = ReadmeYamlExample();
  ASSERT_FALSE(yaml.empty()) << "README.md has no ```yaml block";
  Scenario scenario;
  ASSERT_NO_THROW(scenario = ParseScenario(yaml, "README.md")) << yaml;
  EXPECT_EQ(scenario.name, "approach_wall");
  EXPECT_EQ(scenario.trajectory.segments.size(), 6u);
  EXPECT_EQ(scenario.expect.size(), 3u);
}

}  // namespace
}  // namespace tofu::harness
