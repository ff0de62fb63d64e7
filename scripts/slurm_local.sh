#!/usr/bin/env bash
# A real one-node SLURM cluster on localhost, for the SLURM launcher's tests.
#
#   bash scripts/slurm_local.sh start DIR   # prints `export SLURM_CONF=...`
#   bash scripts/slurm_local.sh stop DIR
#
# Runs as root without systemd or cgroups: munged with its own generated key
# and socket, slurmctld and slurmd in the foreground (-D) in the background,
# proctrack/linuxproc, task/none, no accounting daemon (jobcomp/filetxt keeps
# a completion log). Everything lives in DIR; `start` waits until sinfo shows
# the node idle. Needs the Debian packages slurm-wlm and munge
# (scripts/install_deps.sh).
set -euo pipefail

usage() { echo "usage: $0 start|stop DIR" >&2; exit 2; }
(($# == 2)) || usage
cmd=$1
dir=$(mkdir -p "$2" && cd "$2" && pwd)
ctld_port=${SOMA_SLURMCTLD_PORT:-16817}
slurmd_port=${SOMA_SLURMD_PORT:-16818}

stop_pid() {  # stop_pid NAME: SIGTERM the daemon whose pid is in DIR/NAME.pid
  local file=$dir/$1.pid pid
  [[ -f $file ]] || return 0
  pid=$(cat "$file")
  if kill -0 "$pid" 2>/dev/null; then
    kill -TERM "$pid" 2>/dev/null || true
    for _ in $(seq 50); do kill -0 "$pid" 2>/dev/null || break; sleep 0.1; done
    kill -0 "$pid" 2>/dev/null && kill -KILL "$pid" 2>/dev/null || true
  fi
  rm -f "$file"
}

case $cmd in
  stop)
    stop_pid slurmd
    stop_pid slurmctld
    stop_pid munged
    exit 0
    ;;
  start) ;;
  *) usage ;;
esac

for tool in munged slurmctld slurmd sinfo; do
  command -v "$tool" >/dev/null 2>&1 || PATH=$PATH:/usr/sbin
  if ! command -v "$tool" >/dev/null 2>&1; then
    echo "slurm_local: '$tool' not found; install slurm-wlm and munge" \
         "(scripts/install_deps.sh)" >&2
    exit 1
  fi
done
if [[ $(id -u) -ne 0 ]]; then
  echo "slurm_local: must run as root (slurmd runs jobs as their user)" >&2
  exit 1
fi

mkdir -p "$dir"/{munge,state,spool,log}
chmod 700 "$dir/munge"

# munge: a fresh key, its own socket, log and pid file.
key=$dir/munge/munge.key
if [[ ! -f $key ]]; then
  head -c 1024 /dev/urandom > "$key"
  chmod 400 "$key"
fi
socket=$dir/munge/munge.socket
munged --key-file="$key" --socket="$socket" --pid-file="$dir/munged.pid" \
       --log-file="$dir/log/munged.log" --seed-file="$dir/munge/munged.seed" \
       --force
for _ in $(seq 50); do [[ -S $socket ]] && break; sleep 0.1; done
[[ -S $socket ]] || { echo "slurm_local: munged did not start" \
                           "(see $dir/log/munged.log)" >&2; exit 1; }

# The node as slurmd sees it (CPUs, sockets, cores, threads, memory), so the
# controller does not drain it for a mismatch.
node_hw=$(slurmd -C | head -1 | tr ' ' '\n' |
          grep -E '^(CPUs|Boards|SocketsPerBoard|CoresPerSocket|ThreadsPerCore|RealMemory)=' |
          tr '\n' ' ')
conf=$dir/slurm.conf
cat > "$conf" <<EOF
ClusterName=somatest
SlurmctldHost=localhost
SlurmctldPort=$ctld_port
SlurmdPort=$slurmd_port
AuthType=auth/munge
# cred_expire: a requeued job waits cred_expire+1 s (default 120) to start again.
AuthInfo=socket=$socket,cred_expire=10
CredType=cred/munge
SlurmUser=root
SlurmdUser=root
StateSaveLocation=$dir/state
SlurmdSpoolDir=$dir/spool
SlurmctldPidFile=$dir/slurmctld.pid
SlurmdPidFile=$dir/slurmd.pid
SlurmctldLogFile=$dir/log/slurmctld.log
SlurmdLogFile=$dir/log/slurmd.log
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
SwitchType=switch/none
MpiDefault=none
SelectType=select/cons_tres
SelectTypeParameters=CR_CPU
JobAcctGatherType=jobacct_gather/none
AccountingStorageType=accounting_storage/none
JobCompType=jobcomp/filetxt
JobCompLoc=$dir/log/jobcomp.txt
ReturnToService=2
SchedulerType=sched/backfill
SchedulerParameters=sched_interval=1
MinJobAge=30
KillWait=5
InactiveLimit=0
EnforcePartLimits=ALL
NodeName=localhost NodeAddr=127.0.0.1 $node_hw State=UNKNOWN
PartitionName=debug Nodes=localhost Default=YES MaxTime=INFINITE State=UP
EOF

# slurmd (22.05) initialises a cgroup plugin even with proctrack/linuxproc and
# task/none; its default (autodetect) fails where no cgroup file system is
# mounted (a chroot, e.g. ../shared/tools/fresh-machine.sh: "No filesystem
# mounted on /sys/fs/cgroup"). Naming cgroup/v1 skips the detection; nothing
# here uses cgroups.
cat > "$dir/cgroup.conf" <<EOF
CgroupPlugin=cgroup/v1
EOF
export SLURM_CONF=$conf
slurmctld -D -i -f "$conf" > "$dir/log/slurmctld.out" 2>&1 &
echo $! > "$dir/slurmctld.pid"
slurmd -D -N localhost -f "$conf" > "$dir/log/slurmd.out" 2>&1 &
echo $! > "$dir/slurmd.pid"

for _ in $(seq 300); do
  state=$(sinfo -h -n localhost -o '%t' 2>/dev/null || true)
  [[ $state == idle ]] && break
  sleep 0.2
done
if [[ $state != idle ]]; then
  echo "slurm_local: the node did not become idle (state '${state:-none}');" \
       "see $dir/log/slurmctld.log and $dir/log/slurmd.log" >&2
  exit 1
fi
echo "export SLURM_CONF=$conf"
