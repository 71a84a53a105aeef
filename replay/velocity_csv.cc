#include "replay/velocity_csv.h"

#include <cmath>
#include <string>

#include <fmt/format.h>

#include "core/error.h"
#include "core/file_io.h"
#include "replay/csv_reader.h"

namespace tofu::replay {

estimator::VelocitySeries ParseVelocityCsv(std::string_view text, const std::string& path) {
  CsvReader reader(CsvText{text, path}, std::string(kVelocityCsvHeader),
                   CsvOptions{.header_must_match = true, .blank_lines_only_at_end = true});
  estimator::VelocitySeries series;
  const size_t expected_rows = reader.RowsUpperBound();
  series.t_ns.reserve(expected_rows);
  series.v_mps.reserve(expected_rows);
  int previous_line = 0;
  while (reader.Next()) {
    // Timestamp: an integer number of nanoseconds, strictly after the previous sample's.
    const core::Time t = reader.Integer(0);
    if (!series.t_ns.empty() && t <= series.t_ns.back()) {
      throw reader.Error(0, fmt::format("timestamp {} ns is not after the previous sample's {} "
                                        "ns (line {}): timestamps must increase strictly",
                                        t, series.t_ns.back(), previous_line));
    }
    // Velocities: finite numbers in m/s (a NaN would poison every window it falls in).
    Eigen::Vector3d v;
    for (int axis = 0; axis < 3; ++axis) {
      v[axis] = reader.Number(axis + 1);
      if (!std::isfinite(v[axis])) {
        throw reader.Error(axis + 1, fmt::format("{} is not a finite number; NaN and Inf are "
                                                 "not accepted in a velocity CSV",
                                                 CsvQuoted(reader.Text(axis + 1))));
      }
    }
    series.t_ns.push_back(t);
    series.v_mps.push_back(v);
    previous_line = reader.line();
  }
  if (series.t_ns.empty()) {
    throw core::InputError({path, reader.line() + 1, 0}, "",
                           fmt::format("no samples after the header: expected at least one "
                                       "line like '1000000000,0.12,-0.5,0.0' under '{}'",
                                       kVelocityCsvHeader));
  }
  return series;
}

estimator::VelocitySeries ReadVelocityCsv(const std::string& path) {
  const std::string text = core::ReadWholeFile(path, "velocity CSV");
  return ParseVelocityCsv(text, path);
}

}  // namespace tofu::replay
