#!/usr/bin/env bash
# The two commands of README.md:
#   scripts/dev.sh demo              install what is missing, build, fly the default
#                                    scenario, run the estimator on the real EuRoC excerpt
#                                    (../shared/data)
#   scripts/dev.sh test [--sanitize] install what is missing, build, run the whole test
#                                    suite; --sanitize: in an ASan + UBSan build
# Environment: BUILD_DIR (default build, build-asan when sanitizing), TOFU_SANITIZE=1 (the
# same as --sanitize, for both commands).
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$root"
jobs="$(nproc)"

usage() {
  echo "usage: scripts/dev.sh {demo [SCENARIO] | test [--sanitize]}" >&2
  exit 2
}

command="${1:-}"
[[ $# -gt 0 ]] && shift
sanitize=0
[[ "${TOFU_SANITIZE:-0}" == 1 ]] && sanitize=1
if [[ "$command" == test ]]; then
  for arg in "$@"; do
    case "$arg" in
      --sanitize) sanitize=1 ;;
      *) usage ;;
    esac
  done
fi
if [[ $sanitize == 1 ]]; then
  # Its own tree: a sanitized build never replaces the normal one.
  build_dir="${BUILD_DIR:-build-asan}"
  # UBSan stops at the first finding (with its stack) so that ctest fails on it; ASan
  # halts by default. Leak detection is off: MuJoCo, Mesa's EGL and Ceres keep
  # process-lifetime allocations that LeakSanitizer reports as leaks at every exit.
  export UBSAN_OPTIONS="${UBSAN_OPTIONS:-halt_on_error=1:print_stacktrace=1}"
  export ASAN_OPTIONS="${ASAN_OPTIONS:-detect_leaks=0}"
else
  build_dir="${BUILD_DIR:-build}"
fi

build() {
  "$root/scripts/setup.sh"
  if [[ $sanitize == 1 ]]; then
    # Benchmarks measure speed, which a sanitized build does not have: left out.
    cmake -S "$root" -B "$build_dir" -G Ninja -DCMAKE_BUILD_TYPE=RelWithDebInfo \
      -DTOFU_SANITIZE=ON -DTOFU_BUILD_BENCH=OFF
  else
    cmake -S "$root" -B "$build_dir" -G Ninja -DCMAKE_BUILD_TYPE=Release -DTOFU_SANITIZE=OFF
  fi
  cmake --build "$build_dir" -j "$jobs"
}

case "$command" in
  demo)
    build
    scenario="${1:-scenarios/figure_eight_arena.yaml}"
    "$build_dir/tofu" run "$scenario" --out runs/demo --force
    # A picture of the flight: path against the reference, tracking errors.
    scripts/plot_run.py runs/demo --out runs/demo/tracking.png
    # The estimator on real data: EuRoC V1_02 (IMU + a visual pose estimate), if present.
    euroc="$root/../shared/data/euroc_v1_02"
    if [[ -d "$euroc" ]]; then
      "$build_dir/tofu" estimate "$euroc" --out runs/euroc
      scripts/plot_estimate.py runs/euroc --out runs/euroc/estimate.png
    fi
    ;;
  test)
    build
    ctest --test-dir "$build_dir" --output-on-failure -j "$jobs"
    ;;
  *)
    usage
    ;;
esac
