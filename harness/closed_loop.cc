#include "harness/closed_loop.h"

#include <algorithm>
#include <cmath>

#include <fmt/format.h>

#include "core/lie.h"
#include "core/units.h"

namespace tofu::harness {

const char* StateSourceName(ControlConfig::StateSource source) {
  return source == ControlConfig::StateSource::kEstimate ? "estimate" : "ground_truth";
}

const char* FlightModeName(FlightMode mode) {
  switch (mode) {
    case FlightMode::kTruth: return "truth";
    case FlightMode::kEstimate: return "estimate";
    case FlightMode::kFailsafeHold: return "failsafe_hold";
    case FlightMode::kFailsafeLand: return "failsafe_land";
    case FlightMode::kLanded: return "landed";
  }
  return "?";
}

ClosedLoopPilot::ClosedLoopPilot(const FailsafeConfig& failsafe, const Eigen::Isometry3d& T_BI,
                                 const Eigen::Isometry3d& T_MB_launch)
    : failsafe_(failsafe), T_BI_(T_BI), T_MB_launch_(T_MB_launch) {}

bool ClosedLoopPilot::TryHandover(core::Time t_ns, const estimator::EstimatorOutput* newest) {
  if (handed_over_ || newest == nullptr || !newest->valid) return false;
  Eigen::Isometry3d T_LI = Eigen::Isometry3d::Identity();
  T_LI.linear() = newest->state.q_LI.normalized().toRotationMatrix();
  T_LI.translation() = newest->state.p_LI;
  T_ML_launch_ = core::YawPositionRegistration(T_MB_launch_, T_LI * T_BI_.inverse());
  handed_over_ = true;
  mode_ = FlightMode::kEstimate;
  const std::string detail =
      newest->mission
          ? std::string("estimate valid; the mission flown through its T_ML")
          : fmt::format("estimate valid; L registered to the launch pad (yaw {:.3f} deg)",
                        core::DegFromRad(core::YawOfNearestZRotation(T_ML_launch_.linear())));
  events_.push_back({t_ns, "handover", detail});
  return true;
}

Eigen::Isometry3d ClosedLoopPilot::T_ML(const estimator::EstimatorOutput& o) const {
  return o.mission ? o.mission->T_ML() : T_ML_launch_;
}

sim::RobotState ClosedLoopPilot::StateOf(core::Time t_ns,
                                         const estimator::EstimatorOutput& o) const {
  // Propagate the newest output to the controller's instant (constant v_L and ω_I).
  const double dt_s = std::max(0.0, core::TimeToSeconds(t_ns - o.t_ns));
  const Eigen::Quaterniond q_LI =
      (o.state.q_LI.normalized() * core::ExpQuat(o.omega_I_radps * dt_s)).normalized();
  const Eigen::Vector3d p_LI = o.state.p_LI + o.state.v_L_mps * dt_s;
  const Eigen::Matrix3d R_LI = q_LI.toRotationMatrix();
  const Eigen::Matrix3d R_IB = T_BI_.linear().transpose();
  const Eigen::Vector3d p_IB = -R_IB * T_BI_.translation();
  // p_LB = p_LI + R_LI p_IB, v_LB = v_LI + R_LI (ω_I × p_IB), ω_B = R_BI ω_I.
  const Eigen::Vector3d p_LB = p_LI + R_LI * p_IB;
  const Eigen::Vector3d v_LB = o.state.v_L_mps + R_LI * o.omega_I_radps.cross(p_IB);
  const Eigen::Isometry3d T_ML = this->T_ML(o);
  const Eigen::Matrix3d& R_ML = T_ML.linear();
  sim::RobotState state;
  state.t_ns = t_ns;
  state.p_WB = T_ML * p_LB;
  state.q_WB = Eigen::Quaterniond(R_ML * R_LI * R_IB).normalized();
  state.v_WB_W = R_ML * v_LB;
  state.omega_WB_B = T_BI_.linear() * o.omega_I_radps;
  return state;
}

// Long by design: the pilot's decision at one step (stale or invalid estimate, failsafe,
// landing) in priority order, on the same command.
ClosedLoopPilot::Command ClosedLoopPilot::Fly(core::Time t_ns,
                                              const estimator::EstimatorOutput& newest,
                                              const sim::Reference& mission) {
  if (newest.position_covariance_m2) {
    const Eigen::Vector3d var = newest.position_covariance_m2->diagonal();
    position_std_m_ = std::sqrt(std::max(0.0, var.maxCoeff()));
  }
  Command command;
  command.state = StateOf(t_ns, newest);
  last_state_ = command.state;

  std::optional<std::string> unusable;
  if (!newest.valid) {
    unusable = "estimate invalid: no usable position source";
  } else if (t_ns - newest.t_ns > kStaleAfterNs) {
    // No output for a while (no IMU data reached the estimator): the last one, however
    // valid, is being extrapolated blindly.
    unusable = fmt::format("estimate stale: newest output {:.3f} s old",
                           core::TimeToSeconds(t_ns - newest.t_ns));
  } else if (failsafe_.max_position_std_m && position_std_m_ &&
             !(*position_std_m_ <= *failsafe_.max_position_std_m)) {
    unusable = fmt::format("position std {:.3f} m above {:.3f} m", *position_std_m_,
                           *failsafe_.max_position_std_m);
  }

  if (mode_ == FlightMode::kEstimate && unusable) {
    mode_ = FlightMode::kFailsafeHold;
    failsafe_start_ns_ = t_ns;
    hold_ = sim::Reference{};
    hold_.p_WB = command.state.p_WB;
    hold_.q_WB = command.state.q_WB;
    events_.push_back({t_ns, "failsafe_start", *unusable});
  } else if (mode_ == FlightMode::kFailsafeHold && !unusable) {
    mode_ = FlightMode::kEstimate;
    events_.push_back({t_ns, "failsafe_end", "estimate usable again: mission resumed"});
  } else if (mode_ == FlightMode::kFailsafeHold &&
             t_ns - failsafe_start_ns_ >= core::SecondsToTime(failsafe_.hold_s)) {
    mode_ = FlightMode::kFailsafeLand;
    events_.push_back({t_ns, "failsafe_land",
                       fmt::format("descending at {:.2f} m/s", failsafe_.descent_rate_mps)});
  }

  // Landing: once the estimate has rested at the landing height, disarm.
  if (mode_ == FlightMode::kFailsafeLand) {
    const double landing_s = core::TimeToSeconds(
        t_ns - failsafe_start_ns_ - core::SecondsToTime(failsafe_.hold_s));
    const bool reference_down =
        hold_.p_WB.z() - failsafe_.descent_rate_mps * landing_s <= failsafe_.land_z_m;
    // A land detector's test on the estimate: down at the landing height and at rest
    // vertically (PX4's also asks for low thrust; an estimate drifting on the IMU can
    // still fool it, as it would on the robot).
    if (reference_down && command.state.p_WB.z() <= failsafe_.land_z_m + 0.05 &&
        std::abs(command.state.v_WB_W.z()) < 0.2) {
      if (!at_land_z_since_ns_) at_land_z_since_ns_ = t_ns;
      if (t_ns - *at_land_z_since_ns_ >= kLandedAfterNs) {
        mode_ = FlightMode::kLanded;
        events_.push_back({t_ns, "landed", "at the landing height: disarmed"});
      }
    } else {
      at_land_z_since_ns_.reset();
    }
  }

  if (mode_ != FlightMode::kEstimate) join_offset_m_.reset();
  command.mode = mode_;
  command.disarmed = mode_ == FlightMode::kLanded;
  switch (mode_) {
    case FlightMode::kTruth:
    case FlightMode::kEstimate:
      command.reference = mission;
      JoinMission(t_ns, command.state.p_WB, &command.reference);
      break;
    case FlightMode::kFailsafeHold:
      command.reference = hold_;
      break;
    case FlightMode::kLanded:
    case FlightMode::kFailsafeLand: {
      command.reference = hold_;
      const double descending_s = core::TimeToSeconds(
          t_ns - failsafe_start_ns_ - core::SecondsToTime(failsafe_.hold_s));
      const double z = hold_.p_WB.z() - failsafe_.descent_rate_mps * descending_s;
      if (z > failsafe_.land_z_m) {
        command.reference.p_WB.z() = z;
        command.reference.v_WB_W.z() = -failsafe_.descent_rate_mps;
      } else {
        command.reference.p_WB.z() = std::min(hold_.p_WB.z(), failsafe_.land_z_m);
      }
      break;
    }
  }
  return command;
}

void ClosedLoopPilot::JoinMission(core::Time t_ns, const Eigen::Vector3d& p_WB_believed,
                                  sim::Reference* reference) {
  if (!join_offset_m_) {
    // Joining starts here: at the handover or when a failsafe has ended.
    join_offset_m_ = p_WB_believed - reference->p_WB;
    last_join_ns_ = t_ns;
  }
  const double dt_s = std::max(0.0, core::TimeToSeconds(t_ns - last_join_ns_));
  last_join_ns_ = t_ns;
  Eigen::Vector3d& offset_m = *join_offset_m_;
  const double offset_norm_m = offset_m.norm();
  const double left_m = offset_norm_m - kJoinSpeedMps * dt_s;
  if (left_m <= 0.0) {
    offset_m.setZero();
    return;
  }
  offset_m *= left_m / offset_norm_m;
  reference->p_WB += offset_m;
  reference->v_WB_W -= kJoinSpeedMps * offset_m.normalized();
}

}  // namespace tofu::harness
