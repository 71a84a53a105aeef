#include "estimator/visual_inertial_alignment.h"

#include <algorithm>
#include <cmath>
#include <stdexcept>
#include <string>
#include <utility>

#include <Eigen/Cholesky>
#include <Eigen/Eigenvalues>

#include "core/lie.h"

namespace tofu::estimator {
namespace {

// Two unit vectors spanning the plane orthogonal to a direction (VINS-Mono's TangentBasis).
Eigen::Matrix<double, 3, 2> TangentBasis(const Eigen::Vector3d& direction) {
  const Eigen::Vector3d a = direction.normalized();
  Eigen::Vector3d helper = Eigen::Vector3d::UnitZ();
  if (std::abs(a.dot(helper)) > 0.9) helper = Eigen::Vector3d::UnitX();
  Eigen::Matrix<double, 3, 2> basis;
  basis.col(0) = (helper - a * a.dot(helper)).normalized();
  basis.col(1) = a.cross(basis.col(0));
  return basis;
}

struct Interval {
  double dt_s = 0.0;
  ImuPreintegration pre;
};

// The gyro bias that makes the IMU's rotation increments agree with the stream's
// relative rotations: Log(ΔR̃ᵀ R_kᵀ R_{k+1}) ≈ J^R_bg δb_g (Forster eq. 44), two
// Gauss-Newton steps, re-preintegrating at each bias. Returns the residuals' per-axis std.
bool EstimateGyroBias(const std::vector<ImuPoseInA>& poses, const ImuPreintegrator& preintegrate,
                      bool bias_known, ImuBias* bias, std::vector<Interval>* intervals,
                      std::vector<double>* residual_norms) {
  const std::size_t n = poses.size() - 1;
  const int iterations = bias_known ? 1 : 3;
  for (int iteration = 0; iteration < iterations; ++iteration) {
    intervals->clear();
    residual_norms->clear();
    Eigen::Matrix3d H = Eigen::Matrix3d::Zero();
    Eigen::Vector3d b = Eigen::Vector3d::Zero();
    for (std::size_t k = 0; k < n; ++k) {
      std::optional<ImuPreintegration> pre = preintegrate(poses[k].t_ns, poses[k + 1].t_ns, *bias);
      if (!pre) return false;
      const Eigen::Matrix3d R_rel = poses[k].R_AI.transpose() * poses[k + 1].R_AI;
      const Eigen::Vector3d e = core::LogSO3(pre->delta_R().transpose() * R_rel);
      const Eigen::Matrix3d& J = pre->d_R_d_bg();
      H += J.transpose() * J;
      b += J.transpose() * e;
      residual_norms->push_back(e.norm());
      intervals->push_back(Interval{pre->dt_s(), std::move(*pre)});
    }
    if (iteration + 1 == iterations) break;
    // A window without rotation leaves the bias unobservable: keep it (regularised).
    H += 1e-6 * Eigen::Matrix3d::Identity();
    bias->gyro_radps += H.ldlt().solve(b);
  }
  return true;
}

// Per-axis standard deviation from the norms of 3-vector residuals, robustly: the median
// of a chi distribution with 3 degrees of freedom is 1.538 σ.
double RobustAxisStd(std::vector<double> norms) {
  if (norms.empty()) return 0.0;
  const auto mid = norms.begin() + static_cast<std::ptrdiff_t>(norms.size() / 2);
  std::nth_element(norms.begin(), mid, norms.end());
  return *mid / 1.538;
}

// Index of the last interval whose residual is an outlier, or -1.
int LastOutlier(const std::vector<double>& norms, double axis_std, double sigmas) {
  int last = -1;
  // The norm of a 3-vector of N(0, σ²): beyond sigmas·σ·√3 it is an outlier.
  const double bound = sigmas * axis_std * std::sqrt(3.0);
  for (std::size_t k = 0; k < norms.size(); ++k) {
    if (norms[k] > bound) last = static_cast<int>(k);
  }
  return last;
}

struct LinearSolution {
  std::vector<Eigen::Vector3d> v_A;
  Eigen::Vector3d g_A;
  Eigen::Vector3d b_a;
  Eigen::Matrix2d tangent_covariance = Eigen::Matrix2d::Zero();  // of w, scaled
  std::vector<double> position_residual_norms;
  double chi2 = 0.0;
  int dof = 0;
};

// Weighted least squares over x = [v_0 … v_N, g (3, or 2 tangent coordinates w with
// g = G ĝ + B w), b_a]. Rows per interval k: position (3) and velocity (3) equations of
// the header; plus the accelerometer-bias prior.
// Long by design: the rows of one least-squares system written as the equations above,
// then its solve; splitting would scatter the row layout across functions.
std::optional<LinearSolution> SolveVelocitiesGravity(
    const std::vector<ImuPoseInA>& poses, const std::vector<Interval>& intervals,
    const std::optional<Eigen::Vector3d>& g_direction, double position_std_m,
    double rotation_std_rad, const VisualInertialAlignmentOptions& options) {
  const int n_intervals = static_cast<int>(intervals.size());
  const int n_v = 3 * (n_intervals + 1);
  const int n_g = g_direction ? 2 : 3;
  const int n_x = n_v + n_g + 3;
  const int g_col = n_v;
  const int ba_col = n_v + n_g;
  const double G = options.gravity_mps2;
  Eigen::Matrix<double, 3, 2> B = Eigen::Matrix<double, 3, 2>::Zero();
  Eigen::Vector3d g0 = Eigen::Vector3d::Zero();
  if (g_direction) {
    B = TangentBasis(*g_direction);
    g0 = G * g_direction->normalized();
  }
  Eigen::MatrixXd H = Eigen::MatrixXd::Zero(n_x, n_x);
  Eigen::VectorXd rhs = Eigen::VectorXd::Zero(n_x);
  // One block row A x = y with weight 1/σ²: accumulate AᵀA/σ², Aᵀy/σ².
  struct Row {
    std::vector<std::pair<int, Eigen::Matrix3Xd>> blocks;
    Eigen::Vector3d y;
    double variance;
  };
  std::vector<Row> rows;
  rows.reserve(2 * n_intervals + 1);
  for (int k = 0; k < n_intervals; ++k) {
    const ImuPreintegration& pre = intervals[k].pre;
    const double dt = intervals[k].dt_s;
    const Eigen::Matrix3d& R_k = poses[k].R_AI;
    const Eigen::Vector3d dp_A = R_k * pre.delta_p();
    const Eigen::Vector3d dv_A = R_k * pre.delta_v();
    const Eigen::Matrix<double, 9, 9>& cov = pre.covariance();  // [δθ, δv, δp]
    const double rot2 = rotation_std_rad * rotation_std_rad;
    // p_{k+1} − p_k − R_k Δp̃ = v_k Δt + ½ g Δt² + R_k J^p_ba b_a
    Row position;
    position.blocks.push_back({3 * k, Eigen::Matrix3d::Identity() * dt});
    const Eigen::Matrix3d g_dp = 0.5 * dt * dt * Eigen::Matrix3d::Identity();
    if (g_direction) {
      position.blocks.push_back({g_col, g_dp * B});
    } else {
      position.blocks.push_back({g_col, g_dp});
    }
    position.blocks.push_back({ba_col, R_k * pre.d_p_d_ba()});
    position.y = poses[k + 1].p_AI - poses[k].p_AI - dp_A - g_dp * g0;
    position.variance = position_std_m * position_std_m + cov.block<3, 3>(6, 6).trace() / 3.0 +
                        rot2 * dp_A.squaredNorm();
    rows.push_back(std::move(position));
    // R_k Δṽ = v_{k+1} − v_k − g Δt − R_k J^v_ba b_a
    Row velocity;
    velocity.blocks.push_back({3 * (k + 1), Eigen::Matrix3d::Identity()});
    velocity.blocks.push_back({3 * k, -Eigen::Matrix3d::Identity()});
    const Eigen::Matrix3d g_dv = -dt * Eigen::Matrix3d::Identity();
    if (g_direction) {
      velocity.blocks.push_back({g_col, g_dv * B});
    } else {
      velocity.blocks.push_back({g_col, g_dv});
    }
    velocity.blocks.push_back({ba_col, -R_k * pre.d_v_d_ba()});
    velocity.y = dv_A - g_dv * g0;
    velocity.variance = cov.block<3, 3>(3, 3).trace() / 3.0 + rot2 * dv_A.squaredNorm();
    rows.push_back(std::move(velocity));
  }
  Row prior;
  prior.blocks.push_back({ba_col, Eigen::Matrix3d::Identity()});
  prior.y.setZero();
  prior.variance = options.accel_bias_prior_std_mps2 * options.accel_bias_prior_std_mps2;
  rows.push_back(std::move(prior));

  for (const Row& row : rows) {
    const double w = 1.0 / std::max(row.variance, 1e-18);
    for (const auto& [ci, Ai] : row.blocks) {
      rhs.segment(ci, Ai.cols()) += w * Ai.transpose() * row.y;
      for (const auto& [cj, Aj] : row.blocks) {
        H.block(ci, cj, Ai.cols(), Aj.cols()) += w * Ai.transpose() * Aj;
      }
    }
  }
  const Eigen::LDLT<Eigen::MatrixXd> ldlt(H);
  if (ldlt.info() != Eigen::Success) return std::nullopt;
  const Eigen::VectorXd x = ldlt.solve(rhs);
  if (!x.allFinite()) return std::nullopt;

  LinearSolution out;
  for (int k = 0; k <= n_intervals; ++k) out.v_A.push_back(x.segment<3>(3 * k));
  out.g_A = g_direction ? Eigen::Vector3d(g0 + B * x.segment<2>(g_col))
                        : Eigen::Vector3d(x.segment<3>(g_col));
  out.b_a = x.segment<3>(ba_col);
  for (std::size_t r = 0; r < rows.size(); ++r) {
    Eigen::Vector3d e = -rows[r].y;
    for (const auto& [c, A] : rows[r].blocks) e += A * x.segment(c, A.cols());
    out.chi2 += e.squaredNorm() / std::max(rows[r].variance, 1e-18);
    if (r + 1 < rows.size() && r % 2 == 0) out.position_residual_norms.push_back(e.norm());
  }
  out.dof = 3 * static_cast<int>(rows.size()) - n_x;
  if (g_direction && out.dof > 0) {
    const Eigen::MatrixXd P = ldlt.solve(Eigen::MatrixXd::Identity(n_x, n_x));
    out.tangent_covariance = P.block<2, 2>(g_col, g_col) * (out.chi2 / out.dof);
  }
  return out;
}

}  // namespace

bool VisualInertialAlignmentOptions::IsValid(std::string* why) const {
  auto fail = [why](std::string message) {
    if (why != nullptr) *why = std::move(message);
    return false;
  };
  if (!(gravity_mps2 > 0.0) || !std::isfinite(gravity_mps2)) {
    return fail("gravity_mps2 must be positive and finite");
  }
  if (!(min_window_s >= 0.0) || !std::isfinite(min_window_s)) {
    return fail("min_window_s must be >= 0 and finite");
  }
  // The equations tie consecutive samples: two intervals at least.
  if (min_samples < 3) return fail("min_samples must be at least 3");
  if (!(max_gravity_direction_std_rad > 0.0) || !std::isfinite(max_gravity_direction_std_rad)) {
    return fail("max_gravity_direction_std_rad must be positive and finite");
  }
  if (!(max_gravity_norm_error > 0.0) || !std::isfinite(max_gravity_norm_error)) {
    return fail("max_gravity_norm_error must be positive and finite");
  }
  if (known_gyro_bias_radps && !known_gyro_bias_radps->allFinite()) {
    return fail("known_gyro_bias_radps must be finite");
  }
  if (!(accel_bias_prior_std_mps2 > 0.0) || !std::isfinite(accel_bias_prior_std_mps2)) {
    return fail("accel_bias_prior_std_mps2 must be positive and finite");
  }
  if (!(nominal_relative_position_std_m > 0.0) || !std::isfinite(nominal_relative_position_std_m)) {
    return fail("nominal_relative_position_std_m must be positive and finite");
  }
  // The constrained solution (and the residuals measuring the stream) comes from these.
  if (gravity_refinement_iterations < 1) {
    return fail("gravity_refinement_iterations must be at least 1");
  }
  if (!(outlier_sigmas > 0.0) || !std::isfinite(outlier_sigmas)) {
    return fail("outlier_sigmas must be positive and finite");
  }
  return true;
}

std::optional<VisualInertialAlignment> AlignVisualInertial(
    const std::vector<ImuPoseInA>& poses, const ImuPreintegrator& preintegrate,
    const VisualInertialAlignmentOptions& options) {
  if (std::string why; !options.IsValid(&why)) {
    throw std::invalid_argument("AlignVisualInertial: " + why);
  }
  if (poses.size() < 3 || static_cast<int>(poses.size()) < options.min_samples) return std::nullopt;
  const double window_s = core::TimeToSeconds(poses.back().t_ns - poses.front().t_ns);
  if (window_s < options.min_window_s) return std::nullopt;

  VisualInertialAlignment out;
  out.window_s = window_s;
  out.samples = static_cast<int>(poses.size());
  std::vector<Interval> intervals;
  std::vector<double> rotation_norms;
  if (options.known_gyro_bias_radps) out.bias.gyro_radps = *options.known_gyro_bias_radps;
  if (!EstimateGyroBias(poses, preintegrate, options.known_gyro_bias_radps.has_value(), &out.bias,
                        &intervals, &rotation_norms)) {
    return std::nullopt;
  }
  const double rotation_std = std::max(RobustAxisStd(rotation_norms), 1e-5);
  out.relative_rotation_std_rad = rotation_std;
  const int rotation_outlier = LastOutlier(rotation_norms, rotation_std, options.outlier_sigmas);

  // Gravity free first (its norm checks the stream against the IMU), then on the sphere
  // |g| = G; the stream's relative position noise re-weights the second pass.
  std::optional<LinearSolution> free = SolveVelocitiesGravity(
      poses, intervals, std::nullopt, options.nominal_relative_position_std_m, rotation_std,
      options);
  if (!free || free->g_A.norm() < 1e-6) return std::nullopt;
  out.unconstrained_gravity_norm_mps2 = free->g_A.norm();
  double position_std = RobustAxisStd(free->position_residual_norms);
  Eigen::Vector3d direction = free->g_A.normalized();
  std::optional<LinearSolution> refined;
  for (int pass = 0; pass < 2; ++pass) {
    for (int it = 0; it < options.gravity_refinement_iterations; ++it) {
      refined = SolveVelocitiesGravity(poses, intervals, direction, std::max(position_std, 1e-4),
                                       rotation_std, options);
      if (!refined) return std::nullopt;
      direction = refined->g_A.normalized();
    }
    position_std = RobustAxisStd(refined->position_residual_norms);
  }
  const int position_outlier = LastOutlier(refined->position_residual_norms,
                                           std::max(position_std, 1e-4), options.outlier_sigmas);
  out.drop_leading_samples = std::max(rotation_outlier, position_outlier) + 1;
  out.g_A = options.gravity_mps2 * direction;
  out.v_A_mps = refined->v_A;
  out.bias.accel_mps2 = refined->b_a;
  out.relative_position_std_m = position_std;
  const double tangent_variance =
      Eigen::SelfAdjointEigenSolver<Eigen::Matrix2d>(refined->tangent_covariance).eigenvalues().maxCoeff();
  out.gravity_direction_std_rad = std::sqrt(std::max(0.0, tangent_variance)) / options.gravity_mps2;
  out.observable =
      refined->dof > 0 && out.drop_leading_samples == 0 &&
      out.gravity_direction_std_rad <= options.max_gravity_direction_std_rad &&
      std::abs(out.unconstrained_gravity_norm_mps2 - options.gravity_mps2) <=
          options.max_gravity_norm_error * options.gravity_mps2;
  return out;
}

}  // namespace tofu::estimator
