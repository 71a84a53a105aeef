// renders/: off-screen EGL rendering of a run directory. These tests render in CI with no
// GPU and no display (EGL surfaceless + Mesa's llvmpipe): a frame is neither blank nor
// uniform, the ghost robot appears where the pinhole projection of its pose says, two
// renders are pixel-identical, failure events become keyframes and clips, and a machine
// without EGL gets a clear error, exit code 2 and an untouched run directory.
//
// The run directory is synthetic and tiny (4 s of hover in the indoor arena, a total
// station, one estimate displaced from the truth): every number below is chosen here.

#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <map>
#include <set>
#include <sstream>
#include <string>

#include <Eigen/Geometry>
#include <fmt/format.h>
#include <gtest/gtest.h>

#include "core/error.h"
#include "renders/events.h"
#include "renders/image_io.h"
#include "renders/render_command.h"
#include "renders/run_data.h"
#include "renders/scene_renderer.h"

namespace tofu::renders {
namespace {

namespace fs = std::filesystem;

constexpr int kWidth = 320;
constexpr int kHeight = 240;

// Truth: the robot drifts slowly along +x at 1.5 m, level, heading +x.
Eigen::Vector3d TruePosition_W(double t_s) { return {0.1 * t_s, 0.0, 1.5}; }
// The estimate "ghost": 0.3 m ahead, 0.8 m to the left (+y), 0.2 m lower, yawed 30 deg.
const Eigen::Vector3d kGhostOffset_W(0.3, 0.8, -0.2);
const double kGhostYaw_rad = 30.0 * M_PI / 180.0;
// IMU mount T_BI (as models/robots/omav.xml: upside down, offset).
Eigen::Isometry3d T_BI() {
  Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
  T.translation() = Eigen::Vector3d(0.03, -0.02, 0.04);
  T.linear() = Eigen::AngleAxisd(M_PI, Eigen::Vector3d::UnitX()).toRotationMatrix();
  return T;
}
const Eigen::Vector3d kPrism_B(0.0, 0.05, 0.30);
const Eigen::Vector3d kStation_W(-5.5, -4.5, 1.5);

void Write(const fs::path& path, const std::string& text) {
  fs::create_directories(path.parent_path());
  std::ofstream(path, std::ios::binary) << text;
}

std::string Read(const fs::path& path) {
  std::ifstream in(path, std::ios::binary);
  return std::string((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
}

// A minimal run directory in the layout `tofu run` + `tofu estimate` write.
fs::path MakeRunDirectory(const std::string& name) {
  const fs::path dir = fs::path(::testing::TempDir()) / fmt::format("render_test_{}_{}", name, ::getpid());
  fs::remove_all(dir);
  Write(dir / "scenario.yaml", "name: render_fixture\nworld: indoor_arena\nrobot: omav\n");

  std::string gt =
      "#timestamp [ns],p_WB_x [m],p_WB_y [m],p_WB_z [m],q_WB_w [],q_WB_x [],q_WB_y [],q_WB_z []\n";
  std::string estimate = "#timestamp [ns],p_LI_x [m],p_LI_y [m],p_LI_z [m],q_LI_w [],q_LI_x [],"
                         "q_LI_y [],q_LI_z [],valid,fused\n";
  std::string leica = "#timestamp [ns],arrival [ns],p_Ss_x [m],p_Ss_y [m],p_Ss_z [m],conditions,faults\n";
  std::string errors = "#timestamp [ns],method,position_error [m],rotation_error [deg],valid,nees\n";
  std::string decisions = "#timestamp [ns],method,fused,excluded,unavailable,reason\n";
  std::string consistency = "#timestamp [ns],pair,metric,value\n";
  for (int k = 0; k <= 400; ++k) {
    const int64_t t_ns = int64_t{10'000'000} * k;
    const double t = 0.01 * k;
    const Eigen::Vector3d p = TruePosition_W(t);
    gt += fmt::format("{},{:.6f},{:.6f},{:.6f},1,0,0,0\n", t_ns, p.x(), p.y(), p.z());
    Eigen::Isometry3d T_WB_ghost = Eigen::Isometry3d::Identity();
    T_WB_ghost.translation() = p + kGhostOffset_W;
    T_WB_ghost.linear() = Eigen::AngleAxisd(kGhostYaw_rad, Eigen::Vector3d::UnitZ()).toRotationMatrix();
    // With T_WL = identity the estimate of the IMU frame is T_LI = T_WB T_BI.
    const Eigen::Isometry3d T_LI = T_WB_ghost * T_BI();
    const Eigen::Quaterniond q(T_LI.linear());
    estimate += fmt::format("{},{:.6f},{:.6f},{:.6f},{:.9f},{:.9f},{:.9f},{:.9f},1,leica\n", t_ns,
                            T_LI.translation().x(), T_LI.translation().y(), T_LI.translation().z(),
                            q.w(), q.x(), q.y(), q.z());
    if (k % 5 == 0) {
      const Eigen::Vector3d p_Ss = p + kPrism_B - kStation_W;
      leica += fmt::format("{},{},{:.6f},{:.6f},{:.6f},,{}\n", t_ns, t_ns + 10'000'000, p_Ss.x(),
                           p_Ss.y(), p_Ss.z(), t >= 1.0 ? "non_gaussian_noise" : "");
    }
    if (k % 10 == 0) {
      // Position error: 0.3 m, above 0.5 m from 3 s on.
      errors += fmt::format("{},ghost,{:.3f},1.0,1,\n", t_ns, t < 3.0 ? 0.3 : 0.9);
      decisions += fmt::format("{},consensus,{},{},,{}\n", t_ns, t < 2.5 ? "leica" : "",
                               t < 2.5 ? "" : "leica", t < 2.5 ? "" : "inconsistent, pcc 0.1");
      consistency += fmt::format("{},leica-local,pcc,{:.3f}\n", t_ns, t < 2.5 ? 0.95 : 0.1);
    }
  }
  Write(dir / "groundtruth.csv", gt);
  Write(dir / "estimate_ghost.csv", estimate);
  Write(dir / "estimate_ghost.json",
        R"({"method": "ghost", "T_WL": {"p_m": [0, 0, 0], "q_wxyz": [1, 0, 0, 0]}})");
  Write(dir / "sensors" / "leica.csv", leica);
  Write(dir / "errors.csv", errors);
  Write(dir / "decisions.csv", decisions);
  Write(dir / "consistency_consensus.csv", consistency);
  Write(dir / "labels.csv",
        "#timestamp [ns],sensor,label,source,active\n"
        "1000000000,leica,non_gaussian_noise,fault,1\n"
        "2000000000,leica,occluded,condition,1\n");
  Write(dir / "summary.json",
        R"({"collisions": [{"start_s": 3.5, "end_s": 3.6, "robot_geom": "foot_1", "structure_geom": "column"}]})");
  Write(dir / "calibration.yaml",
        "robot: omav\n"
        "mounts:\n"
        "  imu: {p_m: [0.03, -0.02, 0.04], q_wxyz: [0, 1, 0, 0]}\n"
        "  prism: {p_m: [0, 0.05, 0.30], q_wxyz: [1, 0, 0, 0]}\n"
        "sensors:\n"
        "  imu:\n"
        "    type: imu\n"
        "    site: imu\n"
        "    T_B_s: {p_m: [0.03, -0.02, 0.04], q_wxyz: [0, 1, 0, 0]}\n"
        "    true_T_WS: {p_m: [0, 0, 0], q_wxyz: [1, 0, 0, 0]}\n"
        "  leica:\n"
        "    type: total_station\n"
        "    site: prism\n"
        "    T_B_s: {p_m: [0, 0.05, 0.30], q_wxyz: [1, 0, 0, 0]}\n"
        "    true_T_WS: {p_m: [-5.5, -4.5, 1.5], q_wxyz: [1, 0, 0, 0]}\n");
  return dir;
}

// A run directory for one test, removed when the test ends (kept when it failed, to look at).
class RunDirectory {
 public:
  explicit RunDirectory(const std::string& name) : path_(MakeRunDirectory(name)) {}
  ~RunDirectory() {
    if (!::testing::Test::HasFailure()) fs::remove_all(path_);
  }
  RunDirectory(const RunDirectory&) = delete;
  RunDirectory& operator=(const RunDirectory&) = delete;
  operator const fs::path&() const { return path_; }
  std::string string() const { return path_.string(); }
  fs::path operator/(const std::string& name) const { return path_ / name; }

 private:
  fs::path path_;
};

RenderOptions SmallOptions() {
  RenderOptions o;
  o.width_px = kWidth;
  o.height_px = kHeight;
  return o;
}

// Pinhole projection with the camera MuJoCo used: centre, axes and vertical field of view.
Eigen::Vector2d Project(const CameraView& view, const Eigen::Vector3d& p_W) {
  const Eigen::Vector3d d = p_W - view.p_W;
  const Eigen::Vector3d right = view.forward_W.cross(view.up_W);
  const double z = d.dot(view.forward_W);
  const double f_px = 0.5 * view.height_px / std::tan(0.5 * view.fovy_deg * M_PI / 180.0);
  return {0.5 * view.width_px + f_px * d.dot(right) / z, 0.5 * view.height_px - f_px * d.dot(view.up_W) / z};
}

// The first ghost's colour is magenta: strong red and blue, little green.
bool IsGhostPixel(const uint8_t* p) { return p[0] > p[1] + 60 && p[2] > p[1] + 40; }

struct PixelStats {
  int count = 0;
  Eigen::Vector2d centroid = Eigen::Vector2d::Zero();
};

// Ghost-coloured pixels of `image` in [x0, x1) x [y0, y1) that are not ghost-coloured in
// `without` (the same frame rendered without ghosts; a red line crossing a blue marker
// blends to a purple pixel or two).
PixelStats GhostPixels(const Image& image, const Image& without, int x0, int y0, int x1, int y1) {
  PixelStats s;
  for (int y = std::max(0, y0); y < std::min(image.height, y1); ++y) {
    for (int x = std::max(0, x0); x < std::min(image.width, x1); ++x) {
      if (!IsGhostPixel(image.Pixel(x, y)) || IsGhostPixel(without.Pixel(x, y))) continue;
      ++s.count;
      s.centroid += Eigen::Vector2d(x + 0.5, y + 0.5);
    }
  }
  if (s.count > 0) s.centroid /= s.count;
  return s;
}

TEST(Render, FrameIsNeitherBlankNorUniform) {
  const RunDirectory dir("blank");
  const RunData run = ReadRunData(dir);
  SceneRenderer renderer(run, SmallOptions());
  std::cout << renderer.GlDescription() << "\n";
  for (const std::string camera : {"chase", "overview"}) {
    const Image image = renderer.Render(2'000'000'000, camera);
    ASSERT_EQ(image.width, kWidth);
    ASSERT_EQ(image.height, kHeight);
    double sum = 0.0;
    double sum_sq = 0.0;
    std::set<uint32_t> colours;
    for (size_t i = 0; i < image.rgb.size(); i += 3) {
      const double luma = (image.rgb[i] + image.rgb[i + 1] + image.rgb[i + 2]) / 3.0;
      sum += luma;
      sum_sq += luma * luma;
      colours.insert(image.rgb[i] << 16 | image.rgb[i + 1] << 8 | image.rgb[i + 2]);
    }
    const double n = image.rgb.size() / 3.0;
    const double mean = sum / n;
    const double stddev = std::sqrt(std::max(0.0, sum_sq / n - mean * mean));
    EXPECT_GT(mean, 20.0) << camera << ": nearly black";
    EXPECT_LT(mean, 240.0) << camera << ": nearly white";
    EXPECT_GT(stddev, 15.0) << camera << ": nearly uniform";
    EXPECT_GT(colours.size(), 500u) << camera;
  }
}

TEST(Render, GhostAppearsWhereItsPoseProjects) {
  const RunDirectory dir("ghost");
  const RunData run = ReadRunData(dir);
  ASSERT_EQ(run.estimates.size(), 1u);
  const double t_s = 2.0;
  const core::Time t_ns = core::SecondsToTime(t_s);
  const Eigen::Vector3d ghost_W = TruePosition_W(t_s) + kGhostOffset_W;

  // The 3D scene only: the legend and the inset are not what is tested here.
  RenderOptions options = SmallOptions();
  options.text_overlay = false;
  options.heatmap = false;
  RenderOptions no_ghosts = options;
  no_ghosts.ghosts = false;
  SceneRenderer renderer(run, options);
  SceneRenderer no_ghost_renderer(run, no_ghosts);
  for (const std::string camera : {"chase", "overview"}) {
    const Image image = renderer.Render(t_ns, camera);
    const Image without = no_ghost_renderer.Render(t_ns, camera);
    // Without ghosts the ghost colour is (nearly) absent: the colour test is specific.
    const Image black(kWidth, kHeight);
    EXPECT_LT(GhostPixels(without, black, 0, 0, kWidth, kHeight).count, kWidth * kHeight / 500)
        << camera;

    const Eigen::Vector2d uv = Project(renderer.last_view(), ghost_W);
    ASSERT_GT(uv.x(), 20);
    ASSERT_LT(uv.x(), kWidth - 20);
    ASSERT_GT(uv.y(), 20);
    ASSERT_LT(uv.y(), kHeight - 20);
    const int u = static_cast<int>(uv.x());
    const int v = static_cast<int>(uv.y());
    // Ghost-coloured pixels right at the projected body origin (the hub)...
    const PixelStats near = GhostPixels(image, without, u - 5, v - 5, u + 6, v + 6);
    EXPECT_GE(near.count, 15) << camera << ": projected at (" << u << ", " << v << ")";
    // ...and the ghost as a whole centred there (the robot is nearly symmetric about its
    // centre; the landing gear below pulls the centroid down a little).
    const PixelStats all = GhostPixels(image, without, 0, 0, kWidth, kHeight);
    EXPECT_GT(all.count, 100) << camera;
    EXPECT_LT((all.centroid - uv).norm(), 0.06 * kHeight)
        << camera << ": centroid (" << all.centroid.transpose() << ") vs projection ("
        << uv.transpose() << ")";
    // Not at the true robot, 0.8 m away.
    const Eigen::Vector2d truth_uv = Project(renderer.last_view(), TruePosition_W(t_s));
    const int tu = static_cast<int>(truth_uv.x());
    const int tv = static_cast<int>(truth_uv.y());
    EXPECT_EQ(GhostPixels(image, without, tu - 3, tv - 3, tu + 4, tv + 4).count, 0) << camera;
  }
}

TEST(Render, TwoRendersOfTheSameFrameArePixelIdentical) {
  const RunDirectory dir("twice");
  const RunData run = ReadRunData(dir);
  Image first;
  {
    SceneRenderer renderer(run, SmallOptions());
    first = renderer.Render(1'500'000'000, "chase", "caption");
    renderer.Render(3'000'000'000, "overview");  // other state in between
    const Image again = renderer.Render(1'500'000'000, "chase", "caption");
    EXPECT_TRUE(first.rgb == again.rgb) << "same renderer";
  }
  SceneRenderer fresh(run, SmallOptions());
  const Image second = fresh.Render(1'500'000'000, "chase", "caption");
  EXPECT_TRUE(first.rgb == second.rgb) << "new renderer";
  // And the same PNG bytes.
  WritePng(dir / "a.png", first);
  WritePng(dir / "b.png", second);
  EXPECT_EQ(Read(dir / "a.png"), Read(dir / "b.png"));
  const Image back = ReadPng(dir / "a.png");
  EXPECT_TRUE(back.rgb == first.rgb);
}

std::vector<std::string> Describe(const std::vector<RenderEvent>& events) {
  std::vector<std::string> out;
  for (const RenderEvent& e : events) {
    out.push_back(fmt::format("{:.1f} {} {}", core::TimeToSeconds(e.t_ns), EventKindName(e.kind), e.subject));
  }
  return out;
}

// The options say what is wrong through IsValid ("<option>: <problem>", named as on the
// CLI); a render refuses them as the user's error at that option.
TEST(RenderOptionsCheck, IsValidNamesTheOptionAndARenderRefusesIt) {
  EXPECT_TRUE(RenderEventsOptions{}.IsValid());
  RenderEventsOptions options;
  options.render.width_px = 8;
  std::string why;
  EXPECT_FALSE(options.IsValid(&why));
  EXPECT_EQ(why, "--size: expected WxH with each side in [16, 8192], got 8x480");
  options = RenderEventsOptions{};
  options.fps = 0;
  EXPECT_FALSE(options.IsValid(&why));
  EXPECT_EQ(why, "--fps: expected 1..240 frames per second, got 0");

  const RunDirectory dir("events");
  const RunData run = ReadRunData(dir);
  EventOptions events;
  events.error_bound_m = -1.0;
  try {
    FindEvents(run, events);
    FAIL() << "a negative error bound was accepted";
  } catch (const core::InputError& e) {
    EXPECT_EQ(e.location().file, "render options");
    EXPECT_EQ(e.key_path(), "--error-bound");
    EXPECT_EQ(e.message(), "expected a positive bound in metres, got -1");
  }
}

TEST(RenderEvents, ChosenFromFaultsDecisionsErrorsAndCollisions) {
  const RunDirectory dir("events");
  const RunData run = ReadRunData(dir);
  EventOptions options;
  options.settle_s = 0.5;
  EXPECT_EQ(Describe(FindEvents(run, options)),
            (std::vector<std::string>{"1.0 fault_onset leica", "2.5 detection leica",
                                      "2.5 sensor_switch consensus", "3.0 error_above_bound ghost",
                                      "3.5 collision column"}));
  // With the default 5 s of start-up, this 4 s run's decisions and errors are all start-up.
  EXPECT_EQ(Describe(FindEvents(run)),
            (std::vector<std::string>{"1.0 fault_onset leica", "3.5 collision column"}));
  // A bound the error never fell below: no onset to show.
  options.error_bound_m = 0.2;
  for (const RenderEvent& e : FindEvents(run, options)) EXPECT_NE(e.kind, EventKind::kErrorAboveBound);
}

// A closed-loop flight (closed_loop/<method>/): its true path is a ghost "flown on
// <method>" and its collision an event of the run, drawn where that flight's robot was.
TEST(RenderRunData, ClosedLoopFlightsAreGhostsAndTheirCollisionsEvents) {
  const RunDirectory dir("closed_loop");
  const fs::path flight = dir / "closed_loop" / "naive";
  std::string gt =
      "#timestamp [ns],p_WB_x [m],p_WB_y [m],p_WB_z [m],q_WB_w [],q_WB_x [],q_WB_y [],q_WB_z []\n";
  for (int k = 0; k <= 400; ++k) {
    const Eigen::Vector3d p = TruePosition_W(0.01 * k) + Eigen::Vector3d(0.0, 0.8, 0.0);
    gt += fmt::format("{},{:.6f},{:.6f},{:.6f},1,0,0,0\n", int64_t{10'000'000} * k, p.x(), p.y(),
                      p.z());
  }
  Write(flight / "groundtruth.csv", gt);
  Write(flight / "summary.json",
        R"({"collisions": [{"start_s": 2.2, "end_s": 2.3, "robot_geom": "arm_2", "structure_geom": "wall_east"}]})");
  const RunData run = ReadRunData(dir);
  const auto ghost = std::find_if(run.estimates.begin(), run.estimates.end(),
                                  [](const MethodEstimate& e) { return e.method == "flown on naive"; });
  ASSERT_NE(ghost, run.estimates.end());
  ASSERT_EQ(ghost->T_WB.size(), 401u);
  EXPECT_NEAR(ghost->T_WB[100].p_W.y(), TruePosition_W(1.0).y() + 0.8, 1e-6);
  EventOptions options;
  options.settle_s = 0.5;
  const std::vector<std::string> events = Describe(FindEvents(run, options));
  EXPECT_NE(std::find(events.begin(), events.end(), "2.2 collision wall_east"), events.end());
  // Drawn: the frame with the flight's ghost differs from the frame with the estimate's only.
  RenderOptions o = SmallOptions();
  o.text_overlay = false;
  o.heatmap = false;
  o.methods = {"flown on naive"};
  SceneRenderer with(run, o);
  o.methods = {"ghost"};
  SceneRenderer without(run, o);
  EXPECT_NE(with.Render(core::SecondsToTime(2.2), "overview").rgb,
            without.Render(core::SecondsToTime(2.2), "overview").rgb);
}

TEST(RenderEvents, FlappingMergesIntoOneClipAndTheTotalKeepsTheTellingKinds) {
  RunData run;
  const auto decision = [](double t_s, std::vector<std::string> fused, std::vector<std::string> excluded) {
    DecisionRow d;
    d.t_ns = core::SecondsToTime(t_s);
    d.method = "consensus";
    d.fused = std::move(fused);
    d.excluded = std::move(excluded);
    return d;
  };
  run.decisions = {decision(0.0, {"vio"}, {}),         decision(6.0, {"leica"}, {"vio"}),
                   decision(6.1, {"vio"}, {}),         decision(6.2, {"leica"}, {"vio"}),
                   decision(11.0, {"vio"}, {}),        decision(12.0, {"leica"}, {"vio"})};
  EXPECT_EQ(Describe(FindEvents(run)),
            (std::vector<std::string>{"6.0 detection vio", "6.0 sensor_switch consensus",
                                      "11.0 sensor_switch consensus", "12.0 detection vio"}));
  // Two events at most: the detections outrank the switches.
  EventOptions two;
  two.max_events = 2;
  EXPECT_EQ(Describe(FindEvents(run, two)),
            (std::vector<std::string>{"6.0 detection vio", "12.0 detection vio"}));
  EXPECT_NE(FindEvents(run, two)[0].detail.find("false alarm"), std::string::npos);
  // A fault of vio from 11.5 s: its detection at 12 s outranks the false alarm at 6 s.
  run.labels = {{core::SecondsToTime(11.5), "vio", "divergence", "fault", true}};
  EventOptions one;
  one.max_events = 2;
  EXPECT_EQ(Describe(FindEvents(run, one)),
            (std::vector<std::string>{"11.5 fault_onset vio", "12.0 detection vio"}));
  EXPECT_NE(FindEvents(run, one)[1].detail.find("fault divergence"), std::string::npos);
}

TEST(RenderEvents, KeyframesAndClipsReplaceTheRendersDirectory) {
  const RunDirectory dir("clips");
  Write(dir / "renders" / "stale.png", "old");
  RenderEventsOptions options;
  options.render = SmallOptions();
  options.render.width_px = 160;
  options.render.height_px = 120;
  options.fps = 4;
  options.events.settle_s = 0.5;
  options.clip_half_s = 0.1;  // one frame per clip: the encoder path, quickly
  const RenderEventsResult result = RenderRunEvents(dir, options);
  ASSERT_EQ(result.events.size(), 5u);
  EXPECT_FALSE(fs::exists(dir / "renders" / "stale.png"));
  for (const RenderedEvent& r : result.events) {
    EXPECT_TRUE(fs::is_regular_file(r.keyframe)) << r.keyframe;
    ASSERT_TRUE(r.clip.has_value());
    EXPECT_TRUE(fs::is_regular_file(*r.clip)) << *r.clip;
    EXPECT_GT(fs::file_size(*r.clip), 100u);
    EXPECT_EQ(r.keyframe.parent_path(), fs::absolute(dir / "renders").lexically_normal());
  }
  const std::string csv = Read(dir / "renders" / "events.csv");
  EXPECT_NE(csv.find("fault_onset,leica"), std::string::npos) << csv;
  EXPECT_NE(csv.find("collision,column"), std::string::npos) << csv;
  // Nothing else of the run directory was touched, no staging directory left behind.
  for (const auto& entry : fs::directory_iterator(dir)) {
    EXPECT_EQ(entry.path().filename().string().find(".renders."), std::string::npos) << entry.path();
  }

  // A bad camera fails before any file is written: the previous renders stay.
  const std::string before = Read(dir / "renders" / "events.csv");
  options.camera = "no_such_camera";
  EXPECT_THROW(RenderRunEvents(dir, options), core::InputError);
  EXPECT_EQ(Read(dir / "renders" / "events.csv"), before);
}

TEST(RenderClips, GifFallbackDecodesToTheFrames) {
  const fs::path dir = fs::path(::testing::TempDir()) / fmt::format("render_gif_{}", ::getpid());
  fs::create_directories(dir);
  const struct RemoveAtEnd {
    fs::path path;
    ~RemoveAtEnd() { fs::remove_all(path); }
  } remove_at_end{dir};
  // A gradient with a moving bar: many colours, long LZW runs and table resets.
  std::vector<Image> frames;
  for (int k = 0; k < 3; ++k) {
    Image image(96, 64);
    for (int y = 0; y < image.height; ++y) {
      for (int x = 0; x < image.width; ++x) {
        uint8_t* p = image.Pixel(x, y);
        p[0] = static_cast<uint8_t>(x * 255 / 95);
        p[1] = static_cast<uint8_t>(y * 255 / 63);
        p[2] = (x / 8 == k * 3) ? 255 : 40;
      }
    }
    frames.push_back(image);
  }
  ClipWriter gif(dir / "clip", 96, 64, 10, /*ffmpeg=*/"");
  ASSERT_FALSE(gif.is_mp4());
  for (const Image& f : frames) gif.Add(f);
  const fs::path path = gif.Finish();
  ASSERT_EQ(path.extension(), ".gif");
  const std::string bytes = Read(path);
  ASSERT_GT(bytes.size(), 800u);
  EXPECT_EQ(bytes.substr(0, 6), "GIF89a");
  EXPECT_EQ(bytes.back(), '\x3B');

  // Decode with ffmpeg when the machine has it: the dithered palette stays within a
  // quantisation step of the frames on average.
  const std::string ffmpeg = FindFfmpeg();
  if (ffmpeg.empty()) GTEST_SKIP() << "no ffmpeg to decode the GIF";
  const fs::path raw = dir / "frames.rgb";
  const std::string command = fmt::format("'{}' -hide_banner -loglevel error -y -i '{}' -f rawvideo -pix_fmt rgb24 '{}'",
                                          ffmpeg, path.string(), raw.string());
  ASSERT_EQ(std::system(command.c_str()), 0) << command;
  const std::string decoded = Read(raw);
  ASSERT_EQ(decoded.size(), frames.size() * frames[0].rgb.size());
  for (size_t k = 0; k < frames.size(); ++k) {
    double error = 0.0;
    for (size_t i = 0; i < frames[k].rgb.size(); ++i) {
      error += std::abs(static_cast<int>(static_cast<uint8_t>(decoded[k * frames[k].rgb.size() + i])) -
                        static_cast<int>(frames[k].rgb[i]));
    }
    EXPECT_LT(error / frames[k].rgb.size(), 30.0) << "frame " << k;
  }
}

TEST(RenderRunData, MalformedCsvNamesFileLineAndColumn) {
  const RunDirectory dir("malformed");
  std::string gt = Read(dir / "groundtruth.csv");
  // Line 4, second field (p_WB_x): not a number.
  size_t line4 = 0;
  for (int k = 0; k < 3; ++k) line4 = gt.find('\n', line4) + 1;
  const size_t field = gt.find(',', line4) + 1;
  gt.replace(field, gt.find(',', field) - field, "abc");
  Write(dir / "groundtruth.csv", gt);
  try {
    ReadRunData(dir);
    FAIL() << "expected an InputError";
  } catch (const core::InputError& e) {
    EXPECT_EQ(e.location().line, 4) << e.what();
    EXPECT_GT(e.location().column, 1) << e.what();
    EXPECT_NE(std::string(e.what()).find("groundtruth.csv"), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find("p_WB_x"), std::string::npos) << e.what();
  }
}

// Sensor geometry is the run directory's (calibration.yaml), never the scenario's: a LiDAR's
// beams from its options, a GNSS antenna's sky from the directions the run recorded. The
// renderer includes nothing of harness (ctest `layering`); these layers would be empty,
// and the frames equal, if it did not read them.
constexpr char kGeometrySensors[] =
    "  gnss:\n"
    "    type: gnss\n"
    "    site: prism\n"
    "    true_T_WS: {p_m: [0, 0, 0], q_wxyz: [1, 0, 0, 0]}\n"
    "    sky_directions_S: [[0, 0, 1], [0.6, 0, 0.8], [0, -0.8, 0.6]]\n"
    "    options: {site: prism, sky_ray_length_m: 150}\n"
    "  lidar:\n"
    "    type: lidar_odometry\n"
    "    site: prism\n"
    "    options: {site: prism, azimuth_count: 36, elevation_count: 3, elevation_min_deg: -10,\n"
    "              elevation_max_deg: 20, min_range_m: 0.5, max_range_m: 30}\n";

TEST(RenderRunData, SensorGeometryComesFromTheRunDirectory) {
  const RunDirectory dir("geometry");
  Write(dir / "calibration.yaml", Read(dir / "calibration.yaml") + kGeometrySensors);
  const RunData run = ReadRunData(dir);
  const std::vector<SkyGeometry> skies = SkyGeometries(run);
  ASSERT_EQ(skies.size(), 1u);
  EXPECT_EQ(skies[0].site, "prism");
  EXPECT_EQ(skies[0].ray_length_m, 150.0);
  ASSERT_EQ(skies[0].directions_S.size(), 3u);
  EXPECT_EQ(skies[0].directions_S[1], Eigen::Vector3d(0.6, 0.0, 0.8));
  const std::vector<LidarGeometry> lidars = LidarGeometries(run);
  ASSERT_EQ(lidars.size(), 1u);
  EXPECT_EQ(lidars[0].beams.azimuth_count, 36);
  EXPECT_EQ(lidars[0].beams.elevation_count, 3);
  EXPECT_DOUBLE_EQ(lidars[0].beams.elevation_min_rad, -10.0 * M_PI / 180.0);
  EXPECT_DOUBLE_EQ(lidars[0].beams.elevation_max_rad, 20.0 * M_PI / 180.0);
  EXPECT_EQ(lidars[0].beams.max_range_m, 30.0);

  RenderOptions plain = SmallOptions();
  RenderOptions layered = plain;
  layered.gnss_sky = true;
  layered.lidar_hits = true;
  const Image without = SceneRenderer(run, plain).Render(2'000'000'000, "chase");
  const Image with = SceneRenderer(run, layered).Render(2'000'000'000, "chase");
  int changed = 0;
  for (size_t i = 0; i < with.rgb.size(); ++i) changed += with.rgb[i] != without.rgb[i] ? 1 : 0;
  EXPECT_GT(changed, 100) << "the sky rays and the LiDAR hits were not drawn";
}

TEST(RenderRunData, MalformedSensorGeometryNamesFileLineAndKey) {
  const RunDirectory dir("bad_geometry");
  std::string sensors = kGeometrySensors;
  sensors.replace(sensors.find("[0.6, 0, 0.8]"), 13, "[0.6, 0, 0.9]");  // not a unit vector
  const std::string calibration = Read(dir / "calibration.yaml");
  Write(dir / "calibration.yaml", calibration + sensors);
  const int line = 1 + static_cast<int>(std::count(calibration.begin(), calibration.end(), '\n')) + 4;
  try {
    ReadRunData(dir);
    FAIL() << "expected an InputError";
  } catch (const core::InputError& e) {
    EXPECT_EQ(e.location().line, line) << e.what();
    EXPECT_NE(std::string(e.what()).find("calibration.yaml"), std::string::npos) << e.what();
    EXPECT_EQ(e.key_path(), "sensors.gnss.sky_directions_S[1]") << e.what();
  }
}

// A layer is read when it is asked for: a malformed LiDAR option does not stop a render
// without --lidar, and fails one with it at the option's line; a GNSS sensor of a run
// directory written before runs recorded the sky fails --sky with the fix named.
TEST(RenderRunData, SensorLayersAreReadWhenAskedFor) {
  const RunDirectory dir("layers_on_demand");
  std::string sensors = kGeometrySensors;
  sensors.replace(sensors.find("azimuth_count: 36"), 17, "azimuth_count: 0 ");
  sensors.erase(sensors.find("    sky_directions_S"), sensors.find("    options: {site: prism, sky") -
                                                          sensors.find("    sky_directions_S"));
  Write(dir / "calibration.yaml", Read(dir / "calibration.yaml") + sensors);
  const RunData run = ReadRunData(dir);
  (void)SceneRenderer(run, SmallOptions()).Render(1'000'000'000, "chase");
  try {
    (void)LidarGeometries(run);
    FAIL() << "expected an InputError";
  } catch (const core::InputError& e) {
    EXPECT_EQ(e.key_path(), "sensors.lidar.options.azimuth_count") << e.what();
    EXPECT_GT(e.location().line, 1) << e.what();
  }
  try {
    (void)SkyGeometries(run);
    FAIL() << "expected an InputError";
  } catch (const core::InputError& e) {
    EXPECT_EQ(e.key_path(), "sensors.gnss.sky_directions_S") << e.what();
    EXPECT_NE(std::string(e.what()).find("run the scenario again"), std::string::npos) << e.what();
  }
}

// The CLI: no EGL (simulated by pointing at a library that does not exist, or at a device
// that does not exist) is exit code 2, a message naming the fix, and the run directory
// exactly as it was.
std::map<std::string, std::string> Snapshot(const fs::path& dir) {
  std::map<std::string, std::string> files;
  for (const auto& entry : fs::recursive_directory_iterator(dir)) {
    files[fs::relative(entry.path(), dir).string()] = entry.is_regular_file() ? Read(entry.path()) : "<dir>";
  }
  return files;
}

int RunCli(const std::string& env, const std::string& args, std::string* err) {
  const fs::path err_file = fs::path(::testing::TempDir()) / fmt::format("render_cli_{}.err", ::getpid());
  const std::string command = fmt::format("env {} '{}' {} >/dev/null 2>'{}'", env, TOFU_BINARY, args, err_file.string());
  const int status = std::system(command.c_str());
  *err = Read(err_file);
  fs::remove(err_file);
  return WIFEXITED(status) ? WEXITSTATUS(status) : -1;
}

TEST(RenderCli, NoEglIsExitTwoNamingTheFixAndTouchesNothing) {
  const RunDirectory dir("noegl");
  const auto before = Snapshot(dir);
  std::string err;
  EXPECT_EQ(RunCli("TOFU_EGL_LIBRARY=/nonexistent/libEGL.so.1", "render " + dir.string() + " --events", &err), 2);
  EXPECT_NE(err.find("EGL is not available"), std::string::npos) << err;
  EXPECT_NE(err.find("install libegl1 and libgl1-mesa-dri"), std::string::npos) << err;
  EXPECT_EQ(Snapshot(dir), before);

  EXPECT_EQ(RunCli("TOFU_EGL_PLATFORM=device TOFU_EGL_DEVICE=99", "render " + dir.string() + " --at 1", &err), 2);
  EXPECT_NE(err.find("EGL device 99 does not exist"), std::string::npos) << err;
  EXPECT_NE(err.find("TOFU_EGL_PLATFORM=surfaceless"), std::string::npos) << err;
  EXPECT_EQ(Snapshot(dir), before);

  EXPECT_EQ(RunCli("TOFU_EGL_PLATFORM=vulkan", "render " + dir.string(), &err), 2);
  EXPECT_NE(err.find("expected auto, surfaceless or device"), std::string::npos) << err;
  EXPECT_EQ(Snapshot(dir), before);
}

TEST(RenderCli, AtWritesOnePngAndBadInputIsExitTwo) {
  const RunDirectory dir("cli");
  std::string err;
  const fs::path png = dir / "frame.png";
  ASSERT_EQ(RunCli("", fmt::format("render {} --at 2 --size 96x64 --camera overview --out {}", dir.string(), png.string()), &err), 0) << err;
  const Image image = ReadPng(png);
  EXPECT_EQ(image.width, 96);
  EXPECT_EQ(image.height, 64);
  EXPECT_EQ(RunCli("", "render " + dir.string() + " --at 99", &err), 2);
  EXPECT_NE(err.find("outside the run"), std::string::npos) << err;
  EXPECT_EQ(RunCli("", "render " + dir.string() + " --size 64by48", &err), 2);
  EXPECT_NE(err.find("--size"), std::string::npos) << err;
  EXPECT_EQ(RunCli("", "render " + (dir / "missing").string(), &err), 2);
  EXPECT_NE(err.find("not a directory"), std::string::npos) << err;
}

// `render:` in a scenario: `tofu run` renders the run's failure events into <out>/renders/
// when an expectation failed (`when: failure`, the default) or always; a passing run with
// `when: failure` renders nothing.
TEST(RenderRun, ScenarioRenderKeyRendersFailuresAfterTheRun) {
  const fs::path dir = fs::path(::testing::TempDir()) / fmt::format("render_run_{}", ::getpid());
  fs::remove_all(dir);
  fs::create_directories(dir);
  const std::string scenario = R"(name: render_run
world: indoor_arena
duration_s: 6
trajectory:
  start: {position_m: [0, 0, 1.5]}
  segments:
    - hover: {duration_s: 1}
    - line: {to_m: [1.5, 0, 1.5]}
sensors:
  imu: {}
  vio: {}
faults:
  - {sensor: vio, kind: divergence, start_s: 3, axis: [1, 0, 0], initial_velocity_mps: 0.5, time_constant_s: 2}
estimation:
  methods: [consensus]
render: {size: [96, 64], fps: 5, clip_half_s: 0.4}
expect:
)";
  std::ofstream(dir / "pass.yaml") << scenario << "  - {metric: collisions.count, max: 0}\n";
  std::ofstream(dir / "fail.yaml") << scenario << "  - {metric: collisions.count, min: 1}\n";
  std::string err;
  ASSERT_EQ(RunCli("", fmt::format("run {} --quiet --out {}", (dir / "pass.yaml").string(),
                                   (dir / "pass").string()), &err), 0) << err;
  EXPECT_FALSE(fs::exists(dir / "pass" / "renders")) << "a passing run rendered";
  ASSERT_EQ(RunCli("", fmt::format("run {} --quiet --out {}", (dir / "fail.yaml").string(),
                                   (dir / "fail").string()), &err), 1) << err;
  int keyframes = 0;
  for (const auto& entry : fs::directory_iterator(dir / "fail" / "renders")) {
    keyframes += entry.path().extension() == ".png" ? 1 : 0;
  }
  EXPECT_GE(keyframes, 1) << "the divergence's onset was not rendered";
  fs::remove_all(dir);
}

}  // namespace
}  // namespace tofu::renders
