"""The sample clocks' effect on the six diagnoses (issue 28, items 4 and 5): Python's standard library only.

The gaps, before and after the clocks: diagnose[_gyro]_K.json from run.sh and run_gyro.sh with
configs/arrays/mimu4444_corners.toml as it is. The rank tests' sigmas before: no_clocks/diagnose[_gyro]_K.json,
the diagnoses made before the array file declared the packages' clocks (their gaps are in the metric used before
issue 30, (residual RMS / static noise RMS)^2, and are not read).

    python3 results/mimu4444/discrepancy/clock_effect.py results/mimu4444/discrepancy > results/mimu4444/discrepancy/clock_effect.md
"""
import json
import math
import sys
from pathlib import Path


def rms(v):
    v = [x for x in v if x is not None and math.isfinite(x)]
    return math.sqrt(sum(x * x for x in v) / len(v)) if v else float("nan")


def rank_sigma(d, name, key="sigma"):
    for r in d.get("rank_tests", []):
        if r["name"] == name:
            return rms(r.get(key, []))
    return float("nan")


def clock_gap(entries):
    for e in entries:
        if e["effect"] == "sample_clock":
            return e["dynamic_gap"]
    return None


def fmt(x, digits=1):
    return "-" if x is None or (isinstance(x, float) and not math.isfinite(x)) else f"{x:.{digits}f}"


def main(folder):
    folder = Path(folder)
    print("# The sample clocks in the six diagnoses, both modes\n")
    print("Each recording in turn is the fitting one, the other five held out. Gap: the rotation-phase chi2/dof")
    print("(src/selfcal/misfit.rs, the number `gfcal calibrate` prints; 1 is the noise alone), before -> after")
    print("`sample_clock`, both from the diagnosis with the clocks: fitting recording, before: the motion tracked")
    print("again on the outputs as recorded; after: the calibration's own with the clocks. Held out: before, the")
    print("calibration carried over; after, scaled by the share the fitting recording's relative rates remove there")
    print("(phases from their own gyroscopes; each sample's motion refitted with the timing model) and by the degrees")
    print("of freedom without and with its six unknowns a sample. That ratio is what six unknowns take from a white")
    print("misfit by chance; the clocks read at shifted times take 58.6-92.4% of these misfits (the diagnoses' text),")
    print("so the held-out numbers after the clocks are optimistic. Sigma columns: RMS over the effect's parameters of")
    print("its rank test's sigma, without the clocks (no_clocks/) -> with them: the joint fit of every owner's")
    print("parameters (`sigma`), and each owner's fitted alone, the effect's other owners left out (`sigma_alone`:")
    print("the sigma a test of one owner has, which the naming reads while no other owner is taken; since the")
    print("eleventh session of 2026-12-01 the owners are selected one at a time, each given those already taken).\n")
    print("| recording | mode | sample_clock | fitting rotation-phase chi2/dof | held-out rotation-phase chi2/dof (mean) | quadratic SF sigma | cross-coupling sigma | quadratic SF sigma alone | cross-coupling sigma alone | explanation |")
    print("| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |")
    ratios = {(n, key): [] for key in ("sigma", "sigma_alone") for n in ("scale_factor_quadratic", "cross_coupling")}
    for mode, stem in (("gyro-free", "diagnose_"), ("use-gyro", "diagnose_gyro_")):
        for k in range(1, 7):
            before_path = folder / "no_clocks" / f"{stem}{k}.json"
            after_path = folder / f"{stem}{k}.json"
            if not (before_path.exists() and after_path.exists()):
                continue
            b = json.loads(before_path.read_text())
            a = json.loads(after_path.read_text())
            tried = any(e["name"] == "sample_clock" for e in a.get("effects", []) + a.get("not_named", []))
            if not tried:
                print(f"| recording_{k} | {mode} | not re-run with the clocks | | | | | | | |")
                continue
            named = [e for e in a.get("effects", []) if e["name"] == "sample_clock"]
            named_text = f"named, p = {named[0]['p_value_largest']:.2f}" if named else "not named"
            fit_before = a["fitting"]["before"]["dynamic_gap"]
            fit_after = clock_gap(a.get("fitting_after_each", []))
            ho_before = [h["dynamic_gap_before"] for h in a["held_out"]]
            ho_after = [clock_gap(h.get("after_each", [])) for h in a["held_out"]]
            ho_after = [x for x in ho_after if x is not None]
            mean = lambda v: sum(v) / len(v) if v else None
            cells = []
            for key in ("sigma", "sigma_alone"):
                for name in ("scale_factor_quadratic", "cross_coupling"):
                    sb, sa = rank_sigma(b, name, key), rank_sigma(a, name, key)
                    if math.isfinite(sb) and math.isfinite(sa) and sb > 0:
                        ratios[(name, key)].append((mode, k, sa / sb))
                    cells.append(f"{sb:.2e} -> {sa:.2e}")
            print(
                f"| recording_{k} | {mode} | {named_text} | {fmt(fit_before)} -> {fmt(fit_after)} | "
                f"{fmt(mean(ho_before))} -> {fmt(mean(ho_after))} | {' | '.join(cells)} | {a.get('explanation')} |"
            )
    print()
    for (name, key), r in ratios.items():
        for mode in ("gyro-free", "use-gyro"):
            v = [x for m, _, x in r if m == mode]
            if v:
                halved = sum(x <= 0.5 for x in v)
                listed = ", ".join(f"{x:.3f}" for x in v)
                print(
                    f"- {name}, {key}, {mode}: sigma after / before {listed} (recordings in order; "
                    f"at least halved, <= 0.5, on {halved} of {len(v)})."
                )


if __name__ == "__main__":
    main(sys.argv[1] if len(sys.argv) > 1 else "results/mimu4444/discrepancy")
