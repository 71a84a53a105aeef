#include "estimator/consistency_matrix.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <stdexcept>
#include <utility>

namespace tofu::estimator {

bool ConsistencyMatrixOptions::IsValid(std::string* why) const {
  auto fail = [why](std::string message) {
    if (why != nullptr) *why = std::move(message);
    return false;
  };
  if (metric != ConsistencyMetric::kMae && metric != ConsistencyMetric::kPcc &&
      metric != ConsistencyMetric::kKl && metric != ConsistencyMetric::kCm &&
      metric != ConsistencyMetric::kNis) {
    return fail("metric is not a known ConsistencyMetric");
  }
  if (std::string nested; !consistency.IsValid(&nested)) return fail("consistency." + nested);
  if (history_ns < consistency.window_ns) {
    return fail("history_ns must be at least consistency.window_ns");
  }
  if (max_samples_per_stream < 2) return fail("max_samples_per_stream must be at least 2");
  return true;
}

ConsistencyMatrix::ConsistencyMatrix(std::vector<std::string> stream_names,
                                     ConsistencyMatrixOptions options)
    : options_(std::move(options)) {
  std::string why;
  if (!options_.IsValid(&why)) {
    throw std::invalid_argument("ConsistencyMatrixOptions: " + why);
  }
  streams_.resize(stream_names.size());
  for (std::size_t s = 0; s < stream_names.size(); ++s) {
    if (stream_names[s].empty()) {
      throw std::invalid_argument("ConsistencyMatrix: empty stream name");
    }
    for (std::size_t r = 0; r < s; ++r) {
      if (streams_[r].name == stream_names[s]) {
        std::string message = "ConsistencyMatrix: repeated stream name '";
        message += stream_names[s];
        message += "'";
        throw std::invalid_argument(message);
      }
    }
    streams_[s].name = std::move(stream_names[s]);
  }
  const int n = StreamCount();
  pairs_.reserve(static_cast<std::size_t>(n * (n - 1) / 2));
  for (int i = 0; i < n; ++i) {
    for (int j = i + 1; j < n; ++j) pairs_.push_back(PairConsistency{i, j, std::nullopt});
  }
}

const std::string& ConsistencyMatrix::StreamName(int stream) const {
  return streams_.at(static_cast<std::size_t>(stream)).name;
}

std::optional<int> ConsistencyMatrix::StreamIndex(std::string_view name) const {
  for (int s = 0; s < StreamCount(); ++s) {
    if (streams_[static_cast<std::size_t>(s)].name == name) return s;
  }
  return std::nullopt;
}

const StreamCounters& ConsistencyMatrix::Counters(int stream) const {
  return streams_.at(static_cast<std::size_t>(stream)).counters;
}

std::size_t ConsistencyMatrix::StoredSamples(int stream) const {
  return streams_.at(static_cast<std::size_t>(stream)).samples.t_ns.size();
}

const VelocitySeries& ConsistencyMatrix::Samples(int stream) const {
  return streams_.at(static_cast<std::size_t>(stream)).samples;
}

int ConsistencyMatrix::PairIndex(int i, int j, int n) {
  // Rows 0..i-1 hold (n-1) + (n-2) + ... + (n-i) pairs.
  return i * (2 * n - i - 1) / 2 + (j - i - 1);
}

std::optional<double> ConsistencyMatrix::Value(int i, int j) const {
  const int n = StreamCount();
  if (i == j || i < 0 || j < 0 || i >= n || j >= n) return std::nullopt;
  if (i > j) std::swap(i, j);
  return pairs_[static_cast<std::size_t>(PairIndex(i, j, n))].value;
}

void ConsistencyMatrix::EraseFront(Stream& stream, std::size_t count) {
  tofu::estimator::EraseFront(stream.samples, count);
  stream.base += count;
  stream.counters.dropped += static_cast<int64_t>(count);
}

void ConsistencyMatrix::DropOld(Stream& stream, core::Time cut_ns) {
  const auto& t = stream.samples.t_ns;
  // Erase only once the oldest sample is a whole history older than the cut, so each
  // sample is moved O(1) times on average and the stream spans at most ~2 histories.
  if (t.empty() || t.front() > cut_ns - options_.history_ns) return;
  const auto end = std::upper_bound(t.begin(), t.end(), cut_ns);
  EraseFront(stream, static_cast<std::size_t>(end - t.begin()));
}

AddResult ConsistencyMatrix::Add(int stream_index, core::Time t_ns, const Eigen::Vector3d& v_mps,
                                 const Eigen::Matrix3d* cov_m2ps2) {
  if (stream_index < 0 || stream_index >= StreamCount()) {
    ++rejected_unknown_stream_;
    return AddResult::kRejectedUnknownStream;
  }
  Stream& stream = streams_[static_cast<std::size_t>(stream_index)];
  if (!v_mps.allFinite()) {
    ++stream.counters.rejected_non_finite;
    return AddResult::kRejectedNonFinite;
  }
  if (stream.has_last && t_ns <= stream.last_t_ns) {
    ++stream.counters.rejected_out_of_order;
    return AddResult::kRejectedOutOfOrder;
  }
  stream.has_last = true;
  stream.last_t_ns = t_ns;
  // A stream states covariances from its first sample on, or never; a later sample
  // without one is marked unknown (kNis skips it).
  auto& cov = stream.samples.cov_m2ps2;
  if (stream.counters.accepted == 0) {
    stream.states_covariance = cov_m2ps2 != nullptr;
  }
  if (stream.states_covariance) {
    cov.push_back(cov_m2ps2 != nullptr
                      ? *cov_m2ps2
                      : Eigen::Matrix3d::Constant(std::numeric_limits<double>::quiet_NaN()));
  }
  ++stream.counters.accepted;
  stream.samples.t_ns.push_back(t_ns);
  stream.samples.v_mps.push_back(v_mps);

  DropOld(stream, t_ns - options_.history_ns);
  // Hard cap: drop the oldest half.
  if (stream.samples.t_ns.size() > options_.max_samples_per_stream) {
    EraseFront(stream, stream.samples.t_ns.size() - options_.max_samples_per_stream / 2);
  }
  return AddResult::kAccepted;
}

void ConsistencyMatrix::PrepareCm(Stream& stream) {
  const auto& v = stream.samples.v_mps;
  const std::size_t abs_lo = stream.base + stream.lo;
  const std::size_t abs_hi = stream.base + stream.hi;
  // The previous window [prepared_lo, prepared_hi) can be updated when both ends moved
  // forward, the windows overlap and the samples that left are still stored.
  const bool incremental = stream.prepared && abs_lo >= stream.prepared_lo &&
                           abs_hi >= stream.prepared_hi && abs_lo <= stream.prepared_hi &&
                           stream.prepared_lo >= stream.base;
  for (int axis = 0; axis < 3; ++axis) {
    auto& sorted = stream.sorted[axis];
    bool rebuilt = false;
    if (incremental) {
      removed_.clear();
      added_.clear();
      for (std::size_t k = stream.prepared_lo; k < abs_lo; ++k) {
        removed_.push_back(v[k - stream.base][axis]);
      }
      for (std::size_t k = stream.prepared_hi; k < abs_hi; ++k) {
        added_.push_back(v[k - stream.base][axis]);
      }
      std::sort(removed_.begin(), removed_.end());
      std::sort(added_.begin(), added_.end());
      // One pass: the old values minus the removed ones (a sorted sub-multiset, matched by
      // exact equality: they are the very same numbers), merged with the added ones.
      merged_.clear();
      std::size_t r = 0;
      std::size_t a = 0;
      for (const double x : sorted) {
        if (r < removed_.size() && removed_[r] == x) {
          ++r;
          continue;
        }
        while (a < added_.size() && added_[a] < x) merged_.push_back(added_[a++]);
        merged_.push_back(x);
      }
      while (a < added_.size()) merged_.push_back(added_[a++]);
      // Defensive: if the bookkeeping ever disagreed, fall back to a full sort.
      if (r == removed_.size() && merged_.size() == stream.hi - stream.lo) {
        std::swap(sorted, merged_);
        rebuilt = true;
      }
    }
    if (!rebuilt) {
      sorted.resize(stream.hi - stream.lo);
      for (std::size_t k = 0; k < sorted.size(); ++k) sorted[k] = v[stream.lo + k][axis];
      std::sort(sorted.begin(), sorted.end());
    }
    if (options_.consistency.standardize) {
      double sum = 0.0;
      for (const double x : sorted) sum += x;
      const double mean = sum / static_cast<double>(sorted.size());
      double m2 = 0.0;
      for (const double x : sorted) m2 += (x - mean) * (x - mean);
      stream.mean[axis] = mean;
      stream.m2[axis] = m2;
    }
  }
  stream.prepared = true;
  stream.prepared_lo = abs_lo;
  stream.prepared_hi = abs_hi;
}

double ConsistencyMatrix::PairCm(const Stream& a, const Stream& b) const {
  double total = 0.0;
  for (int axis = 0; axis < 3; ++axis) {
    double d = CramerVonMisesDistanceSorted(a.sorted[axis], b.sorted[axis]);
    if (options_.consistency.standardize) {
      // Pooled standardisation x -> (x − mean) / sd scales ∫(F_P − F_Q)² dx by 1/sd, so
      // D by 1/√sd (the shift does not matter); pooled moments by Chan's combination.
      const auto na = static_cast<double>(a.sorted[axis].size());
      const auto nb = static_cast<double>(b.sorted[axis].size());
      const double delta = b.mean[axis] - a.mean[axis];
      const double m2 = a.m2[axis] + b.m2[axis] + delta * delta * na * nb / (na + nb);
      const double sd = std::sqrt(m2 / (na + nb));
      if (sd > 0.0 && std::isfinite(sd)) d /= std::sqrt(sd);
    }
    total += d;
  }
  return total;
}

const std::vector<PairConsistency>& ConsistencyMatrix::Evaluate(core::Time t_eval_ns) {
  const ConsistencyOptions& copt = options_.consistency;
  const auto min_samples = static_cast<std::size_t>(std::max(1, copt.min_samples));
  const bool cm = options_.metric == ConsistencyMetric::kCm;

  // Window of every stream by binary search; for CM sort each stream's axes once.
  for (Stream& stream : streams_) {
    DropOld(stream, t_eval_ns - options_.history_ns);
    const auto& t = stream.samples.t_ns;
    const auto lo = std::upper_bound(t.begin(), t.end(), t_eval_ns - copt.window_ns);
    const auto hi = std::upper_bound(lo, t.end(), t_eval_ns);
    stream.lo = static_cast<std::size_t>(lo - t.begin());
    stream.hi = static_cast<std::size_t>(hi - t.begin());
    stream.available = stream.hi - stream.lo >= min_samples;
    if (cm && stream.available) PrepareCm(stream);
  }

  for (PairConsistency& pair : pairs_) {
    const Stream& a = streams_[static_cast<std::size_t>(pair.i)];
    const Stream& b = streams_[static_cast<std::size_t>(pair.j)];
    if (!a.available || !b.available) {
      pair.value.reset();
    } else if (cm) {
      pair.value = PairCm(a, b);
    } else {
      pair.value = WindowConsistency(a.samples, b.samples, t_eval_ns, options_.metric, copt);
    }
  }
  return pairs_;
}

}  // namespace tofu::estimator
