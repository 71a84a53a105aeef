#include "harness/hosted_builtin.h"

#include <stdexcept>

#include <nlohmann/json.hpp>

#include "harness/scenario.h"

namespace tofu::harness {

HostedBuiltinEstimator::HostedBuiltinEstimator(std::optional<std::string> method)
    : method_(std::move(method)) {}

void HostedBuiltinEstimator::Start(const api::EstimatorSetup& setup) {
  std::string method = method_.value_or("consensus");
  if (!method_) {
    const auto config = nlohmann::json::parse(setup.config_json, nullptr, false);
    if (config.is_object() && config.contains("method") && config.at("method").is_string()) {
      method = config.at("method").get<std::string>();
    }
  }
  if (method == "oracle" || method.starts_with("oracle@")) {
    throw std::invalid_argument(
        "the oracle fuses by the run's fault labels, which no client is told");
  }
  if (setup.imu >= setup.sensors.size()) {
    throw std::invalid_argument("setup.imu is not the index of a stream");
  }
  std::vector<std::string> names;
  for (const api::SensorInfo& s : setup.sensors) names.push_back(s.name);
  const replay::EstimationConfig estimation = ParseEstimationBlock(
      setup.estimation_yaml, "setup.estimation_yaml", names, names[setup.imu]);
  inner_ = replay::MakeHostedBuiltinEstimator(setup, method, estimation);
}

void HostedBuiltinEstimator::Add(const api::Measurement& measurement,
                                 std::vector<api::Estimate>* out) {
  if (!inner_) throw std::logic_error("Add before Start");
  inner_->Add(measurement, out);
}

}  // namespace tofu::harness
