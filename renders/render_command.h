#pragma once
// `tofu render` and the render step of `tofu run`: renders of a run directory written
// into <run_dir>/renders/ (or another directory), all or nothing: frames go to a staging
// directory that replaces the old one only when every file is complete, so a failure
// (no EGL, a broken ffmpeg, bad input) leaves the run's other outputs and its previous
// renders untouched.
//
// <out>/NN_<kind>_<subject>_<t>ms.png   keyframe at the event (the clip's caption)
// <out>/NN_<kind>_<subject>_<t>ms.mp4   clip of +- clip_half_s (.gif without ffmpeg)
// <out>/events.csv                      t_ns, kind, subject, detail, keyframe, clip
// <out>/render.json                     GL renderer, options, events: what made the pixels

#include <filesystem>
#include <functional>
#include <optional>
#include <string>
#include <vector>

#include "renders/events.h"
#include "renders/scene_renderer.h"

namespace tofu::renders {

struct RenderEventsOptions {
  RenderOptions render;
  EventOptions events;
  std::string camera = "chase";  ///< "chase", "overview" or a camera of the model
  int fps = 30;                  ///< clip frame rate
  double clip_half_s = 2.0;      ///< clip span around each event [s]
  bool clips = true;             ///< false: keyframes only
  /// Output directory; unset: <run_dir>/renders. Replaced as a whole.
  std::optional<std::filesystem::path> out_dir;
  /// Called with the fraction of frames done (optional; e.g. a progress bar).
  std::function<void(double)> progress;

  /// render's, events' and these options within their limits; otherwise false and
  /// *why = "<option>: <problem>".
  bool IsValid(std::string* why = nullptr) const;
};

struct RenderedEvent {
  RenderEvent event;
  std::filesystem::path keyframe;  ///< PNG
  std::optional<std::filesystem::path> clip;  ///< MP4 or GIF
};

struct RenderEventsResult {
  std::filesystem::path out_dir;
  std::vector<RenderedEvent> events;
  std::string gl_description;  ///< EGL platform + GL renderer (software fall-back visible)
  size_t frames = 0;           ///< frames rendered
  std::vector<std::string> notes;
};

/// Finds the failure events of the run in `run_dir` (FindEvents) and renders a keyframe
/// and a clip of each into the output directory (also when there are no events: an empty
/// events.csv says so). What `tofu run` calls when a scenario asks for renders.
/// Throws RenderUnavailableError (no EGL/OpenGL: the message names the fix),
/// core::InputError (bad run directory or options), std::runtime_error (I/O, ffmpeg).
RenderEventsResult RenderRunEvents(const std::filesystem::path& run_dir,
                                   const RenderEventsOptions& options = {});

/// Renders the instant `t_ns` of the run into the PNG `out_png` (written atomically).
/// Returns the GL description. Throws as RenderRunEvents.
std::string RenderRunFrame(const std::filesystem::path& run_dir, core::Time t_ns,
                           const std::string& camera, const RenderOptions& options,
                           const std::filesystem::path& out_png);

/// `tofu render RUN_DIR [--events | --at T] [--size WxH] [--fps N] [--camera NAME] ...`
struct RenderCommandOptions {
  std::string run_dir;
  bool events = false;         ///< the default when --at is not given
  std::optional<double> at_s;  ///< render this instant [s] instead of the events
  std::string size = "640x480";
  int fps = 30;
  std::string camera = "chase";
  std::optional<std::string> out;  ///< --events: directory; --at: PNG file
  bool shadows = false;
  bool reflections = false;
  int msaa = -1;  ///< MSAA samples; -1: auto (0 on a software rasteriser, 4 on a GPU)
  bool lidar_hits = false;
  bool gnss_sky = false;
  bool no_clips = false;
  std::vector<std::string> methods;
  std::string metric;
  double error_bound_m = 0.5;
  double clip_half_s = 2.0;
  std::optional<std::string> egl_platform;  ///< auto | surfaceless | device
  bool quiet = false;
  std::function<void(double)> progress;
};

/// Runs the command; prints the GL renderer line and the files written (unless quiet).
/// Returns the exit code (0). Throws RenderUnavailableError, core::InputError,
/// std::runtime_error as RenderRunEvents (the CLI maps them to exit codes 2, 2, 3).
int RunRenderCommand(const RenderCommandOptions& options);

/// Help text of the render subcommand (the CLI's footer).
extern const char* const kRenderHelp;

}  // namespace tofu::renders
