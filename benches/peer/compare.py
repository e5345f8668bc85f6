"""gfcal against the Python peer, side by side: the quickstart trial, whole processes, alternating
runs, medians of wall time and peak RSS, and the ratio.

    python benches/peer/compare.py [--trials 4000] [--repeats 3] [--workers 1 2]

gfcal runs `target/release/gfcal run` on configs/quickstart.toml with `trials_per_cell` set to
--trials (Parquet and summary included); the peer runs `peer.py` with the same trial count (Parquet
included). Build gfcal first (`cargo build --release`); the peer needs numpy, scipy, numba and
pyarrow. Run from the repository's folder.
"""

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time

HERE = os.path.dirname(os.path.abspath(__file__))
REPO = os.path.dirname(os.path.dirname(HERE))


def timed(cmd):
    """Wall time (s) and peak RSS (MB) of one process and its reaped children."""
    start = time.perf_counter()
    p = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    _, status, usage = os.wait4(p.pid, 0)
    wall = time.perf_counter() - start
    err = p.stderr.read().decode(errors="replace") if p.stderr else ""
    if status != 0:
        sys.exit(f"failed ({status}): {' '.join(cmd)}\n{err}")
    return wall, usage.ru_maxrss / 1024.0


def main():
    ap = argparse.ArgumentParser(description="gfcal vs the Numba peer, side by side")
    ap.add_argument("--trials", type=int, default=4000)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--workers", type=int, nargs="+", default=[1, 2])
    args = ap.parse_args()
    gfcal = os.path.join(os.environ.get("CARGO_TARGET_DIR", os.path.join(REPO, "target")), "release", "gfcal")
    with open(os.path.join(REPO, "configs", "quickstart.toml")) as f:
        text = f.read().replace("trials_per_cell = 20000", f"trials_per_cell = {args.trials}")
    tmp = tempfile.mkdtemp(prefix="gfcal-peer-")
    config = os.path.join(tmp, "quickstart.toml")
    with open(config, "w") as f:
        f.write(text)
    # The peer's first run compiles its Numba code into the cache; not timed.
    subprocess.run([sys.executable, os.path.join(HERE, "peer.py"), "--trials", "10", "--out", os.path.join(tmp, "warm")],
                   check=True, stdout=subprocess.DEVNULL)
    print(f"{args.trials} quickstart trials per run, {args.repeats} alternating runs each; medians")
    print(f"{'workers':>7} {'gfcal trials/s':>15} {'gfcal RSS MB':>13} {'peer trials/s':>14} {'peer RSS MB':>12} {'ratio':>7}")
    for w in args.workers:
        g_times, g_rss, p_times, p_rss = [], [], [], []
        for r in range(args.repeats):
            wall, rss = timed([gfcal, "run", config, "--out", os.path.join(tmp, "g"), "--force", "--threads", str(w),
                               "--progress-interval-s", "1000"])
            g_times.append(wall)
            g_rss.append(rss)
            wall, rss = timed([sys.executable, os.path.join(HERE, "peer.py"), "--trials", str(args.trials),
                               "--processes", str(w), "--out", os.path.join(tmp, "p")])
            p_times.append(wall)
            p_rss.append(rss)
        g = args.trials / statistics.median(g_times)
        p = args.trials / statistics.median(p_times)
        print(f"{w:>7} {g:>15.0f} {statistics.median(g_rss):>13.1f} {p:>14.0f} {statistics.median(p_rss):>12.1f} {g / p:>6.1f}x")


if __name__ == "__main__":
    main()
