// replay/output_spill: what a flight's in-loop method writes as it produces outputs is read
// back bit for bit, in order, leaving nothing in the directory.
#include "replay/output_spill.h"

#include <gtest/gtest.h>

#include <cstring>
#include <filesystem>
#include <random>
#include <string>
#include <vector>

#include "core/error.h"

namespace tofu::replay {
namespace {

namespace fs = std::filesystem;

fs::path FreshDir(const std::string& name) {
  const fs::path dir = fs::temp_directory_path() / ("tofu_output_spill_" + name);
  fs::remove_all(dir);
  fs::create_directories(dir);
  return dir;
}

template <typename Derived>
void Randomize(Eigen::MatrixBase<Derived>& m, std::mt19937_64& rng) {
  std::normal_distribution<double> normal(0.0, 10.0);
  for (Eigen::Index i = 0; i < m.size(); ++i) m.derived().data()[i] = normal(rng);
}

// Outputs with every optional part present or not, fused lists of varied lengths (one
// longer than the reader's 64 kB buffer), and values that are not round in any base.
std::vector<estimator::EstimatorOutput> SomeOutputs(std::size_t n) {
  std::mt19937_64 rng(7);
  std::vector<estimator::EstimatorOutput> outputs(n);
  for (std::size_t i = 0; i < n; ++i) {
    estimator::EstimatorOutput& o = outputs[i];
    o.t_ns = static_cast<core::Time>(i) * 5'000'000 + static_cast<core::Time>(rng() % 1000);
    Randomize(o.state.q_LI.coeffs(), rng);
    Randomize(o.state.p_LI, rng);
    Randomize(o.state.v_L_mps, rng);
    Randomize(o.bias.accel_mps2, rng);
    Randomize(o.bias.gyro_radps, rng);
    Randomize(o.omega_I_radps, rng);
    o.initialized = i % 3 != 0;
    o.valid = i % 4 == 1;
    for (std::size_t k = 0; k < i % 4; ++k) o.fused.push_back(std::string(k * 7 + 1, char('a' + k)));
    if (i == n / 2) o.fused.push_back(std::string(100'000, 'x'));
    if (i % 2 == 0) {
      Eigen::Matrix3d P;
      Randomize(P, rng);
      o.position_covariance_m2 = P;
    }
    if (i % 5 == 0) {
      estimator::MissionFrameEstimate m;
      Randomize(m.p_ML_m, rng);
      Randomize(m.q_ML.coeffs(), rng);
      Randomize(m.variance, rng);
      o.mission = m;
    }
  }
  return outputs;
}

template <typename A, typename B>
bool SameBits(const A& a, const B& b) {
  return a.size() == b.size() && std::memcmp(a.data(), b.data(), sizeof(double) * a.size()) == 0;
}

void ExpectSame(const estimator::EstimatorOutput& a, const estimator::EstimatorOutput& b) {
  EXPECT_EQ(a.t_ns, b.t_ns);
  EXPECT_TRUE(SameBits(a.state.q_LI.coeffs(), b.state.q_LI.coeffs()));
  EXPECT_TRUE(SameBits(a.state.p_LI, b.state.p_LI));
  EXPECT_TRUE(SameBits(a.state.v_L_mps, b.state.v_L_mps));
  EXPECT_TRUE(SameBits(a.bias.accel_mps2, b.bias.accel_mps2));
  EXPECT_TRUE(SameBits(a.bias.gyro_radps, b.bias.gyro_radps));
  EXPECT_TRUE(SameBits(a.omega_I_radps, b.omega_I_radps));
  EXPECT_EQ(a.initialized, b.initialized);
  EXPECT_EQ(a.valid, b.valid);
  EXPECT_EQ(a.fused, b.fused);
  ASSERT_EQ(a.position_covariance_m2.has_value(), b.position_covariance_m2.has_value());
  if (a.position_covariance_m2) {
    EXPECT_TRUE(SameBits(*a.position_covariance_m2, *b.position_covariance_m2));
  }
  ASSERT_EQ(a.mission.has_value(), b.mission.has_value());
  if (a.mission) {
    EXPECT_TRUE(SameBits(a.mission->p_ML_m, b.mission->p_ML_m));
    EXPECT_TRUE(SameBits(a.mission->q_ML.coeffs(), b.mission->q_ML.coeffs()));
    EXPECT_TRUE(SameBits(a.mission->variance, b.mission->variance));
  }
}

std::vector<estimator::EstimatorOutput> ReadBack(const OutputSpill& spill) {
  std::vector<estimator::EstimatorOutput> read;
  spill.ForEach([&](const estimator::EstimatorOutput& o) { read.push_back(o); });
  return read;
}

TEST(OutputSpill, ReadsBackEveryOutputBitForBitInOrder) {
  const fs::path dir = FreshDir("round_trip");
  const std::vector<estimator::EstimatorOutput> outputs = SomeOutputs(3000);  // several buffers
  OutputSpill spill(dir);
  for (const estimator::EstimatorOutput& o : outputs) spill.Append(o);
  EXPECT_EQ(spill.size(), outputs.size());
  const std::vector<estimator::EstimatorOutput> read = ReadBack(spill);
  ASSERT_EQ(read.size(), outputs.size());
  for (std::size_t i = 0; i < read.size(); ++i) {
    SCOPED_TRACE(i);
    ExpectSame(read[i], outputs[i]);
  }
  // The file has no name: the directory stays empty while it is in use.
  EXPECT_TRUE(fs::is_empty(dir));
  fs::remove_all(dir);
}

TEST(OutputSpill, AppendsAfterAReadAndReadsAgain) {
  const fs::path dir = FreshDir("append_after_read");
  const std::vector<estimator::EstimatorOutput> outputs = SomeOutputs(40);
  OutputSpill spill(dir);
  for (std::size_t i = 0; i < 25; ++i) spill.Append(outputs[i]);
  EXPECT_EQ(ReadBack(spill).size(), 25u);
  for (std::size_t i = 25; i < outputs.size(); ++i) spill.Append(outputs[i]);
  const std::vector<estimator::EstimatorOutput> read = ReadBack(spill);
  ASSERT_EQ(read.size(), outputs.size());
  for (std::size_t i = 0; i < read.size(); ++i) {
    SCOPED_TRACE(i);
    ExpectSame(read[i], outputs[i]);
  }
  fs::remove_all(dir);
}

TEST(OutputSpill, NamesTheDirectoryItCannotUse) {
  const fs::path missing = fs::temp_directory_path() / "tofu_output_spill_no_such_dir";
  fs::remove_all(missing);
  try {
    OutputSpill spill(missing);
    FAIL() << "expected core::IoError";
  } catch (const core::IoError& e) {
    EXPECT_NE(std::string(e.what()).find(missing.string()), std::string::npos) << e.what();
  }
}

}  // namespace
}  // namespace tofu::replay
