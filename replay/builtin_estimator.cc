#include "replay/builtin_estimator.h"

#include <algorithm>
#include <stdexcept>
#include <utility>

#include <fmt/format.h>

#include "replay/api_convert.h"
#include "replay/replay_method.h"

namespace tofu::replay {
namespace {

// The naive baseline's privileged information (seed paper Sec. 3.3: "in the naive case, we
// use the ground truth transform between the Leica and local frame"): once the local
// frame L exists, anchored to the sensor that initialised it (T_A0L), every other sensor
// B gets T_BL = T_WB⁻¹ T_WA0 T_A0L from the true reference frames.
void GiveTrueAlignments(const std::vector<RecordedStream>& streams,
                        estimator::MultiGraphEstimator& estimator) {
  const RecordedStream* anchor = nullptr;
  Eigen::Isometry3d T_A0L = Eigen::Isometry3d::Identity();
  for (const RecordedStream& s : streams) {
    if (s.kind == core::MeasurementKind::kImu || !s.true_T_WS) continue;
    if (const auto T_AL = estimator.AlignmentOf(s.name)) {
      anchor = &s;
      T_A0L = *T_AL;
      break;
    }
  }
  if (anchor == nullptr) return;
  for (const RecordedStream& s : streams) {
    if (s.kind == core::MeasurementKind::kImu || !s.true_T_WS || &s == anchor) continue;
    estimator.SetKnownAlignment(s.name, s.true_T_WS->inverse() * *anchor->true_T_WS * T_A0L);
  }
}

}  // namespace

struct BuiltinEstimator::Impl {
  ReplayMethod method;
  std::vector<RecordedStream> streams;  // the names by index; the naive baseline's true frames
  std::optional<estimator::MultiGraphEstimator> fixed;
  std::optional<estimator::ConsensusEstimator> consensus;
  bool true_alignments_given = false;
  // kOracle: the labels, and the sensors they call unhealthy now (by their last sample).
  SensorHealth health;
  std::vector<std::string> unhealthy;

  // The oracle's choice for one sample: a sensor whose labels say faulty or degraded
  // leaves the fused set before its sample is added, and comes back with its first
  // healthy sample. While it is unhealthy its alignment pairs are dropped, as consensus
  // drops an inconsistent sensor's, so that a recovered sensor is re-aligned from
  // healthy data only.
  // Returns true for a sample of an unhealthy sensor: its pair, added with the sample,
  // is dropped after it too (RestartAlignment).
  bool OracleSelect(const core::StampedMeasurement& m) {
    if (std::find(method.fused.begin(), method.fused.end(), m.sensor) == method.fused.end()) {
      return false;  // the IMU, or a stream the method does not fuse
    }
    const bool healthy = health.Healthy(m.sensor, m.t_ns);
    const auto at = std::find(unhealthy.begin(), unhealthy.end(), m.sensor);
    if (healthy == (at == unhealthy.end())) return !healthy;
    if (healthy) {
      unhealthy.erase(at);
    } else {
      unhealthy.push_back(m.sensor);
    }
    std::vector<std::string> fused;
    for (const std::string& name : method.fused) {
      if (std::find(unhealthy.begin(), unhealthy.end(), name) == unhealthy.end()) {
        fused.push_back(name);
      }
    }
    fixed->SetFusedSensors(fused);
    return !healthy;
  }

