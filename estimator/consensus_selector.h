#pragma once
// Consensus-based sensor selection of Lanegger et al. (Sec. "Consensus finding" and
// "Consensus-based Sensor Selection"): from the consistency matrix of N sensors (CM
// distance of every pair, m/s) and of each sensor against the local estimate, decide which
// sensor(s) the local graph fuses, which are faulty and which delivered nothing.
//
// Pure decision logic: no metric computation (estimator/consistency_matrix.h), no I/O.
//
// Eligible for fusion: available, not excluded, not awaiting re-admission, and fusable
// (ConsensusInput::fusable: e.g. a position sensor whose frame alignment is being
// re-estimated still gives evidence through its velocity, but cannot be fused yet).
//
// Rules, in the order they are applied at each Decide():
//  1. Pair judgement. A pair is consistent when its value < the applicable threshold
//     (leave_threshold if either sensor is fused now and hysteresis is on, else threshold),
//     inconsistent when >=, unknown when nullopt/NaN/negative (not evidence either way).
//     A sensor against the local estimate likewise (leave_threshold when it is fused).
//  2. Cross pattern (>= 3 available). Sensors are peeled off one by one while some
//     sensor is inconsistent with a strict majority of the remaining sensors that have a
//     known value with it (the worst first: largest inconsistent fraction, then count,
//     then distance to the local estimate, then sum of pair values, then lower priority),
//     as long as >= 3 remain. The peeled sensors are excluded only if the sensors left are
//     mostly consistent among themselves (more consistent than inconsistent known pairs);
//     otherwise there is no consensus and nothing is excluded by this rule.
//  3. Re-admission dwell (min_dwell_ns > 0): a sensor that was excluded stays excluded
//     until it has had positive evidence (a consistent pair with a non-faulty available
//     sensor, or consistency with the local estimate) for min_dwell_ns without interruption.
//     It still serves as evidence (pairs) for the others.
//  4. Selection among the eligible sensors (available, not excluded):
//     - kPairMember (the paper): if some eligible pair is consistent, the currently fused
//       sensor is kept when it is in such a pair (no needless switching); otherwise one
//       sensor of the most consistent pair (smallest value) is fused, chosen by priority.
//       With return_to_priority (beyond the paper), a fused sensor gives way, outside the
//       dwell, to a sensor earlier in the priority list that has a consistent eligible
//       partner: the preferred sensor is fused again once it has recovered.
//     - kConsistentSet: the largest eligible subset whose known pairs are all
//       consistent and in which every member has at least one known consistent pair
//       (unknown alone is not agreement); ties: smaller sum of known values, then priority.
//       A sensor joins the fused set only with values < threshold (leave_threshold applies
//       between sensors that are both fused).
//     - No consistent eligible pair but known pairs (the degenerate case, e.g. two
//       inconsistent sensors): resolved against the local estimate. The fused sensor is
//       kept unless it is known-inconsistent with local; else the eligible sensor
//       consistent with local with the smallest value is fused; else (within the dwell) the
//       fused one is held; else one with unknown local value by priority; else (all
//       inconsistent with local) the one with the smallest local value. Sensors
//       inconsistent with the winner are excluded.
//     - No pair evidence at all (e.g. one sensor): each sensor is judged against local;
//       known-inconsistent ones are excluded; the fused one is kept, else by priority.
//  5. Dwell (min_dwell_ns > 0): within min_dwell_ns of the last change of the fused set,
//     a fused sensor that is still eligible is not replaced for preference; dropping a
//     sensor that became unavailable or was excluded (faulty) happens at once.
//
// Not thread-safe; one owner.

#include <cstdint>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "core/time.h"

namespace tofu::estimator {

enum class ConsensusPolicy {
  kPairMember,     ///< fuse ONE sensor of the most consistent pair (the paper)
  kConsistentSet,  ///< fuse every sensor of the largest mutually consistent set
};

/// "pair_member", "consistent_set" (the scenario key `consensus: {fuse: ...}`).
std::string_view ConsensusPolicyName(ConsensusPolicy policy);
/// Inverse of ConsensusPolicyName; nullopt for an unknown name.
std::optional<ConsensusPolicy> ConsensusPolicyFromName(std::string_view name);

struct ConsensusOptions {
  /// CM distance (m/s): a pair is consistent when value < threshold (paper: 0.1).
  double threshold = 0.1;
  /// Hysteresis (nullopt = off = paper): a sensor that is currently fused stays consistent
  /// while its values are below leave_threshold (>= threshold, m/s); a sensor that is not
  /// fused must get below `threshold` to enter.
  std::optional<double> leave_threshold;
  /// Minimum dwell (ns, 0 = paper): after the fused set changed, it is not changed again
  /// for preference within min_dwell_ns, and an excluded sensor is re-admitted only after
  /// it was consistent for min_dwell_ns without interruption. A fused sensor that becomes
  /// unavailable or is detected faulty is still dropped at once (safety beats dwell).
  core::Time min_dwell_ns = 0;
  ConsensusPolicy policy = ConsensusPolicy::kPairMember;
  /// kPairMember: a fused sensor gives way (outside the dwell) to a sensor earlier in the
  /// priority list that is eligible and in a consistent pair; false = the paper, which
  /// keeps the fused sensor while it stays consistent.
  bool return_to_priority = true;
  /// Which sensor of the chosen pair to fuse (paper policy), and tie-breaks elsewhere:
  /// earlier = preferred; sensors not listed come after, in the order given to the
  /// constructor.
  std::vector<std::string> priority;

