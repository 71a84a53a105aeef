#!/usr/bin/env bash
# scripts/plot_consensus.py on the synthetic run directory tests/data/consensus_run: it
# writes a PNG (default RUN_DIR/consensus.png, or --out), still draws when files are
# missing, and rejects a malformed CSV naming file:line with exit 2 and no PNG.
#   plot_consensus_check.sh SOURCE_DIR WORK_DIR
set -euo pipefail
source_dir="$1"
work="$2"
script="$source_dir/scripts/plot_consensus.py"
fixture="$source_dir/tests/data/consensus_run"

check=plot_consensus_check
source "$source_dir/tests/plot_check_support.sh"

rm -rf "$work"
mkdir -p "$work"

# Every file present, default output path.
cp -r "$fixture" "$work/full"
"$script" "$work/full" || fail "exit $? on the full fixture"
is_png "$work/full/consensus.png" || fail "no PNG at $work/full/consensus.png"

# --out, and a drawn figure (not a stub).
"$script" "$work/full" --out "$work/full.png" || fail "exit $? with --out"
is_png "$work/full.png" || fail "no PNG at $work/full.png"
(( $(stat -c %s "$work/full.png") > 20000 )) || fail "$work/full.png is suspiciously small"

# --when-ready, with and without "go".
expect_drawn_when_ready "$script" "$fixture" "$work" consensus.png

# Missing files: what exists is drawn, exit 0.
cp -r "$fixture" "$work/partial"
rm "$work/partial/decisions.csv" "$work/partial/consistency_consensus.csv" \
   "$work/partial/summary.json"
"$script" "$work/partial" || fail "exit $? with files missing"
is_png "$work/partial/consensus.png" || fail "no PNG with files missing"
mkdir -p "$work/empty"
"$script" "$work/empty" || fail "exit $? on an empty directory"

# A malformed row: exit 2, the message names file and line, no PNG.
cp -r "$fixture" "$work/bad"
lines=$(wc -l < "$work/bad/errors.csv")
echo "1000000000,consensus,0.1,not_a_number,1," >> "$work/bad/errors.csv"
expect_rejected "malformed errors.csv" "errors.csv:$((lines + 1)): column 'rotation_error'" \
  "$work/bad/consensus.png" -- "$script" "$work/bad"

# A row with the wrong number of fields.
cp -r "$fixture" "$work/short"
echo "5000000000,consensus,vio" >> "$work/short/decisions.csv"
expect_rejected "short decisions.csv row" "decisions.csv:[0-9]*: expected 6 fields" \
  "$work/short/consensus.png" -- "$script" "$work/short"

echo "plot_consensus_check: ok"
