#pragma once
// The consistency matrix of Lanegger et al. (Sec. 2.3, "Consensus-based sensor
// selection"): N named velocity streams, already expressed in one common frame, and the
// metric of consistency.h for every pair over a sliding window. The local estimate is
// simply one more stream (by convention named "local"); the pairs (sensor, local) break
// the tie when only two sensors are left.
//
// Transforming each sensor's velocity into the common frame (paper eq. 1, see
// estimator/velocity.h: rotation chain, lever arm, reference-frame alignment) is the
// caller's job: the matrix compares the numbers it is given, axis by axis.
//
// Library code: no MuJoCo, no simulator, no I/O.

#include <cstddef>
#include <cstdint>
#include <optional>
#include <span>
#include <string>
#include <string_view>
#include <vector>

#include <Eigen/Core>

#include "core/time.h"
#include "estimator/consistency.h"

namespace tofu::estimator {

/// Kernel of CramerVonMisesDistance (eq. 5) for samples that are already sorted in
/// ascending order, finite and non-empty: one merge pass, O(n + m), no allocation.
/// Returns NaN when a sample is empty. (Declared here rather than in the frozen
/// consistency.h; defined in consistency.cc next to CramerVonMisesDistance.)
double CramerVonMisesDistanceSorted(std::span<const double> p_sorted,
                                    std::span<const double> q_sorted);

struct ConsistencyMatrixOptions {
  ConsistencyMetric metric = ConsistencyMetric::kCm;
  /// Window, standardisation, KL bandwidth and min_samples, as in WindowConsistency.
  ConsistencyOptions consistency;
  /// Samples older than (newest sample, or evaluation time) − history_ns may be dropped;
  /// a stream keeps at most about 2 × history_ns of samples. Must be ≥ the window; make
  /// it ≥ window + the lag of Evaluate's t_eval behind the newest samples.
  core::Time history_ns = 2'000'000'000;
  /// Hard cap on the samples kept per stream (memory bound even for absurd rates); when
  /// reached, the oldest half is dropped and counted in StreamCounters::dropped.
  std::size_t max_samples_per_stream = 8192;

  /// True when the options are usable; otherwise false with the broken constraint in
  /// *why (if why is not null).
  bool IsValid(std::string* why = nullptr) const;
};

/// What Add did with a sample.
enum class AddResult {
  kAccepted,
  kRejectedNonFinite,     ///< a velocity component was NaN or infinite
  kRejectedOutOfOrder,    ///< timestamp not after the stream's last accepted one
  kRejectedUnknownStream  ///< stream index out of range
};

/// Per-stream bookkeeping; rejected samples never enter the stream.
struct StreamCounters {
  int64_t accepted = 0;
  int64_t rejected_non_finite = 0;
  int64_t rejected_out_of_order = 0;
  int64_t dropped = 0;  ///< accepted samples later dropped as too old (or by the cap)
};

/// The value of one pair (i < j) at the last evaluation; nullopt = unavailable (a stream
/// has fewer than min_samples samples in the window, or nothing was evaluated yet).
struct PairConsistency {
  int i = 0;
  int j = 0;
  std::optional<double> value;
};

/// Pairwise consistency of N velocity streams, sized for 10 Hz evaluations of ~6 streams
/// at up to a few hundred Hz: buffers are reused, so after warm-up neither Add nor
/// Evaluate allocates (the KL metric aside, which uses per-thread scratch too).
/// Not thread-safe; one owner.
class ConsistencyMatrix final {
 public:
  /// Throws std::invalid_argument if options are invalid or a name repeats or is empty.
  explicit ConsistencyMatrix(std::vector<std::string> stream_names,
                             ConsistencyMatrixOptions options = {});

  int StreamCount() const { return static_cast<int>(streams_.size()); }
  const std::string& StreamName(int stream) const;
  std::optional<int> StreamIndex(std::string_view name) const;
  const ConsistencyMatrixOptions& options() const { return options_; }

  /// Appends one velocity sample (m/s, in the common frame) to a stream, with its stated
  /// covariance [m²/s²] when the stream states one (kNis; a stream states covariances
  /// from its first accepted sample on, or never). NaN/inf values, timestamps not strictly
  /// after the stream's last accepted one and unknown streams are rejected and counted,
  /// never stored.
  AddResult Add(int stream, core::Time t_ns, const Eigen::Vector3d& v_mps,
                const Eigen::Matrix3d* cov_m2ps2 = nullptr);

  /// Computes every pair (i < j) over the window (t_eval − window, t_eval] and returns
  /// them in the order (0,1), (0,2), …, (0,N−1), (1,2), …; the reference stays valid
  /// until the next Evaluate. Samples older than t_eval − history are dropped.
  const std::vector<PairConsistency>& Evaluate(core::Time t_eval_ns);

  /// The pairs of the last Evaluate (all unavailable before the first one).
  const std::vector<PairConsistency>& Values() const { return pairs_; }
  /// Value of the pair {i, j} at the last Evaluate, in either order; nullopt if
  /// unavailable, i == j or an index is out of range.
  std::optional<double> Value(int i, int j) const;
  /// Position of pair (i, j), i < j < n, in the vector returned by Evaluate.
  static int PairIndex(int i, int j, int n);

  const StreamCounters& Counters(int stream) const;
  /// Samples currently stored (the memory bound).
  std::size_t StoredSamples(int stream) const;
  /// The stored samples of a stream (for inspection and tests).
  const VelocitySeries& Samples(int stream) const;
  /// Samples passed to Add with a stream index out of range.
  int64_t rejected_unknown_stream() const { return rejected_unknown_stream_; }

 private:
  struct Stream {
    std::string name;
    VelocitySeries samples;
    StreamCounters counters;
    bool has_last = false;
    core::Time last_t_ns = 0;
    bool states_covariance = false;  // samples.cov_m2ps2 runs beside the samples
    // Samples erased from the front so far: absolute index = base + index in samples.
    std::size_t base = 0;
    // Per evaluation: the window [lo, hi) into samples, and for CM the sorted axis values
    // and per-axis mean and sum of squared deviations (for pooled standardisation).
    std::size_t lo = 0;
    std::size_t hi = 0;
    bool available = false;
    std::vector<double> sorted[3];
    Eigen::Vector3d mean = Eigen::Vector3d::Zero();
    Eigen::Vector3d m2 = Eigen::Vector3d::Zero();
    // Absolute window [prepared_lo, prepared_hi) that `sorted` holds, for the incremental
    // update of the next evaluation.
    bool prepared = false;
    std::size_t prepared_lo = 0;
    std::size_t prepared_hi = 0;
  };

  // Erases samples with t <= cut once the oldest is older than cut − history (amortised).
  void DropOld(Stream& stream, core::Time cut_ns);
  // Erases the oldest `count` samples.
  static void EraseFront(Stream& stream, std::size_t count);
  // Sorted axis values of the stream's window: when the window only slid forward since
  // the last evaluation, the values that left are removed and the new ones merged in
  // (O(n + k log k) for k changes) instead of sorting all n again.
  void PrepareCm(Stream& stream);
  double PairCm(const Stream& a, const Stream& b) const;

  ConsistencyMatrixOptions options_;
  std::vector<Stream> streams_;
  std::vector<PairConsistency> pairs_;
  int64_t rejected_unknown_stream_ = 0;
  // Scratch of PrepareCm, reused.
  std::vector<double> removed_;
  std::vector<double> added_;
  std::vector<double> merged_;
};

}  // namespace tofu::estimator
