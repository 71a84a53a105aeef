#include "estimator/consensus_estimator.h"

#include <algorithm>
#include <cmath>
#include <deque>
#include <stdexcept>
#include <string>
#include <utility>
#include <variant>

#include "estimator/velocity.h"

namespace tofu::estimator {
namespace {

struct RawSample {
  core::Time t_ns = 0;
  Eigen::Vector3d p_As = Eigen::Vector3d::Zero();
  Eigen::Quaterniond q_As = Eigen::Quaterniond::Identity();  ///< pose sensors only
  std::optional<Eigen::Vector3d> v_s_mps;  ///< the sensor's own twist, when it reports one
  Eigen::Matrix3d cov_p_As = Eigen::Matrix3d::Zero();  ///< stated, m² in A
  Eigen::Matrix3d cov_v_s = Eigen::Matrix3d::Zero();   ///< stated twist velocity, m²/s² in s
};

// Puts a stream's velocity samples onto the common evaluation grid (multiples of
// period_ns) by linear interpolation between consecutive samples, never across a gap.
// The CM distance compares empirical distributions: two streams sampling the very same
// velocity at different instants and rates differ by their sampling alone (~1/n of the
// velocity range per axis, 0.05-0.1 m/s for a 10 Hz stream in flight, the size of the
// paper's threshold). On a common grid only the sensors' errors remain.
class GridResampler {
 public:
  GridResampler(core::Time period_ns, core::Time max_gap_ns)
      : period_ns_(period_ns), max_gap_ns_(max_gap_ns) {}

  // cov (may be null: none stated) is interpolated with the same weights: (1−u)Σ₀ + uΣ₁
  // bounds the interpolated velocity's covariance from above whatever the correlation.
  template <typename Emit>
  void Add(core::Time t_ns, const Eigen::Vector3d& v, const Eigen::Matrix3d* cov, Emit&& emit) {
    if (last_ && t_ns <= last_->t_ns) return;
    const Eigen::Matrix3d cov_now = cov != nullptr ? *cov : Eigen::Matrix3d::Zero();
    if (!last_ || t_ns - last_->t_ns > max_gap_ns_) {
      if (t_ns % period_ns_ == 0) emit(t_ns, v, cov);
    } else {
      const core::Time t0 = last_->t_ns;
      Eigen::Matrix3d cov_g;
      for (core::Time g = t0 - t0 % period_ns_ + period_ns_; g <= t_ns; g += period_ns_) {
        const double u = static_cast<double>(g - t0) / static_cast<double>(t_ns - t0);
        if (cov != nullptr) cov_g = (1.0 - u) * last_->cov + u * cov_now;
        emit(g, (1.0 - u) * last_->v + u * v, cov != nullptr ? &cov_g : nullptr);
      }
    }
    last_ = Last{t_ns, v, cov_now};
  }

