"""Is `gfcal inject --effect sampling_delay` a delay of the part of the outputs that carries a delay common
to every accelerometer? With the gyroscopes supplying the rate, that part is the centripetal term
a . w x (w x r), quadratic in the rate; its samples can be aliased where the rate's own are not.
(Expectation and hypothesis: EXPECTATIONS.md, "Outcome of predictions 1 and 2".)

For each recording: w is the mean of the eight gyroscopes (array axes), the dynamic samples are those with
|w| > 2 rad/s and no gyroscope near its rail within 16 samples (the interpolator's reach). For every
accelerometer (position r, axis a) and tau = -1.2 ms:
  A: inject's interpolator (Hann-windowed sinc over 16 neighbours, as src/signal.rs) applied to c = a . w x (w x r)
  B: the same interpolator applied to w, then c formed from the shifted rate (a true shift if w is band-limited)
  C: -tau dc/dt, from w and its derivative by the same interpolator's derivative (analytic product rule)
and the least-squares coefficient of A - c and of B - c on C, pooled over accelerometers.

    python3 results/mimu4444/discrepancy/inject_delay.py ../shared/data/mimu4444 configs/arrays/mimu4444_corners.toml > results/mimu4444/discrepancy/inject_delay.md
"""

import glob
import os
import sys
import tomllib

import numpy as np
import pyarrow.parquet as pq

TAU_S = -1.2e-3
HALF = 16
RAIL_RAD_S = 34.87


def interpolator(d):
    """Weights and first offset of src/signal.rs's FractionalDelay for a delay of d samples."""
    base = int(np.floor(-d))
    ks = np.arange(base - HALF + 1, base + HALF + 1)
    x = -d - ks
    w = np.sinc(x) * 0.5 * (1.0 + np.cos(np.pi * x / HALF))
    return ks, w / w.sum()


def shift(y, d):
    ks, w = interpolator(d)
    idx = np.clip(np.arange(len(y))[:, None] + ks[None, :], 0, len(y) - 1)
    return (y[idx] * w).sum(axis=1)


def derivative(y, dt, h=1e-3):
    """Band-limited derivative: the interpolator's change over +-h samples, per second."""
    return (shift(y, -h) - shift(y, h)) / (2 * h * dt)


def main():
    data, array_file = sys.argv[1], sys.argv[2]
    with open(array_file, "rb") as f:
        arr = tomllib.load(f)
    accs = arr["accelerometer"]
    gyros = arr["gyroscope"]
    print("| recording | dynamic samples | A: inject's shift of the centripetal term, on C | B: term of the shifted rate, on C |")
    print("| --- | --- | --- | --- |")
    for path in sorted(glob.glob(os.path.join(data, "recording_*.parquet"))):
        t = pq.read_table(path)
        ts = t["t_s"].to_numpy()
        dt = (ts[-1] - ts[0]) / (len(ts) - 1)
        d = TAU_S / dt
        cols = np.array([t[g["column"]].to_numpy() for g in gyros])
        axes = np.array([g["axis"] for g in gyros], dtype=float)
        w = np.linalg.lstsq(axes, cols, rcond=None)[0].T  # samples x 3
        railed = np.any(np.abs(cols) >= RAIL_RAD_S, axis=0)
        near = np.convolve(railed.astype(float), np.ones(2 * HALF + 1), mode="same") > 0
        use = (np.linalg.norm(w, axis=1) > 2.0) & ~near
        use[: 2 * HALF] = False
        use[-2 * HALF :] = False
        ws = np.column_stack([shift(w[:, a], d) for a in range(3)])
        al = np.column_stack([derivative(w[:, a], dt) for a in range(3)])
        num_a = num_b = den = 0.0
        for acc in accs:
            r = np.array(acc["position_m"], dtype=float)
            a = np.array(acc["axis"], dtype=float)

            def cent(v):
                return (v * (v @ r)[:, None] - r[None, :] * (v * v).sum(axis=1)[:, None]) @ a

            c = cent(w)
            ca = shift(c, d)
            cb = cent(ws)
            dc = (al * (w @ r)[:, None] + w * (al @ r)[:, None] - 2.0 * r[None, :] * (w * al).sum(axis=1)[:, None]) @ a
            col = -TAU_S * dc  # the change a shift by tau makes, to first order: c(t - tau) - c = -tau dc/dt
            num_a += ((ca - c)[use] * col[use]).sum()
            num_b += ((cb - c)[use] * col[use]).sum()
            den += (col[use] ** 2).sum()
        print(f"| {os.path.basename(path)} | {use.sum()} | {num_a / den:.3f} | {num_b / den:.3f} |")


if __name__ == "__main__":
    main()
