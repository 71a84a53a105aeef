#include "replay/trajectory_metrics.h"

#include <algorithm>
#include <array>
#include <charconv>
#include <cmath>
#include <cstdint>
#include <iterator>
#include <string>

#include <Eigen/Eigenvalues>
#include <Eigen/SVD>
#include <fmt/format.h>

#include "core/error.h"
#include "core/file_io.h"
#include "core/lie.h"
#include "core/units.h"
#include "replay/csv_reader.h"
#include "replay/file_io.h"

namespace tofu::replay {
namespace {

namespace fs = std::filesystem;
using core::InputError;
using core::Time;

using core::kDegPerRad;
constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

// ---- TUM text ----

// The columns of a TUM line, as messages name them.
const std::vector<std::string> kTumColumns = {"t [s]", "x [m]", "y [m]",  "z [m]",
                                              "qx",    "qy",    "qz",     "qw"};

// ---- evaluation helpers ----

bool IsFinite(const PoseSample& s) {
  return s.p.allFinite() && s.q.coeffs().allFinite();
}

std::vector<PoseSample> SortedFinite(const std::vector<PoseSample>& in, size_t* non_finite) {
  std::vector<PoseSample> out;
  out.reserve(in.size());
  for (const PoseSample& s : in) {
    if (IsFinite(s)) {
      out.push_back(s);
      out.back().q.normalize();
    } else if (non_finite != nullptr) {
      ++*non_finite;
    }
  }
  std::stable_sort(out.begin(), out.end(),
                   [](const PoseSample& a, const PoseSample& b) { return a.t_ns < b.t_ns; });
  return out;
}

// The ground truth the errors are taken against: sorted, finite, one sample per stamp, with
// unit quaternions. Either the caller's vector as it is (already in that form: a recorded
// log's ground truth, never copied: an hour at 200 Hz is 46 MB) with each quaternion
// normalised as it is read, or a cleaned copy normalised once; both give the same bits.
class TruthTrack {
 public:
  explicit TruthTrack(const std::vector<PoseSample>& ground_truth) {
    const bool clean =
        std::all_of(ground_truth.begin(), ground_truth.end(), IsFinite) &&
        std::adjacent_find(ground_truth.begin(), ground_truth.end(),
                           [](const PoseSample& a, const PoseSample& b) {
                             return a.t_ns >= b.t_ns;
                           }) == ground_truth.end();
    if (clean) {
      samples_ = &ground_truth;
      return;
    }
    cleaned_.reserve(ground_truth.size());
    for (const PoseSample& s : ground_truth) {
      if (!IsFinite(s)) continue;
      cleaned_.push_back(s);
      cleaned_.back().q.normalize();
    }
    std::stable_sort(cleaned_.begin(), cleaned_.end(),
                     [](const PoseSample& a, const PoseSample& b) { return a.t_ns < b.t_ns; });
    cleaned_.erase(std::unique(cleaned_.begin(), cleaned_.end(),
                               [](const PoseSample& a, const PoseSample& b) {
                                 return a.t_ns == b.t_ns;
                               }),
                   cleaned_.end());
    samples_ = &cleaned_;
    normalise_on_read_ = false;
  }
  TruthTrack(const TruthTrack&) = delete;
  TruthTrack& operator=(const TruthTrack&) = delete;

  // Ground truth at t: the sample at t, or position lerp and attitude slerp between the two
  // samples around t when both are within `max_gap`.
  std::optional<PoseSample> At(Time t, Time max_gap) const {
    const std::vector<PoseSample>& gt = *samples_;
    const auto it = std::lower_bound(gt.begin(), gt.end(), t,
                                     [](const PoseSample& s, Time v) { return s.t_ns < v; });
    if (it != gt.end() && it->t_ns == t) return Read(*it);
    if (it == gt.begin() || it == gt.end()) return std::nullopt;
    const PoseSample a = Read(*(it - 1));
    const PoseSample b = Read(*it);
    if (t - a.t_ns > max_gap || b.t_ns - t > max_gap) return std::nullopt;
    const double alpha =
        static_cast<double>(t - a.t_ns) / static_cast<double>(b.t_ns - a.t_ns);
    PoseSample s;
    s.t_ns = t;
    s.p = a.p + alpha * (b.p - a.p);
    s.q = a.q.slerp(alpha, b.q).normalized();
    return s;
  }

 private:
  PoseSample Read(const PoseSample& s) const {
    PoseSample out = s;
    if (normalise_on_read_) out.q.normalize();
    return out;
  }