 private:
  struct Last {
    core::Time t_ns;
    Eigen::Vector3d v;
    Eigen::Matrix3d cov;
  };
  core::Time period_ns_;
  core::Time max_gap_ns_;
  std::optional<Last> last_;
};

struct LocalSample {
  core::Time t_ns = 0;
  Eigen::Matrix3d R_LI = Eigen::Matrix3d::Identity();
  Eigen::Vector3d v_L_mps = Eigen::Vector3d::Zero();
  Eigen::Vector3d omega_I_radps = Eigen::Vector3d::Zero();
  bool valid = false;
};

// Samples used to measure a stream's period before its half window is fixed.
constexpr std::size_t kPeriodSamples = 9;

// Checked before the estimator, selector and matrix are built from them: the error then
// names the field as the caller set it (e.g. "selection.threshold").
ConsensusEstimatorOptions Validated(ConsensusEstimatorOptions options) {
  std::string why;
  if (!options.IsValid(&why)) throw std::invalid_argument("ConsensusEstimatorOptions: " + why);
  return options;
}

}  // namespace

bool ConsensusEstimatorOptions::IsValid(std::string* why) const {
  auto fail = [why](std::string message) {
    if (why != nullptr) *why = std::move(message);
    return false;
  };
  std::string nested;
  if (!selection.IsValid(&nested)) return fail("selection." + nested);
  if (!consistency.IsValid(&nested)) return fail("consistency." + nested);
  if (evaluation_period_ns <= 0) return fail("evaluation_period_ns must be positive");
  // It is the differentiation's half window (DifferentiationOptions::half_window_ns > 0)
  // until a stream's period is known.
  if (min_differentiation_half_window_ns <= 0) {
    return fail("min_differentiation_half_window_ns must be positive");
  }
  if (evaluation_margin_ns < 0) return fail("evaluation_margin_ns must not be negative");
  // The grid's period, core::PeriodFromRate(grid_rate_hz): at least 1 ns, and small enough
  // for a core::Time.
  if (!(grid_rate_hz >= 1e-9 && grid_rate_hz <= 1e9)) {
    return fail("grid_rate_hz must be in [1e-9, 1e9]");
  }
  if (max_interpolation_gap_ns <= 0) return fail("max_interpolation_gap_ns must be positive");
  if (bias_window_ns < 0) return fail("bias_window_ns must not be negative (0: off)");
  if (bias_window_ns > 0) {
    if (!bias.IsValid(&nested)) return fail("bias." + nested);
    if (bias_min_span_ns <= 0 || bias_min_span_ns > bias_window_ns) {
      return fail("bias_min_span_ns must be in (0, bias_window_ns]");
    }
    if (!(bias_false_alarm > 0.0 && bias_false_alarm < 1.0)) {
      return fail("bias_false_alarm must be in (0, 1)");
    }
  }
  return true;
}

struct ConsensusEstimator::Impl {
  struct Sensor {
    SensorSpec spec;
    int stream = 0;  // index in the matrix
    std::deque<RawSample> raw;
    std::vector<core::Time> first_stamps;  // for the period
    std::optional<core::Time> half_window_ns;
    std::optional<core::Time> last_velocity_ns;  // newest velocity sample in the matrix
    std::optional<GridResampler> grid;
    bool reports_twist = false;  // every sample so far carried a twist
    bool seen = false;
    // Position sensors: R_AL of the newest usable alignment. Its velocity stays comparable
    // while its alignment is re-estimated after an exclusion (R_AL changes only with the
    // slow drift of L), so a recovered sensor shows that it is consistent again.
    std::optional<Eigen::Matrix3d> last_R_AL;
    std::optional<core::Time> period_ns;
    // With the bias test: the grid's velocities of the IMU point in L, with covariances,
    // and for differentiated positions their newest stated covariance in L.
    VelocitySeries in_L;
    std::optional<Eigen::Matrix3d> position_covariance_L;
  };

  Impl(std::string imu, std::vector<SensorSpec> specs, MultiGraphEstimatorOptions estimator_options,
       ConsensusEstimatorOptions opts)
      : options(Validated(std::move(opts))),
        estimator(imu, specs, std::move(estimator_options)),
        selector(Names(specs), options.selection),
        matrix(StreamNames(specs), options.consistency),
        imu_name(std::move(imu)) {
    const core::Time grid_period = core::PeriodFromRate(options.grid_rate_hz);
    for (std::size_t i = 0; i < specs.size(); ++i) {
      Sensor s;
      s.spec = specs[i];
      s.stream = static_cast<int>(i);
      s.grid.emplace(grid_period, options.max_interpolation_gap_ns);
      sensors.push_back(std::move(s));
    }
    local_stream = static_cast<int>(specs.size());
    local_grid.emplace(grid_period, options.max_interpolation_gap_ns);
  }

  static std::vector<std::string> Names(const std::vector<SensorSpec>& specs) {
    std::vector<std::string> names;
    for (const SensorSpec& s : specs) names.push_back(s.name);
    return names;
  }
  static std::vector<std::string> StreamNames(const std::vector<SensorSpec>& specs) {
    std::vector<std::string> names = Names(specs);
    names.push_back("local");
    return names;
  }

