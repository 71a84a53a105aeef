#include "replay/consistency_command.h"

#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <iterator>
#include <limits>

#include <fmt/format.h>

#include "core/error.h"
#include "replay/file_io.h"
#include "replay/velocity_csv.h"

namespace tofu::replay {
namespace {

using core::InputError;
using estimator::ConsistencyMetric;

constexpr ConsistencyMetric kAllMetrics[] = {ConsistencyMetric::kMae, ConsistencyMetric::kPcc,
                                             ConsistencyMetric::kKl, ConsistencyMetric::kCm};

// Largest duration in seconds whose nanoseconds fit comfortably in core::Time.
constexpr double kMaxDurationS = 9.0e9;

std::string MetricList() {
  std::string list;
  for (const ConsistencyMetric m : kAllMetrics) {
    if (!list.empty()) list += ", ";
    list += estimator::MetricName(m);
  }
  return list;
}

// Window length in ns from the command line's seconds.
core::Time WindowFromSeconds(double window_s) {
  if (!(std::isfinite(window_s) && window_s > 0.0 && window_s <= kMaxDurationS) ||
      core::SecondsToTime(window_s) < 1) {
    throw InputError(
        {"--window"}, "",
        fmt::format("expected a positive number of seconds (at least 1 ns), got {}", window_s));
  }
  return core::SecondsToTime(window_s);
}

// Evaluation period in ns from the command line's rate.
core::Time EvaluationPeriod(double rate_hz) {
  if (!(std::isfinite(rate_hz) && rate_hz > 0.0 && 1.0 / rate_hz <= kMaxDurationS) ||
      core::PeriodFromRate(rate_hz) < 1) {
    throw InputError(
        {"--rate"}, "",
        fmt::format("expected a positive rate in Hz (period at least 1 ns), got {}", rate_hz));
  }
  return core::PeriodFromRate(rate_hz);
}


}  // namespace

const char* const kConsistencyHelp =
    "Metrics, each per axis over the window and summed over x, y, z (Lanegger et al., Sec. 2.1):\n"
    R"(  mae  mean absolute error of A against B interpolated at A's times [m/s]
  pcc  Pearson correlation of the same pairs (3: perfectly correlated on every axis)
  kl   Kullback-Leibler divergence between Gaussian kernel density estimates of A and B
  cm   Cramer-von Mises distance between the empirical distributions of A and B
--standardize compares the samples after centring and scaling each axis by the pooled
mean and standard deviation; --kl-bandwidth-scale multiplies KL's Silverman bandwidth.

Input: A.csv and B.csv, velocities of two sensors in the same frame, each starting with
the header line
  #timestamp [ns],v_x [m/s],v_y [m/s],v_z [m/s]
(the EuRoC spelling '#timestamp' is accepted for the first column), then one sample per
line: integer time [ns], v_x, v_y, v_z [m/s]. Reading is strict: a missing or empty
file, another header, a line without exactly 4 fields, a field that is not a number, NaN
or Inf, a timestamp not after the previous one, or a header without samples is bad
input: 'tofu: error: FILE:LINE:COLUMN: ...', exit code 2, nothing written. (Inside a run
the estimator drops and counts such samples; a file given to this command is refused.)

Evaluation times: t_k = t_0 + k * period, t_0 = max(first t of A, first t of B) + window,
period = 1/rate rounded to the nearest ns, for every t_k <= min(last t of A, last t of B);
integer ns arithmetic. The value at t_k uses the samples with t in (t_k - window, t_k].
Streams that overlap by less than one window are bad input.

Output: a header '#timestamp [ns],<metric>', then one line 't_ns,value' per evaluation
time; an empty value means unavailable (a stream has fewer than 3 samples in the window,
e.g. a gap longer than the window). Written to --out (complete, then renamed into place)
or to stdout. Exit codes: 0 ok, 2 bad input.)";

