#include "estimator/window_solver.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <stdexcept>
#include <string>

#include <Eigen/Cholesky>

#include "estimator/local_factors.h"

namespace tofu::estimator {
namespace {

using StateMatrix = Eigen::Matrix<double, kStateTangentSize, kStateTangentSize>;
using StateVector = Eigen::Matrix<double, kStateTangentSize, 1>;
using PlusJacobian = Eigen::Matrix<double, kPoseSize, kPoseTangentSize, Eigen::RowMajor>;

// Offset of a block inside its state's 15 tangent dimensions, and its tangent size.
constexpr int kSpeedBiasOffset = kPoseTangentSize;
int TangentSize(bool is_pose) { return is_pose ? kPoseTangentSize : kSpeedBiasSize; }
int AmbientSize(bool is_pose) { return is_pose ? kPoseSize : kSpeedBiasSize; }
int TangentSize(const WindowBlockRef& b) {
  return b.offset >= 0 ? kWindowOffsetSize : TangentSize(b.is_pose);
}
int AmbientSize(const WindowBlockRef& b) {
  return b.offset >= 0 ? kWindowOffsetSize : AmbientSize(b.is_pose);
}
using BorderBlock = Eigen::Matrix<double, kStateTangentSize, Eigen::Dynamic>;

// Ceres's bounds on the LM diagonal D = diag(H).
constexpr double kMinLmDiagonal = 1e-6;
constexpr double kMaxLmDiagonal = 1e32;

}  // namespace

struct WindowSolver::Impl final : LmProblem {
  // The problem MinimizeLm solves: these states and factors (set by Solve).
  const std::vector<WindowState>* problem_states = nullptr;
  const std::vector<WindowFactor>* problem_factors = nullptr;
  bool Linearize(double* cost) override {
    return Linearize(*problem_states, *problem_factors, cost);
  }
  double StateNorm() const override { return StateNorm(*problem_states); }
  void ApplyDelta() override {
    Save(*problem_states);
    ApplyDelta(*problem_states);
  }
  void Restore() override { Restore(*problem_states); }
  bool EvaluateCost(double* cost) override {
    return EvaluateCost(*problem_states, *problem_factors, cost);
  }

  int n = 0;          // states
  int bandwidth = 0;  // max state distance spanned by a factor
  // Envelope (profile) of H: first[i] is the oldest state a factor joins to state i. The
  // Cholesky factor has no fill-in outside it (Jennings' envelope method), so a row costs
  // (i − first[i])² block products: with two sensors fused most rows reach back one
  // keyframe and a few two or three, where a uniform band would pay for three everywhere.
  std::vector<int> first;
  // Lower band of H = JᵀJ: block (i, i − d) at i (b + 1) + d; diagonal blocks are full.
  std::vector<StateMatrix> H;
  std::vector<StateMatrix> L;  // its Cholesky factor, same layout
  std::vector<StateVector> g;  // Jᵀ r
  std::vector<StateVector> delta;
  std::vector<PlusJacobian> plus_jacobian;
  std::vector<char> pose_constant;
  // The offsets, ordered after the band: G = 3 × their count tangent dimensions. B_i (15 x
  // G) couples state i to them, C (G x G) is their own block; X_i = (L_A⁻¹ B)_i and L_C
  // factorises C + λD − XᵀX. All empty when G = 0: the band alone, as before.
  const std::vector<double*>* offsets = nullptr;
  int G = 0;
  std::vector<BorderBlock> B;
  std::vector<BorderBlock> X;
  Eigen::MatrixXd C;
  Eigen::MatrixXd L_C;
  Eigen::VectorXd g_offset;
  Eigen::VectorXd delta_offset;
  std::vector<double> saved_offsets;
  // Evaluation buffers, kept between calls.
  std::vector<const double*> parameters;
  std::vector<double> residual;
  std::vector<std::vector<double>> jacobian_storage;
  std::vector<double*> jacobians;
  Eigen::MatrixXd J;    // one factor's tangent Jacobian, m x Σ tangent sizes
  // Saved states for a rejected step.
  std::vector<double> saved;
  PoseManifold manifold;

