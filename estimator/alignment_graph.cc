#include "estimator/alignment_graph.h"

#include <algorithm>
#include <cmath>
#include <deque>
#include <limits>
#include <optional>
#include <stdexcept>
#include <utility>
#include <vector>

#include <Eigen/Cholesky>
#include <Eigen/Eigenvalues>

#include "core/lie.h"
#include "estimator/frame_alignment.h"
#include "estimator/levenberg_marquardt.h"
#include "estimator/local_factors.h"

namespace tofu::estimator {
namespace {

using Matrix6d = Eigen::Matrix<double, 6, 6>;

/// R(q) v for q = (w, u) by the quadratic form (w² − u·u) v + 2 (u·v) u + 2 w (u × v):
/// equal to the rotation for a unit q, and the extension off the unit sphere that the
/// ambient Jacobian below differentiates (Ceres evaluates at unit q only, but the two
/// must agree for the chain rule with the manifold's PlusJacobian to hold).
Eigen::Vector3d RotateByQuaternion(const Eigen::Quaterniond& q, const Eigen::Vector3d& v) {
  const Eigen::Vector3d u = q.vec();
  const double w = q.w();
  return (w * w - u.squaredNorm()) * v + 2.0 * u.dot(v) * u + 2.0 * w * u.cross(v);
}

Eigen::Isometry3d IsometryFromParameters(const double* x) {
  Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
  T.translation() = Eigen::Map<const Eigen::Vector3d>(x);
  T.linear() = Eigen::Map<const Eigen::Quaterniond>(x + 3).normalized().toRotationMatrix();
  return T;
}

void ParametersFromIsometry(const Eigen::Isometry3d& T, double* x) {
  Eigen::Map<Eigen::Vector3d> p(x);
  Eigen::Map<Eigen::Quaterniond> q(x + 3);
  p = T.translation();
  q = core::CanonicalQuat(Eigen::Quaterniond(T.linear()).normalized());
}

/// Huber ρ(s) and ρ'(s) of Ceres (s = |r|², cost ½ρ); delta <= 0 means no loss.
double HuberRho(double s, double delta) {
  if (delta <= 0.0 || s <= delta * delta) return s;
  return 2.0 * delta * std::sqrt(s) - delta * delta;
}
double HuberWeight(double s, double delta) {
  if (delta <= 0.0 || s <= delta * delta) return 1.0;
  return delta / std::sqrt(s);
}

/// Whitened residual of one pair, S (p_A − T_AL p_Ls), and its Jacobian in the tangent
/// space [δp, δθ] of PoseManifold: ∂r/∂δp = −S, ∂r/∂δθ = S R_AL [p_Ls]× (from
/// R_AL Exp(δθ) p_Ls ≈ R_AL (p_Ls + δθ × p_Ls)).
Eigen::Vector3d WhitenedResidual(const Eigen::Matrix3d& S, const Eigen::Vector3d& p_A,
                                 const Eigen::Vector3d& p_Ls, const Eigen::Isometry3d& T_AL) {
  return S * (p_A - T_AL * p_Ls);
}
Eigen::Matrix<double, 3, 6> WhitenedTangentJacobian(const Eigen::Matrix3d& S,
                                                    const Eigen::Vector3d& p_Ls,
                                                    const Eigen::Isometry3d& T_AL) {
  Eigen::Matrix<double, 3, 6> J;
  J.leftCols<3>() = -S;
  J.rightCols<3>() = S * T_AL.linear() * core::Hat(p_Ls);
  return J;
}

bool AllFinite(const AlignmentPair& pair) {
  return pair.p_A_measured.allFinite() && pair.covariance_A.allFinite() &&
         pair.p_Ls_estimated.allFinite();
}

}  // namespace

// ---- options ----

bool AlignmentGraphOptions::IsValid(std::string* why) const {
  auto fail = [why](const char* message) {
    if (why != nullptr) *why = message;
    return false;
  };
  if (window_ns <= 0) return fail("window_ns must be positive");
  if (update_period_ns < 0) return fail("update_period_ns must not be negative");
  if (min_pair_spacing_ns < 0) return fail("min_pair_spacing_ns must not be negative");
  if (min_pairs < 3) return fail("min_pairs must be at least 3 (a rigid transform)");
  if (!(position_std_m > 0.0) || !std::isfinite(position_std_m)) {
    return fail("position_std_m must be positive and finite");
  }
  if (!(min_rotation_information > 0.0) || !std::isfinite(min_rotation_information)) {
    return fail("min_rotation_information must be positive and finite");
  }
  if (!(huber_delta >= 0.0) || !std::isfinite(huber_delta)) {
    return fail("huber_delta must be >= 0 and finite");
  }
  if (max_iterations < 1) return fail("max_iterations must be at least 1");
  if (!(reinit_rms_residual_m > 0.0)) return fail("reinit_rms_residual_m must be positive");
  if (!(level_prior_std_rad >= 0.0) || !std::isfinite(level_prior_std_rad)) {
    return fail("level_prior_std_rad must be >= 0 and finite (0: no level prior)");
  }
  return true;
}

Eigen::Vector2d LevelPriorResidual(const Eigen::Isometry3d& T_AL, double std_rad) {
  return (T_AL.linear() * Eigen::Vector3d::UnitZ()).head<2>() / std_rad;
}

Eigen::Matrix<double, 2, 6> LevelPriorTangentJacobian(const Eigen::Isometry3d& T_AL,
                                                      double std_rad) {
  Eigen::Matrix<double, 2, 6> J = Eigen::Matrix<double, 2, 6>::Zero();
  J.rightCols<3>() =
      -(T_AL.linear() * core::Hat(Eigen::Vector3d::UnitZ())).topRows<2>() / std_rad;
  return J;
}

// ---- cost function: paper eq. (9), whitened ----

PositionAlignmentCost::PositionAlignmentCost(const Eigen::Vector3d& p_A_measured,
                                             const Eigen::Vector3d& p_Ls,
                                             const Eigen::Matrix3d& sqrt_information_A)
    : p_A_measured_(p_A_measured), p_Ls_(p_Ls), sqrt_information_A_(sqrt_information_A) {}

bool PositionAlignmentCost::Evaluate(double const* const* parameters, double* residuals,
                                     double** jacobians) const {
  const Eigen::Map<const Eigen::Vector3d> p_AL(parameters[0]);
  const Eigen::Map<const Eigen::Quaterniond> q_AL(parameters[0] + 3);
  Eigen::Map<Eigen::Vector3d> r(residuals);
  r = sqrt_information_A_ * (p_A_measured_ - p_AL - RotateByQuaternion(q_AL, p_Ls_));
  if (jacobians == nullptr || jacobians[0] == nullptr) return true;

  // Ambient Jacobian of R(q) v (quadratic form above), columns x, y, z, w of Eigen's
  // storage:  ∂/∂u = −2 v uᵀ + 2 (u·v) I + 2 u vᵀ − 2 w [v]×,  ∂/∂w = 2 w v + 2 u × v.
  const Eigen::Vector3d u = q_AL.vec();
  const double w = q_AL.w();
  const Eigen::Vector3d& v = p_Ls_;
  Eigen::Matrix<double, 3, 4> dRv_dq;
  dRv_dq.leftCols<3>() = -2.0 * v * u.transpose() +
                         2.0 * u.dot(v) * Eigen::Matrix3d::Identity() +
                         2.0 * u * v.transpose() - 2.0 * w * core::Hat(v);
  dRv_dq.col(3) = 2.0 * w * v + 2.0 * u.cross(v);
  Eigen::Map<Eigen::Matrix<double, 3, 7, Eigen::RowMajor>> J(jacobians[0]);
  J.leftCols<3>() = -sqrt_information_A_;
  J.rightCols<4>() = -sqrt_information_A_ * dRv_dq;
  return true;
}

Eigen::Matrix<double, 3, 6> PositionAlignmentCost::TangentJacobian(
    const Eigen::Isometry3d& T_AL) const {
  return WhitenedTangentJacobian(sqrt_information_A_, p_Ls_, T_AL);
}

Eigen::Vector3d PositionAlignmentCost::Residual(const Eigen::Isometry3d& T_AL) const {
  return WhitenedResidual(sqrt_information_A_, p_A_measured_, p_Ls_, T_AL);
}

// ---- the graph's least squares ----

// Eq. (9) over the window's pairs, ½ Σ ρ(‖S_i (p_Ai − T_AL p_Ls_i)‖²), on the six
// tangent dimensions of T_AL: a 6x6 normal equation, where ceres::Solve spent most of an
// update building its program for 200-400 residual blocks. The Huber loss enters as
// Ceres's Corrector applies it: Huber's ρ'' ≤ 0, so Triggs's correction reduces to the
// weight ρ'(s) on JᵀJ and Jᵀr.
class AlignmentGraph::Problem final : public LmProblem {
 public:
  /// level_prior_std_rad > 0 adds the level prior (no robust loss: it is not data).
  Problem(const std::deque<StoredPair>& pairs, double huber_delta, double level_prior_std_rad,
          double* x)
      : pairs_(pairs), huber_delta_(huber_delta), level_prior_std_rad_(level_prior_std_rad),
        x_(x) {}

