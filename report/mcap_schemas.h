#pragma once
// The JSON Schemas (draft 2020-12 subset) of the messages tofu writes to MCAP: Foxglove's
// types by their names (foxglove.PoseInFrame, ...: the fields tofu fills, which Foxglove
// Studio's panels read by schema name) and tofu's own (tofu.ImuSample, ...). Written from
// the message definitions of docs/MCAP.md; the MCAP test validates every message both
// against the schema in the file and, for foxglove.*, against @foxglove/schemas.

#include <string>

namespace tofu::report {

/// The schema text of `name`; throws std::out_of_range for an unknown name.
const std::string& JsonSchemaText(const std::string& name);

}  // namespace tofu::report
