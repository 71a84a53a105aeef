#include "sim/world.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <limits>
#include <regex>
#include <stdexcept>
#include <string>
#include <tuple>
#include <utility>
#include <vector>

#include <fmt/format.h>
#include <fmt/ranges.h>
#include <mujoco/mujoco.h>

#include "core/error.h"
#include "core/file_io.h"
#include "sim/geom_distance.h"

namespace tofu::sim {
namespace {

namespace fs = std::filesystem;

const char* const kRequiredSites[] = {"imu",   "vio_camera",   "lidar",
                                      "prism", "gnss_antenna", "tool_tip"};
constexpr int kGroundGeomGroup = 1;     // floors, terrain, water (models/ README)
constexpr int kStructureGeomGroup = 0;  // world solids

// MuJoCo reports warnings through a global hook; keep the last text so that a bad
// state turns into an error that says what MuJoCo saw.
thread_local std::string g_last_mujoco_warning;

void OnMujocoWarning(const char* message) { g_last_mujoco_warning = message; }

[[noreturn]] void OnMujocoError(const char* message) {
  // MuJoCo's engine errors are internal invariants (e.g. out of memory); unwinding C++
  // exceptions through its C frames is undefined, so report and stop.
  std::fprintf(stderr, "tofu: MuJoCo engine error: %s\n", message);
  std::abort();
}

void InstallMujocoHandlers() {
  static const bool installed = [] {
    mju_user_warning = OnMujocoWarning;
    mju_user_error = OnMujocoError;
    return true;
  }();
  (void)installed;
}

Eigen::Vector3d Vec3(const mjtNum* v) { return Eigen::Vector3d(v[0], v[1], v[2]); }

Eigen::Matrix3d Mat3(const mjtNum* m) {
  Eigen::Matrix3d R;
  R << m[0], m[1], m[2], m[3], m[4], m[5], m[6], m[7], m[8];
  return R;
}

void RequireModelFile(const fs::path& path, const std::string& key) {
  if (!fs::is_regular_file(path)) {
    std::vector<std::string> names;
    if (fs::is_directory(path.parent_path())) {
      for (const auto& entry : fs::directory_iterator(path.parent_path())) {
        if (entry.path().extension() == ".xml") names.push_back(entry.path().stem().string());
      }
    }
    std::sort(names.begin(), names.end());
    const std::string available = fmt::format("{}", fmt::join(names, ", "));
    throw core::InputError({path.string(), 0, 0}, key,
                           fmt::format("model file not found; available: {}",
                                       available.empty() ? "(none)" : available));
  }
}

// A lower bound on the distance from a point to a geom (0 or negative when inside), exact
// for the primitives worlds are built of. The contact gate and the distance tracker only
// skip what lies provably beyond reach, so a bound that errs low costs time, never truth.
double PointGeomDistanceLowerBound(int type, const mjtNum* size, double rbound_m,
                                   const Eigen::Vector3d& p_W_geom,
                                   const Eigen::Matrix3d& R_W_geom,
                                   const Eigen::Vector3d& p_W) {
  const Eigen::Vector3d p = R_W_geom.transpose() * (p_W - p_W_geom);
  switch (type) {
    case mjGEOM_PLANE:  // infinite for collision, solid below z = 0
      return p.z();
    case mjGEOM_SPHERE:
      return p.norm() - size[0];
    case mjGEOM_CAPSULE:
      return Eigen::Vector3d(p.x(), p.y(), p.z() - std::clamp(p.z(), -size[1], size[1])).norm() -
             size[0];
    case mjGEOM_CYLINDER:
      return std::hypot(std::max(std::hypot(p.x(), p.y()) - size[0], 0.0),
                        std::max(std::abs(p.z()) - size[1], 0.0));
    case mjGEOM_BOX:
      return (p.cwiseAbs() - Vec3(size)).cwiseMax(0.0).norm();
    case mjGEOM_ELLIPSOID:
      return p.norm() - std::max({size[0], size[1], size[2]});
    default:  // meshes, height fields: their bounding sphere, or nothing known
      return rbound_m > 0.0 ? p.norm() - rbound_m : -std::numeric_limits<double>::infinity();
  }
}

// The MJCF without the spans between <!-- tofu:visual-only --> and
// <!-- /tofu:visual-only -->, or nullopt if it has none (or they do not pair up).
std::optional<std::string> StripVisualOnly(const std::string& mjcf) {
  static const std::string kBegin = "<!-- tofu:visual-only -->";
  static const std::string kEnd = "<!-- /tofu:visual-only -->";
  std::string out;
  size_t at = 0;
  bool stripped = false;
  while (true) {
    const size_t begin = mjcf.find(kBegin, at);
    if (begin == std::string::npos) break;
    const size_t end = mjcf.find(kEnd, begin);
    if (end == std::string::npos) return std::nullopt;
    out.append(mjcf, at, begin - at);
    at = end + kEnd.size();
    stripped = true;
  }
  if (!stripped) return std::nullopt;
  out.append(mjcf, at, std::string::npos);
  return out;
}

// The MJCF with each procedural (builtin) texture generated at 8 texels across, its
// aspect kept. The physics model needs a material's texture only to know that the
// material is textured (RayHit::textured); generating the renderer's 512-texel builtins
// is 90 % of loading a scene, and the complete scene still has them.
std::string ShrinkBuiltinTextures(const std::string& mjcf) {
  static const std::regex kTexture(R"re(<texture\b[^>]*>)re");
  static const std::regex kBuiltin(R"re(\bbuiltin\s*=\s*"(\w+)")re");
  static const std::regex kWidth(R"re(\bwidth\s*=\s*"(\d+)")re");
  static const std::regex kHeight(R"re(\bheight\s*=\s*"(\d+)")re");
  constexpr long kTexels = 8;
  std::string out;
  auto at = mjcf.cbegin();
  for (std::sregex_iterator it(mjcf.begin(), mjcf.end(), kTexture), end; it != end; ++it) {
    std::string element = it->str();
    std::smatch builtin;
    std::smatch width;
    std::smatch height;
    if (std::regex_search(element, builtin, kBuiltin) && builtin[1] != "none" &&
        std::regex_search(element, width, kWidth) && std::regex_search(element, height, kHeight)) {
      const long w = std::stol(width[1]);
      const long h = std::stol(height[1]);
      if (w > kTexels) {
        const long new_h = std::max(1L, h * kTexels / w);
        element = std::regex_replace(element, kWidth, fmt::format("width=\"{}\"", kTexels));
        element = std::regex_replace(element, kHeight, fmt::format("height=\"{}\"", new_h));
      }
    }
    out.append(at, mjcf.cbegin() + it->position());
    out += element;
    at = mjcf.cbegin() + it->position() + it->length();
  }
  out.append(at, mjcf.cend());
  return out;
}

bool BitmasksCollide(const mjModel* m, int g1, int g2) {
  return (m->geom_contype[g1] & m->geom_conaffinity[g2]) != 0 ||
         (m->geom_contype[g2] & m->geom_conaffinity[g1]) != 0;
}

bool BodiesExcluded(const mjModel* m, int b1, int b2) {
  const int signature = (std::min(b1, b2) << 16) + std::max(b1, b2);
  for (int e = 0; e < m->nexclude; ++e) {
    if (m->exclude_signature[e] == signature) return true;
  }
  return false;
}

}  // namespace

std::string DefaultModelsDir() {
  if (const char* env = std::getenv("TOFU_MODELS_DIR"); env != nullptr && *env != '\0') {
    return env;
  }
  return TOFU_DEFAULT_MODELS_DIR;
}

const MountSite* RobotDescription::FindSite(const std::string& name) const {
  for (const MountSite& site : sites) {
    if (site.name == name) return &site;
  }
  return nullptr;
}

const MountSite& RobotDescription::Site(const std::string& name, const std::string& who) const {
  const MountSite* site = FindSite(name);
  if (site == nullptr) throw std::invalid_argument(who + ": the robot has no site '" + name + "'");
  return *site;
}

Eigen::Isometry3d MountSite::T_Bs() const {
  Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
  T.translation() = p_Bs;
  T.linear() = q_Bs.normalized().toRotationMatrix();
  return T;
}

struct World::Impl {
  WorldOptions options;
  // The physics steps a model without the robot's visual-only bodies (marked in its MJCF):
  // their ~60 geoms cost a third of MuJoCo's step in kinematics alone. The complete
  // scene (m_full, d_full) serves the renderer and rays that must see the robot's shapes;
  // its kinematics is brought up to date only when asked. Without marks both are one.
  mjModel* m = nullptr;
  mjData* d = nullptr;
  mjModel* m_full = nullptr;
  mjData* d_full = nullptr;
  std::vector<int> geom_to_full;        // physics geom id -> complete scene's
  uint32_t visual_only_groups = 0;      // geom groups only the complete scene holds
  std::vector<mjtNum> qpos_kinematics;  // the qpos d's kinematics was computed at
  int64_t full_synced_step = -1;
  RobotDescription robot;
  int base_body = -1;
  int qpos_root = 0;  // address of the free joint in qpos
  int qvel_root = 0;
  std::array<int, kArmCount> tilt_qpos{};
  std::array<int, kArmCount> tilt_servo_actuator{};
  std::array<int, kArmCount> thrust_actuator{};  // one per coaxial pair (both rotors alike)
  std::array<double, kArmCount> tilt_target_rad{};
  Eigen::Vector3d external_force_W = Eigen::Vector3d::Zero();  // on the base's CoM
  Eigen::Vector3d base_p_B_com = Eigen::Vector3d::Zero();      // the base body's own CoM
  std::vector<char> is_robot_geom;   // by geom id
  std::vector<char> is_foot_geom;    // landing gear: ground contact allowed
  std::array<int, mjNWARNING> warning_count{};
  TruthState last_step_truth;
  mutable TruthState state_now;        // see StateNow
  mutable int64_t state_now_step = -1;
  core::Time timestep_ns = 0;
  int64_t step_count = 0;
  std::vector<Contact> contacts_buffer;  // time is step_count * timestep_ns: no float accumulation

