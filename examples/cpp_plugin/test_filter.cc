// The complementary filter's unit test, without tofu's binary and without a framework:
// synthetic IMU and total-station data of a smooth trajectory go through the filter's class
// (and, given the built module's path as argv[1], through the plug-in's C entry points
// after dlopen, as tofu loads it); every check prints PASS/FAIL and main exits 1 on any
// failure.
//
// Truth: W the world; the anchor's frame S is rotated 0.9 rad about z and offset in W, so
// L := S is tested with a non-trivial S; I is mounted yawed 90 deg in B and the prism s
// 0.33 m from I. IMU at 400 Hz, each sample the average over its interval (as tofu's
// simulated IMU): gyro = Log(R_WI(t_prev)^T R_WI(t)) / dt, specific force
// f_I = R_WI^T (a_WI - g_W) averaged over 8 sub-steps, g_W = (0, 0, -9.81); plus constant
// biases and seeded white noise. Fixes at 20 Hz, 3 mm noise, 10 ms latency (arriving after
// later IMU samples), one 2 m outlier, a 2.5 s dropout. The filter starts with yaw 0 while
// the true yaw of I in S is 56 deg: yaw must converge from the horizontal acceleration.

#include <dlfcn.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <functional>
#include <random>
#include <string>
#include <vector>

#include <Eigen/Core>
#include <Eigen/Geometry>

#include "complementary_filter.h"
#include "tofu/api.h"

