#include "renders/scene_renderer.h"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <optional>
#include <set>

#include <fmt/format.h>
#include <fmt/ranges.h>
#include <mujoco/mujoco.h>

#include "core/error.h"
#include "core/units.h"
#include "renders/overlay.h"
#include "renders/render_options.h"
#include "replay/run_format.h"
#include "sim/world.h"

namespace tofu::renders {
namespace {

constexpr double kDegToRad = core::kRadPerDeg;
constexpr int kMaxSceneGeoms = 12000;

// Free-camera fields of view: the chase camera frames the robot, the overview the run.
constexpr double kChaseFovyDeg = 50.0;
constexpr double kOverviewFovyDeg = 60.0;
constexpr double kChaseDistance_m = 2.8;
constexpr double kChaseElevationDeg = -18.0;
constexpr double kOverviewElevationDeg = -35.0;
// A chase camera stays this far in front of a wall behind it [m].
constexpr double kCameraWallClearance_m = 0.3;
// Opacity of a wall cut away because it stands between the camera and the robot.
constexpr float kCutawayAlpha = 0.1f;
// A ghost is drawn only where its estimate is dense: no interpolation across gaps [s].
constexpr core::Time kGhostMaxGap_ns = 500'000'000;
// Ghost parts smaller than this bounding radius are left out [m].
constexpr float kGhostMinRadius_m = 0.035f;
// A sensor's marker disappears when its last sample is older than this [s].
constexpr core::Time kMarkerMaxAge_ns = 1'000'000'000;

constexpr Rgba kClearGreen = {0.10f, 0.85f, 0.20f, 1.0f};
constexpr Rgba kBlockedRed = {0.95f, 0.10f, 0.10f, 1.0f};

}  // namespace

bool RenderOptions::IsValid(std::string* why) const {
  const auto fail = [why](const std::string& key, const std::string& message) {
    if (why != nullptr) *why = key + ": " + message;
    return false;
  };
  if (width_px < 16 || height_px < 16 || width_px > 8192 || height_px > 8192) {
    return fail("--size", fmt::format("expected WxH with each side in [16, 8192], got {}x{}",
                                      width_px, height_px));
  }
  if (multisamples < -1 || multisamples > 16) return fail("--msaa", "expected 0..16, or -1 (auto)");
  if (shadow_map_px < 256 || shadow_map_px > 8192) {
    return fail("shadow_map_px", "expected 256..8192");
  }
  if (geom_slices < 4 || geom_slices > 64) return fail("geom_slices", "expected 4..64");
  if (!(plane_grid_m >= 0.0 && plane_grid_m <= 100.0)) {
    return fail("plane_grid_m", "expected 0..100 m");
  }
  if (!(trail_s >= 0.0 && trail_s <= 60.0)) return fail("trail_s", "expected 0..60 s");
  if (!(ghost_alpha > 0.0 && ghost_alpha <= 1.0)) return fail("ghost_alpha", "expected (0, 1]");
  return true;
}

std::array<float, 3> GhostColor(size_t method_index) {
  static constexpr std::array<std::array<float, 3>, 4> kGhosts = {{{1.00f, 0.05f, 0.85f},
                                                                   {0.55f, 0.25f, 1.00f},
                                                                   {1.00f, 0.35f, 0.35f},
                                                                   {0.95f, 0.95f, 0.95f}}};
  return kGhosts[method_index % kGhosts.size()];
}

struct SceneRenderer::Impl {
  const RunData& run;
  RenderOptions options;
  std::unique_ptr<EglContext> egl;
  std::unique_ptr<sim::World> world;
  mjModel* model = nullptr;
  mjData* data = nullptr;
  mjData* ghost_data = nullptr;
  mjvScene scene;
  mjvOption vis_options;
  mjvCamera camera;
  mjrContext context;
  bool scene_made = false;
  bool context_made = false;
  int font_scale = mjFONTSCALE_100;
  int root_qpos = 0;
  std::vector<const MethodEstimate*> ghosts;
  std::optional<Overlay> overlay;  // made by Build once the ghosts are chosen
  // Cameras.
  mjvCamera overview;
  double overview_fovy_deg = kOverviewFovyDeg;
  std::vector<Eigen::Vector3d> overview_targets;  // points the overview must show
  std::vector<Eigen::Vector3d> cutaway_targets;   // of the current frame's camera
  CameraView view;
  // Sensor layers, read from the run directory when asked for.
  std::vector<LidarGeometry> lidars;
  std::vector<SkyGeometry> skies;

