#!/usr/bin/python3
"""MPI checks of `meso render` and `meso prefilter` (issue 10, docs/cluster.md), run by CTest when
meso is built with MPI.

  equal      `mpirun -n 1` and `mpirun -n 2` against the plain single-process render of the same
             scene, seed and spp. The ranks render disjoint blocks of the same per-sample seeded
             indices and rank 0 sums the films, so the images may differ only by the order of the
             double-precision sums: |difference| <= 4 float ulps of the pixel value (the EXR is float;
             a double rounding difference can move the float by at most one ulp, the margin covers
             the division by spp). One rank is the same order as no MPI: bit-exact.
  crop       `--crop` with 2 ranks against the plain crop (within 4 ulps)
  time       `--time` with 2 ranks: both stop after the same pass, the record's spp is the sum and
             is a whole number of 2-rank passes, the wall time is near the budget.
  failure    a rank that fails (a missing scene) ends the job with a non-zero exit and a message,
             and leaves no output file.
  prefilter  `mpirun -n 2 meso prefilter` deals the T/S tasks out to the ranks and exchanges them
             after each round: T, S, T_ir, S_ir and h_low must be bit-identical to the plain run's
             (pixels; the EXR headers carry a date), and so must the manifest's statistics but for
             timings.
Usage: check_mpi.py --meso PATH [--out DIR] [--mpirun mpirun]. Exit 1 on any failure.
"""
import argparse
import json
import os
import subprocess
import sys

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.join(os.path.dirname(HERE), "scripts", "experiments"))
from meso_common import load_exr  # noqa: E402

ROOT = os.path.dirname(HERE)
SCENES = [
    (os.path.join(ROOT, "scenes", "demo", "demo.json"), ["-D", "camera.width=64", "-D", "camera.height=48"]),
    (os.path.join(ROOT, "scenes", "colormap", "gaussian_heights_lod.json"),
     ["-D", "camera.width=48", "-D", "camera.height=32"]),
]


def mpirun_cmd(mpirun, n):
    cmd = [mpirun, "-n", str(n), "--oversubscribe"]
    if hasattr(os, "geteuid") and os.geteuid() == 0:
        cmd.append("--allow-run-as-root")
    return cmd


