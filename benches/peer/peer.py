"""The quickstart trial as a strong scientist would write it in Python: NumPy and SciPy, with the
navigation compiled by Numba. The peer against which gfcal's throughput is measured (issue 14).

One trial, as `gfcal run configs/quickstart.toml` does it:
  - draw an error set for the six-accelerometer cube (rho = 0.1 m): bias N(0, 1 mg), scale factor
    1 + N(0, 500 ppm), the paper's triad misalignment angles N(0, 0.5 deg), location N(0, 1 mm);
  - simulate the paper's schedule (12 static poses, 3 spins at 2 pi rad/s; 1 s at 100 Hz each) with
    white noise of 50 ug/sqrt(Hz), and average each step;
  - fit the joint model, separable by accelerometer: six 7-parameter Levenberg-Marquardt problems
    (scipy.optimize.least_squares) from a linear start, and the Cramer-Rao sigmas;
  - navigate the paper's manoeuvre for 10 s with RK4 at 100 Hz (noisy outputs, noise held over a
    step), compensated with nominal and with estimated parameters, and record the drift at
    1, 2, 5 and 10 s;
  - write every trial's drift and parameters to Parquet (pyarrow), as gfcal does.

    python peer.py --trials 2000 --processes 2 --out DIR
    python peer.py --check-drift gfcal_drift.csv     # the nominal drift of configs/paper_manoeuvre.toml

The model follows notes/physics.md and gfcal's sources (not its code): outputs k (b + a . f(r + dr)),
f(r) = a_o + alpha x r + omega x (omega x r) - g_b, the mechanization's least-squares solve with
the navigated rate's centripetal term, and the quaternion RK4 of gfcal's navigator.
"""

import argparse
import math
import multiprocessing
import os
import sys
import time

import numpy as np
import numba
import pyarrow as pa
import pyarrow.parquet as pq
from scipy.optimize import least_squares

G_M_S2 = 9.80665
RHO_M = 0.1
MG = G_M_S2 * 1e-3
UG = G_M_S2 * 1e-6
S = 1.0 / math.sqrt(2.0)
POSITIONS = RHO_M * np.array(
    [[0, 0, -1], [0, -1, 0], [-1, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], dtype=float
)
AXES = S * np.array([[1, 1, 0], [1, 0, 1], [0, 1, 1], [0, -1, 1], [-1, 0, 1], [-1, 1, 0]], dtype=float)
TRIADS = [(0, 3, 5), (1, 2, 4)]  # A = (1, 4, 6), B = (2, 3, 5)


def triad_of(j):
    for t, tr in enumerate(TRIADS):
        if j in tr:
            return t, tr.index(j)
    raise ValueError(j)


def row_coefficients(angles, row):
    """Row `row` of C_a^a' for one triad's angles (xy, xz, yx, yz, zx, zy), rad."""
    xy, xz, yx, yz, zx, zy = angles
    return [(1.0, xz, -xy), (-yz, 1.0, yx), (zy, -zx, 1.0)][row]


def true_axes(triad_angles):
    axes = np.empty((6, 3))
    for j in range(6):
        t, row = triad_of(j)
        c = row_coefficients(triad_angles[t], row)
        tr = TRIADS[t]
        axes[j] = c[0] * AXES[tr[0]] + c[1] * AXES[tr[1]] + c[2] * AXES[tr[2]]
    return axes


def pseudo_inverse(positions, axes):
    m = np.hstack([np.cross(positions, axes), axes])
    return np.linalg.inv(m.T @ m) @ m.T  # 6 x N


# ---------------------------------------------------------------- navigation (Numba)


# Small vectors are tuples (registers, no allocation): what a careful Numba user writes.


@numba.njit(cache=True, inline="always", error_model="numpy")
def _cross(a, b):
    return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])


@numba.njit(cache=True, inline="always", error_model="numpy")
def _dot(a, b):
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


@numba.njit(cache=True, inline="always", error_model="numpy")
def _axpy(x, h, d):
    return (x[0] + h * d[0], x[1] + h * d[1], x[2] + h * d[2])


