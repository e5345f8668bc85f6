#!/bin/sh
# LinCov's error budget against the Sobol' indices of the same error distributions (docs/lincov.md,
# "Error budget and the sensitivity ranking"): the Saltelli design of configs/sobol_indices.toml
# (500 base samples x 44 = 22,000 trials), then `gfcal lincov --compare` on it (ranking.csv: LinCov's
# share, |SRRC|, Sobol' first-order and total index of every parameter for every drift column).
# Writes results/lincov/sobol.md.
#   cargo build --release --locked && results/lincov/sobol.sh [WORK_DIR]     (repository root)
set -eu
GFCAL=${GFCAL:-target/release/gfcal}
WORK=${1:-/tmp/lincov_sobol}
mkdir -p "$WORK"
"$GFCAL" run configs/sobol_indices.toml --out "$WORK/sobol_indices" --force --threads 2 > /dev/null
"$GFCAL" lincov configs/sobol_indices.toml --out "$WORK/sobol_indices" --compare "$WORK/sobol_indices" \
    --threads 2 > /dev/null
python3 results/lincov/tabulate.py --sobol "$WORK/sobol_indices" > results/lincov/sobol.md
