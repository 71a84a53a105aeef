#!/usr/bin/env bash
# `tofu search` across a real Slurm cluster (issue 53): scripts/slurm_local_cluster.sh starts a
# single-node cluster under WORK_DIR; the analytic search (tests/data/search/dropout_search.yaml)
# is flown as two shards on this machine (--shard 0/2, 1/2) and merged, then
#   sbatch --array=0-1 scripts/search.sbatch OUT SPEC          (two shard tasks)
#   sbatch --dependency=afterany:ARRAY --wait scripts/search.sbatch OUT SPEC   (the merge)
# must finish both tasks COMPLETED with exit code 0 and end the merge with the local merge's
# exit code and the same search.json and failures.md (a shard's flights do not depend on
# where it flew). The cluster is stopped on every exit path (trap).
#
#   slurm_search_check.sh TOFU SOURCE_DIR WORK_DIR
#
# Exit 77 (skipped) only when not root or when Slurm/munge are not installed.
set -euo pipefail

# shellcheck source=tests/slurm_test_support.sh
source "$(dirname "${BASH_SOURCE[0]}")/slurm_test_support.sh"
slurm_test_arguments "$@"  # tofu, src, work
spec=$src/tests/data/search/dropout_search.yaml
job_script=$src/scripts/search.sbatch

slurm_skip_unless_possible
[[ -x $tofu ]] || fail "no tofu binary at $tofu"

out=$work/search
rm -rf "$out" "$out.report" "$work/local" "$work"/tofu-search-*.out
mkdir -p "$work"
cd "$work"

echo "== one machine: two shards and their merge"
for shard in 0/2 1/2; do
  status=0
  "$tofu" search "$spec" --out "$work/local" --shard "$shard" --jobs 2 --no-renders --quiet || status=$?
  ((status <= 1)) || fail "local shard $shard exited $status"
done
local_status=0
"$tofu" search "$spec" --out "$work/local" --merge --quiet || local_status=$?
((local_status == 1)) || fail "the local merge exited $local_status, expected 1 (the dropout fails)"

export TOFU_SLURMCTLD_PORT=${TOFU_SLURMCTLD_PORT:-6937}
export TOFU_SLURMD_PORT=${TOFU_SLURMD_PORT:-6938}
slurm_logs=("$work/tofu-search-*.out")
slurm_start "$work/slurm" "$src/scripts/slurm_local_cluster.sh"

export TOFU=$tofu REPORT=$out.report
echo "== sbatch --array=0-1 search.sbatch $out $spec"
array_job=$(sbatch --parsable --array=0-1 "$job_script" "$out" "$spec")
array_job=${array_job%%;*}
[[ -n $array_job ]] || fail "sbatch did not submit the array"
slurm_jobs=("$array_job")
merge_status=0
timeout 480 sbatch --wait --parsable --dependency="afterany:$array_job" "$job_script" "$out" "$spec" \
  >"$work/sbatch.out" &
sbatch_pid=$!
wait "$sbatch_pid" || merge_status=$?
sbatch_pid=
slurm_tasks_ok "$array_job" 2 || fail "not every shard task COMPLETED with exit code 0"
((merge_status == local_status)) || fail "the merge job exited $merge_status, the local merge $local_status"
cmp "$work/local/search.json" "$out/search.json" || fail "the merged search.json differs from the local merge's"
cmp "$work/local/failures.md" "$out/failures.md" || fail "failures.md differs from the local merge's"
[[ -f $out.report/index.html ]] || fail "the merge wrote no report at $out.report"
echo "slurm search ok: 2 shard tasks COMPLETED, the merge exited $merge_status as the local one, same outputs"
