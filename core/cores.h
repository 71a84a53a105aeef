#pragma once
// How many processors this process may use: what `tofu run --threads` and `tofu check
// --jobs` default to.

namespace tofu::core {

/// The processors of this process's CPU affinity (taskset, a Slurm allocation, a container's
/// cpuset), at least 1; the machine's count where the affinity cannot be read. A Slurm task
/// given 2 of a node's 64 cores is 2 here, where std::thread::hardware_concurrency says 64.
int UsableCores();

}  // namespace tofu::core
