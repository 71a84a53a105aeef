#pragma once
// Velocity CSV files, the input of `tofu consistency`: one velocity stream per file, in
// the EuRoC/ASL style of the run directory (DESIGN.md, "Run directory"):
//
//   #timestamp [ns],v_x [m/s],v_y [m/s],v_z [m/s]
//   1000000000,0.12,-0.5,0.0
//   ...
//
// Reading is strict: a user's file that is not exactly this is bad input (an InputError
// naming file, line and column), never a silently shortened stream.

#include <string>
#include <string_view>

#include "estimator/consistency.h"

namespace tofu::replay {

/// The header line a velocity CSV must start with.
inline constexpr std::string_view kVelocityCsvHeader =
    "#timestamp [ns],v_x [m/s],v_y [m/s],v_z [m/s]";

/// Reads the velocity CSV at `path` with the run directory's reader (replay/csv_reader.h):
/// the header line (kVelocityCsvHeader; the EuRoC spelling "#timestamp" without the unit is
/// accepted for the first column, spaces around header fields are ignored), then one
/// sample per line: an integer timestamp in ns and three finite velocities in m/s, comma
/// separated (spaces/tabs around a field and a CR before the newline are allowed). A UTF-8
/// byte-order mark and blank lines at the end of the file are ignored.
///
/// Throws core::InputError (file, 1-based line and column, what was expected) for a
/// missing or unreadable file, an empty file, another header, a line without exactly 4
/// fields, a field that is not a number (timestamps: an integer), NaN or Inf, timestamps
/// that do not increase strictly (both stamps named), a blank line followed by more data,
/// and a header with no samples. The returned series is never empty.
estimator::VelocitySeries ReadVelocityCsv(const std::string& path);

/// Parses velocity CSV text as ReadVelocityCsv does; `path` only names the input in
/// errors.
estimator::VelocitySeries ParseVelocityCsv(std::string_view text, const std::string& path);

}  // namespace tofu::replay
