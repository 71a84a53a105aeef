#pragma once
// Measurement types: what sensors report and estimators consume. Shared vocabulary of
// sim/ (which produces them) and estimator/ (which consumes them); neither knows the other.
// Frames (DESIGN.md): each sensor has its reference frame S (its odometry, station or ENU
// frame) and its mount frame s on the robot; I is the IMU frame.

#include <cstdint>
#include <string>
#include <string_view>
#include <variant>

#include <Eigen/Core>
#include <Eigen/Geometry>

#include "core/time.h"

namespace tofu::core {

/// IMU: specific force f_I = R_WI^T (a_WI - g_W) and angular rate omega_WI_I, in I.
struct ImuMeasurement {
  Eigen::Vector3d acc_I_mps2 = Eigen::Vector3d::Zero();
  Eigen::Vector3d gyro_I_radps = Eigen::Vector3d::Zero();
};

/// Pose of the mount frame s in the sensor's reference frame S, with the sensor's
/// reported covariance, and the body twist of s where the sensor reports one.
struct PoseMeasurement {
  Eigen::Vector3d p_Ss = Eigen::Vector3d::Zero();
  Eigen::Quaterniond q_Ss = Eigen::Quaterniond::Identity();
  /// Covariance of [delta_theta; delta_p] (rad, m), delta_theta a right perturbation
  /// R_Ss = R_hat Exp(delta_theta), delta_p in S.
  Eigen::Matrix<double, 6, 6> covariance = Eigen::Matrix<double, 6, 6>::Identity();
  bool has_twist = false;
  Eigen::Vector3d v_s_s_mps = Eigen::Vector3d::Zero();         ///< linear velocity of s, in s
  Eigen::Vector3d omega_s_s_radps = Eigen::Vector3d::Zero();   ///< angular velocity of s, in s
  /// Covariance of [v; omega] when has_twist.
  Eigen::Matrix<double, 6, 6> twist_covariance = Eigen::Matrix<double, 6, 6>::Identity();
};

/// Position of the mount point s in the sensor's reference frame S.
struct PositionMeasurement {
  Eigen::Vector3d p_Ss = Eigen::Vector3d::Zero();
  Eigen::Matrix3d covariance = Eigen::Matrix3d::Identity();  ///< m^2
};

using Measurement = std::variant<ImuMeasurement, PoseMeasurement, PositionMeasurement>;

/// What a measurement is: the alternative of Measurement it holds (the enum value is the
/// variant index). A sensor's stream, its faults' applicability and its run-directory
/// columns all go by it.
enum class MeasurementKind : uint8_t { kImu = 0, kPose = 1, kPosition = 2 };

/// The kind's name in messages, notes and the replay's stream list: "imu", "pose",
/// "position".
std::string_view MeasurementKindName(MeasurementKind kind);

/// The kind a measurement holds.
MeasurementKind MeasurementKindOf(const Measurement& measurement);

/// A timestamped measurement of a named sensor.
struct StampedMeasurement {
  std::string sensor;
  Time t_ns = 0;  ///< time of validity (what the sensor stamps)
  Measurement value;
};

}  // namespace tofu::core
