#!/usr/bin/env python3
"""Summarises `gfcal calibrate --json` of the six MIMU4444 recordings in both modes (issue 28, item 5).

Usage: clocks.py DIR [BASE] > clocks.md, where DIR holds r{1..6}_{free,gyro}.json (free: gyroscope-free,
gyro: --use-gyro), written by clocks.sh, and BASE (optional) recording_{1..6}.json of the model without clocks
(gyroscope-free). Standard library only.
"""
import json
import math
import sys
from pathlib import Path

d = Path(sys.argv[1])
base = Path(sys.argv[2]) if len(sys.argv) > 2 else None
recs = [k for k in range(1, 7) if (d / f"r{k}_free.json").exists()]
runs = {(k, m): json.loads((d / f"r{k}_{m}.json").read_text()) for k in recs for m in ("free", "gyro")
        if (d / f"r{k}_{m}.json").exists()}


def clocks(j):
    return {c["package"]: c for c in j.get("sample_clocks", [])}


def relative(j, key="rate_offset_ppm"):
    c = clocks(j)
    mean = sum(v[key] for v in c.values()) / len(c)
    return {p: v[key] - mean for p, v in c.items()}


print("# Sample clocks on the six MIMU4444 recordings\n")
print("Written by `results/mimu4444/clocks.py` from `gfcal calibrate --json` in both modes.\n")
print("## The rotation phase's residual, before and after the clock model\n")
print("| rec | mode | RMS before (m/s^2) | RMS after (m/s^2) | variance removed | timing share | null share (max) | rate vs gyroscopes | rate above 20 rad/s |")
print("|---|---|---|---|---|---|---|---|---|")
for (k, m), j in sorted(runs.items()):
    mdl = j.get("sample_clock_model", {})
    b, a = mdl.get("dynamic_residual_rms_before_m_s2"), mdl.get("dynamic_residual_rms_after_m_s2")
    if b is None:
        print(f"| {k} | {m} | | | clocks not fitted: {j.get('sample_clock_note', '')} | | | | |")
        continue
    removed = 1 - (a / b) ** 2
    share = mdl.get("share_removed")
    null = max(mdl.get("null_shares_removed") or [float("nan")])
    g = j.get("gyro_check") or {}
    rel = g.get("relative")
    hi = [r for r in g.get("by_rate", []) if r["low_rad_s"] >= 20]
    hi_rel = (math.sqrt(sum(r["rms_rad_s"] ** 2 * r["samples"] for r in hi) / sum(r["samples"] for r in hi))
              / math.sqrt(sum(1 for _ in [0])) if hi else None)
    hi_txt = ""
    if hi:
        num = sum(r["rms_rad_s"] ** 2 * r["samples"] for r in hi)
        den = sum((r["rms_rad_s"] / r["relative"]) ** 2 * r["samples"] for r in hi if r["relative"])
        hi_txt = f"{100 * math.sqrt(num / den):.1f}%"
    fmt = lambda v, f: (f.format(v) if isinstance(v, (int, float)) and v is not None else "")
    print(f"| {k} | {m} | {b:.3f} | {a:.3f} | {100 * removed:.1f}% | {fmt(share and 100 * share, '{:.1f}%')} | "
          f"{fmt(null * 100 if null == null else None, '{:.1f}%')} | {fmt(rel and 100 * rel, '{:.1f}%')} | {hi_txt} |")

print("\n## Rate offsets (ppm), gyroscope-free, with sigma\n")
pk = sorted(clocks(runs[(recs[0], "free")]).keys())
print("| rec | " + " | ".join(f"p{p}" for p in pk) + " |")
print("|---|" + "---|" * len(pk))
for k in recs:
    c = clocks(runs[(k, "free")])
    print(f"| {k} | " + " | ".join(f"{c[p]['rate_offset_ppm']:.2f} +- {c[p]['rate_offset_sigma_ppm']:.2f}" for p in pk) + " |")

print("\n## Relative rate offsets (ppm; the package's less the packages' mean), gyroscope-free\n")
print("| rec | " + " | ".join(f"p{p}" for p in pk) + " |")
print("|---|" + "---|" * len(pk))
rel = {k: relative(runs[(k, "free")]) for k in recs}
for k in recs:
    print(f"| {k} | " + " | ".join(f"{rel[k][p]:.2f}" for p in pk) + " |")


def chi2_across(sel):
    """chi^2/dof of each package's relative rate about its mean over the recordings `sel`, with
    the reported sigmas (the relative part's sigma taken as the reported total: conservative)."""
    chi2, dof = 0.0, 0
    for p in pk:
        vals = [rel[k][p] for k in sel]
        sig = [clocks(runs[(k, "free")])[p]["rate_offset_sigma_ppm"] for k in sel]
        w = [1 / s ** 2 for s in sig]
        mean = sum(v * wi for v, wi in zip(vals, w)) / sum(w)
        chi2 += sum((v - mean) ** 2 * wi for v, wi in zip(vals, w))
        dof += len(vals) - 1
    return chi2 / max(dof, 1), dof


for sel in (recs, [k for k in recs if k != 6]):
    label = "recordings " + ", ".join(map(str, sel))
    c, dof = chi2_across(sel)
    spread = [max(rel[k][p] for k in sel) - min(rel[k][p] for k in sel) for p in pk]
    print(f"\nAcross {label}: chi^2/dof = {c:.1f} ({dof} dof) with the reported sigmas; "
          f"range of each package's relative rate: {', '.join(f'{s:.1f}' for s in spread)} ppm.")

