# Sourced by the ctests that run array jobs on a local Slurm cluster
# (scripts/slurm_local_cluster.sh): slurm_corpus_check.sh, slurm_check_check.sh.
#
#   slurm_test_arguments "$@"      the test's arguments TOFU SOURCE_DIR WORK_DIR as the
#                                   absolute paths tofu, src, work (usage: exit 2)
#   slurm_skip_unless_possible      exit 77 unless root with Slurm and munge installed
#   fail MESSAGE...                 exit 1 with FAIL: MESSAGE on stderr
#   slurm_start STATE_DIR CLUSTER   start the cluster on ports of the test's own
#                                   (TOFU_SLURMCTLD_PORT/TOFU_SLURMD_PORT, set before) and
#                                   stop it on every exit path, showing the logs of
#                                   slurm_logs (globs) and the daemons' when failing
#   slurm_tasks_ok JOB N            print each of tasks 0..N-1 of array JOB; false unless
#                                   all COMPLETED with exit code 0
#
# Variables the test may set: slurm_logs (array of file globs to show on failure),
# sbatch_pid (an `sbatch --wait` in the background, killed on exit), slurm_jobs (job ids
# to cancel on exit).

slurm_test_arguments() {
  if [[ $# -ne 3 ]]; then
    echo "usage: ${0##*/} TOFU SOURCE_DIR WORK_DIR" >&2
    exit 2
  fi
  tofu=$(realpath "$1")
  src=$(realpath "$2")
  work=$(realpath -m "$3")
}

slurm_skip_unless_possible() {
  local c missing=
  for c in slurmctld slurmd sbatch scontrol sinfo munged munge; do
    command -v "$c" >/dev/null || missing+=" $c"
  done
  if [[ -n $missing ]]; then
    echo "SKIP: not installed:$missing (Debian: slurmctld slurmd slurm-client munge)"
    exit 77
  fi
  if [[ $(id -u) != 0 ]]; then
    echo "SKIP: a local Slurm cluster needs root (slurmd starts jobs as their users)"
    exit 77
  fi
}

fail() {
  echo "FAIL: $*" >&2
  exit 1
}

slurm_logs=()
slurm_jobs=()
sbatch_pid=

_slurm_show_logs() {
  local pattern f
  for pattern in ${slurm_logs[@]+"${slurm_logs[@]}"} "$_slurm_state/log/slurmctld.log" \
    "$_slurm_state/log/slurmd.log"; do
    while IFS= read -r f; do
      [[ -s $f ]] || continue
      echo "---- last lines of $f"
      tail -n 25 "$f"
    done < <(compgen -G "$pattern" || true)
  done
}

_slurm_cleanup() {
  local status=$? job
  trap - EXIT INT TERM
  ((status == 0)) || _slurm_show_logs
  if [[ -n $sbatch_pid ]]; then kill "$sbatch_pid" 2>/dev/null || true; fi
  for job in ${slurm_jobs[@]+"${slurm_jobs[@]}"}; do scancel "$job" 2>/dev/null || true; done
  "$_slurm_cluster" stop "$_slurm_state" || status=1
  exit "$status"
}

slurm_start() {
  _slurm_state=$1
  _slurm_cluster=$2
  export SLURM_CONF=$_slurm_state/etc/slurm.conf
  trap _slurm_cleanup EXIT
  trap 'exit 130' INT TERM
  # The watchdog outlives ctest's 600 s TIMEOUT by a minute: if ctest kills the test with
  # SIGKILL the trap never runs, and the watchdog stops the daemons instead.
  "$_slurm_cluster" start --max-lifetime 660 "$_slurm_state" || fail "the local Slurm cluster did not start"
}

# No slurmdbd here, so no sacct: scontrol keeps finished jobs for MinJobAge (10 min in
# slurm_local_cluster.sh's slurm.conf), one record per array task.
slurm_tasks_ok() {
  local job=$1 count=$2 task rec st ec times ok=0
  local records
  records=$(scontrol -o show job "$job")
  for ((task = 0; task < count; ++task)); do
    rec=$(grep -E "ArrayJobId=$job ArrayTaskId=$task " <<<"$records" || true)
    st=$(grep -oE 'JobState=[A-Z_]+' <<<"$rec" || true)
    ec=$(grep -oE ' ExitCode=[0-9]+:[0-9]+' <<<"$rec" || true)
    times=$(grep -oE '(StartTime|EndTime)=[^ ]+' <<<"$rec" | tr '\n' ' ' || true)
    echo "task $task: ${st:-no record} ${ec# } $times"
    [[ $st == JobState=COMPLETED && $ec == " ExitCode=0:0" ]] || ok=1
  done
  return "$ok"
}