  StateMatrix& HBlock(int i, int j) { return H[i * (bandwidth + 1) + (i - j)]; }
  const StateMatrix& HBlock(int i, int j) const { return H[i * (bandwidth + 1) + (i - j)]; }
  StateMatrix& LBlock(int i, int j) { return L[i * (bandwidth + 1) + (i - j)]; }

  void Setup(const std::vector<WindowState>& states, const std::vector<WindowFactor>& factors,
             const std::vector<double*>& offset_blocks) {
    offsets = &offset_blocks;
    G = kWindowOffsetSize * static_cast<int>(offset_blocks.size());
    n = static_cast<int>(states.size());
    bandwidth = 0;
    first.resize(n);
    for (int i = 0; i < n; ++i) first[i] = i;
    for (const WindowFactor& f : factors) {
      const auto& sizes = f.cost->parameter_block_sizes();
      if (sizes.size() != f.blocks.size()) {
        throw std::invalid_argument("WindowSolver: a factor's blocks do not match its cost");
      }
      int lo = n, hi = -1;
      for (std::size_t k = 0; k < f.blocks.size(); ++k) {
        const WindowBlockRef& b = f.blocks[k];
        if (b.offset >= 0) {
          if (kWindowOffsetSize * b.offset >= G || sizes[k] != kWindowOffsetSize) {
            throw std::invalid_argument("WindowSolver: a factor names an offset it cannot have");
          }
          continue;
        }
        if (b.state < 0 || b.state >= n || sizes[k] != AmbientSize(b.is_pose)) {
          throw std::invalid_argument("WindowSolver: a factor names a block it cannot have");
        }
        lo = std::min(lo, b.state);
        hi = std::max(hi, b.state);
      }
      if (hi < lo) continue;
      bandwidth = std::max(bandwidth, hi - lo);
      for (const WindowBlockRef& b : f.blocks) {
        if (b.offset < 0) first[b.state] = std::min(first[b.state], lo);
      }
    }
    const std::size_t blocks = static_cast<std::size_t>(n) * (bandwidth + 1);
    H.resize(blocks);
    L.resize(blocks);
    g.resize(n);
    delta.resize(n);
    plus_jacobian.resize(n);
    pose_constant.resize(n);
    for (int i = 0; i < n; ++i) pose_constant[i] = states[i].pose_constant ? 1 : 0;
    if (G > 0) {
      B.assign(n, BorderBlock::Zero(kStateTangentSize, G));
      X.assign(n, BorderBlock::Zero(kStateTangentSize, G));
      C.setZero(G, G);
      g_offset.setZero(G);
      delta_offset.setZero(G);
    }
  }

