#!/usr/bin/env bash
# `tofu check` across a real Slurm cluster (issue 36): scripts/slurm_local_cluster.sh
# starts a single-node cluster under WORK_DIR; the test grid (tests/data/check_shard: 2
# scenarios x 2 seeds) is checked once on this machine, then
#   sbatch --array=0-1 scripts/check.sbatch OUT SCENARIOS...          (two shards)
#   sbatch --dependency=afterany:ARRAY --wait scripts/check.sbatch ...  (the merge)
# must finish both array tasks COMPLETED with exit code 0, end the merge job with the
# one-machine check's exit code, and write the same JUnit (wall clock aside), method
# tables and report (tests/check_merge_compare.py). The one-machine check ran with the
# same --out, moved aside afterwards, so that the paths in both are the same. The cluster
# is stopped on every exit path (trap), and by its own watchdog should this be killed.
#
#   slurm_check_check.sh TOFU SOURCE_DIR WORK_DIR
#
# Exit 77 (skipped) only when not root or when Slurm/munge are not installed; any other
# problem, a cluster that does not start included, is a failure.
set -euo pipefail

# shellcheck source=tests/slurm_test_support.sh
source "$(dirname "${BASH_SOURCE[0]}")/slurm_test_support.sh"
slurm_test_arguments "$@"  # tofu, src, work
scenarios=("$src/tests/data/check_shard/a_hover_methods.yaml" "$src/tests/data/check_shard/b_hover_strict.yaml")
job_script=$src/scripts/check.sbatch

slurm_skip_unless_possible
[[ -x $tofu ]] || fail "no tofu binary at $tofu"

out=$work/check
rm -rf "$out" "$out.report" "$work/one_out" "$work/one_report" "$work"/*.xml "$work"/tofu-check-*.out
mkdir -p "$work"

cd "$work"
echo "== one machine: tofu check (2 scenarios x 2 seeds) --out $out"
one_status=0
"$tofu" check "${scenarios[@]}" --seeds 2 --jobs 2 --quiet --out "$out" --junit "$work/one.xml" \
  --report "$work/one_report" || one_status=$?
((one_status == 1)) || fail "the one-machine check exited $one_status, expected 1 (b_hover_strict fails)"
mv "$out" "$work/one_out"

# Ports of our own (not slurm_corpus's, nor a developer's cluster on 6817/6818).
export TOFU_SLURMCTLD_PORT=${TOFU_SLURMCTLD_PORT:-6927}
export TOFU_SLURMD_PORT=${TOFU_SLURMD_PORT:-6928}
slurm_logs=("$work/tofu-check-*.out")
slurm_start "$work/slurm" "$src/scripts/slurm_local_cluster.sh"

export SEEDS=2 TOFU=$tofu JUNIT=$work/merged.xml REPORT=$out.report
echo "== sbatch --array=0-1 check.sbatch $out ..."
array_job=$(sbatch --parsable --array=0-1 "$job_script" "$out" "${scenarios[@]}")
array_job=${array_job%%;*}
[[ -n $array_job ]] || fail "sbatch did not submit the array"
slurm_jobs=("$array_job")
echo "== sbatch --wait --dependency=afterany:$array_job check.sbatch $out ... (the merge)"
# In the background and waited for, so that a SIGTERM (ctest, ^C) is handled at once.
merge_status=0
timeout 480 sbatch --wait --parsable --dependency="afterany:$array_job" "$job_script" "$out" \
  "${scenarios[@]}" >"$work/sbatch.out" &
sbatch_pid=$!
wait "$sbatch_pid" || merge_status=$?
sbatch_pid=
merge_job=$(head -n 1 "$work/sbatch.out")
merge_job=${merge_job%%;*}
[[ -n $merge_job ]] || fail "sbatch did not submit the merge (status $merge_status)"

slurm_tasks_ok "$array_job" 2 || fail "not every shard task COMPLETED with exit code 0"
merge_rec=$(scontrol -o show job "$merge_job")
echo "merge job $merge_job: $(grep -oE 'JobState=[A-Z_]+' <<<"$merge_rec") $(grep -oE ' ExitCode=[0-9]+:[0-9]+' <<<"$merge_rec")"
((merge_status == one_status)) ||
  fail "the merge job exited $merge_status, the one-machine check $one_status"
[[ -f $work/check/check_shard_0000_of_0002.json && -f $work/check/check_shard_0001_of_0002.json ]] ||
  fail "the shards' records are not in $out"

echo "== compare the merge with one machine"
/usr/bin/python3 "$src/tests/check_merge_compare.py" --junit "$work/one.xml" "$work/merged.xml" \
  --out "$work/one_out" "$out" --report "$work/one_report" "$out.report" ||
  fail "the merged check differs from the one-machine check"
echo "slurm check ok: 2 shard tasks COMPLETED, the merge exited $merge_status as one machine did, same outputs"
