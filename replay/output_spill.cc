#include "replay/output_spill.h"

#include <fcntl.h>
#include <unistd.h>

#include <cerrno>
#include <cstdlib>
#include <cstring>
#include <limits>

#include <fmt/format.h>

#include "core/error.h"

namespace tofu::replay {
namespace {

constexpr std::size_t kBufferBytes = 64 * 1024;

void Put(std::vector<char>& out, const void* data, std::size_t bytes) {
  const char* p = static_cast<const char*>(data);
  out.insert(out.end(), p, p + bytes);
}
template <typename T>
void PutValue(std::vector<char>& out, const T& value) {
  Put(out, &value, sizeof(T));
}
template <typename Derived>
void PutMatrix(std::vector<char>& out, const Eigen::MatrixBase<Derived>& m) {
  for (Eigen::Index i = 0; i < m.size(); ++i) PutValue(out, m.derived().data()[i]);
}

// Reads from a contiguous record; the writer's layout, field for field.
class RecordReader {
 public:
  RecordReader(const char* data, std::size_t size) : data_(data), size_(size) {}
  template <typename T>
  T Value() {
    T value;
    Take(&value, sizeof(T));
    return value;
  }
  template <typename Derived>
  void Matrix(Eigen::MatrixBase<Derived>& m) {
    for (Eigen::Index i = 0; i < m.size(); ++i) m.derived().data()[i] = Value<double>();
  }
  void Take(void* out, std::size_t bytes) {
    if (at_ + bytes > size_) throw core::IoError("output spill: record shorter than its fields");
    std::memcpy(out, data_ + at_, bytes);
    at_ += bytes;
  }

