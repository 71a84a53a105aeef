#!/usr/bin/env bash
# `tofu export` against the reference MCAP reader (tests/node/check_mcap.mjs: @mcap/core,
# @foxglove/schemas): the MCAP of paper_consensus_indoor and of a closed-loop run (both
# flown by the scenario_check fixture) read without error, every message validates, the
# channel and message counts match the run directory; the file is smaller than the run's
# CSVs; the same run exports to the same bytes; the uncompressed variant reads too; bad
# input is exit 2 and an unwritable file exit 4, with no file left behind.
#   mcap_check.sh TOFU SOURCE_DIR CHECK_DIR WORK_DIR
set -euo pipefail
tofu="$1"
source_dir="$2"
check_dir="$3"
work="$4"
node_dir="$source_dir/tests/node"

fail() { echo "mcap_check: FAIL: $*" >&2; exit 1; }
command -v node > /dev/null || fail "node is not installed (scripts/setup.sh installs it)"
[[ -d "$node_dir/node_modules/@mcap/core" ]] ||
  fail "$node_dir/node_modules is missing: run scripts/setup.sh (npm ci from package-lock.json)"

rm -rf "$work"
mkdir -p "$work"

run_of() {
  local dir
  dir="$(find "$check_dir/$1" -mindepth 1 -maxdepth 1 -type d -name 'seed_*' | sort | head -n 1)"
  [[ -n "$dir" && -f "$dir/groundtruth.csv" ]] || fail "no run of $1 under $check_dir (scenario_check fixture)"
  echo "$dir"
}

for scenario in paper_consensus_indoor closed_loop_vio_divergence_wall; do
  run="$(run_of "$scenario")"
  mcap="$work/$scenario.mcap"
  "$tofu" export "$run" --mcap "$mcap" || fail "$scenario: tofu export exit $?"
  layout=()
  [[ $scenario == paper_consensus_indoor ]] && layout=("$source_dir/docs/foxglove_layout.json")
  (cd "$node_dir" && node check_mcap.mjs "$mcap" "$run" "${layout[@]}") ||
    fail "$scenario: the reference reader disagrees"
  csv_bytes=$(find "$run" -name '*.csv' -printf '%s\n' | awk '{s += $1} END {print s}')
  mcap_bytes=$(stat -c %s "$mcap")
  (( mcap_bytes < csv_bytes )) || fail "$scenario: MCAP $mcap_bytes bytes, CSVs $csv_bytes bytes"
  echo "mcap_check: $scenario: MCAP $mcap_bytes bytes, CSVs $csv_bytes bytes"
done

# Deterministic: the same run gives the same bytes.
run="$(run_of paper_consensus_indoor)"
"$tofu" export "$run" --mcap "$work/again.mcap" --quiet
cmp -s "$work/paper_consensus_indoor.mcap" "$work/again.mcap" || fail "two exports of one run differ"

# Stored chunks: read by the reference reader as well.
"$tofu" export "$run" --mcap "$work/stored.mcap" --uncompressed --quiet
(cd "$node_dir" && node check_mcap.mjs "$work/stored.mcap" "$run") || fail "uncompressed MCAP rejected"

# Not a run directory: exit 2, nothing written.
mkdir -p "$work/not_a_run"
set +e
"$tofu" export "$work/not_a_run" --mcap "$work/bad.mcap" 2> "$work/err.txt"
status=$?
set -e
[[ $status -eq 2 ]] || fail "export of a non-run directory: exit $status, expected 2"
grep -q "not_a_run" "$work/err.txt" || fail "the message does not name the directory: $(cat "$work/err.txt")"
[[ ! -e "$work/bad.mcap" && ! -e "$work/bad.mcap.partial" ]] || fail "a file was left behind"

# A malformed sensor row: exit 2 naming file:line and the column, nothing written.
cp -r "$run" "$work/bad_run"
vio_csv="$(ls "$work/bad_run/sensors/"*.csv | grep -v imu | head -n 1)"
lines=$(wc -l < "$vio_csv")
echo "oops,1,2,3" >> "$vio_csv"
set +e
"$tofu" export "$work/bad_run" --mcap "$work/bad.mcap" 2> "$work/err.txt"
status=$?
set -e
[[ $status -eq 2 ]] || fail "malformed sensor CSV: exit $status, expected 2"
grep -q "$(basename "$vio_csv"):$((lines + 1))" "$work/err.txt" ||
  fail "the message does not name $(basename "$vio_csv"):$((lines + 1)): $(cat "$work/err.txt")"
[[ ! -e "$work/bad.mcap" && ! -e "$work/bad.mcap.partial" ]] || fail "a file was left behind"

# An MCAP path in a directory that does not exist: exit 4 (I/O), nothing written.
set +e
"$tofu" export "$run" --mcap "$work/no/such/dir/x.mcap" 2> "$work/err.txt"
status=$?
set -e
[[ $status -eq 4 ]] || fail "unwritable MCAP path: exit $status, expected 4 ($(cat "$work/err.txt"))"
echo "mcap_check: ok"
