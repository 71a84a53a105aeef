#!/usr/bin/env bash
# `tofu report` of the whole scenario suite's check (the directory the scenario_check
# fixture wrote: every scenarios/*.yaml flown): the overview page and every run's page open
# in Debian's headless chromium without console or page errors, failed or outside requests,
# broken images or links, and with a non-blank screenshot (tests/node/check_report.mjs).
#   report_scenarios_check.sh TOFU SOURCE_DIR CHECK_DIR WORK_DIR
# Exit 77 (skip) only when chromium or tests/node/node_modules is missing.
set -euo pipefail
tofu="$1"
source_dir="$2"
check_dir="$3"
work="$4"
node_dir="$source_dir/tests/node"
fail() { echo "report_scenarios: FAIL: $*" >&2; exit 1; }
chromium="${TOFU_CHROMIUM:-/usr/bin/chromium}"
if [[ ! -x "$chromium" ]]; then echo "report_scenarios: SKIP: no $chromium (scripts/setup.sh installs it)"; exit 77; fi
if [[ ! -d "$node_dir/node_modules/playwright-core" ]]; then
  echo "report_scenarios: SKIP: no $node_dir/node_modules (scripts/setup.sh runs npm ci)"; exit 77
fi
[[ -d "$check_dir" ]] || fail "no check directory $check_dir (scenario_check fixture)"

rm -rf "$work"
mkdir -p "$work"
"$tofu" report "$check_dir" --out "$work/report" || fail "tofu report exit $?"
pages=("$work/report/index.html")
while IFS= read -r page; do pages+=("$page"); done < <(find "$work/report" -mindepth 3 -name index.html | sort)
(( ${#pages[@]} > 10 )) || fail "only ${#pages[@]} pages: the suite has more scenarios"
# One browser for all pages (starting chromium is most of a page's time).
also=()
for page in "${pages[@]:1}"; do also+=(--also "$page"); done
node "$node_dir/check_report.mjs" "${pages[0]}" --screenshot "$work/page.png" "${also[@]}" > "$work/pages.log" 2>&1 ||
  { cat "$work/pages.log" >&2; fail "a page of the report"; }
(( $(grep -c '^check_report: .* px high' "$work/pages.log") == ${#pages[@]} )) || fail "not every page was checked"
echo "report_scenarios: ok (${#pages[@]} pages)"