  Impl(const RunData& r, const RenderOptions& o) : run(r), options(o) {
    mjv_defaultScene(&scene);
    mjr_defaultContext(&context);
  }

  ~Impl() {
    if (egl) egl->MakeCurrent();
    if (context_made) mjr_freeContext(&context);
    if (scene_made) mjv_freeScene(&scene);
    if (ghost_data != nullptr) mj_deleteData(ghost_data);
    if (data != nullptr) mj_deleteData(data);
    if (model != nullptr) mj_deleteModel(model);
  }

  void Build() {
    RequireValidRenderOptions(options);
    if (options.lidar_hits) lidars = LidarGeometries(run);
    if (options.gnss_sky) skies = SkyGeometries(run);
    // EGL first: without it nothing else is worth doing, and the error names the fix.
    egl = std::make_unique<EglContext>(options.egl);

    sim::WorldOptions world_options;
    world_options.world = run.world;
    world_options.robot = run.robot;
    world = std::make_unique<sim::World>(world_options);
    model = mj_copyModel(nullptr, world->model());
    // The offscreen buffer is allocated at the model's size: make it the frame's.
    model->vis.global.offwidth = options.width_px;
    model->vis.global.offheight = options.height_px;
    model->vis.quality.offsamples =
        options.multisamples >= 0 ? options.multisamples : (egl->software() ? 0 : 4);
    model->vis.quality.shadowsize = options.shadow_map_px;
    // Tessellation of spheres, capsules and cylinders: MuJoCo's defaults (28 slices, 16
    // stacks) make a software rasteriser spend most of a frame on vertices that a 640 px
    // frame cannot show.
    model->vis.quality.numslices = options.geom_slices;
    model->vis.quality.numstacks = std::max(4, options.geom_slices / 2);
    // Planes are drawn as a grid of quads at their third size parameter (the arena floor:
    // 0.1 m, 12 000 quads) for per-vertex lighting; a coarser grid looks the same here
    // and saves a software rasteriser ~30 % of a frame.
    for (int g = 0; g < model->ngeom; ++g) {
      if (model->geom_type[g] != mjGEOM_PLANE) continue;
      mjtNum& spacing = model->geom_size[3 * g + 2];
      spacing = std::max<mjtNum>(spacing, options.plane_grid_m);
    }
    data = mj_makeData(model);
    ghost_data = mj_makeData(model);
    const int root = mj_name2id(model, mjOBJ_JOINT, "root");
    root_qpos = root >= 0 ? model->jnt_qposadr[root] : 0;

    mjv_makeScene(model, &scene, kMaxSceneGeoms);
    scene_made = true;
    mjv_defaultOption(&vis_options);
    // Geom groups (models/ README): 0 structure, 1 ground, 3 robot visuals, 4 decoration;
    // not 2, the robot's collision proxies. Sites: only the world's (group 4).
    const int geom_groups[mjNGROUP] = {1, 1, 0, 1, 1, 0};
    const int site_groups[mjNGROUP] = {0, 0, 0, 0, 1, 0};
    for (int g = 0; g < mjNGROUP; ++g) {
      vis_options.geomgroup[g] = static_cast<mjtByte>(geom_groups[g]);
      vis_options.sitegroup[g] = static_cast<mjtByte>(site_groups[g]);
    }
    font_scale = options.height_px <= 600 ? mjFONTSCALE_100
                 : options.height_px <= 1000 ? mjFONTSCALE_150
                                             : mjFONTSCALE_200;
    mjr_makeContext(model, &context, font_scale);
    context_made = true;
    mjr_setBuffer(mjFB_OFFSCREEN, &context);
    if (context.currentBuffer != mjFB_OFFSCREEN) {
      throw RenderUnavailableError(
          "OpenGL: MuJoCo's offscreen framebuffer is unavailable (framebuffer objects not "
          "supported by this driver); install libgl1-mesa-dri, or set "
          "TOFU_EGL_PLATFORM=surfaceless");
    }

    SelectGhosts();
    const OverlayFrame frame = {.width_px = options.width_px, .height_px = options.height_px,
                                .font_scale = font_scale, .heatmap = options.heatmap};
    overlay.emplace(run, ghosts, options.consistency_metric, frame, &context);
    ComputeOverview();
  }

