#pragma once
// `tofu compare` and `tofu baseline` as the CLI gives them: options in, exit code out.

#include <optional>
#include <string>
#include <vector>

namespace tofu::campaign {

struct CompareCommandOptions {
  /// BASE NEW (check directories or baseline files); with `methods`, one check directory.
  std::vector<std::string> inputs;
  std::vector<std::string> methods;  ///< empty, or the base method and the new method
  std::optional<std::string> markdown_path;
  std::optional<std::string> json_path;
  std::vector<std::string> min_effects;  ///< NAME=VALUE
  double fdr = 0.05;
  std::string fdr_procedure = "bh";  ///< "bh" or "by"
  bool unpaired = false;
  bool quiet = false;
};

/// Compares, prints the table (unless quiet), writes the markdown and JSON (atomically),
/// and returns kExitOk when nothing regressed, kExitExpectationFailed when something did,
/// kExitBadInput (nothing written) when the inputs cannot be compared.
int RunCompareCommand(const CompareCommandOptions& options);

/// `tofu baseline CHECK_DIR --out FILE`: the check's cells as a baseline file (the explicit
/// re-baselining). kExitBadInput when CHECK_DIR is no check directory.
int RunBaselineCommand(const std::string& check_dir, const std::string& out_file, bool quiet);

}  // namespace tofu::campaign