  Sensor* Find(const std::string& name) {
    for (Sensor& s : sensors) {
      if (s.spec.name == name) return &s;
    }
    return nullptr;
  }

  core::Time HalfWindowOf(const Sensor& s) const {
    return s.half_window_ns.value_or(options.min_differentiation_half_window_ns);
  }

  core::Time Delay() const {
    core::Time half = 0;
    for (const Sensor& s : sensors) {
      if (!s.reports_twist) half = std::max(half, HalfWindowOf(s));
    }
    return half + options.evaluation_margin_ns;
  }

  void Buffer(Sensor& s, const core::StampedMeasurement& m) {
    RawSample r;
    r.t_ns = m.t_ns;
    if (const auto* pose = std::get_if<core::PoseMeasurement>(&m.value)) {
      if (!pose->p_Ss.allFinite() || !pose->q_Ss.coeffs().allFinite() || pose->q_Ss.norm() < 1e-9) return;
      r.p_As = pose->p_Ss;
      r.q_As = pose->q_Ss.normalized();
      r.cov_p_As = pose->covariance.bottomRightCorner<3, 3>();
      if (pose->has_twist && pose->v_s_s_mps.allFinite()) {
        r.v_s_mps = pose->v_s_s_mps;
        r.cov_v_s = pose->twist_covariance.topLeftCorner<3, 3>();
      }
    } else if (const auto* position = std::get_if<core::PositionMeasurement>(&m.value)) {
      if (!position->p_Ss.allFinite()) return;
      r.p_As = position->p_Ss;
      r.cov_p_As = position->covariance;
    } else {
      return;
    }
    // Late samples are inserted in time order; a stamp already there is a duplicate.
    auto it = std::upper_bound(s.raw.begin(), s.raw.end(), r.t_ns,
                               [](core::Time t, const RawSample& x) { return t < x.t_ns; });
    if (it != s.raw.begin() && std::prev(it)->t_ns == r.t_ns) return;
    // Too late: its velocity window was already evaluated.
    if (s.last_velocity_ns && r.t_ns <= *s.last_velocity_ns) return;
    s.reports_twist = (s.seen ? s.reports_twist : true) && r.v_s_mps.has_value();
    s.seen = true;
    s.raw.insert(it, r);
    if (!s.half_window_ns) {
      s.first_stamps.push_back(r.t_ns);
      if (s.first_stamps.size() >= kPeriodSamples) {
        std::sort(s.first_stamps.begin(), s.first_stamps.end());
        std::vector<core::Time> spacing;
        for (std::size_t k = 1; k < s.first_stamps.size(); ++k) {
          spacing.push_back(s.first_stamps[k] - s.first_stamps[k - 1]);
        }
        std::nth_element(spacing.begin(), spacing.begin() + spacing.size() / 2, spacing.end());
        const core::Time period = spacing[spacing.size() / 2];
        s.period_ns = period;
        // 1.5 periods + 10 % so a sample's neighbours on both sides are inside despite jitter.
        s.half_window_ns = std::max(options.min_differentiation_half_window_ns,
                                    period * 3 / 2 + period / 10);
      }
    }
  }

  // The local estimate nearest to t (outputs are 200 Hz: within 2.5 ms).
  const LocalSample* LocalAt(core::Time t) const {
    if (local.empty()) return nullptr;
    auto it = std::lower_bound(local.begin(), local.end(), t,
                               [](const LocalSample& x, core::Time tt) { return x.t_ns < tt; });
    if (it == local.end()) --it;
    if (it != local.begin() && t - std::prev(it)->t_ns < it->t_ns - t) --it;
    const core::Time max_gap = 20'000'000;
    if (std::llabs(it->t_ns - t) > max_gap || !it->valid) return nullptr;
    return &*it;
  }

