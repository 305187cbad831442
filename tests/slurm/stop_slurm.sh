#!/usr/bin/env bash
# Stop the one-node test cluster of tests/slurm/start_slurm.sh: cancel every job it holds (it is
# this machine's test cluster, nobody else's), stop slurmd and slurmctld, and munged if that script
# started it. --purge also removes /etc/slurm/slurm.conf and the state under /var/lib/slurm (the
# packages stay installed). A SLURM this script did not configure is left alone.
set -euo pipefail
export PATH="$PATH:/usr/sbin:/sbin"
CONF=/etc/slurm/slurm.conf
MARK="# one-node test cluster written by flatlandia tests/slurm/start_slurm.sh"
RUN=/run/flatlandia-slurm
say() { echo "stop_slurm: $*" >&2; }
alive() { [ -s "$1" ] && kill -0 "$(cat "$1")" 2>/dev/null; }
stop_pid() {
  alive "$1" || return 0
  local pid; pid=$(cat "$1")
  kill "$pid"
  for _ in $(seq 40); do kill -0 "$pid" 2>/dev/null || return 0; sleep 0.25; done
  kill -9 "$pid" 2>/dev/null || true
}

[ -e "$CONF" ] || { say "no $CONF: nothing to stop"; exit 0; }
grep -qxF "$MARK" "$CONF" || { say "$CONF is not the test cluster's: left alone"; exit 2; }

if alive /run/slurmctld.pid && [ -n "$(squeue -h -o %i 2>/dev/null)" ]; then
  squeue -h -o %i | xargs scancel
  for _ in $(seq 40); do [ -z "$(squeue -h -t RUNNING,COMPLETING -o %i 2>/dev/null)" ] && break; sleep 0.5; done
fi
stop_pid /run/slurmd.pid
stop_pid /run/slurmctld.pid
if [ -e "$RUN/munged" ]; then
  stop_pid /run/munge/munged.pid
fi
rm -rf "$RUN"
if [ "${1:-}" = "--purge" ]; then
  rm -rf "$CONF" /var/lib/slurm/slurmctld /var/lib/slurm/slurmd
  say "stopped and removed"
else
  say "stopped"
fi
