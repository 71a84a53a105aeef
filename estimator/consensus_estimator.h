#pragma once
// The consensus-based estimator of the seed paper (Lanegger et al., Sec. 2.3): the
// multi-graph estimator whose fused sensors are chosen online by consensus. Every
// evaluation period (10 Hz) it
//  1. turns each sensor's recent measurements into the velocity of the IMU point in the
//     IMU frame I (paper eq. 1: differentiated positions, rotated by the sensor's own
//     attitude — or, for a position-only sensor, by the local attitude and the sensor's
//     T_AL — and moved over the lever arm with the gyro rate),
//  2. does the same with the local estimate (R_LIᵀ v_L),
//  3. evaluates the consistency matrix (Cramér-von Mises distance, eq. 5, over a 1 s
//     window; or, beyond the paper, kNis: the differences normalised by the covariances
//     each sensor states, propagated through the differentiation and onto the grid) of all
//     sensor pairs and of each sensor against the local estimate,
//  4. lets the ConsensusSelector decide which sensors constrain the local graph
//     (cross-pattern isolation, two-sensor tie-break against the local estimate), and
//     hands that set to MultiGraphEstimator::SetFusedSensors.
// Every evaluation is returned as a ConsensusRecord (decision, reason, matrix values).
//
// A sensor that reports its own twist (odometry) is compared by it, as in the paper;
// positions are differentiated otherwise. Evaluations lag the newest IMU sample by the
// differentiation half window (position streams) plus a margin for late arrivals: a
// velocity at t_k needs the samples up to t_k + half window.
// Library code: Eigen + Ceres only, no I/O.

#include <memory>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "core/measurement.h"
#include "core/time.h"
#include "estimator/consensus_selector.h"
#include "estimator/consistency_matrix.h"
#include "estimator/multi_graph_estimator.h"

namespace tofu::estimator {

struct ConsensusEstimatorOptions {
  ConsensusOptions selection;
  /// CM over a 1 s window (paper); history long enough for the evaluation lag.
  ConsistencyMatrixOptions consistency = [] {
    ConsistencyMatrixOptions o;
    o.metric = ConsistencyMetric::kCm;
    o.consistency.window_ns = 1'000'000'000;
    o.history_ns = 3'000'000'000;
    return o;
  }();
  core::Time evaluation_period_ns = 100'000'000;  ///< 10 Hz
  /// Half window of the local least-squares differentiation of a stream's positions
  /// (estimator/velocity.h): at least this, and at least 1.5 of the stream's sample
  /// periods (measured from its first samples) so every fit has both sides.
  core::Time min_differentiation_half_window_ns = 100'000'000;
  /// Added to the largest half window: how late a sample may arrive and still count.
  core::Time evaluation_margin_ns = 60'000'000;
  /// Every stream (and the local estimate) enters the matrix on a common time grid at
  /// this rate, interpolated linearly between its samples: comparing distributions of
  /// samples taken at different instants would measure the sampling, not the sensors.
  double grid_rate_hz = 50.0;
  /// No interpolation across a gap longer than this (a dropout stays a dropout).
  core::Time max_interpolation_gap_ns = 250'000'000;

  /// Beyond the paper: a pair of sensors is also inconsistent when the mean of its
  /// velocity differences in L over this window fails the test of consistency.h
  /// (WindowMeanDifference: a slow drift that every 1 s window hides); 0 = off (the
  /// paper). The window starts again whenever the pair's value is unavailable or not
  /// below selection.threshold: a fault the window metric sees (and its edges) never
  /// enters the mean, and the test cannot hold a recovered sensor out for longer.
  core::Time bias_window_ns = 0;
  /// The test is taken once the window holds this much since its start.
  core::Time bias_min_span_ns = 2'000'000'000;
  /// Probability that a consistent pair fails one evaluation of the test: the χ² bound
  /// is its quantile for the pair's observed directions.
  double bias_false_alarm = 1e-4;
  /// The test's options; the streams' noise (a, b) and estimate_rotation are set per
  /// pair: a twist's errors correlated over its sample period (or the grid's),
  /// differentiated positions by their stated covariance, and the rotation estimated for
  /// a pair with a position sensor (its velocity comes through its alignment's R_AL).
  MeanDifferenceOptions bias;

  /// True when the options (the nested ones too) are usable; otherwise false with the
  /// broken constraint in *why (if why is not null).
  bool IsValid(std::string* why = nullptr) const;
};

/// One evaluation: the decision and the matrix values behind it.
struct ConsensusRecord {
  /// When the decision was taken and applied: the IMU time that triggered it.
  core::Time t_ns = 0;
  /// The end of the window the values describe: t_ns − evaluation_delay_ns().
  core::Time window_end_ns = 0;
  ConsensusDecision decision;
  /// The metric of the values (the matrix's: cm as in the paper, or nis).
  ConsistencyMetric metric = ConsistencyMetric::kCm;
  /// "a-b" for sensor pairs, "a-local" against the local estimate, in matrix order.
  std::vector<std::pair<std::string, std::optional<double>>> values;
  /// With bias_window_ns: "a-b" for sensor pairs, the χ² of the mean-difference test
  /// (nullopt: not taken).
  std::vector<std::pair<std::string, std::optional<double>>> bias_chi2;
};

class ConsensusEstimator {
 public:
  /// Throws std::invalid_argument when options.IsValid() or estimator_options.IsValid() is
  /// false, or for sensor names the selector or the matrix refuse.
  ConsensusEstimator(std::string imu_name, std::vector<SensorSpec> sensors,
                     MultiGraphEstimatorOptions estimator_options = {},
                     ConsensusEstimatorOptions options = {});
  ~ConsensusEstimator();
  ConsensusEstimator(const ConsensusEstimator&) = delete;
  ConsensusEstimator& operator=(const ConsensusEstimator&) = delete;

  /// Any measurement, in arrival order. Never throws for bad data (the estimator's
  /// gates reject and count it; non-finite samples never reach the matrix).
  void Add(const core::StampedMeasurement& measurement);

  /// The mission survey (MultiGraphEstimator::SetMissionSurvey): T_ML then follows the
  /// surveyed sensors consensus fuses.
  void SetMissionSurvey(MissionSurvey survey);

  /// Estimator outputs produced since the last call.
  std::vector<EstimatorOutput> TakeOutputs();
  /// Consensus evaluations since the last call.
  std::vector<ConsensusRecord> TakeRecords();

  const MultiGraphEstimator& estimator() const;
  const ConsensusSelector& selector() const;
  /// The lag of an evaluation behind the newest IMU sample.
  core::Time evaluation_delay_ns() const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace tofu::estimator
