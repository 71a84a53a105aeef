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

check=plot_closed_loop_check
source "$source_dir/tests/plot_check_support.sh"

rm -rf "$work"
mkdir -p "$work"

cp -r "$fixture" "$work/full"
"$script" "$work/full" || fail "exit $? on the full fixture"
is_png "$work/full/closed_loop.png" || fail "no PNG at $work/full/closed_loop.png"
"$script" "$work/full" --out "$work/full.png" || fail "exit $? with --out"
is_png "$work/full.png" || fail "no PNG at $work/full.png"
(( $(stat -c %s "$work/full.png") > 40000 )) || fail "$work/full.png is suspiciously small"

# --when-ready, with and without "go".
expect_drawn_when_ready "$script" "$fixture" "$work" closed_loop.png

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
expect_rejected "malformed control.csv" "control.csv:$((lines + 1)): column 'tracking_error'" \
  "$work/bad/closed_loop.png" -- "$script" "$work/bad"

# An unknown flight mode, and a row with too few fields.
cp -r "$fixture" "$work/mode"
echo "40000000000,cruise,1,2,3,1,2,3,1,2,3,0.1,0.1,0.5" >> "$work/mode/closed_loop/naive/control.csv"
expect_rejected "unknown mode" "column 'mode'" "$work/mode/closed_loop.png" -- "$script" "$work/mode"
cp -r "$fixture" "$work/short"
echo "5000000000,handover" >> "$work/short/closed_loop/naive/events.csv"
expect_rejected "short events.csv row" "events.csv:[0-9]*: expected 3 fields" \
  "$work/short/closed_loop.png" -- "$script" "$work/short"

echo "plot_closed_loop_check: ok"