  void SelectGhosts() {
    for (const std::string& method : options.methods) {
      const auto it = std::find_if(run.estimates.begin(), run.estimates.end(),
                                   [&](const MethodEstimate& e) { return e.method == method; });
      if (it == run.estimates.end()) {
        std::vector<std::string> known;
        for (const MethodEstimate& e : run.estimates) known.push_back(e.method);
        const std::string listed =
            known.empty() ? "none" : fmt::format("{}", fmt::join(known, ", "));
        throw core::InputError({run.directory.string()}, "--method",
                               fmt::format("no estimate of method '{}' in the run (estimates: {})",
                                           method, listed));
      }
      ghosts.push_back(&*it);
    }
    if (options.methods.empty()) {
      for (const MethodEstimate& e : run.estimates) ghosts.push_back(&e);
    }
    if (!options.ghosts) ghosts.clear();
  }

  // Distance a camera at `lookat` looking along `forward` can back off before a wall.
  double ClearDistance(const Eigen::Vector3d& lookat_W, const Eigen::Vector3d& forward_W,
                       double wanted_m) const {
    const auto hit = world->CastRay(lookat_W, -forward_W, sim::kRayScene);
    if (!hit || hit->distance_m > wanted_m + kCameraWallClearance_m) return wanted_m;
    return std::max(0.5, hit->distance_m - kCameraWallClearance_m);
  }

  static Eigen::Vector3d Forward(double azimuth_deg, double elevation_deg) {
    const double az = azimuth_deg * kDegToRad;
    const double el = elevation_deg * kDegToRad;
    return Eigen::Vector3d(std::cos(el) * std::cos(az), std::cos(el) * std::sin(az), std::sin(el));
  }