  // Evaluates one factor; with_jacobians fills J (tangent, constant columns zeroed).
  // Returns false for a failed or non-finite evaluation. Applies the robust loss (Triggs
  // correction as in Ceres's Corrector) to residual and J; adds ½ ρ(‖r‖²) to *cost.
  // M: the residual count when known at compile time (fixed-size products: at these sizes
  // GEMM's packing costs more than the arithmetic), else Eigen::Dynamic.
  template <int M = Eigen::Dynamic>
  bool EvaluateFactor(const std::vector<WindowState>& states, const WindowFactor& f,
                      bool with_jacobians, double* cost) {
    const int m = f.cost->num_residuals();
    const std::size_t count = f.blocks.size();
    parameters.resize(count);
    jacobians.resize(count);
    if (jacobian_storage.size() < count) jacobian_storage.resize(count);
    int columns = 0;
    for (std::size_t k = 0; k < count; ++k) {
      const WindowBlockRef& b = f.blocks[k];
      parameters[k] = b.offset >= 0 ? (*offsets)[b.offset]
                      : b.is_pose   ? states[b.state].pose
                                    : states[b.state].speed_bias;
      jacobian_storage[k].resize(static_cast<std::size_t>(m) * AmbientSize(b));
      jacobians[k] = jacobian_storage[k].data();
      columns += TangentSize(b);
    }
    residual.resize(m);
    if (!f.cost->Evaluate(parameters.data(), residual.data(),
                          with_jacobians ? jacobians.data() : nullptr)) {
      return false;
    }
    Eigen::Map<Eigen::VectorXd> r(residual.data(), m);
    if (!r.allFinite()) return false;
    if (with_jacobians) {
      J.resize(m, columns);
      int column = 0;
      for (std::size_t k = 0; k < count; ++k) {
        const WindowBlockRef& b = f.blocks[k];
        if (b.offset >= 0) {
          using Ambient = Eigen::Matrix<double, M, kWindowOffsetSize, Eigen::RowMajor>;
          const Eigen::Map<const Ambient> ambient(jacobians[k], m, kWindowOffsetSize);
          if (!ambient.allFinite()) return false;
          J.middleCols<kWindowOffsetSize>(column) = ambient;
        } else if (b.is_pose) {
          using Ambient = Eigen::Matrix<double, M, kPoseSize, Eigen::RowMajor>;
          const Eigen::Map<const Ambient> ambient(jacobians[k], m, kPoseSize);
          if (!ambient.allFinite()) return false;
          auto tangent = J.middleCols<kPoseTangentSize>(column);
          if (pose_constant[b.state]) {
            tangent.setZero();
          } else {
            tangent.noalias() = ambient * plus_jacobian[b.state];
          }
        } else {
          using Ambient = Eigen::Matrix<double, M, kSpeedBiasSize, Eigen::RowMajor>;
          const Eigen::Map<const Ambient> ambient(jacobians[k], m, kSpeedBiasSize);
          if (!ambient.allFinite()) return false;
          J.middleCols<kSpeedBiasSize>(column) = ambient;
        }
        column += TangentSize(b);
      }
    }
    const double squared_norm = r.squaredNorm();
    if (f.loss == nullptr) {
      *cost += 0.5 * squared_norm;
      return true;
    }
    double rho[3];
    f.loss->Evaluate(squared_norm, rho);
    *cost += 0.5 * rho[0];
    // Triggs et al. 1999: scale so that the Gauss-Newton model of ρ(‖r‖²) is exact to first
    // order; the second-order term only where ρ'' > 0 (Ceres's rule: never for Huber).
    const double sqrt_rho1 = std::sqrt(std::max(rho[1], 0.0));
    if (squared_norm == 0.0 || rho[2] <= 0.0) {
      r *= sqrt_rho1;
      if (with_jacobians) J *= sqrt_rho1;
      return true;
    }
    const double D = 1.0 + 2.0 * squared_norm * rho[2] / rho[1];
    const double alpha = 1.0 - std::sqrt(D);
    if (with_jacobians) {
      const Eigen::RowVectorXd rT_J = r.transpose() * J;
      J = sqrt_rho1 * (J - (alpha / squared_norm) * r * rT_J);
    }
    r *= sqrt_rho1 / (1.0 - alpha);
    return true;
  }

  bool EvaluateCost(const std::vector<WindowState>& states,
                    const std::vector<WindowFactor>& factors, double* cost) {
    *cost = 0.0;
    for (const WindowFactor& f : factors) {
      if (!EvaluateFactor(states, f, false, cost)) return false;
    }
    return std::isfinite(*cost);
  }

  // Adds one factor's J_kᵀ J_l to the band (blocks with state_k ≥ state_l; a diagonal
  // block whole) and J_kᵀ r to g, block pair by block pair with the sub-block sizes fixed
  // at compile time: M residual rows (Dynamic for priors), 6 or 9 tangent columns. Lazy
  // (coefficient-wise) products: Eigen sends anything of size ≥ 8 to its GEMM, whose
  // packing costs twice the arithmetic at 6x9x9.
  template <int M>
  void Accumulate(const WindowFactor& f) {
    const int m = static_cast<int>(J.rows());
    const Eigen::Map<const Eigen::Matrix<double, M, Eigen::Dynamic>> Jf(J.data(), m, J.cols());
    const Eigen::Map<const Eigen::Matrix<double, M, 1>> r(residual.data(), m);
    const bool bordered = G > 0 && HasOffset(f);
    int column_k = 0;
    for (const WindowBlockRef& bk : f.blocks) {
      if (bordered) {
        AccumulateBordered(f, bk, column_k, Jf, r);
        column_k += TangentSize(bk);
        continue;
      }
      if (bk.is_pose) {
        g[bk.state].template head<kPoseTangentSize>().noalias() +=
            Jf.template middleCols<kPoseTangentSize>(column_k).transpose() * r;
      } else {
        g[bk.state].template tail<kSpeedBiasSize>().noalias() +=
            Jf.template middleCols<kSpeedBiasSize>(column_k).transpose() * r;
      }
      int column_l = 0;
      for (const WindowBlockRef& bl : f.blocks) {
        if (bk.state >= bl.state) {
          StateMatrix& Hkl = HBlock(bk.state, bl.state);
          AddGram<M>(Jf, column_k, bk.is_pose, column_l, bl.is_pose, &Hkl);
        }
        column_l += TangentSize(bl.is_pose);
      }
      column_k += TangentSize(bk.is_pose);
    }
  }

