"""How gfcal's cost grows with the work: trials/s and peak RSS of whole `gfcal run` processes on
variants of configs/quickstart.toml: navigation horizon (1 to 100 s), sample rate (100 and 1000 Hz,
calibration and navigation), array size (6, 9 and 24 accelerometers).

    cargo build --release && python3 benches/scale.py [--threads 2]

Prints a Markdown table (the README's scale table).
"""

import argparse
import os
import re
import subprocess
import sys
import tempfile
import time

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def variant(base, horizon_s=10.0, rate_hz=100.0, array=None):
    text = base
    h = horizon_s
    text = re.sub(r"horizons_s = \[.*\]", f"horizons_s = [{h / 10}, {h / 5}, {h / 2}, {h}]", text)
    text = text.replace("sample_rate_hz = 100.0", f"sample_rate_hz = {rate_hz}")
    text = text.replace("step_s = 0.01", f"step_s = {1.0 / rate_hz}")
    if array is not None:
        # Another array: its file, unit-axis (tilt) errors, the augmented schedule (the paper's
        # 15 steps leave some location components of other arrays unseen).
        text = text.replace('preset = "cube"\nrho_m = 0.1', f'file = "{array}"')
        text = text.replace('form = "triad"', 'form = "tilt"')
        text = text.replace('preset = "hung_lee_2006"', 'preset = "hung_lee_2006_augmented"')
    return text


def run(gfcal, config_text, trials, threads, tmp):
    config = os.path.join(REPO, "configs", f".scale-{os.getpid()}.toml")
    with open(config, "w") as f:
        f.write(re.sub(r"trials_per_cell = \d+", f"trials_per_cell = {trials}", config_text))
    try:
        start = time.perf_counter()
        p = subprocess.Popen([gfcal, "run", config, "--out", os.path.join(tmp, "out"), "--force", "--threads",
                              str(threads), "--progress-interval-s", "1000"], stdout=subprocess.DEVNULL,
                             stderr=subprocess.PIPE)
        _, status, usage = os.wait4(p.pid, 0)
        wall = time.perf_counter() - start
        err = p.stderr.read().decode(errors="replace")
    finally:
        os.remove(config)
    if status != 0:
        sys.exit(f"gfcal failed:\n{err}")
    return trials / wall, usage.ru_maxrss / 1024.0


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--threads", type=int, default=2)
    args = ap.parse_args()
    gfcal = os.path.join(os.environ.get("CARGO_TARGET_DIR", os.path.join(REPO, "target")), "release", "gfcal")
    with open(os.path.join(REPO, "configs", "quickstart.toml")) as f:
        base = f.read()
    rows = [
        ("horizon 1 s", variant(base, horizon_s=1.0), 20000),
        ("horizon 10 s (quickstart)", variant(base), 8000),
        ("horizon 100 s", variant(base, horizon_s=100.0), 1000),
        ("1000 Hz, horizon 10 s", variant(base, rate_hz=1000.0), 1000),
        ("9 accelerometers", variant(base, array="arrays/nine.toml"), 4000),
        ("24 accelerometers", variant(base, array="arrays/mimu4444_corners.toml"), 2000),
    ]
    tmp = tempfile.mkdtemp(prefix="gfcal-scale-")
    print(f"| work ({args.threads} threads) | trials | trials/s | navigation steps/s | peak RSS |")
    print("| --- | --- | --- | --- | --- |")
    for name, text, trials in rows:
        rate, rss = run(gfcal, text, trials, args.threads, tmp)
        h = float(re.search(r"horizons_s = \[.*, ([0-9.]+)\]", text).group(1))
        step = float(re.search(r"step_s = ([0-9.e-]+)", text).group(1))
        steps = 2 * h / step  # two compensations
        print(f"| {name} | {trials} | {rate:,.0f} | {rate * steps:,.0f} | {rss:.0f} MB |")


if __name__ == "__main__":
    main()