  // The body rate at t for the lever-arm term: the gyro sample nearest t, corrected by the
  // newest bias estimate (none before the local graph exists: the raw rate, whose bias of
  // a few mrad/s moves a 0.2 m lever arm's velocity by < 1 mm/s).
  std::optional<Eigen::Vector3d> GyroAt(core::Time t) const {
    if (gyro.empty()) return std::nullopt;
    auto it = std::lower_bound(gyro.begin(), gyro.end(), t,
                               [](const auto& g, core::Time tt) { return g.first < tt; });
    if (it == gyro.end()) --it;
    if (it != gyro.begin() && t - std::prev(it)->first < it->first - t) --it;
    if (std::llabs(it->first - t) > 20'000'000) return std::nullopt;
    return it->second - gyro_bias_radps;
  }

  bool BiasTest() const { return options.bias_window_ns > 0; }

  // A grid velocity of the IMU point in I, into L through the local attitude at its time
  // (the bias test needs a frame in which a drift stays one vector while the robot turns).
  void AddInLocal(Sensor& s, core::Time t_ns, const Eigen::Vector3d& v_I,
                  const Eigen::Matrix3d& cov_I) {
    const LocalSample* l = LocalAt(t_ns);
    if (l == nullptr) return;
    VelocitySeries& series = s.in_L;
    if (!series.t_ns.empty() && t_ns <= series.t_ns.back()) return;
    series.t_ns.push_back(t_ns);
    series.v_mps.push_back(l->R_LI * v_I);
    series.cov_m2ps2.push_back(l->R_LI * cov_I * l->R_LI.transpose());
  }

  // What the errors of a stream's mean velocity are: a twist's white errors, correlated
  // over its sample period or the grid's; differentiated positions telescope.
  MeanNoise MeanNoiseOf(const Sensor& s) const {
    MeanNoise noise;
    const core::Time grid = core::PeriodFromRate(options.grid_rate_hz);
    noise.correlation_time_ns = std::max(grid, s.period_ns.value_or(grid));
    if (!s.reports_twist) noise.position_covariance_m2 = s.position_covariance_L;
    return noise;
  }

  // The mean-difference test of every sensor pair over the window since the pair was last
  // inconsistent by its value (or unavailable), into input.pair_biased and the record.
  void TestBias(core::Time t_eval, ConsensusInput& input, ConsensusRecord& record) {
    const int n = static_cast<int>(sensors.size());
    if (bias_from_ns.empty()) bias_from_ns.assign(input.pair.size(), INT64_MIN);
    input.pair_biased.assign(input.pair.size(), false);
    const core::Time keep_from = t_eval - options.bias_window_ns;
    for (Sensor& s : sensors) {
      const auto& t = s.in_L.t_ns;
      EraseFront(s.in_L, static_cast<std::size_t>(std::upper_bound(t.begin(), t.end(), keep_from) -
                                                   t.begin()));
    }
    for (int i = 0; i < n; ++i) {
      for (int j = i + 1; j < n; ++j) {
        const auto pair = static_cast<std::size_t>(ConsistencyMatrix::PairIndex(i, j, n));
        const Sensor& a = sensors[static_cast<std::size_t>(i)];
        const Sensor& b = sensors[static_cast<std::size_t>(j)];
        std::optional<double> chi2;
        const std::optional<double>& value = input.pair[pair];
        if (!value || !(*value < options.selection.threshold)) {
          bias_from_ns[pair] = t_eval;
        } else if (t_eval - std::max(keep_from, bias_from_ns[pair]) >= options.bias_min_span_ns &&
                   (a.reports_twist || a.position_covariance_L) &&
                   (b.reports_twist || b.position_covariance_L)) {
          MeanDifferenceOptions test = options.bias;
          test.a = MeanNoiseOf(a);
          test.b = MeanNoiseOf(b);
          test.estimate_rotation =
              a.spec.kind == SensorKind::kPosition || b.spec.kind == SensorKind::kPosition;
          // A drift that began t ago shows best over a window of about t (its mean grows
          // with t, the noise of the mean falls with √window): the window and its half and
          // quarter, each at a third of the false-alarm probability. The record keeps the
          // largest χ² (the bound is the same for each but where a window observes fewer
          // directions).
          const core::Time from = std::max(keep_from, bias_from_ns[pair]);
          for (const core::Time window : {t_eval - from, (t_eval - from) / 2, (t_eval - from) / 4}) {
            if (window < options.bias_min_span_ns) break;
            const std::optional<MeanDifference> d =
                WindowMeanDifference(a.in_L, b.in_L, t_eval - window, t_eval, test);
            if (!d) continue;
            chi2 = std::max(chi2.value_or(0.0), d->chi2);
            if (d->chi2 > ChiSquareUpperQuantile(d->dof, options.bias_false_alarm / 3.0)) {
              input.pair_biased[pair] = true;
            }
          }
        }
        record.bias_chi2.emplace_back(a.spec.name + "-" + b.spec.name, chi2);
      }
    }
  }

