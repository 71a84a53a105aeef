#include "campaign/compare_command.h"

#include <cstdlib>

#include <fmt/format.h>

#include "campaign/compare.h"
#include "core/error.h"
#include "replay/file_io.h"

namespace tofu::campaign {
namespace {

using core::InputError;

CompareOptions ParseOptions(const CompareCommandOptions& command) {
  CompareOptions options;
  if (!(command.fdr > 0.0 && command.fdr < 1.0)) {
    throw InputError({"--fdr"}, "", fmt::format("expected a rate in (0, 1), got {}", command.fdr));
  }
  options.fdr = command.fdr;
  if (command.fdr_procedure == "bh") {
    options.fdr_procedure = FdrProcedure::kBenjaminiHochberg;
  } else if (command.fdr_procedure == "by") {
    options.fdr_procedure = FdrProcedure::kBenjaminiYekutieli;
  } else {
    throw InputError({"--fdr-procedure"}, "",
                     fmt::format("expected bh (Benjamini-Hochberg) or by (Benjamini-Yekutieli), "
                                 "got '{}'",
                                 command.fdr_procedure));
  }
  options.unpaired = command.unpaired;
  for (const std::string& entry : command.min_effects) {
    const auto equals = entry.find('=');
    char* end = nullptr;
    const double value = equals == std::string::npos ? 0.0 : std::strtod(entry.c_str() + equals + 1, &end);
    if (equals == std::string::npos || equals == 0 || end == entry.c_str() + equals + 1 || *end != '\0') {
      throw InputError({"--min-effect"}, entry,
                       "expected NAME=VALUE, e.g. methods.<method>.ate_m=0.1 (a ratio metric's "
                       "relative change) or methods.consensus.max_detection_delay_s=0.5");
    }
    options.minimal_effects[entry.substr(0, equals)] = value;
  }
  return options;
}

}  // namespace

int RunCompareCommand(const CompareCommandOptions& command) {
  Comparison comparison;
  try {
    const CompareOptions options = ParseOptions(command);
    if (!command.methods.empty()) {
      if (command.methods.size() != 2 || command.inputs.size() != 1) {
        throw InputError({"--methods"}, "",
                         "expected one check directory and --methods BASE_METHOD NEW_METHOD");
      }
      comparison = CompareMethods(ReadCampaign(command.inputs[0]), command.methods[0],
                                  command.methods[1], options);
    } else {
      if (command.inputs.size() != 2) {
        throw InputError({"tofu compare"}, "",
                         fmt::format("expected BASE NEW (two check directories or baseline "
                                     "files), got {} arguments",
                                     command.inputs.size()));
      }
      comparison = CompareCampaigns(ReadCampaign(command.inputs[0]), ReadCampaign(command.inputs[1]),
                                    options);
    }
  } catch (const InputError& e) {
    fmt::print(stderr, "tofu: error: {}\n", e.what());
    return core::kExitBadInput;
  }
  try {
    if (command.markdown_path) {
      replay::WriteFileAtomically(*command.markdown_path, ComparisonMarkdown(comparison), "--markdown");
    }
    if (command.json_path) {
      replay::WriteFileAtomically(*command.json_path, ComparisonJson(comparison).dump(1) + "\n",
                                  "--json");
    }
  } catch (const core::IoError& e) {
    fmt::print(stderr, "tofu: error: {}\n", e.what());
    return core::kExitIoError;
  }
  if (!command.quiet) fmt::print("{}", ComparisonTable(comparison));
  return comparison.Count(Verdict::kRegressed) > 0 ? core::kExitExpectationFailed : core::kExitOk;
}

int RunBaselineCommand(const std::string& check_dir, const std::string& out_file, bool quiet) {
  CampaignRecord campaign;
  try {
    campaign = ReadCheckDirectory(check_dir);
  } catch (const InputError& e) {
    fmt::print(stderr, "tofu: error: {}\n", e.what());
    return core::kExitBadInput;
  }
  try {
    replay::WriteFileAtomically(out_file, BaselineJson(campaign), "--out");
  } catch (const core::IoError& e) {
    fmt::print(stderr, "tofu: error: {}\n", e.what());
    return core::kExitIoError;
  }
  if (!quiet) {
    fmt::print("baseline of {} ({} cells, tofu {} {}): {}\n", check_dir, campaign.cells.size(),
               campaign.tofu_version, campaign.tofu_commit, out_file);
  }
  return core::kExitOk;
}

}  // namespace tofu::campaign
