// libFuzzer target: the velocity CSV reader of `tofu consistency`,
// replay::ParseVelocityCsv. A series it returns is never empty and strictly increasing
// in time with finite velocities (velocity_csv.h): checked too.
#include <cmath>
#include <string>

#include "fuzz/fuzz_support.h"
#include "replay/velocity_csv.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const std::string text = tofu::fuzz::InputText(data, size);
  tofu::estimator::VelocitySeries series;
  if (!tofu::fuzz::ParsesOrInputError(
          [&] { series = tofu::replay::ParseVelocityCsv(text, "fuzz_velocity.csv"); })) {
    return 0;
  }
  if (series.t_ns.empty() || series.t_ns.size() != series.v_mps.size()) {
    tofu::fuzz::Finding("a velocity series that is empty or has unequal columns");
  }
  for (size_t i = 0; i < series.t_ns.size(); ++i) {
    if (i > 0 && series.t_ns[i] <= series.t_ns[i - 1]) {
      tofu::fuzz::Finding("velocity timestamps that do not increase strictly");
    }
    if (!series.v_mps[i].allFinite()) tofu::fuzz::Finding("a velocity that is not finite");
  }
  return 0;
}
