#!/usr/bin/env bash
# The examples of docs/INTERFACE.md where users look (issue 33, item 4): the Python ESKF,
# the Python controller and the out-of-tree C++ plug-in (built by install_and_build_plugin)
# flown by `tofu check scenarios/clients` (open and closed loop; JUnit, the method table,
# the HTML report), exported to MCAP, and in a corpus (generated and verified).
#   client_examples_check.sh TOFU SOURCE_DIR WORK_DIR PLUGIN_DIR
set -euo pipefail
tofu="$1"; source_dir="$2"; work="$3"; plugin_dir="$4"
rm -rf "$work"; mkdir -p "$work"
export TOFU_PLUGIN_DIR="$plugin_dir"
fail() { echo "client_examples: $*" >&2; exit 1; }

"$tofu" check "$source_dir/scenarios/clients" --seeds 1 --jobs 2 --quiet \
  --junit "$work/junit.xml" --out "$work/check" --report "$work/report" \
  || fail "tofu check scenarios/clients failed (exit $?): $(cat "$work"/check/*/seed_*.log | tail -40)"
for method in "external:python_ekf" "plugin:complementary"; do
  grep -q "$method" "$work/check/methods.md" || fail "$method is not in the method table"
  grep -q "$method" "$work/report/index.html" || fail "$method is not in the HTML report"
  grep -q "closed_loop.$method" "$work/junit.xml" || fail "no closed-loop test case of $method in the JUnit"
done
grep -q "python_controller" "$work/junit.xml" || fail "the controller's scenario is not in the JUnit"

# MCAP: the client's estimate is a topic of its own (the channel records of the summary
# section are not compressed).
"$tofu" export "$work/check/python_ekf_wall/seed_1" --mcap "$work/ekf.mcap" --uncompressed
grep -aq "external:python_ekf" "$work/ekf.mcap" || fail "the MCAP file has no topic of external:python_ekf"

# A corpus with the client in the loop, open and closed loop.
"$tofu" corpus generate "$source_dir/corpora/clients_smoke.yaml" --out "$work/corpus" --quiet \
  || fail "corpus generate failed"
"$tofu" corpus verify "$work/corpus" --quiet || fail "corpus verify failed"
for method in "external:python_ekf" "plugin:complementary"; do
  grep -q "$method" "$work/corpus/manifest.csv" || fail "the manifest has no column of $method"
done
echo "client examples ok"
