#!/usr/bin/env bash
# The accelerometers' lag behind the gyroscopes on any recording of the board (docs/real-hardware.md, "The
# accelerometers' lag behind the gyroscopes"): calibrates each recording given (default: the six in
# ../shared/data/mimu4444/) with --use-gyro and the array file's accelerometer_lag_ms set to 0, 1.0, 1.3, 1.4,
# 1.5, 1.6, 1.7, 2.0 and 3.0 ms in turn, prints the rotation-phase chi^2/dof of each and the minimum of a parabola
# through the three points around the lowest (a few percent of bumps from the fit's stopping points; a value far
# below its neighbours is a fit that ended in another minimum, not the lag). The shipped file declares 1.5 ms,
# fitted on the six recordings; another recording of the board should put its minimum within 1.4-1.6 ms.
#   bash results/mimu4444/lag_scan.sh [RECORDING.parquet ...]      (GFCAL=path/to/gfcal to skip the build)
set -euo pipefail
cd "$(dirname "$0")/../.."
array=configs/arrays/mimu4444_corners.toml
if [ "$#" -eq 0 ]; then set -- ../shared/data/mimu4444/recording_{1,2,3,4,5,6}.parquet; fi
if [ -z "${GFCAL-}" ]; then cargo build --release --quiet; GFCAL=./target/release/gfcal; fi
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
lags=(0 1.0 1.3 1.4 1.5 1.6 1.7 2.0 3.0)
for lag in "${lags[@]}"; do
  grep -v '^accelerometer_lag_ms' "$array" \
    | sed "s/^name = \"mimu4444_corners\"/name = \"mimu4444_corners\"\naccelerometer_lag_ms = $lag/" > "$tmp/array_$lag.toml"
done
echo "| recording | $(printf '%s ms | ' "${lags[@]}")minimum, ms |"
for rec in "$@"; do
  values=()
  for lag in "${lags[@]}"; do
    if ! "$GFCAL" calibrate "$rec" --array "$tmp/array_$lag.toml" --use-gyro --json "$tmp/out.json" > /dev/null 2> "$tmp/err"; then
      cat "$tmp/err" >&2
      exit 1
    fi
    values+=("$(python3 -c "import json; print(json.load(open('$tmp/out.json'))['dynamic']['chi2_dof'])")")
  done
  python3 - "$rec" "${lags[*]}" "${values[*]}" <<'PY'
import sys
rec, lags, values = sys.argv[1], [float(x) for x in sys.argv[2].split()], [float(x) for x in sys.argv[3].split()]
k = min(range(1, len(values) - 1), key=lambda i: values[i]) if len(values) > 2 else 0
(x0, x1, x2), (y0, y1, y2) = lags[k - 1:k + 2], values[k - 1:k + 2]
# The vertex of the parabola through the three points.
num = (x1 - x0) ** 2 * (y1 - y2) - (x1 - x2) ** 2 * (y1 - y0)
den = (x1 - x0) * (y1 - y2) - (x1 - x2) * (y1 - y0)
vertex = x1 - 0.5 * num / den if den != 0 else float("nan")
print(f"| {rec} | " + " | ".join(f"{v:.1f}" for v in values) + f" | {vertex:.2f} |")
PY
done