def run(cmd):
    return subprocess.run(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, timeout=600)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--meso", required=True)
    ap.add_argument("--out", default="mpi_check")
    ap.add_argument("--mpirun", default="mpirun")
    a = ap.parse_args()
    os.makedirs(a.out, exist_ok=True)
    failures = []

    for k, (scene, defines) in enumerate(SCENES):
        base = [a.meso, "render", scene, "--spp", "16", "--seed", "5", "-q", "--threads", "1"] + defines
        imgs = {}
        for label, prefix in (("plain", []), ("n1", mpirun_cmd(a.mpirun, 1)), ("n2", mpirun_cmd(a.mpirun, 2))):
            exr = os.path.join(a.out, f"s{k}_{label}.exr")
            r = run(prefix + base + ["-o", exr])
            if r.returncode != 0:
                failures.append(f"{label} render of {scene} failed: {r.stderr.strip()}")
                continue
            imgs[label] = load_exr(a.meso, exr)
            with open(exr[:-4] + ".json") as f:
                rec = json.load(f)
            want_ranks = 2 if label == "n2" else 1
            if rec.get("ranks") != want_ranks or rec.get("spp") != 16:
                failures.append(f"{label}: record has ranks {rec.get('ranks')} spp {rec.get('spp')}")
        if len(imgs) < 3:
            continue
        p = imgs["plain"].astype(np.float32)
        if not np.array_equal(p, imgs["n1"].astype(np.float32)):
            failures.append(f"{scene}: 1 rank differs from the plain render (expected bit-exact)")
        d = np.abs(imgs["n2"].astype(np.float32) - p)
        ulp = np.spacing(np.abs(p).astype(np.float32))
        worst = float(np.max(d / np.maximum(ulp, np.finfo(np.float32).tiny)))
        same = float(np.mean(d == 0))
        print(f"{os.path.basename(scene)}: 2 ranks vs plain: {100 * same:.2f}% of values bit-identical, "
              f"max difference {worst:.1f} ulp")
        if worst > 4:
            failures.append(f"{scene}: 2 ranks differ from the plain render by {worst:.1f} ulp (> 4)")

    # --crop under 2 ranks: the window's pixels as in the plain crop (and merge-able)
    scene, defines = SCENES[0]
    crop = ["--crop", "8,4,40,30", "--spp", "16", "--seed", "5", "-q", "--threads", "1"] + defines
    ca, cb = os.path.join(a.out, "crop_plain.exr"), os.path.join(a.out, "crop_n2.exr")
    ra = run([a.meso, "render", scene, "-o", ca] + crop)
    rb = run(mpirun_cmd(a.mpirun, 2) + [a.meso, "render", scene, "-o", cb] + crop)
    if ra.returncode or rb.returncode:
        failures.append(f"crop renders failed: {ra.stderr.strip()[:200]} {rb.stderr.strip()[:200]}")
    else:
        ia, ib = load_exr(a.meso, ca).astype(np.float32), load_exr(a.meso, cb).astype(np.float32)
        worst = float(np.max(np.abs(ia - ib) / np.maximum(np.spacing(np.abs(ia)), np.finfo(np.float32).tiny)))
        print(f"--crop with 2 ranks vs plain crop: max difference {worst:.1f} ulp")
        if ia.shape != (26, 32, 3) or worst > 4:
            failures.append(f"crop: 2 ranks differ from the plain crop ({worst:.1f} ulp) or wrong size {ia.shape}")

    # --time across ranks
    exr = os.path.join(a.out, "timed.exr")
    scene, defines = SCENES[0]
    r = run(mpirun_cmd(a.mpirun, 2) + [a.meso, "render", scene, "--time", "1.5", "-q", "--threads", "1", "-o", exr]
            + defines)
    if r.returncode != 0:
        failures.append(f"timed render failed: {r.stderr.strip()}")
    else:
        with open(exr[:-4] + ".json") as f:
            rec = json.load(f)
        block = -(-8192 // (64 * 48))  # spp per rank and pass under --time (render/renderer.cpp)
        print(f"--time 1.5 with 2 ranks: {rec['spp']} spp in {rec['passes']} passes, wall {rec['wall_s']:.2f} s")
        if rec["ranks"] != 2 or rec["spp"] != rec["passes"] * 2 * block:
            failures.append(f"timed: spp {rec['spp']} is not passes x 2 ranks x {block}")
        if not (0.75 * 1.5 <= rec["wall_s"] <= 1.5 * 1.5):
            failures.append(f"timed: wall {rec['wall_s']:.2f} s is not near the 1.5 s budget")

    # a failing rank ends the job, no output
    exr = os.path.join(a.out, "fail.exr")
    r = run(mpirun_cmd(a.mpirun, 2) + [a.meso, "render", os.path.join(a.out, "no_such_scene.json"), "-o", exr])
    msg = r.stderr + r.stdout
    if r.returncode == 0:
        failures.append("a missing scene under mpirun exited 0")
    if "no_such_scene.json" not in msg:
        failures.append(f"the failure message does not name the scene: {msg.strip()[:300]}")
    if os.path.exists(exr):
        failures.append("a failed MPI render left an output file")
    print(f"failing rank: exit {r.returncode}, message: {msg.strip().splitlines()[0] if msg.strip() else '(none)'}")

    # prefilter: 1 process vs 2 ranks, two rounds
    pf = ["prefilter", "--generator", "gaussian", "--size", "64", "--scales", "8", "-M", "2", "-N", "5", "--paths", "8",
          "--low-paths", "8", "--target-error", "0.001", "--max-rounds", "2", "-q"]
    outs = {}
    for label, prefix in (("plain", []), ("n2", mpirun_cmd(a.mpirun, 2))):
        d = os.path.join(a.out, f"prefilter_{label}")
        r = run(prefix + [a.meso] + pf + ["-o", d])
        if r.returncode != 0:
            failures.append(f"prefilter ({label}) failed: {r.stderr.strip()[:300]}")
        outs[label] = d
    if not failures or all("prefilter" not in f for f in failures):
        for t in ("T", "S", "T_ir", "S_ir", "h_low"):
            ia = load_exr(a.meso, os.path.join(outs["plain"], "level_8", t + ".exr"))
            ib = load_exr(a.meso, os.path.join(outs["n2"], "level_8", t + ".exr"))
            if not np.array_equal(ia, ib):
                failures.append(f"prefilter: {t} differs between 1 process and 2 ranks")

        def stats(d):
            with open(os.path.join(d, "manifest.json")) as f:
                m = json.load(f)
            lv = m["levels"][0]
            drop = {"timing", "core_seconds_orig", "core_seconds_low", "seconds"}
            return {k: v for k, v in lv.items() if k not in drop}, m.get("ranks")
        (sa, ra), (sb, rb) = stats(outs["plain"]), stats(outs["n2"])
        for k in set(sa) | set(sb):
            if sa.get(k) != sb.get(k):
                failures.append(f"prefilter: manifest level key '{k}' differs: {sa.get(k)} vs {sb.get(k)}")
        if rb != 2:
            failures.append(f"prefilter: manifest ranks {rb}, expected 2")
        print("prefilter: 1 process vs 2 ranks: T, S, T_ir, S_ir, h_low " +
              ("identical" if not any("prefilter" in f for f in failures) else "DIFFER"))

    for f in failures:
        print("FAIL: " + f, file=sys.stderr)
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