@numba.njit(cache=True, inline="always", error_model="numpy")
def _qaxpy(x, h, d):
    return (x[0] + h * d[0], x[1] + h * d[1], x[2] + h * d[2], x[3] + h * d[3])


@numba.njit(cache=True, inline="always", error_model="numpy")
def _qmul(a, b):
    # (w, x, y, z)
    return (
        a[0] * b[0] - a[1] * b[1] - a[2] * b[2] - a[3] * b[3],
        a[0] * b[1] + a[1] * b[0] + a[2] * b[3] - a[3] * b[2],
        a[0] * b[2] - a[1] * b[3] + a[2] * b[0] + a[3] * b[1],
        a[0] * b[3] + a[1] * b[2] - a[2] * b[1] + a[3] * b[0],
    )


@numba.njit(cache=True, inline="always", error_model="numpy")
def _rotate(q, v, sign):
    """q v q^-1 (sign = 1) or q^-1 v q (sign = -1) for a unit quaternion q (w, x, y, z)."""
    u = (sign * q[1], sign * q[2], sign * q[3])
    c = _cross(u, v)
    t = (2.0 * c[0], 2.0 * c[1], 2.0 * c[2])
    c2 = _cross(u, t)
    return (v[0] + q[0] * t[0] + c2[0], v[1] + q[0] * t[1] + c2[1], v[2] + q[0] * t[2] + c2[2])


@numba.njit(cache=True, inline="always", error_model="numpy")
def _normalized(q):
    n = math.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
    return (q[0] / n, q[1] / n, q[2] / n, q[3] / n)


@numba.njit(cache=True, error_model="numpy")
def _truth(t, alpha_x, accel_x):
    """The paper's manoeuvre: rotation about x by alpha t^2 / 2, inertial acceleration (accel_x, 0, 0)."""
    angle = 0.5 * alpha_x * t * t
    q = (math.cos(0.5 * angle), math.sin(0.5 * angle), 0.0, 0.0)
    omega = (alpha_x * t, 0.0, 0.0)
    v = (accel_x * t, 0.0, 0.0)
    r = (0.5 * accel_x * t * t, 0.0, 0.0)
    return q, omega, v, r


@numba.njit(cache=True, error_model="numpy")
def _outputs(t, alpha_x, accel_x, g, k, b, axes, pos, noise, out):
    q, omega, _, _ = _truth(t, alpha_x, accel_x)
    alpha = (alpha_x, 0.0, 0.0)
    a_b = _rotate(q, (accel_x, 0.0, 0.0), -1.0)
    g_b = _rotate(q, (0.0, 0.0, -g), -1.0)
    for j in range(axes.shape[0]):
        r = (pos[j, 0], pos[j, 1], pos[j, 2])
        ar = _cross(alpha, r)
        wwr = _cross(omega, _cross(omega, r))
        f = (a_b[0] + ar[0] + wwr[0] - g_b[0], a_b[1] + ar[1] + wwr[1] - g_b[1], a_b[2] + ar[2] + wwr[2] - g_b[2])
        out[j] = k[j] * (b[j] + axes[j, 0] * f[0] + axes[j, 1] * f[1] + axes[j, 2] * f[2]) + k[j] * noise[j]


@numba.njit(cache=True, error_model="numpy")
def _derivative(q, w, s, inv_k, bias, cpos, caxes, pinv, g):
    n = _normalized(q)
    g_b = _rotate(n, (0.0, 0.0, -g), -1.0)
    x0 = x1 = x2 = x3 = x4 = x5 = 0.0
    for j in range(s.shape[0]):
        m = s[j] * inv_k[j] - bias[j]
        r = (cpos[j, 0], cpos[j, 1], cpos[j, 2])
        a = (caxes[j, 0], caxes[j, 1], caxes[j, 2])
        y = m - _dot(a, _cross(w, _cross(w, r))) + _dot(a, g_b)
        x0 += pinv[0, j] * y
        x1 += pinv[1, j] * y
        x2 += pinv[2, j] * y
        x3 += pinv[3, j] * y
        x4 += pinv[4, j] * y
        x5 += pinv[5, j] * y
    dq = _qmul(q, (0.0, w[0], w[1], w[2]))
    dq = (0.5 * dq[0], 0.5 * dq[1], 0.5 * dq[2], 0.5 * dq[3])
    return dq, (x0, x1, x2), _rotate(n, (x3, x4, x5), 1.0)