  static bool HasOffset(const WindowFactor& f) {
    for (const WindowBlockRef& b : f.blocks) {
      if (b.offset >= 0) return true;
    }
    return false;
  }

  // Accumulate for a factor with an offset block, block row k: into the band, the border
  // B or C, and g. Few factors have one; plain dynamic-size products.
  template <typename JMap, typename RMap>
  void AccumulateBordered(const WindowFactor& f, const WindowBlockRef& bk, int column_k,
                          const JMap& Jf, const RMap& r) {
    const int tk = TangentSize(bk);
    const auto J_k = Jf.middleCols(column_k, tk);
    const int row_k = bk.offset >= 0 ? kWindowOffsetSize * bk.offset
                      : bk.is_pose   ? 0
                                     : kSpeedBiasOffset;
    if (bk.offset >= 0) {
      g_offset.segment(row_k, tk).noalias() += J_k.transpose() * r;
    } else {
      g[bk.state].segment(row_k, tk).noalias() += J_k.transpose() * r;
    }
    int column_l = 0;
    for (const WindowBlockRef& bl : f.blocks) {
      const int tl = TangentSize(bl);
      const auto J_l = Jf.middleCols(column_l, tl);
      if (bk.offset >= 0 && bl.offset >= 0) {
        C.block(row_k, kWindowOffsetSize * bl.offset, tk, tl).noalias() +=
            J_k.transpose() * J_l;
      } else if (bk.offset < 0 && bl.offset >= 0) {
        B[bk.state].block(row_k, kWindowOffsetSize * bl.offset, tk, tl).noalias() +=
            J_k.transpose() * J_l;
      } else if (bk.offset < 0 && bk.state >= bl.state) {
        const int row_l = bl.is_pose ? 0 : kSpeedBiasOffset;
        HBlock(bk.state, bl.state).block(row_k, row_l, tk, tl).noalias() +=
            J_k.transpose() * J_l;
      }
      column_l += tl;
    }
  }

  template <int M, int TK, int TL, typename JMap>
  static void AddGramBlock(const JMap& Jf, int column_k, int column_l, int offset_k,
                           int offset_l, StateMatrix* H_kl) {
    H_kl->template block<TK, TL>(offset_k, offset_l).noalias() +=
        Jf.template middleCols<TK>(column_k).transpose().lazyProduct(
            Jf.template middleCols<TL>(column_l));
  }

  template <int M, typename JMap>
  static void AddGram(const JMap& Jf, int column_k, bool pose_k, int column_l, bool pose_l,
                      StateMatrix* H_kl) {
    constexpr int P = kPoseTangentSize;
    constexpr int S = kSpeedBiasSize;
    if (pose_k && pose_l) {
      AddGramBlock<M, P, P>(Jf, column_k, column_l, 0, 0, H_kl);
    } else if (pose_k) {
      AddGramBlock<M, P, S>(Jf, column_k, column_l, 0, kSpeedBiasOffset, H_kl);
    } else if (pose_l) {
      AddGramBlock<M, S, P>(Jf, column_k, column_l, kSpeedBiasOffset, 0, H_kl);
    } else {
      AddGramBlock<M, S, S>(Jf, column_k, column_l, kSpeedBiasOffset, kSpeedBiasOffset, H_kl);
    }
  }