  // Contact gate (see GateContacts) and distance tracking (see World::ClosestStructure).
  struct StaticGeom {
    int id = -1;
    Eigen::Vector3d p_W = Eigen::Vector3d::Zero();
    Eigen::Matrix3d R_W = Eigen::Matrix3d::Identity();
    double margin_m = 0.0;  ///< contact margin of its pairs with the robot
  };
  std::vector<int> robot_proxies;            // robot geoms that can collide with the world
  std::vector<StaticGeom> world_colliders;   // static world geoms some proxy can touch
  std::vector<std::vector<int>> structure_partners;  // by geom id: proxies it pairs with
  std::vector<int> structure_geoms;          // group-0 geoms with partners
  double robot_reach_m = 0.0;  // every proxy lies within this distance of B's origin
  bool gate_contacts = false;  // the gate is sound for this scene
  bool static_structure = false;  // structure geoms never move (clearances stay valid)
  // Distances to convex sets (and to planes) change no faster than the point moves: while
  // B's origin stays within the clearance measured at `reference_W`, whatever was out of
  // reach there still is (a few ns instead of a pass over the world).
  struct Clearance {
    Eigen::Vector3d reference_W = Eigen::Vector3d::Zero();
    double clearance_m = -1.0;  // < 0: nothing known
    bool Holds(const Eigen::Vector3d& p_W) const {
      return (p_W - reference_W).norm() < clearance_m;
    }
    void Set(const Eigen::Vector3d& p_W, double clearance) {
      reference_W = p_W;
      clearance_m = clearance;
    }
    void Forget() { clearance_m = -1.0; }
  };
  Clearance gate_clearance;       // no world geom within the robot's reach
  Clearance structure_clearance;  // no structure within the distance horizon
  int model_disableflags = 0;
  int64_t closest_step = -1;   // step of the cached ClosestStructure answer
  std::optional<Proximity> closest;
  std::vector<mjContact> narrow_phase_scratch;
  struct DistanceCandidate {
    double lower_bound_m;
    int proxy;
    int geom;
  };
  std::vector<DistanceCandidate> distance_candidates;

  ConvexGeom GeomNow(int g) const {
    return {m->geom_type[g], Vec3(m->geom_size + 3 * g), Vec3(d->geom_xpos + 3 * g),
            Mat3(d->geom_xmat + 9 * g)};
  }

  // Distance between a proxy and a structure geom now: exact (to 1 um) while apart; when
  // they touch, the penetration MuJoCo's contact functions report (as in Contacts()).
  double PairDistance(int proxy, int g, double lower_bound_m) {
    std::optional<double> apart_m;
    const int type = m->geom_type[g];
    if (m->geom_type[proxy] == mjGEOM_SPHERE &&
        (type == mjGEOM_BOX || type == mjGEOM_CYLINDER || type == mjGEOM_SPHERE ||
         type == mjGEOM_CAPSULE || type == mjGEOM_PLANE)) {
      apart_m = lower_bound_m;  // exact for a sphere against these
    } else {
      apart_m = GeomDistance(GeomNow(proxy), GeomNow(g));
    }
    if (apart_m && *apart_m > 0.0) return *apart_m;
    // As MuJoCo's pipeline orders a pair: the world body's geom first, unless the table
    // (which holds each type pair once, lower type first) wants them swapped. Box-box is
    // not symmetric in deep penetration.
    int g1 = g;
    int g2 = proxy;
    if (m->geom_type[g1] > m->geom_type[g2]) std::swap(g1, g2);
    const mjfCollision collide = mjCOLLISIONFUNC[m->geom_type[g1]][m->geom_type[g2]];
    if (collide == nullptr) return std::numeric_limits<double>::infinity();
    // Meshes and height fields: MuJoCo's own estimate within the horizon.
    const double margin_m = apart_m ? 0.0 : options.distance_horizon_m;
    const int n = collide(m, d, narrow_phase_scratch.data(), g1, g2, margin_m);
    double distance_m = apart_m ? 0.0 : std::numeric_limits<double>::infinity();
    for (int i = 0; i < n; ++i) distance_m = std::min(distance_m, narrow_phase_scratch[i].dist);
    return distance_m;
  }