  const std::vector<PoseSample>* samples_ = nullptr;
  std::vector<PoseSample> cleaned_;
  bool normalise_on_read_ = true;
};

// Closest rotation to M in the Frobenius sense (the chordal mean when M = sum of R_i).
Eigen::Matrix3d ProjectToSO3(const Eigen::Matrix3d& M) {
  const Eigen::JacobiSVD<Eigen::Matrix3d> svd(M, Eigen::ComputeFullU | Eigen::ComputeFullV);
  Eigen::Matrix3d D = Eigen::Matrix3d::Identity();
  if ((svd.matrixU() * svd.matrixV().transpose()).determinant() < 0.0) D(2, 2) = -1.0;
  return svd.matrixU() * D * svd.matrixV().transpose();
}

// The matched samples: each an estimate sample (T_LI) and the ground truth (T_WI)
// interpolated at its time. Only the estimate's index is stored; both poses are rebuilt
// from their sources, with the same arithmetic, whenever they are read: two stored poses
// per sample would be 98 MB for an hour at 200 Hz.
class Matches {
 public:
  // `normalize`: the estimate's quaternions still need it (taken as they came).
  Matches(const std::vector<PoseSample>& estimate, bool normalize, const TruthTrack& gt,
          Time max_gap)
      : estimate_(estimate), normalize_(normalize), gt_(gt), max_gap_(max_gap) {}

  void Add(std::size_t estimate_index) { index_.push_back(estimate_index); }
  void Reserve(std::size_t n) { index_.reserve(n); }
  std::size_t size() const { return index_.size(); }
  bool empty() const { return index_.empty(); }
  Time t_ns(std::size_t k) const { return estimate_[index_[k]].t_ns; }
  PoseSample estimate(std::size_t k) const {
    PoseSample e = estimate_[index_[k]];
    if (normalize_) e.q.normalize();
    return e;
  }
  PoseSample truth(std::size_t k) const { return *gt_.At(t_ns(k), max_gap_); }

