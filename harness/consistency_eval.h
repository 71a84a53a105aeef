#pragma once
// The consistency evaluation of a run (seed paper Sec. 2.1 and 3.2): every velocity-
// capable sensor's delivered stream turned into the body velocity of B (paper eq. 1),
// compared pairwise and against the truth with each configured metric over a sliding
// window. Frame alignment of position sensors is estimated in closed form from the data
// (estimator/frame_alignment.h) against the ground truth, which stands in for the local
// estimate until the estimator exists: roll and pitch are found quickly, yaw only once
// the robot moves horizontally, as in the paper.

#include <optional>
#include <string>
#include <vector>

#include "core/time.h"
#include "estimator/consistency.h"

namespace tofu::harness {

struct RunRecord;

/// `consistency:` in a scenario.
struct ConsistencyConfig {
  double rate_hz = 10.0;   ///< evaluation rate
  double window_s = 1.0;   ///< sliding window of each metric
  std::vector<estimator::ConsistencyMetric> metrics = {estimator::ConsistencyMetric::kCm};
  bool standardize = false;
  double kl_bandwidth_scale = 1.0;
  double alignment_window_s = 20.0;  ///< trailing window of the closed-form alignment
  double alignment_rate_hz = 10.0;   ///< how often the alignment is re-estimated
  /// Position differentiation: least-squares line over the samples within this trailing
  /// window (its estimate refers to the window's midpoint: a delay of half of it).
  double differentiation_window_s = 0.2;
};

struct ConsistencyRow {
  core::Time t_ns = 0;
  std::string pair;  ///< "a-b" (stream names; "truth" is the body-frame ground truth)
  estimator::ConsistencyMetric metric = estimator::ConsistencyMetric::kCm;
  std::optional<double> value;  ///< nullopt: unavailable
};

struct AlignmentRow {
  core::Time t_ns = 0;
  std::string sensor;
  double rotation_error_deg = 0.0;  ///< estimated vs true rotation of the delivered frame
  int observable_rotation_dofs = 0;
  double rms_residual_m = 0.0;
};

struct ConsistencyEvaluation {
  std::vector<std::string> streams;
  std::vector<ConsistencyRow> rows;
  std::vector<AlignmentRow> alignment;
};

/// Computes the evaluation from a finished run (its delivered sensor streams).
ConsistencyEvaluation EvaluateConsistency(const RunRecord& record, const ConsistencyConfig& config);

}  // namespace tofu::harness