  // Velocities of the sensor's samples in (last_velocity, t_eval], as v_I of the IMU
  // point in I (paper eq. 1), onto the grid and into the matrix. The sensor's own twist
  // when it reports one (odometry does: the paper compares these), else its positions
  // differentiated by a local least-squares fit.
  void AddSensorVelocities(Sensor& s, core::Time t_eval) {
    if (s.raw.empty()) return;
    const Eigen::Matrix3d R_Is = s.spec.T_Is.linear();
    const Eigen::Vector3d p_Is = s.spec.T_Is.translation();
    // Covariances only where the metric or the bias test reads them: the paper's metrics
    // compare the numbers alone.
    const bool nis = options.consistency.metric == ConsistencyMetric::kNis;
    const bool stated = nis || BiasTest();
    const auto emit = [&](core::Time tg, const Eigen::Vector3d& v, const Eigen::Matrix3d* cov) {
      matrix.Add(s.stream, tg, v, nis ? cov : nullptr);
      if (BiasTest()) AddInLocal(s, tg, v, *cov);
    };
    const core::Time half = HalfWindowOf(s);
    if (s.reports_twist) {
      for (const RawSample& r : s.raw) {
        if (r.t_ns > t_eval) break;
        if (s.last_velocity_ns && r.t_ns <= *s.last_velocity_ns) continue;
        s.last_velocity_ns = r.t_ns;
        const std::optional<Eigen::Vector3d> omega_I = GyroAt(r.t_ns);
        if (!omega_I || !r.v_s_mps) continue;
        // v_I = R_Is v_s − ω_I × p_Is: the mount point's velocity moved to the IMU point.
        Eigen::Matrix3d cov_I;
        if (stated) cov_I = R_Is * r.cov_v_s * R_Is.transpose();
        s.grid->Add(r.t_ns, R_Is * *r.v_s_mps - omega_I->cross(p_Is), stated ? &cov_I : nullptr,
                    emit);
      }
    } else if (s.raw.size() >= 3) {
      DifferentiationOptions diff;
      diff.half_window_ns = half;
      diff.max_gap_ns = std::max<core::Time>(3 * half, 250'000'000);
      std::vector<core::Time> t;
      std::vector<Eigen::Vector3d> p;
      std::vector<Eigen::Matrix3d> cov_p;
      for (const RawSample& r : s.raw) {
        t.push_back(r.t_ns);
        p.push_back(r.p_As);
        if (stated) cov_p.push_back(r.cov_p_As);
      }
      const VelocitySeries v_A = DifferentiatePositions(t, p, cov_p, diff);
      std::optional<Eigen::Matrix3d> R_AL;
      if (s.spec.kind == SensorKind::kPosition) {
        if (const auto T_AL = estimator.AlignmentOf(s.spec.name)) s.last_R_AL = T_AL->linear();
        R_AL = s.last_R_AL;
      }
      for (std::size_t k = 0; k < v_A.t_ns.size(); ++k) {
        const core::Time tk = v_A.t_ns[k];
        if (tk > t_eval) break;
        if (s.last_velocity_ns && tk <= *s.last_velocity_ns) continue;
        // Marked done even when no velocity can be formed: it will not get better.
        s.last_velocity_ns = tk;
        const std::optional<Eigen::Vector3d> omega_I = GyroAt(tk);
        if (!omega_I) continue;
        const RawSample& raw = s.raw[static_cast<std::size_t>(
            std::lower_bound(t.begin(), t.end(), tk) - t.begin())];
        // The local attitude: a position sensor's comes from it (and its T_AL), and the
        // bias test takes every stream into L with it.
        const LocalSample* l =
            s.spec.kind == SensorKind::kPosition || BiasTest() ? LocalAt(tk) : nullptr;
        Eigen::Matrix3d R_AI;
        if (s.spec.kind == SensorKind::kPose) {
          R_AI = raw.q_As.toRotationMatrix() * R_Is.transpose();
        } else {
          // Without both (nothing fused yet, never aligned) it is unavailable.
          if (l == nullptr || !R_AL) continue;
          R_AI = *R_AL * l->R_LI;
        }
        // v_I = R_AIᵀ v_A(s) − ω_I × p_Is.
        Eigen::Matrix3d cov_I;
        if (stated) cov_I = R_AI.transpose() * v_A.cov_m2ps2[k] * R_AI;
        if (BiasTest() && l != nullptr) {
          const Eigen::Matrix3d R_LA = l->R_LI * R_AI.transpose();
          s.position_covariance_L = R_LA * raw.cov_p_As * R_LA.transpose();
        }
        s.grid->Add(tk, R_AI.transpose() * v_A.v_mps[k] - omega_I->cross(p_Is),
                    stated ? &cov_I : nullptr, emit);
      }
    }
    // Keep what the next fits need: a half window before the newest done sample.
    const core::Time keep_from = s.last_velocity_ns.value_or(s.raw.front().t_ns) - 2 * half;
    while (s.raw.size() > 3 && s.raw.front().t_ns < keep_from) s.raw.pop_front();
  }

