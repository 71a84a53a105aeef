// Consistency metrics and the consistency matrix (estimator/consistency*.h): one CM and
// one KL between two 200-sample windows, and a full 10 Hz matrix update at realistic
// rates (IMU-derived local estimate 200 Hz, VIO 200 Hz, LIO 10 Hz, total station 20 Hz,
// GNSS 10 Hz; optionally a sixth stream at 30 Hz) over a 1 s window. Target: <= 50 us
// per CM matrix update on one core.
//
//   build/bench/bench_consistency --benchmark_repetitions=3

#include <algorithm>
#include <cmath>
#include <cstddef>
#include <string>
#include <vector>

#include <benchmark/benchmark.h>
#include <Eigen/Core>

#include "core/random.h"
#include "core/time.h"
#include "estimator/consistency.h"
#include "estimator/consistency_matrix.h"

namespace {

using tofu::core::Time;
using tofu::estimator::ConsistencyMatrix;
using tofu::estimator::ConsistencyMatrixOptions;
using tofu::estimator::ConsistencyMetric;

std::vector<double> Sample(std::size_t n, double mean, const char* name) {
  tofu::core::RandomStream random(1, name);
  std::vector<double> x(n);
  for (double& value : x) value = mean + 0.3 * random.Normal();
  return x;
}

void BM_CramerVonMises_200x200(benchmark::State& state) {
  const std::vector<double> p = Sample(200, 0.0, "p");
  const std::vector<double> q = Sample(200, 0.05, "q");
  for (auto _ : state) {
    benchmark::DoNotOptimize(tofu::estimator::CramerVonMisesDistance(p, q));
  }
}
BENCHMARK(BM_CramerVonMises_200x200);

void BM_CramerVonMisesSortedKernel_200x200(benchmark::State& state) {
  std::vector<double> p = Sample(200, 0.0, "p");
  std::vector<double> q = Sample(200, 0.05, "q");
  std::sort(p.begin(), p.end());
  std::sort(q.begin(), q.end());
  for (auto _ : state) {
    benchmark::DoNotOptimize(tofu::estimator::CramerVonMisesDistanceSorted(p, q));
  }
}
BENCHMARK(BM_CramerVonMisesSortedKernel_200x200);

void BM_KlDivergence_200x200(benchmark::State& state) {
  const std::vector<double> p = Sample(200, 0.0, "p");
  const std::vector<double> q = Sample(200, 0.05, "q");
  for (auto _ : state) {
    benchmark::DoNotOptimize(tofu::estimator::KlDivergence(p, q));
  }
}
BENCHMARK(BM_KlDivergence_200x200);

// Streams of the matrix benchmark: rate and a velocity offset (one inconsistent sensor).
struct StreamSpec {
  const char* name;
  double rate_hz;
};
constexpr StreamSpec kStreams[] = {{"local", 200.0}, {"vio", 200.0}, {"lio", 10.0},
                                   {"total_station", 20.0}, {"gnss", 10.0},
                                   {"extra", 30.0}};

// Feeds the matrix from t_begin (exclusive) to t_end (inclusive) with a smooth motion
// plus precomputed noise.
class Feeder {
 public:
  explicit Feeder(int streams) : streams_(streams) {
    tofu::core::RandomStream random(2, "noise");
    noise_.resize(4096);
    for (auto& n : noise_) n = 0.02 * Eigen::Vector3d(random.Normal(), random.Normal(),
                                                      random.Normal());
    next_.assign(static_cast<std::size_t>(streams), 0);
    for (int s = 0; s < streams; ++s) {
      periods_.push_back(tofu::core::PeriodFromRate(kStreams[s].rate_hz));
      next_[static_cast<std::size_t>(s)] = periods_.back() + s * 1'000'000;
    }
  }

  void Feed(ConsistencyMatrix& matrix, Time t_end) {
    for (int s = 0; s < streams_; ++s) {
      Time& t = next_[static_cast<std::size_t>(s)];
      for (; t <= t_end; t += periods_[static_cast<std::size_t>(s)]) {
        const double ts = tofu::core::TimeToSeconds(t);
        const Eigen::Vector3d v(std::sin(ts), 0.5 * std::cos(1.3 * ts), 0.2);
        matrix.Add(s, t, v + noise_[counter_++ % noise_.size()] +
                             Eigen::Vector3d(s == 4 ? 0.3 : 0.0, 0.0, 0.0));
      }
    }
  }

