// The scenario example in README.md is a valid scenario: documentation cannot drift
// from the format.

#include <fstream>
#include <sstream>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "harness/scenario.h"

namespace tofu::harness {
namespace {

// The ```yaml blocks of README.md, in order.
std::vector<std::string> ReadmeYamlBlocks() {
  std::ifstream in(std::string(TOFU_SOURCE_DIR) + "/README.md");
  std::stringstream text;
  text << in.rdbuf();
  const std::string readme = text.str();
  const std::string open = "```yaml\n";
  std::vector<std::string> blocks;
  for (size_t begin = readme.find(open); begin != std::string::npos;
       begin = readme.find(open, begin + 1)) {
    const size_t end = readme.find("```", begin + open.size());
    blocks.push_back(readme.substr(begin + open.size(), end - begin - open.size()));
  }
  return blocks;
}

// "Test your own estimator or controller": the clients' fragment is valid with the
// paper's sensors and a controller client beside the estimator.
TEST(Readme, ClientExampleIsValid) {
  const std::vector<std::string> blocks = ReadmeYamlBlocks();
  ASSERT_FALSE(blocks.empty());
  const std::string yaml = R"(name: readme_clients
world: indoor_arena
duration_s: 10
trajectory:
  start: {position_m: [0, 0, 1.5]}
  segments:
    - hover: {duration_s: 1}
sensors:
  imu: {}
  vio: {}
  leica: {type: total_station}
)" + blocks[0];
  // The fragment names python_pd as the controller; give it one as the README's section does.
  std::string with_controller = yaml;
  with_controller.replace(with_controller.find("external:\n"), 10,
                          "external:\n  python_pd: {command: [/usr/bin/python3, pd.py]}\n");
  Scenario scenario;
  ASSERT_NO_THROW(scenario = ParseScenario(with_controller, "README.md")) << with_controller;
  ASSERT_EQ(scenario.clients.size(), 2u);
  ASSERT_TRUE(scenario.control.has_value());
  EXPECT_EQ(scenario.control->controller, "external:python_pd");
  EXPECT_EQ(scenario.estimation->methods[1], "external:python_ekf");
}

// "tofu compare": a scenario's own minimal effects, parsed (the names are checked against
// compare's metric table by the campaign layer, compare_test).
TEST(Readme, CompareExampleIsValid) {
  const std::vector<std::string> blocks = ReadmeYamlBlocks();
  ASSERT_GT(blocks.size(), 1u);
  const std::string yaml = R"(name: readme_compare
world: indoor_arena
duration_s: 10
trajectory:
  start: {position_m: [0, 0, 1.5]}
  segments:
    - hover: {duration_s: 1}
)" + blocks[1];
  Scenario scenario;
  ASSERT_NO_THROW(scenario = ParseScenario(yaml, "README.md")) << yaml;
  EXPECT_EQ(scenario.compare_minimal_effects.at("methods.<method>.ate_m"), 0.10);
  EXPECT_EQ(scenario.compare_minimal_effects.at("methods.consensus.max_detection_delay_s"), 0.5);
}

TEST(Readme, ScenarioExampleIsValid) {
  const std::vector<std::string> blocks = ReadmeYamlBlocks();
  ASSERT_FALSE(blocks.empty()) << "README.md has no ```yaml block";
  const std::string& yaml = blocks[2];
  Scenario scenario;
  ASSERT_NO_THROW(scenario = ParseScenario(yaml, "README.md")) << yaml;
  EXPECT_EQ(scenario.name, "approach_wall");
  EXPECT_EQ(scenario.trajectory.segments.size(), 6u);
  EXPECT_EQ(scenario.expect.size(), 3u);
}

// The sensors-and-faults example is a fragment: valid once put into a scenario.
TEST(Readme, SensorExampleIsValid) {
  const std::vector<std::string> blocks = ReadmeYamlBlocks();
  ASSERT_GE(blocks.size(), 3u);
  const std::string yaml = R"(name: readme_sensors
world: bridge
duration_s: 60
trajectory:
  start: {position_m: [-9, 0, 3]}
  segments:
    - hover: {duration_s: 1}
)" + blocks[3];
  Scenario scenario;
  ASSERT_NO_THROW(scenario = ParseScenario(yaml, "README.md")) << yaml;
  EXPECT_EQ(scenario.sensors.size(), 5u);
  EXPECT_EQ(scenario.faults.size(), 4u);
}

// The estimation example is a fragment too: valid with the paper scenario's sensors.
TEST(Readme, EstimationExampleIsValid) {
  const std::vector<std::string> blocks = ReadmeYamlBlocks();
  ASSERT_GE(blocks.size(), 4u);
  const std::string yaml = R"(name: readme_estimation
world: indoor_arena
duration_s: 60
trajectory:
  start: {position_m: [0, 0, 1.5]}
  segments:
    - hover: {duration_s: 1}
sensors:
  imu: {}
  vio: {}
  lio: {type: lidar_odometry}
  leica: {type: total_station}
)" + blocks[4];
  Scenario scenario;
  ASSERT_NO_THROW(scenario = ParseScenario(yaml, "README.md")) << yaml;
  ASSERT_TRUE(scenario.estimation.has_value());
  EXPECT_EQ(scenario.estimation->methods.size(), 4u);
  // The example names no profile: it flies the default, whose threshold is the 0.3 the
  // shipped scenarios use.
  EXPECT_EQ(scenario.estimation->profile, replay::EstimationConfig::kDefaultProfile);
  EXPECT_EQ(scenario.estimation->consensus.threshold, 0.3);
  EXPECT_EQ(scenario.expect.size(), 3u);
}

// The closed-loop example: valid with an estimation block that has its methods.
TEST(Readme, ControlExampleIsValid) {
  const std::vector<std::string> blocks = ReadmeYamlBlocks();
  ASSERT_GE(blocks.size(), 5u);
  const std::string yaml = R"(name: readme_control
world: indoor_arena
duration_s: 20
trajectory:
  start: {position_m: [0, 0, 1.5]}
  segments:
    - hover: {duration_s: 1}
sensors:
  imu: {}
  vio: {}
  leica: {type: total_station}
estimation:
  methods: [consensus, naive]
)" + blocks[5];
  Scenario scenario;
  ASSERT_NO_THROW(scenario = ParseScenario(yaml, "README.md")) << yaml;
  ASSERT_TRUE(scenario.control.has_value());
  EXPECT_EQ(scenario.control->state_source, ControlConfig::StateSource::kEstimate);
  EXPECT_EQ(scenario.control->methods, (std::vector<std::string>{"consensus", "naive"}));
  EXPECT_FALSE(scenario.control->failsafe.max_position_std_m.has_value());
  EXPECT_EQ(scenario.expect.size(), 3u);
}

// The render example, likewise.
TEST(Readme, RenderExampleIsValid) {
  const std::vector<std::string> blocks = ReadmeYamlBlocks();
  ASSERT_GE(blocks.size(), 6u);
  const std::string yaml = R"(name: readme_render
world: indoor_arena
duration_s: 5
trajectory:
  start: {position_m: [0, 0, 1.5]}
  segments:
    - hover: {duration_s: 1}
)" + blocks[6];
  Scenario scenario;
  ASSERT_NO_THROW(scenario = ParseScenario(yaml, "README.md")) << yaml;
  ASSERT_TRUE(scenario.render.has_value());
  EXPECT_FALSE(scenario.render->always);
  EXPECT_EQ(scenario.render->width_px, 640);
}

}  // namespace
}  // namespace tofu::harness
