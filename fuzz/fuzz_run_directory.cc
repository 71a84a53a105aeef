// libFuzzer target: the run-directory reader, replay::ReadRecordedLog on layout (a)
// (recorded_log.h): the input is sensors/fuzz.csv of a run directory whose other files
// (an IMU stream, calibration.yaml with the stream's mount and noise, groundtruth.csv) are
// valid; its header decides the stream's kind (IMU, pose, position).
#include "fuzz/fuzz_support.h"
#include "fuzz/recorded_log_layouts.h"
#include "replay/recorded_log.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  static const std::filesystem::path dir = [] {
    const std::filesystem::path d = tofu::fuzz::ScratchDir::Path() / "run";
    tofu::fuzz::WriteRunDirectory(d);
    return d;
  }();
  tofu::fuzz::WriteFile(dir / "sensors" / "fuzz.csv", tofu::fuzz::InputText(data, size));
  tofu::fuzz::ParsesOrInputError([&] { (void)tofu::replay::ReadRecordedLog(dir); });
  return 0;
}