ConsistencyMetric ParseConsistencyMetric(std::string_view name) {
  const auto metric = estimator::MetricFromName(name);
  if (metric == estimator::ConsistencyMetric::kNis) {
    throw InputError({"--metric"}, "",
                     fmt::format("metric 'nis' needs each sample's stated covariance, which "
                                 "these velocity CSVs do not carry (a scenario's consensus "
                                 "can use it); expected one of: {}", MetricList()));
  }
  if (metric) return *metric;
  throw InputError({"--metric"}, "",
                   fmt::format("unknown metric '{}', expected one of: {}", name, MetricList()));
}

std::vector<core::Time> ConsistencyEvaluationTimes(const estimator::VelocitySeries& a,
                                                   const estimator::VelocitySeries& b,
                                                   core::Time window_ns, core::Time period_ns) {
  std::vector<core::Time> times;
  const core::Time first = std::max(a.t_ns.front(), b.t_ns.front());
  const core::Time last = std::min(a.t_ns.back(), b.t_ns.back());
  if (first > std::numeric_limits<core::Time>::max() - window_ns) return times;
  const core::Time t0 = first + window_ns;
  if (t0 > last) return times;
  // t_k = t0 + k * period; (last - t0) / period cannot overflow, nor can t0 + k * period.
  const core::Time count = (last - t0) / period_ns + 1;
  times.reserve(static_cast<size_t>(count));
  for (core::Time k = 0; k < count; ++k) times.push_back(t0 + k * period_ns);
  return times;
}

std::string ConsistencyOutputCsv(const estimator::VelocitySeries& a,
                                 const estimator::VelocitySeries& b,
                                 const std::vector<core::Time>& times, ConsistencyMetric metric,
                                 const estimator::ConsistencyOptions& options) {
  std::string csv = fmt::format("#timestamp [ns],{}\n", estimator::MetricName(metric));
  csv.reserve(csv.size() + times.size() * 32);
  auto out = std::back_inserter(csv);
  for (const core::Time t : times) {
    const std::optional<double> value = estimator::WindowConsistency(a, b, t, metric, options);
    // Shortest representation that reads back to the same double; empty: unavailable.
    if (value) {
      fmt::format_to(out, "{},{}\n", t, *value);
    } else {
      fmt::format_to(out, "{},\n", t);
    }
  }
  return csv;
}

void RunConsistencyCommand(const ConsistencyCommandOptions& options) {
  // Options first: a typo is reported before reading large files.
  const ConsistencyMetric metric = ParseConsistencyMetric(options.metric);
  estimator::ConsistencyOptions metric_options;
  metric_options.window_ns = WindowFromSeconds(options.window_s);
  metric_options.standardize = options.standardize;
  if (!(std::isfinite(options.kl_bandwidth_scale) && options.kl_bandwidth_scale > 0.0)) {
    throw InputError({"--kl-bandwidth-scale"}, "",
                     fmt::format("expected a positive factor, got {}", options.kl_bandwidth_scale));
  }
  metric_options.kl_bandwidth_scale = options.kl_bandwidth_scale;
  const core::Time period_ns = EvaluationPeriod(options.rate_hz);

  const estimator::VelocitySeries a = ReadVelocityCsv(options.path_a);
  const estimator::VelocitySeries b = ReadVelocityCsv(options.path_b);
  const std::vector<core::Time> times =
      ConsistencyEvaluationTimes(a, b, metric_options.window_ns, period_ns);
  if (times.empty()) {
    throw InputError(
        {options.path_a}, "",
        fmt::format("overlaps {} by less than one window ({} s), nothing to evaluate: {} spans "
                    "t = {} .. {} ns, {} spans t = {} .. {} ns (same clock?)",
                    options.path_b, options.window_s, options.path_a, a.t_ns.front(), a.t_ns.back(),
                    options.path_b, b.t_ns.front(), b.t_ns.back()));
  }

  const std::string csv = ConsistencyOutputCsv(a, b, times, metric, metric_options);
  if (options.out_path) {
    WriteFileAtomically(*options.out_path, csv, "--out");
  } else {
    std::fwrite(csv.data(), 1, csv.size(), stdout);
    std::fflush(stdout);
  }
}

}  // namespace tofu::replay