  void AddLocalVelocities(core::Time t_eval) {
    // The local estimate states no velocity covariance: kNis takes it as exact next to the
    // sensor it is compared with (its velocity is IMU-driven, far steadier than a sensor's).
    const auto emit = [&](core::Time tg, const Eigen::Vector3d& v, const Eigen::Matrix3d*) {
      matrix.Add(local_stream, tg, v);
    };
    for (const LocalSample& l : local) {
      if (l.t_ns > t_eval) break;
      if (last_local_velocity_ns && l.t_ns <= *last_local_velocity_ns) continue;
      last_local_velocity_ns = l.t_ns;
      if (!l.valid) continue;
      local_grid->Add(l.t_ns, l.R_LI.transpose() * l.v_L_mps, nullptr, emit);
    }
    const core::Time keep_from = t_eval - options.consistency.history_ns;
    while (!local.empty() && local.front().t_ns < keep_from) local.pop_front();
    while (!gyro.empty() && gyro.front().first < keep_from) gyro.pop_front();
  }

  // A stream takes part in an evaluation only when its samples cover the window: enough
  // of them, reaching to its end (not stopped: a dropout) and spanning at least half of
  // it (not just resumed). A stream that stopped mid-window compares the velocities of
  // its last moments with the others' whole window and looks inconsistent while it is
  // merely gone.
  bool CoversWindow(int stream, core::Time t_eval) const {
    const std::vector<core::Time>& ts = matrix.Samples(stream).t_ns;
    const core::Time window = options.consistency.consistency.window_ns;
    const auto lo = std::upper_bound(ts.begin(), ts.end(), t_eval - window);
    const auto hi = std::upper_bound(ts.begin(), ts.end(), t_eval);
    if (hi - lo < options.consistency.consistency.min_samples) return false;
    const core::Time newest = *std::prev(hi);
    const core::Time oldest = *lo;
    return newest >= t_eval - options.max_interpolation_gap_ns && newest - oldest >= window / 2;
  }

