#pragma once
// Closed-loop co-testing (a scenario's `control:` block): the controller flies on an
// estimation method's output instead of ground truth, and the flight is judged against
// ground truth. The pilot below is what a flight stack puts between its estimator and
// its position controller:
//  - start-up: until the method reports a valid estimate, the robot hovers on ground
//    truth over the launch pad (the stand-in for waiting on it). At the first valid
//    output it hands over. From then on the mission, stated in the mission frame M (=
//    W), is flown through the estimate's T_ML, the estimator's global output (the
//    launch pad's registration, then the surveyed absolute sensors it trusts:
//    estimator/mission_frame.h). An estimate without T_ML (a client's that does not
//    publish one) is registered once, at the handover, to the launch pad's pose: the
//    operator's "the robot is here". The pilot never reads ground truth (its interface
//    has none).
//  - failsafe: when the output is flagged invalid (no fused sensor for longer than the
//    estimator's max_unfused_ns), stale (none for 100 ms: the IMU stopped reaching the
//    estimator) or its position standard deviation passes an opt-in bound, the
//    pilot holds the estimated position and attitude on IMU propagation for hold_s, then
//    descends at descent_rate_mps to land_z_m; a usable estimate during the hold resumes
//    the mission (PX4's position-loss failsafe: hold, then land). Once the estimate has
//    been at land_z_m for landed_after_s, the pilot disarms (mode landed: no thrust),
//    as a land detector does; the estimate is not trusted to hold the robot on the floor.
//  - the state it hands the controller is the newest output, propagated to the
//    controller's instant at constant velocity and body rate (the output is at 200 Hz;
//    the controller may run faster).

#include <optional>
#include <string>
#include <vector>

#include <Eigen/Core>
#include <Eigen/Geometry>

#include "core/time.h"
#include "estimator/multi_graph_estimator.h"
#include "sim/controller.h"
#include "sim/trajectory.h"

namespace tofu::harness {

struct FailsafeConfig {
  double hold_s = 2.0;              ///< hover on IMU propagation before descending
  double descent_rate_mps = 0.5;    ///< then descend at this rate
  double land_z_m = 0.3;            ///< down to this height of B in W, then disarm
  /// Largest position std the controller flies on; unset: no bound. Off by default: the
  /// local graph's covariance is that of p_LI in its own drifting frame L, which only
  /// relative constraints tie down, so it grows with the distance flown whatever the
  /// sensors' health (measured: 0.5 m after 85 s of figure-eights fusing LiDAR odometry).
  /// A bound suits an estimator whose covariance is absolute.
  std::optional<double> max_position_std_m;
};

/// `control:` in a scenario.
struct ControlConfig {
  enum class StateSource { kGroundTruth, kEstimate };
  StateSource state_source = StateSource::kGroundTruth;
  /// `state_source: estimate`: one closed-loop flight per method (names of `estimation:`).
  std::vector<std::string> methods;
  /// A flight whose true position leaves the reference by more than this has diverged.
  double corridor_m = 0.5;
  FailsafeConfig failsafe;
  /// Who flies every flight of the scenario: a client ("external:<key>", "plugin:<key>")
  /// of the scenario's external:/plugins: blocks; unset: tofu's SE(3) controller.
  std::optional<std::string> controller;
};

/// `control.controller` naming tofu's own SE(3) controller (the default).
inline constexpr const char* kBuiltinControllerName = "se3";

const char* StateSourceName(ControlConfig::StateSource source);

enum class FlightMode { kTruth, kEstimate, kFailsafeHold, kFailsafeLand, kLanded };
const char* FlightModeName(FlightMode mode);

/// Something the pilot did: "handover", "failsafe_start" (detail: the reason),
/// "failsafe_end", "failsafe_land", "landed" (disarmed); or how the flight ended early:
/// "ended_after_collision" (detail: the simulation's failure after the robot had hit
/// something).
struct FlightEvent {
  core::Time t_ns = 0;
  std::string event;
  std::string detail;
};

class ClosedLoopPilot {
 public:
  /// `T_BI`: the IMU's nominal mount (what the estimator is given); `T_MB_launch`: the
  /// launch pad's pose of B in M, as the scenario states it.
  ClosedLoopPilot(const FailsafeConfig& failsafe, const Eigen::Isometry3d& T_BI,
                  const Eigen::Isometry3d& T_MB_launch);

  bool handed_over() const { return handed_over_; }
  /// Before the handover: hands over when `newest` is valid (registering L to the launch
  /// pad when the estimate carries no T_ML). Returns whether it handed over.
  bool TryHandover(core::Time t_ns, const estimator::EstimatorOutput* newest);

  /// After the handover: what the controller flies on at t_ns, from the newest output.
  struct Command {
    sim::RobotState state;
    sim::Reference reference;
    FlightMode mode = FlightMode::kEstimate;
    bool disarmed = false;  ///< landed: the rotors stop
  };
  /// An output older than this at the controller's instant is stale (unusable).
  static constexpr core::Time kStaleAfterNs = 100'000'000;
  /// How long the estimate must rest at land_z_m before the pilot disarms.
  static constexpr core::Time kLandedAfterNs = 1'000'000'000;
  /// Joining the mission at the handover or after a failsafe: the reference starts where
  /// the robot believes it is and closes on the mission's at this speed, over the
  /// mission's own motion. A step onto a reference that has moved on saturates the
  /// actuators and the tilt servos, and the overshoot it leaves is not flown out (a
  /// figure-eight from t = 0 handed over 1.1 m behind its reference: 33 contacts).
  static constexpr double kJoinSpeedMps = 0.5;
  Command Fly(core::Time t_ns, const estimator::EstimatorOutput& newest,
              const sim::Reference& mission);

  /// The estimate of B in W as the controller saw it at its last update.
  const std::optional<sim::RobotState>& last_state() const { return last_state_; }
  FlightMode mode() const { return mode_; }
  const std::vector<FlightEvent>& events() const { return events_; }
  /// T_ML the newest state was flown through: the estimate's, else the launch pad's.
  Eigen::Isometry3d T_ML(const estimator::EstimatorOutput& o) const;

 private:
  sim::RobotState StateOf(core::Time t_ns, const estimator::EstimatorOutput& o) const;
  /// Moves `reference` (the mission's, at t_ns) by what is left of the join offset.
  void JoinMission(core::Time t_ns, const Eigen::Vector3d& p_WB_believed, sim::Reference* reference);

  FailsafeConfig failsafe_;
  Eigen::Isometry3d T_BI_;
  Eigen::Isometry3d T_MB_launch_;
  /// The launch pad's registration of L, for estimates without T_ML.
  Eigen::Isometry3d T_ML_launch_ = Eigen::Isometry3d::Identity();
  bool handed_over_ = false;
  FlightMode mode_ = FlightMode::kTruth;
  std::optional<double> position_std_m_;  // from the newest output that carried one
  core::Time failsafe_start_ns_ = 0;
  std::optional<core::Time> at_land_z_since_ns_;
  sim::Reference hold_;
  /// Reference minus mission while joining it (see kJoinSpeedMps); unset once joined.
  std::optional<Eigen::Vector3d> join_offset_m_;
  core::Time last_join_ns_ = 0;
  std::optional<sim::RobotState> last_state_;
  std::vector<FlightEvent> events_;
};

}  // namespace tofu::harness