  ~Impl() {
    if (d != nullptr) mj_deleteData(d);
    if (m != nullptr) mj_deleteModel(m);
    if (d_full != nullptr) mj_deleteData(d_full);
    if (m_full != nullptr) mj_deleteModel(m_full);
  }

  const mjModel* Full() const { return m_full != nullptr ? m_full : m; }
  // The hit of a ray (unit direction) on `geom` of `model` (the physics model, or the
  // complete scene when `full`) at `distance_m` (see CastRay).
  RayHit HitOn(const mjModel* model, const mjData* data, bool full, int geom, double distance_m,
               const Eigen::Vector3d& origin_W, const Eigen::Vector3d& unit_W) const;
  int ToFull(int geom) const { return geom < 0 || m_full == nullptr ? geom : geom_to_full[geom]; }

  // The complete scene at the physics state: state arrays now, kinematics (geom and site
  // poses) at the last step's start, as d's.
  mjData* SyncedFull() {
    if (m_full == nullptr) return d;
    if (full_synced_step != step_count) {
      mju_copy(d_full->qpos, qpos_kinematics.data(), m->nq);
      mj_kinematics(m_full, d_full);
      mju_copy(d_full->qpos, d->qpos, m->nq);
      mju_copy(d_full->qvel, d->qvel, m->nv);
      mju_copy(d_full->act, d->act, m->na);
      mju_copy(d_full->ctrl, d->ctrl, m->nu);
      d_full->time = d->time;
      full_synced_step = step_count;
    }
    return d_full;
  }

  int Id(int type, const std::string& name, const char* what) const {
    const int id = mj_name2id(m, type, name.c_str());
    if (id < 0) {
      throw core::InputError(
          {fs::path(options.models_dir) / "robots" / (options.robot + ".xml"), 0, 0}, "robot",
          fmt::format("the robot model has no {} named '{}'", what, name));
    }
    return id;
  }

  void Load() {
    const fs::path models = fs::absolute(options.models_dir);
    RequireModelFile(models / "worlds" / (options.world + ".xml"), "world");
    RequireModelFile(models / "robots" / (options.robot + ".xml"), "robot");
    // Compose the scene in memory; includes resolve relative to models/.
    const std::string scene = fmt::format(
        "<mujoco model=\"tofu_{0}_{1}\">\n"
        "  <include file=\"common/materials.xml\"/>\n"
        "  <include file=\"robots/{1}.xml\"/>\n"
        "  <include file=\"worlds/{0}.xml\"/>\n"
        "</mujoco>\n",
        options.world, options.robot);
    m_full = LoadScene(models, scene, {});
    // The physics model: the same scene with the robot's visual-only parts cut out.
    const fs::path robot_path = models / "robots" / (options.robot + ".xml");
    const std::optional<std::string> physics_robot =
        StripVisualOnly(core::ReadWholeFile(robot_path, "robot model"));
    if (physics_robot) {
      const fs::path materials_path = models / "common" / "materials.xml";
      m = LoadScene(models, scene,
                    {{robot_path.string(), *physics_robot},
                     {materials_path.string(),
                      ShrinkBuiltinTextures(core::ReadWholeFile(materials_path, "materials"))}});
      if (!MapGeomsToFull()) {  // not a pure cut (e.g. unnamed bodies): one model for all
        mj_deleteModel(m);
        m = nullptr;
      }
    }
    if (m == nullptr) std::swap(m, m_full);
    for (mjModel* model : {m, m_full}) {
      if (model == nullptr) continue;
      model->opt.timestep = 1.0 / options.physics_rate_hz;
      model->opt.integrator = mjINT_EULER;
    }
    timestep_ns = core::PeriodFromRate(options.physics_rate_hz);
    d = mj_makeData(m);
    if (m_full != nullptr) d_full = mj_makeData(m_full);
    qpos_kinematics.assign(d->qpos, d->qpos + m->nq);
  }

  // Loads the scene; override_files replace files it includes (path, text).
  mjModel* LoadScene(const fs::path& models, const std::string& scene,
                     const std::vector<std::pair<std::string, std::string>>& override_files) {
    const std::string scene_path = (models / "scene.xml").string();
    mjVFS vfs;
    mj_defaultVFS(&vfs);
    const auto add = [&vfs](const std::string& path, const std::string& text) {
      mj_makeEmptyFileVFS(&vfs, path.c_str(), static_cast<int>(text.size()));
      const int file = mj_findFileVFS(&vfs, path.c_str());
      std::memcpy(vfs.filedata[file], text.data(), text.size());
    };
    add(scene_path, scene);
    // MuJoCo looks includes up in the VFS (by file name) before the disk.
    for (const auto& [path, text] : override_files) add(path, text);
    char error[1024] = "";
    mjModel* model = mj_loadXML(scene_path.c_str(), &vfs, error, sizeof(error));
    mj_deleteVFS(&vfs);
    if (model == nullptr) {
      throw core::InputError({(models / "worlds" / (options.world + ".xml")).string(), 0, 0},
                             "world", fmt::format("MuJoCo could not load the scene: {}", error));
    }
    return model;
  }

  // Geom ids of m in m_full: bodies match by name (the world body is 0), and a kept body
  // keeps all its geoms in order. False if m is not such a cut of m_full.
  bool MapGeomsToFull() {
    if (m->nq != m_full->nq || m->nv != m_full->nv || m->nu != m_full->nu ||
        m->na != m_full->na) {
      return false;
    }
    geom_to_full.assign(m->ngeom, -1);
    std::vector<char> mapped(m_full->ngeom, 0);
    for (int b = 0; b < m->nbody; ++b) {
      const char* name = mj_id2name(m, mjOBJ_BODY, b);
      const int full_body = b == 0 ? 0 : (name ? mj_name2id(m_full, mjOBJ_BODY, name) : -1);
      if (full_body < 0 || m->body_geomnum[b] != m_full->body_geomnum[full_body]) return false;
      for (int k = 0; k < m->body_geomnum[b]; ++k) {
        const int g = m->body_geomadr[b] + k;
        const int full = m_full->body_geomadr[full_body] + k;
        if (m->geom_type[g] != m_full->geom_type[full]) return false;
        geom_to_full[g] = full;
        mapped[full] = 1;
      }
    }
    visual_only_groups = 0;
    for (int g = 0; g < m_full->ngeom; ++g) {
      if (mapped[g]) continue;
      if (m_full->geom_contype[g] != 0 || m_full->geom_conaffinity[g] != 0) return false;
      visual_only_groups |= 1u << m_full->geom_group[g];
    }
    return true;
  }