print("\n## Gyroscope-free against --use-gyro (relative rate offsets)\n")
chi2, n = 0.0, 0
diffs = []
for k in recs:
    if (k, "gyro") not in runs or "sample_clocks" not in runs[(k, "gyro")]:
        continue
    rg = relative(runs[(k, "gyro")])
    cf, cg = clocks(runs[(k, "free")]), clocks(runs[(k, "gyro")])
    for p in pk:
        dlt = rel[k][p] - rg[p]
        s2 = cf[p]["rate_offset_sigma_ppm"] ** 2 + cg[p]["rate_offset_sigma_ppm"] ** 2
        chi2 += dlt ** 2 / s2
        n += 1
        diffs.append(dlt)
if n:
    rms = math.sqrt(sum(x * x for x in diffs) / n)
    print(f"{n} package-recordings: RMS difference {rms:.3f} ppm, chi^2/dof {chi2 / n:.2f} (sigmas as reported, "
          "treated as independent although both fits start from the same gyroscopes' sawtooth).")

def spread_mm(par):
    loc = {}
    for q in par:
        if q["name"] in ("dx", "dy", "dz"):
            loc.setdefault(q["accelerometer"], {})[q["name"]] = q["value"]
    out = []
    for p in pk:
        axes = [[loc[3 * (p - 1) + i + 1][c] for c in ("dx", "dy", "dz")] for i in range(3)]
        out.append(1000 * max(math.dist(a, b) for a in axes for b in axes))
    return out


if base is not None:
    print("\n## Without the clock model (gyroscope-free; BASE)\n")
    print("| rec | dynamic residual RMS (m/s^2) | rate vs gyroscopes | largest within-package location spread (mm) |")
    print("|---|---|---|---|")
    for k in recs:
        f = base / f"recording_{k}.json"
        if f.exists():
            j = json.loads(f.read_text())
            rel0 = (j.get("gyro_check") or {}).get("relative")
            rel_txt = f"{100 * rel0:.1f}%" if rel0 is not None else ""
            print(f"| {k} | {j['dynamic']['residual_rms_m_s2']:.3f} | {rel_txt} | "
                  f"{max(spread_mm(j['parameters'])):.1f} |")

def locations(par):
    """{accelerometer: ([dx, dy, dz] m, [sigmas] m)}"""
    loc = {}
    for q in par:
        if q["name"] in ("dx", "dy", "dz"):
            i = "dx dy dz".split().index(q["name"])
            v, s = loc.setdefault(q["accelerometer"], ([0.0] * 3, [0.0] * 3))
            v[i], s[i] = q["value"], q["sigma"] if q["sigma"] is not None else float("nan")
    return loc


for mode, label in (("free", "gyroscope-free"), ("gyro", "--use-gyro")):
    print(f"\n## Sensing points within each package ({label})\n")
    print("Largest distance between two axes' fitted locations in one package (mm), per recording; each axis group's "
          "common shift is the gauge's (its mean sensing point the drawing's):\n")
    print("| rec | " + " | ".join(f"p{p}" for p in pk) + " | max |")
    print("|---|" + "---|" * (len(pk) + 1))
    for k in recs:
        if (k, mode) not in runs:
            continue
        row = spread_mm(runs[(k, mode)]["parameters"])
        print(f"| {k} | " + " | ".join(f"{v:.1f}" for v in row) + f" | {max(row):.1f} |")

print("\n## Locations against the drawing and across the recordings\n")
print("Per mode: the RMS and largest |location error| (fitted less the drawing's package centre) over the 72 "
      "components and six recordings; each component's standard deviation over the six recordings against the RMS "
      "of its six printed sigmas (median ratio, and the share of components within 3 times).\n")
print("| mode | RMS error (mm) | largest (mm) | median SD / sigma | within 3 sigma | median sigma (mm) |")
print("|---|---|---|---|---|---|")
for mode, label in (("free", "gyroscope-free"), ("gyro", "--use-gyro")):
    locs = [locations(runs[(k, mode)]["parameters"]) for k in recs if (k, mode) in runs]
    if len(locs) < 2:
        continue
    vals = [v for l in locs for a in l.values() for v in a[0]]
    ratios, sigmas = [], []
    for acc in locs[0]:
        for c in range(3):
            xs = [l[acc][0][c] for l in locs]
            ss = [l[acc][1][c] for l in locs]
            m = sum(xs) / len(xs)
            sd = math.sqrt(sum((x - m) ** 2 for x in xs) / (len(xs) - 1))
            rs = math.sqrt(sum(x * x for x in ss) / len(ss))
            ratios.append(sd / rs)
            sigmas.append(rs)
    ratios.sort()
    sigmas.sort()
    within = sum(r <= 3 for r in ratios) / len(ratios)
    print(f"| {label} | {1000 * math.sqrt(sum(v * v for v in vals) / len(vals)):.2f} | "
          f"{1000 * max(abs(v) for v in vals):.2f} | {ratios[len(ratios) // 2]:.2f} | {100 * within:.0f}% | "
          f"{1000 * sigmas[len(sigmas) // 2]:.2f} |")
