#!/usr/bin/env bash
# Captures the outputs that a refactoring must not change, into DIR:
#   .ci/outputs.sh capture DIR        (builds the release binary first)
#   .ci/outputs.sh compare OLD NEW    (exit 1 on any difference; needs python3 with pyarrow)
# What is captured: the quickstart's Parquet tables and summary, `gfcal paper`, `gfcal drift --csv`,
# `calibrate --json` and `diagnose --json` on two real recordings (gyroscope-free and --use-gyro),
# a simulated log and its diagnosis. Time stamps, durations and the commit are masked by
# .ci/compare_outputs.py; everything else must be byte-identical (Parquet: every column bit-identical).
set -euo pipefail
cd "$(dirname "$0")/.."
case "${1-}" in
  capture)
    out=$2
    rm -rf "$out"; mkdir -p "$out"
    out=$(cd "$out" && pwd)
    echo "$out" > "$out/.captured_into"
    cargo build --release --quiet
    bin=./target/release/gfcal
    data=../shared/data/mimu4444
    arr=configs/arrays/mimu4444_corners.toml
    $bin run configs/quickstart.toml --out "$out/quickstart" --threads 2 > "$out/quickstart.txt"
    $bin summarize "$out/quickstart" > "$out/summarize.txt"
    $bin sensitivity "$out/quickstart" --max-trials 5000 > "$out/sensitivity.txt"
    $bin paper --out "$out/paper" --trials 200 > "$out/paper.txt"
    $bin drift configs/paper_manoeuvre.toml --csv "$out/drift.csv" > "$out/drift.txt"
    $bin identify configs/hung_lee_2006_design.toml > "$out/identify.txt"
    for k in 1 4; do
      $bin calibrate "$data/recording_$k.parquet" --array "$arr" --json "$out/calibrate_$k.json" \
        --held-out "$data/recording_2.parquet" > "$out/calibrate_$k.txt"
      $bin calibrate "$data/recording_$k.parquet" --array "$arr" --use-gyro --json "$out/calibrate_gyro_$k.json" \
        > "$out/calibrate_gyro_$k.txt"
      $bin diagnose "$data/recording_$k.parquet" --array "$arr" --json "$out/diagnose_$k.json" \
        --held-out "$data/recording_3.parquet" > "$out/diagnose_$k.txt"
    done
    $bin simulate-log configs/discrepancy_example.toml --out "$out/log.csv" > "$out/simulate.txt"
    $bin diagnose "$out/log.csv" --json "$out/diagnose_log.json" > "$out/diagnose_log.txt"
    echo "captured into $out"
    ;;
  compare)
    python3 .ci/compare_outputs.py "$2" "$3"
    ;;
  *)
    echo "usage: .ci/outputs.sh capture DIR | compare OLD NEW" >&2; exit 2 ;;
esac