  void IndexRobot() {
    base_body = Id(mjOBJ_BODY, "base", "body");
    const int root_joint = Id(mjOBJ_JOINT, "root", "joint");
    if (m->jnt_type[root_joint] != mjJNT_FREE || m->jnt_bodyid[root_joint] != base_body) {
      throw core::InputError({options.robot, 0, 0}, "robot",
                             "joint 'root' must be the free joint of body 'base'");
    }
    qpos_root = m->jnt_qposadr[root_joint];
    qvel_root = m->jnt_dofadr[root_joint];
    base_p_B_com = Vec3(m->body_ipos + 3 * base_body);
    for (int k = 0; k < kArmCount; ++k) {
      const int joint = Id(mjOBJ_JOINT, fmt::format("tilt_{}", k + 1), "joint");
      tilt_qpos[k] = m->jnt_qposadr[joint];
      tilt_servo_actuator[k] = Id(mjOBJ_ACTUATOR, fmt::format("tilt_servo_{}", k + 1), "actuator");
      thrust_actuator[k] = Id(mjOBJ_ACTUATOR, fmt::format("thrust_{}", k + 1), "actuator");
    }
    is_robot_geom.assign(m->ngeom, 0);
    is_foot_geom.assign(m->ngeom, 0);
    for (int g = 0; g < m->ngeom; ++g) {
      const int body = m->geom_bodyid[g];
      if (m->body_rootid[body] != base_body) continue;
      if (m->geom_contype[g] == 0 && m->geom_conaffinity[g] == 0) continue;
      is_robot_geom[g] = 1;
      const char* name = mj_id2name(m, mjOBJ_GEOM, g);
      is_foot_geom[g] = name != nullptr && std::strncmp(name, "foot", 4) == 0;
    }
  }

  // Contacts need MuJoCo's collision pipeline only when some robot proxy can reach a world
  // geom. MuJoCo 2.2.2 has no cheap broad phase for that (its sweep-and-prune plus the
  // bounding-sphere tests of every proxy against every world geom cost ~10 us a step, half
  // the step), so the World tests one sphere that encloses all proxies against the static
  // world geoms and switches contacts off for the steps where nothing is within reach. The
  // physics is unchanged: those steps would have produced no contact anyway.
  void IndexContacts() {
    model_disableflags = m->opt.disableflags;
    std::vector<double> reach_m(m->nbody, 0.0);  // of a body's origin from B's, any pose
    bool reach_bounded = true;
    for (int b = 0; b < m->nbody; ++b) {
      if (m->body_rootid[b] != base_body || b == base_body) continue;
      double r = reach_m[m->body_parentid[b]] + Vec3(m->body_pos + 3 * b).norm();
      for (int j = m->body_jntadr[b]; j < m->body_jntadr[b] + m->body_jntnum[b]; ++j) {
        // A hinge or ball about an anchor a from the origin moves the origin by <= 2|a|.
        if (m->jnt_type[j] == mjJNT_HINGE || m->jnt_type[j] == mjJNT_BALL) {
          r += 2.0 * Vec3(m->jnt_pos + 3 * j).norm();
        } else {
          reach_bounded = false;
        }
      }
      reach_m[b] = r;
    }
    robot_reach_m = 0.0;
    double proxy_margin_m = 0.0;
    bool self_collision = false;
    robot_proxies.clear();
    for (int g = 0; g < m->ngeom; ++g) {
      if (!is_robot_geom[g]) continue;
      robot_proxies.push_back(g);
      robot_reach_m = std::max(robot_reach_m, reach_m[m->geom_bodyid[g]] +
                                                  Vec3(m->geom_pos + 3 * g).norm() +
                                                  m->geom_rbound[g]);
      proxy_margin_m = std::max(proxy_margin_m, m->geom_margin[g]);
      for (const int other : robot_proxies) {
        self_collision |= other != g && m->geom_bodyid[other] != m->geom_bodyid[g] &&
                          BitmasksCollide(m, g, other);
      }
    }
    // DescribeRobot's mj_forward left the static geoms' poses in d.
    bool dynamic_colliders = false;
    world_colliders.clear();
    structure_geoms.clear();
    structure_partners.assign(m->ngeom, {});
    for (int g = 0; g < m->ngeom; ++g) {
      if (is_robot_geom[g]) continue;
      std::vector<int> partners;
      for (const int proxy : robot_proxies) {
        if (BitmasksCollide(m, g, proxy) &&
            !BodiesExcluded(m, m->geom_bodyid[g], m->geom_bodyid[proxy])) {
          partners.push_back(proxy);
        }
      }
      if (partners.empty()) continue;
      if (m->geom_group[g] == kStructureGeomGroup) {
        structure_geoms.push_back(g);
        structure_partners[g] = std::move(partners);
      }
      if (m->body_weldid[m->geom_bodyid[g]] != 0) {
        dynamic_colliders = true;  // only static geoms keep the poses recorded here
        continue;
      }
      world_colliders.push_back({g, Vec3(d->geom_xpos + 3 * g), Mat3(d->geom_xmat + 9 * g),
                                 std::max(m->geom_margin[g], proxy_margin_m)});
    }
    gate_contacts = reach_bounded && !self_collision && !dynamic_colliders &&
                    (model_disableflags & mjDSBL_CONTACT) == 0;
    static_structure = reach_bounded && !dynamic_colliders;
    gate_clearance.Forget();
    structure_clearance.Forget();
    narrow_phase_scratch.resize(mjMAXCONPAIR);
  }

  // The external force on the base's CoM as the free joint's generalised force, J^T f:
  // the CoM moves with v_com = v_WB + R_WB (omega_B x p_B_com), so its Jacobian is I on
  // the free joint's translation (velocity in W), -R_WB [p_B_com]x on its rotation
  // (angular velocity in B) and zero on the hinges, which do not move the base; hence
  // J^T f = (f, p_B_com x R_WB^T f). MuJoCo's xfrc_applied computes the same J^T f with a
  // dense Jacobian over all dofs (mj_applyFT): 2 % of the step for three numbers.
  // Evaluated every step at the current attitude, so a force held in W stays in W.
  void ApplyExternalForce(const Eigen::Quaterniond& q_WB) {
    mjtNum* f = d->qfrc_applied + qvel_root;
    if (external_force_W.isZero(0.0)) {
      std::fill(f, f + 6, 0.0);
      return;
    }
    const Eigen::Vector3d torque_B = base_p_B_com.cross(q_WB.conjugate() * external_force_W);
    for (int k = 0; k < 3; ++k) {
      f[k] = external_force_W(k);
      f[3 + k] = torque_B(k);
    }
  }

  // Switches MuJoCo's contacts on for the coming step when a proxy may touch a world geom
  // at the current qpos (the one mj_step's collision detection will see).
  void GateContacts() {
    if (!gate_contacts) return;
    const Eigen::Vector3d p_WB = Vec3(d->qpos + qpos_root);
    if (gate_clearance.Holds(p_WB)) return;
    double clearance_m = std::numeric_limits<double>::infinity();
    for (const StaticGeom& w : world_colliders) {
      const double distance_m =
          PointGeomDistanceLowerBound(m->geom_type[w.id], m->geom_size + 3 * w.id,
                                      m->geom_rbound[w.id], w.p_W, w.R_W, p_WB);
      // MuJoCo reports a contact below the margin; the slack absorbs rounding.
      clearance_m = std::min(clearance_m, distance_m - (robot_reach_m + w.margin_m + 1e-6));
    }
    const bool reachable = clearance_m <= 0.0;
    gate_clearance.Set(p_WB, clearance_m);
    m->opt.disableflags =
        reachable ? model_disableflags : (model_disableflags | mjDSBL_CONTACT);
  }