@numba.njit(cache=True, error_model="numpy")
def navigate(step, horizons, alpha_x, accel_x, g, k, b, axes, pos, noise, inv_k, bias, cpos, caxes, pinv):
    """RK4 from the true initial state; returns (rate, attitude, velocity, position) errors per horizon."""
    n = axes.shape[0]
    out = np.empty((horizons.shape[0], 4))
    q = (1.0, 0.0, 0.0, 0.0)
    w = (0.0, 0.0, 0.0)
    v = (0.0, 0.0, 0.0)
    r = (0.0, 0.0, 0.0)
    s1 = np.empty(n)
    s2 = np.empty(n)
    s3 = np.empty(n)
    t = 0.0
    i = 0
    for hz in range(horizons.shape[0]):
        while True:
            remaining = horizons[hz] - t
            if remaining <= 1e-9 * step:
                t = horizons[hz]
                break
            h = remaining if remaining < step * (1.0 + 1e-9) else step
            _outputs(t, alpha_x, accel_x, g, k, b, axes, pos, noise[i], s1)
            _outputs(t + 0.5 * h, alpha_x, accel_x, g, k, b, axes, pos, noise[i], s2)
            _outputs(t + h, alpha_x, accel_x, g, k, b, axes, pos, noise[i], s3)
            hh = 0.5 * h
            k1q, k1w, k1v = _derivative(q, w, s1, inv_k, bias, cpos, caxes, pinv, g)
            k2q, k2w, k2v = _derivative(_qaxpy(q, hh, k1q), _axpy(w, hh, k1w), s2, inv_k, bias, cpos, caxes, pinv, g)
            k3q, k3w, k3v = _derivative(_qaxpy(q, hh, k2q), _axpy(w, hh, k2w), s2, inv_k, bias, cpos, caxes, pinv, g)
            k4q, k4w, k4v = _derivative(_qaxpy(q, h, k3q), _axpy(w, h, k3w), s3, inv_k, bias, cpos, caxes, pinv, g)
            # dr/dt is the stage state's velocity.
            k2r = _axpy(v, hh, k1v)
            k3r = _axpy(v, hh, k2v)
            k4r = _axpy(v, h, k3v)
            h6 = h / 6.0
            r = tuple_sum3(r, h6, v, k2r, k3r, k4r)
            q = tuple_sum4(q, h6, k1q, k2q, k3q, k4q)
            w = tuple_sum3(w, h6, k1w, k2w, k3w, k4w)
            v = tuple_sum3(v, h6, k1v, k2v, k3v, k4v)
            q = _normalized(q)
            t = t + h if h == step else horizons[hz]
            i += 1
            finite = True
            for c in range(3):
                finite = finite and math.isfinite(w[c]) and math.isfinite(v[c]) and math.isfinite(r[c])
            for c in range(4):
                finite = finite and math.isfinite(q[c])
            if not finite:
                for m in range(hz, horizons.shape[0]):
                    out[m, :] = np.inf
                return out
        qt, wt, vt, rt = _truth(horizons[hz], alpha_x, accel_x)
        # Attitude error: the angle of q_true^-1 q_nav.
        dq = _qmul((qt[0], -qt[1], -qt[2], -qt[3]), q)
        out[hz, 0] = math.sqrt((w[0] - wt[0]) ** 2 + (w[1] - wt[1]) ** 2 + (w[2] - wt[2]) ** 2)
        out[hz, 1] = 2.0 * math.atan2(math.sqrt(dq[1] ** 2 + dq[2] ** 2 + dq[3] ** 2), abs(dq[0]))
        out[hz, 2] = math.sqrt((v[0] - vt[0]) ** 2 + (v[1] - vt[1]) ** 2 + (v[2] - vt[2]) ** 2)
        out[hz, 3] = math.sqrt((r[0] - rt[0]) ** 2 + (r[1] - rt[1]) ** 2 + (r[2] - rt[2]) ** 2)
    return out


