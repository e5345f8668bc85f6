"""What widens the six recordings' spread of scale factors and tilts beyond the Monte Carlo's prediction.

Reads the six calibrations (recording_K.json, as run.sh writes them), the recordings themselves
(../shared/data/mimu4444/) and the protocol's Monte Carlo summary (protocol_run/summary.csv), and
writes static_tension.md:
1. the spread split by recording (the three with a static chi^2/dof near 2 against the other three);
2. per recording, the static chi^2/dof as fitted and with each accelerometer's bias, scale factor and
   tilts refitted to the static pose means alone (the poses held at the joint fit's): how far the
   joint fit's rotation phase pulls the intrinsic parameters from what the static phase says;
3. the spread over the six recordings with those static-only parameters, without and with a bias
   drift in time per accelerometer.
The static model is written again here from docs/model.md (output = k (b + a . g up), the axis
tilted from nominal by tilt_u, tilt_w in the basis of sensor::misalignment::tilt_basis), not taken
from gfcal: part 2's "as fitted" column reproduces the chi^2/dof that gfcal calibrate prints, which
checks it.

    python3 results/mimu4444/static_tension.py     (repository root; needs numpy and pyarrow)
"""

import csv
import json
import math
import statistics as st
import sys
import tomllib
from collections import Counter
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq

ROOT = Path(__file__).resolve().parents[2]
RESULTS = ROOT / "results" / "mimu4444"
DATA = ROOT.parent / "shared" / "data" / "mimu4444"
GRAVITY_M_S2 = 9.80665
RECORDINGS = range(1, 7)


def tilt_basis(theta):
    k = int(np.argmin(np.abs(theta)))
    e = np.zeros(3)
    e[k] = 1.0
    u = e - theta * theta.dot(e)
    u /= np.linalg.norm(u)
    return u, np.cross(theta, u)


def tilted_axis(theta, tilt_u_rad, tilt_w_rad):
    u, w = tilt_basis(theta)
    phi = math.hypot(tilt_u_rad, tilt_w_rad)
    if phi == 0.0:
        return theta
    return theta * math.cos(phi) + (u * tilt_u_rad + w * tilt_w_rad) * (math.sin(phi) / phi)


def static_output(x, theta, ups, t_rel_s):
    """x = (scale factor, bias m/s^2, tilt_u rad, tilt_w rad, bias drift m/s^2/s)."""
    a = tilted_axis(theta, x[2], x[3])
    return x[0] * (x[1] + x[4] * t_rel_s + ups @ a * GRAVITY_M_S2)


def refit(x0, theta, ups, t_rel_s, means, weights, with_drift):
    """Weighted Gauss-Newton on the static pose means alone (central differences)."""
    x = np.array(x0, float)
    free = [0, 1, 2, 3] + ([4] if with_drift else [])
    sw = np.sqrt(weights)
    for _ in range(6):
        pred = static_output(x, theta, ups, t_rel_s)
        cols = []
        for q in free:
            h = 1e-7 if q != 4 else 1e-9
            xp, xm = x.copy(), x.copy()
            xp[q] += h
            xm[q] -= h
            cols.append((static_output(xp, theta, ups, t_rel_s) - static_output(xm, theta, ups, t_rel_s)) / (2 * h))
        jac = np.column_stack(cols)
        step, *_ = np.linalg.lstsq(jac * sw[:, None], (means - pred) * sw, rcond=None)
        x[free] += step
    return x


