#!/usr/bin/env bash
# A real Slurm run: installs Debian's slurm-wlm and munge (if missing), starts a one-node cluster on
# this machine (slurmctld and slurmd on loopback), submits the README's job file
# (configs/slurm/job_array.sh) as an array of 4 tasks that all start at the same moment into one
# folder, waits, runs `gfcal summarize`, and compares every table with an unsharded run.
#
#   .ci/slurm.sh CONFIG UNSHARDED_RUN_DIR PYTHON_WITH_PYARROW
#
# Needs root (it writes /etc/slurm/slurm.conf and starts daemons) and target/release/gfcal, or the
# binary GFCAL_BIN names (.ci/run passes the test build's).
set -euo pipefail
cd "$(dirname "$0")/.."
config=$1
unsharded=$2
python=$3
gfcal=${GFCAL_BIN:-${CARGO_TARGET_DIR:-$PWD/target}/release/gfcal}
test -x "$gfcal" || { echo "slurm.sh: build target/release/gfcal first (or name a binary in GFCAL_BIN)" >&2; exit 2; }
t0=$(date +%s)

if ! command -v slurmctld > /dev/null || ! command -v munged > /dev/null; then
  echo "== installing slurm-wlm and munge"
  apt-get update -qq
  DEBIAN_FRONTEND=noninteractive apt-get install -y -qq slurm-wlm munge > /dev/null
fi
t_installed=$(date +%s)

work=$(mktemp -d /tmp/gfcal-slurm.XXXXXX)
chmod 755 "$work"
stop() {
  scancel --full --quiet --user root 2> /dev/null || true
  [ -f "$work/slurmd.pid" ] && kill "$(cat "$work/slurmd.pid")" 2> /dev/null || true
  [ -f "$work/slurmctld.pid" ] && kill "$(cat "$work/slurmctld.pid")" 2> /dev/null || true
  [ -f /run/munge/munged.pid ] && kill "$(cat /run/munge/munged.pid)" 2> /dev/null || true
}
trap stop EXIT

echo "== munge"
if [ ! -s /etc/munge/munge.key ]; then
  dd if=/dev/urandom of=/etc/munge/munge.key bs=1024 count=1 status=none
fi
chown munge:munge /etc/munge/munge.key
chmod 400 /etc/munge/munge.key
mkdir -p /run/munge /var/log/munge /var/lib/munge
chown munge:munge /run/munge /var/log/munge /var/lib/munge
runuser -u munge -- /usr/sbin/munged --force
munge -n | unmunge > /dev/null

echo "== slurmctld and slurmd (one node, loopback)"
host=$(hostname -s)
mkdir -p "$work/state" "$work/spool" /etc/slurm
# Four CPUs on the node even on a 2-core machine, so that the 4 tasks start at the same moment.
cat > /etc/slurm/slurm.conf <<CONF
ClusterName=gfcal-ci
SlurmctldHost=$host(127.0.0.1)
SlurmUser=root
SlurmdUser=root
AuthType=auth/munge
CredType=cred/munge
MpiDefault=none
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
SlurmdParameters=config_overrides
SchedulerType=sched/backfill
SelectType=select/cons_tres
SelectTypeParameters=CR_CPU
ReturnToService=2
JobAcctGatherType=jobacct_gather/none
AccountingStorageType=accounting_storage/none
StateSaveLocation=$work/state
SlurmdSpoolDir=$work/spool
SlurmctldPidFile=$work/slurmctld.pid
SlurmdPidFile=$work/slurmd.pid
SlurmctldLogFile=$work/slurmctld.log
SlurmdLogFile=$work/slurmd.log
NodeName=$host NodeAddr=127.0.0.1 CPUs=4 RealMemory=2000 State=UNKNOWN
PartitionName=ci Nodes=ALL Default=YES MaxTime=INFINITE State=UP
CONF
slurmctld -i
slurmd -N "$host"
for _ in $(seq 1 60); do
  sinfo --noheader --Format=StateCompact 2> /dev/null | grep -q idle && break
  sleep 1