namespace {

using Eigen::Isometry3d;
using Eigen::Quaterniond;
using Eigen::Vector3d;
using Mat3 = Eigen::Matrix3d;
namespace api = tofu::api;

constexpr double kPi = 3.14159265358979323846;
constexpr double kGravity_mps2 = 9.81;
constexpr std::int64_t kImuPeriod_ns = 2'500'000;   // 400 Hz
constexpr std::int64_t kFixPeriod_ns = 50'000'000;  // 20 Hz
constexpr std::int64_t kFixLatency_ns = 10'000'000;

int g_failures = 0;

void Check(bool ok, const std::string& what) {
  std::printf("%s  %s\n", ok ? "PASS" : "FAIL", what.c_str());
  if (!ok) ++g_failures;
}

std::string Fmt(const char* format, double a, double b = 0.0) {
  char buffer[256];
  std::snprintf(buffer, sizeof buffer, format, a, b);
  return buffer;
}

Mat3 Rz(double a) { return Eigen::AngleAxisd(a, Vector3d::UnitZ()).toRotationMatrix(); }
Mat3 Ry(double a) { return Eigen::AngleAxisd(a, Vector3d::UnitY()).toRotationMatrix(); }
Mat3 Rx(double a) { return Eigen::AngleAxisd(a, Vector3d::UnitX()).toRotationMatrix(); }

Vector3d LogSO3(const Mat3& R) {
  const Eigen::AngleAxisd aa(R);
  return aa.angle() * aa.axis();
}

api::Pose ToPose(const Isometry3d& T) {
  const Quaterniond q(T.linear());
  api::Pose pose;
  pose.p_m = {T.translation().x(), T.translation().y(), T.translation().z()};
  pose.q_wxyz = {q.w(), q.x(), q.y(), q.z()};
  return pose;
}

/// The synthetic world: the robot's trajectory and the fixed frames.
struct World {
  Isometry3d T_WS = Isometry3d::Identity();  ///< the anchor's frame S (= L) in W
  Isometry3d T_BI = Isometry3d::Identity();
  Vector3d p_Bs_m{0.10, -0.05, 0.30};        ///< the prism in B
  World() {
    T_WS.linear() = Rz(0.9);
    T_WS.translation() = Vector3d(5.0, -3.0, 0.2);
    T_BI.linear() = Rz(kPi / 2) * Rx(0.02);
    T_BI.translation() = Vector3d(0.02, -0.01, 0.05);
  }
  /// 0 until 1 s (at rest: the filter's start-up window), smooth to 1 at 3 s.
  static double Ramp(double t) {
    const double x = std::clamp((t - 1.0) / 2.0, 0.0, 1.0);
    return x * x * x * (10.0 - 15.0 * x + 6.0 * x * x);
  }
  /// A figure-eight with a vertical wobble (1 m/s, up to 1.3 m/s^2) and a swinging yaw.
  Isometry3d T_WB(double t) const {
    const double r = Ramp(t), w = 2.0 * kPi / 12.0;
    Isometry3d T = Isometry3d::Identity();
    T.translation() = Vector3d(0.0, 0.0, 1.5) +
                      r * Vector3d(2.0 * std::sin(w * t), 1.2 * std::sin(2.0 * w * t),
                                   0.3 * std::sin(0.5 * t));
    T.linear() = Rz(0.3 + r * 0.5 * std::sin(0.4 * t)) * Ry(r * 0.06 * std::sin(0.6 * t + 1.0)) *
                 Rx(r * 0.08 * std::sin(0.9 * t));
    return T;
  }
  Isometry3d T_WI(double t) const { return T_WB(t) * T_BI; }
  Isometry3d T_SI(double t) const { return T_WS.inverse() * T_WI(t); }
  Vector3d a_WI(double t) const {
    const double h = 1e-3;  // central second difference: error ~h^2/12 |p''''| < 1e-6
    return (T_WI(t + h).translation() - 2.0 * T_WI(t).translation() + T_WI(t - h).translation()) /
           (h * h);
  }
};

struct DataOptions {
  double duration_s = 60.0;
  std::uint32_t seed = 7;
  double gyro_noise_radps = 0.01;  // per sample (0.5 mrad/s/sqrt(Hz) at 400 Hz)
  double acc_noise_mps2 = 0.4;     // per sample (0.02 m/s^2/sqrt(Hz): white + vibration)
  Vector3d bias_gyro_radps{0.004, -0.003, 0.005};
  Vector3d bias_acc_mps2{0.05, -0.04, 0.06};
  double fix_std_m = 0.003;
  double outlier_at_s = 30.0;  // one fix 2 m off
  double dropout_from_s = 40.0, dropout_to_s = 42.5;
};

api::EstimatorSetup MakeSetup(const World& world, const std::string& config_json) {
  api::EstimatorSetup setup;
  setup.method = "plugin:cf";
  setup.gravity_mps2 = kGravity_mps2;
  setup.config_json = config_json;
  auto sensor = [](const char* name, api::SensorKind kind, const Isometry3d& T_Is) {
    api::SensorInfo info;
    info.name = name;
    info.kind = kind;
    info.T_Is = ToPose(T_Is);
    return info;
  };
  Isometry3d T_Bs = Isometry3d::Identity();
  T_Bs.translation() = world.p_Bs_m;
  // A pose sensor first: the default anchor is the first *position* sensor, and the filter
  // must ignore every other stream. Mounts are given in I: T_Is = T_BI^-1 T_Bs.
  const api::SensorInfo vio = sensor("vio", api::SensorKind::kPose, world.T_BI.inverse());
  const api::SensorInfo imu = sensor("imu", api::SensorKind::kImu, Isometry3d::Identity());
  const api::SensorInfo leica = sensor("leica", api::SensorKind::kPosition, world.T_BI.inverse() * T_Bs);
  setup.sensors = {vio, imu, leica};
  setup.imu = 1;
  return setup;
}

/// All samples in arrival order (ties: the IMU first).
std::vector<api::Measurement> MakeData(const World& world, const DataOptions& o) {
  std::mt19937 rng(o.seed);
  std::normal_distribution<double> n01(0.0, 1.0);
  auto noise = [&](double sigma) -> Vector3d { return Vector3d(n01(rng), n01(rng), n01(rng)) * sigma; };
  const Vector3d g_W(0.0, 0.0, -kGravity_mps2);
  std::vector<api::Measurement> out;
  const auto end_ns = static_cast<std::int64_t>(o.duration_s * 1e9);
  std::int64_t next_fix_ns = 0;
  for (std::int64_t t_ns = kImuPeriod_ns; t_ns <= end_ns; t_ns += kImuPeriod_ns) {
    const double t = static_cast<double>(t_ns) * 1e-9, dt = static_cast<double>(kImuPeriod_ns) * 1e-9;
    // Fixes that arrive before this IMU sample.
    while (next_fix_ns + kFixLatency_ns <= t_ns) {
      const double tf = static_cast<double>(next_fix_ns) * 1e-9;
      const bool dropped = tf >= o.dropout_from_s && tf < o.dropout_to_s;
      if (!dropped) {
        api::Measurement m;
        m.t_ns = next_fix_ns;
        m.arrival_ns = next_fix_ns + kFixLatency_ns;
        m.sensor = 2;
        m.kind = api::SensorKind::kPosition;
        Vector3d p_Ss = world.T_WS.inverse() * (world.T_WB(tf) * world.p_Bs_m) + noise(o.fix_std_m);
        if (std::abs(tf - o.outlier_at_s) < 1e-6) p_Ss += Vector3d(2.0, 0.0, 0.0);
        m.position.p_Ss_m = {p_Ss.x(), p_Ss.y(), p_Ss.z()};
        const double var = o.fix_std_m * o.fix_std_m;
        m.position.covariance_m2 = {var, 0, 0, 0, var, 0, 0, 0, var};
        out.push_back(m);
      }
      next_fix_ns += kFixPeriod_ns;
    }
    const Mat3 R0 = world.T_WI(t - dt).linear(), R1 = world.T_WI(t).linear();
    const Vector3d gyro = LogSO3(R0.transpose() * R1) / dt + o.bias_gyro_radps + noise(o.gyro_noise_radps);
    Vector3d f = Vector3d::Zero();
    for (int j = 0; j < 8; ++j) {
      const double tau = t - dt + (j + 0.5) * dt / 8.0;
      f += world.T_WI(tau).linear().transpose() * (world.a_WI(tau) - g_W) / 8.0;
    }
    f += o.bias_acc_mps2 + noise(o.acc_noise_mps2);
    api::Measurement m;
    m.t_ns = m.arrival_ns = t_ns;
    m.sensor = 1;
    m.kind = api::SensorKind::kImu;
    m.imu.acc_I_mps2 = {f.x(), f.y(), f.z()};
    m.imu.gyro_I_radps = {gyro.x(), gyro.y(), gyro.z()};
    out.push_back(m);
  }
  return out;
}

/// Errors of one estimate against the truth T_SI (L := S: no alignment).
struct Errors {
  double t_s, position_m, yaw_rad, tilt_rad, nees;
  bool valid;
  std::size_t fused;
};

Errors Evaluate(const World& world, const api::Estimate& e) {
  const double t = static_cast<double>(e.t_ns) * 1e-9;
  const Isometry3d T_SI = world.T_SI(t);
  const Vector3d p(e.T_LI.p_m[0], e.T_LI.p_m[1], e.T_LI.p_m[2]);
  const Mat3 R = Quaterniond(e.T_LI.q_wxyz[0], e.T_LI.q_wxyz[1], e.T_LI.q_wxyz[2], e.T_LI.q_wxyz[3])
                     .normalized()
                     .toRotationMatrix();
  const Mat3 D = R * T_SI.linear().transpose();  // attitude error, in L
  const Vector3d dp = p - T_SI.translation();
  double nees = -1.0;
  if (e.position_covariance_m2) {
    const Mat3 P = Eigen::Map<const Eigen::Matrix<double, 3, 3, Eigen::RowMajor>>(e.position_covariance_m2->data());
    nees = dp.dot(P.ldlt().solve(dp));
  }
  const double cos_tilt = (R.transpose() * Vector3d::UnitZ()).dot(T_SI.linear().transpose() * Vector3d::UnitZ());
  return {t, dp.norm(), std::atan2(D(1, 0), D(0, 0)), std::acos(std::clamp(cos_tilt, -1.0, 1.0)), nees,
          e.valid, e.fused ? e.fused->size() : 99};
}

struct RunResult {
  std::vector<Errors> errors;
  std::size_t imu_samples_after_init = 0;
  bool threw = false;
  std::string what;
};

RunResult Run(api::Estimator& estimator, const World& world, const std::vector<api::Measurement>& data,
              const std::string& config_json) {
  RunResult r;
  try {
    estimator.Start(MakeSetup(world, config_json));
    std::vector<api::Estimate> out;
    std::int64_t last_t = -1;
    bool non_decreasing = true;
    for (const auto& m : data) {
      out.clear();
      estimator.Add(m, &out);
      for (const auto& e : out) {
        non_decreasing = non_decreasing && e.t_ns >= last_t;
        last_t = e.t_ns;
        r.errors.push_back(Evaluate(world, e));
      }
    }
    if (!non_decreasing) r.what = "estimate times decrease";
  } catch (const std::exception& e) {
    r.threw = true;
    r.what = e.what();
  }
  return r;
}

struct Stats {
  double rms = 0.0, max = 0.0;
  std::size_t n = 0;
};
Stats Over(const RunResult& r, double from_s, double to_s, const std::function<double(const Errors&)>& f,
           bool skip_dropout = true) {
  Stats s;
  double sum = 0.0;
  for (const auto& e : r.errors) {
    if (e.t_s < from_s || e.t_s > to_s) continue;
    if (skip_dropout && e.t_s >= 40.0 && e.t_s < 45.0) continue;  // dead reckoning and re-entry
    const double v = f(e);
    sum += v * v;
    s.max = std::max(s.max, std::abs(v));
    ++s.n;
  }
  s.rms = s.n > 0 ? std::sqrt(sum / static_cast<double>(s.n)) : NAN;
  return s;
}
const Errors* At(const RunResult& r, double t_s) {
  for (const auto& e : r.errors) {
    if (e.t_s >= t_s) return &e;
  }
  return nullptr;
}
constexpr double kDeg = 180.0 / kPi;

// ---------------------------------------------------------------------------------------

void TestConvergence(const World& world, const std::vector<api::Measurement>& data) {
  std::printf("-- nominal run: 60 s, yaw starts 56 deg off --\n");
  tofu_example::ComplementaryFilter filter;
  const RunResult r = Run(filter, world, data, "{}");
  Check(!r.threw && r.what.empty(), "runs without error, estimate times non-decreasing " + r.what);
  Check(filter.initialized() && !r.errors.empty() && r.errors.front().t_s < 1.0,
        Fmt("initialised within 1 s (first estimate at %.3f s)", r.errors.empty() ? -1.0 : r.errors.front().t_s));
  // One estimate per IMU sample from initialisation on.
  std::size_t imu_after = 0;
  for (const auto& m : data) {
    if (m.kind == api::SensorKind::kImu && !r.errors.empty() && m.t_ns >= static_cast<std::int64_t>(std::llround(r.errors.front().t_s * 1e9))) ++imu_after;
  }
  Check(r.errors.size() == imu_after, Fmt("one estimate per IMU sample (%.0f of %.0f)", static_cast<double>(r.errors.size()), static_cast<double>(imu_after)));

  const auto yaw = [](const Errors& e) { return e.yaw_rad * kDeg; };
  const auto tilt = [](const Errors& e) { return e.tilt_rad * kDeg; };
  const auto pos = [](const Errors& e) { return e.position_m; };
  const Errors* start = At(r, 1.0);
  Check(start != nullptr && std::abs(start->yaw_rad * kDeg) > 40.0,
        Fmt("yaw unobserved at rest: error %.1f deg at 1 s (truth 56 deg off)", start ? start->yaw_rad * kDeg : NAN));
  const Stats yaw_late = Over(r, 20.0, 60.0, yaw);
  Check(yaw_late.max < 2.0, Fmt("yaw converged: max |error| over 20..60 s %.3f deg (< 2), rms %.3f", yaw_late.max, yaw_late.rms));
  const Stats tilt_all = Over(r, 5.0, 60.0, tilt);
  Check(tilt_all.max < 1.0, Fmt("tilt: max error over 5..60 s %.3f deg (< 1), rms %.3f", tilt_all.max, tilt_all.rms));
  const Stats pos_late = Over(r, 20.0, 60.0, pos);
  Check(pos_late.rms < 0.01 && pos_late.max < 0.03,
        Fmt("position over 20..60 s: rms %.4f m (< 0.01), max %.4f m (< 0.03)", pos_late.rms, pos_late.max));
  const Stats pos_outlier = Over(r, 29.9, 31.0, pos);
  Check(filter.fixes_rejected() >= 1 && pos_outlier.max < 0.03,
        Fmt("2 m outlier at 30 s rejected (%.0f rejected), max error around it %.4f m", filter.fixes_rejected(), pos_outlier.max));
  const Stats nees = Over(r, 20.0, 60.0, [](const Errors& e) { return std::sqrt(std::max(e.nees, 0.0)); });
  const double mean_nees = nees.rms * nees.rms;  // mean of NEES = rms of sqrt(NEES)^2
  Check(mean_nees > 0.2 && mean_nees < 15.0, Fmt("position NEES mean %.2f over 20..60 s (3 dof; accept 0.2..15)", mean_nees));
  const Vector3d bg_error = filter.bias_gyro_radps() - DataOptions{}.bias_gyro_radps;
  Check(bg_error.norm() < 1.5e-3, Fmt("gyro bias error %.5f rad/s (< 0.0015)", bg_error.norm()));
  Check(filter.fixes_too_old() == 0, Fmt("no fix older than the replay buffer (%.0f)", filter.fixes_too_old()));

  const Errors* before = At(r, 40.9);
  const Errors* silent = At(r, 41.6);
  const Errors* back = At(r, 43.0);
  Check(before && before->valid && before->fused == 1, "valid, fused {leica} 0.9 s into the dropout");
  Check(silent && !silent->valid && silent->fused == 0, "anchor silent > 1 s: valid = false, fused = {}");
  Check(back && back->valid && back->fused == 1, "anchor back: valid, fused {leica} again");
  const Stats pos_after = Over(r, 44.0, 46.0, pos, false);
  Check(pos_after.max < 0.03, Fmt("position after the dropout (44..46 s) max %.4f m", pos_after.max));

  std::printf("   accuracy: position rms %.2f mm (max %.2f), yaw rms %.3f deg, tilt rms %.3f deg\n",
              pos_late.rms * 1e3, pos_late.max * 1e3, yaw_late.rms, tilt_all.rms);
  std::printf("   report: %s\n", filter.ReportJson().c_str());
}

/// The same checks must fail on a filter that cannot observe yaw: the yaw gains at zero.
void TestNegativeControl(const World& world, const std::vector<api::Measurement>& data) {
  std::printf("-- negative control: yaw gains zero --\n");
  tofu_example::ComplementaryFilter filter;
  const RunResult r = Run(filter, world, data, R"({"gains": {"yaw_kp": 0, "yaw_kp_aligned": 0, "yaw_ki": 0}})");
  const Stats yaw_late = Over(r, 20.0, 60.0, [](const Errors& e) { return e.yaw_rad * kDeg; });
  const Stats pos_late = Over(r, 20.0, 60.0, [](const Errors& e) { return e.position_m; });
  Check(!r.threw && yaw_late.max > 20.0,
        Fmt("without yaw correction the yaw check would fail: max error %.1f deg (position rms %.4f m)", yaw_late.max, pos_late.rms));
}

/// valid_before_aligned = false: nothing is valid until yaw has been seen, then yaw is close.
void TestValidOnlyAligned(const World& world, const std::vector<api::Measurement>& data) {
  std::printf("-- valid_before_aligned: false --\n");
  tofu_example::ComplementaryFilter filter;
  const RunResult r = Run(filter, world, data, R"({"valid_before_aligned": false})");
  const Errors* first_valid = nullptr;
  for (const auto& e : r.errors) {
    if (e.valid) {
      first_valid = &e;
      break;
    }
  }
  Check(!r.threw && filter.aligned() && first_valid != nullptr &&
            std::abs(first_valid->t_s - static_cast<double>(filter.aligned_ns()) * 1e-9) < 0.1,
        Fmt("first valid estimate at %.2f s, when aligned (%.2f s)", first_valid ? first_valid->t_s : NAN,
            static_cast<double>(filter.aligned_ns()) * 1e-9));
  Check(first_valid != nullptr && std::abs(first_valid->yaw_rad * kDeg) < 5.0,
        Fmt("yaw error at the first valid estimate %.2f deg (< 5)", first_valid ? first_valid->yaw_rad * kDeg : NAN));
}

void TestConfig(const World& world) {
  std::printf("-- configuration --\n");
  auto throws = [&](const std::string& config, const std::string& needle) {
    tofu_example::ComplementaryFilter filter;
    try {
      filter.Start(MakeSetup(world, config));
    } catch (const std::exception& e) {
      return std::string(e.what()).find(needle) != std::string::npos;
    }
    return false;
  };
  Check(throws(R"({"gains": {"tilt_kP": 1}})", "gains.tilt_kP"), "unknown gain key named in the error");
  Check(throws(R"({"anchr": "leica"})", "anchr"), "unknown key named in the error");
  Check(throws(R"({"anchor": "gnss"})", "gnss"), "unknown anchor named in the error");
  Check(throws(R"({"anchor": "imu"})", "IMU"), "an IMU as anchor refused");
  Check(throws(R"({"match_window_s": -1})", "match_window_s"), "out-of-range value named");
  Check(throws("[1, 2", "not JSON"), "malformed JSON refused");
  Check(!throws(R"({"anchor": "leica", "gains": {"yaw_kp": 0.5}, "acc_noise": 0.3})", ""), "a valid config accepted");
}

/// The built module through its C entry points, as tofu loads it.
void TestModule(const char* path, const World& world, const std::vector<api::Measurement>& data) {
  std::printf("-- the module %s --\n", path);
  void* handle = dlopen(path, RTLD_NOW | RTLD_LOCAL);
  Check(handle != nullptr, std::string("dlopen: ") + (handle ? "ok" : dlerror()));
  if (handle == nullptr) return;
  using VersionFn = int (*)();
  using CreateFn = api::Estimator* (*)(const char*);
  using DestroyFn = void (*)(api::Estimator*);
  using CreateControllerFn = api::Controller* (*)(const char*);
  auto version = reinterpret_cast<VersionFn>(dlsym(handle, "tofu_plugin_api_version"));
  auto create = reinterpret_cast<CreateFn>(dlsym(handle, "tofu_create_estimator"));
  auto destroy = reinterpret_cast<DestroyFn>(dlsym(handle, "tofu_destroy_estimator"));
  auto create_controller = reinterpret_cast<CreateControllerFn>(dlsym(handle, "tofu_create_controller"));
  Check(version && create && destroy, "estimator entry points exported");
  Check(create_controller == nullptr, "no controller entry point (the library makes no controllers)");
  if (version && create && destroy) {
    Check(version() == TOFU_API_VERSION, Fmt("tofu_plugin_api_version() = %.0f", version()));
    // One estimator per library: any key of the scenario's plugins: map gets it.
    for (const char* name : {"cf", "complementary", "whatever_the_scenario_calls_it"}) {
      api::Estimator* e = create(name);
      Check(e != nullptr, std::string("tofu_create_estimator(\"") + name + "\") returns an estimator");
      if (e == nullptr) continue;
      if (std::string(name) == "cf") {
        const std::vector<api::Measurement> first(data.begin(), data.begin() + static_cast<long>(data.size() / 4));
        const RunResult r = Run(*e, world, first, "{}");
        const Errors* last = r.errors.empty() ? nullptr : &r.errors.back();
        Check(!r.threw && last && last->valid && last->position_m < 0.05,
              Fmt("runs through the module: valid at %.1f s, position error %.4f m", last ? last->t_s : NAN, last ? last->position_m : NAN));
      }
      destroy(e);
    }
  }
  dlclose(handle);
}

}  // namespace

int main(int argc, char** argv) {
  const World world;
  const std::vector<api::Measurement> data = MakeData(world, DataOptions{});
  TestConvergence(world, data);
  TestNegativeControl(world, data);
  TestValidOnlyAligned(world, data);
  TestConfig(world);
  if (argc > 1) TestModule(argv[1], world, data);
  std::printf("%s: %d failure(s)\n", g_failures == 0 ? "OK" : "FAILED", g_failures);
  return g_failures == 0 ? 0 : 1;
}
