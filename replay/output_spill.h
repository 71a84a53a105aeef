#pragma once
// A method's estimator outputs in the order it produced them, kept on disk instead of in
// memory: a flight's in-loop method writes each output here as it produces it, and the
// scoring and the estimate files read them back in order once the flight is over. At 200 Hz
// an hour of outputs is 720 k of them (about 280 MB held as EstimatorOutput); spilled, the
// memory of a flight no longer grows with its length or with its number of methods
// (docs/BENCHMARKS.md, "Memory over flight time").
//
// The file is anonymous (O_TMPFILE) in the directory given: on the run's own file system,
// never a tmpfs; it has no name, so nothing is left behind whatever ends the process.
// Every field is stored bit for bit: what is read back equals what was written.

#include <cstddef>
#include <cstdint>
#include <filesystem>
#include <functional>
#include <memory>
#include <string>
#include <vector>

#include "estimator/multi_graph_estimator.h"

namespace tofu::replay {

class OutputSpill {
 public:
  /// Opens an anonymous file in `dir` (which exists). Throws core::IoError naming the
  /// directory when the file system cannot hold one.
  explicit OutputSpill(const std::filesystem::path& dir);
  ~OutputSpill();
  OutputSpill(const OutputSpill&) = delete;
  OutputSpill& operator=(const OutputSpill&) = delete;

  /// Appends one output (buffered). Throws core::IoError when the disk is full.
  void Append(const estimator::EstimatorOutput& output);
  std::size_t size() const { return count_; }
  /// Every output appended so far, in order, read back through a buffer of 64 kB.
  void ForEach(const std::function<void(const estimator::EstimatorOutput&)>& visit) const;

 private:
  void Flush() const;

  std::filesystem::path dir_;
  int fd_ = -1;
  std::size_t count_ = 0;
  mutable std::vector<char> pending_;  // appended, not yet written
  mutable std::uint64_t written_bytes_ = 0;
};

}  // namespace tofu::replay
