#!/usr/bin/env bash
# The same six diagnoses as run.sh with the angular rate taken from the board's gyroscopes
# (`--use-gyro`), so that the gyroscopes' own scale factor and misalignment can be tried; writes
# diagnose_gyro_K.json and diagnose_gyro_K.txt. About a minute with a release build.
set -euo pipefail
cd "$(dirname "$0")/../../.."
data=../shared/data/mimu4444
out=results/mimu4444/discrepancy
cargo build --release --quiet
for k in 1 2 3 4 5 6; do
  others=()
  for m in 1 2 3 4 5 6; do [ "$m" = "$k" ] || others+=("$data/recording_$m.parquet"); done
  ./target/release/gfcal diagnose "$data/recording_$k.parquet" --array configs/arrays/mimu4444_corners.toml \
    --use-gyro --held-out "${others[@]}" --json "$out/diagnose_gyro_$k.json" > "$out/diagnose_gyro_$k.txt"
done
