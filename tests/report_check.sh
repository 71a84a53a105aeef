#!/usr/bin/env bash
# `tofu report` end to end, in a real browser: flies a short closed-loop run with a
# diverging VIO (one expectation fails on purpose, so the page has red rows and the run's
# failure renders), writes its report, runs a tiny `tofu check --seeds 2 --report` over
# copies of two short suite scenarios and that run, and opens the run page, the check
# overview and a run page of the check in Debian's headless chromium (tests/node/check_report.mjs: no script error, no
# request leaving the report, images decoded, links resolve, a non-blank screenshot, the
# plot's tooltip on hover and its zoom). Also: bad input is exit 2 naming the path and
# touches nothing. Exits 77 (ctest: skipped) only when chromium or tests/node/node_modules
# is missing.
#   report_check.sh SOURCE_DIR TOFU_BINARY WORK_DIR
set -euo pipefail
source_dir="$1"
tofu="$2"
work="$3"
node_dir="$source_dir/tests/node"
chromium="${TOFU_CHROMIUM:-/usr/bin/chromium}"

check=report_check
source "$source_dir/tests/plot_check_support.sh"

if [[ ! -x "$chromium" ]]; then
  echo "$check: SKIP: no $chromium (apt-get install chromium)"
  exit 77
fi
if [[ ! -d "$node_dir/node_modules/playwright-core" ]]; then
  echo "$check: SKIP: no $node_dir/node_modules (run: cd $node_dir && npm ci)"
  exit 77
fi

rm -rf "$work"
mkdir -p "$work/scenarios"

# A run: 8 s along the arena's east wall with the seed paper's sensors; the VIO diverges
# from 4 s; consensus and naive run in the loop and each flies once (closed loop). The last
# expectation cannot hold, so the run fails (exit 1) and renders its failure events.
cat > "$work/report_run.yaml" <<'EOF'
name: report_run
description: "Closed loop along the east wall; the VIO diverges at 4 s (report_check.sh)"
world: indoor_arena
duration_s: 8
seed: 3
trajectory:
  start: {position_m: [2.0, -2.0, 1.5]}
  limits: {max_speed_mps: 0.6, max_acceleration_mps2: 0.6}
  segments:
    - hover: {duration_s: 1}
    - line: {to_m: [4.5, -2.0, 1.5]}
    - line: {to_m: [4.5, 0.0, 1.5]}
sensors:
  imu: {}
  vio: {}
  lio: {type: lidar_odometry}
  leica: {type: total_station}
faults:
  - {sensor: vio, kind: divergence, start_s: 4, axis: [1, 0, 0], initial_velocity_mps: 0.3, time_constant_s: 8}
estimation:
  methods: [consensus, naive, "single:vio@clean"]
  consensus: {threshold: 0.3, priority: [leica, lio, vio]}
  huber_delta: 3
control:
  state_source: estimate
  methods: [consensus, naive]
render: {size: [320, 240], fps: 10, clip_half_s: 0.5}
expect:
  - {metric: collisions.count, max: 0}
  - {metric: methods.consensus.ate_m, max: 0.5}
  - {metric: tracking.position_rmse_m, max: 0.000001}
EOF
set +e
"$tofu" run "$work/report_run.yaml" --out "$work/run" --quiet
status=$?
set -e
[[ $status -eq 1 ]] || fail "tofu run: exit $status, expected 1 (one expectation fails on purpose)"
"$tofu" report "$work/run" --out "$work/run_report" || fail "tofu report of the run: exit $?"
[[ -s "$work/run_report/index.html" ]] || fail "no $work/run_report/index.html"

# Bad input: exit 2 naming the path and the expected forms; nothing written or touched.
expect_rejected "not a run directory" "neither a tofu run directory" "$work/none" -- \
  "$tofu" report "$work/scenarios" --out "$work/none"
mkdir -p "$work/mine"
echo "keep" > "$work/mine/notes.txt"
expect_rejected "--out of other files" "not a tofu report" "$work/mine/index.html" -- \
  "$tofu" report "$work/run" --out "$work/mine"
[[ "$(ls "$work/mine")" == "notes.txt" ]] || fail "--out of other files was touched"

# A tiny check with --report, two seeds each: copies of two short suite scenarios (they
# pass) and the run above (fails on purpose: red rows, renders on the run pages).
cp "$source_dir/scenarios/hover_arena.yaml" "$source_dir/scenarios/hover_tilted_arena.yaml" \
  "$work/report_run.yaml" "$work/scenarios/"
expect_rejected "check --report of other files" "not a tofu report" "$work/mine/index.html" -- \
  "$tofu" check "$work/scenarios" --out "$work/check" --report "$work/mine" --quiet
[[ ! -e "$work/check" ]] || fail "check --report with a bad --report ran anyway"
set +e
"$tofu" check "$work/scenarios" --seeds 2 --jobs 2 --out "$work/check" \
  --junit "$work/check/junit.xml" --report "$work/check_report" --quiet
status=$?
set -e
[[ $status -eq 1 ]] || fail "tofu check --report: exit $status, expected 1 (report_run fails)"
for page in index.html hover_arena/seed_1/index.html hover_arena/seed_2/index.html \
            report_run/seed_3/index.html report_run/seed_4/index.html; do
  [[ -s "$work/check_report/$page" ]] || fail "no $work/check_report/$page"
done
[[ -e "$work/check_report/report_run/seed_4/run.log" ]] || fail "the run's log is not beside its page"

# The pages in the browser.
node "$node_dir/check_report.mjs" "$work/run_report/index.html" --plot \
  --screenshot "$work/run_report.png" --expect "report_run" --expect "Expectations" \
  --expect "Closed-loop flights" --expect "Failure renders" || fail "the run's page (above)"
node "$node_dir/check_report.mjs" "$work/check_report/index.html" \
  --screenshot "$work/check_report.png" --expect "hover_arena" --expect "hover_tilted_arena" \
  --expect "FAIL 0/2" --expect "seed 4" || fail "the check's overview (above)"
node "$node_dir/check_report.mjs" "$work/check_report/report_run/seed_4/index.html" --plot \
  --screenshot "$work/check_run.png" --expect "check overview" --expect "Failure renders" \
  || fail "a run page of the check (above)"

echo "$check: ok"
