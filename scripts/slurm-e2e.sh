#!/usr/bin/env bash
# End-to-end test of `nlsim batch` on a real SLURM: starts munged, slurmctld and slurmd as a
# single node on loopback (no systemd, no accounting), submits a job array through
# `nlsim batch sbatch --submit`, waits for it, merges the shards, checks the merged file equals
# a single-process run bit for bit (scripts/h5check.py), and stops the daemons by PID.
#
#   scripts/slurm-e2e.sh PATH/TO/nlsim
#
# Needs Debian's slurm-wlm, munge and python3-h5py (scripts/ensure-deps.sh --test installs
# them) and root (slurmd runs jobs as their user).
set -euo pipefail
nlsim=$(realpath "${1:?usage: scripts/slurm-e2e.sh PATH/TO/nlsim}")
here=$(cd "$(dirname "$0")" && pwd)
say() { printf 'slurm-e2e: %s\n' "$*" >&2; }

for cmd in munged slurmctld slurmd sbatch squeue; do
  command -v "$cmd" >/dev/null || { say "$cmd not found: run scripts/ensure-deps.sh --test"; exit 1; }
done
if [ "$(id -u)" -ne 0 ]; then
  # CI runs as root; a developer without root is told, not failed.
  [ -n "${CI:-}" ] && { say "needs root (slurmd starts jobs as their user)"; exit 1; }
  say "skipped: needs root (slurmd starts jobs as their user); CI runs it"
  exit 0
fi
py=$("$here/find-h5py.sh")

work=$(mktemp -d /tmp/nlsim-slurm.XXXXXX)
pids=()
cleanup() {
  local rc=$?
  for p in "${pids[@]}"; do kill "$p" 2>/dev/null || true; done
  for p in "${pids[@]}"; do
    for _ in $(seq 50); do kill -0 "$p" 2>/dev/null || break; sleep 0.1; done
    kill -9 "$p" 2>/dev/null || true
  done
  if [ $rc -ne 0 ]; then
    say "failed; daemon logs:"
    tail -n 20 "$work"/*.log >&2 2>/dev/null || true
    tail -n 20 "$work"/out/logs/* >&2 2>/dev/null || true
  fi
  rm -rf "$work"
  exit $rc
}
trap cleanup EXIT

# munge: its own key, socket and pid file under $work.
mkdir -p "$work/munge"
chmod 700 "$work/munge"
dd if=/dev/urandom of="$work/munge/munge.key" bs=1024 count=1 status=none
chmod 400 "$work/munge/munge.key"
socket="$work/munge/munge.socket"
munged --force --key-file="$work/munge/munge.key" --socket="$socket" \
  --pid-file="$work/munge/munged.pid" --log-file="$work/munged.log" --seed-file="$work/munge/seed"
for _ in $(seq 50); do [ -s "$work/munge/munged.pid" ] && break; sleep 0.1; done
pids+=("$(cat "$work/munge/munged.pid")")

cpus=$(nproc)
mkdir -p "$work/state" "$work/spool"
cat > "$work/slurm.conf" <<EOF
ClusterName=nlsimci
SlurmctldHost=localhost(127.0.0.1)
SlurmUser=root
SlurmdUser=root
AuthType=auth/munge
AuthInfo=socket=$socket
CredType=cred/munge
SlurmctldPort=16817
SlurmdPort=16818
StateSaveLocation=$work/state
SlurmdSpoolDir=$work/spool
SlurmctldPidFile=$work/slurmctld.pid
SlurmdPidFile=$work/slurmd.pid
SlurmctldLogFile=$work/slurmctld.log
SlurmdLogFile=$work/slurmd.log
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
JobAcctGatherType=jobacct_gather/none
AccountingStorageType=accounting_storage/none
SchedulerType=sched/backfill
SelectType=select/cons_tres
SelectTypeParameters=CR_Core
MpiDefault=none
ReturnToService=2
NodeName=nlsimnode NodeAddr=127.0.0.1 NodeHostname=localhost CPUs=$cpus State=UNKNOWN
PartitionName=ci Nodes=nlsimnode Default=YES MaxTime=INFINITE State=UP
EOF
export SLURM_CONF="$work/slurm.conf"

slurmctld -D -i >"$work/slurmctld.out" 2>&1 &
pids+=($!)
slurmd -D -N nlsimnode >"$work/slurmd.out" 2>&1 &
pids+=($!)
for i in $(seq 100); do
  state=$(sinfo -h -N -o '%T' 2>/dev/null | head -n1 || true)
  [ "$state" = idle ] && break
  [ "$i" -eq 100 ] && { say "the node did not come up (state '$state')"; exit 1; }
  sleep 0.3
done
say "SLURM up: node nlsimnode idle with $cpus CPUs"

# A batch of 12 FRFs: 2 force levels x a 6-point Latin hypercube of the cubic stiffness.
cat > "$work/jobs.toml" <<'EOF'
name = "slurm-e2e"
command = "frf"
model = "duffing_fig3"
seed = 11
output = "out"

[frf]
from = 22.0
to = 40.0
harmonics = 3
mode = "step-up"
points = 60

[[sweep]]
option = "force"
values = [1.0, 2.0]

[lhs]
samples = 6
params = [{ set = "spring.k3", min = 5e14, max = 5e15, log = true }]
EOF

tasks=3
id=$("$nlsim" --quiet batch sbatch "$work/jobs.toml" --tasks "$tasks" --submit)
say "submitted job array $id ($tasks tasks)"
for i in $(seq 600); do
  [ -z "$(squeue -h -j "$id" 2>/dev/null || true)" ] && break
  [ "$i" -eq 600 ] && { say "job $id still queued or running after 120 s"; squeue >&2; exit 1; }
  sleep 0.2
done
"$nlsim" batch merge "$work/jobs.toml"
"$nlsim" --quiet batch "$work/jobs.toml" --output "$work/single" --task-count 1 --task-index 0
"$nlsim" --quiet batch merge "$work/jobs.toml" --output "$work/single"
"$py" "$here/h5check.py" read "$work/out/merged.h5"
"$py" "$here/h5check.py" same "$work/out/merged.h5" "$work/single/merged.h5"
say "passed: $tasks SLURM array tasks merged equal a single-process run bit for bit"