@numba.njit(cache=True, inline="always", error_model="numpy")
def tuple_sum3(x, h6, a, b, c, d):
    return (
        x[0] + (a[0] + 2.0 * b[0] + 2.0 * c[0] + d[0]) * h6,
        x[1] + (a[1] + 2.0 * b[1] + 2.0 * c[1] + d[1]) * h6,
        x[2] + (a[2] + 2.0 * b[2] + 2.0 * c[2] + d[2]) * h6,
    )


@numba.njit(cache=True, inline="always", error_model="numpy")
def tuple_sum4(x, h6, a, b, c, d):
    return (
        x[0] + (a[0] + 2.0 * b[0] + 2.0 * c[0] + d[0]) * h6,
        x[1] + (a[1] + 2.0 * b[1] + 2.0 * c[1] + d[1]) * h6,
        x[2] + (a[2] + 2.0 * b[2] + 2.0 * c[2] + d[2]) * h6,
        x[3] + (a[3] + 2.0 * b[3] + 2.0 * c[3] + d[3]) * h6,
    )


def drift(step, horizons, k, b, axes, dr, comp_k, comp_b, comp_axes, comp_dr, noise):
    pos = POSITIONS + dr
    cpos = POSITIONS + comp_dr
    pinv = pseudo_inverse(cpos, comp_axes)
    return navigate(
        step,
        np.asarray(horizons, dtype=float),
        math.pi / 4.0,
        9.81,
        G_M_S2,
        k,
        b,
        axes,
        pos,
        noise,
        1.0 / comp_k,
        comp_b,
        cpos,
        comp_axes,
        pinv,
    )


# ---------------------------------------------------------------- calibration


def schedule():
    """The paper's schedule: (up in body axes, spin rate vector) per step."""
    steps = []
    for j in (4, 1, 2, 3, 0, 5):
        for sign in (1.0, -1.0):
            steps.append((sign * AXES[j], np.zeros(3)))
    for k in range(3):
        e = np.zeros(3)
        e[k] = 1.0
        steps.append((-e, 2.0 * math.pi * e))
    return steps


STEPS = schedule()
UPS = np.array([s[0] for s in STEPS])
OMEGAS = np.array([s[1] for s in STEPS])


# f(r) = g up + omega x (omega x r) = F0 + W2 r per step, W2 = omega omega^T - |omega|^2 I.
F0 = G_M_S2 * UPS
W2 = np.einsum("si,sj->sij", OMEGAS, OMEGAS) - np.einsum("s,ij->sij", (OMEGAS**2).sum(axis=1), np.eye(3))


def step_forces(r):
    """Specific force at body point r (3,) in each step (15, 3)."""
    return F0 + W2 @ r


def row_basis(j):
    """The ideal axis of accelerometer j and the two triad neighbours its angles tilt it toward."""
    t, row = triad_of(j)
    tr = TRIADS[t]
    others = [m for m in range(3) if m != row]
    return AXES[tr[row]], AXES[tr[others[0]]], AXES[tr[others[1]]]


BASES = [row_basis(j) for j in range(6)]


def model_and_jacobian(p, j):
    """Step means of accelerometer j for parameters (k, b, c1, c2, dx, dy, dz), and d/dp."""
    k, b, c1, c2 = p[:4]
    a0, a1, a2 = BASES[j]
    axis = a0 + c1 * a1 + c2 * a2
    f = step_forces(POSITIONS[j] + p[4:])
    fa = f @ axis
    jac = np.empty((len(STEPS), 7))
    jac[:, 0] = b + fa
    jac[:, 1] = k
    jac[:, 2] = k * (f @ a1)
    jac[:, 3] = k * (f @ a2)
    jac[:, 4:] = k * (W2 @ axis)  # W2 is symmetric
    return k * (b + fa), jac