 private:
  const char* data_;
  std::size_t size_;
  std::size_t at_ = 0;
};

// One output as bytes: [u32 record size][fields]. The size prefix lets the reader find
// each record's end before decoding it.
void Encode(const estimator::EstimatorOutput& o, std::vector<char>& out) {
  const std::size_t start = out.size();
  PutValue(out, std::uint32_t{0});
  PutValue(out, o.t_ns);
  PutMatrix(out, o.state.q_LI.coeffs());
  PutMatrix(out, o.state.p_LI);
  PutMatrix(out, o.state.v_L_mps);
  PutMatrix(out, o.bias.accel_mps2);
  PutMatrix(out, o.bias.gyro_radps);
  PutMatrix(out, o.omega_I_radps);
  PutValue(out, static_cast<std::uint8_t>((o.initialized ? 1 : 0) | (o.valid ? 2 : 0) |
                                          (o.position_covariance_m2 ? 4 : 0) |
                                          (o.mission ? 8 : 0)));
  PutValue(out, static_cast<std::uint32_t>(o.fused.size()));
  for (const std::string& name : o.fused) {
    PutValue(out, static_cast<std::uint32_t>(name.size()));
    Put(out, name.data(), name.size());
  }
  if (o.position_covariance_m2) PutMatrix(out, *o.position_covariance_m2);
  if (o.mission) {
    PutMatrix(out, o.mission->p_ML_m);
    PutMatrix(out, o.mission->q_ML.coeffs());
    PutMatrix(out, o.mission->variance);
  }
  const auto bytes = static_cast<std::uint32_t>(out.size() - start);
  std::memcpy(out.data() + start, &bytes, sizeof(bytes));
}

estimator::EstimatorOutput Decode(RecordReader& in) {
  estimator::EstimatorOutput o;
  o.t_ns = in.Value<core::Time>();
  Eigen::Vector4d q;
  in.Matrix(q);
  o.state.q_LI.coeffs() = q;
  in.Matrix(o.state.p_LI);
  in.Matrix(o.state.v_L_mps);
  in.Matrix(o.bias.accel_mps2);
  in.Matrix(o.bias.gyro_radps);
  in.Matrix(o.omega_I_radps);
  const auto flags = in.Value<std::uint8_t>();
  o.initialized = (flags & 1) != 0;
  o.valid = (flags & 2) != 0;
  const auto fused = in.Value<std::uint32_t>();
  o.fused.resize(fused);
  for (std::string& name : o.fused) {
    name.resize(in.Value<std::uint32_t>());
    in.Take(name.data(), name.size());
  }
  if ((flags & 4) != 0) {
    Eigen::Matrix3d P;
    in.Matrix(P);
    o.position_covariance_m2 = P;
  }
  if ((flags & 8) != 0) {
    estimator::MissionFrameEstimate m;
    in.Matrix(m.p_ML_m);
    in.Matrix(m.q_ML.coeffs());
    in.Matrix(m.variance);
    o.mission = m;
  }
  return o;
}

}  // namespace

OutputSpill::OutputSpill(const std::filesystem::path& dir) : dir_(dir) {
  fd_ = ::open(dir.c_str(), O_TMPFILE | O_RDWR | O_CLOEXEC, 0600);
  if (fd_ < 0 && (errno == EOPNOTSUPP || errno == EISDIR)) {
    // A file system without O_TMPFILE (NFS, older kernels): a named file, unlinked at once,
    // so it has no name either once this constructor returns.
    std::string name = (dir / ".tofu-spill-XXXXXX").string();
    fd_ = ::mkostemp(name.data(), O_CLOEXEC);
    if (fd_ >= 0) ::unlink(name.c_str());
  }
  if (fd_ < 0) {
    throw core::IoError(fmt::format("cannot create the estimate spill file in {}: {}",
                                    dir.string(), std::strerror(errno)));
  }
  pending_.reserve(kBufferBytes + 4096);
}

OutputSpill::~OutputSpill() {
  if (fd_ >= 0) ::close(fd_);
}

void OutputSpill::Flush() const {
  std::size_t done = 0;
  while (done < pending_.size()) {
    const ssize_t n = ::pwrite(fd_, pending_.data() + done, pending_.size() - done,
                               static_cast<off_t>(written_bytes_ + done));
    if (n < 0 && errno == EINTR) continue;
    if (n <= 0) {
      throw core::IoError(fmt::format("cannot write the estimate spill file in {}: {}",
                                      dir_.string(), std::strerror(errno)));
    }
    done += static_cast<std::size_t>(n);
  }
  written_bytes_ += pending_.size();
  pending_.clear();
}

void OutputSpill::Append(const estimator::EstimatorOutput& output) {
  Encode(output, pending_);
  ++count_;
  if (pending_.size() >= kBufferBytes) Flush();
}

void OutputSpill::ForEach(const std::function<void(const estimator::EstimatorOutput&)>& visit) const {
  Flush();
  std::vector<char> buffer(kBufferBytes);
  std::size_t filled = 0;    // bytes of buffer holding data
  std::size_t at = 0;        // next record's start in buffer
  std::uint64_t offset = 0;  // file offset of buffer[filled]
  std::size_t visited = 0;
  while (visited < count_) {
    // A whole record at buffer[at]? Else move the rest to the front and read more.
    std::uint32_t bytes = 0;
    if (filled - at >= sizeof(bytes)) std::memcpy(&bytes, buffer.data() + at, sizeof(bytes));
    if (filled - at < sizeof(bytes) || filled - at < bytes) {
      std::memmove(buffer.data(), buffer.data() + at, filled - at);
      filled -= at;
      at = 0;
      if (bytes > buffer.size()) buffer.resize(bytes);
      const ssize_t n = ::pread(fd_, buffer.data() + filled, buffer.size() - filled,
                                static_cast<off_t>(offset));
      if (n < 0 && errno == EINTR) continue;
      if (n <= 0) {
        throw core::IoError(fmt::format("cannot read the estimate spill file in {}: {}",
                                        dir_.string(), n == 0 ? "ended early" : std::strerror(errno)));
      }
      filled += static_cast<std::size_t>(n);
      offset += static_cast<std::uint64_t>(n);
      continue;
    }
    if (bytes <= sizeof(bytes)) {
      throw core::IoError(fmt::format("the estimate spill file in {} is corrupt (record {})",
                                      dir_.string(), visited));
    }
    RecordReader record(buffer.data() + at + sizeof(bytes), bytes - sizeof(bytes));
    visit(Decode(record));
    at += bytes;
    ++visited;
  }
}

}  // namespace tofu::replay
