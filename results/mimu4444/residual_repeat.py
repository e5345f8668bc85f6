"""Does the rotation phase's residual after the clocks repeat across the six real recordings?

Reads residual_K.csv (K = 1..6) as the ignored test
`simulate::write_the_rotation_phase_residual_of_each_real_recording` writes them, and prints:

- (a)-(c) held-out regressions: per accelerometer, the residual on (a) its own output's first and
  second central differences, (b) its own output squared, its package's two other axes' outputs and
  their products with its own, (c) both; fitted on recording A, scored on recording B (the constant
  refitted on B) as the share of B's residual variance removed, over the 30 ordered pairs;
- (d) spatial modes: the share of B's residual variance in the span of the top k eigenvectors of
  A's 24 x 24 residual covariance, and the same share on A itself.

Usage: python3 results/mimu4444/residual_repeat.py DIR   (needs numpy)
Expectations and outcomes: results/mimu4444/EXPECTATIONS.md (2026-11-30, from 03:04 UTC).
"""

import sys

import numpy as np


def read(path):
    """(residual, output) as samples x accelerometers (NaN where unused), and each one's package."""
    data = np.genfromtxt(path, delimiter=",", names=True)
    sample = data["sample"].astype(int)
    acc = data["accelerometer"].astype(int)
    n, m = sample.max() + 1, acc.max() + 1
    residual = np.full((n, m), np.nan)
    output = np.full((n, m), np.nan)
    residual[sample, acc] = data["residual_m_s2"]
    output[sample, acc] = data["output_m_s2"]
    package = np.zeros(m, dtype=int)
    package[acc] = data["package"].astype(int)
    return residual, output, package


def design(kind, residual, output, package, j):
    """The regressors of accelerometer j (a constant first), its residual, and the rows to use."""
    n = residual.shape[0]
    y = output[:, j]
    cols = [np.ones(n)]
    if kind in ("a", "c"):
        d1 = np.full(n, np.nan)
        d2 = np.full(n, np.nan)
        d1[1:-1] = (y[2:] - y[:-2]) / 2
        d2[1:-1] = y[2:] - 2 * y[1:-1] + y[:-2]
        cols += [d1, d2]
    if kind in ("b", "c"):
        others = [k for k in range(residual.shape[1]) if package[k] == package[j] and k != j]
        cols += [y**2] + [output[:, k] for k in others] + [output[:, k] * y for k in others]
    x = np.column_stack(cols)
    ok = np.all(np.isfinite(x), axis=1) & np.isfinite(residual[:, j])
    return x, residual[:, j], ok


def removed_share(kind, coefs, rec):
    """The share of rec's residual variance that the slopes `coefs` remove (constants refitted)."""
    residual, output, package = rec
    left = total = 0.0
    for j in range(residual.shape[1]):
        x, y, ok = design(kind, residual, output, package, j)
        e = y[ok] - x[ok][:, 1:] @ coefs[j][1:]
        left += ((e - e.mean()) ** 2).sum()
        total += ((y[ok] - y[ok].mean()) ** 2).sum()
    return 1 - left / total


def main():
    folder = sys.argv[1]
    recs = {k: read(f"{folder}/residual_{k}.csv") for k in range(1, 7)}
    for k, (residual, _, _) in recs.items():
        print(f"recording {k}: {residual.shape[0]} samples, residual RMS {np.sqrt(np.nanmean(residual**2)):.3f} m/s^2")
    off = ~np.eye(6, dtype=bool)
    for kind in ("a", "b", "c"):
        coefs = {}
        for k, (residual, output, package) in recs.items():
            coefs[k] = []
            for j in range(residual.shape[1]):
                x, y, ok = design(kind, residual, output, package, j)
                coefs[k].append(np.linalg.lstsq(x[ok], y[ok], rcond=None)[0])
        share = np.array([[removed_share(kind, coefs[a], recs[b]) for b in recs] for a in recs])
        print(f"({kind}) in sample: " + " ".join(f"{x:.3f}" for x in np.diag(share)))
        held = share[off]
        print(f"({kind}) held out: median {np.median(held):.3f}, min {held.min():.3f}, max {held.max():.3f}")
    cov = {}
    for k, (residual, _, _) in recs.items():
        r = residual[np.all(np.isfinite(residual), axis=1)]
        r = r - r.mean(axis=0)
        cov[k] = r.T @ r / len(r)
        w = np.linalg.eigvalsh(cov[k])[::-1]
        print(f"recording {k}: eigenvalue shares " + " ".join(f"{x:.3f}" for x in w[:5] / w.sum()))
    for top in (1, 3, 5):
        share = np.zeros((6, 6))
        for a in cov:
            v = np.linalg.eigh(cov[a])[1][:, ::-1][:, :top]
            for b in cov:
                share[a - 1, b - 1] = np.trace(v.T @ cov[b] @ v) / np.trace(cov[b])
        ratio = share / np.diag(share)[:, None]
        print(
            f"(d) top {top}: in sample {np.diag(share).min():.3f}-{np.diag(share).max():.3f}; held out median "
            f"{np.median(share[off]):.3f} ({share[off].min():.3f}-{share[off].max():.3f}); held out / in sample "
            f"median {np.median(ratio[off]):.2f}, min {ratio[off].min():.2f}"
        )


if __name__ == "__main__":
    main()
