// libFuzzer target: the TUM trajectory reader, replay::ReadTumTrajectory (the *.tum pose
// streams of real logs, tofu's own groundtruth.tum and estimate_*.tum).
#include <string>

#include "fuzz/fuzz_support.h"
#include "replay/trajectory_metrics.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  static const std::filesystem::path file = tofu::fuzz::ScratchDir::Path() / "stream.tum";
  tofu::fuzz::WriteFile(file, tofu::fuzz::InputText(data, size));
  tofu::fuzz::ParsesOrInputError([&] { (void)tofu::replay::ReadTumTrajectory(file); });
  return 0;
}
