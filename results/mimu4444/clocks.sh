#!/usr/bin/env bash
# Calibrates the six MIMU4444 recordings with the sample clocks in both modes (gyroscope-free and
# --use-gyro) into results/mimu4444/clocks/, then clocks.md from them (issue 28, item 5).
set -euo pipefail
cd "$(dirname "$0")/../.."
data=../shared/data/mimu4444
out=results/mimu4444/clocks
mkdir -p "$out"
cargo build --release --quiet
for k in 1 2 3 4 5 6; do
  ./target/release/gfcal calibrate "$data/recording_$k.parquet" --array configs/arrays/mimu4444_corners.toml \
    --json "$out/r${k}_free.json" > "$out/r${k}_free.txt"
  ./target/release/gfcal calibrate "$data/recording_$k.parquet" --array configs/arrays/mimu4444_corners.toml \
    --use-gyro --json "$out/r${k}_gyro.json" > "$out/r${k}_gyro.txt"
done
python3 results/mimu4444/clocks.py "$out" results/mimu4444 > results/mimu4444/clocks.md