 private:
  const std::vector<PoseSample>& estimate_;
  bool normalize_;
  const TruthTrack& gt_;
  Time max_gap_;
  std::vector<std::uint32_t> index_;
};

// T_WL from the matches inside the alignment range (see TrajectoryErrorOptions); sets the
// number of them it aligned on.
Eigen::Isometry3d Align(const Matches& matches, const TrajectoryErrorOptions& options,
                        bool* from_attitude, std::size_t* aligned_on) {
  Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
  *from_attitude = false;
  const auto in_range = [&](std::size_t k) {
    return matches.t_ns(k) >= options.align_from_ns && matches.t_ns(k) <= options.align_to_ns;
  };
  std::size_t count = 0;
  for (std::size_t k = 0; k < matches.size(); ++k) count += in_range(k) ? 1 : 0;
  *aligned_on = count;
  if (options.alignment == TrajectoryAlignment::kNone || count == 0) return T;
  const double n = static_cast<double>(count);

  // Centroids, centred cross-covariance H = sum a b^T (a: estimate, b: truth), the truth's
  // scatter, and the sum of attitude offsets R_WI R_LI^T.
  Eigen::Vector3d mu_est = Eigen::Vector3d::Zero();
  Eigen::Vector3d mu_true = Eigen::Vector3d::Zero();
  for (std::size_t k = 0; k < matches.size(); ++k) {
    if (!in_range(k)) continue;
    mu_est += matches.estimate(k).p;
    mu_true += matches.truth(k).p;
  }
  mu_est /= n;
  mu_true /= n;
  Eigen::Matrix3d H = Eigen::Matrix3d::Zero();
  Eigen::Matrix3d scatter = Eigen::Matrix3d::Zero();
  Eigen::Matrix3d attitude_sum = Eigen::Matrix3d::Zero();
  for (std::size_t k = 0; k < matches.size(); ++k) {
    if (!in_range(k)) continue;
    const PoseSample estimate = matches.estimate(k);
    const PoseSample truth = matches.truth(k);
    const Eigen::Vector3d a = estimate.p - mu_est;
    const Eigen::Vector3d b = truth.p - mu_true;
    H += a * b.transpose();
    scatter += b * b.transpose();
    attitude_sum += truth.q.toRotationMatrix() * estimate.q.toRotationMatrix().transpose();
  }
  scatter /= n;
  const double min_variance = options.min_alignment_spread_m * options.min_alignment_spread_m;

  Eigen::Matrix3d R = Eigen::Matrix3d::Identity();
  if (options.alignment == TrajectoryAlignment::kSE3) {
    // Horn/Umeyama without scale: R = V diag(1, 1, det(V U^T)) U^T for H = U S V^T,
    // determined when the positions span a plane (second principal variance).
    const Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> eig(scatter);
    if (count >= 3 && eig.eigenvalues()(1) >= min_variance) {
      R = ProjectToSO3(H.transpose());
    } else {
      R = ProjectToSO3(attitude_sum);
      *from_attitude = true;
    }
  } else {
    // 4-DoF: yaw maximising sum b^T Rz(psi) a over the horizontal components,
    // psi = atan2(sum(a_x b_y - a_y b_x), sum(a_x b_x + a_y b_y)); needs horizontal spread.
    const Eigen::SelfAdjointEigenSolver<Eigen::Matrix2d> eig(scatter.topLeftCorner<2, 2>());
    double yaw = 0.0;
    if (count >= 2 && eig.eigenvalues()(1) >= min_variance) {
      yaw = std::atan2(H(0, 1) - H(1, 0), H(0, 0) + H(1, 1));
    } else {
      // Projection of the attitude offsets onto rotations about z.
      yaw = core::YawOfNearestZRotation(attitude_sum);
      *from_attitude = true;
    }
    R = Eigen::AngleAxisd(yaw, Eigen::Vector3d::UnitZ()).toRotationMatrix();
  }
  T.linear() = R;
  T.translation() = mu_true - R * mu_est;
  return T;
}

double Rms(const std::vector<double>& v) {
  if (v.empty()) return kNaN;
  double sum = 0.0;
  for (const double x : v) sum += x * x;
  return std::sqrt(sum / static_cast<double>(v.size()));
}

Eigen::Isometry3d ToIsometry(const PoseSample& s) {
  Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
  T.linear() = s.q.toRotationMatrix();
  T.translation() = s.p;
  return T;
}

}  // namespace

double Median(std::vector<double> v) {
  if (v.empty()) return kNaN;
  const size_t mid = v.size() / 2;
  std::nth_element(v.begin(), v.begin() + static_cast<std::ptrdiff_t>(mid), v.end());
  if (v.size() % 2 == 1) return v[mid];
  const double upper = v[mid];
  const double lower = *std::max_element(v.begin(), v.begin() + static_cast<std::ptrdiff_t>(mid));
  return 0.5 * (lower + upper);
}

std::optional<Time> ParseSecondsAsNanoseconds(std::string_view text) {
  // value = 0.d1 d2 d3 ... x 10^point, d1 != 0; only the first digits matter: an int64 of
  // ns has at most 19 digits, one more decides the rounding.
  constexpr int kKeep = 24;
  std::array<uint8_t, kKeep> digits{};
  int kept = 0;
  long point = 0;
  bool started = false;
  bool any_digit = false;
  size_t i = 0;
  const size_t n = text.size();
  bool negative = false;
  if (i < n && (text[i] == '+' || text[i] == '-')) negative = text[i++] == '-';
  bool before_point = true;
  for (; i < n; ++i) {
    const char c = text[i];
    if (c == '.') {
      if (!before_point) return std::nullopt;
      before_point = false;
      continue;
    }
    if (c < '0' || c > '9') break;
    any_digit = true;
    if (!started && c == '0') {
      if (!before_point) --point;
      continue;
    }
    started = true;
    if (kept < kKeep) digits[kept++] = static_cast<uint8_t>(c - '0');
    if (before_point) ++point;
  }
  if (!any_digit) return std::nullopt;
  if (i < n && (text[i] == 'e' || text[i] == 'E')) {
    ++i;
    bool exp_negative = false;
    if (i < n && (text[i] == '+' || text[i] == '-')) exp_negative = text[i++] == '-';
    if (i >= n || text[i] < '0' || text[i] > '9') return std::nullopt;
    long exponent = 0;
    for (; i < n && text[i] >= '0' && text[i] <= '9'; ++i) {
      if (exponent < 1'000'000) exponent = exponent * 10 + (text[i] - '0');
    }
    point += exp_negative ? -exponent : exponent;
  }
  if (i != n) return std::nullopt;
  if (!started) return Time{0};

  // ns = 0.d1 d2 ... x 10^(point + 9): the first `whole` digits, rounded by the next one.
  const long whole = point + 9;
  if (whole > 19) return std::nullopt;  // >= 10^19 ns, beyond int64
  uint64_t magnitude = 0;
  for (long k = 0; k < whole; ++k) magnitude = magnitude * 10 + (k < kept ? digits[k] : 0u);
  if (whole >= 0 && whole < kept && digits[whole] >= 5) ++magnitude;
  constexpr uint64_t kMax = static_cast<uint64_t>(std::numeric_limits<Time>::max());
  if (magnitude > kMax + (negative ? 1u : 0u)) return std::nullopt;
  if (negative) return magnitude == kMax + 1 ? std::numeric_limits<Time>::min()
                                             : -static_cast<Time>(magnitude);
  return static_cast<Time>(magnitude);
}

std::string FormatNanosecondsAsSeconds(Time t_ns) {
  const uint64_t a = t_ns < 0 ? uint64_t{0} - static_cast<uint64_t>(t_ns)
                              : static_cast<uint64_t>(t_ns);
  constexpr uint64_t kNs = static_cast<uint64_t>(core::kNanosecondsPerSecond);
  return fmt::format("{}{}.{:09d}", t_ns < 0 ? "-" : "", a / kNs, a % kNs);
}

std::vector<PoseSample> ReadTumTrajectory(const fs::path& file) {
  CsvReader reader(file, "t[s] x y z qx qy qz qw per line",
                   CsvOptions{.columns = kTumColumns, .whitespace_separated = true});
  std::vector<PoseSample> poses;
  poses.reserve(reader.RowsUpperBound());
  while (reader.Next()) {
    PoseSample s;
    const std::optional<Time> t = ParseSecondsAsNanoseconds(reader.Text(0));
    if (!t) {
      throw reader.Error(0, fmt::format("expected a time in seconds (decimal or scientific "
                                        "notation, finite, within the int64 ns range), got {}",
                                        CsvQuoted(reader.Text(0))));
    }
    s.t_ns = *t;
    std::array<double, 7> v{};
    for (int f = 1; f < static_cast<int>(kTumColumns.size()); ++f) v[f - 1] = reader.Number(f);
    s.p = Eigen::Vector3d(v[0], v[1], v[2]);
    s.q = Eigen::Quaterniond(v[6], v[3], v[4], v[5]);  // w, x, y, z
    const double norm = s.q.norm();
    if (std::isfinite(norm) && norm > 0.0) s.q.coeffs() /= norm;
    poses.push_back(s);
  }
  return poses;
}

void WriteTumTrajectory(const fs::path& file, const std::vector<PoseSample>& poses) {
  AtomicFileWriter out(file);
  for (const PoseSample& s : poses) {
    const Eigen::Quaterniond q = s.q.w() < 0.0 ? Eigen::Quaterniond(-s.q.coeffs()) : s.q;
    out.Format("{} {:.6f} {:.6f} {:.6f} {:.9f} {:.9f} {:.9f} {:.9f}\n",
               FormatNanosecondsAsSeconds(s.t_ns), s.p.x(), s.p.y(), s.p.z(), q.x(), q.y(), q.z(),
               q.w());
  }
  out.Commit();
}

// Long by design: match, align, then ATE and RPE over the same matched samples, in the
// order docs/RESULTS.md defines them (one pass each, no copy of an hour of outputs).
TrajectoryErrors EvaluateTrajectory(const std::vector<PoseSample>& estimate,
                                    const std::vector<PoseSample>& ground_truth,
                                    const TrajectoryErrorOptions& options) {
  TrajectoryErrors r;
  r.rpe_delta_s = core::TimeToSeconds(options.rpe_delta_ns);
  const TruthTrack gt(ground_truth);
  // The estimate finite, normalised and in time order: sorted already (an estimator's
  // outputs), its samples are taken one by one instead of from a sorted copy (46 MB for an
  // hour at 200 Hz), with the same result.
  const auto by_time = [](const PoseSample& a, const PoseSample& b) { return a.t_ns < b.t_ns; };
  const bool in_order = std::is_sorted(estimate.begin(), estimate.end(), by_time);
  std::vector<PoseSample> est;
  if (!in_order) est = SortedFinite(estimate, &r.skipped_non_finite);
  const std::vector<PoseSample>& est_source = in_order ? estimate : est;

  // Match every estimate sample with interpolated ground truth.
  Matches pairs(est_source, in_order, gt, options.max_interpolation_gap_ns);
  pairs.Reserve(est_source.size());
  for (std::size_t i = 0; i < est_source.size(); ++i) {
    const PoseSample& e = est_source[i];
    if (in_order && !IsFinite(e)) {
      ++r.skipped_non_finite;
      continue;
    }
    if (!gt.At(e.t_ns, options.max_interpolation_gap_ns)) {
      ++r.skipped_no_ground_truth;
      continue;
    }
    pairs.Add(i);
  }
  r.matched = pairs.size();

  r.T_WL = Align(pairs, options, &r.alignment_from_attitude, &r.aligned_on);

  // ATE and attitude error per matched sample.
  const Eigen::Matrix3d R_WL = r.T_WL.linear();
  r.t_ns.reserve(pairs.size());
  r.position_error_m.reserve(pairs.size());
  r.rotation_error_deg.reserve(pairs.size());
  r.position_step_max_m = kNaN;
  Eigen::Vector3d e_previous_W = Eigen::Vector3d::Zero();
  for (std::size_t k = 0; k < pairs.size(); ++k) {
    const PoseSample T_LI = pairs.estimate(k);
    const PoseSample T_WI = pairs.truth(k);
    const Eigen::Vector3d p_W = r.T_WL * T_LI.p;
    const Eigen::Matrix3d R_WI = R_WL * T_LI.q.toRotationMatrix();
    const Eigen::Vector3d e_W = p_W - T_WI.p;
    if (k > 0 && pairs.t_ns(k) - pairs.t_ns(k - 1) <= options.max_step_gap_ns) {
      const double step = (e_W - e_previous_W).norm();
      if (r.step_pairs == 0 || step > r.position_step_max_m) {
        r.position_step_max_m = step;
        r.position_step_max_t_ns = pairs.t_ns(k);
      }
      ++r.step_pairs;
    }
    e_previous_W = e_W;
    r.t_ns.push_back(pairs.t_ns(k));
    r.position_error_m.push_back(e_W.norm());
    r.rotation_error_deg.push_back(
        core::RotationAngleBetween(T_WI.q.toRotationMatrix(), R_WI) * kDegPerRad);
  }
  if (pairs.empty()) {
    r.ate_position_rmse_m = r.ate_position_mean_m = r.ate_position_median_m =
        r.ate_position_max_m = r.rotation_rmse_deg = r.rotation_max_deg = kNaN;
  } else {
    double sum = 0.0;
    for (const double e : r.position_error_m) sum += e;
    r.ate_position_rmse_m = Rms(r.position_error_m);
    r.ate_position_mean_m = sum / static_cast<double>(pairs.size());
    r.ate_position_median_m = Median(r.position_error_m);
    r.ate_position_max_m = *std::max_element(r.position_error_m.begin(), r.position_error_m.end());
    r.rotation_rmse_deg = Rms(r.rotation_error_deg);
    r.rotation_max_deg =
        *std::max_element(r.rotation_error_deg.begin(), r.rotation_error_deg.end());
  }

  // RPE over rpe_delta_ns: E = (T_true,i^-1 T_true,j)^-1 (T_est,i^-1 T_est,j).
  std::vector<double> rpe_translation;
  std::vector<double> rpe_rotation;
  if (options.rpe_delta_ns > 0) {
    // The matched times are sorted (matches keep the estimate's order): r.t_ns.
    for (size_t i = 0; i < pairs.size(); ++i) {
      const Time target = r.t_ns[i] + options.rpe_delta_ns;
      const auto it = std::lower_bound(r.t_ns.begin() + static_cast<std::ptrdiff_t>(i), r.t_ns.end(),
                                       target);
      if (it == r.t_ns.end()) break;
      if (*it - target > options.rpe_tolerance_ns) continue;
      const std::size_t j = static_cast<std::size_t>(it - r.t_ns.begin());
      const Eigen::Isometry3d d_true =
          ToIsometry(pairs.truth(i)).inverse() * ToIsometry(pairs.truth(j));
      const Eigen::Isometry3d d_est =
          ToIsometry(pairs.estimate(i)).inverse() * ToIsometry(pairs.estimate(j));
      const Eigen::Isometry3d E = d_true.inverse() * d_est;
      rpe_translation.push_back(E.translation().norm());
      rpe_rotation.push_back(core::LogSO3(E.linear()).norm() * kDegPerRad);
    }
  }
  r.rpe_pairs = rpe_translation.size();
  r.rpe_translation_rmse_m = Rms(rpe_translation);
  r.rpe_rotation_rmse_deg = Rms(rpe_rotation);
  return r;
}

}  // namespace tofu::replay
