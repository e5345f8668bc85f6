#!/usr/bin/env bash
# Regenerates results/mimu4444/: calibrates each of the six recordings (the other five held out),
# writes recording_K.json and recording_K.html, runs the Monte Carlo prediction of the protocol
# (configs/mimu4444_protocol.toml into protocol_run/), then tables.md from them (summarize.py).
set -euo pipefail
cd "$(dirname "$0")/../.."
data=../shared/data/mimu4444
for k in 1 2 3 4 5 6; do
  others=()
  for m in 1 2 3 4 5 6; do [ "$m" = "$k" ] || others+=("$data/recording_$m.parquet"); done
  cargo run --release --quiet -- calibrate "$data/recording_$k.parquet" --array configs/arrays/mimu4444_corners.toml \
    --json "results/mimu4444/recording_$k.json" --report "results/mimu4444/recording_$k.html" --held-out "${others[@]}" \
    > "results/mimu4444/recording_$k.txt"
done
# The Monte Carlo prediction of the protocol (100 simulated recordings: 14 min on 2026-11-28 on a slow machine, the clocks' outer iterations run to convergence).
rm -rf results/mimu4444/protocol_run
cargo run --release --quiet -- run configs/mimu4444_protocol.toml --out results/mimu4444/protocol_run > /dev/null
python3 results/mimu4444/summarize.py results/mimu4444 > results/mimu4444/tables.md
python3 results/mimu4444/figures.py results/mimu4444
