#!/usr/bin/env python3
"""The tables of scripts/cloudscape-bench.sh: reads OUT/times.csv and OUT/errors.csv, writes
OUT/time_to_rmse.csv and OUT/summary.md.

Usage: scripts/cloudscape_report.py OUT TARGET_BUDGET REF_SPP

Time to a fixed RMSE: the target is the RMSE ratio tracking reaches at TARGET_BUDGET
seconds; each estimator's time to it is interpolated on its own measured curve, linearly in
log(seconds) against log(RMSE) between the two budgets that straddle it. A curve that starts
below the target is extrapolated back from its first point as RMSE ~ 1/sqrt(time) (marked);
one that never reaches the target within the largest budget has no time (its bias or noise
floor is above it). Pure Python, no dependencies.
"""
import csv
import math
import sys

BAKE = ("pins", "pinms", "pinres")
NO_BAKE = ("ratio", "residual", "delta")


def rows(path):
    with open(path) as f:
        return list(csv.DictReader(f))


def time_to(curve, target):
    """(seconds, note) to reach `target` on `curve` [(seconds, rmse)] sorted by seconds."""
    if not curve:
        return None, "not measured"
    t0, r0 = curve[0]
    if r0 <= target:
        return t0 * (r0 / target) ** 2, "extrapolated as 1/sqrt(t)"
    for (ta, ra), (tb, rb) in zip(curve, curve[1:]):
        if ra >= target >= rb and ra > rb:
            f = (math.log(ra) - math.log(target)) / (math.log(ra) - math.log(rb))
            return math.exp(math.log(ta) + f * (math.log(tb) - math.log(ta))), ""
    return None, f"not reached in {curve[-1][0]:g} s (RMSE {curve[-1][1]:.4g} there)"


def main(argv):
    if len(argv) != 4:
        sys.exit(__doc__)
    out, target_budget, ref_spp = argv[1], float(argv[2]), argv[3]
    times = rows(f"{out}/times.csv")
    errors = rows(f"{out}/errors.csv")
    md = ["# Cloudscape benchmark", ""]

    # (a) render time against instance count.
    counts = sorted({int(r["instances"]) for r in times})
    runs = []
    for r in times:
        k = (r["estimator"], r["backend"], r["spp"])
        if k not in runs:
            runs.append(k)
    md += ["## Render time (s) against instance count", ""]
    md.append("| estimator | backend | spp | " + " | ".join(str(c) for c in counts) + " |")
    md.append("|---|---|---|" + "---|" * len(counts))
    for e, b, spp in runs:
        cells = []
        for c in counts:
            v = [r["seconds"] for r in times if (r["estimator"], r["backend"]) == (e, b) and int(r["instances"]) == c]
            cells.append(v[0] if v else "")
        md.append(f"| {e} | {b} | {spp} | " + " | ".join(cells) + " |")
    md.append("")

    # (b) RMSE against run time on 256 instances.
    curves = {}
    for r in errors:
        curves.setdefault(r["estimator"], []).append((float(r["seconds"]), float(r["rmse"]), r["budget_s"], r["spp"]))
    budgets = []
    for r in errors:
        if r["budget_s"] not in budgets:
            budgets.append(r["budget_s"])
    md += [f"## RMSE against run time, 256 instances (reference: ratio tracking, {ref_spp} spp)", ""]
    md.append("| estimator | " + " | ".join(f"{b} s" for b in budgets) + " |")
    md.append("|---|" + "---|" * len(budgets))
    for e, c in curves.items():
        md.append(f"| {e} | " + " | ".join(f"{x[1]:.4g} ({x[3]} spp)" for x in c) + " |")
    md.append("")
    md += ["Best bake-reading against best no-bake estimator at each budget:", ""]
    md.append("| budget (s) | best bake-reading | RMSE | best no-bake | RMSE | ratio |")
    md.append("|---|---|---|---|---|---|")
    for b in budgets:
        def best(names):
            cand = [(x[1], e) for e, c in curves.items() if e in names for x in c if x[2] == b]
            return min(cand) if cand else None
        pb, nb = best(BAKE), best(NO_BAKE)
        if pb and nb:
            md.append(f"| {b} | {pb[1]} | {pb[0]:.4g} | {nb[1]} | {nb[0]:.4g} | {pb[0] / nb[0]:.2f} |")
    md.append("")

    # (c) time to a fixed RMSE.
    target = None
    for x in curves.get("ratio", []):
        if float(x[2]) == target_budget:
            target = x[1]
    with open(f"{out}/time_to_rmse.csv", "w") as f:
        w = csv.writer(f)
        w.writerow(["estimator", "target_rmse", "seconds", "note"])
        if target is not None:
            md += [f"## Time to RMSE {target:.4g} (ratio tracking's at {target_budget:g} s)", ""]
            md.append("| estimator | seconds | against ratio | note |")
            md.append("|---|---|---|---|")
            ratio_t, _ = time_to(sorted((x[0], x[1]) for x in curves["ratio"]), target)
            for e, c in curves.items():
                t, note = time_to(sorted((x[0], x[1]) for x in c), target)
                w.writerow([e, f"{target:.6g}", "" if t is None else f"{t:.3f}", note])
                rel = "" if t is None or not ratio_t else f"{t / ratio_t:.2f}"
                md.append(f"| {e} | {'' if t is None else f'{t:.2f}'} | {rel} | {note} |")
            md.append("")
    with open(f"{out}/summary.md", "w") as f:
        f.write("\n".join(md) + "\n")


if __name__ == "__main__":
    main(sys.argv)
