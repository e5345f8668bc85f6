#!/bin/bash
# A Slurm job array that runs one gfcal sweep as shards into one folder on a shared file system.
#
#   sbatch configs/slurm/job_array.sh CONFIG OUT [GFCAL]
#   sbatch --array=0-3 --cpus-per-task=1 configs/slurm/job_array.sh configs/quickstart.toml runs/q   (options override)
#
# Each task runs shard SLURM_ARRAY_TASK_ID - SLURM_ARRAY_TASK_MIN of SLURM_ARRAY_TASK_COUNT. The tasks
# may start at the same moment: the first prepares the folder, the others join it, and each part is
# computed by one process. A task that is preempted or fails can be resubmitted as it is (--resume).
# When every task is done: gfcal summarize OUT.
#SBATCH --job-name=gfcal
#SBATCH --array=0-31
#SBATCH --cpus-per-task=8
#SBATCH --time=02:00:00
#SBATCH --output=gfcal-%A_%a.out
set -euo pipefail
config=${1:?usage: sbatch job_array.sh CONFIG OUT [GFCAL]}
out=${2:?usage: sbatch job_array.sh CONFIG OUT [GFCAL]}
gfcal=${3:-./target/release/gfcal}
srun "$gfcal" run "$config" --out "$out" --threads "${SLURM_CPUS_PER_TASK:-1}" --resume
