#pragma once
// Renders one instant of a run off-screen: the world and the true robot (MuJoCo's mjr
// renderer into its offscreen framebuffer), a translucent ghost robot at each method's
// estimated pose, every sensor's measurement mapped into W with a short trail, the total
// station's line of sight (green clear, red blocked), optionally the LiDAR's hits and the
// GNSS sky rays, a text overlay (time, fused, excluded, faults, consistency values) and a
// consistency-matrix heat-map inset. Deterministic: the same run, time, camera and
// options give the same pixels on the same machine (no wall-clock anywhere).

#include <array>
#include <memory>
#include <string>
#include <vector>

#include <Eigen/Core>

#include "core/time.h"
#include "renders/egl_context.h"
#include "renders/image_io.h"
#include "renders/run_data.h"

namespace tofu::renders {

struct RenderOptions {
  int width_px = 640;
  int height_px = 480;
  bool shadows = false;      ///< shadow maps of the lights that cast them (costly on a CPU)
  bool reflections = false;  ///< planar reflections of reflective materials
  /// MSAA samples of the offscreen buffer: 0 off; -1 auto: 4 on a GPU, 0 on a software
  /// rasteriser (llvmpipe spends 3-4x the time on 4 samples).
  int multisamples = -1;
  int shadow_map_px = 2048;  ///< shadow map size when shadows are on
  int geom_slices = 12;      ///< tessellation of round geoms (MuJoCo's default: 28)
  double plane_grid_m = 0.5; ///< coarsest grid spacing of planes [m] (0: the model's)
  bool lidar_hits = false;   ///< LiDAR rays cast from the true pose, hits as dots
  bool gnss_sky = false;     ///< GNSS satellite rays from the antenna: green clear, red blocked
  bool text_overlay = true;
  bool heatmap = true;
  double trail_s = 1.0;      ///< length of each sensor's marker trail [s]
  double ghost_alpha = 0.3;
  bool ghosts = true;  ///< draw the estimated poses at all
  /// Methods drawn as ghosts (empty: every estimate of the run).
  std::vector<std::string> methods;
  /// Consistency metric of the overlay and inset ("": the first in the files).
  std::string consistency_metric;
  EglOptions egl;

  /// The options within their limits; otherwise false and *why = "<option>: <problem>",
  /// options named as on the command line (RequireValidRenderOptions throws it).
  bool IsValid(std::string* why = nullptr) const;
};

/// The camera a frame was rendered from, as OpenGL used it: enough to project a point in
/// W to a pixel with a pinhole model (tests check the ghost appears where it should).
struct CameraView {
  std::string name;
  Eigen::Vector3d p_W = Eigen::Vector3d::Zero();        ///< camera centre
  Eigen::Vector3d forward_W = Eigen::Vector3d::UnitX();  ///< unit viewing direction
  Eigen::Vector3d up_W = Eigen::Vector3d::UnitZ();       ///< unit, orthogonal to forward
  double fovy_deg = 45.0;                                ///< vertical field of view
  int width_px = 0;
  int height_px = 0;
};

/// The ghost colour of the k-th drawn method (RGB in [0, 1]); method 0 is magenta, a hue
/// that appears nowhere else in the scenes.
std::array<float, 3> GhostColor(size_t method_index);

class SceneRenderer {
 public:
  /// Creates the EGL context, composes the run's world (sim::World) and the GL resources.
  /// Throws RenderUnavailableError when EGL/OpenGL cannot start, core::InputError for bad
  /// options or a world/robot the models directory lacks.
  SceneRenderer(const RunData& run, const RenderOptions& options);
  ~SceneRenderer();
  SceneRenderer(const SceneRenderer&) = delete;
  SceneRenderer& operator=(const SceneRenderer&) = delete;

  /// Renders the instant `t_ns` (clamped to the run) from `camera` ("chase", "overview"
  /// or a camera of the MuJoCo model). `caption` is an extra overlay line (e.g. the
  /// event). Throws core::InputError for an unknown camera.
  Image Render(core::Time t_ns, const std::string& camera, const std::string& caption = "");

  /// The view of the last Render().
  const CameraView& last_view() const;
  /// "chase", "overview", then the model's cameras.
  std::vector<std::string> CameraNames() const;
  /// The ghost methods drawn, in order (index = GhostColor index).
  std::vector<std::string> GhostMethods() const;
  /// The EGL/OpenGL line (platform and GL renderer: a silent software fall-back shows).
  std::string GlDescription() const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace tofu::renders
