#include "harness/consistency_eval.h"

#include <algorithm>
#include <cmath>

#include "core/lie.h"
#include "core/units.h"
#include "estimator/frame_alignment.h"
#include "estimator/velocity.h"
#include "harness/run.h"

namespace tofu::harness {
namespace {

// The ground-truth sample at or just before t (200 Hz: within 5 ms), standing in for the
// local estimate's attitude and angular rate.
const sim::TruthState* TruthAt(const std::vector<sim::TruthState>& truth, core::Time t_ns) {
  if (truth.empty() || t_ns < truth.front().t_ns) return nullptr;
  const auto it = std::upper_bound(truth.begin(), truth.end(), t_ns,
                                   [](core::Time t, const sim::TruthState& s) { return t < s.t_ns; });
  return &*(it - 1);
}

// Rotation of the delivered reference frame S' in W: the true frame with the scheduled
// misalignments active at t applied (p_S' = R_F p_S + t_F, so R_WS' = R_WS R_F^T).
Eigen::Matrix3d DeliveredFrameRotation(const RunRecord& record, const SensorStream& stream,
                                       core::Time t_ns) {
  Eigen::Matrix3d R_WS = stream.T_WS.linear();
  for (const sim::FaultSpec& fault : record.scenario.faults) {
    if (fault.sensor != stream.name || fault.kind != sim::FaultKind::kMisalignment) continue;
    if (!sim::WindowOf(fault).Contains(t_ns)) continue;
    R_WS = R_WS * fault.misalignment.q_FS.toRotationMatrix().transpose();
  }
  return R_WS;
}

Eigen::Vector3d PositionOf(const core::Measurement& m) {
  if (const auto* p = std::get_if<core::PositionMeasurement>(&m)) return p->p_Ss;
  return std::get<core::PoseMeasurement>(m).p_Ss;
}

// Paper eq. (1) with a = the body point B: a stream that reports its own body twist gives
// v_B with no reference frame, only the extrinsics (R_Bs, the lever arm p_sB in s).
estimator::VelocitySeries BodyVelocityFromTwists(const SensorStream& stream,
                                                 const Eigen::Matrix3d& R_Bs,
                                                 const Eigen::Vector3d& p_sB) {
  estimator::VelocitySeries v_B;
  for (const sim::SensorSample& s : stream.delivered) {
    const auto& m = std::get<core::PoseMeasurement>(s.measured);
    if (!v_B.t_ns.empty() && s.t_ns <= v_B.t_ns.back()) continue;
    v_B.t_ns.push_back(s.t_ns);
    v_B.v_mps.push_back(estimator::TransferVelocity(
        Eigen::Matrix3d::Identity(), Eigen::Matrix3d::Identity(), R_Bs, m.v_s_s_mps,
        m.omega_s_s_radps, p_sB));
  }
  return v_B;
}

// Position sensors: differentiate, then rotate with the estimated frame alignment: a
// closed-form alignment over a trailing window, re-estimated at alignment_rate_hz against
// the mount's true positions (the local estimate's stand-in); each alignment's error is
// appended to *alignment.
estimator::VelocitySeries BodyVelocityFromPositions(
    const RunRecord& record, const SensorStream& stream, const sim::MountSite& site,
    const ConsistencyConfig& config, std::vector<AlignmentRow>* alignment) {
  const std::vector<sim::TruthState>& truth = record.groundtruth;
  const core::Time alignment_period_ns = core::PeriodFromRate(config.alignment_rate_hz);
  const core::Time alignment_window_ns = core::SecondsToTime(config.alignment_window_s);
  const Eigen::Matrix3d R_Bs = site.q_Bs.toRotationMatrix();
  const Eigen::Vector3d p_sB = -(R_Bs.transpose() * site.p_Bs);  // lever arm s -> B, in s
  estimator::VelocitySeries v_B;
  std::vector<core::Time> t_ns;
  std::vector<Eigen::Vector3d> p_S;
  for (const sim::SensorSample& s : stream.delivered) {
    t_ns.push_back(s.t_ns);
    p_S.push_back(PositionOf(s.measured));
  }
  estimator::DifferentiationOptions diff;
  diff.half_window_ns = core::SecondsToTime(config.differentiation_window_s / 2.0);
  const estimator::VelocitySeries v_S = estimator::DifferentiatePositions(t_ns, p_S, diff);

  std::optional<Eigen::Matrix3d> R_WS_est;
  core::Time next_alignment_ns = 0;
  size_t k = 0;  // next velocity sample
  size_t window_begin = 0;
  size_t window_end = 0;
  const core::Time end_ns = v_S.t_ns.empty() ? 0 : v_S.t_ns.back();
  for (core::Time t = next_alignment_ns; t <= end_ns + alignment_period_ns;
       t += alignment_period_ns) {
    // Velocities up to t use the alignment known before t (causal).
    while (k < v_S.t_ns.size() && v_S.t_ns[k] < t) {
      if (R_WS_est) {
        const sim::TruthState* x = TruthAt(truth, v_S.t_ns[k]);
        if (x != nullptr) {
          const Eigen::Matrix3d R_WB = x->q_WB.toRotationMatrix();
          const Eigen::Matrix3d R_Ss = R_WS_est->transpose() * R_WB * R_Bs;
          v_B.t_ns.push_back(v_S.t_ns[k]);
          v_B.v_mps.push_back(estimator::TransferVelocityFromReference(
              R_WB, *R_WS_est, v_S.v_mps[k], R_Ss, R_Bs.transpose() * x->omega_WB_B, p_sB));
        }
      }
      ++k;
    }
    while (window_end < t_ns.size() && t_ns[window_end] <= t) ++window_end;
    while (window_begin < window_end && t_ns[window_begin] <= t - alignment_window_ns) {
      ++window_begin;
    }
    std::vector<Eigen::Vector3d> p_W;
    std::vector<Eigen::Vector3d> p_A;
    for (size_t i = window_begin; i < window_end; ++i) {
      const sim::TruthState* x = TruthAt(truth, t_ns[i]);
      if (x == nullptr) continue;
      p_W.push_back(x->p_WB + x->q_WB.toRotationMatrix() * site.p_Bs);
      p_A.push_back(p_S[i]);
    }
    if (const auto aligned = estimator::AlignPositions(p_W, p_A)) {
      R_WS_est = aligned->T_AL.linear().transpose();
      alignment->push_back(
          {t, stream.name,
           core::DegFromRad(core::RotationAngleBetween(
               *R_WS_est, DeliveredFrameRotation(record, stream, t))),
           aligned->observable_rotation_dofs, aligned->rms_residual_m});
    }
  }
  return v_B;
}

// Every pair of series (and metric) compared over a sliding window at config.rate_hz.
void AddPairRows(const std::vector<estimator::VelocitySeries>& series, core::Time end_ns,
                 const ConsistencyConfig& config, ConsistencyEvaluation& eval) {
  estimator::ConsistencyOptions options;
  options.window_ns = core::SecondsToTime(config.window_s);
  options.standardize = config.standardize;
  options.kl_bandwidth_scale = config.kl_bandwidth_scale;
  const core::Time period_ns = core::PeriodFromRate(config.rate_hz);
  for (core::Time t = options.window_ns; t <= end_ns; t += period_ns) {
    for (size_t i = 0; i < series.size(); ++i) {
      for (size_t j = i + 1; j < series.size(); ++j) {
        for (const estimator::ConsistencyMetric metric : config.metrics) {
          eval.rows.push_back({t, eval.streams[i] + "-" + eval.streams[j], metric,
                               estimator::WindowConsistency(series[i], series[j], t, metric,
                                                            options)});
        }
      }
    }
  }
}

}  // namespace

ConsistencyEvaluation EvaluateConsistency(const RunRecord& record,
                                          const ConsistencyConfig& config) {
  ConsistencyEvaluation eval;
  const std::vector<sim::TruthState>& truth = record.groundtruth;
  if (truth.size() < 2) return eval;

  std::vector<estimator::VelocitySeries> series;
  for (const SensorStream& stream : record.sensors) {
    if (stream.kind == core::MeasurementKind::kImu || stream.delivered.empty()) continue;
    const sim::MountSite* site = record.robot.FindSite(stream.site);
    if (site == nullptr) continue;
    const Eigen::Matrix3d R_Bs = site->q_Bs.toRotationMatrix();
    const Eigen::Vector3d p_sB = -(R_Bs.transpose() * site->p_Bs);  // lever arm s -> B, in s
    const auto* first_pose = std::get_if<core::PoseMeasurement>(&stream.delivered.front().measured);
    eval.streams.push_back(stream.name);
    series.push_back(first_pose != nullptr && first_pose->has_twist
                         ? BodyVelocityFromTwists(stream, R_Bs, p_sB)
                         : BodyVelocityFromPositions(record, stream, *site, config, &eval.alignment));
  }

  // Last, the body velocity of B in B from the ground truth: each sensor against it.
  eval.streams.push_back("truth");
  series.emplace_back();
  for (const sim::TruthState& s : truth) {
    series.back().t_ns.push_back(s.t_ns);
    series.back().v_mps.push_back(s.q_WB.toRotationMatrix().transpose() * s.v_WB_W);
  }
  AddPairRows(series, truth.back().t_ns, config, eval);
  return eval;
}

}  // namespace tofu::harness