  std::vector<estimator::EstimatorOutput> AddAndTake(const core::StampedMeasurement& m) {
    if (!fixed) {
      consensus->Add(m);
      return consensus->TakeOutputs();
    }
    const bool unhealthy = method.kind == ReplayMethod::Kind::kOracle && OracleSelect(m);
    fixed->Add(m);
    if (unhealthy) fixed->RestartAlignment(m.sensor);
    if (method.kind == ReplayMethod::Kind::kNaive && !true_alignments_given &&
        fixed->local().initialized()) {
      GiveTrueAlignments(streams, *fixed);
      true_alignments_given = true;
    }
    return fixed->TakeOutputs();
  }
};

BuiltinEstimator::BuiltinEstimator(const RecordedLog& log, const ReplayMethod& method,
                                   const EstimationSetup& setup)
    : impl_(std::make_unique<Impl>()) {
  if (method.kind == ReplayMethod::Kind::kClient) {
    throw std::invalid_argument(
        fmt::format("method '{}' is a client method, not one of tofu's own", method.name));
  }
  impl_->method = method;
  impl_->streams = log.streams;
  if (method.kind == ReplayMethod::Kind::kConsensus) {
    estimator::ConsensusEstimatorOptions chosen = setup.consensus;
    if (method.policy) chosen.selection.policy = *method.policy;
    impl_->consensus.emplace(log.imu_stream, setup.sensors, setup.estimator, chosen);
  } else {
    impl_->fixed.emplace(log.imu_stream, setup.sensors, setup.estimator);
    impl_->fixed->SetFusedSensors(method.fused);
  }
}

BuiltinEstimator::~BuiltinEstimator() = default;

void BuiltinEstimator::Start(const api::EstimatorSetup& setup) {
  if (setup.sensors.size() != impl_->streams.size()) {
    throw std::invalid_argument(fmt::format("setup of {} streams for a method configured with {}",
                                            setup.sensors.size(), impl_->streams.size()));
  }
  for (std::size_t i = 0; i < setup.sensors.size(); ++i) {
    if (setup.sensors[i].name != impl_->streams[i].name) {
      throw std::invalid_argument(fmt::format("setup stream {} is '{}', configured '{}'", i,
                                              setup.sensors[i].name, impl_->streams[i].name));
    }
  }
  // The mission frame: the launch pad and the surveyed frames, as any estimator is told.
  estimator::MissionSurvey survey;
  if (setup.T_MI_launch) survey.T_MI_launch = FromApiPose(*setup.T_MI_launch);
  for (const api::SensorInfo& sensor : setup.sensors) {
    if (sensor.T_MS) survey.T_MS[sensor.name] = FromApiPose(*sensor.T_MS);
  }
  if (!survey.T_MI_launch && survey.T_MS.empty()) return;
  if (impl_->consensus) {
    impl_->consensus->SetMissionSurvey(std::move(survey));
  } else {
    impl_->fixed->SetMissionSurvey(std::move(survey));
  }
}

void BuiltinEstimator::Add(const api::Measurement& measurement, std::vector<api::Estimate>* out) {
  if (measurement.sensor >= impl_->streams.size()) {
    throw std::invalid_argument(fmt::format("measurement of stream {} of {}", measurement.sensor,
                                            impl_->streams.size()));
  }
  for (estimator::EstimatorOutput& o : impl_->AddAndTake(
           FromApiMeasurement(measurement, impl_->streams[measurement.sensor].name))) {
    out->push_back(ToApiEstimate(std::move(o)));
  }
}

void BuiltinEstimator::AddLabel(const LabelEvent& label) { impl_->health.Add(label); }

const estimator::MultiGraphEstimator& BuiltinEstimator::estimator() const {
  return impl_->fixed ? *impl_->fixed : impl_->consensus->estimator();
}

std::vector<estimator::ConsensusRecord> BuiltinEstimator::TakeConsensusRecords() {
  if (!impl_->consensus) return {};
  return impl_->consensus->TakeRecords();
}

std::unique_ptr<BuiltinEstimator> MakeHostedBuiltinEstimator(const api::EstimatorSetup& setup,
                                                             const std::string& method_name,
                                                             const EstimationConfig& config) {
  std::vector<std::pair<std::string, core::MeasurementKind>> kinds;
  for (const api::SensorInfo& s : setup.sensors) {
    kinds.emplace_back(s.name, FromApi(s.kind));
  }
  const RecordedLog log = DescribeRunStreams(kinds, setup.calibration_yaml, "");
  const ReplayMethod method = ParseReplayMethod(method_name, log);
  auto estimator = std::make_unique<BuiltinEstimator>(log, method, MakeEstimationSetup(log, config));
  estimator->Start(setup);
  return estimator;
}

}  // namespace tofu::replay
