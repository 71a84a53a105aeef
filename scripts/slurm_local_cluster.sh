#!/usr/bin/env bash
# A real single-node Slurm cluster on this machine, for running tofu's array jobs
# (scripts/corpus.sbatch) the way a university cluster runs them, without touching the
# system's Slurm or munge configuration: every file (munge key and socket, slurm.conf,
# state, spool, logs, pid files) lives under STATE_DIR, and every Slurm command finds the
# cluster through SLURM_CONF=STATE_DIR/etc/slurm.conf.
#
#   scripts/slurm_local_cluster.sh start  [--max-lifetime SECONDS] [--timeout SECONDS] [STATE_DIR]
#   scripts/slurm_local_cluster.sh stop   [STATE_DIR]
#   scripts/slurm_local_cluster.sh status [STATE_DIR]
#
# STATE_DIR defaults to /tmp/tofu-slurm. Needs root (slurmd must be able to start jobs as
# any user) and Debian's slurmctld, slurmd, slurm-client and munge.
#
# start: idempotent. If the cluster of STATE_DIR is already up it only re-arms the watchdog
#   (and keeps its configuration: stop it first to change ports).
#   A watchdog process stops the cluster by itself after --max-lifetime seconds (default
#   1800) so that a crashed test never leaves daemons running. --timeout (default 90) bounds
#   the wait for the node to become idle. Prints `export SLURM_CONF=...`.
# stop: cancels the cluster's jobs and kills exactly the daemons this script started (their
#   pid files under STATE_DIR), munged only if this script started it, and any slurmstepd or
#   job process left behind by this cluster's slurmd.
# status: the daemons, sinfo and squeue.
#
# Exit codes: 0 ok (status: running); 1 failed to start (reason and log tails on stderr) or,
# for status, not running; 2 misuse (bad arguments, not root, Slurm/munge not installed).
#
# Ports: 6817 (slurmctld) and 6818 (slurmd), or TOFU_SLURMCTLD_PORT / TOFU_SLURMD_PORT, for
# a machine that already runs a Slurm daemon.
set -euo pipefail

