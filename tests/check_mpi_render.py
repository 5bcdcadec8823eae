#!/usr/bin/python3
"""MPI checks of `meso render` (issue 10, docs/cluster.md), run by CTest when meso is built with MPI.

  equal      `mpirun -n 1` and `mpirun -n 2` against the plain single-process render of the same
             scene, seed and spp. The ranks render disjoint blocks of the same per-sample seeded
             indices and rank 0 sums the films, so the images may differ only by the order of the
             double-precision sums: |difference| <= 4 float ulps of the pixel value (the EXR is float;
             a double rounding difference can move the float by at most one ulp, the margin covers
             the division by spp). One rank is the same order as no MPI: bit-exact.
  time       `--time` with 2 ranks: both stop after the same pass, the record's spp is the sum and
             is a whole number of 2-rank passes, the wall time is near the budget.
  failure    a rank that fails (a missing scene) ends the job with a non-zero exit and a message,
             and leaves no output file.
Usage: check_mpi_render.py --meso PATH [--out DIR] [--mpirun mpirun]. Exit 1 on any failure.
"""
import argparse
import json
import os
import subprocess
import sys

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.join(os.path.dirname(HERE), "scripts"))
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

    for f in failures:
        print("FAIL: " + f, file=sys.stderr)
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