def fit_j(means, j, sigma_mean):
    """Linear start (no location), then Levenberg-Marquardt on all seven (analytic Jacobian)."""
    a0, a1, a2 = BASES[j]
    f0 = step_forces(POSITIONS[j])
    # s = k b + k (f.a0) + k c1 (f.a1) + k c2 (f.a2): linear in (kb, k, kc1, kc2)
    a = np.column_stack([np.ones(len(means)), f0 @ a0, f0 @ a1, f0 @ a2])
    sol, *_ = np.linalg.lstsq(a, means, rcond=None)
    kb, k, kc1, kc2 = sol
    p0 = np.array([k, kb / k, kc1 / k, kc2 / k, 0.0, 0.0, 0.0])
    res = least_squares(
        lambda p: (model_and_jacobian(p, j)[0] - means) / sigma_mean,
        p0,
        jac=lambda p: model_and_jacobian(p, j)[1] / sigma_mean,
        method="lm",
        xtol=1e-12,
        ftol=1e-12,
    )
    cov = np.linalg.pinv(res.jac.T @ res.jac)
    return res.x, np.sqrt(np.maximum(np.diag(cov), 0.0)), res.success


def est_axis(j, c1, c2):
    a0, a1, a2 = BASES[j]
    return a0 + c1 * a1 + c2 * a2


def run_trial(seed, trial, noise_density=50.0 * UG, fs=100.0, nav_step=0.01, horizons=(1.0, 2.0, 5.0, 10.0)):
    rng = np.random.default_rng([seed, trial])
    bias = rng.normal(0.0, MG, 6)
    k = 1.0 + rng.normal(0.0, 500e-6, 6)
    angles = rng.normal(0.0, math.radians(0.5), (2, 6))
    dr = rng.normal(0.0, 1e-3, (6, 3))
    axes = true_axes(angles)
    # Calibration: 100 samples per step, averaged.
    sigma = noise_density * math.sqrt(fs)
    n_samples = int(fs)
    means = np.empty((len(STEPS), 6))
    for j in range(6):
        clean = k[j] * (bias[j] + step_forces(POSITIONS[j] + dr[j]) @ axes[j])
        samples = clean[:, None] + k[j] * sigma * rng.standard_normal((len(STEPS), n_samples))
        means[:, j] = samples.mean(axis=1)
    sigma_mean = sigma / math.sqrt(n_samples)
    est = np.empty((6, 7))
    est_sigma = np.empty((6, 7))
    converged = True
    for j in range(6):
        est[j], est_sigma[j], ok = fit_j(means[:, j], j, sigma_mean)
        converged &= bool(ok)
    est_axes = np.array([est_axis(j, est[j, 2], est[j, 3]) for j in range(6)])
    # Navigation noise: one draw per step, held over it.
    steps = int(round(max(horizons) / nav_step))
    noise = noise_density * math.sqrt(1.0 / nav_step) * rng.standard_normal((steps + len(horizons), 6))
    nominal = drift(nav_step, horizons, k, bias, axes, dr, np.ones(6), np.zeros(6), AXES, np.zeros((6, 3)), noise)
    if converged:
        estimated = drift(nav_step, horizons, k, bias, axes, dr, est[:, 0], est[:, 1], est_axes, est[:, 4:], noise)
    else:
        estimated = np.full((len(horizons), 4), np.nan)
    # Truth per accelerometer as gfcal lays it out: k, b, the two angles of its triad row, dx, dy, dz.
    truth = np.empty((6, 7))
    for j in range(6):
        t, row = triad_of(j)
        c = row_coefficients(angles[t], row)
        others = [m for m in range(3) if m != row]
        truth[j] = [k[j], bias[j], c[others[0]], c[others[1]], *dr[j]]
    # Cramer-Rao sigmas at the truth.
    crb = np.empty((6, 7))
    for j in range(6):
        jac = model_and_jacobian(truth[j], j)[1]
        info = jac.T @ jac / sigma_mean**2
        crb[j] = np.sqrt(np.maximum(np.diag(np.linalg.pinv(info)), 0.0))
    return trial, converged, nominal.ravel(), estimated.ravel(), truth.ravel(), est.ravel(), est_sigma.ravel(), crb.ravel()


