#pragma once
// A method's name and what it fuses (ReplayMethod), parsed against a log's streams or a
// scenario's sensor names, and the estimator's defaults for a log: options (IMU noise,
// sample convention) and the specifications of its sensors.

#include <optional>
#include <string>
#include <vector>

#include "estimator/consensus_estimator.h"
#include "estimator/multi_graph_estimator.h"
#include "replay/estimation_config.h"
#include "replay/recorded_log.h"

namespace tofu::replay {

/// What a method fuses. Names:
///  - "single:<sensor>": one sensor all the time; "fuse:<a>+<b>": several all the time;
///  - "imu_only": nothing (IMU propagation from the first state);
///  - "naive": every sensor all the time, with the true frame transforms T_AL (the seed
///    paper's naive baseline, given "the ground truth transform between the Leica and
///    local frame");
///  - "consensus": the sensors chosen online by consensus (estimator/consensus_estimator.h),
///    fusing as the scenario's `consensus: {fuse: ...}` says; "consensus:pair_member" and
///    "consensus:consistent_set" choose that explicitly (both can run in one flight);
///  - "oracle": at every sample, exactly the sensors the ground-truth labels call healthy
///    (no fault, no condition active: replay/labels.h), with the estimated alignments as
///    consensus has them: what a perfect fault detector would fuse, not a bound on
///    selection (a sensor labelled faulty can still help, a healthy one can hurt: consensus
///    beats it in some suite scenarios, docs/RESULTS.md). A log without labels.csv (a real
///    log) has no label, so the oracle fuses everything there.
/// A suffix "@clean" runs the method on the un-faulted streams (sensors/clean/): the
/// paper's reference is "single:vio@clean".
///  - "external:<name>", "plugin:<name>": a user's estimator, a process speaking the
///    protocol of docs/INTERFACE.md or a C++ plug-in, as the scenario's `external:` or
///    `plugins:` entry <name> says (EstimationConfig::clients).
struct ReplayMethod {
  enum class Kind { kFixed, kNaive, kConsensus, kOracle, kClient };
  std::string name;
  Kind kind = Kind::kFixed;
  std::optional<ClientSpec> client;  ///< kClient
  std::vector<std::string> fused;  ///< kFixed, kNaive and kOracle: the sensors it may fuse
  bool clean_streams = false;      ///< "@clean"
  /// kConsensus: the fusion rule when the name states one (else the scenario's).
  std::optional<estimator::ConsensusPolicy> policy;
};

/// Parses a method name against the log's streams; throws core::InputError naming the
/// method, the unknown sensor and the known ones.
/// `clients`: the scenario's users' estimators (external:/plugin: names).
ReplayMethod ParseReplayMethod(const std::string& name, const RecordedLog& log,
                               const std::vector<ClientSpec>& clients = {});
/// The same check against a list of sensor names (a scenario's, before any run): returns
/// an error message, or nullopt when the name is a valid method for these sensors.
std::optional<std::string> CheckMethodName(const std::string& name,
                                           const std::vector<std::string>& sensors,
                                           const std::vector<ClientSpec>& clients = {});

/// The names of the log's non-IMU streams, in the log's order: the sensors a method may
/// name.
std::vector<std::string> SensorNamesOf(const RecordedLog& log);

/// Datasheet (and Kalibr at-rest) white-noise densities describe an IMU on a table; on a
/// flying multicopter, rotor vibration, its aliasing and unmodelled scale and misalignment
/// errors make the effective noise an order of magnitude larger (tofu's own IMU model adds
/// ~0.16 m/s² RMS of rotor vibration, 5x its white noise at 400 Hz). Visual-inertial
/// systems configure EuRoC's ADIS16448 accordingly (VINS-Mono: 40x and 24x the datasheet).
/// 10x is what docs/RESULTS.md measured best on both tofu's runs and EuRoC V1_02;
/// `tofu estimate --imu-noise-scale` overrides it (DefaultEstimatorOptions applies it).
inline constexpr double kInFlightImuNoiseScale = 10.0;

/// Estimator options for a log: IMU noise from its calibration when known (else the
/// ADIS16448 datasheet), inflated 10x for flight (rotor vibration), the IMU sample
/// convention of its layout (tofu's simulated IMU averages over each interval; a real
/// log's samples are instantaneous).
estimator::MultiGraphEstimatorOptions DefaultEstimatorOptions(const RecordedLog& log);
/// Sensor specifications (kinds, mounts) of the log's non-IMU streams.
std::vector<estimator::SensorSpec> SensorSpecsOf(const RecordedLog& log);

/// A method name as used in file names: ':', '+', '/' and ' ' become '_'.
std::string MethodFileStem(const std::string& method);

}  // namespace tofu::replay