  // The overview: the flown volume (and the total stations) framed from the diagonal
  // with the most room, or the model's camera "overview" when the world has one.
  void ComputeOverview() {
    mjv_defaultCamera(&overview);
    const int fixed = mj_name2id(model, mjOBJ_CAMERA, "overview");
    if (fixed >= 0) {
      overview.type = mjCAMERA_FIXED;
      overview.fixedcamid = fixed;
      overview_fovy_deg = model->cam_fovy[fixed];
      return;
    }
    Eigen::Vector3d lo = run.groundtruth.front().p_W;
    Eigen::Vector3d hi = lo;
    for (const TimedPose& p : run.groundtruth) {
      lo = lo.cwiseMin(p.p_W);
      hi = hi.cwiseMax(p.p_W);
    }
    for (const SensorTrack& s : run.sensors) {
      if (replay::SensorModelOfName(s.type) != replay::SensorModel::kTotalStation) continue;
      lo = lo.cwiseMin(s.true_T_WS.translation());
      hi = hi.cwiseMax(s.true_T_WS.translation());
    }
    // The ghosts too, where they are near the truth: a diverged estimate would otherwise
    // shrink the whole run to a dot.
    constexpr double kGhostFramingRadius_m = 5.0;
    for (const MethodEstimate* g : ghosts) {
      for (size_t i = 0; i < g->T_WB.size(); i += 10) {
        const Eigen::Vector3d p = g->T_WB[i].p_W;
        if ((p - InterpolatePose(run.groundtruth, g->T_WB[i].t_ns).p_W).norm() > kGhostFramingRadius_m) {
          continue;
        }
        lo = lo.cwiseMin(p);
        hi = hi.cwiseMax(p);
      }
    }
    const Eigen::Vector3d lookat = 0.5 * (lo + hi);
    const double radius = std::max(2.0, 0.5 * (hi - lo).norm() + 0.5);
    // The sphere around the flown volume fits in the frame's height.
    const double distance =
        std::min(40.0, radius / std::sin(0.5 * kOverviewFovyDeg * kDegToRad));
    overview_targets = {lookat};
    for (int corner = 0; corner < 8; ++corner) {
      overview_targets.emplace_back(corner & 1 ? hi.x() : lo.x(), corner & 2 ? hi.y() : lo.y(),
                                    corner & 4 ? hi.z() : lo.z());
    }
    // The diagonal whose view needs the fewest walls cut away (ties: the first).
    size_t best_count = 0;
    double best_azimuth = 45.0;
    for (int k = 0; k < 4; ++k) {
      const double azimuth = 45.0 + 90.0 * k;
      const Eigen::Vector3d eye =
          lookat - distance * Forward(azimuth, kOverviewElevationDeg);
      const size_t count = Occluders(eye, overview_targets).size();
      if (k == 0 || count < best_count) {
        best_count = count;
        best_azimuth = azimuth;
      }
    }
    overview.type = mjCAMERA_FREE;
    for (int k = 0; k < 3; ++k) overview.lookat[k] = lookat(k);
    overview.distance = distance;
    overview.azimuth = best_azimuth;
    overview.elevation = kOverviewElevationDeg;
  }

  // Structure and decoration geoms (groups 0 and 4) between `eye` and any of `targets`:
  // drawn nearly transparent, a cutaway, so that walls, ceilings and decks never hide the
  // robot. Rays go both ways: MuJoCo's ray cast from inside a box finds no exit, so one
  // direction alone misses the second of two stacked slabs (a deck and its underside).
  std::set<int> Occluders(const Eigen::Vector3d& eye_W,
                          const std::vector<Eigen::Vector3d>& targets_W) const {
    constexpr uint32_t kOccluderGroups = (1u << 0) | (1u << 4);
    constexpr double kStep_m = 0.02;  // past a surface before casting again
    std::set<int> occluders;
    const auto walk = [&](const Eigen::Vector3d& from, const Eigen::Vector3d& to) {
      const Eigen::Vector3d d = to - from;
      const double length = d.norm();
      if (length < 1e-6) return;
      const Eigen::Vector3d u = d / length;
      double travelled = 0.0;
      for (int i = 0; i < 16 && travelled < length; ++i) {
        const auto hit = world->CastRay(from + travelled * u, u, kOccluderGroups);
        if (!hit || travelled + hit->distance_m >= length) break;
        occluders.insert(hit->geom);
        travelled += hit->distance_m + kStep_m;
      }
    };
    for (const Eigen::Vector3d& target : targets_W) {
      walk(eye_W, target);
      walk(target, eye_W);
    }
    return occluders;
  }

  // ---- scene building ----

  mjvGeom* NewGeom() {
    if (scene.ngeom >= scene.maxgeom) return nullptr;
    return scene.geoms + scene.ngeom++;
  }

  void Style(mjvGeom* g, const Rgba& rgba, float emission) {
    g->category = mjCAT_DECOR;
    g->objtype = mjOBJ_UNKNOWN;
    g->objid = -1;
    g->segid = -1;
    g->texid = -1;
    std::copy(rgba.begin(), rgba.end(), g->rgba);
    g->emission = emission;
    g->specular = 0.2f;
    g->shininess = 0.3f;
    g->reflectance = 0.0f;
    g->transparent = rgba[3] < 1.0f;
    g->label[0] = '\0';
  }

