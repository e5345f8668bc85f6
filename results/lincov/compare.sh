#!/bin/sh
# LinCov against 20,000 Monte Carlo trials on four configs (docs/lincov.md, "Checked against Monte
# Carlo"): the paper's errors on the paper's and the augmented schedule (configs/hung_lee_2006.toml
# at 20,000 trials), the nine accelerometers, a tilted fixture with navigation noise, the quickstart.
# Writes the runs under WORK_DIR and the table results/lincov/compare.md; times in WORK_DIR/times.txt.
#   cargo build --release --locked && results/lincov/compare.sh [WORK_DIR]     (repository root)
set -eu
GFCAL=${GFCAL:-target/release/gfcal}
WORK=${1:-/tmp/lincov_compare}
mkdir -p "$WORK"
sed -e 's/^trials_per_cell = 1000$/trials_per_cell = 20000/' -e 's/^trials_per_part = 1000$/trials_per_part = 2048/' \
    configs/hung_lee_2006.toml > "$WORK/hung_lee_2006_20000.toml"
for cfg in "$WORK/hung_lee_2006_20000.toml" configs/nine_accelerometer_run.toml configs/fixture_error.toml \
    configs/quickstart.toml; do
    name=$(basename "$cfg" .toml)
    start=$(date +%s.%N)
    "$GFCAL" run "$cfg" --out "$WORK/$name" --force --threads 2
    mid=$(date +%s.%N)
    "$GFCAL" lincov "$cfg" --out "$WORK/$name" --compare "$WORK/$name" --threads 2
    end=$(date +%s.%N)
    echo "$name monte_carlo_s $(echo "$mid - $start" | bc) lincov_s $(echo "$end - $mid" | bc)" >> "$WORK/times.txt"
done
python3 results/lincov/tabulate.py "$WORK" > results/lincov/compare.md
