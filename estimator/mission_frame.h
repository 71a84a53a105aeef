#pragma once
// The estimator's global output (issue 34): T_ML, the mission frame M in the local frame
// L, beside the smooth local state the controller needs (the paper's L at 200 Hz).
//
// M is the frame the mission is planned in: the survey of the structure, in which the
// absolute sensors' reference frames S are known (a total station set up on surveyed
// points, a GNSS ENU frame tied to the site's survey): T_MS per surveyed sensor. Both M
// and L are gravity aligned, so T_ML is a heading and a translation (4 DoF).
//  - Before any surveyed sensor is trusted, T_ML registers L to the launch pad as an
//    operator would ("the robot is here"): the IMU's pose in M at launch, against the
//    local state at the estimator's first output.
//  - A surveyed sensor the caller does not distrust (the fused ones of a fixed selection;
//    for consensus, every one it has not excluded) is followed when its own live fit of
//    T_SL (4 DoF, the last window_ns of its positions against the local estimate, closed
//    form) explains its positions: the fit's χ² per degree of freedom at most
//    max_fit_chi2_per_dof, its newest position at most max_position_age_ns old. The
//    target is then T_MS T_SL. The paper's frozen T_AL cannot serve: the local graph
//    fuses an absolute sensor as displacements, so L drifts against S while its T_AL is
//    held fixed; and a sensor consensus cannot judge yet (no usable 6-DoF alignment, as
//    on a straight corridor) can still be checked in 4 DoF, both frames being levelled.
//    With several, the one whose target is the most certain at the robot is followed.
//  - The published T_ML moves towards its target at most max_rate_mps at the robot's
//    position and max_rate_radps in heading: a change of source, a sensor's exclusion or
//    the first alignment never makes the state the controller sees jump.
// Library code: Eigen and core/ only.

#include <deque>
#include <map>
#include <optional>
#include <string>
#include <vector>

#include <Eigen/Core>
#include <Eigen/Geometry>

#include "core/time.h"
#include "core/units.h"

namespace tofu::estimator {

struct MissionFrameOptions {
  /// Positions of a trusted surveyed sensor its T_SL is fitted over. Short, because L
  /// drifts against S while the sensor is fused as displacements; long enough to average
  /// its noise (10 s of a 10 Hz RTK GNSS: 100 positions).
  core::Time window_ns = 10'000'000'000;
  core::Time min_pair_spacing_ns = 50'000'000;  ///< fitted at most at 20 Hz
  /// A fit needs this many positions spanning min_span_ns.
  int min_pairs = 10;
  core::Time min_span_ns = 2'000'000'000;
  /// The heading is fitted only when the motion over the window makes it this well known
  /// (1σ); otherwise the published heading is kept and only the translation follows the
  /// sensor (a hover: positions fix where L is, not how it is turned).
  double max_yaw_std_rad = core::RadFromDeg(1.0);
  /// A fit is followed only when it explains the window: Σ wᵢ|rᵢ|² / (3n − 4) at most
  /// this (a jump, a drift or understated noise in the window fails it), and when the
  /// sensor's newest position is at most max_position_age_ns old (occluded: the frame
  /// is held, not dragged by old positions).
  double max_fit_chi2_per_dof = 4.0;
  core::Time max_position_age_ns = 1'000'000'000;
  /// A sensor is followed only while it states its positions to this (the rms of its
  /// stated standard deviations over the window), as a flight stack gates GNSS by its
  /// reported accuracy (PX4 EKF2_REQ_EPH): an RTK-fixed GNSS (1-2 cm) or a total station
  /// (mm) serve, a float (0.3 m) or standalone fix (1.5 m) does not, whose errors are
  /// correlated over the window and would not average out as the fit assumes.
  double max_source_std_m = 0.1;
  /// Prior std of the drift of L against S the fit estimates (what fused odometry does:
  /// cm/s): a short window (a sensor just back in view) does not extrapolate a drift
  /// fitted to noise.
  double drift_rate_std_mps = 0.02;
  /// Added to each position's stated std in the fit: the local estimate's own error over
  /// the window (L drifts against S while the odometries are fused).
  double local_position_std_m = 0.01;
  /// Largest change of the published T_ML: the speed it moves the robot's position in M,
  /// and its heading rate.
  double max_rate_mps = 0.1;
  double max_rate_radps = core::RadFromDeg(2.0);
  /// 1σ of the launch pad registration (the robot's placement on the pad).
  double launch_position_std_m = 0.05;
  double launch_yaw_std_rad = core::RadFromDeg(2.0);