  bool Linearize(double* cost) override {
    const Eigen::Isometry3d T_AL = IsometryFromParameters(x_);
    H_.setZero();
    g_.setZero();
    double sum = 0.0;
    for (const StoredPair& pair : pairs_) {
      const Eigen::Vector3d r =
          WhitenedResidual(pair.sqrt_information_A, pair.p_A_measured, pair.p_Ls, T_AL);
      const Eigen::Matrix<double, 3, 6> J =
          WhitenedTangentJacobian(pair.sqrt_information_A, pair.p_Ls, T_AL);
      const double s = r.squaredNorm();
      const double weight = HuberWeight(s, huber_delta_);
      sum += HuberRho(s, huber_delta_);
      H_.noalias() += weight * J.transpose() * J;
      g_.noalias() += weight * J.transpose() * r;
    }
    if (level_prior_std_rad_ > 0.0) {
      const Eigen::Vector2d r = LevelPriorResidual(T_AL, level_prior_std_rad_);
      const Eigen::Matrix<double, 2, 6> J = LevelPriorTangentJacobian(T_AL, level_prior_std_rad_);
      sum += r.squaredNorm();
      H_.noalias() += J.transpose() * J;
      g_.noalias() += J.transpose() * r;
    }
    *cost = 0.5 * sum;
    return std::isfinite(*cost) && H_.allFinite() && g_.allFinite();
  }
  double GradientMaxNorm() const override { return g_.cwiseAbs().maxCoeff(); }
  bool Factorize(double lambda) override {
    llt_.compute(H_ + lambda * Damping().asDiagonal().toDenseMatrix());
    return llt_.info() == Eigen::Success;
  }
  void SolveForDelta() override { delta_ = -llt_.solve(g_); }
  double GradientDotDelta() const override { return g_.dot(delta_); }
  double DampingEnergy() const override { return delta_.cwiseProduct(Damping()).dot(delta_); }
  double DeltaNorm() const override { return delta_.norm(); }
  double StateNorm() const override { return Eigen::Map<const Vector7d>(x_).norm(); }
  void ApplyDelta() override {
    std::copy(x_, x_ + kPoseSize, saved_);
    PoseManifold().Plus(saved_, delta_.data(), x_);
  }
  void Restore() override { std::copy(saved_, saved_ + kPoseSize, x_); }
  bool EvaluateCost(double* cost) override {
    const Eigen::Isometry3d T_AL = IsometryFromParameters(x_);
    double sum = 0.0;
    for (const StoredPair& pair : pairs_) {
      sum += HuberRho(
          WhitenedResidual(pair.sqrt_information_A, pair.p_A_measured, pair.p_Ls, T_AL)
              .squaredNorm(),
          huber_delta_);
    }
    if (level_prior_std_rad_ > 0.0) {
      sum += LevelPriorResidual(T_AL, level_prior_std_rad_).squaredNorm();
    }
    *cost = 0.5 * sum;
    return std::isfinite(*cost);
  }

