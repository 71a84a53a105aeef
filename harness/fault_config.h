#pragma once
// Private to harness: scheduled faults in YAML. `faults:` is a list of maps, one fault
// each; the keys allowed depend on the kind:
//
//   faults:
//     - {sensor: vio, kind: divergence, start_s: 100, end_s: 140,
//        axis: [0, 1, 0], initial_velocity_mps: 0.01, time_constant_s: 10}
//
//   every kind          sensor (required), kind (required), start_s (default 0),
//                       end_s (default: open, until the run's end)
//   misalignment        rpy_deg, translation_m
//   non_gaussian_noise  white_std_m, brown_std_m_per_sqrt_s, brown_time_constant_s
//                       (absent: an unbounded random walk)
//   divergence          axis, initial_velocity_mps, time_constant_s
//   dropout, freeze     (none)
//   delay               delay_s, arrival_delay_s
//   jump                translation_m, rpy_deg
//   outliers            rate_hz, scale_m, rotation_scale_deg, acc_scale_mps2,
//                       gyro_scale_degps, degrees_of_freedom
//
// Semantics and defaults: sim/faults.h.

#include <map>
#include <string>
#include <vector>

#include <yaml-cpp/yaml.h>

#include "harness/yaml_reader.h"
#include "sim/faults.h"

namespace tofu::harness::internal {

/// Reads one fault map (strict): an unknown kind lists the kinds; a key not allowed for
/// the kind names the line, the key path and the kind's keys; the window must lie in the
/// run, 0 <= start_s < end_s <= run_duration_s. Does not check that `sensor` exists.
sim::FaultSpec ReadFaultSpec(const YamlValue& value, double run_duration_s);

/// Reads the `faults:` list and checks each fault against the scenario's sensors: the
/// sensor must exist (error at `sensor`, listing them) and the kind must apply to its
/// measurement type (sim::CheckFaultApplies; error at `kind`).
std::vector<sim::FaultSpec> ReadFaults(const YamlValue& list, double run_duration_s,
                                       const std::map<std::string, core::MeasurementKind>& sensors);

/// Emits one fault as a full map (BeginMap ... EndMap) with every key of its kind; an open
/// end_s and an infinite brown_time_constant_s are written by leaving the key out.
void EmitFaultSpec(YAML::Emitter& out, const sim::FaultSpec& spec);

}  // namespace tofu::harness::internal
