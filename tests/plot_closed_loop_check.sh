#!/usr/bin/env bash
# scripts/plot_closed_loop.py on the run directory tests/data/closed_loop_run (two
# closed-loop flights of closed_loop_vio_divergence_wall, subsampled): it writes a PNG
# (default RUN_DIR/closed_loop.png, or --out), still draws when files are missing, and
# rejects a malformed CSV naming file:line and the column with exit 2 and no PNG.
#   plot_closed_loop_check.sh SOURCE_DIR WORK_DIR
set -euo pipefail
source_dir="$1"
work="$2"
script="$source_dir/scripts/plot_closed_loop.py"
fixture="$source_dir/tests/data/closed_loop_run"

fail() { echo "plot_closed_loop_check: FAIL: $*" >&2; exit 1; }
is_png() { [[ -s "$1" ]] && [[ "$(head -c 8 "$1" | od -An -tx1 | tr -d ' \n')" == "89504e470d0a1a0a" ]]; }

rm -rf "$work"
mkdir -p "$work"

cp -r "$fixture" "$work/full"
"$script" "$work/full" || fail "exit $? on the full fixture"
is_png "$work/full/closed_loop.png" || fail "no PNG at $work/full/closed_loop.png"
"$script" "$work/full" --out "$work/full.png" || fail "exit $? with --out"
is_png "$work/full.png" || fail "no PNG at $work/full.png"
(( $(stat -c %s "$work/full.png") > 40000 )) || fail "$work/full.png is suspiciously small"

# Missing files: a flight's folder, the labels, the world: what exists is drawn, exit 0.
cp -r "$fixture" "$work/partial"
rm -r "$work/partial/closed_loop/naive"
rm "$work/partial/labels.csv" "$work/partial/scenario.yaml"
"$script" "$work/partial" || fail "exit $? with files missing"
is_png "$work/partial/closed_loop.png" || fail "no PNG with files missing"
mkdir -p "$work/empty"
"$script" "$work/empty" || fail "exit $? on an empty directory"

# A malformed number: exit 2, file:line and the column named, no PNG.
cp -r "$fixture" "$work/bad"
control="$work/bad/closed_loop/consensus/control.csv"
lines=$(wc -l < "$control")
echo "40000000000,estimate,1,2,3,1,2,3,1,2,3,oops,0.1,0.5" >> "$control"
set +e
"$script" "$work/bad" 2> "$work/bad.err"
status=$?
set -e
[[ $status -eq 2 ]] || fail "malformed control.csv: exit $status, expected 2"
grep -q "control.csv:$((lines + 1)): column 'tracking_error'" "$work/bad.err" ||
  fail "message does not name control.csv:$((lines + 1)) and the column: $(cat "$work/bad.err")"
[[ ! -e "$work/bad/closed_loop.png" ]] || fail "a PNG was written despite the malformed CSV"

# An unknown flight mode, and a row with too few fields.
cp -r "$fixture" "$work/mode"
echo "40000000000,cruise,1,2,3,1,2,3,1,2,3,0.1,0.1,0.5" >> "$work/mode/closed_loop/naive/control.csv"
set +e
"$script" "$work/mode" 2> "$work/mode.err"
status=$?
set -e
[[ $status -eq 2 ]] || fail "unknown mode: exit $status, expected 2"
grep -q "column 'mode'" "$work/mode.err" || fail "unknown mode not named: $(cat "$work/mode.err")"
cp -r "$fixture" "$work/short"
echo "5000000000,handover" >> "$work/short/closed_loop/naive/events.csv"
set +e
"$script" "$work/short" 2> "$work/short.err"
status=$?
set -e
[[ $status -eq 2 ]] || fail "short events.csv row: exit $status, expected 2"
grep -q "events.csv:[0-9]*: expected 3 fields" "$work/short.err" ||
  fail "message does not name events.csv:line: $(cat "$work/short.err")"

echo "plot_closed_loop_check: ok"
