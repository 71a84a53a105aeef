#include "renders/render_command.h"

#include <unistd.h>

#include <charconv>
#include <cmath>
#include <fstream>

#include <fmt/format.h>
#include <nlohmann/json.hpp>

#include "core/error.h"
#include "renders/render_options.h"
#include "renders/run_data.h"

namespace tofu::renders {
namespace {

namespace fs = std::filesystem;

void WriteText(const fs::path& path, const std::string& text) {
  std::ofstream out(path, std::ios::binary);
  out.write(text.data(), static_cast<std::streamsize>(text.size()));
  out.close();
  if (!out) throw core::IoError("cannot write " + path.string());
}

// A sibling of `path` for staging, unique to this process.
fs::path Sibling(const fs::path& path, const std::string& tag) {
  return path.parent_path() / fmt::format(".{}.{}-{}", path.filename().string(), tag, ::getpid());
}

std::string CsvField(const std::string& text) {
  std::string out = text;
  for (char& c : out) {
    if (c == ',' || c == '\n') c = ';';
  }
  return out;
}

// Frame times of a clip: [t - half, t + half] within the run, every 1/fps, in integer ns
// (no float accumulation: the same frames on every machine).
std::vector<core::Time> ClipTimes(const RunData& run, core::Time t_ns, double half_s, int fps) {
  const core::Time half_ns = core::SecondsToTime(half_s);
  const core::Time start = std::max(run.start_ns(), t_ns - half_ns);
  const core::Time end = std::min(run.end_ns(), t_ns + half_ns);
  std::vector<core::Time> times;
  for (int64_t k = 0;; ++k) {
    const core::Time t = start + k * core::kNanosecondsPerSecond / fps;
    if (t > end) break;
    times.push_back(t);
  }
  return times;
}

nlohmann::ordered_json OptionsJson(const RenderEventsOptions& o) {
  return {{"size", fmt::format("{}x{}", o.render.width_px, o.render.height_px)},
          {"camera", o.camera},
          {"fps", o.fps},
          {"clip_half_s", o.clip_half_s},
          {"shadows", o.render.shadows},
          {"reflections", o.render.reflections},
          {"multisamples", o.render.multisamples},
          {"lidar_hits", o.render.lidar_hits},
          {"gnss_sky", o.render.gnss_sky},
          {"error_bound_m", o.events.error_bound_m}};
}

std::pair<int, int> ParseSize(const std::string& text) {
  const size_t x = text.find('x');
  int w = 0;
  int h = 0;
  const auto parse = [](std::string_view s, int* v) {
    const auto [end, ec] = std::from_chars(s.data(), s.data() + s.size(), *v);
    return !s.empty() && ec == std::errc() && end == s.data() + s.size();
  };
  if (x == std::string::npos || !parse(std::string_view(text).substr(0, x), &w) ||
      !parse(std::string_view(text).substr(x + 1), &h)) {
    throw core::InputError({"command line"}, "--size",
                           fmt::format("expected WxH in pixels (e.g. 640x480), got '{}'", text));
  }
  return {w, h};
}

}  // namespace

bool RenderEventsOptions::IsValid(std::string* why) const {
  if (!render.IsValid(why) || !events.IsValid(why)) return false;
  const auto fail = [why](const std::string& key, const std::string& message) {
    if (why != nullptr) *why = key + ": " + message;
    return false;
  };
  if (fps < 1 || fps > 240) {
    return fail("--fps", fmt::format("expected 1..240 frames per second, got {}", fps));
  }
  if (!(clip_half_s >= 0.0 && clip_half_s <= 60.0)) {
    return fail("--clip-half", fmt::format("expected 0..60 s, got {}", clip_half_s));
  }
  return true;
}

// Long by design: render into a staging directory, write its files and swap it in as one
// all-or-nothing sequence with one cleanup path.
RenderEventsResult RenderRunEvents(const fs::path& run_dir, const RenderEventsOptions& options) {
  RequireValidRenderOptions(options);
  const RunData run = ReadRunData(run_dir);
  const std::vector<RenderEvent> events = FindEvents(run, options.events);
  // The renderer (EGL) before any file is touched: without it nothing is written.
  SceneRenderer renderer(run, options.render);

  RenderEventsResult result;
  result.out_dir = fs::absolute(options.out_dir.value_or(run_dir / "renders")).lexically_normal();
  result.gl_description = renderer.GlDescription();
  result.notes = run.notes;

  size_t total_frames = events.size();
  std::vector<std::vector<core::Time>> clip_times;
  for (const RenderEvent& e : events) {
    clip_times.push_back(options.clips ? ClipTimes(run, e.t_ns, options.clip_half_s, options.fps)
                                       : std::vector<core::Time>());
    total_frames += clip_times.back().size();
  }

  fs::create_directories(result.out_dir.parent_path());
  const fs::path staging = Sibling(result.out_dir, "tmp");
  fs::remove_all(staging);
  fs::create_directories(staging);
  try {
    std::string csv = "#timestamp [ns],kind,subject,detail,keyframe,clip\n";
    nlohmann::ordered_json listed = nlohmann::ordered_json::array();
    size_t done = 0;
    const auto tick = [&]() {
      ++done;
      ++result.frames;
      if (options.progress) options.progress(static_cast<double>(done) / std::max<size_t>(1, total_frames));
    };
    for (size_t i = 0; i < events.size(); ++i) {
      const RenderEvent& e = events[i];
      const std::string stem = fmt::format("{:02d}_{}", i + 1, e.Slug());
      const std::string caption = fmt::format("{}: {}", EventKindName(e.kind), e.detail);
      RenderedEvent rendered{e, result.out_dir / (stem + ".png"), std::nullopt};
      WritePng(staging / (stem + ".png"), renderer.Render(e.t_ns, options.camera, caption));
      tick();
      if (!clip_times[i].empty()) {
        ClipWriter clip(staging / stem, options.render.width_px, options.render.height_px,
                        options.fps);
        for (const core::Time t : clip_times[i]) {
          clip.Add(renderer.Render(t, options.camera, caption));
          tick();
        }
        rendered.clip = result.out_dir / clip.Finish().filename();
      }
      csv += fmt::format("{},{},{},{},{},{}\n", e.t_ns, EventKindName(e.kind), CsvField(e.subject),
                         CsvField(e.detail), rendered.keyframe.filename().string(),
                         rendered.clip ? rendered.clip->filename().string() : "");
      listed.push_back({{"t_ns", e.t_ns},
                        {"kind", EventKindName(e.kind)},
                        {"subject", e.subject},
                        {"detail", e.detail},
                        {"keyframe", rendered.keyframe.filename().string()},
                        {"clip", rendered.clip ? rendered.clip->filename().string() : ""}});
      result.events.push_back(std::move(rendered));
    }
    WriteText(staging / "events.csv", csv);
    nlohmann::ordered_json meta;
    meta["run"] = run.scenario_name;
    meta["gl"] = result.gl_description;
    meta["options"] = OptionsJson(options);
    meta["ghosts"] = renderer.GhostMethods();
    meta["events"] = listed;
    meta["notes"] = result.notes;
    WriteText(staging / "render.json", meta.dump(2) + "\n");

    // Swap in: old aside, new in, old gone (a reader never sees a half-written set).
    const fs::path old = Sibling(result.out_dir, "old");
    fs::remove_all(old);
    if (fs::exists(result.out_dir)) fs::rename(result.out_dir, old);
    fs::rename(staging, result.out_dir);
    fs::remove_all(old);
  } catch (...) {
    std::error_code ignored;
    fs::remove_all(staging, ignored);
    throw;
  }
  return result;
}

std::string RenderRunFrame(const fs::path& run_dir, core::Time t_ns, const std::string& camera,
                           const RenderOptions& options, const fs::path& out_png) {
  const RunData run = ReadRunData(run_dir);
  if (t_ns < run.start_ns() || t_ns > run.end_ns()) {
    throw core::InputError({"command line"}, "--at",
                           fmt::format("t = {:.3f} s is outside the run ({:.3f} .. {:.3f} s)",
                                       core::TimeToSeconds(t_ns), core::TimeToSeconds(run.start_ns()),
                                       core::TimeToSeconds(run.end_ns())));
  }
  SceneRenderer renderer(run, options);
  const Image image = renderer.Render(t_ns, camera);
  const fs::path out = fs::absolute(out_png).lexically_normal();
  fs::create_directories(out.parent_path());
  const fs::path staging = Sibling(out, "tmp");
  try {
    WritePng(staging, image);
    fs::rename(staging, out);
  } catch (...) {
    std::error_code ignored;
    fs::remove(staging, ignored);
    throw;
  }
  return renderer.GlDescription();
}

int RunRenderCommand(const RenderCommandOptions& o) {
  const auto [width, height] = ParseSize(o.size);
  RenderEventsOptions options;
  options.render.width_px = width;
  options.render.height_px = height;
  options.render.shadows = o.shadows;
  options.render.reflections = o.reflections;
  options.render.multisamples = o.msaa;
  options.render.lidar_hits = o.lidar_hits;
  options.render.gnss_sky = o.gnss_sky;
  options.render.methods = o.methods;
  options.render.consistency_metric = o.metric;
  if (o.egl_platform) options.render.egl.platform = o.egl_platform;
  options.events.error_bound_m = o.error_bound_m;
  options.camera = o.camera;
  options.fps = o.fps;
  options.clip_half_s = o.clip_half_s;
  options.clips = !o.no_clips;
  options.progress = o.progress;
  RequireValidRenderOptions(options);

  const fs::path run_dir = o.run_dir;
  if (o.at_s) {
    if (!std::isfinite(*o.at_s)) {
      throw core::InputError({"command line"}, "--at", "expected a time in seconds");
    }
    const core::Time t_ns = core::SecondsToTime(*o.at_s);
    const fs::path out = o.out ? fs::path(*o.out)
                               : run_dir / "renders" /
                                     fmt::format("at_{:07d}ms_{}.png", t_ns / 1'000'000, o.camera);
    const std::string gl = RenderRunFrame(run_dir, t_ns, o.camera, options.render, out);
    if (!o.quiet) fmt::print("render: {}\nwrote {}\n", gl, out.string());
    return core::kExitOk;
  }
  if (o.out) options.out_dir = fs::path(*o.out);
  const RenderEventsResult result = RenderRunEvents(run_dir, options);
  if (!o.quiet) {
    fmt::print("render: {}\n", result.gl_description);
    for (const std::string& note : result.notes) fmt::print("note: {}\n", note);
    if (result.events.empty()) fmt::print("no failure events in {}\n", run_dir.string());
    for (const RenderedEvent& r : result.events) {
      fmt::print("{:8.2f} s  {:<18} {}\n          {}{}\n", core::TimeToSeconds(r.event.t_ns),
                 EventKindName(r.event.kind), r.event.detail, r.keyframe.string(),
                 r.clip ? "\n          " + r.clip->string() : "");
    }
    fmt::print("{} frames into {}\n", result.frames, result.out_dir.string());
  }
  return core::kExitOk;
}

const char* const kRenderHelp = R"(
Renders a run directory off-screen with EGL (no display, no GPU needed: Mesa's llvmpipe).
--events (default): the failure events (fault onset, detection, sensor switch, error above
  --error-bound, collision), each a keyframe PNG and a clip of +-2 s (MP4 via ffmpeg, GIF
  without it), into RUN_DIR/renders/ (or --out DIR), replaced as a whole.
--at T: one PNG of the instant T [s] (RUN_DIR/renders/at_<ms>ms_<camera>.png or --out FILE).
Cameras: chase, overview, or a camera of the world model.
EGL platform: auto (a GPU device if there is one, else surfaceless), overridden by
--egl-platform or $TOFU_EGL_PLATFORM (surfaceless | device; $TOFU_EGL_DEVICE picks the
device). Exit codes: 0 ok, 2 bad input or no EGL (the message names the fix), 3 I/O failure.)";

}  // namespace tofu::renders