  bool IsValid(std::string* why = nullptr) const;
};

/// What the estimator knows of M before the flight.
struct MissionSurvey {
  /// The IMU's pose in M at launch (the launch pad's surveyed pose through the nominal
  /// mount); unset: no registration before a surveyed sensor is trusted.
  std::optional<Eigen::Isometry3d> T_MI_launch;
  /// Surveyed reference frames of absolute sensors, by sensor name.
  std::map<std::string, Eigen::Isometry3d> T_MS;
};

/// T_ML as published with one output (compact: one per 200 Hz output is kept). The
/// rotation is about z (q_ML stored, not its angle, so that it crosses the api exactly).
struct MissionFrameEstimate {
  Eigen::Vector3d p_ML_m = Eigen::Vector3d::Zero();
  Eigen::Quaterniond q_ML = Eigen::Quaterniond::Identity();
  /// Variances of [x, y, z] (m², in M, at the robot's position) and of the heading (rad²).
  Eigen::Vector4d variance = Eigen::Vector4d::Zero();
  Eigen::Isometry3d T_ML() const;
  double yaw_rad() const;
};

class MissionFrame {
 public:
  MissionFrame(MissionFrameOptions options, MissionSurvey survey);

  bool Surveyed(const std::string& sensor) const;
  /// A position of a surveyed sensor's mount point s in S, as the sensor states it
  /// (covariance in m², in S), and the local estimate of s in L at the same time. Only
  /// positions taken while the sensor is a candidate are given; Forget drops the rest.
  void AddPair(const std::string& sensor, core::Time t_ns, const Eigen::Vector3d& p_Ss,
               const Eigen::Vector3d& p_Ls, const Eigen::Matrix3d& covariance_S);
  /// The sensor stopped being a candidate: its positions no longer describe where L is.
  void Forget(const std::string& sensor);

  /// The local state at an output: the first call registers T_ML to the launch pad (when
  /// the survey has one); each call moves the published frame towards the most certain
  /// candidate's fit that explains its window, within the rate limits.
  void Update(core::Time t_ns, const Eigen::Isometry3d& T_LI,
              const std::vector<std::string>& candidates);
  const std::optional<MissionFrameEstimate>& published() const { return published_; }
  /// The sensor the published frame follows now (empty: none).
  const std::string& source() const { return source_; }

 private:
  struct Pair {
    core::Time t_ns;
    Eigen::Vector3d p_S;
    Eigen::Vector3d p_L;
    double stated_variance_m2;  // the sensor's, isotropic (trace / 3)
    double weight;              // 1 / (stated + local variance)
  };
  struct Target {
    double yaw_rad;
    Eigen::Vector3d p_M_of_robot;  // where the target frame puts the robot
    Eigen::Vector4d variance;
  };
  std::optional<Target> Fit(core::Time t_ns, const std::string& sensor, const Eigen::Vector3d& p_LI,
                            double current_yaw_rad) const;

  MissionFrameOptions options_;
  MissionSurvey survey_;
  std::map<std::string, std::deque<Pair>> pairs_;
  std::optional<MissionFrameEstimate> published_;
  std::string source_;
  core::Time last_update_ns_ = 0;
};

}  // namespace tofu::estimator