done
sinfo --noheader --Format=StateCompact | grep -q idle || {
  echo "slurm.sh: the node did not come up" >&2
  sinfo >&2 || true
  tail -n 30 "$work/slurmctld.log" "$work/slurmd.log" >&2 || true
  exit 1
}
t_started=$(date +%s)

echo "== sbatch --array=0-3 configs/slurm/job_array.sh $config"
sharded="$work/sharded"
set +e
sbatch --wait --array=0-3 --cpus-per-task=1 --output="$work/task-%a.out" \
  configs/slurm/job_array.sh "$config" "$sharded" "$gfcal"
status=$?
set -e
for f in "$work"/task-*.out; do
  echo "-- $(basename "$f")"
  grep "^gfcal:" "$f" | grep -v "trials/s" || true
done
if [ $status -ne 0 ]; then
  echo "slurm.sh: the job array failed (sbatch exit $status)" >&2
  exit 1
fi
t_ran=$(date +%s)
# Each part was computed by exactly one task.
written=$(grep -ho "[0-9]* parts written" "$work"/task-*.out | awk '{s += $1} END {print s}')
total=$("$python" -c 'import json, sys; print(json.load(open(sys.argv[1]))["parts_total"])' "$sharded/run.json")
[ "$written" -eq "$total" ] || { echo "slurm.sh: $written parts written by the tasks, $total in the run" >&2; exit 1; }

echo "== gfcal summarize on the sharded folder, then compare with the unsharded run"
"$gfcal" summarize "$sharded" > /dev/null
"$python" - "$unsharded" "$sharded" <<'PY'
import sys, pathlib, numpy as np, pyarrow as pa, pyarrow.parquet as pq
a, b = (pathlib.Path(p) for p in sys.argv[1:3])

def same(ta, tb):
    """Equal columns, NaN equal to NaN and null to null in the same place (no estimate: null in the
    drift columns, NaN in the parameters)."""
    if ta.schema.names != tb.schema.names or ta.num_rows != tb.num_rows:
        return False
    for x, y in zip(ta.columns, tb.columns):
        if x.null_count != y.null_count or not x.is_null().equals(y.is_null()):
            return False
        if pa.types.is_floating(x.type):
            if not np.array_equal(x.to_numpy(), y.to_numpy(), equal_nan=True):
                return False
        elif not x.equals(y):
            return False
    return True

n = 0
for sub in ("trials", "parameters"):
    fa = sorted(p.name for p in (a / sub).glob("*.parquet"))
    fb = sorted(p.name for p in (b / sub).glob("*.parquet"))
    assert fa == fb, f"{sub}: different part files"
    for name in fa:
        ta, tb = pq.read_table(a / sub / name), pq.read_table(b / sub / name)
        assert same(ta, tb), f"{sub}/{name} differs"
        n += ta.num_rows
sa, sb = (a / "summary.csv").read_text(), (b / "summary.csv").read_text()
assert sa == sb, "summary.csv differs"
print(f"identical: {n} rows in {len(fa)} parts per table, and summary.csv")
PY
# A finished run leaves no lock file or empty folder (issue 30; summarize tidies after the last task).
# (No `find` on locks/: it is gone, and under pipefail a failing find would end this script silently.)
if [ -e "$sharded/locks" ]; then
  echo "slurm.sh: the locks/ folder is left behind, with $(ls -A "$sharded/locks" | wc -l) part claim(s)" >&2
  exit 1
fi
[ ! -e "$sharded/.gfcal-run.lock" ] || { echo "slurm.sh: the run's lock file is left behind" >&2; exit 1; }
echo "slurm: install $((t_installed - t0)) s, cluster start $((t_started - t_installed)) s, job array $((t_ran - t_started)) s"
