// libFuzzer target: the EuRoC ground-truth reader, replay::ReadRecordedLog on layout (b)
// (recorded_log.h): the input is mav0/state_groundtruth_estimate0/data.csv of a log whose
// other files (the IMU stream, a .tum pose stream, calibration.yaml) are valid.
#include "fuzz/fuzz_support.h"
#include "fuzz/recorded_log_layouts.h"
#include "replay/recorded_log.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  static const std::filesystem::path dir = [] {
    const std::filesystem::path d = tofu::fuzz::ScratchDir::Path() / "euroc";
    tofu::fuzz::WriteEurocDirectory(d, tofu::fuzz::kEurocGroundTruth);
    return d;
  }();
  tofu::fuzz::WriteFile(dir / tofu::fuzz::kEurocGroundTruth, tofu::fuzz::InputText(data, size));
  tofu::fuzz::ParsesOrInputError([&] { (void)tofu::replay::ReadRecordedLog(dir); });
  return 0;
}