SELF=$(readlink -f "${BASH_SOURCE[0]}")
PROG=${0##*/}

usage() {  # [status]: 0 for --help (on stdout), 2 for misuse
  if [[ ${1:-2} == 0 ]]; then sed -n '2,28p' "$SELF" | sed 's/^# \{0,1\}//'; exit 0; fi
  sed -n '8,10p' "$SELF" | sed 's/^# *//' >&2
  exit 2
}
die() { echo "$PROG: $*" >&2; exit 2; }
log() { echo "$PROG: $*" >&2; }

# ---------------------------------------------------------------- arguments
[[ $# -ge 1 ]] || usage
[[ $1 == -h || $1 == --help ]] && usage 0
cmd=$1
shift
max_lifetime=1800
ready_timeout=90
state_dir=
while [[ $# -gt 0 ]]; do
  case $1 in
    --max-lifetime) [[ $# -ge 2 ]] || usage; max_lifetime=$2; shift 2 ;;
    --max-lifetime=*) max_lifetime=${1#*=}; shift ;;
    --timeout) [[ $# -ge 2 ]] || usage; ready_timeout=$2; shift 2 ;;
    --timeout=*) ready_timeout=${1#*=}; shift ;;
    -h|--help) usage 0 ;;
    -*) log "unknown option $1"; usage ;;
    *) [[ -z $state_dir ]] || { log "one STATE_DIR only"; usage; }; state_dir=$1; shift ;;
  esac
done
[[ $max_lifetime =~ ^[1-9][0-9]*$ ]] || die "--max-lifetime wants whole seconds > 0, got '$max_lifetime'"
[[ $ready_timeout =~ ^[1-9][0-9]*$ ]] || die "--timeout wants whole seconds > 0, got '$ready_timeout'"
case $cmd in
  start|stop|status|_watchdog) ;;
  *) log "unknown command '$cmd'"; usage ;;
esac

# Absolute, because slurm.conf and munged want absolute paths and the watchdog runs from /.
S=$(realpath -m "${state_dir:-/tmp/tofu-slurm}")
CONF=$S/etc/slurm.conf
RUN=$S/run
LOGS=$S/log
MUNGE_SOCKET=$S/munge/run/munge.socket
export SLURM_CONF=$CONF
ctld_port=${TOFU_SLURMCTLD_PORT:-6817}
slurmd_port=${TOFU_SLURMD_PORT:-6818}
node=$(hostname -s)

# ---------------------------------------------------------------- process helpers
# A pid file names one of our processes only if that pid is alive, is the expected program
# (comm) and, when given, mentions STATE_DIR on its command line: a stale pid file whose pid
# the kernel has reused for something else must never get that something killed.
pid_of() {  # pidfile comm [must-contain] -> prints pid, or fails
  local pidfile=$1 comm=$2 needle=${3:-} pid
  [[ -s $pidfile ]] || return 1
  pid=$(tr -dc '0-9' <"$pidfile")
  [[ -n $pid && -d /proc/$pid ]] || return 1
  [[ $(cat "/proc/$pid/comm" 2>/dev/null) == "$comm" ]] || return 1
  # Zombies are dead already (their parent has not reaped them yet).
  [[ $(awk '{print $3}' "/proc/$pid/stat" 2>/dev/null) != Z ]] || return 1
  if [[ -n $needle ]]; then
    tr '\0' ' ' <"/proc/$pid/cmdline" 2>/dev/null | grep -qF -- "$needle" || return 1
  fi
  echo "$pid"
}

alive() { [[ -d /proc/$1 ]] && [[ $(awk '{print $3}' "/proc/$1/stat" 2>/dev/null) != Z ]]; }

terminate() {  # pid name: TERM, up to 15 s, then KILL
  local pid=$1 name=$2 i
  kill -TERM "$pid" 2>/dev/null || return 0
  for ((i = 0; i < 150; i++)); do
    alive "$pid" || return 0
    sleep 0.1
  done
  log "$name (pid $pid) ignored SIGTERM for 15 s: SIGKILL"
  kill -KILL "$pid" 2>/dev/null || true
}

tails() {  # the last lines of every log, for a failed start
  local f
  for f in "$LOGS"/munged.log "$LOGS"/slurmctld.log "$LOGS"/slurmd.log "$LOGS"/*.stderr; do
    [[ -s $f ]] || continue
    echo "---- last lines of $f" >&2
    tail -n 15 "$f" >&2
  done
}

fail_start() {
  log "failed to start: $*"
  tails
  # Leave nothing half-started behind.
  do_stop >/dev/null 2>&1 || true
  exit 1
}

ctld_pid() { pid_of "$RUN/slurmctld.pid" slurmctld "$CONF"; }
slurmd_pid() { pid_of "$RUN/slurmd.pid" slurmd "$CONF"; }
# munged we started: private (key under STATE_DIR) or, as a fallback, on the system paths;
# run/munged.ours says which pid file to trust. A munged we did not start is never ours.
munged_pid() {
  [[ -s $RUN/munged.ours ]] || return 1
  pid_of "$(cat "$RUN/munged.ours")" munged
}
watchdog_pid() { pid_of "$RUN/watchdog.pid" bash "_watchdog --max-lifetime"; }

node_state() { timeout 10 sinfo -h -N -n "$node" -o '%t' 2>/dev/null | head -n 1; }

# ---------------------------------------------------------------- munge
munge_works() {  # socket
  timeout 10 munge -n -S "$1" 2>/dev/null | timeout 10 unmunge -S "$1" >/dev/null 2>&1
}

start_private_munged() {  # [--force]
  local m=$S/munge
  # munged refuses a socket directory that is not traversable by all, and a key, seed or
  # log that others could read or write; the key dir is private, the socket dir is not.
  mkdir -p "$m/etc" "$m/run" "$m/lib"
  chmod 0755 "$m" "$m/run"
  chmod 0700 "$m/etc" "$m/lib"
  if [[ ! -s $m/etc/munge.key ]]; then
    if command -v mungekey >/dev/null; then
      mungekey --create --keyfile="$m/etc/munge.key" >/dev/null
    else
      dd if=/dev/urandom of="$m/etc/munge.key" bs=1 count=1024 status=none
    fi
  fi
  chmod 0600 "$m/etc/munge.key"
  rm -f "$m/run/munged.pid"
  munged "$@" --key-file="$m/etc/munge.key" --socket="$MUNGE_SOCKET" \
    --pid-file="$m/run/munged.pid" --log-file="$LOGS/munged.log" \
    --seed-file="$m/lib/munged.seed" </dev/null >>"$LOGS/munged.stderr" 2>&1 || return 1
  echo "$m/run/munged.pid" >"$RUN/munged.ours"
  local i
  for ((i = 0; i < 50; i++)); do
    munge_works "$MUNGE_SOCKET" && return 0
    sleep 0.2
  done
  return 1
}

# Sets munge_socket_for_conf: the socket Slurm should use, empty for the system default.
munge_socket_for_conf=
start_munge() {
  if start_private_munged || { log "munged refused STATE_DIR's paths, retrying with --force (see $LOGS/munged.stderr)"; start_private_munged --force; }; then
    munge_socket_for_conf=$MUNGE_SOCKET
    return 0
  fi
  log "could not run munged under $S; falling back to the system munged"
  rm -f "$RUN/munged.ours"
  local sys=/run/munge/munge.socket.2
  if munge_works "$sys"; then
    munge_socket_for_conf=
    return 0
  fi
  mkdir -p /run/munge /var/log/munge /var/lib/munge
  munged --force </dev/null >>"$LOGS/munged.stderr" 2>&1 || fail_start "the system munged did not start either"
  echo /run/munge/munged.pid >"$RUN/munged.ours"
  local i
  for ((i = 0; i < 50; i++)); do
    if munge_works "$sys"; then munge_socket_for_conf=; return 0; fi
    sleep 0.2
  done
  fail_start "munged (system paths) started but does not answer on $sys"
}

# ---------------------------------------------------------------- slurm.conf
write_conf() {
  local cpus mem_kb mem_mb
  cpus=$(nproc)
  mem_kb=$(awk '/^MemTotal:/ {print $2}' /proc/meminfo)
  # slurmd drains a node whose configured RealMemory exceeds what it measures; slurmd
  # measures a little less than MemTotal, so configure 95 % of it.
  mem_mb=$((mem_kb * 95 / 100 / 1024))
  {
    echo "# Generated by $SELF start $S on $(date -u +%FT%TZ); regenerated on every fresh start."
    echo "ClusterName=tofu"
    # Loopback: a test cluster needs no network and must not depend on DNS for its name.
    echo "SlurmctldHost=$node(127.0.0.1)"
    echo "SlurmctldPort=$ctld_port"
    echo "SlurmdPort=$slurmd_port"
    echo "SlurmUser=root"
    echo "SlurmdUser=root"
    echo "AuthType=auth/munge"
    echo "CredType=cred/munge"
    if [[ -n $munge_socket_for_conf ]]; then
      echo "AuthInfo=socket=$munge_socket_for_conf"
    fi
    echo "StateSaveLocation=$S/state"
    echo "SlurmdSpoolDir=$S/spool"
    echo "SlurmctldPidFile=$RUN/slurmctld.pid"
    echo "SlurmdPidFile=$RUN/slurmd.pid"
    echo "SlurmctldLogFile=$LOGS/slurmctld.log"
    echo "SlurmdLogFile=$LOGS/slurmd.log"
    echo "SlurmctldDebug=info"
    echo "SlurmdDebug=info"
    # No cgroups: a container or a VM without a delegated cgroup tree still runs jobs.
    echo "ProctrackType=proctrack/linuxproc"
    echo "TaskPlugin=task/none"
    # Cores are the consumable resource, so a node with N cores runs N 1-CPU tasks at once.
    echo "SelectType=select/cons_tres"
    echo "SelectTypeParameters=CR_Core"
    echo "SchedulerType=sched/backfill"
    echo "MpiDefault=none"
    echo "JobAcctGatherType=jobacct_gather/none"
    echo "AccountingStorageType=accounting_storage/none"
    # No slurmdbd, so no sacct: one line per finished job (JobState, ExitCode) instead.
    echo "JobCompType=jobcomp/filetxt"
    echo "JobCompLoc=$LOGS/jobcomp.txt"
    # Finished jobs stay visible to scontrol for 10 min so a test can read their state.
    echo "MinJobAge=600"
    echo "ReturnToService=2"
    echo "MailProg=/bin/true"
    # Our own (empty) plugstack, so that no SPANK plugin of the system configuration loads.
    echo "PlugStackConfig=$S/etc/plugstack.conf"
    echo "NodeName=$node NodeAddr=127.0.0.1 CPUs=$cpus RealMemory=$mem_mb State=UNKNOWN"
    echo "PartitionName=local Nodes=$node Default=YES MaxTime=INFINITE State=UP"
  } >"$CONF"
  : >"$S/etc/plugstack.conf"
}

port_in_use() { ss -Hltn "sport = :$1" 2>/dev/null | grep -q .; }

# ---------------------------------------------------------------- watchdog
arm_watchdog() {
  local old
  if old=$(watchdog_pid); then
    kill -TERM -- "-$old" 2>/dev/null || kill -TERM "$old" 2>/dev/null || true
  fi
  rm -f "$RUN/watchdog.pid"
  # setsid: its own process group, out of the caller's (ctest's) job control; no inherited
  # stdout, so that $(...) and ctest do not wait for it.
  setsid "$SELF" _watchdog --max-lifetime "$max_lifetime" "$S" </dev/null >>"$LOGS/watchdog.log" 2>&1 &
  local i
  for ((i = 0; i < 50; i++)); do
    watchdog_pid >/dev/null && return 0
    sleep 0.1
  done
  fail_start "the watchdog did not start (see $LOGS/watchdog.log)"
}

run_watchdog() {
  # Out of the caller's directory, which a test may delete (or a user unmount) meanwhile.
  cd /
  echo $$ >"$RUN/watchdog.pid"
  local deadline=$((SECONDS + max_lifetime))
  echo "$(date -u +%FT%TZ) watchdog $$: stopping the cluster of $S in $max_lifetime s"
  while ((SECONDS < deadline)); do
    # Superseded (start re-armed a new watchdog) or the cluster was stopped: nothing to do.
    [[ $(cat "$RUN/watchdog.pid" 2>/dev/null) == "$$" ]] || exit 0
    sleep 2
  done
  echo "$(date -u +%FT%TZ) watchdog $$: --max-lifetime $max_lifetime s reached, stopping"
  TOFU_SLURM_FROM_WATCHDOG=$$ "$SELF" stop "$S"
}

# ---------------------------------------------------------------- stop
do_stop() {
  local pid p env_file
  local stopped=0 killed=()
  # Let the jobs end through Slurm (slurmstepd kills their processes) while it still runs.
  if ctld_pid >/dev/null && slurmd_pid >/dev/null; then
    local jobs
    jobs=$(timeout 10 squeue -h -o %A 2>/dev/null | sort -u | tr '\n' ' ') || jobs=
    if [[ -n ${jobs// /} ]]; then
      # shellcheck disable=SC2086 # one word per job id
      timeout 10 scancel --quiet $jobs 2>/dev/null || true
      for ((p = 0; p < 50; p++)); do
        [[ -z $(timeout 10 squeue -h -t RUNNING,COMPLETING -o %A 2>/dev/null) ]] && break
        sleep 0.2
      done
    fi
  fi
  if pid=$(slurmd_pid); then terminate "$pid" slurmd; log "stopped slurmd (pid $pid)"; stopped=1; killed+=("$pid"); fi
  if pid=$(ctld_pid); then terminate "$pid" slurmctld; log "stopped slurmctld (pid $pid)"; stopped=1; killed+=("$pid"); fi
  # Whatever this cluster's slurmd left behind: slurmstepd inherits slurmd's environment
  # (our SLURM_CONF); job processes carry our SLURM_CONF and a SLURM_JOB_ID. The caller's
  # own shell has SLURM_CONF but no SLURM_JOB_ID, and is never touched.
  local environ
  for env_file in /proc/[0-9]*/environ; do
    p=${env_file#/proc/}
    p=${p%/environ}
    [[ $p == "$$" || $p == "$PPID" ]] && continue
    # Processes come and go while we look, and kernel threads have no environment.
    environ=$( { tr '\0' '\n' <"$env_file"; } 2>/dev/null) || continue
    grep -qxF "SLURM_CONF=$CONF" <<<"$environ" || continue
    if [[ $(cat "/proc/$p/comm" 2>/dev/null) == slurmstepd ]] || grep -q '^SLURM_JOB_ID=' <<<"$environ"; then
      log "killing leftover $(cat "/proc/$p/comm" 2>/dev/null) (pid $p)"
      kill -KILL "$p" 2>/dev/null || true
      killed+=("$p")
    fi
  done
  if pid=$(munged_pid); then terminate "$pid" munged; log "stopped munged (pid $pid)"; stopped=1; killed+=("$pid"); fi
  rm -f "$RUN/munged.ours" "$RUN/slurmctld.pid" "$RUN/slurmd.pid"
  if pid=$(watchdog_pid); then
    if [[ ${TOFU_SLURM_FROM_WATCHDOG:-} != "$pid" ]]; then
      # Its whole group: the watchdog and its sleep.
      kill -TERM -- "-$pid" 2>/dev/null || kill -TERM "$pid" 2>/dev/null || true
      killed+=("$pid")
    fi
  fi
  rm -f "$RUN/watchdog.pid"
  # The daemons were reparented to init, which reaps them when it gets to it; until then
  # they linger as zombies in `pgrep`. Give it up to 5 s so that "stopped" means gone.
  local lingering
  for ((p = 0; p < 50; p++)); do
    lingering=
    for pid in "${killed[@]}"; do [[ -d /proc/$pid ]] && lingering+=" $pid"; done
    [[ -z $lingering ]] && break
    sleep 0.1
  done
  if ((stopped)); then log "cluster of $S stopped"; else log "no cluster of $S was running"; fi
}

# ---------------------------------------------------------------- start
do_start() {
  local c
  for c in slurmctld slurmd sinfo squeue sbatch scancel munged munge unmunge setsid ss; do
    command -v "$c" >/dev/null || die "'$c' not found: install Debian's slurmctld slurmd slurm-client munge (scripts/packages-test.txt)"
  done
  [[ $(id -u) == 0 ]] || die "must run as root (slurmd starts jobs as their submitting user)"
  mkdir -p "$S"/etc "$S"/state "$S"/spool "$RUN" "$LOGS"
  # munged checks every directory above its files: none may be writable by others.
  chmod 0755 "$S" "$S/etc" "$RUN" "$LOGS"

  # Idempotent: an up cluster only gets its watchdog re-armed (the lifetime counts from now).
  local state=
  if ctld_pid >/dev/null && slurmd_pid >/dev/null && [[ -s $CONF ]]; then
    state=$(node_state || true)
    if [[ $state == idle || $state == mix || $state == alloc ]]; then
      arm_watchdog
      log "already running (node $node: $state); watchdog re-armed for $max_lifetime s"
      echo "export SLURM_CONF=$CONF"
      return 0
    fi
  fi
  # Half up (a daemon died) or stale pid files: start from scratch.
  do_stop >/dev/null 2>&1 || true
  for c in "$ctld_port" "$slurmd_port"; do
    if port_in_use "$c"; then
      fail_start "TCP port $c is in use (another Slurm?); choose others with TOFU_SLURMCTLD_PORT / TOFU_SLURMD_PORT"
    fi
  done
  # Fresh logs, so that the tails of a failed start show this attempt; one previous kept.
  local f
  for f in "$LOGS"/*.log "$LOGS"/*.stderr; do
    [[ -e $f ]] && mv -f "$f" "$f.prev"
  done

  start_munge
  write_conf

  # -c: a fresh controller state each start. The cluster is disposable; resuming a corpus
  # is tofu's business (finished episodes are kept in the shards), not Slurm's.
  slurmctld -c -f "$CONF" </dev/null >>"$LOGS/slurmctld.stderr" 2>&1 ||
    fail_start "slurmctld exited with status $?"
  slurmd -N "$node" -f "$CONF" </dev/null >>"$LOGS/slurmd.stderr" 2>&1 ||
    fail_start "slurmd exited with status $?"

  # The daemons fork into the background and write their pid files a moment later.
  local deadline=$((SECONDS + ready_timeout)) missing
  while ((SECONDS < deadline)); do
    missing=
    ctld_pid >/dev/null || missing+=" slurmctld"
    slurmd_pid >/dev/null || missing+=" slurmd"
    [[ -z $missing ]] && break
    sleep 0.2
  done
  [[ -z $missing ]] || fail_start "not running:$missing"
  while ((SECONDS < deadline)); do
    ctld_pid >/dev/null || fail_start "slurmctld died"
    slurmd_pid >/dev/null || fail_start "slurmd died"
    state=$(node_state || true)
    [[ $state == idle ]] && break
    sleep 1
  done
  [[ $state == idle ]] || fail_start "node $node is '${state:-not reported by sinfo}' after $ready_timeout s, not idle"

  arm_watchdog
  log "cluster of $S up: node $node idle with $(nproc) CPUs; slurmctld $(ctld_pid), slurmd $(slurmd_pid)," \
    "munged $(munged_pid || echo 'of the system'); stops by itself in $max_lifetime s"
  echo "export SLURM_CONF=$CONF"
}

# ---------------------------------------------------------------- status
do_status() {
  local pid d up=1
  for d in slurmctld slurmd munged watchdog; do
    case $d in
      slurmctld) pid=$(ctld_pid) || pid= ;;
      slurmd) pid=$(slurmd_pid) || pid= ;;
      munged) pid=$(munged_pid) || pid= ;;
      watchdog) pid=$(watchdog_pid) || pid= ;;
    esac
    if [[ -n $pid ]]; then
      echo "$d: pid $pid"
    elif [[ $d == munged ]] && [[ ! -s $RUN/munged.ours ]] && [[ -s $CONF ]] && ! grep -q '^AuthInfo=socket=' "$CONF"; then
      echo "munged: the system's (not started by this script)"
    else
      echo "$d: not running"
      [[ $d == watchdog ]] || up=0
    fi
  done
  echo "export SLURM_CONF=$CONF"
  if ((up)); then
    timeout 10 sinfo || up=0
    timeout 10 squeue || up=0
  fi
  ((up))
}

case $cmd in
  start) do_start ;;
  stop)
    [[ $(id -u) == 0 ]] || die "must run as root"
    do_stop
    ;;
  status) do_status || exit 1 ;;
  _watchdog) run_watchdog ;;
esac
