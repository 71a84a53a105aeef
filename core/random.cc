#include "core/random.h"

#include "core/digest.h"
#include "core/hash.h"

namespace tofu::core {
namespace {

uint64_t SplitMix64(uint64_t x) {
  x += 0x9e3779b97f4a7c15ULL;
  x = (x ^ (x >> 30)) * 0xbf58476d1ce4e5b9ULL;
  x = (x ^ (x >> 27)) * 0x94d049bb133111ebULL;
  return x ^ (x >> 31);
}

}  // namespace

uint64_t StreamSeed(uint64_t scenario_seed, std::string_view stream_name) {
  return SplitMix64(SplitMix64(scenario_seed) ^ Fnv1a64(stream_name));
}

namespace {
thread_local RandomStreamLedger* current_ledger = nullptr;
}  // namespace

RandomStreamLedger* RandomStreamLedger::Current() { return current_ledger; }

RandomStreamLedger::Scope::Scope(RandomStreamLedger& ledger) : previous_(current_ledger) {
  current_ledger = &ledger;
}

RandomStreamLedger::Scope::~Scope() { current_ledger = previous_; }

void RandomStreamLedger::Add(std::string_view stream_name, uint64_t seed) {
  seeds_.insert_or_assign(std::string(stream_name), seed);
}

uint64_t RandomStreamLedger::Digest() const {
  Fnv1a64Hasher hasher;
  for (const auto& [name, seed] : seeds_) hasher.Add(name).Add(uint64_t{name.size()}).Add(seed);
  return hasher.value();
}

RandomStream::RandomStream(uint64_t scenario_seed, std::string_view stream_name)
    : engine_(StreamSeed(scenario_seed, stream_name)) {
  if (current_ledger != nullptr) current_ledger->Add(stream_name, StreamSeed(scenario_seed, stream_name));
}

double RandomStream::Normal() { return normal_(engine_); }

Eigen::Vector3d RandomStream::Normal3() {
  Eigen::Vector3d v;
  v.z() = Normal();
  v.y() = Normal();
  v.x() = Normal();
  return v;
}

double RandomStream::Uniform(double lo, double hi) {
  return std::uniform_real_distribution<double>(lo, hi)(engine_);
}

}  // namespace tofu::core
