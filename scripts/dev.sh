#!/usr/bin/env bash
# The two commands of README.md:
#   scripts/dev.sh demo   install what is missing, build, fly the default scenario, run
#                         the estimator on the real EuRoC excerpt (../shared/data)
#   scripts/dev.sh test   install what is missing, build, run the whole test suite
# Environment: BUILD_DIR (default build), TOFU_SANITIZE=1 for an ASan+UBSan build.
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$root"
build_dir="${BUILD_DIR:-build}"
jobs="$(nproc)"

build() {
  "$root/scripts/setup.sh"
  local sanitize=OFF build_type=Release
  if [[ "${TOFU_SANITIZE:-0}" == 1 ]]; then sanitize=ON; build_type=RelWithDebInfo; fi
  cmake -S "$root" -B "$build_dir" -G Ninja -DCMAKE_BUILD_TYPE="$build_type" \
    -DTOFU_SANITIZE="$sanitize"
  cmake --build "$build_dir" -j "$jobs"
}

case "${1:-}" in
  demo)
    build
    scenario="${2:-scenarios/figure_eight_arena.yaml}"
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
    echo "usage: scripts/dev.sh {demo [SCENARIO] | test}" >&2
    exit 2
    ;;
esac
