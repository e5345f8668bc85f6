"""Is there a sampling skew between the MIMU4444's IMUs? A first check for issue 11, on the gyroscopes.

Written before looking (the expectation): the 8 gyroscopes see one rigid-body rate. Mapped into the array
frame, each differs from the mean of the other seven by its own small gain, misalignment and bias errors
and by noise. If the IMUs are sampled at the same instant through the same filter, a time offset tau_k
fitted per IMU (the residual's regression on the rate's time derivative) is 0 within its standard error
(about 0.1 ms from thousands of dynamic samples). A real skew or filter-lag difference is a tau_k that is
many standard errors from 0 and the same, within a few standard errors, on all six recordings. A packet
mix-up of one sample would show as about 16 ms (the sample interval at 62.5 Hz).

    python3 results/mimu4444/discrepancy/skew.py ../shared/data/mimu4444  > results/mimu4444/discrepancy/skew.md
"""

import glob
import os
import sys

import numpy as np
import pyarrow.parquet as pq

CLIP_RAD_S = 34.0  # below the gyroscopes' 34.9 rad/s saturation


def array_frame(k, v):
    """IMU k's sensor-axis samples (n, 3) in array axes (bottom IMUs, even k, are flipped)."""
    if k % 2 == 0:
        # sensor (x, y, z) = (-v_y, -v_x, -v_z) of the array vector v, so v = (-s_y, -s_x, -s_z)
        return np.column_stack([-v[:, 1], -v[:, 0], -v[:, 2]])
    return v


def analyse(path, inject_s=0.0):
    """tau per IMU; `inject_s` shifts IMU 3's gyroscope by that much first (a check of the method)."""
    t = pq.read_table(path)
    ts = t["t_s"].to_numpy()
    dt = np.median(np.diff(ts))
    w = np.stack([array_frame(k, np.column_stack([t[f"gyro{k}_{a}_rad_s"].to_numpy() for a in "xyz"]))
                  for k in range(1, 9)])  # (8, n, 3)
    if inject_s:
        # IMU 3 leads by inject_s: its sample i is the signal at t_i + inject_s (tau_3 = +inject_s).
        w[2] = np.column_stack([np.interp(ts + inject_s, ts, w[2][:, a]) for a in range(3)])
    raw_max = np.max(np.abs(np.stack([t[f"gyro{k}_{a}_rad_s"].to_numpy() for k in range(1, 9) for a in "xyz"])), axis=0)
    mean = w.mean(axis=0)
    speed = np.linalg.norm(mean, axis=1)
    # Dynamic, unclipped samples with both neighbours unclipped (for the central difference).
    ok = (raw_max < CLIP_RAD_S) & (speed > 2.0)
    ok[1:-1] &= ok[:-2] & ok[2:]
    ok[[0, -1]] = False
    idx = np.nonzero(ok)[0]
    rows = []
    for k in range(8):
        others = (w.sum(axis=0) - w[k]) / 7.0
        deriv = (others[idx + 1] - others[idx - 1]) / (ts[idx + 1] - ts[idx - 1])[:, None]
        r = w[k][idx] - others[idx]  # (m, 3)
        # r = tau * d(others)/dt + M others + b, per IMU: tau, 3x3 M, 3 b  (13 unknowns, 3m equations)
        m = len(idx)
        a = np.zeros((3 * m, 13))
        y = r.reshape(-1)
        for ax in range(3):
            rows_ax = slice(ax, 3 * m, 3)
            a[rows_ax, 0] = deriv[:, ax]
            a[rows_ax, 1 + 3 * ax:4 + 3 * ax] = others[idx]
            a[rows_ax, 10 + ax] = 1.0
        x, *_ = np.linalg.lstsq(a, y, rcond=None)
        res = y - a @ x
        sigma2 = res @ res / (len(y) - 13)
        cov = sigma2 * np.linalg.inv(a.T @ a)
        rms_before = np.sqrt(np.mean((y - a[:, 1:] @ np.linalg.lstsq(a[:, 1:], y, rcond=None)[0]) ** 2))
        rows.append((k + 1, x[0], np.sqrt(cov[0, 0]), rms_before, np.sqrt(sigma2)))
    return dt, len(idx), rows


def main():
    folder = sys.argv[1] if len(sys.argv) > 1 else "../shared/data/mimu4444"
    files = sorted(glob.glob(os.path.join(folder, "recording_*.parquet")))
    print("# Time offset of each IMU's gyroscope against the mean of the other seven\n")
    print("tau_k: the residual `w_k - mean(others)` regressed on d(mean others)/dt, with a 3 x 3 gain-misalignment")
    print("matrix and a bias per IMU; dynamic samples (|w| > 2 rad/s), none within one sample of a clipped gyro.")
    print("sigma: least-squares standard error under white residuals (optimistic if they are correlated).")
    print("rms: the residual's RMS without and with tau (rad/s).\n")
    table = {}
    for f in files:
        dt, m, rows = analyse(f)
        name = os.path.basename(f).split(".")[0]
        table[name] = rows
        print(f"## {name}: {m} samples at {1 / dt:.1f} Hz\n")
        print("| IMU | tau (ms) | sigma (ms) | rms without tau | rms with tau |")
        print("| --- | --- | --- | --- | --- |")
        for k, tau, s, before, after in rows:
            print(f"| {k} | {1e3 * tau:+.2f} | {1e3 * s:.2f} | {before:.4f} | {after:.4f} |")
        print()
    print("## Check of the method: IMU 3 shifted by a known 2 ms (linear interpolation), recording 1\n")
    _, _, rows = analyse(files[0], inject_s=2e-3)
    print("| IMU | tau (ms) | sigma (ms) |")
    print("| --- | --- | --- |")
    for k, tau, s, _, _ in rows:
        print(f"| {k} | {1e3 * tau:+.2f} | {1e3 * s:.3f} |")
    print()
    print("## Across recordings\n")
    print("| IMU | mean tau (ms) | spread (std, ms) | min | max |")
    print("| --- | --- | --- | --- | --- |")
    for k in range(8):
        taus = np.array([1e3 * table[n][k][1] for n in table])
        print(f"| {k + 1} | {taus.mean():+.2f} | {taus.std(ddof=1):.2f} | {taus.min():+.2f} | {taus.max():+.2f} |")


if __name__ == "__main__":
    main()
