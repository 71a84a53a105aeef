#pragma once
// What tofu is: its version (CMake's project version) and the commit it was built from
// (`git describe --always --dirty`, "unknown" outside a git checkout). Defined in a file
// generated at every build (cmake/TofuVersion.cmake, library tofu_version), so the commit
// is the one built, not the one configured.

namespace tofu::core {

const char* TofuVersion();
const char* TofuCommit();

}  // namespace tofu::core