  // Mass properties, arm geometry and mounts, read at the zero-tilt, level pose.
  void DescribeRobot() {
    mj_resetData(m, d);
    for (int k = 0; k < 4; ++k) d->qpos[qpos_root + 3 + k] = (k == 0) ? 1.0 : 0.0;
    mj_forward(m, d);
    const Eigen::Vector3d p_W_base = Vec3(d->xpos + 3 * base_body);
    const Eigen::Matrix3d R_W_base = Mat3(d->xmat + 9 * base_body);
    const Eigen::Vector3d p_W_com = Vec3(d->subtree_com + 3 * base_body);

    RigidBodyParams& rb = robot.rigid_body;
    rb.mass_kg = m->body_subtreemass[base_body];
    rb.gravity_mps2 = -m->opt.gravity[2];
    Eigen::Matrix3d inertia_W = Eigen::Matrix3d::Zero();
    for (int b = 0; b < m->nbody; ++b) {
      if (m->body_rootid[b] != base_body) continue;
      const Eigen::Matrix3d R_W_principal = Mat3(d->ximat + 9 * b);
      const Eigen::Vector3d r = Vec3(d->xipos + 3 * b) - p_W_com;
      const double mass = m->body_mass[b];
      // Parallel-axis theorem about the composite CoM.
      inertia_W += R_W_principal * Vec3(m->body_inertia + 3 * b).asDiagonal() *
                       R_W_principal.transpose() +
                   mass * (r.squaredNorm() * Eigen::Matrix3d::Identity() - r * r.transpose());
    }
    rb.inertia_B_kgm2 = R_W_base.transpose() * inertia_W * R_W_base;
    robot.p_B_CoM = R_W_base.transpose() * (p_W_com - p_W_base);

    AllocationParams& alloc = robot.allocation;
    for (int k = 0; k < kArmCount; ++k) {
      const int joint = Id(mjOBJ_JOINT, fmt::format("tilt_{}", k + 1), "joint");
      alloc.arms[k].p_CoM_hinge_B =
          R_W_base.transpose() * (Vec3(d->xanchor + 3 * joint) - p_W_com);
      alloc.arms[k].tilt_axis_B = (R_W_base.transpose() * Vec3(d->xaxis + 3 * joint)).normalized();
    }
    const int servo = tilt_servo_actuator[0];
    alloc.tilt_min_rad = m->actuator_ctrlrange[2 * servo];
    alloc.tilt_max_rad = m->actuator_ctrlrange[2 * servo + 1];
    const int thrust = thrust_actuator[0];
    alloc.rotor_min_thrust_N = m->actuator_ctrlrange[2 * thrust];
    alloc.rotor_max_thrust_N = m->actuator_ctrlrange[2 * thrust + 1];

    const int rate_id = mj_name2id(m, mjOBJ_NUMERIC, "tilt_servo_max_rate_radps");
    if (rate_id >= 0 && m->numeric_size[rate_id] >= 1) {
      robot.tilt_servo_max_rate_radps = m->numeric_data[m->numeric_adr[rate_id]];
    }

    robot.sites.clear();
    for (const char* name : kRequiredSites) {
      const int site = Id(mjOBJ_SITE, name, "site");
      MountSite mount;
      mount.name = name;
      mount.p_Bs = R_W_base.transpose() * (Vec3(d->site_xpos + 3 * site) - p_W_base);
      mount.q_Bs = Eigen::Quaterniond(R_W_base.transpose() * Mat3(d->site_xmat + 9 * site));
      mount.q_Bs.normalize();
      if (mount.q_Bs.w() < 0.0) mount.q_Bs.coeffs() *= -1.0;
      robot.sites.push_back(mount);
    }
  }

  TruthState ReadState() const {
    TruthState s;
    s.t_ns = step_count * timestep_ns;
    s.p_WB = Vec3(d->qpos + qpos_root);
    const mjtNum* q = d->qpos + qpos_root + 3;
    s.q_WB = Eigen::Quaterniond(q[0], q[1], q[2], q[3]).normalized();
    // MuJoCo's free joint: linear velocity in W, angular velocity in the body frame.
    s.v_WB_W = Vec3(d->qvel + qvel_root);
    s.omega_WB_B = Vec3(d->qvel + qvel_root + 3);
    for (int k = 0; k < kArmCount; ++k) s.tilt_rad[k] = d->qpos[tilt_qpos[k]];
    return s;
  }

  // ReadState at the current step, read once: the harness asks for it (Truth) before each
  // step, and Step starts from the same state.
  const TruthState& StateNow() const {
    if (state_now_step != step_count) {
      state_now = ReadState();
      state_now_step = step_count;
    }
    return state_now;
  }

