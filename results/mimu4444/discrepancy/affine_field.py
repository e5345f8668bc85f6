"""Is the rotation-phase gap in the rigid-body form of the centripetal term, or per sensor?

Expectation, written before the first run: each dynamic sample's 24 calibrated readings
(u_j = s_j / k_j - b_j, true axes a_j and positions r_j + dr_j from `gfcal calibrate`'s JSON) are fitted
by a general affine field of specific force over the board, f + G r (12 unknowns, linear least squares;
the rigid body is the special case G = [alpha x] + omega omega^T - |omega|^2 I with 9 unknowns).
- If the affine field leaves residuals near the static noise (RMS below 0.1 m/s^2, against 1.2-1.7 for the
  rigid form), the gap is in the rigid-body form of the centripetal term (the readings of one sample are not
  of one instant of one rigid motion: filter or sampling smear while the rate changes fast).
- If it leaves about the same residual (above 1 m/s^2), no field over the board explains the 24 readings:
  the cause is per sensor (timing or filtering of one axis, nonlinearity, a board that is not rigid).
The board is nearly flat (sensing points at z = +-1 mm), so G's third column is barely seen; the least-squares
solution is taken with an SVD (minimum norm), which does not change the residual.

Second table (what the affine residual is; each check's expectation written with it, before the run):
- a delay per accelerometer (the affine residual regressed on tau_j d u_j / dt, 24 unknowns): a timing effect
  lowers the residual and gives delays of a fraction of a sample period (16 ms), alike for the axes of one IMU;
- deterministic regressors per accelerometer (rate monomials, rate, its derivative from the gyroscopes, its own
  reading squared and cubed): a deterministic per-sensor effect lowers the residual by much more than the
  1% that 15 extra regressors take out of noise;
- whiteness (lag-1 autocorrelation) and structure (the largest singular value's share of the 24 columns): a
  deterministic effect is correlated in time and dominated by a few patterns; noise is neither;
- the residual by the size of the reading.

    python affine_field.py ../shared/data/mimu4444 results/mimu4444 > results/mimu4444/discrepancy/affine_field.md
"""
import json
import sys
import tomllib
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq


def tilt_axis(theta, t):
    k = int(np.argmin(np.abs(theta)))
    e = np.eye(3)[k]
    u = e - theta * theta.dot(e)
    u /= np.linalg.norm(u)
    w = np.cross(theta, u)
    phi = np.hypot(*t)
    if phi == 0:
        return theta
    return theta * np.cos(phi) + (u * t[0] + w * t[1]) * (np.sin(phi) / phi)


