#!/usr/bin/env bash
# Fuzzes tofu's readers with libFuzzer (docs/FUZZING.md): configures and builds the fuzz
# build directory (clang, -DTOFU_FUZZ=ON: ASan + UBSan + coverage), then runs each target
# of fuzz/ for SECONDS on a fresh corpus of its seeds (fuzz/seeds/<target>/ plus the
# project's own files: scenarios, corpus specs, excerpts of ../shared/data/euroc_v1_02),
# prints each target's executions per second and final coverage and a summary table, and
# fails on any finding.
#
# Usage: scripts/fuzz.sh SECONDS [TARGET...]
#   SECONDS   run time per target (-max_total_time), a positive integer
#   TARGET    fuzz_scenario, fuzz_calibration, ... (default: every target of fuzz/)
# Environment:
#   BUILD_DIR   the fuzz build directory (default build-fuzz)
#   JOBS        build parallelism (default 1)
#   CXX_FUZZ    the clang C++ compiler (default clang++-14, else clang++)
#   FUZZ_TMPDIR where the targets write their scratch files (default /dev/shm/tofu-fuzz-PID
#               when /dev/shm is writable, else BUILD_DIR/tmp)
#   KEEP_CORPUS=1  keep BUILD_DIR/corpus/<target> of an earlier run instead of starting
#               from the seeds again (longer campaigns in steps)
#   KEEP_GOING=1   fuzz on after a finding (libFuzzer's -fork=1 with -ignore_crashes,
#               -ignore_timeouts, -ignore_ooms): every finding of the run is kept as an
#               artifact and the run still fails; for measuring a target whose known,
#               unfixed finding would otherwise stop it within seconds. Fork mode counts
#               coverage differently (its cov: is not comparable with a plain run's).
#               KEEP_GOING="fuzz_calibration ..." does so for the targets named only.
# Outputs, per target: BUILD_DIR/artifacts/<target>/ (crash-*, leak-*, timeout-*, oom-*
# reproducers; emptied at the start of the target's run), BUILD_DIR/logs/<target>.log
# (libFuzzer's output), BUILD_DIR/corpus/<target>/; BUILD_DIR/fuzz_summary.txt (the table).
# Reproduce a finding: BUILD_DIR/fuzz/<target> BUILD_DIR/artifacts/<target>/crash-...
#
# Exit codes: 0 every target ran clean; 1 a finding (an artifact or a non-zero libFuzzer
# exit) in at least one target; 2 bad usage (SECONDS not a positive integer, an unknown
# target); 3 the build failed or a tool is missing (clang, libFuzzer, cmake, ninja).
set -uo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$root"

usage() {
  sed -n '/^# Usage:/,/^#   TARGET/p' "$0" | sed 's/^# \{0,1\}//' >&2
  exit 2
}

all_targets=(fuzz_scenario fuzz_calibration fuzz_run_directory fuzz_euroc_imu
             fuzz_euroc_groundtruth fuzz_tum fuzz_velocity_csv fuzz_corpus_spec
             fuzz_search_spec fuzz_client_message)