  void AddSphere(const Eigen::Vector3d& p_W, double radius_m, const Rgba& rgba) {
    mjvGeom* g = NewGeom();
    if (g == nullptr) return;
    const mjtNum size[3] = {radius_m, radius_m, radius_m};
    const mjtNum pos[3] = {p_W.x(), p_W.y(), p_W.z()};
    mjv_initGeom(g, mjGEOM_SPHERE, size, pos, nullptr, rgba.data());
    Style(g, rgba, 0.3f);
  }

  void AddSegment(const Eigen::Vector3d& a_W, const Eigen::Vector3d& b_W, double radius_m,
                  const Rgba& rgba) {
    if ((b_W - a_W).norm() < 1e-6) return;
    mjvGeom* g = NewGeom();
    if (g == nullptr) return;
    mjv_initGeom(g, mjGEOM_CAPSULE, nullptr, nullptr, nullptr, rgba.data());
    const mjtNum from[3] = {a_W.x(), a_W.y(), a_W.z()};
    const mjtNum to[3] = {b_W.x(), b_W.y(), b_W.z()};
    mjv_makeConnector(g, mjGEOM_CAPSULE, radius_m, from[0], from[1], from[2], to[0], to[1], to[2]);
    Style(g, rgba, 0.3f);
  }

  Eigen::Isometry3d Mount(const std::string& site) const {
    const auto it = run.mounts.find(site);
    return it != run.mounts.end() ? it->second : Eigen::Isometry3d::Identity();
  }

  void AddGhosts(core::Time t_ns) {
    for (size_t k = 0; k < ghosts.size(); ++k) {
      const std::vector<TimedPose>& poses = ghosts[k]->T_WB;
      if (t_ns < poses.front().t_ns || t_ns > poses.back().t_ns + kGhostMaxGap_ns) continue;
      const auto after = std::lower_bound(
          poses.begin(), poses.end(), t_ns,
          [](const TimedPose& p, core::Time t) { return p.t_ns < t; });
      if (after != poses.end() && after != poses.begin() &&
          after->t_ns - (after - 1)->t_ns > kGhostMaxGap_ns) {
        continue;  // inside a gap of the estimate: no made-up pose
      }
      const TimedPose pose = InterpolatePose(poses, t_ns);
      // The ghost shares the true robot's joint angles; only its base pose differs.
      mju_copy(ghost_data->qpos, data->qpos, model->nq);
      for (int i = 0; i < 3; ++i) ghost_data->qpos[root_qpos + i] = pose.p_W(i);
      ghost_data->qpos[root_qpos + 3] = pose.q_W.w();
      ghost_data->qpos[root_qpos + 4] = pose.q_W.x();
      ghost_data->qpos[root_qpos + 5] = pose.q_W.y();
      ghost_data->qpos[root_qpos + 6] = pose.q_W.z();
      mj_kinematics(model, ghost_data);
      const int first = scene.ngeom;
      mjv_addGeoms(model, ghost_data, &vis_options, nullptr, mjCAT_DYNAMIC, &scene);
      const std::array<float, 3> c = GhostColor(k);
      const Rgba rgba = {c[0], c[1], c[2], static_cast<float>(options.ghost_alpha)};
      // The ghost is the robot's silhouette: its small parts (fasteners, sensor bodies)
      // cost a software rasteriser draw calls and show nothing at a ghost's opacity.
      int kept = first;
      for (int i = first; i < scene.ngeom; ++i) {
        if (scene.geoms[i].modelrbound > 0.0f && scene.geoms[i].modelrbound < kGhostMinRadius_m) continue;
        scene.geoms[kept] = scene.geoms[i];
        mjvGeom* g = scene.geoms + kept++;
        Style(g, rgba, 0.25f);
        g->transparent = options.ghost_alpha < 1.0;
      }
      scene.ngeom = kept;
    }
  }

