#!/usr/bin/env bash
# The two commands of README.md:
#   scripts/dev.sh demo [SCENARIO]   install what building and running tofu needs, build only
#                                    `tofu`, fly the default scenario (sensors, a scheduled
#                                    fault, the estimators in the loop, closed-loop flights on
#                                    their estimates), render its failure events, write its
#                                    HTML report and figures, run the estimator on the real
#                                    EuRoC excerpt (../shared/data), print where all of it is
#   scripts/dev.sh test [--sanitize] install everything, build everything, run the whole test
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
  if [[ $command == demo ]]; then
    # Only the CLI: the tests and benchmarks are the test command's (about half the build).
    "$root/scripts/setup.sh" --demo
    cmake -S "$root" -B "$build_dir" -G Ninja -DCMAKE_BUILD_TYPE=Release \
      -DTOFU_SANITIZE="$( ((sanitize)) && echo ON || echo OFF)" \
      -DTOFU_BUILD_TESTS=OFF -DTOFU_BUILD_BENCH=OFF
    cmake --build "$build_dir" -j "$jobs" --target tofu
    return
  fi
  "$root/scripts/setup.sh"
  if [[ $sanitize == 1 ]]; then
    # Benchmarks measure speed, which a sanitized build does not have: left out. Without
    # precompiled headers, a file that forgot an #include fails here.
    cmake -S "$root" -B "$build_dir" -G Ninja -DCMAKE_BUILD_TYPE=RelWithDebInfo \
      -DTOFU_SANITIZE=ON -DTOFU_BUILD_TESTS=ON -DTOFU_BUILD_BENCH=OFF \
      -DTOFU_PRECOMPILE_HEADERS=OFF
  else
    cmake -S "$root" -B "$build_dir" -G Ninja -DCMAKE_BUILD_TYPE=Release -DTOFU_SANITIZE=OFF \
      -DTOFU_BUILD_TESTS=ON -DTOFU_BUILD_BENCH=ON
  fi
  cmake --build "$build_dir" -j "$jobs"
}

case "$command" in
  demo)
    started=$SECONDS
    build
    scenario="${1:-scenarios/closed_loop_vio_divergence_wall.yaml}"
    out=runs/demo
    # 0: every expectation held, 1: one failed (still a flight worth looking at); any
    # other status is an error the demo cannot show past.
    run_status=0
    "$build_dir/tofu" run "$scenario" --out "$out" --force || run_status=$?
    ((run_status <= 1)) || exit "$run_status"
    "$build_dir/tofu" render "$out" --quiet
    "$build_dir/tofu" report "$out" --out "$out/report"
    # The estimator on real data: EuRoC V1_02 (IMU + a visual pose estimate), if present.
    euroc="$root/../shared/data/euroc_v1_02"
    if [[ -d "$euroc" ]]; then
      "$build_dir/tofu" estimate "$euroc" --out runs/euroc
      scripts/plot_estimate.py runs/euroc --out runs/euroc/estimate.png
    fi
    echo
    echo "demo: $scenario flown in $((SECONDS - started)) s, build included"
    for f in "$out/report/index.html" "$out/consensus.png" "$out/closed_loop.png" \
             "$out/renders" runs/euroc/estimate.png; do
      [[ -e "$f" ]] && echo "  $root/$f"
    done
    exit "$run_status"
    ;;
  test)
    build
    ctest --test-dir "$build_dir" --output-on-failure -j "$jobs"
    ;;
  *)
    usage
    ;;
esac
