#include "replay/stream_comparison.h"

#include <algorithm>
#include <numeric>
#include <stdexcept>
#include <variant>

#include "estimator/velocity.h"

namespace tofu::replay {

namespace {

// A stream's samples in time order of validity: positions in its frame A, and its
// attitudes q_As (pose streams only).
struct StreamSamples {
  std::vector<core::Time> t_ns;
  std::vector<Eigen::Vector3d> p_A;
  std::vector<Eigen::Quaterniond> q_As;
};

StreamSamples SortedSamplesOf(const RecordedLog& log, const RecordedStream& stream) {
  std::vector<core::Time> t;
  std::vector<Eigen::Vector3d> p_A;
  std::vector<Eigen::Quaterniond> q_As;
  for (const core::StampedMeasurement& m : log.measurements) {
    if (m.sensor != stream.name) continue;
    if (const auto* pose = std::get_if<core::PoseMeasurement>(&m.value)) {
      t.push_back(m.t_ns);
      p_A.push_back(pose->p_Ss);
      q_As.push_back(pose->q_Ss);
    } else if (const auto* position = std::get_if<core::PositionMeasurement>(&m.value)) {
      t.push_back(m.t_ns);
      p_A.push_back(position->p_Ss);
    }
  }
  std::vector<std::size_t> order(t.size());
  std::iota(order.begin(), order.end(), 0);
  std::stable_sort(order.begin(), order.end(), [&](auto a, auto b) { return t[a] < t[b]; });
  StreamSamples sorted;
  for (std::size_t k : order) {
    sorted.t_ns.push_back(t[k]);
    sorted.p_A.push_back(p_A[k]);
    if (!q_As.empty()) sorted.q_As.push_back(q_As[k]);
  }
  return sorted;
}

// The fit needs neighbours on both sides of every sample: a half window of at least
// 1.5 sample periods (estimator/velocity.h), e.g. 150 ms for a 10 Hz visual stream.
estimator::DifferentiationOptions DifferentiationFor(const std::vector<core::Time>& t_sorted) {
  estimator::DifferentiationOptions diff;
  if (t_sorted.size() >= 3) {
    std::vector<core::Time> spacing;
    for (std::size_t k = 1; k < t_sorted.size(); ++k) spacing.push_back(t_sorted[k] - t_sorted[k - 1]);
    std::nth_element(spacing.begin(), spacing.begin() + spacing.size() / 2, spacing.end());
    const core::Time period_ns = spacing[spacing.size() / 2];
    diff.half_window_ns = std::max(diff.half_window_ns, period_ns * 3 / 2 + period_ns / 10);
    diff.max_gap_ns = std::max(diff.max_gap_ns, 3 * period_ns);
  }
  return diff;
}

// The local estimate's velocity at the mount, in s, at the output times.
estimator::VelocitySeries LocalVelocityAtMount(const ReplayResult& result,
                                               const RecordedStream& stream) {
  estimator::VelocitySeries local;
  const Eigen::Matrix3d R_Is = stream.T_Is.linear();
  const Eigen::Vector3d p_Is = stream.T_Is.translation();
  for (const estimator::EstimatorOutput& o : result.outputs) {
    if (!o.valid) continue;
    const Eigen::Matrix3d R_LI = o.state.q_LI.toRotationMatrix();
    local.t_ns.push_back(o.t_ns);
    local.v_mps.push_back(R_Is.transpose() *
                          (R_LI.transpose() * o.state.v_L_mps + o.omega_I_radps.cross(p_Is)));
  }
  return local;
}

// The sensor's velocity in s: its velocity in A rotated by its own attitude (pose
// streams), or by the local attitude and the final alignment (position streams).
estimator::VelocitySeries SensorVelocityAtMount(const ReplayResult& result,
                                                const RecordedStream& stream,
                                                const StreamSamples& samples,
                                                const estimator::VelocitySeries& v_A,
                                                const estimator::VelocitySeries& local) {
  estimator::VelocitySeries sensor;
  const Eigen::Matrix3d R_Is = stream.T_Is.linear();
  const auto alignment = result.alignment.find(stream.name);
  for (std::size_t k = 0; k < v_A.t_ns.size(); ++k) {
    const core::Time tk = v_A.t_ns[k];
    Eigen::Matrix3d R_As;
    if (!samples.q_As.empty()) {
      const auto it = std::lower_bound(samples.t_ns.begin(), samples.t_ns.end(), tk);
      R_As = samples.q_As[static_cast<std::size_t>(it - samples.t_ns.begin())]
                 .normalized()
                 .toRotationMatrix();
    } else {
      if (alignment == result.alignment.end() || !alignment->second.valid) break;
      const auto it = std::lower_bound(local.t_ns.begin(), local.t_ns.end(), tk);
      if (it == local.t_ns.end()) break;
      const estimator::EstimatorOutput* o = nullptr;
      for (const estimator::EstimatorOutput& out_k : result.outputs) {
        if (out_k.valid && out_k.t_ns == *it) { o = &out_k; break; }
      }
      if (o == nullptr) continue;
      R_As = alignment->second.T_AL.linear() * o->state.q_LI.toRotationMatrix() * R_Is;
    }
    sensor.t_ns.push_back(tk);
    sensor.v_mps.push_back(R_As.transpose() * v_A.v_mps[k]);
  }
  return sensor;
}

}  // namespace

std::vector<LocalConsistencySeries> LocalConsistency(
    const RecordedLog& log, const ReplayResult& result, estimator::ConsistencyMetric metric,
    const estimator::ConsistencyOptions& options, double rate_hz) {
  std::vector<LocalConsistencySeries> out;
  // Looks outputs up by time: the in-memory ones (`tofu estimate`'s), not a flight's spill.
  if (result.spilled != nullptr) throw std::logic_error("LocalConsistency: outputs were spilled");
  if (result.outputs.empty()) return out;
  for (const RecordedStream& stream : log.streams) {
    if (stream.kind == core::MeasurementKind::kImu) continue;
    const StreamSamples samples = SortedSamplesOf(log, stream);
    const estimator::VelocitySeries v_A = estimator::DifferentiatePositions(
        samples.t_ns, samples.p_A, DifferentiationFor(samples.t_ns));
    const estimator::VelocitySeries local = LocalVelocityAtMount(result, stream);
    if (local.t_ns.size() < 2) continue;
    const estimator::VelocitySeries sensor =
        SensorVelocityAtMount(result, stream, samples, v_A, local);
    if (sensor.t_ns.size() < 2) continue;

    LocalConsistencySeries series;
    series.sensor = stream.name;
    const core::Time period = core::PeriodFromRate(rate_hz);
    const core::Time t0 = std::max(sensor.t_ns.front(), local.t_ns.front()) + options.window_ns;
    const core::Time t1 = std::min(sensor.t_ns.back(), local.t_ns.back());
    for (core::Time te = t0; te <= t1; te += period) {
      series.t_ns.push_back(te);
      series.value.push_back(estimator::WindowConsistency(sensor, local, te, metric, options));
    }
    out.push_back(std::move(series));
  }
  return out;
}

std::vector<PoseSample> RawPoseTrajectory(const RecordedLog& log, const RecordedStream& stream,
                                          core::Time from_ns, core::Time to_ns) {
  std::vector<PoseSample> raw;
  const Eigen::Isometry3d T_sI = stream.T_Is.inverse();
  for (const core::StampedMeasurement& m : log.measurements) {
    if (m.sensor != stream.name || m.t_ns < from_ns || m.t_ns > to_ns) continue;
    const auto* pose = std::get_if<core::PoseMeasurement>(&m.value);
    if (pose == nullptr || !pose->p_Ss.allFinite() || !pose->q_Ss.coeffs().allFinite()) continue;
    Eigen::Isometry3d T_As = Eigen::Isometry3d::Identity();
    T_As.linear() = pose->q_Ss.normalized().toRotationMatrix();
    T_As.translation() = pose->p_Ss;
    const Eigen::Isometry3d T_AI = T_As * T_sI;
    raw.push_back({m.t_ns, T_AI.translation(), Eigen::Quaterniond(T_AI.linear())});
  }
  std::stable_sort(raw.begin(), raw.end(),
                   [](const PoseSample& a, const PoseSample& b) { return a.t_ns < b.t_ns; });
  return raw;
}

}  // namespace tofu::replay