  template <int M>
  bool LinearizeFactor(const std::vector<WindowState>& states, const WindowFactor& f,
                       double* cost) {
    if (!EvaluateFactor<M>(states, f, true, cost)) return false;
    Accumulate<M>(f);
    return true;
  }

  // H = JᵀJ and g = Jᵀr at the states' values, factor by factor into the band.
  bool Linearize(const std::vector<WindowState>& states, const std::vector<WindowFactor>& factors,
                 double* cost) {
    for (int i = 0; i < n; ++i) {
      for (int j = first[i]; j <= i; ++j) HBlock(i, j).setZero();
    }
    for (StateVector& v : g) v.setZero();
    if (G > 0) {
      for (BorderBlock& b : B) b.setZero();
      C.setZero();
      g_offset.setZero();
    }
    for (int i = 0; i < n; ++i) manifold.PlusJacobian(states[i].pose, plus_jacobian[i].data());
    *cost = 0.0;
    for (const WindowFactor& f : factors) {
      // The local graph's factors have 3 (position between), 6 (pose between, bias walk,
      // pose prior) or 9 (IMU, speed-bias prior) rows; marginalisation priors any number.
      bool ok = false;
      switch (f.cost->num_residuals()) {
        case 3: ok = LinearizeFactor<3>(states, f, cost); break;
        case 6: ok = LinearizeFactor<6>(states, f, cost); break;
        case 9: ok = LinearizeFactor<9>(states, f, cost); break;
        default: ok = LinearizeFactor<Eigen::Dynamic>(states, f, cost); break;
      }
      if (!ok) return false;
    }
    // A constant pose has no columns: identity keeps the factorisation defined, δ stays 0.
    for (int i = 0; i < n; ++i) {
      if (pose_constant[i]) {
        HBlock(i, i).topLeftCorner<kPoseTangentSize, kPoseTangentSize>().diagonal().array() += 1.0;
      }
    }
    return std::isfinite(*cost);
  }

  // L Lᵀ = H + λ D, D = diag(H) clamped as Ceres's LM strategy does. Block envelope
  // Cholesky: L_ij = (H_ij − Σ_k L_ik L_jkᵀ) L_jj⁻ᵀ for first[i] ≤ j ≤ i.
  bool Factorize(double lambda) override {
    Eigen::LLT<StateMatrix> llt;
    for (int i = 0; i < n; ++i) {
      for (int j = first[i]; j <= i; ++j) {
        StateMatrix S = HBlock(i, j);
        for (int k = std::max(first[i], first[j]); k < j; ++k) {
          S.noalias() -= LBlock(i, k) * LBlock(j, k).transpose();
        }
        if (j < i) {
          LBlock(j, j).transpose().triangularView<Eigen::Upper>().solveInPlace<Eigen::OnTheRight>(
              S);
          LBlock(i, j) = S;
        } else {
          if (lambda > 0.0) {
            S.diagonal() += lambda * HBlock(i, i).diagonal().cwiseMax(kMinLmDiagonal).cwiseMin(
                                         kMaxLmDiagonal);
          }
          llt.compute(S);
          if (llt.info() != Eigen::Success) return false;
          LBlock(i, i) = llt.matrixL();
        }
      }
    }
    return G == 0 || FactorizeBorder(lambda);
  }

  // X_i = L_ii⁻¹ (B_i − Σ_k L_ik X_k) (forward substitution of L_A X = B), then
  // L_C L_Cᵀ = C + λ D − Σ_i X_iᵀ X_i.
  bool FactorizeBorder(double lambda) {
    Eigen::MatrixXd S = C;
    for (int i = 0; i < n; ++i) {
      BorderBlock x = B[i];
      for (int k = first[i]; k < i; ++k) x.noalias() -= LBlock(i, k) * X[k];
      LBlock(i, i).triangularView<Eigen::Lower>().solveInPlace(x);
      X[i] = x;
      S.noalias() -= x.transpose() * x;
    }
    if (lambda > 0.0) {
      S.diagonal() += lambda * C.diagonal().cwiseMax(kMinLmDiagonal).cwiseMin(kMaxLmDiagonal);
    }
    const Eigen::LLT<Eigen::MatrixXd> llt(S);
    if (llt.info() != Eigen::Success) return false;
    L_C = llt.matrixL();
    return true;
  }

