#!/usr/bin/env bash
# Regenerates the diagnosis of the six recordings (issue 11): each recording in turn is the fitting
# one and the other five are held out; writes diagnose_K.json, diagnose_K.txt and the report
# diagnose_K.html, then gaps.md
# (gaps.py). About a minute with a release build.
set -euo pipefail
cd "$(dirname "$0")/../../.."
data=../shared/data/mimu4444
out=results/mimu4444/discrepancy
cargo build --release --quiet
for k in 1 2 3 4 5 6; do
  others=()
  for m in 1 2 3 4 5 6; do [ "$m" = "$k" ] || others+=("$data/recording_$m.parquet"); done
  ./target/release/gfcal diagnose "$data/recording_$k.parquet" --array configs/arrays/mimu4444_corners.toml \
    --held-out "${others[@]}" --json "$out/diagnose_$k.json" --report "$out/diagnose_$k.html" > "$out/diagnose_$k.txt"
done
python3 "$out/gaps.py" "$out" > "$out/gaps.md"
