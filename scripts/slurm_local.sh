#!/usr/bin/env bash
# A single-node SLURM cluster on this machine, for the cluster test and for trying the
# SLURM profile: munged, slurmctld and slurmd started directly (no systemd in containers),
# cgroup-free settings, one partition `cpu` holding this host.
#
#   scripts/slurm_local.sh start    start (idempotent); exit 0 once the node takes jobs
#   scripts/slurm_local.sh stop     stop the daemons this script started
#   scripts/slurm_local.sh conf     only write /etc/slurm/slurm.conf (scripts/install_slurm.sh)
#
# MessageTimeout is 1 s (SLURM's default: 10 s): the SLURM executor plugin runs `scontrol show
# config` whenever Snakemake starts, whatever the executor, and while no controller runs that
# call retries for a second less than the timeout (9 s a Snakemake start with the default, 1 s
# with 2 s, none with 1 s; messages on one machine take milliseconds).
#
# Exit status 3 with a one-line reason on stderr when SLURM cannot run here (not installed, not
# root); 4 when it is installed and a daemon or the node fails to come up (a fault to look at).
set -euo pipefail
state=${SLURM_LOCAL_STATE:-/var/lib/towerpipe-slurm}
conf=/etc/slurm/slurm.conf
why() { echo "slurm_local: $*" >&2; exit 3; }
fail() { echo "slurm_local: $*" >&2; exit 4; }
alive() { [ -s "$state/$1.pid" ] && kill -0 "$(cat "$state/$1.pid")" 2>/dev/null; }
ready() { scontrol ping >/dev/null 2>&1 && sinfo -h -o %t 2>/dev/null | grep -qE '^(idle|mix|alloc)'; }

write_conf() {
  mkdir -p "$(dirname "$conf")"
  host=$(hostname -s)
  cpus=$(nproc)
  mem=$(awk '/MemTotal/ {printf "%d", $2 / 1024 * 0.8}' /proc/meminfo)
  cat > "$conf" <<CONF
# written by scripts/slurm_local.sh: a single-node cluster without cgroups or accounting
ClusterName=towerpipe
SlurmctldHost=$host
SlurmUser=root
SlurmdUser=root
AuthType=auth/munge
StateSaveLocation=$state/ctld
SlurmdSpoolDir=$state/d
SlurmctldPidFile=$state/slurmctld.pid
SlurmdPidFile=$state/slurmd.pid
SlurmctldLogFile=$state/slurmctld.log
SlurmdLogFile=$state/slurmd.log
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
JobAcctGatherType=jobacct_gather/none
AccountingStorageType=accounting_storage/none
SchedulerType=sched/backfill
SelectType=select/cons_tres
SelectTypeParameters=CR_Core_Memory
ReturnToService=2
MessageTimeout=1
MinJobAge=600
NodeName=$host CPUs=$cpus RealMemory=$mem State=UNKNOWN
PartitionName=cpu Nodes=$host Default=YES MaxTime=INFINITE State=UP
CONF
}

start() {
  for b in munged slurmctld slurmd sinfo; do command -v "$b" >/dev/null || why "$b is not installed (scripts/install_slurm.sh)"; done
  [ "$(id -u)" = 0 ] || why "needs root to start munged, slurmctld and slurmd"
  if alive slurmctld && alive slurmd && ready; then return 0; fi
  mkdir -p "$state"/{ctld,d} /run/munge /var/log/munge /var/lib/munge
  chown munge:munge /run/munge /var/log/munge /var/lib/munge
  [ -s /etc/munge/munge.key ] || { mungekey -c -k /etc/munge/munge.key && chown munge:munge /etc/munge/munge.key; }
  if ! pgrep -u munge -x munged >/dev/null; then
    runuser -u munge -- /usr/sbin/munged || fail "munged did not start"
  fi
  write_conf
  alive slurmctld || slurmctld || fail "slurmctld did not start (see $state/slurmctld.log)"
  alive slurmd || slurmd || fail "slurmd did not start (see $state/slurmd.log)"
  for _ in $(seq 60); do
    if alive slurmd && ready; then return 0; fi
    sleep 1
  done
  fail "the node did not become idle in 60 s: $(sinfo -h -o '%t %E' 2>&1 | head -1)"
}

stop() {
  for p in slurmd slurmctld; do [ -s "$state/$p.pid" ] && kill "$(cat "$state/$p.pid")" 2>/dev/null || true; done
}

case "${1:-}" in
  start) start ;;
  stop) stop ;;
  conf) [ "$(id -u)" = 0 ] || why "needs root to write $conf"; write_conf ;;
  *) echo "usage: scripts/slurm_local.sh start|stop|conf" >&2; exit 2 ;;
esac