def main():
    array = tomllib.load(open(ROOT / "configs" / "arrays" / "mimu4444_corners.toml", "rb"))["accelerometer"]
    rows = [r for r in csv.DictReader(open(RESULTS / "protocol_run" / "summary.csv")) if r["table"] == "parameter"]
    rmse = {(r["name"].split(".")[1], int(r["name"].split(".")[0][1:])): float(r["rmse"]) for r in rows}
    kinds = ["scale_factor", "tilt_u", "tilt_w"]
    joint, static, static_drift = {}, {}, {}
    per_recording = []
    for k in RECORDINGS:
        cal = json.load(open(RESULTS / f"recording_{k}.json"))
        table = pq.read_table(DATA / f"recording_{k}.parquet")
        t_s = table.column("t_s").to_numpy()
        par = {(p["accelerometer"], p["name"]): (p["value"], p["sigma"]) for p in cal["parameters"]}
        noise = cal["static"]["noise_sigma_m_s2"]
        poses = cal["poses"]
        ups = np.array([[p["up_x"], p["up_y"], p["up_z"]] for p in poses])
        inside = [(t_s >= p["start_s"]) & (t_s <= p["end_s"]) for p in poses]
        mid = np.array([0.5 * (p["start_s"] + p["end_s"]) for p in poses])
        t_rel_s = mid - mid.mean()
        chi2_fitted = chi2_static = 0.0
        moves, moves_z = [], []
        for j, acc in enumerate(array, start=1):
            theta = np.array(acc["axis"], float)
            out = table.column(acc["column"]).to_numpy()
            means = np.array([out[s].mean() for s in inside])
            weights = np.array([s.sum() for s in inside]) / noise[j - 1] ** 2
            x0 = [par[(j, n)][0] for n in ["scale_factor", "bias", "tilt_u", "tilt_w"]] + [0.0]
            r0 = means - static_output(np.array(x0), theta, ups, t_rel_s)
            chi2_fitted += float(np.sum(weights * r0 * r0))
            xs = refit(x0, theta, ups, t_rel_s, means, weights, False)
            r1 = means - static_output(xs, theta, ups, t_rel_s)
            chi2_static += float(np.sum(weights * r1 * r1))
            xd = refit(x0, theta, ups, t_rel_s, means, weights, True)
            for q, name in [(2, "tilt_u"), (3, "tilt_w")]:
                moves.append(xs[q] - x0[q])
                moves_z.append((xs[q] - x0[q]) / par[(j, name)][1])
            for q, name in [(0, "scale_factor"), (2, "tilt_u"), (3, "tilt_w")]:
                joint.setdefault((name, j), []).append(x0[q])
                static.setdefault((name, j), []).append(xs[q])
                static_drift.setdefault((name, j), []).append(xd[q])
        dof = len(poses) * len(array) - (4 * len(array) - 3 + 2 * len(poses))
        per_recording.append((k, chi2_fitted / dof, cal["static"]["chi2_dof"], chi2_static / dof,
                              math.sqrt(np.mean(np.square(moves))), float(np.max(np.abs(moves))),
                              math.sqrt(np.mean(np.square(moves_z)))))

    def spread(values, name, recs):
        idx = [k - 1 for k in recs]
        return st.median(st.stdev([values[(name, j)][i] for i in idx]) / rmse[(name, j)] for j in range(1, 25))

    def within3(values, name):
        return sum(1 for j in range(1, 25) if st.stdev(values[(name, j)]) / rmse[(name, j)] <= 3) / 24

    def farthest(values, name):
        c = Counter()
        for j in range(1, 25):
            v = values[(name, j)]
            m = st.mean(v)
            c[1 + max(range(len(v)), key=lambda i: abs(v[i] - m))] += 1
        return ", ".join(f"{k}: {n}" for k, n in sorted(c.items()))

    w = sys.stdout.write
    w("<!-- generated by results/mimu4444/static_tension.py; do not edit -->\n\n")
    w("Spread: per parameter the standard deviation of the recordings' estimates over the simulated calibrations' "
      "RMS error (protocol_run/summary.csv), median over the 24 accelerometers, as summarize.py computes it.\n\n")
    w("## 1. The spread by recording\n\n| parameter | all six | recordings 2, 3, 5 | recordings 1, 4, 6 | farthest from the six-recording mean (recording: count) |\n|---|---|---|---|---|\n")
    for name in kinds:
        w(f"| {name} | {spread(joint, name, RECORDINGS):.2f} | {spread(joint, name, [2, 3, 5]):.2f} | "
          f"{spread(joint, name, [1, 4, 6]):.2f} | {farthest(joint, name)} |\n")
    w("\n## 2. The static phase against the joint fit\n\n| recording | static chi2/dof as fitted (here) | gfcal's | "
      "with bias, scale factor and tilts refitted to the static phase alone (poses held) | tilts' move RMS (rad) | "
      "largest (rad) | RMS in printed sigmas |\n|---|---|---|---|---|---|---|\n")
    for k, c0, cg, c1, m, mx, mz in per_recording:
        w(f"| {k} | {c0:.2f} | {cg:.2f} | {c1:.2f} | {m:.2e} | {mx:.2e} | {mz:.2f} |\n")
    w("\n## 3. The spread with the static phase's own parameters\n\n| parameter | joint fit | static-only refit | "
      "share within 3 | static-only with a bias drift in time | share within 3 | farthest (with drift) |\n|---|---|---|---|---|---|---|\n")
    for name in kinds:
        w(f"| {name} | {spread(joint, name, RECORDINGS):.2f} | {spread(static, name, RECORDINGS):.2f} | "
          f"{within3(static, name):.0%} | {spread(static_drift, name, RECORDINGS):.2f} | {within3(static_drift, name):.0%} | "
          f"{farthest(static_drift, name)} |\n")


if __name__ == "__main__":
    main()
