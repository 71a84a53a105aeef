#pragma once
// tofu's own methods (replay_method.h ReplayMethod: consensus, naive, single, fuse, oracle,
// imu_only) as an api::Estimator: the multi-graph estimator of the seed paper behind the
// interface every user's estimator implements, so the run loop, `tofu estimate`, the
// plug-in path and the process protocol all drive one kind of object.
//
// Privileged inputs stay outside the public interface: the oracle's labels (AddLabel)
// and the naive baseline's true frames (from the log's calibration, at construction).

#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "estimator/consensus_estimator.h"
#include "estimator/multi_graph_estimator.h"
#include "replay/estimation_config.h"
#include "replay/labels.h"
#include "replay/recorded_log.h"
#include "tofu/api.h"

namespace tofu::replay {

struct ReplayMethod;

class BuiltinEstimator : public api::Estimator {
 public:
  /// `log` describes the streams (its measurements are not read); `method` must not be
  /// a client method. Throws std::invalid_argument for options the estimator refuses.
  BuiltinEstimator(const RecordedLog& log, const ReplayMethod& method,
                   const EstimationSetup& setup);
  ~BuiltinEstimator() override;

  /// Configured by the constructor; the setup is checked against the log's streams.
  void Start(const api::EstimatorSetup& setup) override;
  void Add(const api::Measurement& measurement, std::vector<api::Estimate>* out) override;

  /// A label the oracle learns (other methods ignore it).
  void AddLabel(const LabelEvent& label);
  const estimator::MultiGraphEstimator& estimator() const;
  /// Consensus methods: the evaluations since the last call.
  std::vector<estimator::ConsensusRecord> TakeConsensusRecords();

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

/// The built-in method a process client or plug-in that hosts tofu's own estimator runs
/// (tofu-estimator-host, the lossless tests): the method `method_name` configured from
/// the setup's calibration (calibration_yaml) and `config`, as in the run that sent it.
std::unique_ptr<BuiltinEstimator> MakeHostedBuiltinEstimator(const api::EstimatorSetup& setup,
                                                             const std::string& method_name,
                                                             const EstimationConfig& config);

}  // namespace tofu::replay