  // δ = −(L Lᵀ)⁻¹ g: forward then backward substitution within the envelope.
  void SolveForDelta() override {
    for (int i = 0; i < n; ++i) {
      StateVector y = -g[i];
      for (int k = first[i]; k < i; ++k) y.noalias() -= LBlock(i, k) * delta[k];
      LBlock(i, i).triangularView<Eigen::Lower>().solveInPlace(y);
      delta[i] = y;
    }
    if (G > 0) {
      // L_C y_C = −g_C − Xᵀ y_A; L_Cᵀ δ_C = y_C; then L_Aᵀ δ_A = y_A − X δ_C below.
      Eigen::VectorXd y = -g_offset;
      for (int i = 0; i < n; ++i) y.noalias() -= X[i].transpose() * delta[i];
      L_C.triangularView<Eigen::Lower>().solveInPlace(y);
      L_C.transpose().triangularView<Eigen::Upper>().solveInPlace(y);
      delta_offset = y;
      for (int i = 0; i < n; ++i) delta[i].noalias() -= X[i] * delta_offset;
    }
    for (int i = n - 1; i >= 0; --i) {
      StateVector x = delta[i];
      for (int k = i + 1; k <= std::min(n - 1, i + bandwidth); ++k) {
        if (first[k] <= i) x.noalias() -= LBlock(k, i).transpose() * delta[k];
      }
      LBlock(i, i).transpose().triangularView<Eigen::Upper>().solveInPlace(x);
      delta[i] = x;
    }
  }

  void Save(const std::vector<WindowState>& states) {
    saved.resize(static_cast<std::size_t>(n) * (kPoseSize + kSpeedBiasSize));
    double* out = saved.data();
    for (const WindowState& s : states) {
      out = std::copy(s.pose, s.pose + kPoseSize, out);
      out = std::copy(s.speed_bias, s.speed_bias + kSpeedBiasSize, out);
    }
    saved_offsets.resize(static_cast<std::size_t>(G));
    out = saved_offsets.data();
    for (const double* o : *offsets) out = std::copy(o, o + kWindowOffsetSize, out);
  }
  void Restore(const std::vector<WindowState>& states) const {
    const double* in = saved.data();
    for (const WindowState& s : states) {
      std::copy(in, in + kPoseSize, s.pose);
      in += kPoseSize;
      std::copy(in, in + kSpeedBiasSize, s.speed_bias);
      in += kSpeedBiasSize;
    }
    in = saved_offsets.data();
    for (double* o : *offsets) {
      std::copy(in, in + kWindowOffsetSize, o);
      in += kWindowOffsetSize;
    }
  }

  void ApplyDelta(const std::vector<WindowState>& states) {
    for (int i = 0; i < n; ++i) {
      const WindowState& s = states[i];
      if (!pose_constant[i]) {
        double moved[kPoseSize];
        manifold.Plus(s.pose, delta[i].data(), moved);
        std::copy(moved, moved + kPoseSize, s.pose);
      }
      for (int k = 0; k < kSpeedBiasSize; ++k) s.speed_bias[k] += delta[i][kSpeedBiasOffset + k];
    }
    for (int j = 0; j < G; ++j) {
      (*offsets)[j / kWindowOffsetSize][j % kWindowOffsetSize] += delta_offset[j];
    }
  }

  // H = L Lᵀ with the last state ordered last among the states: (A⁻¹)_nn = L_nn⁻ᵀ L_nn⁻¹.
  // With offsets, (H⁻¹)_nn = (A⁻¹)_nn + Z_n S⁻¹ Z_nᵀ, Z = A⁻¹ B, whose last block row is
  // L_nn⁻ᵀ X_n (nothing follows it in the back substitution), S = L_C L_Cᵀ.
  std::optional<StateCovariance> LastBlockCovariance() {
    StateMatrix L_inverse = StateMatrix::Identity();
    LBlock(n - 1, n - 1).triangularView<Eigen::Lower>().solveInPlace(L_inverse);
    StateCovariance covariance = L_inverse.transpose() * L_inverse;
    if (G > 0) {
      BorderBlock Z_n = X[n - 1];
      LBlock(n - 1, n - 1).transpose().triangularView<Eigen::Upper>().solveInPlace(Z_n);
      Eigen::MatrixXd W = Z_n.transpose();
      L_C.triangularView<Eigen::Lower>().solveInPlace(W);
      covariance.noalias() += W.transpose() * W;
    }
    if (!covariance.allFinite()) return std::nullopt;
    return covariance;
  }

