#pragma once
// `tofu corpus plan | generate | verify` (docs/CORPUS.md).
//
// A corpus directory holds corpus.yaml (the spec, which fixes what the directory is for),
// one HDF5 file per finished shard (shard_<I>_of_<N>.h5, with its manifest part
// shard_<I>_of_<N>.manifest.json), and, while a shard runs, .shard_<I>_of_<N>/ with its
// committed episodes (one small HDF5 file each, renamed into place when complete). A
// killed shard leaves its committed episodes; running the same shard again resumes after
// them, and assembles the shard file once all are there. `verify` checks the whole and
// writes manifest.csv, manifest.json and CARD.md.

#include <cstdint>
#include <filesystem>
#include <functional>
#include <optional>
#include <string>

#include "harness/shard.h"

namespace tofu::corpus {

// The shard of a `generate` (harness/shard.h: the same rule and sources as `tofu check`).
using harness::Shard;

struct GenerateOptions {
  std::filesystem::path spec;
  std::filesystem::path out_dir;
  Shard shard;
  bool quiet = false;
  /// After each episode flown now (not those resumed): (episodes done in this shard,
  /// episodes of this shard, seconds elapsed).
  std::function<void(std::uint64_t, std::uint64_t, double)> progress;
};

/// Writes each episode's scenario YAML to out_dir/episodes/<id>.yaml and the planned
/// label counts to out_dir/plan.json. Returns the exit code.
int RunCorpusPlan(const std::filesystem::path& spec, const std::filesystem::path& out_dir, bool quiet);
/// Generates (or resumes) one shard. Returns the exit code.
int RunCorpusGenerate(const GenerateOptions& options);
/// Checks a corpus directory; writes manifest.csv, manifest.json and CARD.md. Exit 0 when
/// every planned episode is present exactly once with matching content hashes and the
/// event tables agree with the masks, 1 otherwise (each problem printed).
int RunCorpusVerify(const std::filesystem::path& dir, bool quiet);

}  // namespace tofu::corpus
