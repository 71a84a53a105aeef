// libFuzzer target: the scenario reader, harness::ParseScenario (strict YAML).
// Oracle (fuzz_support.h): parses or throws core::InputError naming the file. A scenario
// that parses must also round-trip as scenario.h documents: its resolved YAML loads back
// (no exception at all) and resolves to the same text up to floating-point noise in
// numbers (scenario_round_trip.h).
#include <string>

#include "fuzz/fuzz_support.h"
#include "fuzz/scenario_round_trip.h"
#include "harness/scenario.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const std::string text = tofu::fuzz::InputText(data, size);
  tofu::harness::Scenario scenario;
  if (!tofu::fuzz::ParsesOrInputError(
          [&] { scenario = tofu::harness::ParseScenario(text, "fuzz_scenario.yaml"); })) {
    return 0;
  }
  const std::string resolved = tofu::harness::ResolvedScenarioYaml(scenario);
  std::string again;
  try {
    again = tofu::harness::ResolvedScenarioYaml(
        tofu::harness::ParseScenario(resolved, "resolved_scenario.yaml"));
  } catch (const std::exception& e) {
    tofu::fuzz::Finding(std::string("the resolved scenario does not load back: ") + e.what() +
                        "\n--- resolved ---\n" + resolved);
  }
  const std::string difference = tofu::fuzz::RoundTripDifference(resolved, again);
  if (!difference.empty()) {
    tofu::fuzz::Finding("the resolved scenario resolves to other text (" + difference +
                        ")\n--- first ---\n" + resolved + "\n--- second ---\n" + again);
  }
  return 0;
}