  double DeltaNorm() const override {
    double sum = 0.0;
    for (const StateVector& d : delta) sum += d.squaredNorm();
    if (G > 0) sum += delta_offset.squaredNorm();
    return std::sqrt(sum);
  }
  double StateNorm(const std::vector<WindowState>& states) const {
    double sum = 0.0;
    for (const WindowState& s : states) {
      for (int k = 0; k < kPoseSize; ++k) sum += s.pose[k] * s.pose[k];
      for (int k = 0; k < kSpeedBiasSize; ++k) sum += s.speed_bias[k] * s.speed_bias[k];
    }
    for (const double* o : *offsets) {
      for (int k = 0; k < kWindowOffsetSize; ++k) sum += o[k] * o[k];
    }
    return std::sqrt(sum);
  }
  double GradientMaxNorm() const override {
    double max = 0.0;
    for (const StateVector& v : g) max = std::max(max, v.cwiseAbs().maxCoeff());
    if (G > 0) max = std::max(max, g_offset.cwiseAbs().maxCoeff());
    return max;
  }
  // gᵀδ and δᵀ D δ of the last step.
  double GradientDotDelta() const override {
    double sum = 0.0;
    for (int i = 0; i < n; ++i) sum += g[i].dot(delta[i]);
    if (G > 0) sum += g_offset.dot(delta_offset);
    return sum;
  }
  double DampingEnergy() const override {
    double sum = 0.0;
    for (int i = 0; i < n; ++i) {
      const StateVector d =
          HBlock(i, i).diagonal().cwiseMax(kMinLmDiagonal).cwiseMin(kMaxLmDiagonal);
      sum += delta[i].cwiseProduct(d).dot(delta[i]);
    }
    if (G > 0) {
      const Eigen::VectorXd d = C.diagonal().cwiseMax(kMinLmDiagonal).cwiseMin(kMaxLmDiagonal);
      sum += delta_offset.cwiseProduct(d).dot(delta_offset);
    }
    return sum;
  }
};

WindowSolver::WindowSolver() : impl_(std::make_unique<Impl>()) {}
WindowSolver::~WindowSolver() = default;

WindowSolveSummary WindowSolver::Solve(const std::vector<WindowState>& states,
                                       const std::vector<WindowFactor>& factors,
                                       const WindowSolverOptions& options,
                                       const std::vector<double*>& offsets) {
  std::string why;
  if (!options.IsValid(&why)) throw std::invalid_argument("LmOptions: " + why);
  Impl& s = *impl_;
  s.Setup(states, factors, offsets);
  if (s.n == 0) {
    WindowSolveSummary summary;
    summary.termination = WindowTermination::kConverged;
    return summary;
  }
  s.problem_states = &states;
  s.problem_factors = &factors;
  const WindowSolveSummary summary = MinimizeLm(s, options);
  s.problem_states = nullptr;
  s.problem_factors = nullptr;
  s.offsets = nullptr;
  return summary;
}

std::optional<StateCovariance> WindowSolver::LastStateCovariance(
    const std::vector<WindowState>& states, const std::vector<WindowFactor>& factors,
    const std::vector<double*>& offsets) {
  Impl& s = *impl_;
  s.Setup(states, factors, offsets);
  if (s.n == 0) return std::nullopt;
  double cost = 0.0;
  std::optional<StateCovariance> covariance;
  if (s.Linearize(states, factors, &cost) && s.Factorize(0.0)) covariance = s.LastBlockCovariance();
  s.offsets = nullptr;
  return covariance;
}

}  // namespace tofu::estimator
