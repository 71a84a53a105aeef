#include "harness/run_directory.h"

#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <iterator>
#include <stdexcept>

#include <fmt/format.h>

namespace tofu::harness {
namespace {

namespace fs = std::filesystem;

void WriteText(const fs::path& path, const std::string& text) {
  std::ofstream out(path, std::ios::binary);
  out.write(text.data(), static_cast<std::streamsize>(text.size()));
  out.close();
  if (!out) throw std::runtime_error("cannot write " + path.string());
}

// "1.234567890" from integer nanoseconds: exact, no float rounding in time stamps.
std::string SecondsText(core::Time t_ns) {
  const char* sign = t_ns < 0 ? "-" : "";
  const core::Time a = t_ns < 0 ? -t_ns : t_ns;
  return fmt::format("{}{}.{:09d}", sign, a / core::kNanosecondsPerSecond,
                     a % core::kNanosecondsPerSecond);
}

std::string GroundTruthCsv(const RunRecord& record) {
  fmt::memory_buffer out;
  fmt::format_to(std::back_inserter(out),
                 "#timestamp [ns],p_WB_x [m],p_WB_y [m],p_WB_z [m],"
                 "q_WB_w [],q_WB_x [],q_WB_y [],q_WB_z [],"
                 "v_WB_W_x [m/s],v_WB_W_y [m/s],v_WB_W_z [m/s],"
                 "omega_WB_B_x [rad/s],omega_WB_B_y [rad/s],omega_WB_B_z [rad/s],"
                 "a_WB_W_x [m/s^2],a_WB_W_y [m/s^2],a_WB_W_z [m/s^2]\n");
  for (const sim::TruthState& s : record.groundtruth) {
    Eigen::Quaterniond q = s.q_WB;
    if (q.w() < 0.0) q.coeffs() *= -1.0;
    fmt::format_to(std::back_inserter(out),
                   "{},{:.6f},{:.6f},{:.6f},{:.9f},{:.9f},{:.9f},{:.9f},{:.6f},{:.6f},{:.6f},"
                   "{:.6f},{:.6f},{:.6f},{:.5f},{:.5f},{:.5f}\n",
                   s.t_ns, s.p_WB.x(), s.p_WB.y(), s.p_WB.z(), q.w(), q.x(), q.y(), q.z(),
                   s.v_WB_W.x(), s.v_WB_W.y(), s.v_WB_W.z(), s.omega_WB_B.x(),
                   s.omega_WB_B.y(), s.omega_WB_B.z(), s.a_WB_W.x(), s.a_WB_W.y(),
                   s.a_WB_W.z());
  }
  return fmt::to_string(out);
}

// TUM trajectory format (what evo reads): "t x y z qx qy qz qw", t in seconds.
std::string GroundTruthTum(const RunRecord& record) {
  fmt::memory_buffer out;
  for (const sim::TruthState& s : record.groundtruth) {
    Eigen::Quaterniond q = s.q_WB;
    if (q.w() < 0.0) q.coeffs() *= -1.0;
    fmt::format_to(std::back_inserter(out), "{} {:.6f} {:.6f} {:.6f} {:.9f} {:.9f} {:.9f} {:.9f}\n",
                   SecondsText(s.t_ns), s.p_WB.x(), s.p_WB.y(), s.p_WB.z(), q.x(), q.y(), q.z(),
                   q.w());
  }
  return fmt::to_string(out);
}

std::string TrackingCsv(const RunRecord& record) {
  fmt::memory_buffer out;
  fmt::format_to(std::back_inserter(out),
                 "#timestamp [ns],p_ref_x [m],p_ref_y [m],p_ref_z [m],"
                 "q_ref_w [],q_ref_x [],q_ref_y [],q_ref_z [],"
                 "v_ref_x [m/s],v_ref_y [m/s],v_ref_z [m/s],"
                 "position_error [m],attitude_error [deg]\n");
  for (const TrackingSample& s : record.tracking) {
    Eigen::Quaterniond q = s.reference.q_WB;
    if (q.w() < 0.0) q.coeffs() *= -1.0;
    const auto& r = s.reference;
    fmt::format_to(std::back_inserter(out),
                   "{},{:.6f},{:.6f},{:.6f},{:.9f},{:.9f},{:.9f},{:.9f},{:.6f},{:.6f},{:.6f},"
                   "{:.7f},{:.5f}\n",
                   s.t_ns, r.p_WB.x(), r.p_WB.y(), r.p_WB.z(), q.w(), q.x(), q.y(), q.z(),
                   r.v_WB_W.x(), r.v_WB_W.y(), r.v_WB_W.z(), s.position_error_m,
                   s.attitude_error_rad * 180.0 / 3.14159265358979323846);
  }
  return fmt::to_string(out);
}

// Mounts and mass properties as the simulator built them: what a calibration of the
// real robot would give the estimator.
std::string CalibrationYaml(const RunRecord& record) {
  const sim::RobotDescription& robot = record.robot;
  std::string out = "# Robot calibration (ground truth), frames per DESIGN.md: T_BS = pose of\n"
                    "# mount frame S in body frame B; quaternions [w, x, y, z].\n";
  out += fmt::format("robot: {}\nmass_kg: {:.6f}\n", record.scenario.robot,
                     robot.rigid_body.mass_kg);
  const Eigen::Matrix3d& J = robot.rigid_body.inertia_B_kgm2;
  out += fmt::format(
      "inertia_B_kgm2: [[{:.6f}, {:.6f}, {:.6f}], [{:.6f}, {:.6f}, {:.6f}], [{:.6f}, {:.6f}, "
      "{:.6f}]]\n",
      J(0, 0), J(0, 1), J(0, 2), J(1, 0), J(1, 1), J(1, 2), J(2, 0), J(2, 1), J(2, 2));
  out += fmt::format("p_B_CoM_m: [{:.6f}, {:.6f}, {:.6f}]\nmounts:\n", robot.p_B_CoM.x(),
                     robot.p_B_CoM.y(), robot.p_B_CoM.z());
  for (const sim::MountSite& site : robot.sites) {
    out += fmt::format(
        "  {}:\n    p_B_m: [{:.6f}, {:.6f}, {:.6f}]\n    q_B_wxyz: [{:.9f}, {:.9f}, {:.9f}, "
        "{:.9f}]\n",
        site.name, site.p_B_s.x(), site.p_B_s.y(), site.p_B_s.z(), site.q_B_s.w(),
        site.q_B_s.x(), site.q_B_s.y(), site.q_B_s.z());
  }
  return out;
}

std::string TimingJson(const RunRecord& record) {
  const double simulated_s = record.scenario.physics.rate_hz > 0.0
                                 ? static_cast<double>(record.physics_steps) /
                                       record.scenario.physics.rate_hz
                                 : 0.0;
  nlohmann::json j = {
      {"wall_time_s", record.wall_time_s},
      {"simulated_s", simulated_s},
      {"real_time_factor", record.wall_time_s > 0.0 ? simulated_s / record.wall_time_s : 0.0},
      {"physics_steps_per_s",
       record.wall_time_s > 0.0 ? static_cast<double>(record.physics_steps) / record.wall_time_s
                                : 0.0},
      {"note", "wall-clock figures: the only file of the run that differs between two runs"}};
  return j.dump(2) + "\n";
}

}  // namespace

void WriteRunDirectory(const RunRecord& record, const Evaluation& evaluation,
                       const std::string& out_dir) {
  const fs::path out = fs::absolute(out_dir).lexically_normal();
  const fs::path parent = out.parent_path();
  fs::create_directories(parent);
  const std::string suffix = fmt::format(".tmp-{}", ::getpid());
  const fs::path staging = parent / (out.filename().string() + suffix);
  fs::remove_all(staging);
  try {
    fs::create_directories(staging);
    WriteText(staging / "scenario.yaml", ResolvedScenarioYaml(record.scenario));
    WriteText(staging / "groundtruth.csv", GroundTruthCsv(record));
    WriteText(staging / "groundtruth.tum", GroundTruthTum(record));
    WriteText(staging / "tracking.csv", TrackingCsv(record));
    WriteText(staging / "calibration.yaml", CalibrationYaml(record));
    WriteText(staging / "summary.json", evaluation.summary.dump(2) + "\n");
    WriteText(staging / "timing.json", TimingJson(record));
    // Replace atomically from a reader's point of view: old aside, new in, old gone.
    const fs::path old = parent / (out.filename().string() + fmt::format(".old-{}", ::getpid()));
    if (fs::exists(out)) fs::rename(out, old);
    fs::rename(staging, out);
    fs::remove_all(old);
  } catch (...) {
    std::error_code ignored;
    fs::remove_all(staging, ignored);
    throw;
  }
}

}  // namespace tofu::harness