[[ $# -ge 1 ]] || usage
seconds="$1"
shift
[[ "$seconds" =~ ^[1-9][0-9]*$ ]] || { echo "fuzz.sh: SECONDS must be a positive integer, got '$seconds'" >&2; usage; }
targets=("$@")
((${#targets[@]} > 0)) || targets=("${all_targets[@]}")
for t in "${targets[@]}"; do
  if [[ " ${all_targets[*]} " != *" $t "* ]]; then
    echo "fuzz.sh: unknown target '$t'; expected one of: ${all_targets[*]}" >&2
    exit 2
  fi
done

build_dir="${BUILD_DIR:-build-fuzz}"
[[ "$build_dir" = /* ]] || build_dir="$root/$build_dir"
jobs="${JOBS:-1}"
cxx="${CXX_FUZZ:-}"
if [[ -z "$cxx" ]]; then
  if command -v clang++-14 > /dev/null; then cxx=clang++-14; else cxx=clang++; fi
fi
cc="${cxx/clang++/clang}"
for tool in "$cxx" "$cc" cmake ninja; do
  command -v "$tool" > /dev/null || { echo "fuzz.sh: '$tool' not found (scripts/setup.sh)" >&2; exit 3; }
done

# ---- build ----
echo "fuzz.sh: building the fuzz targets in $build_dir ($cxx, ASan + UBSan + libFuzzer)"
# RelWithDebInfo without NDEBUG: -O1 -g, asserts (tofu's and Eigen's) stay on.
if ! nice -n 10 cmake -S "$root" -B "$build_dir" -G Ninja -DCMAKE_BUILD_TYPE=RelWithDebInfo \
    -DCMAKE_CXX_FLAGS_RELWITHDEBINFO="-O1 -g" -DCMAKE_C_FLAGS_RELWITHDEBINFO="-O1 -g" \
    -DCMAKE_CXX_COMPILER="$cxx" -DCMAKE_C_COMPILER="$cc" -DTOFU_FUZZ=ON \
    -DTOFU_BUILD_TESTS=OFF -DTOFU_BUILD_BENCH=OFF > "$build_dir.configure.log" 2>&1; then
  cat "$build_dir.configure.log" >&2
  echo "fuzz.sh: cmake configure failed" >&2
  exit 3
fi
rm -f "$build_dir.configure.log"
if ! nice -n 10 cmake --build "$build_dir" -j "$jobs" --target "${targets[@]}"; then
  echo "fuzz.sh: build failed" >&2
  exit 3
fi

# ---- seeds ----
euroc="$root/../shared/data/euroc_v1_02"
# An excerpt of a large file: its first 20000 bytes, cut at the last whole line.
excerpt() { head -c 20000 "$1" | awk 'BEGIN{RS="\n"; ORS="\n"} {lines[NR]=$0} END{for(i=1;i<NR;i++) print lines[i]; if (NR==1) print lines[1]}'; }
seed() {  # seed TARGET CORPUS_DIR: fills CORPUS_DIR with the target's seeds
  local t="$1" dir="$2" f
  [[ -d "$root/fuzz/seeds/$t" ]] && cp "$root/fuzz/seeds/$t"/* "$dir"/ 2> /dev/null
  case "$t" in
    fuzz_scenario)
      for f in "$root"/scenarios/*.yaml "$root"/scenarios/bench/*.yaml \
               "$root"/tests/data/scenarios/*.yaml "$root"/tests/data/closed_loop_run/scenario.yaml; do
        [[ -f "$f" ]] && cp "$f" "$dir/project_$(basename "$(dirname "$f")")_$(basename "$f")"
      done ;;
    fuzz_corpus_spec)
      for f in "$root"/corpora/*.yaml; do cp "$f" "$dir/project_$(basename "$f")"; done ;;
    fuzz_search_spec)
      for f in "$root"/tests/data/search/*_search.yaml; do cp "$f" "$dir/project_$(basename "$f")"; done ;;
    fuzz_euroc_imu)
      [[ -f "$euroc/mav0/imu0/data.csv" ]] && excerpt "$euroc/mav0/imu0/data.csv" > "$dir/shared_euroc_imu0.csv" ;;
    fuzz_euroc_groundtruth)
      [[ -f "$euroc/mav0/state_groundtruth_estimate0/data.csv" ]] &&
        excerpt "$euroc/mav0/state_groundtruth_estimate0/data.csv" > "$dir/shared_euroc_groundtruth.csv" ;;
    fuzz_tum)
      [[ -f "$euroc/pose_estimate.tum" ]] && excerpt "$euroc/pose_estimate.tum" > "$dir/shared_euroc_pose_estimate.tum" ;;
  esac
  return 0
}
# A dictionary: the committed one of the target's format, plus (YAML targets) every key
# and identifier of the target's seeds, so that strict readers get past unknown-key errors.
dictionary() {  # dictionary TARGET CORPUS_DIR OUT
  local t="$1" dir="$2" out="$3"
  case "$t" in
    fuzz_scenario|fuzz_calibration|fuzz_corpus_spec|fuzz_search_spec)
      cp "$root/fuzz/dicts/yaml.dict" "$out"
      cat "$dir"/* | grep -oE '[A-Za-z_][A-Za-z0-9_]{2,}' | sort -u | sed 's/.*/"&"/' >> "$out" ;;
    fuzz_client_message) cp "$root/fuzz/dicts/client_message.dict" "$out" ;;
    *) cp "$root/fuzz/dicts/csv.dict" "$out" ;;
  esac
}
max_len() {
  case "$1" in
    fuzz_scenario) echo 16384 ;;
    fuzz_calibration|fuzz_corpus_spec|fuzz_search_spec) echo 8192 ;;
    *) echo 20480 ;;
  esac
}

# ---- run ----
export ASAN_OPTIONS="abort_on_error=1:detect_leaks=1:detect_stack_use_after_return=1:strict_string_checks=1:check_initialization_order=1:symbolize=1"
export UBSAN_OPTIONS="halt_on_error=1:abort_on_error=1:print_stacktrace=1:symbolize=1"
mkdir -p "$build_dir/logs"
# The targets' scratch files (the input written once per execution): on a tmpfs when there
# is one, since on a busy disk the file-based targets wait on I/O (fuzz_tum ran at 252
# exec/s with its scratch in the build directory and ~10x that on /dev/shm).
scratch_root="${FUZZ_TMPDIR:-}"
if [[ -z "$scratch_root" ]]; then
  if [[ -d /dev/shm && -w /dev/shm ]]; then scratch_root="/dev/shm/tofu-fuzz-$$"; else scratch_root="$build_dir/tmp"; fi
fi
trap 'rm -rf "/dev/shm/tofu-fuzz-$$"' EXIT
summary="$build_dir/fuzz_summary.txt"
rows=()
failed=()
for t in "${targets[@]}"; do
  corpus="$build_dir/corpus/$t"
  artifacts="$build_dir/artifacts/$t"
  tmp="$scratch_root/$t"
  log="$build_dir/logs/$t.log"
  dict="$build_dir/dicts/$t.dict"
  if [[ "${KEEP_CORPUS:-0}" != 1 ]]; then rm -rf "$corpus"; fi
  rm -rf "$artifacts" "$tmp"
  mkdir -p "$corpus" "$artifacts" "$tmp" "$build_dir/dicts"
  seed "$t" "$corpus"
  dictionary "$t" "$corpus" "$dict"
  echo "fuzz.sh: $t for ${seconds}s ($(ls "$corpus" | wc -l) seeds)"
  mode=()
  keep_going="${KEEP_GOING:-0}"
  if [[ "$keep_going" == 1 || " $keep_going " == *" $t "* ]]; then
    mode=(-fork=1 -ignore_crashes=1 -ignore_timeouts=1 -ignore_ooms=1)
  fi
  started=$SECONDS
  TMPDIR="$tmp" nice -n 10 "$build_dir/fuzz/$t" "$corpus" -max_total_time="$seconds" \
    -max_len="$(max_len "$t")" -timeout=10 -rss_limit_mb=2048 -dict="$dict" \
    -artifact_prefix="$artifacts/" -print_final_stats=1 "${mode[@]}" > "$log" 2>&1
  status=$?
  ran=$((SECONDS - started))  # wall time of the run: less than SECONDS when a finding stops it
  rm -rf "$tmp"
  # The last status line ("#N DONE cov: C ft: F corp: K/S exec/s: E rss: R"; fork mode:
  # "#N: cov: C ft: F corp: K exec/s E oom/timeout/crash: ... time: T job: J") and the
  # final stats (plain mode only).
  last="$(grep -E '^#[0-9]+:?[[:space:]]+(INITED|NEW|REDUCE|pulse|DONE|RELOAD|cov:)' "$log" | tail -n 1)"
  field() { sed -nE "s/.* $1:? ([^ ]+).*/\1/p" <<< "$last"; }
  runs="$(sed -nE 's/^stat::number_of_executed_units: *([0-9]+)/\1/p' "$log" | tail -n 1)"
  eps="$(sed -nE 's/^stat::average_exec_per_sec: *([0-9]+)/\1/p' "$log" | tail -n 1)"
  rss="$(sed -nE 's/^stat::peak_rss_mb: *([0-9]+)/\1/p' "$log" | tail -n 1)"
  if [[ -z "$runs" && -n "$last" ]]; then  # fork mode: runs and exec/s of the whole run
    runs="$(sed -nE 's/^#([0-9]+).*/\1/p' <<< "$last")"
    elapsed="$(sed -nE 's/.* time: ([0-9]+)s.*/\1/p' <<< "$last")"
    ((${elapsed:-0} > 0)) && eps=$((runs / elapsed))
  fi
  found=$(find "$artifacts" -type f \( -name 'crash-*' -o -name 'leak-*' -o -name 'timeout-*' \
            -o -name 'oom-*' \) | wc -l)
  if ((status != 0 || found > 0)); then
    result="FINDING (exit $status, $found artifact(s) in ${artifacts#$root/}/)"
    ((${#mode[@]} > 0)) && result="$result, fork mode"
    failed+=("$t")
    grep -m 1 -E '==tofu-fuzz== FINDING|ERROR: (AddressSanitizer|LeakSanitizer|libFuzzer)|runtime error:' "$log" | sed 's/^/  /'
  else
    result="clean"
  fi
  echo "  $t: ${ran}s, ${eps:-?} exec/s, ${runs:-?} runs, cov: $(field cov) ft: $(field ft) corp: $(field corp), peak rss ${rss:-?} MB: $result"
  rows+=("$(printf '%-24s %6s %10s %8s %7s %7s %12s %6s  %s' "$t" "$ran" "${runs:-?}" \
            "${eps:-?}" "$(field cov)" "$(field ft)" "$(field corp)" "${rss:-?}" "$result")")
done

{
  echo "tofu fuzz run: $(date -u +%Y-%m-%dT%H:%M:%SZ), ${seconds}s per target (time_s: wall time run), $(nproc) cores," \
       "$(grep -m 1 'model name' /proc/cpuinfo | sed 's/.*: //'), $("$cxx" --version | head -n 1)"
  printf '%-24s %6s %10s %8s %7s %7s %12s %6s  %s\n' target "time_s" runs "exec/s" cov ft corp rss_mb result
  printf '%s\n' "${rows[@]}"
} > "$summary"
echo
cat "$summary"
if ((${#failed[@]} > 0)); then
  echo "fuzz.sh: findings in ${failed[*]} (reproducers in ${build_dir#$root/}/artifacts/)" >&2
  exit 1
fi
echo "fuzz.sh: clean"