  void Evaluate(core::Time t_now) {
    const core::Time t_eval = t_now - Delay();
    if (t_eval <= 0) return;
    for (Sensor& s : sensors) AddSensorVelocities(s, t_eval);
    AddLocalVelocities(t_eval);
    matrix.Evaluate(t_eval);

    const int n = static_cast<int>(sensors.size());
    ConsensusInput input;
    input.t_ns = t_now;
    for (int i = 0; i < n; ++i) {
      input.available.push_back(CoversWindow(i, t_eval));
      // A position sensor constrains the local graph only through a usable T_AL.
      const Sensor& sensor = sensors[static_cast<std::size_t>(i)];
      input.fusable.push_back(sensor.spec.kind == SensorKind::kPose ||
                              estimator.AlignmentOf(sensor.spec.name).has_value());
    }
    const bool local_covers = CoversWindow(local_stream, t_eval);
    ConsensusRecord record;
    record.t_ns = t_now;
    record.window_end_ns = t_eval;
    record.metric = options.consistency.metric;
    for (int i = 0; i < n; ++i) {
      for (int j = i + 1; j < n; ++j) {
        const std::optional<double> v = input.available[i] && input.available[j]
                                            ? matrix.Value(i, j)
                                            : std::optional<double>();
        input.pair.push_back(v);
        record.values.emplace_back(sensors[i].spec.name + "-" + sensors[j].spec.name, v);
      }
    }
    for (int i = 0; i < n; ++i) {
      const std::optional<double> v = local_covers && input.available[i]
                                          ? matrix.Value(i, local_stream)
                                          : std::optional<double>();
      input.vs_local.push_back(v);
      record.values.emplace_back(sensors[i].spec.name + "-local", v);
    }
    if (BiasTest()) TestBias(t_eval, input, record);
    record.decision = selector.Decide(input);
    // A fused sensor just found inconsistent was fused while its fault went unnoticed:
    // its factors since the start of the window that showed it go too (beyond the paper,
    // which only stops fusing it).
    const std::vector<std::string> previously_fused = estimator.fused_sensors();
    for (const std::string& name : record.decision.excluded) {
      if (std::find(previously_fused.begin(), previously_fused.end(), name) != previously_fused.end()) {
        estimator.DiscardSensor(name, t_eval - options.consistency.consistency.window_ns);
      }
    }
    if (record.decision.fused != estimator.fused_sensors()) {
      estimator.SetFusedSensors(record.decision.fused);
    }
    // The pairs an inconsistent sensor's alignment graph collected may hold the fault (a
    // jump, a drift): its T_AL is re-estimated from what comes after. Kept, they would
    // make the alignment unusable for a whole alignment window (20 s) after the fault
    // ended, and the recovered sensor unavailable that long.
    for (const std::string& name : record.decision.inconsistent) {
      estimator.RestartAlignment(name);
    }
    // The mission frame may follow any surveyed sensor consensus has not excluded: one it
    // cannot judge yet (unavailable to the matrix without a usable alignment) is checked
    // by its own fit.
    std::vector<std::string> candidates;
    for (const Sensor& sensor : sensors) {
      const std::string& name = sensor.spec.name;
      const auto& excluded = record.decision.excluded;
      if (std::find(excluded.begin(), excluded.end(), name) == excluded.end()) candidates.push_back(name);
    }
    estimator.SetMissionCandidates(candidates);
    records.push_back(std::move(record));
  }

  void CollectOutputs() {
    for (EstimatorOutput& o : estimator.TakeOutputs()) {
      LocalSample l;
      l.t_ns = o.t_ns;
      l.R_LI = o.state.q_LI.toRotationMatrix();
      l.v_L_mps = o.state.v_L_mps;
      l.omega_I_radps = o.omega_I_radps;
      l.valid = o.valid;
      if (o.initialized) gyro_bias_radps = o.bias.gyro_radps;
      if (local.empty() || l.t_ns > local.back().t_ns) local.push_back(l);
      outputs.push_back(std::move(o));
    }
  }

