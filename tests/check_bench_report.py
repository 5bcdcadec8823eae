#!/usr/bin/python3
"""Checks a `meso bench` output directory (the CTest Bench.Tiny.Report): results.json has every
(scene, variant, method, budget) with finite, positive errors and times, the reference noise and
the equal-time comparisons; report.md has its sections; the figures exist and are PNGs.
Usage: check_bench_report.py OUT_DIR [--methods original,forig_hlow,...]. Exit 1 with a list of
what is missing."""
import json
import math
import os
import sys


def main():
    out = sys.argv[1]
    methods = None
    if "--methods" in sys.argv:
        methods = sys.argv[sys.argv.index("--methods") + 1].split(",")
    bad = []
    with open(os.path.join(out, "results.json")) as f:
        res = json.load(f)
    fin = lambda x: isinstance(x, (int, float)) and math.isfinite(x)
    if not res.get("rows"):
        bad.append("results.json: no rows")
    if not (fin(res.get("total_s")) and res["total_s"] > 0):
        bad.append("results.json: total_s")
    for r in res.get("rows", []):
        tag = f"{r.get('scene')}/{r.get('variant')}"
        ref = r.get("reference", {})
        if not (fin(ref.get("noise_mse")) and ref["noise_mse"] >= 0):
            bad.append(f"{tag}: reference noise")
        want = methods or list(r["methods"])
        for m in want:
            runs = r["methods"].get(m)
            if runs is None:
                if m != "vmf" and m != "leadr":
                    bad.append(f"{tag}: method {m} missing")
                continue
            if [x["budget_s"] for x in runs] != res["times"]:
                bad.append(f"{tag}/{m}: budgets {[x['budget_s'] for x in runs]} != {res['times']}")
            for x in runs:
                for k in ("mse", "mse_se", "relmse", "time_s", "spp"):
                    if not (fin(x.get(k)) and x[k] >= 0):
                        bad.append(f"{tag}/{m}/{x.get('budget_s')}: {k} = {x.get(k)}")
                if x.get("nan_count", 1) != 0:
                    bad.append(f"{tag}/{m}/{x.get('budget_s')}: NaN pixels")
                if fin(x.get("time_s")) and x["time_s"] > 1.5 * x["budget_s"] + 0.5:
                    bad.append(f"{tag}/{m}/{x['budget_s']}: ran {x['time_s']:.2f} s, over its budget")
        tp = r.get("texels_per_pixel")
        if not (tp and fin(tp.get("median")) and tp["median"] > 0 and 0 < tp.get("covered", 0) <= 1):
            bad.append(f"{tag}: texels_per_pixel = {tp}")
        if len(r.get("comparison", [])) != len(res["times"]):
            bad.append(f"{tag}: equal-time comparison missing")
        for c in r.get("comparison", []):
            if not all(fin(c.get(k)) for k in ("original_mse", "ours_mse", "ratio", "noise_2se")):
                bad.append(f"{tag}: comparison not finite at {c.get('budget_s')}")
    for m in res.get("models", {}).values():
        for t in m:
            for k in ("model_kb", "total_s", "original_kb"):
                if not fin(t.get("table3", {}).get(k)):
                    bad.append(f"model {t.get('dir')}: table3.{k}")
    with open(os.path.join(out, "report.md")) as f:
        rep = f.read()
    for s in ("## Equal time", "## Every method", "## Error against time", "## Storage and precomputation",
              "Suite run time", "Time to reach"):
        if s not in rep:
            bad.append(f"report.md: no '{s}'")
    if "nan" in rep.lower().replace("nan pixels", ""):
        bad.append("report.md: contains 'nan'")
    for p in res.get("figures", []) + ["curves.png"]:
        fp = os.path.join(out, p)
        if not os.path.isfile(fp):
            bad.append(f"figure {p} missing")
            continue
        with open(fp, "rb") as f:
            if f.read(8) != b"\x89PNG\r\n\x1a\n":
                bad.append(f"figure {p} is not a PNG")
    if bad:
        print("bench report incomplete:\n  " + "\n  ".join(bad))
        return 1
    print(f"bench report complete: {len(res['rows'])} rows, {len(res['times'])} budgets, figures {res.get('figures')}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
