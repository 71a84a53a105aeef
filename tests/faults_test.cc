// Scheduled faults: each kind changes a synthetic stream exactly as specified inside its
// window and not at all outside; truth is never touched; labels match the schedule; the
// YAML reader rejects every class of bad fault map with a located message.

#include "sim/faults.h"

#include <cmath>
#include <functional>
#include <map>
#include <string>
#include <vector>

#include <gtest/gtest.h>
#include <yaml-cpp/yaml.h>

#include "core/error.h"
#include "core/lie.h"
#include "harness/config_io.h"
#include "harness/fault_config.h"
#include "harness/yaml_reader.h"

namespace tofu::sim {
namespace {

using core::SecondsToTime;
using core::Time;

// ---- synthetic streams on a known trajectory ----

Eigen::Vector3d Position(double t) {
  return Eigen::Vector3d(2.0 * std::cos(0.3 * t), 2.0 * std::sin(0.3 * t), 1.0 + 0.1 * t);
}

Eigen::Quaterniond Attitude(double t) {
  return core::CanonicalQuat(core::ExpQuat(Eigen::Vector3d(0.1 * std::sin(t), 0.2 * t, 0.05)));
}

core::Measurement PositionAt(double t) {
  core::PositionMeasurement m;
  m.p_Ss = Position(t);
  m.covariance = Eigen::Vector3d(1e-4, 4e-4, 9e-4).asDiagonal();
  return m;
}

core::Measurement PoseAt(double t) {
  core::PoseMeasurement m;
  m.p_Ss = Position(t);
  m.q_Ss = Attitude(t);
  Eigen::Matrix<double, 6, 6> A = Eigen::Matrix<double, 6, 6>::Identity();
  A(5, 0) = 0.3;  // a non-isotropic, correlated covariance: rotations show in it
  A(4, 3) = -0.2;
  m.covariance = 1e-4 * A * A.transpose();
  m.has_twist = true;
  m.v_s_s_mps = Eigen::Vector3d(std::sin(t), 0.5, std::cos(t));
  m.omega_s_s_radps = Eigen::Vector3d(0.1, 0.2 * t, -0.3);
  return m;
}

core::Measurement ImuAt(double t) {
  core::ImuMeasurement m;
  m.acc_I_mps2 = Eigen::Vector3d(std::sin(t), std::cos(t), 9.81 + 0.01 * t);
  m.gyro_I_radps = Eigen::Vector3d(0.1 * t, -0.2, 0.3 * std::sin(2.0 * t));
  return m;
}

// Samples at `rate_hz` from 0 to duration_s (exclusive), measured == truth (clean).
std::vector<SensorSample> Stream(const std::function<core::Measurement(double)>& at,
                                 double rate_hz, double duration_s) {
  std::vector<SensorSample> samples;
  const Time period_ns = core::PeriodFromRate(rate_hz);
  for (Time t_ns = 0; t_ns < SecondsToTime(duration_s); t_ns += period_ns) {
    SensorSample s;
    s.t_ns = t_ns;
    s.arrival_ns = t_ns + 5'000'000;
    s.measured = at(core::TimeToSeconds(t_ns));
    s.truth = s.measured;
    s.conditions = kMultipath;
    samples.push_back(s);
  }
  return samples;
}

std::vector<SensorSample> Inject(FaultInjector* injector, const std::vector<SensorSample>& in) {
  std::vector<SensorSample> out;
  for (const SensorSample& s : in) injector->Apply(s, &out);
  return out;
}

std::vector<SensorSample> Inject(const std::vector<FaultSpec>& specs,
                              const std::vector<SensorSample>& in, uint64_t seed = 1) {
  FaultInjector injector(specs, seed);
  return Inject(&injector, in);
}

// Bitwise equality of two measurements (every field).
bool Same(const core::Measurement& a, const core::Measurement& b) {
  if (a.index() != b.index()) return false;
  if (const auto* x = std::get_if<core::ImuMeasurement>(&a)) {
    const auto& y = std::get<core::ImuMeasurement>(b);
    return x->acc_I_mps2 == y.acc_I_mps2 && x->gyro_I_radps == y.gyro_I_radps;
  }
  if (const auto* x = std::get_if<core::PoseMeasurement>(&a)) {
    const auto& y = std::get<core::PoseMeasurement>(b);
    return x->p_Ss == y.p_Ss && x->q_Ss.coeffs() == y.q_Ss.coeffs() &&
           x->covariance == y.covariance && x->has_twist == y.has_twist &&
           x->v_s_s_mps == y.v_s_s_mps && x->omega_s_s_radps == y.omega_s_s_radps &&
           x->twist_covariance == y.twist_covariance;
  }
  const auto& x = std::get<core::PositionMeasurement>(a);
  const auto& y = std::get<core::PositionMeasurement>(b);
  return x.p_Ss == y.p_Ss && x.covariance == y.covariance;
}

const Eigen::Vector3d& P(const core::Measurement& m) {
  if (const auto* pose = std::get_if<core::PoseMeasurement>(&m)) return pose->p_Ss;
  return std::get<core::PositionMeasurement>(m).p_Ss;
}
const core::PoseMeasurement& Pose(const core::Measurement& m) {
  return std::get<core::PoseMeasurement>(m);
}
const core::ImuMeasurement& Imu(const core::Measurement& m) {
  return std::get<core::ImuMeasurement>(m);
}

// Checks the invariants of every fault on a stream without drops: same stamps, truth and
// conditions; bit-identical measurement outside `window`. Calls `inside` for the rest.
void ExpectOnlyInside(const std::vector<SensorSample>& in, const std::vector<SensorSample>& out,
                      const FaultWindow& window,
                      const std::function<void(const SensorSample&, const SensorSample&)>& inside) {
  ASSERT_EQ(in.size(), out.size());
  int n_inside = 0;
  for (size_t k = 0; k < in.size(); ++k) {
    ASSERT_EQ(out[k].t_ns, in[k].t_ns);
    EXPECT_TRUE(Same(out[k].truth, in[k].truth)) << "truth changed at " << in[k].t_ns;
    EXPECT_EQ(out[k].conditions, in[k].conditions);
    if (window.Contains(in[k].t_ns)) {
      ++n_inside;
      inside(in[k], out[k]);
    } else {
      EXPECT_TRUE(Same(out[k].measured, in[k].measured)) << "changed outside at " << in[k].t_ns;
      EXPECT_EQ(out[k].arrival_ns, in[k].arrival_ns);
    }
  }
  EXPECT_GT(n_inside, 0);
}

FaultSpec Spec(FaultKind kind, double start_s, double end_s) {
  FaultSpec spec;
  spec.sensor = "vio";
  spec.kind = kind;
  spec.start_s = start_s;
  spec.end_s = end_s;
  return spec;
}

Eigen::Quaterniond RpyDeg(double roll, double pitch, double yaw) {
  return harness::internal::config::QuatFromRpyDeg(Eigen::Vector3d(roll, pitch, yaw));
}

// ---- each kind ----

TEST(Faults, MisalignmentTransformsPoseAndPositionExactlyInsideTheWindow) {
  FaultSpec spec = Spec(FaultKind::kMisalignment, 2.0, 5.0);
  spec.misalignment.q_FS = RpyDeg(30.0, 60.0, 120.0);  // the paper's offsets
  spec.misalignment.p_FS_m = Eigen::Vector3d(1.0, -2.0, 0.5);
  const Eigen::Matrix3d R = spec.misalignment.q_FS.toRotationMatrix();
  const Eigen::Vector3d t = spec.misalignment.p_FS_m;

  const auto poses = Stream(PoseAt, 200.0, 8.0);
  ExpectOnlyInside(poses, Inject({spec}, poses), WindowOf(spec),
                   [&](const SensorSample& in, const SensorSample& out) {
                     const auto& a = Pose(in.measured);
                     const auto& b = Pose(out.measured);
                     EXPECT_LT((b.p_Ss - (R * a.p_Ss + t)).norm(), 1e-12);
                     EXPECT_LT(b.q_Ss.angularDistance(spec.misalignment.q_FS * a.q_Ss), 1e-12);
                     EXPECT_GE(b.q_Ss.w(), 0.0);
                     // The twist is in s: a change of the reference frame leaves it alone.
                     EXPECT_EQ(b.v_s_s_mps, a.v_s_s_mps);
                     EXPECT_EQ(b.omega_s_s_radps, a.omega_s_s_radps);
                     Eigen::Matrix<double, 6, 6> J = Eigen::Matrix<double, 6, 6>::Identity();
                     J.bottomRightCorner<3, 3>() = R;
                     EXPECT_LT((b.covariance - J * a.covariance * J.transpose()).norm(), 1e-18);
                   });

  const auto positions = Stream(PositionAt, 20.0, 8.0);
  ExpectOnlyInside(positions, Inject({spec}, positions), WindowOf(spec),
                   [&](const SensorSample& in, const SensorSample& out) {
                     EXPECT_LT((P(out.measured) - (R * P(in.measured) + t)).norm(), 1e-12);
                   });
}

TEST(Faults, NonGaussianNoiseWhitePartHasTheConfiguredStd) {
  FaultSpec spec = Spec(FaultKind::kNonGaussianNoise, 10.0, 510.0);
  spec.noise.white_std_m = 0.5;
  spec.noise.brown_std_m_per_sqrt_s = 0.0;
  const auto in = Stream(PositionAt, 20.0, 520.0);
  const auto out = Inject({spec}, in, 3);
  std::vector<double> e;
  ExpectOnlyInside(in, out, WindowOf(spec), [&](const SensorSample& a, const SensorSample& b) {
    const Eigen::Vector3d d = P(b.measured) - P(a.measured);
    for (int i = 0; i < 3; ++i) e.push_back(d[i]);
    // The reported covariance does not know about the noise.
    EXPECT_EQ(std::get<core::PositionMeasurement>(b.measured).covariance,
              std::get<core::PositionMeasurement>(a.measured).covariance);
  });
  const double n = static_cast<double>(e.size());  // 30000
  double sum = 0.0, sum_sq = 0.0, sum_lag = 0.0;
  for (size_t k = 0; k < e.size(); ++k) {
    sum += e[k];
    sum_sq += e[k] * e[k];
    if (k >= 3) sum_lag += e[k] * e[k - 3];  // same axis, previous sample
  }
  const double std = std::sqrt(sum_sq / n);
  // 5 sigma of the sample mean, std (sigma sqrt(1/(2n))) and lag-1 correlation (1/sqrt(n)).
  EXPECT_NEAR(sum / n, 0.0, 5.0 * 0.5 / std::sqrt(n));
  EXPECT_NEAR(std, 0.5, 5.0 * 0.5 / std::sqrt(2.0 * n));
  EXPECT_NEAR(sum_lag / sum_sq, 0.0, 5.0 / std::sqrt(n));
}

// Error (measured - clean) of the first axes at `t_s` after the window's start, over seeds.
std::vector<double> ErrorsAt(const FaultSpec& spec, const std::vector<SensorSample>& in,
                             double t_s, int seeds) {
  std::vector<double> errors;
  for (int seed = 0; seed < seeds; ++seed) {
    const auto out = Inject({spec}, in, static_cast<uint64_t>(seed));
    for (size_t k = 0; k < in.size(); ++k) {
      if (in[k].t_ns == SecondsToTime(spec.start_s + t_s)) {
        const Eigen::Vector3d d = P(out[k].measured) - P(in[k].measured);
        errors.insert(errors.end(), {d.x(), d.y(), d.z()});
      }
    }
  }
  return errors;
}

double MeanSquare(const std::vector<double>& x) {
  double s = 0.0;
  for (double v : x) s += v * v;
  return s / static_cast<double>(x.size());
}

TEST(Faults, NonGaussianNoiseBrownPartIsARandomWalk) {
  FaultSpec spec = Spec(FaultKind::kNonGaussianNoise, 1.0, 401.0);
  spec.noise.white_std_m = 0.0;
  spec.noise.brown_std_m_per_sqrt_s = 0.2;
  const auto in = Stream(PositionAt, 20.0, 402.0);
  const auto out = Inject({spec}, in, 5);

  // Increments of the error are independent N(0, sigma^2 dt), dt = 0.05 s.
  std::vector<double> increments;
  Eigen::Vector3d previous = Eigen::Vector3d::Zero();
  bool first = true;
  ExpectOnlyInside(in, out, WindowOf(spec), [&](const SensorSample& a, const SensorSample& b) {
    const Eigen::Vector3d e = P(b.measured) - P(a.measured);
    if (first) {
      EXPECT_EQ(e, Eigen::Vector3d::Zero());  // the walk starts at 0 at the window's start
      first = false;
    } else {
      for (int i = 0; i < 3; ++i) increments.push_back(e[i] - previous[i]);
    }
    previous = e;
  });
  const double n = static_cast<double>(increments.size());  // ~24000
  const double step_std = 0.2 * std::sqrt(0.05);
  EXPECT_NEAR(std::sqrt(MeanSquare(increments)), step_std, 5.0 * step_std / std::sqrt(2.0 * n));
  double lag = 0.0;
  for (size_t k = 3; k < increments.size(); ++k) lag += increments[k] * increments[k - 3];
  EXPECT_NEAR(lag / (n * step_std * step_std), 0.0, 5.0 / std::sqrt(n));

  // Growth: Var b(t) = sigma^2 t, checked at t = 5 s and 20 s over 200 seeds (600 values;
  // the relative std of a variance estimate is sqrt(2/600)).
  const auto short_in = Stream(PositionAt, 20.0, 22.0);
  const double tolerance = 5.0 * std::sqrt(2.0 / 600.0);
  for (const double t_s : {5.0, 20.0}) {
    const std::vector<double> errors = ErrorsAt(spec, short_in, t_s, 200);
    ASSERT_EQ(errors.size(), 600u);
    EXPECT_NEAR(MeanSquare(errors) / (0.04 * t_s), 1.0, tolerance) << "t = " << t_s;
  }

  // With a time constant the walk is a Gauss-Markov process, bounded at sigma^2 tau / 2.
  spec.noise.brown_time_constant_s = 2.0;
  const std::vector<double> bounded = ErrorsAt(spec, short_in, 20.0, 200);
  const double stationary = 0.04 * 2.0 / 2.0 * (1.0 - std::exp(-2.0 * 20.0 / 2.0));
  EXPECT_NEAR(MeanSquare(bounded) / stationary, 1.0, tolerance);
}

TEST(Faults, DivergenceAddsTheAnalyticIntegralAlongTheAxis) {
  FaultSpec spec = Spec(FaultKind::kDivergence, 1.0, 6.0);
  spec.divergence.axis_S = Eigen::Vector3d(1.0, 2.0, 0.0);  // normalised when applied
  spec.divergence.initial_velocity_mps = 0.05;
  spec.divergence.time_constant_s = 2.0;
  const Eigen::Vector3d a = Eigen::Vector3d(1.0, 2.0, 0.0) / std::sqrt(5.0);
  const auto offset = [&](Time t_ns) {
    const double x = core::TimeToSeconds(t_ns) - 1.0;
    return Eigen::Vector3d(0.05 * 2.0 * (std::exp(x / 2.0) - 1.0) * a);
  };
  const auto velocity = [&](Time t_ns) {
    const double x = core::TimeToSeconds(t_ns) - 1.0;
    return Eigen::Vector3d(0.05 * std::exp(x / 2.0) * a);
  };

  const auto poses = Stream(PoseAt, 200.0, 8.0);
  const auto out = Inject({spec}, poses);
  ExpectOnlyInside(poses, out, WindowOf(spec), [&](const SensorSample& in, const SensorSample& f) {
    const auto& p = Pose(in.measured);
    const auto& q = Pose(f.measured);
    EXPECT_LT((q.p_Ss - p.p_Ss - offset(in.t_ns)).norm(), 1e-12);
    EXPECT_EQ(q.q_Ss.coeffs(), p.q_Ss.coeffs());
    EXPECT_LT((q.v_s_s_mps - p.v_s_s_mps - p.q_Ss.conjugate() * velocity(in.t_ns)).norm(), 1e-12);
    EXPECT_EQ(q.omega_s_s_radps, p.omega_s_s_radps);
  });
  // At the end of the window (t = 5.995 s): d = v0 tau (e^(4.995/2) - 1) = 1.1152 m.
  EXPECT_NEAR((P(out[1199].measured) - P(poses[1199].measured)).norm(),
              0.1 * (std::exp(4.995 / 2.0) - 1.0), 1e-12);

  const auto positions = Stream(PositionAt, 20.0, 8.0);
  ExpectOnlyInside(positions, Inject({spec}, positions), WindowOf(spec),
                   [&](const SensorSample& in, const SensorSample& f) {
                     EXPECT_LT((P(f.measured) - P(in.measured) - offset(in.t_ns)).norm(), 1e-12);
                   });
}

TEST(Faults, DropoutRemovesExactlyTheSamplesInTheWindow) {
  const auto in = Stream(ImuAt, 400.0, 4.0);  // 2.5 ms period
  for (const auto& [start_s, end_s] : {std::pair{1.0, 2.5}, std::pair{1.0012, 2.5013}}) {
    const FaultSpec spec = Spec(FaultKind::kDropout, start_s, end_s);
    const auto out = Inject({spec}, in);
    std::vector<SensorSample> expected;
    for (const SensorSample& s : in) {
      if (s.t_ns < SecondsToTime(start_s) || s.t_ns >= SecondsToTime(end_s)) expected.push_back(s);
    }
    ASSERT_EQ(out.size(), expected.size());
    for (size_t k = 0; k < out.size(); ++k) {
      EXPECT_EQ(out[k].t_ns, expected[k].t_ns);
      EXPECT_TRUE(Same(out[k].measured, expected[k].measured));
    }
  }
  // Boundaries: the sample at exactly 1.0 s is dropped, the one at 2.5 s kept.
  const auto out = Inject({Spec(FaultKind::kDropout, 1.0, 2.5)}, in);
  EXPECT_EQ(out.size(), in.size() - 600);
  EXPECT_EQ(out[399].t_ns, SecondsToTime(0.9975));
  EXPECT_EQ(out[400].t_ns, SecondsToTime(2.5));
}

TEST(Faults, FreezeHoldsTheLastValueBeforeTheWindow) {
  const FaultSpec spec = Spec(FaultKind::kFreeze, 1.0, 2.0);
  for (const auto& in : {Stream(PoseAt, 200.0, 3.0), Stream(ImuAt, 400.0, 3.0)}) {
    const auto out = Inject({spec}, in);
    // The last sample before 1.0 s.
    size_t last_before = 0;
    while (in[last_before + 1].t_ns < SecondsToTime(1.0)) ++last_before;
    ExpectOnlyInside(in, out, WindowOf(spec), [&](const SensorSample& a, const SensorSample& b) {
      EXPECT_TRUE(Same(b.measured, in[last_before].measured)) << a.t_ns;
      EXPECT_EQ(b.arrival_ns, a.arrival_ns);  // stamps keep advancing
    });
  }
  // A freeze from the very first sample holds that sample.
  const auto in = Stream(PositionAt, 20.0, 2.0);
  const auto out = Inject({Spec(FaultKind::kFreeze, 0.0, 1.0)}, in);
  for (size_t k = 0; k < 20; ++k) EXPECT_TRUE(Same(out[k].measured, in[0].measured));
  EXPECT_TRUE(Same(out[20].measured, in[20].measured));
}

TEST(Faults, DelayCarriesTheCleanValueOfTMinusDelay) {
  const auto in = Stream(ImuAt, 400.0, 4.0);  // 2.5 ms period
  const Time period_ns = 2'500'000;
  const auto clean_at = [&](Time t_ns) { return in[static_cast<size_t>(t_ns / period_ns)]; };

  // delay = 40 periods: exactly the value of t - delay; stamp, truth, arrival of t.
  FaultSpec spec = Spec(FaultKind::kDelay, 1.0, 3.0);
  spec.delay.delay_s = 0.1;
  ExpectOnlyInside(in, Inject({spec}, in), WindowOf(spec),
                   [&](const SensorSample& a, const SensorSample& b) {
                     EXPECT_TRUE(Same(b.measured, clean_at(a.t_ns - 100'000'000).measured));
                     EXPECT_EQ(b.arrival_ns, a.arrival_ns);
                   });

  // Off the sample grid: the latest value stamped at or before t - delay (zero-order hold).
  spec.delay.delay_s = 0.0037;  // t - 3.7 ms -> the sample at t - 5 ms
  ExpectOnlyInside(in, Inject({spec}, in), WindowOf(spec),
                   [&](const SensorSample& a, const SensorSample& b) {
                     EXPECT_TRUE(Same(b.measured, clean_at(a.t_ns - 5'000'000).measured));
                   });

  // Transport delay: values and stamps unchanged, arrival later.
  spec.delay.delay_s = 0.0;
  spec.delay.arrival_delay_s = 0.05;
  ExpectOnlyInside(in, Inject({spec}, in), WindowOf(spec),
                   [&](const SensorSample& a, const SensorSample& b) {
                     EXPECT_TRUE(Same(b.measured, a.measured));
                     EXPECT_EQ(b.arrival_ns, a.arrival_ns + 50'000'000);
                   });

  // From the run's start there is no value that old yet: those samples are dropped.
  FaultSpec at_start = Spec(FaultKind::kDelay, 0.0, 1.0);
  at_start.delay.delay_s = 0.1;
  const auto out = Inject({at_start}, in);
  ASSERT_EQ(out.size(), in.size() - 40);
  EXPECT_EQ(out[0].t_ns, SecondsToTime(0.1));
  EXPECT_TRUE(Same(out[0].measured, in[0].measured));
}

TEST(Faults, JumpAddsAStepOffset) {
  FaultSpec spec = Spec(FaultKind::kJump, 2.0, 4.0);
  spec.jump.translation_S_m = Eigen::Vector3d(0.5, -0.2, 1.0);
  const auto positions = Stream(PositionAt, 20.0, 6.0);
  ExpectOnlyInside(positions, Inject({spec}, positions), WindowOf(spec),
                   [&](const SensorSample& a, const SensorSample& b) {
                     EXPECT_LT((P(b.measured) - P(a.measured) - spec.jump.translation_S_m).norm(),
                               1e-14);
                   });

  // With a rotation: the first sample jumps by exactly (translation, q_jump); the later
  // motion continues rotated about the jump point.
  spec.jump.q_jump = RpyDeg(0.0, 0.0, 90.0);
  const Eigen::Matrix3d R = spec.jump.q_jump.toRotationMatrix();
  const auto poses = Stream(PoseAt, 200.0, 6.0);
  const size_t k0 = 400;  // t = 2.0 s
  const Eigen::Vector3d p0 = P(poses[k0].measured);
  ExpectOnlyInside(poses, Inject({spec}, poses), WindowOf(spec),
                   [&](const SensorSample& a, const SensorSample& b) {
                     const auto& x = Pose(a.measured);
                     const auto& y = Pose(b.measured);
                     const Eigen::Vector3d expected =
                         p0 + spec.jump.translation_S_m + R * (x.p_Ss - p0);
                     EXPECT_LT((y.p_Ss - expected).norm(), 1e-12);
                     EXPECT_LT(y.q_Ss.angularDistance(spec.jump.q_jump * x.q_Ss), 1e-12);
                     EXPECT_EQ(y.v_s_s_mps, x.v_s_s_mps);
                   });
  const auto out = Inject({spec}, poses);
  EXPECT_LT((P(out[k0].measured) - p0 - spec.jump.translation_S_m).norm(), 1e-14);
}

TEST(Faults, OutliersFollowThePoissonRateAndAHeavyTail) {
  FaultSpec spec = Spec(FaultKind::kOutliers, 0.0, 600.0);
  spec.outliers.rate_hz = 2.0;
  spec.outliers.scale_m = 0.5;
  const auto in = Stream(PositionAt, 20.0, 600.0);  // 12000 samples
  const auto out = Inject({spec}, in, 9);

  // Outlier count: Bernoulli per sample with p = 1 - exp(-rate dt) (the first sample, at
  // the window's start, has dt = 0); expected 11999 * 0.0952 = 1142, sigma 32.
  double expected = 0.0, variance = 0.0;
  int count = 0;
  std::vector<double> z;  // offset components / scale
  ExpectOnlyInside(in, out, WindowOf(spec), [&](const SensorSample& a, const SensorSample& b) {
    const double p = a.t_ns == 0 ? 0.0 : 1.0 - std::exp(-2.0 * 0.05);
    expected += p;
    variance += p * (1.0 - p);
    const Eigen::Vector3d d = P(b.measured) - P(a.measured);
    if (d != Eigen::Vector3d::Zero()) {
      ++count;
      for (int i = 0; i < 3; ++i) z.push_back(d[i] / 0.5);
    }
  });
  EXPECT_NEAR(count, expected, 4.0 * std::sqrt(variance));
  // Poisson rate: 2 Hz * 600 s = 1200 events, thinned to at most one per sample.
  EXPECT_NEAR(count, 1200.0, 4.0 * std::sqrt(1200.0) + (1200.0 - expected));

  // Heavy tail: Student-t, nu = 2, per axis P(|z| > k) = 1 - k / sqrt(k^2 + 2): 0.0955 at
  // k = 3 (a Gaussian: 0.0027); the median of |z| is sqrt(2/3).
  const auto fraction_above = [&](double k) {
    double n = 0.0;
    for (double v : z) n += std::abs(v) > k ? 1.0 : 0.0;
    return n / static_cast<double>(z.size());
  };
  const double m = static_cast<double>(z.size());
  const double p3 = 1.0 - 3.0 / std::sqrt(11.0);
  EXPECT_NEAR(fraction_above(3.0), p3, 5.0 * std::sqrt(p3 * (1.0 - p3) / m));
  const double p10 = 1.0 - 10.0 / std::sqrt(102.0);
  EXPECT_NEAR(fraction_above(10.0), p10, 5.0 * std::sqrt(p10 * (1.0 - p10) / m));
  EXPECT_NEAR(fraction_above(std::sqrt(2.0 / 3.0)), 0.5, 5.0 * 0.5 / std::sqrt(m));

  // IMU readings: both acc and gyro are hit at the same rate.
  FaultSpec imu_spec = Spec(FaultKind::kOutliers, 1.0, 61.0);
  imu_spec.outliers.rate_hz = 4.0;
  const auto imu_in = Stream(ImuAt, 400.0, 62.0);  // 24000 samples in the window
  const auto imu_out = Inject({imu_spec}, imu_in, 9);
  int imu_count = 0;
  ExpectOnlyInside(imu_in, imu_out, WindowOf(imu_spec),
                   [&](const SensorSample& a, const SensorSample& b) {
                     const bool acc = Imu(a.measured).acc_I_mps2 != Imu(b.measured).acc_I_mps2;
                     const bool gyro =
                         Imu(a.measured).gyro_I_radps != Imu(b.measured).gyro_I_radps;
                     EXPECT_EQ(acc, gyro);
                     imu_count += acc ? 1 : 0;
                   });
  const double p_imu = 1.0 - std::exp(-4.0 * 0.0025);
  const double n_imu = 23999.0;
  EXPECT_NEAR(imu_count, n_imu * p_imu, 4.0 * std::sqrt(n_imu * p_imu * (1.0 - p_imu)));
}

// ---- schedule, composition, determinism ----

TEST(Faults, ActiveFaultsAndLabelsMatchTheSchedule) {
  const std::vector<FaultSpec> specs = {
      Spec(FaultKind::kMisalignment, 0.0, std::numeric_limits<double>::infinity()),
      Spec(FaultKind::kDivergence, 100.0, 140.0),
      Spec(FaultKind::kDropout, 120.0, 130.0),
      Spec(FaultKind::kFreeze, 130.0, 200.0),  // ends exactly at the run's end
      Spec(FaultKind::kJump, 250.0, 260.0),    // after the run's end: no labels
  };
  const FaultInjector injector(specs, 1);
  const uint32_t mis = FaultBit(FaultKind::kMisalignment);
  const uint32_t div = FaultBit(FaultKind::kDivergence);
  const uint32_t drop = FaultBit(FaultKind::kDropout);
  const uint32_t freeze = FaultBit(FaultKind::kFreeze);
  EXPECT_EQ(injector.ActiveFaults(0), mis);
  EXPECT_EQ(injector.ActiveFaults(SecondsToTime(100.0) - 1), mis);
  EXPECT_EQ(injector.ActiveFaults(SecondsToTime(100.0)), mis | div);
  EXPECT_EQ(injector.ActiveFaults(SecondsToTime(120.0)), mis | div | drop);
  EXPECT_EQ(injector.ActiveFaults(SecondsToTime(130.0)), mis | div | freeze);
  EXPECT_EQ(injector.ActiveFaults(SecondsToTime(140.0) - 1), mis | div | freeze);
  EXPECT_EQ(injector.ActiveFaults(SecondsToTime(140.0)), mis | freeze);
  EXPECT_EQ(injector.ActiveFaults(SecondsToTime(255.0)), mis | FaultBit(FaultKind::kJump));
  EXPECT_EQ(FaultBit(FaultKind::kOutliers), 1u << 7);

  const std::vector<FaultLabel> labels = FaultLabels(specs, SecondsToTime(200.0));
  const std::vector<std::tuple<Time, std::string, bool>> expected = {
      {0, "misalignment", true},
      {SecondsToTime(100.0), "divergence", true},
      {SecondsToTime(120.0), "dropout", true},
      {SecondsToTime(130.0), "dropout", false},  // an end before a start at the same time
      {SecondsToTime(130.0), "freeze", true},
      {SecondsToTime(140.0), "divergence", false},
      {SecondsToTime(200.0), "freeze", false},
  };
  ASSERT_EQ(labels.size(), expected.size());
  for (size_t i = 0; i < labels.size(); ++i) {
    EXPECT_EQ(labels[i].t_ns, std::get<0>(expected[i])) << i;
    EXPECT_EQ(labels[i].fault, std::get<1>(expected[i])) << i;
    EXPECT_EQ(labels[i].active, std::get<2>(expected[i])) << i;
    EXPECT_EQ(labels[i].sensor, "vio");
  }
  // The labels agree with ActiveFaults just before and at each transition.
  for (const FaultLabel& label : labels) {
    const uint32_t bit = FaultBit(*FaultKindFromName(label.fault));
    EXPECT_EQ((injector.ActiveFaults(label.t_ns) & bit) != 0, label.active) << label.t_ns;
    if (label.t_ns > 0) {
      EXPECT_EQ((injector.ActiveFaults(label.t_ns - 1) & bit) != 0, !label.active);
    }
  }
}

TEST(Faults, OverlappingFaultsComposeInListOrder) {
  FaultSpec mis = Spec(FaultKind::kMisalignment, 0.0, 10.0);
  mis.misalignment.q_FS = RpyDeg(10.0, -20.0, 45.0);
  mis.misalignment.p_FS_m = Eigen::Vector3d(3.0, 0.0, -1.0);
  FaultSpec div = Spec(FaultKind::kDivergence, 2.0, 6.0);
  div.divergence.initial_velocity_mps = 0.1;
  FaultSpec jump = Spec(FaultKind::kJump, 4.0, 8.0);
  jump.jump.translation_S_m = Eigen::Vector3d(0.0, 0.0, 2.0);
  const FaultSpec drop = Spec(FaultKind::kDropout, 5.0, 5.5);
  const Eigen::Matrix3d R = mis.misalignment.q_FS.toRotationMatrix();
  const auto d = [](double t) {  // divergence offset along y of S: v0 tau (e^(x/tau) - 1)
    if (t < 2.0 || t >= 6.0) return Eigen::Vector3d::Zero().eval();
    return Eigen::Vector3d(0.0, 0.1 * 10.0 * (std::exp((t - 2.0) / 10.0) - 1.0), 0.0);
  };
  const auto in_window = [](double t, double a, double b) { return t >= a && t < b; };

  const auto in = Stream(PositionAt, 20.0, 12.0);
  // misalignment, then divergence, then jump (all in S of the faulted output), then dropout.
  const auto out = Inject({mis, div, jump, drop}, in);
  ASSERT_EQ(out.size(), in.size() - 10);
  for (const SensorSample& s : out) {
    const double t = core::TimeToSeconds(s.t_ns);
    EXPECT_FALSE(in_window(t, 5.0, 5.5));
    Eigen::Vector3d expected = Position(t);
    if (in_window(t, 0.0, 10.0)) expected = R * expected + mis.misalignment.p_FS_m;
    expected += d(t);
    if (in_window(t, 4.0, 8.0)) expected += jump.jump.translation_S_m;
    EXPECT_LT((P(s.measured) - expected).norm(), 1e-12) << t;
    EXPECT_TRUE(Same(s.truth, PositionAt(t)));
  }
  // The other order: divergence before the misalignment is rotated with the frame.
  const auto swapped = Inject({div, mis}, in);
  for (const SensorSample& s : swapped) {
    const double t = core::TimeToSeconds(s.t_ns);
    Eigen::Vector3d expected = Position(t) + d(t);
    if (in_window(t, 0.0, 10.0)) expected = R * expected + mis.misalignment.p_FS_m;
    EXPECT_LT((P(s.measured) - expected).norm(), 1e-12) << t;
  }
}

TEST(Faults, SameSeedGivesTheSameOutput) {
  FaultSpec noise = Spec(FaultKind::kNonGaussianNoise, 1.0, 9.0);
  FaultSpec outliers = Spec(FaultKind::kOutliers, 2.0, 8.0);
  outliers.outliers.rate_hz = 5.0;
  outliers.outliers.rotation_scale_rad = 0.1;
  const auto in = Stream(PoseAt, 200.0, 10.0);
  const auto a = Inject({noise, outliers}, in, 42);
  const auto b = Inject({noise, outliers}, in, 42);
  const auto c = Inject({noise, outliers}, in, 43);
  ASSERT_EQ(a.size(), b.size());
  bool any_difference = false;
  for (size_t k = 0; k < a.size(); ++k) {
    EXPECT_TRUE(Same(a[k].measured, b[k].measured));
    any_difference = any_difference || !Same(a[k].measured, c[k].measured);
  }
  EXPECT_TRUE(any_difference);
}

TEST(Faults, CheckFaultAppliesByMeasurementType) {
  for (const FaultKind kind : AllFaultKinds()) {
    const FaultSpec spec = Spec(kind, 0.0, 1.0);
    const bool imu_ok = kind == FaultKind::kDropout || kind == FaultKind::kFreeze ||
                        kind == FaultKind::kDelay || kind == FaultKind::kOutliers;
    EXPECT_EQ(!CheckFaultApplies(spec, core::MeasurementKind::kImu).has_value(), imu_ok)
        << FaultKindName(kind);
    EXPECT_FALSE(CheckFaultApplies(spec, core::MeasurementKind::kPose).has_value());
    EXPECT_FALSE(CheckFaultApplies(spec, core::MeasurementKind::kPosition).has_value());
    EXPECT_EQ(FaultKindFromName(FaultKindName(kind)), kind);
  }
  FaultSpec imu_outliers = Spec(FaultKind::kOutliers, 0.0, 1.0);
  imu_outliers.outliers.acc_scale_mps2 = 0.0;
  imu_outliers.outliers.gyro_scale_radps = 0.0;
  EXPECT_TRUE(CheckFaultApplies(imu_outliers, core::MeasurementKind::kImu).has_value());
  EXPECT_FALSE(CheckFaultApplies(imu_outliers, core::MeasurementKind::kPosition).has_value());
  EXPECT_EQ(core::MeasurementKindOf(ImuAt(0.0)), core::MeasurementKind::kImu);
  EXPECT_EQ(core::MeasurementKindOf(PoseAt(0.0)), core::MeasurementKind::kPose);
  EXPECT_EQ(core::MeasurementKindOf(PositionAt(0.0)), core::MeasurementKind::kPosition);
}

}  // namespace
}  // namespace tofu::sim

