#!/usr/bin/env bash
# Regenerates the diagnosis of the six recordings (issue 11): each recording in turn is the fitting
# one and the other five are held out; writes diagnose_K.json, diagnose_K.txt and the report
# diagnose_K.html, then gaps.md (gaps.py). About two minutes with a release build.
# With --use-gyro (run_gyro.sh): the rate from the gyroscopes, diagnose_gyro_K.json and .txt only.
# GFCAL=path/to/gfcal runs that binary instead of building the release one.
set -euo pipefail
cd "$(dirname "$0")/../../.."
data=../shared/data/mimu4444
out=results/mimu4444/discrepancy
gyro=false
[ "${1-}" = "--use-gyro" ] && gyro=true
if [ -z "${GFCAL-}" ]; then cargo build --release --quiet; GFCAL=./target/release/gfcal; fi
for k in 1 2 3 4 5 6; do
  others=()
  for m in 1 2 3 4 5 6; do [ "$m" = "$k" ] || others+=("$data/recording_$m.parquet"); done
  if $gyro; then extra=(--use-gyro); stem="diagnose_gyro_$k"; else extra=(--report "$out/diagnose_$k.html"); stem="diagnose_$k"; fi
  "$GFCAL" diagnose "$data/recording_$k.parquet" --array configs/arrays/mimu4444_corners.toml \
    "${extra[@]}" --held-out "${others[@]}" --json "$out/$stem.json" > "$out/$stem.txt"
done
$gyro || python3 "$out/gaps.py" "$out" > "$out/gaps.md"
