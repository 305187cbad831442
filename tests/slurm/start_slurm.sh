#!/usr/bin/env bash
# A one-node SLURM cluster on this machine, for tests/test_slurm.py and for trying the cluster
# profile by hand (docs/usage.md, "Audit trail, report, cluster"). Idempotent: run it again and it only
# checks that the cluster is up. Debian (apt-get) and root only.
#
#   bash tests/slurm/start_slurm.sh    install Debian's slurm-wlm and munge if missing, write
#                                      /etc/slurm/slurm.conf for this host, start munged, slurmctld
#                                      and slurmd, wait until `sinfo` shows the node up
#   bash tests/slurm/stop_slurm.sh     cancel its jobs and stop the daemons (--purge: remove it all)
#
# The cluster: node $(hostname -s) with all its CPUs and its memory less 10 % (at least 512 MB),
# one partition `debug` (the default), accounting off (no slurmdbd: sacct answers nothing useful,
# the profile asks squeue), no cgroups (proctrack/linuxproc, task/none), select/cons_tres with
# CR_Core_Memory (jobs get the CPUs and memory they ask for), ReturnToService=2, state under
# /var/lib/slurm, logs under /var/log/slurm. A slurm.conf this script did not write is left alone
# (exit 2). Exit status: 0 up, 1 a daemon failed (the last line says which), 2 cannot run here.
set -euo pipefail

PARTITION=debug
CONF=/etc/slurm/slurm.conf
MARK="# one-node test cluster written by flatlandia tests/slurm/start_slurm.sh"
STATE=/var/lib/slurm
LOGS=/var/log/slurm
RUN=/run/flatlandia-slurm   # what this script started (stop_slurm.sh stops only that)
WAIT_S=${SLURM_START_WAIT_S:-60}

say() { echo "start_slurm: $*" >&2; }
cannot() { say "$*"; exit 2; }
failed() { say "$*"; exit 1; }
last_log() { [ -r "$1" ] && tail -n 1 "$1" | cut -c1-300 || echo "no log at $1"; }
alive() { [ -s "$1" ] && kill -0 "$(cat "$1")" 2>/dev/null; }

[ "$(id -u)" = 0 ] || cannot "needs root (it installs packages and starts daemons)"
command -v apt-get >/dev/null && [ -r /etc/debian_version ] || cannot "needs Debian's apt-get"

# ---------------------------------------------------------------- packages
missing=0
for tool in munged munge unmunge slurmctld slurmd sbatch squeue scancel sinfo scontrol; do
  PATH="$PATH:/usr/sbin:/sbin" command -v "$tool" >/dev/null || missing=1
done
if [ "$missing" = 1 ]; then
  say "installing slurm-wlm and munge (apt-get)"
  export DEBIAN_FRONTEND=noninteractive
  pkgs=(slurm-wlm munge)
  { apt-get install -y -q --no-install-recommends "${pkgs[@]}" ||
    { apt-get update -q && apt-get install -y -q --no-install-recommends "${pkgs[@]}"; }; } >/dev/null ||
    cannot "apt-get install ${pkgs[*]} failed"
fi
export PATH="$PATH:/usr/sbin:/sbin"

# ---------------------------------------------------------------- the configuration
HOST=$(hostname -s)
CPUS=$(nproc)
MEM=$(free -m | awk '/^Mem:/ {print $2}')
MARGIN=$((MEM / 10 > 512 ? MEM / 10 : 512))
REAL=$((MEM - MARGIN))
if [ -e "$CONF" ] && ! grep -qxF "$MARK" "$CONF"; then
  cannot "$CONF exists and is not this script's: this machine has a SLURM of its own, left alone"
