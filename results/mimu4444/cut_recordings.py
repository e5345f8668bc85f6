#!/usr/bin/env python3
"""The six recordings cut shorter, as stand-ins for recordings the calibration has not seen (EXPECTATIONS.md (bb)).

Per recording three cut tables, written into WORK (never into the repository): R60 and R35 keep the first 60% and
35% of the rotation phase (its interval from `recording_K.json`'s segmentation; every row after the cut dropped),
S-5 drops the first 130 s (about five static poses). Each is calibrated gyroscope-free as `run.sh` does it, without
held-out recordings, and set against the whole recording's calibration (`recording_K.json`): the rate against the
gyroscopes (overall and above 20 rad/s), the largest distance between two axes' sensing points in one package, the
clocks' share of the rotation phase's misfit, and the relative clock rates (each package's rate offset less the
eight's mean; the whole recording's carried to the cut one's reference time by its drift) within 3 of the cut
recording's sigma. Prints a Markdown table.

    python3 results/mimu4444/cut_recordings.py WORK     (repository root; needs pyarrow; GFCAL=path/to/gfcal,
                                                         default target/release/gfcal)
"""
import json
import math
import os
import subprocess
import sys
from pathlib import Path

import pyarrow.compute as pc
import pyarrow.parquet as pq

DATA = Path("../shared/data/mimu4444")
RESULTS = Path("results/mimu4444")
ARRAY = "configs/arrays/mimu4444_corners.toml"
GFCAL = os.environ.get("GFCAL", "target/release/gfcal")
RECORDINGS = range(1, 7)


def cut_tables(k, work):
    table = pq.read_table(DATA / f"recording_{k}.parquet")
    full = json.loads((RESULTS / f"recording_{k}.json").read_text())
    rotation = full["segmentation"]["dynamic_intervals"][0]
    start, end = rotation["start_s"], rotation["end_s"]
    t = table.column("t_s")
    cuts = {
        "R60": pc.less_equal(t, start + 0.6 * (end - start)),
        "R35": pc.less_equal(t, start + 0.35 * (end - start)),
        "S-5": pc.greater_equal(t, 130.0),
    }
    for name, keep in cuts.items():
        pq.write_table(table.filter(keep), work / f"recording_{k}_{name}.parquet")
    return full


def within_package_mm(parameters):
    loc = {}
    for p in parameters:
        if p["name"] in ("dx", "dy", "dz"):
            loc.setdefault(p["accelerometer"], {})[p["name"]] = p["value"]
    packages = len(loc) // 3
    out = []
    for q in range(packages):
        axes = [[loc[3 * q + i + 1][c] for c in ("dx", "dy", "dz")] for i in range(3)]
        out.append(1000 * max(math.dist(a, b) for a in axes for b in axes))
    return max(out)


def above(check, low_rad_s):
    err = ref = 0.0
    for band in check["by_rate"]:
        if band["low_rad_s"] >= low_rad_s and band["samples"]:
            err += band["rms_rad_s"] ** 2 * band["samples"]
            ref += (band["rms_rad_s"] / band["relative"]) ** 2 * band["samples"]
    return math.sqrt(err / ref)


def relative_rates(clocks, t_ref_s):
    rates = [c["rate_offset_ppm"] + c["drift_ppm_per_s"] * (t_ref_s - c["phase_time_s"]) for c in clocks]
    mean = sum(rates) / len(rates)
    return [r - mean for r in rates]


def main():
    work = Path(sys.argv[1])
    work.mkdir(parents=True, exist_ok=True)
    print("| variant | recording | exit | rate off the gyroscopes | above 20 rad/s | within-package distance (mm) | clocks' share removed | clocks fitted | relative rates within 3 sigma |")
    print("|---|---|---|---|---|---|---|---|---|")
    for k in RECORDINGS:
        full = cut_tables(k, work)
        for name in ("R60", "R35", "S-5"):
            table, out = work / f"recording_{k}_{name}.parquet", work / f"recording_{k}_{name}.json"
            run = subprocess.run([GFCAL, "calibrate", str(table), "--array", ARRAY, "--json", str(out)],
                                 capture_output=True, text=True)
            if run.returncode != 0:
                print(f"| {name} | {k} | {run.returncode} | | | | | | |")
                continue
            j = json.loads(out.read_text())
            clocks = j.get("sample_clocks") or []
            agree = ""
            if clocks and full.get("sample_clocks"):
                t_ref_s = clocks[0]["phase_time_s"]
                mine = relative_rates(clocks, t_ref_s)
                theirs = relative_rates(full["sample_clocks"], t_ref_s)
                n = sum(abs(a - b) <= 3 * c["rate_offset_sigma_ppm"] for a, b, c in zip(mine, theirs, clocks))
                agree = f"{n} of {len(clocks)}"
            check = j.get("gyro_check") or {}
            model = j.get("sample_clock_model") or {}
            share = model.get("share_removed")
            print(
                f"| {name} | {k} | 0 | {100 * check['relative']:.1f}% | {100 * above(check, 20.0):.1f}% | "
                f"{within_package_mm(j['parameters']):.2f} | "
                + (f"{100 * share:.1f}%" if share is not None else "")
                + f" | {len(clocks)} | {agree} |"
            )


if __name__ == "__main__":
    main()
