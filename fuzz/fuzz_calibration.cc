// libFuzzer target: the calibration reader (calibration.yaml of run directories and real
// logs), through its string-level entry point replay::DescribeRunStreams, which parses
// the text with the very parser ReadRecordedLog uses and applies it to four streams
// (an IMU, two pose streams, a position stream: the names tofu's runs use); then the
// same text through replay::ParseRunCalibration, asking every sensor for what the
// renderer reads (LiDAR beams, sky directions, the GNSS sky's ray length).
#include <string>
#include <utility>
#include <vector>

#include "fuzz/fuzz_support.h"
#include "replay/recorded_log.h"
#include "replay/run_calibration.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  using tofu::core::MeasurementKind;
  const std::string text = tofu::fuzz::InputText(data, size);
  std::vector<std::pair<std::string, MeasurementKind>> streams = {{"imu", MeasurementKind::kImu},
                                                                  {"vio", MeasurementKind::kPose},
                                                                  {"lio", MeasurementKind::kPose},
                                                                  {"leica", MeasurementKind::kPosition}};
  tofu::fuzz::ParsesOrInputError(
      [&] { (void)tofu::replay::DescribeRunStreams(streams, text, "fuzz_run"); });
  tofu::fuzz::ParsesOrInputError([&] {
    const tofu::replay::RunCalibration calibration =
        tofu::replay::ParseRunCalibration(text, "fuzz_run/calibration.yaml");
    for (const auto& [name, sensor] : calibration.sensors) {
      (void)calibration.LidarBeams(name);
      (void)calibration.OptionNumber(name, "sky_ray_length_m");
    }
  });
  return 0;
}
