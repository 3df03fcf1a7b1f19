#!/usr/bin/env bash
# A single-node Slurm cluster in a private folder, for testing farm scripts on one machine.
#
#   scripts/slurm-local.sh start DIR   # munge key, slurm.conf, munged, slurmctld, slurmd;
#                                      # prints the SLURM_CONF line to export
#   scripts/slurm-local.sh stop DIR    # stops the daemons that `start DIR` started
#
# Nothing outside DIR is written: the daemons use their own munge socket, spool, state, pid and
# log files and two free TCP ports on this host. Needs the Debian packages slurm-wlm and munge
# (`.ci/run` installs them). Run as root (the daemons' user is the caller).
set -euo pipefail
cmd=${1:-}
dir=${2:-}
[ -n "$cmd" ] && [ -n "$dir" ] || { echo "usage: $0 start|stop DIR" >&2; exit 2; }

stop() {
  for pid in "$dir/slurmd.pid" "$dir/slurmctld.pid" "$dir/munge/munged.pid"; do
    if [ -s "$pid" ]; then kill "$(cat "$pid")" 2>/dev/null || true; fi
  done
  # Wait for them to go (at most 10 s), so a later start finds free ports and no stale pids.
  for _ in $(seq 50); do
    alive=0
    for pid in "$dir/slurmd.pid" "$dir/slurmctld.pid" "$dir/munge/munged.pid"; do
      if [ -s "$pid" ] && kill -0 "$(cat "$pid")" 2>/dev/null; then alive=1; fi
    done
    [ "$alive" = 0 ] && break
    sleep 0.2
  done
  rm -f "$dir/slurmd.pid" "$dir/slurmctld.pid" "$dir/munge/munged.pid"
}

case "$cmd" in
stop) stop; exit 0 ;;
start) ;;
*) echo "usage: $0 start|stop DIR" >&2; exit 2 ;;
esac

for tool in munged slurmctld slurmd sbatch scontrol; do
  command -v "$tool" >/dev/null || {
    echo "slurm-local: $tool not found: install the Debian packages slurm-wlm and munge" >&2
    exit 1
  }
done
mkdir -p "$dir"
dir=$(cd "$dir" && pwd)
mkdir -p "$dir/munge" "$dir/state" "$dir/spool" "$dir/log"
chmod 700 "$dir/munge"
if [ ! -s "$dir/munge/munge.key" ]; then
  head -c 1024 /dev/urandom > "$dir/munge/munge.key"
  chmod 400 "$dir/munge/munge.key"
fi
free_port() {
  python3 -c 'import socket; s=socket.socket(); s.bind(("127.0.0.1", 0)); print(s.getsockname()[1])'
}
ctld_port=$(free_port)
slurmd_port=$(free_port)
while [ "$slurmd_port" = "$ctld_port" ]; do slurmd_port=$(free_port); done
host=$(hostname -s)
# The node advertises at least a farm node's size (16 CPUs, 16 GiB) whatever this machine has,
# so scripts written for the farm (`#SBATCH --cpus-per-task=8 --mem=8G`) run here unchanged;
# `config_overrides` tells slurmd to trust these numbers instead of draining the node.
# SLURM_LOCAL_CPUS raises the CPU floor (the farm test advertises room for every task of its
# arrays at once: Slurm starts tasks that wait for CPUs about 3 s apart).
cpus=$(nproc); [ "$cpus" -lt "${SLURM_LOCAL_CPUS:-16}" ] && cpus=${SLURM_LOCAL_CPUS:-16}
mem_mb=$(awk '/MemTotal/ {print int($2 / 1024)}' /proc/meminfo); [ "$mem_mb" -lt 16384 ] && mem_mb=16384
cat > "$dir/slurm.conf" <<CONF
ClusterName=pinbake-local
SlurmctldHost=$host
SlurmUser=$(id -un)
SlurmdUser=$(id -un)
AuthType=auth/munge
AuthInfo=socket=$dir/munge/sock
CredType=cred/munge
StateSaveLocation=$dir/state
SlurmdSpoolDir=$dir/spool
SlurmctldPidFile=$dir/slurmctld.pid
SlurmdPidFile=$dir/slurmd.pid
SlurmctldPort=$ctld_port
SlurmdPort=$slurmd_port
SlurmctldLogFile=$dir/log/slurmctld.log
SlurmdLogFile=$dir/log/slurmd.log
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
SchedulerType=sched/backfill
SelectType=select/cons_tres
SelectTypeParameters=CR_Core
ReturnToService=2
MpiDefault=none
JobCompType=jobcomp/none
AccountingStorageType=accounting_storage/none
JobAcctGatherType=jobacct_gather/none
SlurmdParameters=config_overrides
NodeName=$host CPUs=$cpus RealMemory=$mem_mb State=UNKNOWN
PartitionName=local Nodes=ALL Default=YES MaxTime=INFINITE State=UP
CONF
export SLURM_CONF="$dir/slurm.conf"
fail() {
  echo "slurm-local: $1; last log lines:" >&2
  tail -n 5 "$dir"/log/*.log 2>/dev/null | tr '\n' ' ' >&2
  echo >&2
  stop
  exit 1
}
munged --force --key-file="$dir/munge/munge.key" --socket="$dir/munge/sock" \
  --pid-file="$dir/munge/munged.pid" --log-file="$dir/log/munged.log" \
  --seed-file="$dir/munge/seed" || fail "munged did not start"
slurmctld -f "$dir/slurm.conf" || fail "slurmctld did not start"
slurmd -f "$dir/slurm.conf" || fail "slurmd did not start"
# Ready when the node reports idle (at most 30 s).
for _ in $(seq 150); do
  state=$(sinfo -h -N -o '%T' 2>/dev/null | head -n 1 || true)
  [ "$state" = idle ] && { echo "export SLURM_CONF=$dir/slurm.conf"; exit 0; }
  sleep 0.2
done
fail "the node did not become idle (state: '${state:-none}')"