 private:
  int streams_;
  std::vector<Eigen::Vector3d> noise_;
  std::vector<Time> periods_;
  std::vector<Time> next_;
  std::size_t counter_ = 0;
};

ConsistencyMatrix MakeMatrix(int streams, ConsistencyMetric metric) {
  std::vector<std::string> names;
  for (int s = 0; s < streams; ++s) names.emplace_back(kStreams[s].name);
  ConsistencyMatrixOptions options;
  options.metric = metric;
  return ConsistencyMatrix(names, options);
}

// One 10 Hz update: 100 ms of samples into every stream, then Evaluate over the last 1 s.
void MatrixUpdate(benchmark::State& state, ConsistencyMetric metric) {
  const int streams = static_cast<int>(state.range(0));
  ConsistencyMatrix matrix = MakeMatrix(streams, metric);
  Feeder feeder(streams);
  Time t = 3 * tofu::core::kNanosecondsPerSecond;
  feeder.Feed(matrix, t);  // warm-up: 3 s of history, buffers grown
  matrix.Evaluate(t);
  for (auto _ : state) {
    t += 100'000'000;
    feeder.Feed(matrix, t);
    benchmark::DoNotOptimize(matrix.Evaluate(t).data());
  }
  state.counters["pairs"] = static_cast<double>(matrix.Values().size());
}
void BM_MatrixUpdateCm(benchmark::State& state) { MatrixUpdate(state, ConsistencyMetric::kCm); }
BENCHMARK(BM_MatrixUpdateCm)->Arg(5)->Arg(6);
void BM_MatrixUpdateMae(benchmark::State& state) {
  MatrixUpdate(state, ConsistencyMetric::kMae);
}
BENCHMARK(BM_MatrixUpdateMae)->Arg(5);
void BM_MatrixUpdateKl(benchmark::State& state) { MatrixUpdate(state, ConsistencyMetric::kKl); }
BENCHMARK(BM_MatrixUpdateKl)->Arg(5);

// Evaluate alone on a fixed state (no new samples).
void BM_MatrixEvaluateCm(benchmark::State& state) {
  const int streams = static_cast<int>(state.range(0));
  ConsistencyMatrix matrix = MakeMatrix(streams, ConsistencyMetric::kCm);
  Feeder feeder(streams);
  const Time t = 3 * tofu::core::kNanosecondsPerSecond;
  feeder.Feed(matrix, t);
  for (auto _ : state) benchmark::DoNotOptimize(matrix.Evaluate(t).data());
}
BENCHMARK(BM_MatrixEvaluateCm)->Arg(5)->Arg(6);

// Only the Add calls of one update (the part of BM_MatrixUpdateCm that is not Evaluate).
void BM_MatrixFeedOnly(benchmark::State& state) {
  const int streams = static_cast<int>(state.range(0));
  ConsistencyMatrix matrix = MakeMatrix(streams, ConsistencyMetric::kCm);
  Feeder feeder(streams);
  Time t = 3 * tofu::core::kNanosecondsPerSecond;
  feeder.Feed(matrix, t);
  for (auto _ : state) {
    t += 100'000'000;
    feeder.Feed(matrix, t);
  }
}
BENCHMARK(BM_MatrixFeedOnly)->Arg(5);

}  // namespace

// The bias test of one sensor pair (consistency.h WindowMeanDifference) over 10 s of the
// 50 Hz grid (500 pairs): the plain mean (arg 0) and with the frame rotation fitted
// beside it (arg 1). Consensus runs it for each pair over three windows at 10 Hz.
void BM_WindowMeanDifference10s(benchmark::State& state) {
  tofu::core::RandomStream random(2, "bias");
  tofu::estimator::VelocitySeries a, b;
  for (Time t = 20'000'000; t <= 10'000'000'000; t += 20'000'000) {
    const double s = tofu::core::TimeToSeconds(t);
    const Eigen::Vector3d v(std::sin(s), 0.5 * std::cos(0.7 * s), 0.1);
    for (auto* series : {&a, &b}) {
      series->t_ns.push_back(t);
      series->v_mps.push_back(v + 0.02 * Eigen::Vector3d(random.Normal(), random.Normal(),
                                                         random.Normal()));
      series->cov_m2ps2.push_back(Eigen::Matrix3d::Identity() * 4e-4);
    }
  }
  tofu::estimator::MeanDifferenceOptions options;
  options.estimate_rotation = state.range(0) != 0;
  for (auto _ : state) {
    benchmark::DoNotOptimize(
        tofu::estimator::WindowMeanDifference(a, b, 0, 10'000'000'000, options));
  }
}
BENCHMARK(BM_WindowMeanDifference10s)->ArgName("rotation")->Arg(0)->Arg(1);

BENCHMARK_MAIN();