fi
mkdir -p /etc/slurm "$STATE/slurmctld" "$STATE/slurmd" "$LOGS" "$RUN"
new=$(mktemp)
cat >"$new" <<CONF
$MARK
ClusterName=flatlandia-test
SlurmctldHost=$HOST(127.0.0.1)
SlurmUser=root
AuthType=auth/munge
StateSaveLocation=$STATE/slurmctld
SlurmdSpoolDir=$STATE/slurmd
SlurmctldPidFile=/run/slurmctld.pid
SlurmdPidFile=/run/slurmd.pid
SlurmctldLogFile=$LOGS/slurmctld.log
SlurmdLogFile=$LOGS/slurmd.log
MpiDefault=none
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
SchedulerType=sched/backfill
SelectType=select/cons_tres
SelectTypeParameters=CR_Core_Memory
DefMemPerCPU=1000
AccountingStorageType=accounting_storage/none
JobAcctGatherType=jobacct_gather/none
JobCompType=jobcomp/none
ReturnToService=2
SlurmdParameters=config_overrides
# finished jobs stay visible to squeue 5 min (the profile's status checks rely on it)
MinJobAge=300
KillWait=5
InactiveLimit=0
NodeName=$HOST NodeAddr=127.0.0.1 CPUs=$CPUS RealMemory=$REAL State=UNKNOWN
PartitionName=$PARTITION Nodes=$HOST Default=YES MaxTime=INFINITE State=UP
CONF
changed=0
if ! cmp -s "$new" "$CONF"; then
  install -m 0644 "$new" "$CONF"
  changed=1
fi
rm -f "$new"

# ---------------------------------------------------------------- munge
if ! munge -n </dev/null 2>/dev/null | unmunge >/dev/null 2>&1; then
  key=/etc/munge/munge.key
  install -d -o munge -g munge -m 0700 /etc/munge /var/lib/munge /var/log/munge
  install -d -o munge -g munge -m 0755 /run/munge
  if [ ! -s "$key" ]; then
    mungekey --create --keyfile="$key" 2>/dev/null || dd if=/dev/urandom of="$key" bs=1024 count=1 status=none
  fi
  chown munge:munge "$key"
  chmod 0400 "$key"
  runuser -u munge -- /usr/sbin/munged || failed "munged did not start: $(last_log /var/log/munge/munged.log)"
  touch "$RUN/munged"
  for _ in $(seq 20); do munge -n </dev/null 2>/dev/null | unmunge >/dev/null 2>&1 && break; sleep 0.5; done
  munge -n </dev/null 2>/dev/null | unmunge >/dev/null 2>&1 || failed "munged does not answer: $(last_log /var/log/munge/munged.log)"
fi

# ---------------------------------------------------------------- slurmctld, slurmd
stop_pid() {  # pidfile: stop that process and wait for it
  alive "$1" || return 0
  local pid; pid=$(cat "$1")
  kill "$pid"
  for _ in $(seq 40); do kill -0 "$pid" 2>/dev/null || return 0; sleep 0.25; done
  kill -9 "$pid" 2>/dev/null || true
}
if [ "$changed" = 1 ]; then  # a new configuration: restart what runs on the old one
  stop_pid /run/slurmd.pid
  stop_pid /run/slurmctld.pid
fi
if ! alive /run/slurmctld.pid; then
  slurmctld || failed "slurmctld did not start: $(last_log "$LOGS/slurmctld.log")"
  touch "$RUN/slurmctld"
fi
for _ in $(seq "$((WAIT_S * 2))"); do scontrol ping 2>/dev/null | grep -q UP && break; sleep 0.5; done
scontrol ping 2>/dev/null | grep -q UP || failed "slurmctld does not answer: $(last_log "$LOGS/slurmctld.log")"
if ! alive /run/slurmd.pid; then
  slurmd || failed "slurmd did not start: $(last_log "$LOGS/slurmd.log")"
  touch "$RUN/slurmd"
  # the daemon writes its pid file after the command returns (over a stale one of a killed slurmd)
  for _ in $(seq 40); do alive /run/slurmd.pid && break; sleep 0.25; done
fi

# ---------------------------------------------------------------- the node
state=""
for i in $(seq "$((WAIT_S * 2))"); do
  alive /run/slurmd.pid || failed "slurmd stopped: $(last_log "$LOGS/slurmd.log")"
  state=$(sinfo -h -n "$HOST" -p "$PARTITION" -o %T 2>/dev/null | head -n 1)
  case "$state" in
    idle | mixed | allocated | completing) break ;;
    down* | drain* | *drained)  # e.g. left down by an earlier stop: slurmd is up again
      [ $((i % 4)) = 0 ] && scontrol update NodeName="$HOST" State=RESUME 2>/dev/null || true ;;
  esac
  sleep 0.5
done
case "$state" in
  idle | mixed | allocated | completing) ;;
  *) failed "node $HOST is '${state:-unknown}' after ${WAIT_S} s: $(last_log "$LOGS/slurmd.log")" ;;
esac
say "up: node $HOST ($CPUS CPUs, ${REAL} MB), partition $PARTITION, $state"
