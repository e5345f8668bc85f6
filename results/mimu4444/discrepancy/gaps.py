"""The gap tables of the six diagnoses (diagnose_K.json, from run.sh): Python's standard library only.

    python3 results/mimu4444/discrepancy/gaps.py results/mimu4444/discrepancy > results/mimu4444/discrepancy/gaps.md
"""
import json
import statistics
import sys
from pathlib import Path


def name(path):
    return Path(path).stem


def held_out_table(runs, phase, cell):
    """One row per fitting recording, one column per recording: the held-out gap before -> after."""
    print(f"\n## Held-out recordings: {phase} gap before -> after\n")
    print("| fitted on | " + " | ".join(f"recording_{k}" for k in range(1, 7)) + " |")
    print("| --- " * 7 + "|")
    for r in runs:
        cells = {name(h["recording"]): cell(h) for h in r["held_out"]}
        row = [cells.get(f"recording_{k}", "(fitting)") for k in range(1, 7)]
        print(f"| {name(r['recording'])} | " + " | ".join(row) + " |")


def main(folder):
    runs = [json.loads((Path(folder) / f"diagnose_{k}.json").read_text()) for k in range(1, 7)]
    print("# The baseline's gap on the six recordings, and after the named effects\n")
    print("Each recording in turn is the fitting one; the other five are held out (poses, motion and the named")
    print("per-recording effects refitted there). Static: chi2/dof of the interval means. Dynamic: the rotation-phase")
    print("chi2/dof (src/selfcal/misfit.rs, the number `gfcal calibrate` prints), before the sample clocks. 1 is noise")
    print("alone; above 2 counts as above the noise.\n")
    print("## Fitting recordings\n")
    print("| recording | static gap | dynamic gap | effects named | explanation |")
    print("| --- | --- | --- | --- | --- |")
    for r in runs:
        f = r["fitting"]["before"]
        named = ", ".join(dict.fromkeys(e["name"] for e in r["effects"])) or "none"
        dyn = f["dynamic_gap"]
        print(f"| {name(r['recording'])} | {f['static_chi2_dof']:.2f} | {dyn:.0f} | {named} | {r['explanation']} |")
    held_out_table(runs, "static", lambda h: f"{h['gap_before']:.0f} -> {h['gap_after']:.1f}")
    held_out_table(runs, "dynamic", lambda h: f"{h['dynamic_gap_before']:.0f} -> {h['dynamic_gap_after']:.0f}")
    print("\n## Effects tried on every split\n")
    print("| fitted on | named | not named (why) |")
    print("| --- | --- | --- |")
    for r in runs:
        named = ", ".join(dict.fromkeys(e["name"] for e in r["effects"])) or "none"
        why = "; ".join(f"{x['name']}: {x['why']}" for x in r["not_named"]) or "-"
        print(f"| {name(r['recording'])} | {named} | {why} |")
    ks, kz = [], []
    for r in runs:
        for h in r["held_out"]:
            for c, s in zip(h["scale_factor_change"], h["scale_factor_change_sigma"]):
                ks.append(abs(c))
                kz.append(abs(c) / s)
    print(f"\nScale-factor changes between recordings (refitted with the biases), over the 30 ordered pairs and 24")
    print(f"accelerometers: median |change| {statistics.median(ks) * 1e6:.0f} ppm, largest {max(ks) * 1e6:.0f} ppm;")
    print(f"median |change| / sigma {statistics.median(kz):.1f}, largest {max(kz):.1f}.")
    print("\n## bias_turn_on: the bias change between recordings\n")
    changes, zs = [], []
    for r in runs:
        for h in r["held_out"]:
            for c, s in zip(h["bias_change_m_s2"], h["bias_change_sigma_m_s2"]):
                changes.append(abs(c))
                zs.append(abs(c) / s)
    print(f"Over the 30 ordered pairs and 24 accelerometers: median |change| {statistics.median(changes):.4f} m/s^2,")
    print(f"largest {max(changes):.4f} m/s^2; median |change| / sigma {statistics.median(zs):.0f}, largest {max(zs):.0f}.")
    print("\n| fitted on | largest p over held-out | RMS change per accelerometer, m/s^2 (median, largest) |")
    print("| --- | --- | --- |")
    for r in runs:
        for e in r["effects"]:
            if e["name"] != "bias_turn_on":
                continue
            v = e["value"]
            print(f"| {name(r['recording'])} | {e['p_value_largest']:.1e} | {statistics.median(v):.4f}, {max(v):.4f} |")


if __name__ == "__main__":
    main(sys.argv[1])
