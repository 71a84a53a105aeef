// Off-screen rendering speed (renders/): frames per second of render + read-back, and of
// render + read-back + encode (PNG keyframes; H.264 clips through the ffmpeg pipe, the
// encoder running in its own process). Results go to docs/BENCHMARKS.md ("Renders").
//
//   taskset -c 1 build/bench/bench_render --benchmark_repetitions=3
//
// CPU time is the whole process's (llvmpipe's rasteriser threads included; not ffmpeg's,
// a child process): on a core of its own, fps = 1000 / CPU [ms]. Wall time includes what
// other jobs take of the core.
//
// The run: $TOFU_BENCH_RUN_DIR if set (any tofu run directory), else a synthetic one
// written here: 20 s of a slow circle in the indoor arena, a total station with its line
// of sight, two estimates (ghosts) and consensus decisions, so that every layer is drawn.

#include <unistd.h>

#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <memory>

#include <Eigen/Geometry>
#include <benchmark/benchmark.h>
#include <fmt/format.h>

#include "renders/image_io.h"
#include "renders/run_data.h"
#include "renders/scene_renderer.h"

namespace {

namespace fs = std::filesystem;
using tofu::renders::Image;
using tofu::renders::RenderOptions;
using tofu::renders::RunData;
using tofu::renders::SceneRenderer;

constexpr double kDurationS = 20.0;

void Write(const fs::path& path, const std::string& text) {
  fs::create_directories(path.parent_path());
  std::ofstream(path, std::ios::binary) << text;
}

Eigen::Vector3d Circle_W(double t_s) {
  return {2.0 * std::cos(0.3 * t_s), 1.5 * std::sin(0.3 * t_s), 1.5};
}

fs::path SyntheticRun() {
  const fs::path dir = fs::temp_directory_path() / fmt::format("tofu_bench_render_{}", ::getpid());
  fs::remove_all(dir);
  Write(dir / "scenario.yaml", "name: bench_render\nworld: indoor_arena\nrobot: omav\n");
  std::string gt = "#timestamp [ns],p_WB_x [m],p_WB_y [m],p_WB_z [m],q_WB_w [],q_WB_x [],q_WB_y [],q_WB_z []\n";
  std::string leica = "#timestamp [ns],arrival [ns],p_Ss_x [m],p_Ss_y [m],p_Ss_z [m],conditions,faults\n";
  std::string decisions = "#timestamp [ns],method,fused,excluded,unavailable,reason\n";
  std::string consistency = "#timestamp [ns],pair,metric,value\n";
  std::string estimates[2] = {"", ""};
  for (std::string& e : estimates) {
    e = "#timestamp [ns],p_LI_x [m],p_LI_y [m],p_LI_z [m],q_LI_w [],q_LI_x [],q_LI_y [],q_LI_z [],valid,fused\n";
  }
  const Eigen::Vector3d station_W(-5.5, -4.5, 1.5);
  for (int k = 0; k <= static_cast<int>(kDurationS * 200); ++k) {
    const int64_t t_ns = int64_t{5'000'000} * k;
    const double t = 0.005 * k;
    const Eigen::Vector3d p = Circle_W(t);
    const Eigen::Quaterniond q(Eigen::AngleAxisd(0.3 * t + M_PI / 2, Eigen::Vector3d::UnitZ()));
    gt += fmt::format("{},{:.6f},{:.6f},{:.6f},{:.9f},0,0,{:.9f}\n", t_ns, p.x(), p.y(), p.z(), q.w(), q.z());
    for (int m = 0; m < 2; ++m) {
      // Estimates of the IMU frame (mount identity here) drifting away from the truth.
      const Eigen::Vector3d drift = (m + 1) * 0.02 * t * Eigen::Vector3d(1.0, -0.5, 0.1);
      estimates[m] += fmt::format("{},{:.6f},{:.6f},{:.6f},{:.9f},0,0,{:.9f},1,leica\n", t_ns,
                                  p.x() + drift.x(), p.y() + drift.y(), p.z() + drift.z(), q.w(), q.z());
    }
    if (k % 10 == 0) {
      const Eigen::Vector3d p_Ss = p + Eigen::Vector3d(0, 0.05, 0.3) - station_W;
      leica += fmt::format("{},{},{:.6f},{:.6f},{:.6f},,\n", t_ns, t_ns, p_Ss.x(), p_Ss.y(), p_Ss.z());
    }
    if (k % 20 == 0) {
      decisions += fmt::format("{},consensus,leica,vio,,\n", t_ns);
      consistency += fmt::format("{},leica-vio,pcc,{:.3f}\n{},leica-local,pcc,0.9\n{},vio-local,pcc,0.4\n",
                                 t_ns, 0.5 + 0.4 * std::sin(t), t_ns, t_ns);
    }
  }
  Write(dir / "groundtruth.csv", gt);
  Write(dir / "sensors" / "leica.csv", leica);
  Write(dir / "decisions.csv", decisions);
  Write(dir / "consistency_consensus.csv", consistency);
  for (int m = 0; m < 2; ++m) {
    const std::string name = m == 0 ? "consensus" : "naive";
    Write(dir / ("estimate_" + name + ".csv"), estimates[m]);
    Write(dir / ("estimate_" + name + ".json"),
          fmt::format(R"({{"method": "{}", "T_WL": {{"p_m": [0, 0, 0], "q_wxyz": [1, 0, 0, 0]}}}})", name));
  }
  Write(dir / "labels.csv", "#timestamp [ns],sensor,label,source,active\n10000000000,leica,occluded,condition,1\n");
  Write(dir / "calibration.yaml",
        "robot: omav\n"
        "mounts:\n"
        "  imu: {p_m: [0, 0, 0], q_wxyz: [1, 0, 0, 0]}\n"
        "  prism: {p_m: [0, 0.05, 0.30], q_wxyz: [1, 0, 0, 0]}\n"
        "sensors:\n"
        "  imu: {type: imu, site: imu, T_B_s: {p_m: [0, 0, 0], q_wxyz: [1, 0, 0, 0]},\n"
        "        true_T_WS: {p_m: [0, 0, 0], q_wxyz: [1, 0, 0, 0]}}\n"
        "  leica: {type: total_station, site: prism, T_B_s: {p_m: [0, 0.05, 0.30], q_wxyz: [1, 0, 0, 0]},\n"
        "          true_T_WS: {p_m: [-5.5, -4.5, 1.5], q_wxyz: [1, 0, 0, 0]}}\n");
  return dir;
}

// The synthetic run is read once and removed again at exit.
struct SyntheticRunDirectory {
  fs::path path = SyntheticRun();
  ~SyntheticRunDirectory() { fs::remove_all(path); }
};

const RunData& Run() {
  static const RunData run = [] {
    const char* env = std::getenv("TOFU_BENCH_RUN_DIR");
    if (env != nullptr && *env != '\0') return tofu::renders::ReadRunData(env);
    static const SyntheticRunDirectory synthetic;
    return tofu::renders::ReadRunData(synthetic.path);
  }();
  return run;
}

// Frame k of the benchmark: 30 fps through the run, wrapping around.
int64_t FrameTime(const RunData& run, int64_t k) {
  const int64_t span = run.end_ns() - run.start_ns();
  return run.start_ns() + (k * 1'000'000'000 / 30) % std::max<int64_t>(1, span);
}

RenderOptions Options(const benchmark::State& state) {
  RenderOptions o;
  o.width_px = 640;
  o.height_px = 480;
  o.shadows = state.range(0) != 0;
  o.reflections = state.range(0) != 0;
  o.multisamples = static_cast<int>(state.range(1));
  return o;
}

// Render + read-back (mjr_readPixels and the row flip).
void BM_RenderReadback(benchmark::State& state) {
  const RunData& run = Run();
  SceneRenderer renderer(run, Options(state));
  state.SetLabel(renderer.GlDescription());
  int64_t k = 0;
  for (auto _ : state) {
    const Image image = renderer.Render(FrameTime(run, k++), "chase");
    benchmark::DoNotOptimize(image.rgb.data());
  }
  state.counters["fps"] = benchmark::Counter(static_cast<double>(k), benchmark::Counter::kIsRate);
}

// Render + read-back + H.264 encode of a clip (frames piped to ffmpeg, as tofu render
// writes event clips; GIF when there is no ffmpeg).
void BM_RenderReadbackEncodeClip(benchmark::State& state) {
  const RunData& run = Run();
  SceneRenderer renderer(run, Options(state));
  const fs::path dir = fs::temp_directory_path() / fmt::format("tofu_bench_clip_{}", ::getpid());
  fs::create_directories(dir);
  int64_t k = 0;
  {
    tofu::renders::ClipWriter clip(dir / "clip", 640, 480, 30);
    state.SetLabel(clip.is_mp4() ? "mp4 (ffmpeg libx264)" : "gif (no ffmpeg)");
    for (auto _ : state) clip.Add(renderer.Render(FrameTime(run, k++), "chase"));
    clip.Finish();  // inside the timing: the encoder must have caught up
  }
  fs::remove_all(dir);
  state.counters["fps"] = benchmark::Counter(static_cast<double>(k), benchmark::Counter::kIsRate);
}

// Render + read-back + PNG encode (keyframes).
void BM_RenderReadbackEncodePng(benchmark::State& state) {
  const RunData& run = Run();
  SceneRenderer renderer(run, Options(state));
  const fs::path png = fs::temp_directory_path() / fmt::format("tofu_bench_{}.png", ::getpid());
  int64_t k = 0;
  for (auto _ : state) tofu::renders::WritePng(png, renderer.Render(FrameTime(run, k++), "chase"));
  fs::remove(png);
  state.counters["fps"] = benchmark::Counter(static_cast<double>(k), benchmark::Counter::kIsRate);
}

// Args: {shadows and reflections (0/1), MSAA samples}. MSAA 0 is what tofu render uses
// on a software rasteriser (multisamples -1: auto); 4 is its GPU default.
BENCHMARK(BM_RenderReadback)
    ->ArgNames({"shadows_reflections", "msaa"})
    ->Args({0, 0})
    ->Args({1, 0})
    ->Args({0, 4})
    ->Args({1, 4})
    ->Unit(benchmark::kMillisecond)
    ->MeasureProcessCPUTime()  // llvmpipe rasterises in its own threads
    ->UseRealTime();
BENCHMARK(BM_RenderReadbackEncodeClip)
    ->ArgNames({"shadows_reflections", "msaa"})
    ->Args({0, 0})
    ->Args({1, 0})
    ->Unit(benchmark::kMillisecond)
    ->MeasureProcessCPUTime()
    ->UseRealTime();
BENCHMARK(BM_RenderReadbackEncodePng)
    ->ArgNames({"shadows_reflections", "msaa"})
    ->Args({0, 0})
    ->Unit(benchmark::kMillisecond)
    ->MeasureProcessCPUTime()
    ->UseRealTime();

}  // namespace

BENCHMARK_MAIN();
