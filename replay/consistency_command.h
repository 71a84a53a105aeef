#pragma once
// `tofu consistency`: a consistency metric (estimator/consistency.h) between two
// velocity streams read from CSV files, evaluated over a sliding window at a fixed rate
// and written as CSV. The CLI only parses arguments into ConsistencyCommandOptions.

#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "core/time.h"
#include "estimator/consistency.h"

namespace tofu::replay {

/// What `tofu consistency` was asked for, as typed on the command line (validated by
/// RunConsistencyCommand, not by the CLI).
struct ConsistencyCommandOptions {
  std::string metric;                   ///< "mae", "pcc", "kl" or "cm"
  double window_s = 1.0;                ///< window length [s], > 0
  double rate_hz = 10.0;                ///< evaluation rate [Hz], > 0, period >= 1 ns
  bool standardize = false;             ///< ConsistencyOptions::standardize
  double kl_bandwidth_scale = 1.0;      ///< ConsistencyOptions::kl_bandwidth_scale, > 0
  std::string path_a;                   ///< velocity CSV of stream A
  std::string path_b;                   ///< velocity CSV of stream B
  std::optional<std::string> out_path;  ///< output CSV; stdout when empty
};

/// The command's description for `tofu consistency --help` (input format, strictness,
/// evaluation times, output format).
extern const char* const kConsistencyHelp;

/// The metric named `name`; throws core::InputError listing the known names otherwise.
estimator::ConsistencyMetric ParseConsistencyMetric(std::string_view name);

/// Evaluation times of two streams (both non-empty): t_k = t_0 + k * period_ns with
/// t_0 = max(a.t_ns.front(), b.t_ns.front()) + window_ns, for every t_k <=
/// min(a.t_ns.back(), b.t_ns.back()); empty when t_0 is past that end. Integer
/// arithmetic only (t_k is computed from k, never accumulated).
std::vector<core::Time> ConsistencyEvaluationTimes(const estimator::VelocitySeries& a,
                                                   const estimator::VelocitySeries& b,
                                                   core::Time window_ns, core::Time period_ns);

/// The output CSV: header "#timestamp [ns],<metric name>", then one line "t_ns,value"
/// per time of `times`, the value empty where WindowConsistency is unavailable.
std::string ConsistencyOutputCsv(const estimator::VelocitySeries& a,
                                 const estimator::VelocitySeries& b,
                                 const std::vector<core::Time>& times,
                                 estimator::ConsistencyMetric metric,
                                 const estimator::ConsistencyOptions& options);

/// The whole command: validates the options, reads both CSVs (ReadVelocityCsv), computes
/// the metric at every evaluation time and writes the CSV to `out_path` (through a
/// temporary sibling renamed into place) or to stdout. Throws core::InputError on bad
/// input, before anything is written.
void RunConsistencyCommand(const ConsistencyCommandOptions& options);

}  // namespace tofu::replay