  void CheckWarnings() {
    for (int w = 0; w < mjNWARNING; ++w) {
      if (d->warning[w].number == warning_count[w]) continue;
      warning_count[w] = d->warning[w].number;
      if (w == mjWARN_VGEOMFULL) continue;  // a rendering limit, not a physics fault
      static const char* const kWhat[mjNWARNING] = {
          "near-singular inertia", "contact buffer full", "constraint buffer full",
          "visual geom buffer full", "non-finite qpos", "non-finite qvel",
          "non-finite or huge qacc (MuJoCo would silently reset the simulation)",
          "non-finite ctrl"};
      throw core::SimulationError(fmt::format(
          "simulation failed at t = {:.3f} s: MuJoCo warning: {} ({})",
          core::TimeToSeconds((step_count - 1) * timestep_ns), kWhat[w], g_last_mujoco_warning));
    }
  }
};

World::World(const WorldOptions& options) : impl_(std::make_unique<Impl>()) {
  InstallMujocoHandlers();
  impl_->options = options;
  impl_->Load();
  impl_->IndexRobot();
  impl_->DescribeRobot();
  impl_->IndexContacts();
  Reset(Waypoint{Eigen::Vector3d(0.0, 0.0, 1.0), Eigen::Quaterniond::Identity()});
}

World::~World() = default;

const RobotDescription& World::robot() const { return impl_->robot; }
const WorldOptions& World::options() const { return impl_->options; }
const mjModel_* World::model() const { return impl_->Full(); }
const mjData_* World::data() const { return impl_->SyncedFull(); }
const mjModel_* World::physics_model() const { return impl_->m; }
const mjData_* World::physics_data() const { return impl_->d; }
core::Time World::time_ns() const { return impl_->step_count * impl_->timestep_ns; }
core::Time World::timestep_ns() const { return impl_->timestep_ns; }

void World::Reset(const Waypoint& pose) {
  Impl& s = *impl_;
  mj_resetData(s.m, s.d);
  s.step_count = 0;
  s.external_force_W.setZero();
  const Eigen::Quaterniond q = pose.q_WB.normalized();
  for (int k = 0; k < 3; ++k) s.d->qpos[s.qpos_root + k] = pose.p_WB(k);
  s.d->qpos[s.qpos_root + 3] = q.w();
  s.d->qpos[s.qpos_root + 4] = q.x();
  s.d->qpos[s.qpos_root + 5] = q.y();
  s.d->qpos[s.qpos_root + 6] = q.z();

  // Hover allocation at this attitude: gravity compensation about the CoM.
  const Allocator allocator(s.robot.allocation);
  const RigidBodyParams& rb = s.robot.rigid_body;
  const Wrench hover{q.toRotationMatrix().transpose() *
                         Eigen::Vector3d(0.0, 0.0, rb.mass_kg * rb.gravity_mps2),
                     Eigen::Vector3d::Zero()};
  const AllocationResult a = allocator.Allocate(hover, {});
  for (int k = 0; k < kArmCount; ++k) {
    s.d->qpos[s.tilt_qpos[k]] = a.command.tilt_rad[k];
    s.tilt_target_rad[k] = a.command.tilt_rad[k];
    s.d->ctrl[s.tilt_servo_actuator[k]] = a.command.tilt_rad[k];
    const int act = s.thrust_actuator[k];
    s.d->ctrl[act] = a.command.rotor_thrust_N[k];
    // Filter actuators: spin the motors up to the hover thrust already. In MuJoCo 2.2
    // the activations belong to the last na actuators, in order.
    const int act_index = act - (s.m->nu - s.m->na);
    if (s.m->actuator_dyntype[act] != mjDYN_NONE && act_index >= 0) {
      s.d->act[act_index] = a.command.rotor_thrust_N[k];
    }
  }
  s.GateContacts();
  mj_forward(s.m, s.d);
  s.qpos_kinematics.assign(s.d->qpos, s.d->qpos + s.m->nq);
  s.closest_step = -1;
  s.full_synced_step = -1;
  s.gate_clearance.Forget();
  s.structure_clearance.Forget();
  for (int w = 0; w < mjNWARNING; ++w) s.warning_count[w] = s.d->warning[w].number;
  s.state_now_step = -1;  // qpos was just set
  s.last_step_truth = s.StateNow();
}

void World::SetCommand(const ActuatorCommand& command) {
  Impl& s = *impl_;
  for (int k = 0; k < kArmCount; ++k) {
    s.tilt_target_rad[k] = command.tilt_rad[k];
    s.d->ctrl[s.thrust_actuator[k]] = command.rotor_thrust_N[k];
  }
}

void World::SetExternalForce_W(const Eigen::Vector3d& force_W) {
  impl_->external_force_W = force_W;
}

const TruthState& World::Step() {
  Impl& s = *impl_;
  // Servo set-points move towards their targets no faster than the servo can turn.
  const double max_step_rad = s.robot.tilt_servo_max_rate_radps * s.m->opt.timestep;
  for (int k = 0; k < kArmCount; ++k) {
    double& setpoint = s.d->ctrl[s.tilt_servo_actuator[k]];
    setpoint += std::clamp(s.tilt_target_rad[k] - setpoint, -max_step_rad, max_step_rad);
  }
  TruthState truth = s.StateNow();
  s.ApplyExternalForce(truth.q_WB);
  s.GateContacts();
  std::copy(s.d->qpos, s.d->qpos + s.m->nq, s.qpos_kinematics.begin());
  mj_step(s.m, s.d);
  ++s.step_count;
  s.CheckWarnings();
  // With the Euler integrator, qacc is the acceleration at the pre-step state.
  truth.a_WB_W = Vec3(s.d->qacc + s.qvel_root);
  truth.alpha_WB_B = Vec3(s.d->qacc + s.qvel_root + 3);
  if (!truth.p_WB.allFinite() || !truth.a_WB_W.allFinite()) {
    throw core::SimulationError(
        fmt::format("simulation failed at t = {:.3f} s: non-finite robot state", s.d->time));
  }
  s.last_step_truth = truth;
  return s.last_step_truth;
}

TruthState World::Truth() const {
  TruthState s = impl_->StateNow();
  s.a_WB_W = impl_->last_step_truth.a_WB_W;
  s.alpha_WB_B = impl_->last_step_truth.alpha_WB_B;
  return s;
}

const std::vector<Contact>& World::Contacts() const {
  const Impl& s = *impl_;
  std::vector<Contact>& contacts = impl_->contacts_buffer;
  contacts.clear();
  for (int i = 0; i < s.d->ncon; ++i) {
    const mjContact& c = s.d->contact[i];
    if (c.dist >= 0.0) continue;
    int robot_geom = c.geom1;
    int other = c.geom2;
    if (!s.is_robot_geom[robot_geom]) std::swap(robot_geom, other);
    if (!s.is_robot_geom[robot_geom] || s.is_robot_geom[other]) continue;
    if (s.is_foot_geom[robot_geom] && s.m->geom_group[other] == kGroundGeomGroup) continue;
    contacts.push_back({s.ToFull(robot_geom), s.ToFull(other), c.dist});
  }
  return contacts;
}

std::optional<Proximity> World::ClosestStructure() const {
  // Proxy-structure pairs in the order of a cheap lower bound on their distance, measured
  // exactly until the bound exceeds the best so far: in open space no pair is measured at
  // all, near a wall one or two.
  Impl& s = *impl_;
  if (s.closest_step == s.step_count) return s.closest;
  s.closest_step = s.step_count;
  s.closest.reset();
  const mjModel* m = s.m;
  const mjData* d = s.d;
  const double horizon_m = s.options.distance_horizon_m;
  const Eigen::Vector3d p_WB = Vec3(d->xpos + 3 * s.base_body);
  // As in GateContacts: nothing within the horizon while B stays within the clearance.
  if (s.static_structure && s.structure_clearance.Holds(p_WB)) {
    return s.closest;
  }
  double clearance_m = std::numeric_limits<double>::infinity();
  s.distance_candidates.clear();
  for (const int g : s.structure_geoms) {
    const Eigen::Vector3d p_W_geom = Vec3(d->geom_xpos + 3 * g);
    const Eigen::Matrix3d R_W_geom = Mat3(d->geom_xmat + 9 * g);
    const auto lower_bound_m = [&](const Eigen::Vector3d& p_W) {
      return PointGeomDistanceLowerBound(m->geom_type[g], m->geom_size + 3 * g,
                                         m->geom_rbound[g], p_W_geom, R_W_geom, p_W);
    };
    const double beyond_m = lower_bound_m(p_WB) - s.robot_reach_m - horizon_m;
    clearance_m = std::min(clearance_m, beyond_m);
    if (beyond_m >= 0.0) continue;
    for (const int proxy : s.structure_partners[g]) {
      const double bound_m =
          lower_bound_m(Vec3(d->geom_xpos + 3 * proxy)) - m->geom_rbound[proxy];
      if (bound_m < horizon_m) s.distance_candidates.push_back({bound_m, proxy, g});
    }
  }
  s.structure_clearance.Set(p_WB, clearance_m);
  std::sort(s.distance_candidates.begin(), s.distance_candidates.end(),
            [](const Impl::DistanceCandidate& a, const Impl::DistanceCandidate& b) {
              return std::tie(a.lower_bound_m, a.proxy, a.geom) <
                     std::tie(b.lower_bound_m, b.proxy, b.geom);
            });
  double best_m = horizon_m;
  for (const Impl::DistanceCandidate& c : s.distance_candidates) {
    // Apart pairs are bounded below by their bound; touching ones (bound <= 0) are not:
    // MuJoCo's penetration depth may go deeper, so each of those is measured.
    if (c.lower_bound_m >= best_m && c.lower_bound_m > 0.0) break;
    const double distance_m = s.PairDistance(c.proxy, c.geom, c.lower_bound_m);
    if (distance_m < best_m) {
      best_m = distance_m;
      s.closest = Proximity{distance_m, s.ToFull(c.proxy), s.ToFull(c.geom)};
    }
  }
  return s.closest;
}

std::string World::GeomName(int geom_id) const {
  const char* name = mj_id2name(impl_->Full(), mjOBJ_GEOM, geom_id);
  return name != nullptr ? std::string(name) : fmt::format("geom{}", geom_id);
}

std::optional<double> World::RayDistance(const Eigen::Vector3d& origin_W,
                                         const Eigen::Vector3d& direction_W) const {
  const Impl& s = *impl_;
  const Eigen::Vector3d dir = direction_W.normalized();
  mjtByte groups[mjNGROUP] = {};
  groups[kStructureGeomGroup] = 1;
  groups[kGroundGeomGroup] = 1;
  int geom_id = -1;
  const mjtNum distance = mj_ray(s.m, s.d, origin_W.data(), dir.data(), groups, 1, -1, &geom_id);
  if (distance < 0.0) return std::nullopt;
  return distance;
}

namespace {

// Outward surface normal of a primitive geom at a point on its surface, in W.
Eigen::Vector3d GeomSurfaceNormal_W(const mjModel* m, const mjData* d, int g,
                                    const Eigen::Vector3d& point_W,
                                    const Eigen::Vector3d& ray_dir_W) {
  const Eigen::Matrix3d R = Mat3(d->geom_xmat + 9 * g);
  const Eigen::Vector3d p = R.transpose() * (point_W - Vec3(d->geom_xpos + 3 * g));
  const mjtNum* size = m->geom_size + 3 * g;
  Eigen::Vector3d n_local = Eigen::Vector3d::Zero();
  switch (m->geom_type[g]) {
    case mjGEOM_PLANE:
      n_local = Eigen::Vector3d::UnitZ();
      break;
    case mjGEOM_SPHERE:
    case mjGEOM_ELLIPSOID:
      n_local = p;
      break;
    case mjGEOM_BOX: {
      // The face whose normalised coordinate is largest.
      int axis = 0;
      double best = -1.0;
      for (int k = 0; k < 3; ++k) {
        const double r = std::abs(p(k)) / size[k];
        if (r > best) {
          best = r;
          axis = k;
        }
      }
      n_local(axis) = p(axis) >= 0.0 ? 1.0 : -1.0;
      break;
    }
    case mjGEOM_CYLINDER:
      if (std::abs(std::abs(p.z()) - size[1]) < 1e-6 * (1.0 + size[1]) ||
          std::hypot(p.x(), p.y()) < size[0] * (1.0 - 1e-6)) {
        n_local = Eigen::Vector3d(0.0, 0.0, p.z() >= 0.0 ? 1.0 : -1.0);
      } else {
        n_local = Eigen::Vector3d(p.x(), p.y(), 0.0);
      }
      break;
    case mjGEOM_CAPSULE:
      n_local = p - Eigen::Vector3d(0.0, 0.0, std::clamp(p.z(), -size[1], size[1]));
      break;
    default:  // meshes, height fields: facing the ray is the best we know cheaply
      return -ray_dir_W.normalized();
  }
  Eigen::Vector3d n = (R * n_local).normalized();
  if (n.dot(ray_dir_W) > 0.0) n = -n;  // face the ray origin (e.g. hits on a plane's back)
  return n;
}

// The geom groups of a RayGroups mask, as mj_ray takes them.
std::array<mjtByte, mjNGROUP> GroupMask(uint32_t groups) {
  std::array<mjtByte, mjNGROUP> mask{};
  for (int g = 0; g < mjNGROUP; ++g) mask[g] = (groups >> g) & 1u;
  return mask;
}

// mj_ray's choice of the geoms a ray may meet (engine_ray.c, ray_eliminate), for
// mj_ray(..., flg_static = 1, bodyexclude = -1): visible, and in one of the groups.
bool RayMayMeet(const mjModel* m, int geom, const std::array<mjtByte, mjNGROUP>& mask) {
  const int material = m->geom_matid[geom];
  if (material < 0 && m->geom_rgba[4 * geom + 3] == 0) return false;
  if (material >= 0 && m->mat_rgba[4 * material + 3] == 0) return false;
  return mask[std::clamp(m->geom_group[geom], 0, mjNGROUP - 1)] != 0;
}

// Distance along the ray to `geom` by MuJoCo's own intersection (mj_ray's dispatch), -1
// when it misses.
mjtNum RayToGeom(const mjModel* m, const mjData* d, int geom, const mjtNum* origin_W,
                 const mjtNum* unit_W) {
  switch (m->geom_type[geom]) {
    case mjGEOM_MESH:
      return mj_rayMesh(m, d, geom, origin_W, unit_W);
    case mjGEOM_HFIELD:
      return mj_rayHfield(m, d, geom, origin_W, unit_W);
    default:
      return mju_rayGeom(d->geom_xpos + 3 * geom, d->geom_xmat + 9 * geom,
                         m->geom_size + 3 * geom, origin_W, unit_W, m->geom_type[geom]);
  }
}

// The bounds are grown (and the lower bounds shrunk) by far more than the rounding of
// MuJoCo's own intersections, so that they never rule out a hit MuJoCo would report.
constexpr double kFanRelativeSlack = 1e-9;
constexpr double kFanAbsoluteSlackM = 1e-9;

// Whether the ray o + t u, t >= 0, can meet the box |x_k| <= h_k (in the box's frame): the
// slab test (Kay & Kajiya 1986).
bool RayMeetsBox(const Eigen::Vector3d& origin_G, const Eigen::Vector3d& unit_G,
                 const Eigen::Vector3d& half_size_m) {
  double enter = 0.0;
  double leave = std::numeric_limits<double>::infinity();
  for (int k = 0; k < 3; ++k) {
    if (unit_G[k] == 0.0) {
      if (std::abs(origin_G[k]) > half_size_m[k]) return false;
      continue;
    }
    const double inverse = 1.0 / unit_G[k];
    double near = (-half_size_m[k] - origin_G[k]) * inverse;
    double far = (half_size_m[k] - origin_G[k]) * inverse;
    if (near > far) std::swap(near, far);
    enter = std::max(enter, near);
    leave = std::min(leave, far);
    if (enter > leave) return false;
  }
  return true;
}

}  // namespace

// How a fan rules a geom out for most rays: a box by its own faces (walls and slabs, whose
// bounding spheres are as large as the room), the other solids by their bounding sphere
// (geom_rbound); planes, height fields and meshes are tested by every ray.
RayFan::Bound RayFan::BoundOf(int geom_type) {
  switch (geom_type) {
    case mjGEOM_BOX:
      return Bound::kBox;
    case mjGEOM_SPHERE:
    case mjGEOM_CAPSULE:
    case mjGEOM_ELLIPSOID:
    case mjGEOM_CYLINDER:
      return Bound::kSphere;
    default:
      return Bound::kNone;
  }
}

RayHit World::Impl::HitOn(const mjModel* model, const mjData* data, bool full, int geom,
                          double distance_m, const Eigen::Vector3d& origin_W,
                          const Eigen::Vector3d& unit_W) const {
  RayHit hit;
  hit.distance_m = distance_m;
  hit.geom = full ? geom : ToFull(geom);
  hit.point_W = origin_W + distance_m * unit_W;
  hit.normal_W = GeomSurfaceNormal_W(model, data, geom, hit.point_W, unit_W);
  const int material = model->geom_matid[geom];
  hit.textured = material >= 0 && model->mat_texid[material] >= 0;
  hit.group = model->geom_group[geom];
  return hit;
}

std::optional<RayHit> World::CastRay(const Eigen::Vector3d& origin_W,
                                     const Eigen::Vector3d& direction_W,
                                     uint32_t groups) const {
  Impl& s = *impl_;
  // Groups only the complete scene holds (the robot's visual shapes) need its kinematics;
  // the rest is cheaper in the physics model (fewer geoms to test).
  const bool full = (groups & s.visual_only_groups) != 0;
  const mjModel* m = full ? s.Full() : s.m;
  const mjData* d = full ? s.SyncedFull() : s.d;
  const Eigen::Vector3d dir = direction_W.normalized();
  const std::array<mjtByte, mjNGROUP> group_mask = GroupMask(groups);
  int geom = -1;
  const mjtNum distance =
      mj_ray(m, d, origin_W.data(), dir.data(), group_mask.data(), 1, -1, &geom);
  if (distance < 0.0 || geom < 0) return std::nullopt;
  return s.HitOn(m, d, full, geom, distance, origin_W, dir);
}

RayFan World::RaysFrom(const Eigen::Vector3d& origin_W, uint32_t groups) const {
  Impl& s = *impl_;
  RayFan fan;
  fan.world_ = this;
  fan.full_ = (groups & s.visual_only_groups) != 0;
  fan.origin_W_ = origin_W;
  const mjModel* m = fan.full_ ? s.Full() : s.m;
  const mjData* d = fan.full_ ? s.SyncedFull() : s.d;
  fan.model_ = m;
  fan.data_ = d;
  const std::array<mjtByte, mjNGROUP> group_mask = GroupMask(groups);
  for (int g = 0; g < m->ngeom; ++g) {
    if (!RayMayMeet(m, g, group_mask)) continue;
    RayFan::Candidate& c = fan.candidates_.emplace_back();
    c.geom = g;
    c.bound = RayFan::BoundOf(m->geom_type[g]);
    const Eigen::Vector3d p_WG = Vec3(d->geom_xpos + 3 * g);
    double distance_m = 0.0;  // from the origin to the geom's bound
    if (c.bound == RayFan::Bound::kBox) {
      c.R_WG = Mat3(d->geom_xmat + 9 * g);
      c.origin_G = c.R_WG.transpose() * (origin_W - p_WG);
      const Eigen::Vector3d half_size_m = Vec3(m->geom_size + 3 * g);
      c.half_size_m =
          half_size_m * (1.0 + kFanRelativeSlack) + Eigen::Vector3d::Constant(kFanAbsoluteSlackM);
      distance_m = (c.origin_G.cwiseAbs() - half_size_m).cwiseMax(0.0).norm();
    } else if (c.bound == RayFan::Bound::kSphere) {
      c.center_from_origin_W = p_WG - origin_W;
      c.squared_center_distance_m2 = c.center_from_origin_W.squaredNorm();
      const double radius_m = m->geom_rbound[g];
      c.squared_radius_m2 = radius_m * radius_m;
      distance_m = std::max(0.0, std::sqrt(c.squared_center_distance_m2) - radius_m);
    }
    c.lower_bound_m =
        std::max(0.0, distance_m * (1.0 - kFanRelativeSlack) - kFanAbsoluteSlackM);
  }
  std::sort(fan.candidates_.begin(), fan.candidates_.end(),
            [](const RayFan::Candidate& a, const RayFan::Candidate& b) {
              return a.lower_bound_m != b.lower_bound_m ? a.lower_bound_m < b.lower_bound_m
                                                        : a.geom < b.geom;
            });
  return fan;
}

std::optional<RayHit> RayFan::Cast(const Eigen::Vector3d& direction_W) const {
  const Eigen::Vector3d dir = direction_W.normalized();
  double best_m = -1.0;
  int best_geom = -1;
  for (const Candidate& c : candidates_) {
    if (best_m >= 0.0 && c.lower_bound_m > best_m) break;  // sorted: no nearer hit follows
    if (c.bound == Bound::kBox) {
      if (!RayMeetsBox(c.origin_G, c.R_WG.transpose() * dir, c.half_size_m)) continue;
    } else if (c.bound == Bound::kSphere) {
      // It passes wide of the sphere, or the sphere lies behind an origin outside it.
      const double along_m = c.center_from_origin_W.dot(dir);
      const double slack_m2 = 2.0 * kFanRelativeSlack * c.squared_radius_m2 +
                              1e-12 * (1.0 + c.squared_center_distance_m2);
      const bool outside = c.squared_center_distance_m2 > c.squared_radius_m2 + slack_m2;
      if (outside && along_m < 0.0) continue;
      if (c.squared_center_distance_m2 - along_m * along_m > c.squared_radius_m2 + slack_m2) {
        continue;
      }
    }
    const double distance_m = RayToGeom(model_, data_, c.geom, origin_W_.data(), dir.data());
    // mj_ray keeps the first geom (lowest id) of equal distances.
    if (distance_m >= 0.0 &&
        (best_m < 0.0 || distance_m < best_m || (distance_m == best_m && c.geom < best_geom))) {
      best_m = distance_m;
      best_geom = c.geom;
    }
  }
  if (best_geom < 0) return std::nullopt;
  return world_->impl_->HitOn(model_, data_, full_, best_geom, best_m, origin_W_, dir);
}

std::array<double, kArmCount * kRotorsPerArm> World::RotorThrusts_N() const {
  const Impl& s = *impl_;
  std::array<double, kArmCount * kRotorsPerArm> thrust{};
  for (int k = 0; k < kArmCount; ++k) {
    // The pair's actuator force is the thrust of each rotor (its gear doubles it).
    for (int r = 0; r < kRotorsPerArm; ++r) {
      thrust[kRotorsPerArm * k + r] = s.d->actuator_force[s.thrust_actuator[k]];
    }
  }
  return thrust;
}

Eigen::Isometry3d World::SitePose_W(const std::string& site) const {
  Impl& s = *impl_;
  const mjModel* m = s.m;
  const mjData* d = s.d;
  if (mj_name2id(m, mjOBJ_SITE, site.c_str()) < 0 && s.m_full != nullptr) {
    m = s.m_full;  // a site on a visual-only body
    d = s.SyncedFull();
  }
  const int id = mj_name2id(m, mjOBJ_SITE, site.c_str());
  if (id < 0) s.Id(mjOBJ_SITE, site, "site");  // throws, naming the site
  Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
  T.linear() = Mat3(d->site_xmat + 9 * id);
  T.translation() = Vec3(d->site_xpos + 3 * id);
  return T;
}

}  // namespace tofu::sim