  /// True when the options are usable; otherwise false with the broken constraint in
  /// *why (if why is not null).
  bool IsValid(std::string* why = nullptr) const;
};

/// One evaluation's input: per sensor whether it delivered data in the window, the pair
/// values of the consistency matrix (sensor i vs j) and each sensor vs the local estimate;
/// std::nullopt = unavailable. NaN, infinite and negative values count as unavailable.
struct ConsensusInput {
  core::Time t_ns = 0;
  std::vector<bool> available;  ///< size N
  /// N*(N-1)/2 values (m/s), order (0,1),(0,2),...,(0,N-1),(1,2),... as
  /// ConsistencyMatrix::PairIndex.
  std::vector<std::optional<double>> pair;
  std::vector<std::optional<double>> vs_local;  ///< size N (m/s)
  /// Size N, or empty (= every sensor fusable): whether the sensor could constrain the
  /// estimate now. A sensor that is available but not fusable counts as evidence only.
  std::vector<bool> fusable;
  /// Empty, or N*(N-1)/2 in the order of `pair`: the pair failed a test beyond its value
  /// (ConsensusEstimatorOptions::bias_window_ns, a bias the window cannot see) and is
  /// inconsistent whatever its value says.
  std::vector<bool> pair_biased;
};

struct ConsensusDecision {
  core::Time t_ns = 0;
  std::vector<std::string> fused;        ///< sensors to fuse now, by priority (empty: IMU-only)
  std::vector<std::string> excluded;     ///< available but not trusted (faulty or waiting)
  /// The part of `excluded` judged inconsistent by this decision's values (cross pattern,
  /// inconsistent with the fused sensor), not merely awaiting re-admission.
  std::vector<std::string> inconsistent;
  /// Sensors that could be fused now: available, trusted (not excluded, not waiting) and
  /// fusable. A recovered sensor is re-admitted once it is here again.
  std::vector<std::string> eligible;
  std::vector<std::string> unavailable;  ///< available[i] == false
  std::string reason;                    ///< one line, human readable, no commas (CSV)
  bool changed = false;                  ///< fused set differs from the previous decision
};

class ConsensusSelector final {
 public:
  /// Throws std::invalid_argument for invalid options, empty/duplicate names, a priority
  /// name not in sensors, and more than kMaxSensorsLargestSet sensors with the
  /// largest-set policy.
  ConsensusSelector(std::vector<std::string> sensors, ConsensusOptions options = {});

  /// The largest-set policy enumerates subsets (2^N); N is bounded for it.
  static constexpr int kMaxSensorsLargestSet = 16;

  /// One decision. Throws std::invalid_argument when a vector's size does not match N or
  /// t_ns is earlier than the previous decision's.
  ConsensusDecision Decide(const ConsensusInput& input);

  /// The fused sensors of the last decision (empty before the first).
  const std::vector<std::string>& fused() const { return fused_; }
  /// Number of decisions with changed == true after the first non-empty fused set.
  int switches() const { return switches_; }

  const std::vector<std::string>& sensors() const { return sensors_; }
  const ConsensusOptions& options() const { return options_; }
  /// Input values ignored because they were NaN, infinite or negative.
  int64_t ignored_values() const { return ignored_values_; }

 private:
  // The decision's lists from the selection (per sensor: available, in the cross pattern,
  // waiting for re-admission, eligible, fused, excluded), and the state it leaves:
  // quarantine, the fused set, the switch count.
  void Conclude(const std::vector<bool>& available, const std::vector<bool>& cross,
                const std::vector<bool>& waiting, const std::vector<bool>& eligible,
                const std::vector<bool>& fused, const std::vector<bool>& excluded,
                ConsensusDecision& decision);

  std::vector<std::string> sensors_;
  ConsensusOptions options_;
  std::vector<int> rank_;  // priority rank per sensor, 0 = most preferred
  std::vector<bool> fused_mask_;
  std::vector<std::string> fused_;
  // Re-admission dwell: excluded sensors waiting, and since when they are clean.
  std::vector<bool> quarantined_;
  std::vector<std::optional<core::Time>> clean_since_ns_;
  std::optional<core::Time> last_t_ns_;
  std::optional<core::Time> last_change_ns_;
  int switches_ = 0;
  bool had_fused_ = false;
  int64_t ignored_values_ = 0;
};

}  // namespace tofu::estimator