  void AddSensorMarkers(core::Time t_ns) {
    const core::Time trail_ns = core::SecondsToTime(options.trail_s);
    for (size_t k = 0; k < run.sensors.size(); ++k) {
      const SensorTrack& s = run.sensors[k];
      if (s.t_ns.empty()) continue;
      const Rgba color = SensorColor(k);
      const auto end = std::upper_bound(s.t_ns.begin(), s.t_ns.end(), t_ns);
      if (end == s.t_ns.begin()) continue;
      const size_t last = static_cast<size_t>(end - s.t_ns.begin()) - 1;
      const core::Time age_ns = t_ns - s.t_ns[last];
      if (age_ns > kMarkerMaxAge_ns) continue;  // silent sensor: no marker
      const bool faulted = !s.faults[last].empty();
      // A stale sample (the sensor went quiet) fades out over kMarkerMaxAge_ns.
      Rgba marker = color;
      marker[3] = 1.0f - 0.7f * static_cast<float>(age_ns) / static_cast<float>(kMarkerMaxAge_ns);
      AddSphere(s.p_W[last], 0.045, marker);
      if (faulted) AddSphere(s.p_W[last], 0.075, {kBlockedRed[0], kBlockedRed[1], kBlockedRed[2], 0.35f});
      // Trail: at most 60 segments over the last trail_s.
      const auto begin =
          std::lower_bound(s.t_ns.begin(), s.t_ns.end(), t_ns - trail_ns) - s.t_ns.begin();
      const size_t first = static_cast<size_t>(begin);
      const size_t stride = std::max<size_t>(1, (last - first) / 60 + 1);
      Rgba trail = color;
      trail[3] = 0.7f;
      size_t previous = first;
      for (size_t i = first + stride; i <= last; i += stride) {
        AddSegment(s.p_W[previous], s.p_W[i], 0.008, trail);
        previous = i;
      }
      if (previous != last) AddSegment(s.p_W[previous], s.p_W[last], 0.008, trail);
    }
  }

  void AddLineOfSight(core::Time t_ns, const Eigen::Isometry3d& T_WB) {
    for (const SensorTrack& s : run.sensors) {
      if (replay::SensorModelOfName(s.type) != replay::SensorModel::kTotalStation) continue;
      const Eigen::Vector3d station_W = s.true_T_WS.translation();
      const Eigen::Vector3d prism_W = T_WB * Mount(s.site).translation();
      const bool blocked = run.LabelActive(s.name, "occluded", t_ns);
      AddSegment(station_W, prism_W, 0.01, blocked ? kBlockedRed : kClearGreen);
      AddSphere(station_W, 0.06, blocked ? kBlockedRed : kClearGreen);
    }
  }

  void AddLidarHits(const Eigen::Isometry3d& T_WB) {
    for (const LidarGeometry& lidar : lidars) {
      const Eigen::Isometry3d T_Ws = T_WB * Mount(lidar.site);
      const core::LidarBeamPattern& beams = lidar.beams;
      for (int row = 0; row < beams.elevation_count; ++row) {
        for (int column = 0; column < beams.azimuth_count; ++column) {
          const Eigen::Vector3d d_s = beams.Direction_s(row, column);
          const auto hit = world->CastRay(T_Ws.translation(), T_Ws.linear() * d_s, sim::kRayScene);
          if (!hit || !beams.InRange(hit->distance_m)) continue;
          AddSphere(hit->point_W, 0.02, {1.0f, 0.45f, 0.0f, 1.0f});
        }
      }
    }
  }

  void AddSkyRays(const Eigen::Isometry3d& T_WB) {
    constexpr double kDrawnLength_m = 6.0;
    for (const SkyGeometry& sky : skies) {
      const Eigen::Vector3d antenna_W = T_WB * Mount(sky.site).translation();
      for (const Eigen::Vector3d& d_S : sky.directions_S) {
        const Eigen::Vector3d d_W = sky.T_WS.linear() * d_S;
        const auto hit = world->CastRay(antenna_W, d_W, sim::kRayScene);
        const bool blocked = hit && hit->distance_m <= sky.ray_length_m;
        const double length = blocked ? std::min(hit->distance_m, kDrawnLength_m) : kDrawnLength_m;
        Rgba c = blocked ? kBlockedRed : kClearGreen;
        c[3] = 0.8f;
        AddSegment(antenna_W, antenna_W + length * d_W.normalized(), 0.005, c);
      }
    }
  }

