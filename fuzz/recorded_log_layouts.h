#pragma once
// The fixed files around the fuzz input of the recorded-log targets (fuzz_run_directory,
// fuzz_euroc_imu, fuzz_euroc_groundtruth): small valid files of both layouts that
// replay::ReadRecordedLog reads (recorded_log.h), so that a rejection comes from the
// input. The targets write them once per process into their scratch directory;
// tests/fuzz_regression_test.cc replays the seeds and findings in the same layouts.

#include <filesystem>
#include <string_view>

#include "fuzz/fuzz_support.h"

namespace tofu::fuzz {

// ---- (a) a tofu run directory: sensors/imu.csv, sensors/fuzz.csv (the input),
// calibration.yaml, groundtruth.csv ----

inline constexpr std::string_view kRunImuCsv =
    "#timestamp [ns],w_RS_S_x [rad s^-1],w_RS_S_y [rad s^-1],w_RS_S_z [rad s^-1],"
    "a_RS_S_x [m s^-2],a_RS_S_y [m s^-2],a_RS_S_z [m s^-2],arrival [ns],err_w_x [rad s^-1],"
    "conditions,faults\n"
    "2500000,-0.013158389,-0.002398773,-0.001363355,0.3031958,-0.0145781,-9.8235665,2500000,"
    "0.001,,\n"
    "5000000,0.000061543,-0.000239058,-0.020141173,-0.0262912,-0.4088756,-9.7241422,5000000,"
    "0.002,,\n";

inline constexpr std::string_view kRunCalibrationYaml =
    "# tofu calibration (fuzz fixture)\n"
    "sensors:\n"
    "  imu:\n"
    "    type: imu\n"
    "    T_B_s: {p_m: [0.03, -0.02, 0.04], q_wxyz: [0, 1, 0, 0]}\n"
    "    true_T_B_s: {p_m: [0.03, -0.02, 0.04], q_wxyz: [0, 1, 0, 0]}\n"
    "    options:\n"
    "      gyro_noise_density_radps_per_sqrthz: 0.00016968\n"
    "      gyro_random_walk_radps2_per_sqrthz: 1.9393e-05\n"
    "      accel_noise_density_mps2_per_sqrthz: 0.002\n"
    "      accel_random_walk_mps3_per_sqrthz: 0.003\n"
    "  fuzz:\n"
    "    type: vio\n"
    "    T_B_s: {p_m: [0.2, 0, -0.12], q_wxyz: [0.405579567, -0.57922812, 0.57922812, "
    "-0.405579567]}\n"
    "    true_T_WS: {p_m: [0.2, 0, 1.38], q_wxyz: [1, 0, 0, 0]}\n"
    "    options: {position_noise_m: 0.002, rotation_noise_deg: 0.0573, "
    "position_random_walk_m_per_sqrtm: 0.005}\n";

inline constexpr std::string_view kRunGroundTruthCsv =
    "#timestamp [ns],p_WB_x [m],p_WB_y [m],p_WB_z [m],q_WB_w [],q_WB_x [],q_WB_y [],q_WB_z []\n"
    "0,0.000000,0.000000,1.500000,1.000000000,0.000000000,0.000000000,0.000000000\n"
    "5000000,-0.000000,0.000000,1.500000,1.000000000,0.000000000,0.000000000,0.000000000\n";

/// Writes the run directory's fixed files under `dir`; the input goes to
/// dir/sensors/fuzz.csv.
inline void WriteRunDirectory(const std::filesystem::path& dir) {
  WriteFile(dir / "sensors" / "imu.csv", kRunImuCsv);
  WriteFile(dir / "calibration.yaml", kRunCalibrationYaml);
  WriteFile(dir / "groundtruth.csv", kRunGroundTruthCsv);
}

// ---- (b) an EuRoC-style log: mav0/imu0/data.csv, pose.tum,
// mav0/state_groundtruth_estimate0/data.csv, calibration.yaml ----

inline constexpr std::string_view kEurocImuCsv =
    "#timestamp [ns],w_RS_S_x [rad s^-1],w_RS_S_y [rad s^-1],w_RS_S_z [rad s^-1],"
    "a_RS_S_x [m s^-2],a_RS_S_y [m s^-2],a_RS_S_z [m s^-2]\n"
    "1403715523912140000,-0.0006981317,0.0195476876,0.0767944871,9.218251,0.3023717083,"
    "-3.1544724167\n"
    "1403715523917140000,-0.0006981317,0.020943951,0.0726056969,9.3163175,0.2941995,"
    "-3.2525389167\n";

inline constexpr std::string_view kEurocPoseTum =
    "1.403715529112143517e+09 -6.151e-02 4.838e-02 1.7712e-01 8.1321e-01 -2.73e-02 5.8066e-01 "
    "2.779e-02\n"
    "1.403715529212142944e+09 7.722e-02 6.744e-02 2.2247e-01 8.2033e-01 -2.737e-02 5.7064e-01 "
    "2.598e-02\n";

inline constexpr std::string_view kEurocGroundTruthCsv =
    "#timestamp, p_RS_R_x [m], p_RS_R_y [m], p_RS_R_z [m], q_RS_w [], q_RS_x [], q_RS_y [], "
    "q_RS_z [], v_RS_R_x [m s^-1]\n"
    "1403715524907143168,0.515356,1.996773,0.971104,0.161996,0.789985,-0.205376,0.554528,"
    "-0.002276\n"
    "1403715524912143104,0.515342,1.996723,0.971077,0.161904,0.790015,-0.205283,0.554546,"
    "-0.003425\n";

inline constexpr std::string_view kEurocCalibrationYaml =
    "sensors:\n"
    "  pose:\n"
    "    T_B_s: {p_m: [0, 0, 0], q_wxyz: [1, 0, 0, 0]}\n"
    "    options: {position_noise_m: 0.01}\n";

inline const std::filesystem::path kEurocImu = std::filesystem::path("mav0") / "imu0" / "data.csv";
inline const std::filesystem::path kEurocGroundTruth =
    std::filesystem::path("mav0") / "state_groundtruth_estimate0" / "data.csv";

/// Writes an EuRoC-style log under `dir` with every fixed file but `input` (kEurocImu or
/// kEurocGroundTruth), which the caller writes.
inline void WriteEurocDirectory(const std::filesystem::path& dir,
                                const std::filesystem::path& input) {
  if (input != kEurocImu) WriteFile(dir / kEurocImu, kEurocImuCsv);
  if (input != kEurocGroundTruth) WriteFile(dir / kEurocGroundTruth, kEurocGroundTruthCsv);
  WriteFile(dir / "pose.tum", kEurocPoseTum);
  WriteFile(dir / "calibration.yaml", kEurocCalibrationYaml);
}

}  // namespace tofu::fuzz