 private:
  using Vector6d = Eigen::Matrix<double, 6, 1>;
  using Vector7d = Eigen::Matrix<double, 7, 1>;
  // Ceres's LM diagonal: diag(H) clamped to [1e-6, 1e32].
  Vector6d Damping() const { return H_.diagonal().cwiseMax(1e-6).cwiseMin(1e32); }

  const std::deque<StoredPair>& pairs_;
  double huber_delta_;
  double level_prior_std_rad_;
  double* x_;
  double saved_[kPoseSize] = {};
  Matrix6d H_ = Matrix6d::Zero();
  Vector6d g_ = Vector6d::Zero();
  Vector6d delta_ = Vector6d::Zero();
  Eigen::LLT<Matrix6d> llt_;
};

// ---- the graph ----

AlignmentGraph::AlignmentGraph(AlignmentGraphOptions options) : options_(std::move(options)) {
  std::string why;
  if (!options_.IsValid(&why)) throw std::invalid_argument("AlignmentGraphOptions: " + why);
}

bool AlignmentGraph::AddPair(const AlignmentPair& pair) {
  // Validation: finite data, increasing time, a usable covariance.
  if (!AllFinite(pair) || (has_input_ && pair.t_ns <= last_input_t_ns_)) {
    ++rejected_pairs_;
    return false;
  }
  Eigen::Matrix3d covariance_A = pair.covariance_A;
  if (covariance_A.isZero(0.0)) {
    covariance_A = options_.position_std_m * options_.position_std_m * Eigen::Matrix3d::Identity();
  }
  const Eigen::LLT<Eigen::Matrix3d> llt(0.5 * (covariance_A + covariance_A.transpose()));
  if (llt.info() != Eigen::Success) {
    ++rejected_pairs_;
    return false;
  }
  // Σ = L Lᵀ ⇒ S = L⁻¹ gives Sᵀ S = Σ⁻¹.
  const Eigen::Matrix3d sqrt_information_A =
      llt.matrixL().solve(Eigen::Matrix3d::Identity());
  if (!sqrt_information_A.allFinite()) {
    ++rejected_pairs_;
    return false;
  }
  has_input_ = true;
  last_input_t_ns_ = pair.t_ns;

  // Valid but not stored: frozen (circular, see header) or decimated to min spacing.
  if (frozen_) {
    ++dropped_frozen_pairs_;
    return true;
  }
  if (has_stored_ && pair.t_ns - last_stored_t_ns_ < options_.min_pair_spacing_ns) {
    ++decimated_pairs_;
    return true;
  }
  pairs_.push_back({pair.t_ns, pair.p_A_measured, sqrt_information_A, pair.p_Ls_estimated});
  has_stored_ = true;
  last_stored_t_ns_ = pair.t_ns;
  // Memory stays bounded by the window even if Update is not called.
  DropOlderThan(pair.t_ns - options_.window_ns);
  return true;
}

void AlignmentGraph::DropOlderThan(core::Time t_oldest_ns) {
  while (!pairs_.empty() && pairs_.front().t_ns < t_oldest_ns) pairs_.pop_front();
}

bool AlignmentGraph::Update(core::Time now_ns) {
  if (frozen_) return false;
  if (has_solved_ && now_ns - last_solve_ns_ < options_.update_period_ns) return false;
  DropOlderThan(now_ns - options_.window_ns);
  if (static_cast<int>(pairs_.size()) < options_.min_pairs) return false;
  return Solve(now_ns);
}

void AlignmentGraph::SetFrozen(bool frozen) {
  frozen_ = frozen;
  estimate_.frozen = frozen;
}

void AlignmentGraph::Reset() {
  pairs_.clear();
  estimate_ = AlignmentEstimate{};
  estimate_.frozen = frozen_;
  has_input_ = false;
  has_stored_ = false;
  has_solved_ = false;
}

std::optional<double> AlignmentGraph::MedianResidualOf(const Eigen::Isometry3d& T_AL) const {
  if (static_cast<int>(pairs_.size()) < options_.min_pairs) return std::nullopt;
  std::vector<double> residual_m;
  residual_m.reserve(pairs_.size());
  for (const StoredPair& pair : pairs_) {
    residual_m.push_back((pair.p_A_measured - T_AL * pair.p_Ls).norm());
  }
  const auto middle = residual_m.begin() + static_cast<std::ptrdiff_t>(residual_m.size() / 2);
  std::nth_element(residual_m.begin(), middle, residual_m.end());
  return *middle;
}

double AlignmentGraph::RobustCost(const Eigen::Isometry3d& T_AL, double* rms_residual_m) const {
  double cost = 0.0;
  double sum_squares_m2 = 0.0;
  for (const StoredPair& pair : pairs_) {
    const Eigen::Vector3d error_A = pair.p_A_measured - T_AL * pair.p_Ls;
    sum_squares_m2 += error_A.squaredNorm();
    cost += HuberRho((pair.sqrt_information_A * error_A).squaredNorm(), options_.huber_delta);
  }
  if (options_.level_prior_std_rad > 0.0) {
    cost += LevelPriorResidual(T_AL, options_.level_prior_std_rad).squaredNorm();
  }
  if (rms_residual_m != nullptr) {
    *rms_residual_m = std::sqrt(sum_squares_m2 / static_cast<double>(pairs_.size()));
  }
  return cost;
}

bool AlignmentGraph::Solve(core::Time now_ns) {
  // Initial guess: warm start from the previous estimate; the closed form (Umeyama) when
  // there is none or when the previous T_AL no longer fits the window. Of the two, the
  // one with the lower robust cost (Umeyama is not robust to outliers).
  std::optional<Eigen::Isometry3d> T_AL_guess;
  double guess_cost = std::numeric_limits<double>::infinity();
  bool try_closed_form = true;
  if (estimate_.valid) {
    double rms_m = 0.0;
    guess_cost = RobustCost(estimate_.T_AL, &rms_m);
    T_AL_guess = estimate_.T_AL;
    try_closed_form = rms_m > options_.reinit_rms_residual_m;
  }
  if (try_closed_form) {
    std::vector<Eigen::Vector3d> p_L;
    std::vector<Eigen::Vector3d> p_A;
    p_L.reserve(pairs_.size());
    p_A.reserve(pairs_.size());
    for (const StoredPair& pair : pairs_) {
      p_L.push_back(pair.p_Ls);
      p_A.push_back(pair.p_A_measured);
    }
    if (options_.level_prior_std_rad > 0.0) {
      // Levelled frames: the yaw-only closed form. Umeyama's would be no better a guess
      // and, along a line, could turn the frame upside down about it (R_AL e_z = −e_z),
      // where the level prior is zero too.
      if (const auto level = AlignPositionsLevel(p_L, p_A)) {
        if (RobustCost(*level, nullptr) < guess_cost) T_AL_guess = *level;
      }
    } else if (const auto closed_form = AlignPositions(p_L, p_A, /*min_spread_m2=*/0.0)) {
      // Any non-zero spread is enough for a guess: with motion along a line the rotation
      // about it is arbitrary, and the refinement leaves it there (no gradient).
      if (RobustCost(closed_form->T_AL, nullptr) < guess_cost) T_AL_guess = closed_form->T_AL;
    }
  }
  // Motion collapsed to a point and no previous estimate: start anywhere; the rotation
  // comes out unobservable.
  if (!T_AL_guess) T_AL_guess = Eigen::Isometry3d::Identity();

  double x[kPoseSize];
  ParametersFromIsometry(*T_AL_guess, x);
  Problem problem(pairs_, options_.huber_delta, options_.level_prior_std_rad, x);
  LmOptions lm;  // Ceres's defaults, as the ceres::Solve this replaced
  lm.max_iterations = options_.max_iterations;
  lm.max_time_s = std::numeric_limits<double>::infinity();  // deterministic: no time cap
  lm.function_tolerance = 1e-6;
  lm.parameter_tolerance = 1e-8;
  lm.gradient_tolerance = 1e-10;
  lm.initial_trust_region_radius = 1e4;
  if (MinimizeLm(problem, lm).termination == LmTermination::kFailure) return false;

  const Eigen::Isometry3d T_AL = IsometryFromParameters(x);
  estimate_.valid = true;
  estimate_.T_AL = T_AL;
  estimate_.pairs = static_cast<int>(pairs_.size());
  estimate_.t_ns = now_ns;
  estimate_.frozen = frozen_;
  RobustCost(T_AL, &estimate_.rms_residual_m);
  AnalyseObservability(T_AL);
  has_solved_ = true;
  last_solve_ns_ = now_ns;
  return true;
}

void AlignmentGraph::AnalyseObservability(const Eigen::Isometry3d& T_AL) {
  // Information at the solution, H = Σ w_i J_iᵀ J_i with the tangent Jacobian of eq. (9)
  // and the Huber weight w_i = ρ'(|r_i|²) (the IRLS weight Ceres' solve used).
  Matrix6d H = Matrix6d::Zero();
  for (const StoredPair& pair : pairs_) {
    const Eigen::Matrix<double, 3, 6> J =
        WhitenedTangentJacobian(pair.sqrt_information_A, pair.p_Ls, T_AL);
    const double weight = HuberWeight(
        WhitenedResidual(pair.sqrt_information_A, pair.p_A_measured, pair.p_Ls, T_AL)
            .squaredNorm(),
        options_.huber_delta);
    H.noalias() += weight * J.transpose() * J;
  }
  const double n = static_cast<double>(pairs_.size());

  // Marginalise δp (Schur complement): the rotation information with the translation
  // estimated jointly. H_pp = Σ w SᵀS is positive definite for any pair.
  const Eigen::Matrix3d H_pp = H.topLeftCorner<3, 3>();
  const Eigen::Matrix3d H_pt = H.topRightCorner<3, 3>();
  Eigen::Matrix3d H_tt = H.bottomRightCorner<3, 3>();
  // The level prior's information on the tilt.
  if (options_.level_prior_std_rad > 0.0) {
    const Eigen::Matrix<double, 2, 3> J_theta =
        LevelPriorTangentJacobian(T_AL, options_.level_prior_std_rad).rightCols<3>();
    H_tt.noalias() += J_theta.transpose() * J_theta;
  }
  const Eigen::LLT<Eigen::Matrix3d> llt_pp(H_pp);
  const Eigen::Matrix3d K = llt_pp.solve(H_pt);  // H_pp⁻¹ H_pθ
  Eigen::Matrix3d H_rot = H_tt - H_pt.transpose() * K;
  H_rot = 0.5 * (H_rot + H_rot.transpose()).eval();  // eval: no aliasing

  // Directions: eigen-decomposition (ascending), per pair so the threshold does not
  // depend on the window length.
  const Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> eigen(H_rot);
  const Eigen::Vector3d lambda = eigen.eigenvalues();
  const Eigen::Matrix3d V = eigen.eigenvectors();
  estimate_.rotation_information_eigenvalues = lambda / n;
  estimate_.rotation_information_directions = V;
  // With the level prior a direction also counts when the prior holds it: information at
  // least the prior's 1/σ², i.e. a std of σ or less whatever the pairs say.
  const double held_information =
      options_.level_prior_std_rad > 0.0
          ? (1.0 - 1e-9) / (options_.level_prior_std_rad * options_.level_prior_std_rad)
          : std::numeric_limits<double>::infinity();
  estimate_.observable_rotation_dofs =
      static_cast<int>(((estimate_.rotation_information_eigenvalues.array() >
                         options_.min_rotation_information) ||
                        (lambda.array() >= held_information))
                           .count());

  // Covariance of δθ by directions, 1/λ capped: an information-free direction gets a
  // huge finite variance instead of inf (no NaN in the blocks below).
  Eigen::Vector3d variance_rad2;
  for (int k = 0; k < 3; ++k) {
    variance_rad2(k) = lambda(k) > 1.0 / kUnobservableVariance ? 1.0 / lambda(k)
                                                               : kUnobservableVariance;
  }
  const Eigen::Matrix3d Sigma_tt = V * variance_rad2.asDiagonal() * V.transpose();
  // Block inverse of H through the Schur complement:
  //   Σ_θθ = H_rot⁻¹, Σ_pθ = −H_pp⁻¹ H_pθ Σ_θθ, Σ_pp = H_pp⁻¹ + H_pp⁻¹ H_pθ Σ_θθ H_θp H_pp⁻¹.
  const Eigen::Matrix3d H_pp_inverse = llt_pp.solve(Eigen::Matrix3d::Identity());
  Matrix6d covariance;
  covariance.bottomRightCorner<3, 3>() = Sigma_tt;
  covariance.topRightCorner<3, 3>() = -K * Sigma_tt;
  covariance.bottomLeftCorner<3, 3>() = covariance.topRightCorner<3, 3>().transpose();
  covariance.topLeftCorner<3, 3>() = H_pp_inverse + K * Sigma_tt * K.transpose();
  estimate_.covariance = 0.5 * (covariance + covariance.transpose());

  // Yaw (rotation about L's z, δθ being in L): marginal information, i.e. the inverse of
  // its variance with roll and pitch estimated jointly. The conditional e_zᵀ H_rot e_z
  // would be wrong for motion along a tilted line: rotation about that line is free and
  // has a yaw component, so yaw is undetermined although e_zᵀ H_rot e_z > 0.
  const double yaw_variance_rad2 = Sigma_tt(2, 2);
  estimate_.yaw_information_per_pair = 1.0 / (n * yaw_variance_rad2);
  estimate_.yaw_observable =
      estimate_.yaw_information_per_pair > options_.min_rotation_information;
}

}  // namespace tofu::estimator
