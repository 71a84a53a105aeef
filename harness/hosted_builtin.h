#pragma once
// tofu's own estimation methods hosted behind the public interface as a user's estimator
// would be: built at Start from nothing but the setup (the streams, the run's calibration
// and estimation: block) and the method named by the host or by config.method. Served by
// tofu-estimator-host over the process protocol and by tofu's built-in plug-in library;
// both must give byte-identical estimate files to the in-process method (the lossless
// tests), so neither path may lose a bit.

#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "replay/builtin_estimator.h"
#include "tofu/api.h"

namespace tofu::harness {

class HostedBuiltinEstimator : public api::Estimator {
 public:
  /// `method`: the built-in method to run (consensus, naive, single:<s>, ...); nullopt:
  /// the setup's config.method, default consensus. The oracle is refused: it fuses by the
  /// run's fault labels, which no client is told.
  explicit HostedBuiltinEstimator(std::optional<std::string> method);
  void Start(const api::EstimatorSetup& setup) override;
  void Add(const api::Measurement& measurement, std::vector<api::Estimate>* out) override;

 private:
  std::optional<std::string> method_;
  std::unique_ptr<replay::BuiltinEstimator> inner_;
};

}  // namespace tofu::harness