  // ---- cameras ----

  double SetCamera(core::Time t_ns, const std::string& name, const TimedPose& truth) {
    cutaway_targets.clear();
    if (name == "overview") {
      camera = overview;
      if (camera.type == mjCAMERA_FREE) {
        cutaway_targets = overview_targets;
        cutaway_targets.push_back(truth.p_W);
      }
      return overview_fovy_deg;
    }
    if (name == "chase") {
      // Behind the robot, looking along its heading averaged over the last 2 s (smooth
      // under yaw oscillation; an OMAV may fly sideways, so not along the velocity).
      Eigen::Vector2d heading = Eigen::Vector2d::Zero();
      for (int k = 0; k <= 20; ++k) {
        const TimedPose p = InterpolatePose(run.groundtruth, t_ns - k * 100'000'000);
        const Eigen::Vector3d x_W = p.q_W * Eigen::Vector3d::UnitX();
        heading += x_W.head<2>();
      }
      const double azimuth =
          heading.norm() > 1e-6 ? std::atan2(heading.y(), heading.x()) / kDegToRad : overview.azimuth;
      const Eigen::Vector3d lookat = truth.p_W + Eigen::Vector3d(0.0, 0.0, 0.1);
      camera.type = mjCAMERA_FREE;
      for (int k = 0; k < 3; ++k) camera.lookat[k] = lookat(k);
      camera.azimuth = azimuth;
      camera.elevation = kChaseElevationDeg;
      camera.distance = ClearDistance(lookat, Forward(azimuth, kChaseElevationDeg), kChaseDistance_m);
      for (const double dx : {-0.4, 0.0, 0.4}) {
        for (const double dy : {-0.4, 0.0, 0.4}) {
          cutaway_targets.push_back(truth.p_W + Eigen::Vector3d(dx, dy, 0.0));
        }
      }
      return kChaseFovyDeg;
    }
    const int id = mj_name2id(model, mjOBJ_CAMERA, name.c_str());
    if (id < 0) {
      throw core::InputError({run.directory.string()}, "--camera",
                             fmt::format("unknown camera '{}'; expected one of: {}", name,
                                         fmt::join(CameraNames(), ", ")));
    }
    camera.type = mjCAMERA_FIXED;
    camera.fixedcamid = id;
    return model->cam_fovy[id];
  }

  std::vector<std::string> CameraNames() const {
    std::vector<std::string> names = {"chase", "overview"};
    for (int i = 0; i < model->ncam; ++i) {
      const char* n = mj_id2name(model, mjOBJ_CAMERA, i);
      if (n != nullptr && std::strcmp(n, "overview") != 0) names.emplace_back(n);
    }
    return names;
  }

