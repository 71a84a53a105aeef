#pragma once
// Sensor models: turn the true motion (and the scene geometry, through ray casts) into
// the streams an estimator consumes. Every model is a small class with its own options
// struct, its own seeded random stream, and the physics written in its doc comment.
// Models are stepped at the physics rate and decide themselves when a sample is due;
// expensive work (ray casts) runs only at the rate each model needs.

#include <array>
#include <cstdint>
#include <string>
#include <string_view>
#include <vector>

#include "core/measurement.h"
#include "core/random.h"
#include "core/time.h"
#include "sim/allocation.h"
#include "sim/world.h"

namespace tofu::sim {

/// Degradations caused by the scene or the motion (not scheduled faults). A model reports
/// the set active now as a bit mask; the harness turns changes into labels.
enum Condition : uint32_t {
  kConditionNone = 0,
  kOccluded = 1u << 0,        ///< line of sight blocked (total station)
  kLockLost = 1u << 1,        ///< tracker lost its target (total station, VIO reset)
  kSearching = 1u << 2,       ///< re-acquiring after a loss
  kFeatureStarved = 1u << 3,  ///< too few visual features (VIO)
  kMotionBlur = 1u << 4,      ///< angular rate beyond the blur limit (VIO)
  kTrackerReset = 1u << 5,    ///< relocalisation with a pose jump (VIO)
  kDegenerate = 1u << 6,      ///< a direction unconstrained by the geometry (LiDAR)
  kFewReturns = 1u << 7,      ///< too few returns, output diverging (LiDAR)
  kNoFix = 1u << 8,           ///< no GNSS solution
  kSingleFix = 1u << 9,       ///< standalone GNSS
  kFloatFix = 1u << 10,       ///< RTK float
  kMultipath = 1u << 11,      ///< structure nearby reflects signals (GNSS)
  kSaturated = 1u << 12,      ///< a measurement axis at its range limit (IMU)
};

/// Name of a single condition bit ("occluded", "lock_lost", ...).
std::string_view ConditionName(Condition condition);
/// Every condition bit, in bit order.
const std::array<Condition, 13>& AllConditions();

/// What a sensor model sees at one physics step. `truth` is the state of B at t_ns
/// (with its accelerations); `world` answers geometric queries (static scene; the
/// robot's own geoms are at the step's end, 1 physics step later).
struct SensorInput {
  const TruthState& truth;
  const World& world;
  /// Actual (motor-filtered) thrust of each rotor [N], arm-major: [arm0 top, arm0 bottom, ...].
  const std::array<double, kArmCount * kRotorsPerArm>& rotor_thrust_N;
};

/// One output sample: what the sensor reports, what a perfect sensor would have reported
/// at the same instant (true error and NEES come from the pair), and when it arrives.
struct SensorSample {
  core::Time t_ns = 0;        ///< time of validity, as stamped by the sensor
  core::Time arrival_ns = 0;  ///< t_ns + latency: when a consumer may see it
  core::Measurement measured;
  core::Measurement truth;
  uint32_t conditions = kConditionNone;  ///< degradations active for this sample
};

/// White noise on the body twist a pose sensor reports: velocity_noise_mps on
/// measured->v_s_s_mps, then angular_rate_noise_radps on measured->omega_s_s_radps, each
/// drawn only when positive (a noise-free option draws nothing from the stream).
void AddTwistWhiteNoise(double velocity_noise_mps, double angular_rate_noise_radps,
                        core::RandomStream& stream, core::PoseMeasurement* measured);

class SensorModel {
 public:
  virtual ~SensorModel() = default;
  /// The stream's name (scenario key, CSV file name).
  virtual const std::string& name() const = 0;
  /// Advances by one physics step; appends the samples whose time of validity falls in
  /// this step to `out`.
  virtual void Step(const SensorInput& input, std::vector<SensorSample>* out) = 0;
  /// Conditions active now (also while no samples come out, e.g. occluded).
  virtual uint32_t conditions() const = 0;
  /// The sensor's reference frame S in W (identity for the IMU): for scoring.
  virtual Eigen::Isometry3d T_WS() const { return Eigen::Isometry3d::Identity(); }
  /// The mount site on the robot.
  virtual const std::string& site() const = 0;
  /// Unit directions in S of the signal sources the sensor needs a line of sight to and
  /// that are fixed for the run (GNSS satellites); empty for the others. Recorded in the
  /// run directory so that a picture of the run needs no model.
  virtual std::vector<Eigen::Vector3d> sky_directions_S() const { return {}; }
};

}  // namespace tofu::sim