def main(data, results):
    array = tomllib.loads(Path("configs/arrays/mimu4444_corners.toml").read_text())
    accs = array["accelerometer"]
    n = len(accs)
    print("# The rotation-phase residual: rigid-body form against a general affine field\n")
    print("Residual RMS (m/s^2) of the dynamic samples' 24 calibrated readings; static noise about 0.04 m/s^2.")
    print("Rigid: `gfcal calibrate`'s fit (9 unknowns per sample). Affine: f + G r, 12 unknowns, linear.")
    print("By axis: the affine residual RMS of the x, y and z axes of the eight IMUs (sensor axes).\n")
    print("| recording | samples | rigid RMS | affine RMS | affine RMS, x / y / z axes | affine RMS at rates below 10 / 10-20 / above 20 rad/s |")
    print("| --- | --- | --- | --- | --- | --- |")
    structure = []
    for k in range(1, 7):
        cal = json.loads((Path(results) / f"recording_{k}.json").read_text())
        par = {(p["accelerometer"], p["name"]): p["value"] for p in cal["parameters"]}
        table = pq.read_table(Path(data) / f"recording_{k}.parquet")
        t = table.column("t_s").to_numpy()
        s = np.column_stack([table.column(a["column"]).to_numpy().astype(float) for a in accs])
        axes, pos = [], []
        for j, a in enumerate(accs, start=1):
            axes.append(tilt_axis(np.array(a["axis"], float), (par[(j, "tilt_u")], par[(j, "tilt_w")])))
            pos.append(np.array(a["position_m"]) + np.array([par[(j, "dx")], par[(j, "dy")], par[(j, "dz")]]))
        axes, pos = np.array(axes), np.array(pos)
        k_j = np.array([par[(j, "scale_factor")] for j in range(1, n + 1)])
        b_j = np.array([par[(j, "bias")] for j in range(1, n + 1)])
        u = s / k_j - b_j
        # The dynamic interval(s) of the calibration, unclipped samples only.
        mask = np.zeros(len(t), bool)
        for iv in cal["segmentation"]["dynamic_intervals"]:
            mask |= (t >= iv["start_s"]) & (t <= iv["end_s"])
        clipped = np.any(np.abs(s) >= 156.9, axis=1)
        mask &= ~clipped
        # Design: reading j = a_j . (f + G r_j) = a_j . f + sum_{m,c} a_jm G_mc r_jc.
        design = np.zeros((n, 12))
        design[:, :3] = axes
        for m in range(3):
            for c in range(3):
                design[:, 3 + 3 * m + c] = axes[:, m] * pos[:, c]
        coef, *_ = np.linalg.lstsq(design, u[mask].T, rcond=1e-10)
        resid = u[mask] - (design @ coef).T
        rms = float(np.sqrt(np.mean(resid**2)))
        by_axis = [float(np.sqrt(np.mean(resid[:, a::3] ** 2))) for a in range(3)]
        # The rate from the reference gyroscopes, for the split by rate.
        gyro = np.column_stack([table.column(g["column"]).to_numpy().astype(float) for g in array["gyroscope"][:3]])
        rate = np.linalg.norm(gyro[mask], axis=1)
        bins = []
        for lo, hi in [(0, 10), (10, 20), (20, 1e9)]:
            sel = (rate >= lo) & (rate < hi)
            bins.append(f"{np.sqrt(np.mean(resid[sel] ** 2)):.3f}" if sel.any() else "-")
        rigid = cal["dynamic"]["residual_rms_m_s2"]
        structure.append(describe(k, t[mask], u[mask], resid, design, gyro[mask]))
        print(
            f"| recording_{k} | {int(mask.sum())} | {rigid:.3f} | {rms:.3f} | "
            + " / ".join(f"{v:.3f}" for v in by_axis)
            + " | "
            + " / ".join(bins)
            + " |"
        )

    print("\n## What the affine residual is\n")
    print("| recording | with a delay per accelerometer | largest delay (ms) | with 15 regressors per accelerometer |"
          " lag-1 autocorrelation (median) | largest component's share | RMS by reading size below 20 / 20-50 / 50-100 / above 100 m/s^2 |")
    print("| --- | --- | --- | --- | --- | --- | --- |")
    for row in structure:
        print(row)


def describe(k, t, u, resid, design, gyro):
    n = u.shape[1]
    q = np.eye(n) - design @ np.linalg.pinv(design, rcond=1e-10)
    du = np.gradient(u, t, axis=0)
    # Delays: Q (u_i - diag(tau) du_i) = Q u_i - Q diag(du_i) tau, least squares in tau over every sample.
    a = np.concatenate([q * du[i][None, :] for i in range(len(t))], axis=0)
    b = resid.reshape(-1)
    tau, *_ = np.linalg.lstsq(a, b, rcond=None)
    with_delay = float(np.sqrt(np.mean((b - a @ tau) ** 2)))
    dw = np.gradient(gyro, t, axis=0)
    w = gyro
    base = np.column_stack(
        [w[:, 0] ** 2, w[:, 1] ** 2, w[:, 2] ** 2, w[:, 0] * w[:, 1], w[:, 0] * w[:, 2], w[:, 1] * w[:, 2], w, dw]
    )
    left = 0.0
    for j in range(n):
        x = np.column_stack([base, u[:, j] ** 2, u[:, j] ** 3, np.ones(len(t))])
        c, *_ = np.linalg.lstsq(x, resid[:, j], rcond=None)
        left += float(np.sum((resid[:, j] - x @ c) ** 2))
    with_regressors = float(np.sqrt(left / resid.size))
    lag1 = float(np.median([np.corrcoef(resid[:-1, j], resid[1:, j])[0, 1] for j in range(n)]))
    sv = np.linalg.svd(resid, compute_uv=False)
    share = float(sv[0] ** 2 / np.sum(sv**2))
    size = np.abs(u)
    bins = []
    for lo, hi in [(0, 20), (20, 50), (50, 100), (100, 1e9)]:
        sel = (size >= lo) & (size < hi)
        bins.append(f"{np.sqrt(np.mean(resid[sel] ** 2)):.2f}" if sel.any() else "-")
    return (
        f"| recording_{k} | {with_delay:.3f} | {np.max(np.abs(tau)) * 1e3:.2f} | {with_regressors:.3f} | {lag1:.2f} | "
        f"{share:.2f} | " + " / ".join(bins) + " |"
    )


if __name__ == "__main__":
    main(sys.argv[1], sys.argv[2])