  ConsensusEstimatorOptions options;
  MultiGraphEstimator estimator;
  ConsensusSelector selector;
  ConsistencyMatrix matrix;
  std::string imu_name;
  std::vector<Sensor> sensors;
  int local_stream = 0;
  std::deque<LocalSample> local;
  std::deque<std::pair<core::Time, Eigen::Vector3d>> gyro;  // raw rate samples, time order
  Eigen::Vector3d gyro_bias_radps = Eigen::Vector3d::Zero();
  std::optional<core::Time> last_local_velocity_ns;
  std::vector<core::Time> bias_from_ns;  // per sensor pair: where its bias window starts
  std::optional<GridResampler> local_grid;
  std::optional<core::Time> next_evaluation_ns;
  std::vector<EstimatorOutput> outputs;
  std::vector<ConsensusRecord> records;
};

ConsensusEstimator::ConsensusEstimator(std::string imu_name, std::vector<SensorSpec> sensors,
                                       MultiGraphEstimatorOptions estimator_options,
                                       ConsensusEstimatorOptions options)
    : impl_(std::make_unique<Impl>(std::move(imu_name), std::move(sensors),
                                   std::move(estimator_options), std::move(options))) {}

ConsensusEstimator::~ConsensusEstimator() = default;

void ConsensusEstimator::Add(const core::StampedMeasurement& measurement) {
  Impl& impl = *impl_;
  const auto accepted_so_far = [&]() -> std::int64_t {
    const auto& streams = impl.estimator.counters().streams;
    const auto it = streams.find(measurement.sensor);
    return it == streams.end() ? 0 : it->second.accepted;
  };
  const std::int64_t accepted_before = accepted_so_far();
  impl.estimator.Add(measurement);
  impl.CollectOutputs();
  if (Impl::Sensor* s = impl.Find(measurement.sensor)) {
    // Only what the estimator's gate accepted takes part in consensus: a sensor whose
    // samples are all rejected (NaN covariances, stamps out of order) is unavailable,
    // never selected for a fusion that would then have nothing to fuse.
    if (accepted_so_far() > accepted_before) impl.Buffer(*s, measurement);
    return;
  }
  if (measurement.sensor != impl.imu_name) return;
  if (!std::holds_alternative<core::ImuMeasurement>(measurement.value)) return;
  // Evaluations are clocked by the IMU: the estimator's notion of "now".
  const core::Time t = measurement.t_ns;
  const auto& imu = std::get<core::ImuMeasurement>(measurement.value);
  if (imu.gyro_I_radps.allFinite() && (impl.gyro.empty() || t > impl.gyro.back().first)) {
    impl.gyro.emplace_back(t, imu.gyro_I_radps);
  }
  if (!impl.next_evaluation_ns) {
    impl.next_evaluation_ns = t - t % impl.options.evaluation_period_ns + impl.options.evaluation_period_ns;
  }
  // A stamp far ahead (a corrupted clock) must not trigger thousands of evaluations.
  if (t - *impl.next_evaluation_ns > 100 * impl.options.evaluation_period_ns) {
    impl.next_evaluation_ns = t - t % impl.options.evaluation_period_ns;
  }
  while (t >= *impl.next_evaluation_ns) {
    impl.Evaluate(*impl.next_evaluation_ns);
    *impl.next_evaluation_ns += impl.options.evaluation_period_ns;
  }
}

void ConsensusEstimator::SetMissionSurvey(MissionSurvey survey) {
  impl_->estimator.SetMissionSurvey(std::move(survey));
}

std::vector<EstimatorOutput> ConsensusEstimator::TakeOutputs() {
  impl_->CollectOutputs();
  return std::exchange(impl_->outputs, {});
}

std::vector<ConsensusRecord> ConsensusEstimator::TakeRecords() {
  return std::exchange(impl_->records, {});
}

const MultiGraphEstimator& ConsensusEstimator::estimator() const { return impl_->estimator; }
const ConsensusSelector& ConsensusEstimator::selector() const { return impl_->selector; }
core::Time ConsensusEstimator::evaluation_delay_ns() const { return impl_->Delay(); }

}  // namespace tofu::estimator
