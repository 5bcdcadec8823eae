#!/usr/bin/python3
"""Checks that `meso bench`'s LoD chain for `ours` holds the levels the renderer selects (issue 21
item 5), the CTest Bench.ChainCoversSampleFootprints:
  * the renderer scales camera footprints by the bench's sample_footprint_scale (measured: the
    `footprint` aov of a timed render over the same aov at 1 spp, on scenes/bench/plane.json at
    64 spp and at 4 spp; the ratio of medians must be 1/8 and 1/2 within 3%);
  * for a footprint range, chain_scales(chain_need) starts at a factor no coarser than twice the
    smallest per-sample footprint (below half the first factor the selection falls back to the
    original, geometry/lod.h) and ends at one no finer than the largest.
Exit 1 with a list of what fails.
Usage: check_bench_chain.py [--meso build/meso] [--out DIR]
"""
import argparse
import importlib.machinery
import importlib.util
import os
import sys
import tempfile
import types

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
sys.path.insert(0, os.path.join(ROOT, "scripts", "experiments"))
from meso_common import load_exr, read_scene, run  # noqa: E402

FOOTPRINT = 'integrator={"type":"aov","aov":"footprint","resolution":1e-9}'


def load_bench():
    path = os.path.join(ROOT, "scripts", "experiments", "bench")
    loader = importlib.machinery.SourceFileLoader("meso_bench", path)
    spec = importlib.util.spec_from_loader("meso_bench", loader)
    mod = importlib.util.module_from_spec(spec)
    loader.exec_module(mod)
    return mod


def median_footprint(meso, scene, exr, extra):
    run([meso, "render", scene, "-o", exr, "-q", "--seed", "1", "-D", FOOTPRINT,
         "-D", "camera.width=64", "-D", "camera.height=48"] + extra)
    fp = load_exr(meso, exr)[..., 0]
    return float(np.median(fp[np.isfinite(fp) & (fp > 1e-3)]))


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--meso", default=os.path.join(ROOT, "build", "meso"))
    ap.add_argument("--out", default="")
    a = ap.parse_args()
    bench = load_bench()
    out = a.out or tempfile.mkdtemp(prefix="bench_chain_")
    os.makedirs(out, exist_ok=True)
    scene = os.path.join(ROOT, "scenes", "bench", "plane.json")
    fails = []
    one = median_footprint(a.meso, scene, os.path.join(out, "fp_1spp.exr"), ["--spp", "1"])
    for spp in (64, 4):
        sc = types.SimpleNamespace(json=read_scene(scene))
        sc.json["sampler"]["sample_count"] = spp
        expected = bench.sample_footprint_scale(sc)
        timed = median_footprint(a.meso, scene, os.path.join(out, f"fp_timed_{spp}.exr"),
                                 ["--time", "0.2", "-D", f"sampler.sample_count={spp}"])
        print(f"sample_count {spp}: timed / 1-spp footprint {timed / one:.4f}, bench's scale {expected:.4f}")
        if abs(timed / one / expected - 1) > 0.03:
            fails.append(f"sample_count {spp}: the renderer scales footprints by {timed / one:.4f}, "
                         f"the bench assumes {expected:.4f}")
    geo = {"wrap": "repeat", "map": [512, 512]}
    t = {"level": 32, "prefilter": ["-M", "4"]}
    for need in [(2.1, 8.3), (0.3, 3.0), (5.0, 5.0), (40.0, 900.0)]:
        scales = bench.chain_scales(geo, t, need)
        chain = [s for s in scales if s != t["level"]] or scales
        print(f"footprints {need}: chain {scales}")
        if chain[0] > max(2.0, 2 * need[0]):
            fails.append(f"footprints {need}: first factor {chain[0]} > twice the smallest footprint")
        if max(scales) < min(need[1], 128):
            fails.append(f"footprints {need}: last factor {max(scales)} below the largest footprint")
    big = bench.chain_scales({"wrap": "repeat", "map": [2048, 2048]}, {"level": 16, "prefilter": ["-M", "1"]}, (2.2, 2.6))
    print(f"2048^2 map, footprints (2.2, 2.6): chain {big}")
    if big[0] != 4:  # x2 would be 1M patches, over MAX_LEVEL_PATCHES
        fails.append(f"2048^2 map: chain {big} should start at x4 (at most {bench.MAX_LEVEL_PATCHES} patches a level)")
    for f in fails:
        print("FAIL:", f)
    return 1 if fails else 0


if __name__ == "__main__":
    sys.exit(main())