  Image Render(core::Time t_ns, const std::string& camera_name, const std::string& caption) {
    egl->MakeCurrent();
    t_ns = std::clamp(t_ns, run.start_ns(), run.end_ns());
    const TimedPose truth = InterpolatePose(run.groundtruth, t_ns);

    // The true robot: World::Reset places it with the hover tilts of its attitude (the
    // run directory does not record joint angles).
    world->Reset(sim::Waypoint{truth.p_W, truth.q_W});
    mju_copy(data->qpos, world->data()->qpos, model->nq);
    mju_zero(data->qvel, model->nv);
    data->time = core::TimeToSeconds(t_ns);
    mj_forward(model, data);

    const double fovy_deg = SetCamera(t_ns, camera_name, truth);
    model->vis.global.fovy = static_cast<float>(fovy_deg);
    mjv_updateScene(model, data, &vis_options, nullptr, &camera, mjCAT_ALL, &scene);
    if (!cutaway_targets.empty()) {
      const Eigen::Vector3d lookat(camera.lookat[0], camera.lookat[1], camera.lookat[2]);
      const Eigen::Vector3d eye = lookat - camera.distance * Forward(camera.azimuth, camera.elevation);
      const std::set<int> occluders = Occluders(eye, cutaway_targets);
      for (int i = 0; i < scene.ngeom; ++i) {
        mjvGeom& g = scene.geoms[i];
        if (g.objtype != mjOBJ_GEOM || occluders.count(g.objid) == 0) continue;
        g.rgba[3] = std::min(g.rgba[3], kCutawayAlpha);
        g.transparent = 1;
      }
    }

    const Eigen::Isometry3d T_WB = truth.T_W();
    AddLineOfSight(t_ns, T_WB);
    AddSensorMarkers(t_ns);
    if (options.lidar_hits) AddLidarHits(T_WB);
    if (options.gnss_sky) AddSkyRays(T_WB);
    AddGhosts(t_ns);

    // Transparent geoms are drawn back to front by camera distance.
    const mjvGLCamera eye = mjv_averageCamera(scene.camera, scene.camera + 1);
    for (int i = 0; i < scene.ngeom; ++i) {
      mjvGeom& g = scene.geoms[i];
      const float dx = g.pos[0] - eye.pos[0];
      const float dy = g.pos[1] - eye.pos[1];
      const float dz = g.pos[2] - eye.pos[2];
      g.camdist = std::sqrt(dx * dx + dy * dy + dz * dz);
    }
    scene.flags[mjRND_SHADOW] = options.shadows ? 1 : 0;
    scene.flags[mjRND_REFLECTION] = options.reflections ? 1 : 0;
    scene.flags[mjRND_SKYBOX] = 1;

    view.name = camera_name;
    view.p_W = Eigen::Vector3d(eye.pos[0], eye.pos[1], eye.pos[2]);
    view.forward_W = Eigen::Vector3d(eye.forward[0], eye.forward[1], eye.forward[2]).normalized();
    view.up_W = Eigen::Vector3d(eye.up[0], eye.up[1], eye.up[2]).normalized();
    view.fovy_deg = fovy_deg;
    view.width_px = options.width_px;
    view.height_px = options.height_px;

    mjr_setBuffer(mjFB_OFFSCREEN, &context);
    const mjrRect viewport = {0, 0, options.width_px, options.height_px};
    mjr_render(viewport, &scene, &context);
    if (options.text_overlay) {
      overlay->DrawText(t_ns, camera_name, caption);
      overlay->DrawLegend();
    }
    if (options.heatmap) overlay->DrawHeatmap(t_ns);

    // Read back (OpenGL rows run bottom to top) and flip.
    Image bottom_up(options.width_px, options.height_px);
    mjr_readPixels(bottom_up.rgb.data(), nullptr, viewport, &context);
    Image image(options.width_px, options.height_px);
    const size_t row = static_cast<size_t>(3) * options.width_px;
    for (int y = 0; y < options.height_px; ++y) {
      std::memcpy(image.rgb.data() + row * y,
                  bottom_up.rgb.data() + row * (options.height_px - 1 - y), row);
    }
    return image;
  }
};

SceneRenderer::SceneRenderer(const RunData& run, const RenderOptions& options)
    : impl_(std::make_unique<Impl>(run, options)) {
  impl_->Build();
}

SceneRenderer::~SceneRenderer() = default;

Image SceneRenderer::Render(core::Time t_ns, const std::string& camera, const std::string& caption) {
  return impl_->Render(t_ns, camera, caption);
}

const CameraView& SceneRenderer::last_view() const { return impl_->view; }
std::vector<std::string> SceneRenderer::CameraNames() const { return impl_->CameraNames(); }

std::vector<std::string> SceneRenderer::GhostMethods() const {
  std::vector<std::string> names;
  for (const MethodEstimate* g : impl_->ghosts) names.push_back(g->method);
  return names;
}

std::string SceneRenderer::GlDescription() const { return impl_->egl->Description(); }

}  // namespace tofu::renders