// ---- YAML ----

namespace tofu::harness::internal {
namespace {

constexpr const char* kLabel = "faults.yaml";

std::vector<YamlValue> FaultItems(const std::string& yaml) {
  const YamlValue root = ParseDocument(yaml, kLabel);
  return root.Peek("faults")->List(false);
}

core::InputError ReadError(const std::string& yaml, double duration_s = 200.0) {
  try {
    for (const YamlValue& item : FaultItems(yaml)) ReadFaultSpec(item, duration_s);
  } catch (const core::InputError& e) {
    return e;
  }
  ADD_FAILURE() << "expected an InputError for:\n" << yaml;
  return core::InputError({}, "", "");
}

void ExpectContains(const std::string& text, const std::string& part) {
  EXPECT_NE(text.find(part), std::string::npos) << "'" << part << "' not in: " << text;
}

TEST(FaultConfig, ReadsAFaultOfEachKindAndEmitsItBack) {
  const std::string yaml = R"yaml(faults:
  - {sensor: vio, kind: divergence, start_s: 100, end_s: 140, axis: [0, 1, 0],
     initial_velocity_mps: 0.01, time_constant_s: 10}
  - {sensor: total_station, kind: misalignment, rpy_deg: [30, 60, 120], translation_m: [1, 2, 3]}
  - {sensor: total_station, kind: non_gaussian_noise, start_s: 50, white_std_m: 0.2,
     brown_std_m_per_sqrt_s: 0.05}
  - {sensor: gnss, kind: non_gaussian_noise, brown_time_constant_s: 30}
  - {sensor: lio, kind: dropout, start_s: 10, end_s: 20}
  - {sensor: lio, kind: freeze, start_s: 30, end_s: 31.5}
  - {sensor: imu, kind: delay, start_s: 1, end_s: 2, delay_s: 0.05, arrival_delay_s: 0.01}
  - {sensor: vio, kind: jump, start_s: 60, end_s: 61, translation_m: [0.5, 0, 0],
     rpy_deg: [0, 0, 15]}
  - {sensor: imu, kind: outliers, start_s: 5, end_s: 6, rate_hz: 3, scale_m: 0.4,
     rotation_scale_deg: 2, acc_scale_mps2: 7, gyro_scale_degps: 30, degrees_of_freedom: 1}
)yaml";
  std::vector<sim::FaultSpec> specs;
  for (const YamlValue& item : FaultItems(yaml)) specs.push_back(ReadFaultSpec(item, 200.0));
  ASSERT_EQ(specs.size(), 9u);
  const sim::FaultSpec& div = specs[0];
  EXPECT_EQ(div.sensor, "vio");
  EXPECT_EQ(div.kind, sim::FaultKind::kDivergence);
  EXPECT_EQ(div.start_s, 100.0);
  EXPECT_EQ(div.end_s, 140.0);
  EXPECT_EQ(div.divergence.axis_S, Eigen::Vector3d(0, 1, 0));
  EXPECT_EQ(div.divergence.initial_velocity_mps, 0.01);
  EXPECT_EQ(div.divergence.time_constant_s, 10.0);
  EXPECT_EQ(specs[1].start_s, 0.0);
  EXPECT_TRUE(std::isinf(specs[1].end_s));
  EXPECT_LT(specs[1].misalignment.q_FS.angularDistance(
                config::QuatFromRpyDeg(Eigen::Vector3d(30, 60, 120))),
            1e-15);
  EXPECT_EQ(specs[1].misalignment.p_FS_m, Eigen::Vector3d(1, 2, 3));
  EXPECT_EQ(specs[2].noise.white_std_m, 0.2);
  EXPECT_TRUE(std::isinf(specs[2].noise.brown_time_constant_s));
  EXPECT_EQ(specs[3].noise.brown_time_constant_s, 30.0);
  EXPECT_EQ(specs[6].delay.delay_s, 0.05);
  EXPECT_EQ(specs[6].delay.arrival_delay_s, 0.01);
  EXPECT_EQ(specs[7].jump.translation_S_m, Eigen::Vector3d(0.5, 0, 0));
  EXPECT_NEAR(specs[8].outliers.gyro_scale_radps, 30.0 * config::kRadPerDeg, 1e-15);
  EXPECT_EQ(specs[8].outliers.degrees_of_freedom, 1);