def _chunk(args):
    seed, start, stop = args
    return [run_trial(seed, t) for t in range(start, stop)]


def write_parquet(rows, out):
    os.makedirs(out, exist_ok=True)
    cols = {
        "trial": pa.array([r[0] for r in rows], pa.uint64()),
        "converged": pa.array([r[1] for r in rows]),
    }
    for name, idx in (("nominal", 2), ("estimated", 3)):
        m = np.array([r[idx] for r in rows])
        for c in range(m.shape[1]):
            cols[f"{name}_{c}"] = pa.array(m[:, c])
    pq.write_table(pa.table(cols), os.path.join(out, "trials.parquet"), compression="zstd")
    params = {
        "trial": pa.array(np.repeat([r[0] for r in rows], 42), pa.uint64()),
        "true": pa.array(np.concatenate([r[4] for r in rows])),
        "estimated": pa.array(np.concatenate([r[5] for r in rows])),
        "estimated_sigma": pa.array(np.concatenate([r[6] for r in rows])),
        "crb_sigma": pa.array(np.concatenate([r[7] for r in rows])),
    }
    pq.write_table(pa.table(params), os.path.join(out, "parameters.parquet"), compression="zstd")


def check_drift(csv_path):
    """The nominal drift of configs/paper_manoeuvre.toml (Tables 6-7, 1 ms steps, no noise)
    against gfcal's `drift --csv`; prints the largest relative difference."""
    import csv

    angles = np.radians(np.array([[0.6, 0.5, 0.8, 0.7, 0.4, 0.8]] * 2))
    k = np.array([0.5, 2.5, 0.5, 2.5, 2.5, 2.5])
    bias = np.full(6, 1e-3 * G_M_S2)
    dr = 1e-3 * np.array([[0.5, 0.8, 0.6], [0.7, 0.5, 0.6], [0.5, 0.9, 0.8], [0.4, 0.7, 0.5], [0.8, 0.7, 0.5], [0.6, 0.8, 0.9]])
    horizons = [0.5, 1.0, 2.0, 5.0, 10.0]
    step = 0.001
    noise = np.zeros((int(10.0 / step) + 10, 6))
    mine = drift(step, horizons, k, bias, true_axes(angles), dr, k, np.zeros(6), AXES, np.zeros((6, 3)), noise)
    with open(csv_path) as f:
        rows = [r for r in csv.DictReader(f) if r["compensation"] == "nominal"]
    worst = 0.0
    for r in rows:
        h = horizons.index(float(r["horizon_s"]))
        for c, name in enumerate(["rate_err_rad_s", "attitude_err_rad", "velocity_err_m_s", "position_err_m"]):
            theirs = float(r[name])
            rel = abs(mine[h, c] - theirs) / abs(theirs)
            worst = max(worst, rel)
            print(f"{r['horizon_s']:>5} s {name:<18} peer {mine[h, c]:.15e} gfcal {theirs:.15e} rel {rel:.1e}")
    print(f"largest relative difference: {worst:.2e}")
    return worst


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--trials", type=int, default=1000)
    ap.add_argument("--processes", type=int, default=1)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--out", default="peer_out")
    ap.add_argument("--check-drift", metavar="GFCAL_DRIFT_CSV")
    args = ap.parse_args()
    if args.check_drift:
        sys.exit(0 if check_drift(args.check_drift) < 1e-9 else 1)
    run_trial(args.seed, 0)  # compile (Numba cache) before timing
    start = time.perf_counter()
    n = args.trials
    per = max(1, n // (8 * args.processes))
    chunks = [(args.seed, s, min(n, s + per)) for s in range(0, n, per)]
    if args.processes > 1:
        with multiprocessing.Pool(args.processes) as pool:
            rows = [r for part in pool.map(_chunk, chunks) for r in part]
    else:
        rows = [r for c in chunks for r in _chunk(c)]
    write_parquet(rows, args.out)
    elapsed = time.perf_counter() - start
    print(f"peer: {n} trials in {elapsed:.2f} s: {n / elapsed:.0f} trials/s on {args.processes} process(es)")


if __name__ == "__main__":
    main()
