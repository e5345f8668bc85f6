"""Do the accelerometers and the gyroscopes of the MIMU4444 sample the same instant? A second check for
issue 11 (after skew.py found the eight gyroscopes synchronous to 0.02 ms).

Written before looking (the expectation): the difference of two top-side accelerometer triads is the
rigid-body term alpha x d + omega x (omega x d) for their baseline d (18.9 mm per axis), plus their
small error differences. With omega from the gyroscopes (their mean) shifted by tau and alpha its time
derivative, the residual's RMS is smallest at tau = 0 if accelerometers and gyroscopes are sampled
together through filters of equal delay. A minimum at tau != 0, the same on all six recordings, is a
relative lag (sensor MEMS parts often run their accelerometer and gyroscope through different low-pass
filters, whose group delays differ by milliseconds); a minimum whose depth is a small share of the RMS
means the lag explains little of the gap.

    python3 results/mimu4444/discrepancy/accel_gyro_lag.py ../shared/data/mimu4444 > results/mimu4444/discrepancy/accel_gyro_lag.md
"""

import glob
import itertools
import os
import sys

import numpy as np
import pyarrow.parquet as pq

TOP = {1: (-9.45, 9.45, 1.0), 3: (-9.45, -9.45, 1.0), 5: (9.45, 9.45, 1.0), 7: (9.45, -9.45, 1.0)}
CLIP_RAD_S = 34.0
CLIP_M_S2 = 150.0


def residual_rms(t, ts, acc, w, taus_s):
    """RMS of the pairwise residuals (after a per-pair affine fit) for each gyro shift tau."""
    out = []
    pairs = list(itertools.combinations(TOP, 2))
    for tau in taus_s:
        ws = np.column_stack([np.interp(ts + tau, ts, w[:, a]) for a in range(3)])
        alpha = np.gradient(ws, ts, axis=0)
        total, count = 0.0, 0
        for i, j in pairs:
            d = (np.array(TOP[i]) - np.array(TOP[j])) * 1e-3
            model = np.cross(alpha, d) + np.cross(ws, np.cross(ws, d))
            diff = acc[i] - acc[j]
            for ax in range(3):
                # diff = k * model + b per axis (the two triads' gain and bias differences, to first order)
                a = np.column_stack([model[t, ax], np.ones(t.sum())])
                x, *_ = np.linalg.lstsq(a, diff[t, ax], rcond=None)
                r = diff[t, ax] - a @ x
                total += r @ r
                count += len(r)
        out.append(np.sqrt(total / count))
    return np.array(out)


def residual_rms_free_alpha(t, ts, acc, w, taus_s):
    """As residual_rms, but alpha solved per sample from the six pairs (18 equations, 3 unknowns)
    instead of differentiated from the 62.5 Hz gyroscope samples; no per-pair gain fit."""
    pairs = list(itertools.combinations(TOP, 2))
    ds = [(np.array(TOP[i]) - np.array(TOP[j])) * 1e-3 for i, j in pairs]
    # alpha x d = -[d]x alpha: stacked (18 x 3) matrix, the same for every sample.
    def skew(d):
        return np.array([[0, -d[2], d[1]], [d[2], 0, -d[0]], [-d[1], d[0], 0]])
    big = np.vstack([-skew(d) for d in ds])
    pinv = np.linalg.pinv(big)
    out = []
    for tau in taus_s:
        ws = np.column_stack([np.interp(ts + tau, ts, w[:, a]) for a in range(3)])[t]
        y = np.hstack([(acc[i] - acc[j])[t] - np.cross(ws, np.cross(ws, d)) for (i, j), d in zip(pairs, ds)])
        alpha = y @ pinv.T
        r = y - alpha @ big.T
        out.append(np.sqrt(np.mean(r**2)))
    return np.array(out)


def main():
    folder = sys.argv[1] if len(sys.argv) > 1 else "../shared/data/mimu4444"
    files = sorted(glob.glob(os.path.join(folder, "recording_*.parquet")))
    taus_ms = np.arange(-24.0, 24.01, 0.5)
    print("# Relative lag of the gyroscopes against the accelerometers\n")
    print("Residual RMS (m/s^2) of the six pairwise differences of the top-side accelerometer triads (IMUs 1, 3, 5, 7)")
    print("against alpha x d + omega x (omega x d), omega the gyroscopes' mean shifted by tau (linear interpolation),")
    print("alpha its derivative; dynamic samples (|omega| > 2 rad/s) with no gyroscope or accelerometer near its clip.")
    print("Positive tau: the model uses the gyroscope sample taken tau later, i.e. the gyroscopes lag.\n")
    print("Second table: alpha solved per sample from the pairs (free), not differentiated.\n")
    print("| recording | samples | RMS at tau = 0 | best tau (ms) | RMS at best | drop | free alpha: RMS at 0 | best tau | RMS at best |")
    print("| --- | --- | --- | --- | --- | --- | --- | --- | --- |")
    for f in files:
        tb = pq.read_table(f)
        ts = tb["t_s"].to_numpy()
        acc = {k: np.column_stack([tb[f"acc{k}_{a}_m_s2"].to_numpy() for a in "xyz"]) for k in TOP}
        w = np.mean([np.column_stack([tb[f"gyro{k}_{a}_rad_s"].to_numpy() for a in "xyz"]) for k in TOP], axis=0)
        gmax = np.max(np.abs(np.stack([tb[c].to_numpy() for c in tb.column_names if c.startswith("gyro")])), axis=0)
        amax = np.max(np.abs(np.stack([tb[c].to_numpy() for c in tb.column_names if c.startswith("acc")])), axis=0)
        ok = (gmax < CLIP_RAD_S) & (amax < CLIP_M_S2) & (np.linalg.norm(w, axis=1) > 2.0)
        # keep away from clipped neighbours (interpolation and the derivative reach one sample out)
        ok[1:-1] &= ok[:-2] & ok[2:]
        ok[[0, -1]] = False
        rms = residual_rms(ok, ts, acc, w, taus_ms * 1e-3)
        best = int(np.argmin(rms))
        zero = int(np.argmin(np.abs(taus_ms)))
        free = residual_rms_free_alpha(ok, ts, acc, w, taus_ms * 1e-3)
        fbest = int(np.argmin(free))
        name = os.path.basename(f).split(".")[0]
        print(f"| {name} | {ok.sum()} | {rms[zero]:.3f} | {taus_ms[best]:+.1f} | {rms[best]:.3f} | "
              f"{100 * (1 - rms[best] / rms[zero]):.0f}% | {free[zero]:.3f} | {taus_ms[fbest]:+.1f} | {free[fbest]:.3f} |")


if __name__ == "__main__":
    main()
