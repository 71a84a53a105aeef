#!/usr/bin/env bash
# Behaviour unchanged? Runs each scenario with two tofu binaries (a build before a change
# and one after) and compares the run directories file by file, byte for byte; then the
# same for `tofu estimate` on three of those runs and on the EuRoC excerpt when
# ../shared/data has it.
#
#   scripts/compare_runs.sh OLD_TOFU NEW_TOFU [SCENARIO.yaml ...]
#
# Default scenarios: scenarios/*.yaml. Left out of the comparison: timing*.json (wall
# clock) and *.png (matplotlib figures). Prints one line per run and the differing files;
# exit 0 when every run directory is identical, 1 otherwise, 2 on bad usage.
set -uo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
if [[ $# -lt 2 || ! -x "$1" || ! -x "$2" ]]; then
  echo "usage: scripts/compare_runs.sh OLD_TOFU NEW_TOFU [SCENARIO.yaml ...]" >&2
  exit 2
fi
old="$(realpath "$1")"
new="$(realpath "$2")"
shift 2
if [[ $# -gt 0 ]]; then
  scenarios=("$@")
else
  scenarios=("$root"/scenarios/*.yaml)
fi
work="$(mktemp -d "${TMPDIR:-/tmp}/tofu_compare.XXXXXX")"
trap 'rm -rf "$work"' EXIT
status=0

compare() {  # name, old dir, new dir, old exit, new exit
  local differing
  differing=$(diff -rq -x 'timing*.json' -x '*.png' "$2" "$3" 2>&1)
  if [[ "$4" != "$5" || -n "$differing" ]]; then
    echo "DIFFERS   $1 (exit $4 -> $5)"
    [[ -n "$differing" ]] && sed 's/^/          /' <<<"$differing"
    status=1
  else
    echo "identical $1 (exit $4, $(find "$2" -type f | wc -l) files)"
  fi
}

for scenario in "${scenarios[@]}"; do
  name="$(basename "$scenario" .yaml)"
  (cd "$root" && "$old" run "$scenario" --out "$work/old/$name" --quiet --force >/dev/null 2>&1)
  a=$?
  (cd "$root" && "$new" run "$scenario" --out "$work/new/$name" --quiet --force >/dev/null 2>&1)
  b=$?
  compare "$name" "$work/old/$name" "$work/new/$name" "$a" "$b"
done

# `tofu estimate` on recorded runs (the old binary's run directory, read by both): the
# first three with an IMU stream, which read calibration.yaml and every sensor CSV.
estimated=0
for scenario in "${scenarios[@]}"; do
  name="$(basename "$scenario" .yaml)"
  [[ -f "$work/old/$name/sensors/imu.csv" && $estimated -lt 3 ]] || continue
  estimated=$((estimated + 1))
  "$old" estimate "$work/old/$name" --out "$work/old/estimate_$name" >/dev/null 2>&1
  a=$?
  "$new" estimate "$work/old/$name" --out "$work/new/estimate_$name" >/dev/null 2>&1
  b=$?
  compare "estimate $name" "$work/old/estimate_$name" "$work/new/estimate_$name" "$a" "$b"
done

euroc="$root/../shared/data/euroc_v1_02"
if [[ -d "$euroc" ]]; then
  "$old" estimate "$euroc" --out "$work/old/euroc" >/dev/null 2>&1
  a=$?
  "$new" estimate "$euroc" --out "$work/new/euroc" >/dev/null 2>&1
  b=$?
  compare "estimate euroc_v1_02" "$work/old/euroc" "$work/new/euroc" "$a" "$b"
fi
exit $status