  // Emit and read back: the same specs.
  YAML::Emitter out;
  out << YAML::BeginMap << YAML::Key << "faults" << YAML::Value << YAML::BeginSeq;
  for (const sim::FaultSpec& spec : specs) EmitFaultSpec(out, spec);
  out << YAML::EndSeq << YAML::EndMap;
  ASSERT_TRUE(out.good()) << out.GetLastError();
  const std::vector<YamlValue> items = FaultItems(out.c_str());
  ASSERT_EQ(items.size(), specs.size());
  for (size_t i = 0; i < specs.size(); ++i) {
    const sim::FaultSpec back = ReadFaultSpec(items[i], 200.0);
    const sim::FaultSpec& s = specs[i];
    EXPECT_EQ(back.sensor, s.sensor);
    EXPECT_EQ(back.kind, s.kind);
    EXPECT_EQ(back.start_s, s.start_s);
    EXPECT_EQ(back.end_s, s.end_s);
    EXPECT_LT(back.misalignment.q_FS.angularDistance(s.misalignment.q_FS), 1e-12);
    EXPECT_EQ(back.misalignment.p_FS_m, s.misalignment.p_FS_m);
    EXPECT_EQ(back.noise.white_std_m, s.noise.white_std_m);
    EXPECT_EQ(back.noise.brown_std_m_per_sqrt_s, s.noise.brown_std_m_per_sqrt_s);
    EXPECT_EQ(back.noise.brown_time_constant_s, s.noise.brown_time_constant_s);
    EXPECT_EQ(back.divergence.axis_S, s.divergence.axis_S);
    EXPECT_EQ(back.divergence.initial_velocity_mps, s.divergence.initial_velocity_mps);
    EXPECT_EQ(back.divergence.time_constant_s, s.divergence.time_constant_s);
    EXPECT_EQ(back.delay.delay_s, s.delay.delay_s);
    EXPECT_EQ(back.delay.arrival_delay_s, s.delay.arrival_delay_s);
    EXPECT_EQ(back.jump.translation_S_m, s.jump.translation_S_m);
    EXPECT_LT(back.jump.q_jump.angularDistance(s.jump.q_jump), 1e-12);
    EXPECT_EQ(back.outliers.rate_hz, s.outliers.rate_hz);
    EXPECT_EQ(back.outliers.scale_m, s.outliers.scale_m);
    EXPECT_NEAR(back.outliers.rotation_scale_rad, s.outliers.rotation_scale_rad, 1e-15);
    EXPECT_EQ(back.outliers.acc_scale_mps2, s.outliers.acc_scale_mps2);
    EXPECT_NEAR(back.outliers.gyro_scale_radps, s.outliers.gyro_scale_radps, 1e-15);
    EXPECT_EQ(back.outliers.degrees_of_freedom, s.outliers.degrees_of_freedom);
  }
}

TEST(FaultConfig, UnknownKindListsTheKinds) {
  const core::InputError e = ReadError(R"yaml(faults:
  - {sensor: vio, kind: divergance, start_s: 1}
)yaml");
  EXPECT_EQ(e.location().line, 2) << e.what();
  EXPECT_EQ(e.key_path(), "faults[0].kind");
  ExpectContains(e.message(), "unknown fault kind 'divergance'");
  ExpectContains(e.message(), "did you mean 'divergence'");
  ExpectContains(e.message(),
                 "misalignment, non_gaussian_noise, divergence, dropout, freeze, delay, jump, "
                 "outliers");
  const core::InputError missing = ReadError("faults:\n  - {sensor: vio, start_s: 1}\n");
  ExpectContains(missing.message(), "missing required key 'kind'");
}

TEST(FaultConfig, KeyNotAllowedForTheKindNamesLineAndTheKindsKeys) {
  const core::InputError e = ReadError(R"yaml(faults:
  - sensor: vio
    kind: dropout
    start_s: 1
    end_s: 2
    axis: [0, 1, 0]
)yaml");
  EXPECT_EQ(e.location().line, 6) << e.what();
  EXPECT_EQ(e.key_path(), "faults[0].axis");
  ExpectContains(e.message(), "unknown key 'axis'");
  ExpectContains(e.message(), "sensor, kind, start_s, end_s");
  ExpectContains(e.what(), "faults.yaml:6:");

  const core::InputError typo = ReadError(R"yaml(faults:
  - {sensor: vio, kind: divergence, axis: [0, 1, 0], time_constant: 3}
)yaml");
  EXPECT_EQ(typo.key_path(), "faults[0].time_constant");
  ExpectContains(typo.message(), "did you mean 'time_constant_s'");
  ExpectContains(typo.message(), "axis, initial_velocity_mps, time_constant_s");

  const core::InputError zero_axis =
      ReadError("faults:\n  - {sensor: vio, kind: divergence, axis: [0, 0, 0]}\n");
  EXPECT_EQ(zero_axis.key_path(), "faults[0].axis");
}

TEST(FaultConfig, WindowOutsideTheRunIsAnError) {
  const core::InputError late = ReadError(R"yaml(faults:
  - {sensor: vio, kind: dropout, start_s: 250}
)yaml");
  EXPECT_EQ(late.location().line, 2);
  EXPECT_EQ(late.key_path(), "faults[0].start_s");
  ExpectContains(late.message(), "[0, 200)");
  const core::InputError negative =
      ReadError("faults:\n  - {sensor: vio, kind: dropout, start_s: -1}\n");
  EXPECT_EQ(negative.key_path(), "faults[0].start_s");
  const core::InputError past_end =
      ReadError("faults:\n  - {sensor: vio, kind: freeze, start_s: 10, end_s: 201}\n");
  EXPECT_EQ(past_end.key_path(), "faults[0].end_s");
  ExpectContains(past_end.message(), "within the run of 200 s");
}

TEST(FaultConfig, StartAtOrAfterEndIsAnError) {
  for (const char* end : {"10", "5"}) {
    const core::InputError e = ReadError(
        std::string("faults:\n  - {sensor: vio, kind: dropout, start_s: 10, end_s: ") + end +
        "}\n");
    EXPECT_EQ(e.location().line, 2);
    EXPECT_EQ(e.key_path(), "faults[0].end_s");
    ExpectContains(e.message(), "after start_s = 10");
  }
}

TEST(FaultConfig, FaultsMustNameASensorOfACompatibleType) {
  const std::map<std::string, core::MeasurementKind> sensors = {
      {"imu", core::MeasurementKind::kImu}, {"vio", core::MeasurementKind::kPose},
      {"total_station", core::MeasurementKind::kPosition}};
  const auto read = [&](const std::string& yaml) {
    return ReadFaults(*ParseDocument(yaml, kLabel).Peek("faults"), 200.0, sensors);
  };
  const auto specs = read(R"yaml(faults:
  - {sensor: imu, kind: freeze, start_s: 1, end_s: 2}
  - {sensor: total_station, kind: jump, start_s: 3}
)yaml");
  ASSERT_EQ(specs.size(), 2u);

  const auto error = [&](const std::string& yaml) {
    try {
      read(yaml);
    } catch (const core::InputError& e) {
      return e;
    }
    ADD_FAILURE() << "expected an InputError for:\n" << yaml;
    return core::InputError({}, "", "");
  };
  const core::InputError incompatible = error(R"yaml(faults:
  - {sensor: vio, kind: jump, start_s: 3}
  - {sensor: imu, kind: misalignment, rpy_deg: [0, 0, 10]}
)yaml");
  EXPECT_EQ(incompatible.location().line, 3);
  EXPECT_EQ(incompatible.key_path(), "faults[1].kind");
  ExpectContains(incompatible.message(), "misalignment does not apply to imu measurements");
  const core::InputError unknown = error("faults:\n  - {sensor: vi0, kind: dropout}\n");
  EXPECT_EQ(unknown.key_path(), "faults[0].sensor");
  ExpectContains(unknown.message(), "did you mean 'vio'");
  ExpectContains(unknown.message(), "imu, total_station, vio");
}

}  // namespace
}  // namespace tofu::harness::internal
