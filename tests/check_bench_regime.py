#!/usr/bin/python3
"""Checks that a `meso bench` suite is in paper 004's regime (issue 21 item 4), the CTest
Bench.SuiteRegime on scenes/bench/suite.json:
  * every scene renders at least 320 x 240 (after the suite's defines);
  * the median texels per pixel over the pixels that see a mapped shape (the bench's measure:
    the `footprint` aov at 1 spp, the major axis of each pixel's ray-differential footprint in
    texels of the full-resolution map, tiling included) is at least 16;
  * every target's `level` is the one its own footprint calls for: of the factors its map allows
    (powers of two that divide the map, after a clamp/mirror extension, into a multiple of M
    coarse cells, as `meso prefilter --scales` requires), the one nearest the target's median
    footprint in log scale (a coarse cell about one pixel). With several targets, each one's
    median is measured with the other targets' displacement removed;
  * every target's detail is sub-pixel or kept: at most --max-pixel-band (2%) of its map's slope
    energy lies at wavelengths between half its median footprint P and P
    (scripts/experiments/slope_spectrum). Detail there is resolved or aliased into the converged
    image (moire), so a level that prefilters it is biased and one that keeps it keeps its
    noise: no level can win (the session-31 plane, 16 x 16 tiles: 0.55; relief, 2048^2 with
    8-16-texel noise: 0.39). Detail above P stays in the coarse geometry h_low.
Prints one line per scene and target. Exit 1 with a list of what fails.
Usage: check_bench_regime.py [SUITE] [--meso build/meso] [--out DIR] [--min-texels 16]
                             [--max-pixel-band 0.02]
"""
import argparse
import copy
import json
import math
import os
import subprocess
import sys
import tempfile

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
sys.path.insert(0, os.path.join(ROOT, "scripts", "experiments"))
from meso_common import apply_define, load_exr, read_pfm, read_scene, run, slope_fractions  # noqa: E402

FOOTPRINT = 'integrator={"type":"aov","aov":"footprint","resolution":1e-9}'


def footprint_stats(meso, scene, defines, exr):
    """Median and 10th / 90th percentiles of the footprint aov over the mapped pixels (as the
    bench's texels_per_pixel), or None when no pixel sees a mapped shape."""
    cmd = [meso, "render", scene, "-o", exr, "-q", "--spp", "1", "--seed", "1", "-D", FOOTPRINT]
    for d in defines:
        cmd += ["-D", d]
    run(cmd)
    fp = load_exr(meso, exr)[..., 0]
    v = fp[np.isfinite(fp) & (fp > 1e-3)]
    if v.size == 0:
        return None
    return {"median": float(np.median(v)), "p10": float(np.percentile(v, 10)), "p90": float(np.percentile(v, 90))}


def allowed_levels(disp_info, prefilter_opts):
    """The downsampling factors `meso prefilter --scales` accepts for this map and M."""
    ext = 1 if disp_info["wrap"] == "repeat" else 2
    w, h = disp_info["map"][0] * ext, disp_info["map"][1] * ext
    opts = [str(x) for x in prefilter_opts]
    M = int(opts[opts.index("-M") + 1]) if "-M" in opts else 4
    out, f = [], 2
    while w % f == 0 and h % f == 0 and (w // f) % M == 0 and (h // f) % M == 0:
        out.append(f)
        f *= 2
    return out


def called_for(levels, texels):
    """The level nearest `texels` in log scale (ties to the finer one)."""
    return min(levels, key=lambda f: (abs(math.log2(f) - math.log2(texels)), f))


def map_heights(meso, mapobj, scene_dir, tmp, tag):
    """The displacement map's heights (one tile) as an array: an inline generator object through
    `meso genmap` (its `image` resolves against the scene's directory), or a map file."""
    pfm = os.path.join(tmp, f"{tag}_map.pfm")
    if isinstance(mapobj, dict):
        exr = os.path.join(tmp, f"{tag}_map.exr")
        cmd = [meso, "genmap", mapobj["generator"], "-o", exr]
        for k, v in mapobj.items():
            if k != "generator":
                cmd += ["-p", f"{k}={v}"]
        subprocess.run(cmd, cwd=scene_dir, check=True, stdout=subprocess.DEVNULL)
        src = exr
    else:
        src = os.path.normpath(os.path.join(scene_dir, mapobj))
    run([meso, "convert", src, pfm])
    h = read_pfm(pfm)
    return h[..., 0] if h.ndim == 3 else h


def check_pixel_band(a, name, i, sj, scene_dir, median, tmp, bad):
    """The fraction of the target's slope energy between half a pixel and a pixel (see above)."""
    h = map_heights(a.meso, sj["shapes"][i]["displacement"]["map"], scene_dir, tmp, f"{name}_s{i}")
    above_p, above_half = slope_fractions(h, [median], divisors=(1, 2))[median]
    band = above_half - above_p
    print(f"  shapes[{i}]: slope energy above P {above_p:.3f}, between P/2 and P {band:.3f}", flush=True)
    if band > a.max_pixel_band:
        bad.append(f"{name}: shapes[{i}] has {band:.3f} of its slope energy between half a pixel and a pixel "
                   f"(P = {median:.1f} texels; at most {a.max_pixel_band:g}): pixel-scale detail, outside the regime")


def check_scene(a, name, entry, sdir, tmp, bad):
    scene = os.path.normpath(os.path.join(sdir, entry["scene"]))
    defines = list(entry.get("defines", []))
    sj = read_scene(scene)
    for d in defines:
        apply_define(sj, d)
    cam = sj["camera"]
    if cam.get("width", 0) < 320 or cam.get("height", 0) < 240:
        bad.append(f"{name}: {cam.get('width')} x {cam.get('height')} is below 320 x 240")
    info_cmd = [a.meso, "info", scene, "--json", "-"]
    for d in defines:
        info_cmd += ["-D", d]
    info = json.loads(run(info_cmd))
    whole = footprint_stats(a.meso, scene, defines, os.path.join(tmp, f"{name}.exr"))
    if whole is None:
        bad.append(f"{name}: no pixel sees a mapped shape")
        return
    if whole["median"] < a.min_texels:
        bad.append(f"{name}: median texels per pixel {whole['median']:.1f} < {a.min_texels:g}")
    print(f"{name}: {cam.get('width')} x {cam.get('height')}, texels/px median {whole['median']:.1f} "
          f"(10th-90th {whole['p10']:.1f}-{whole['p90']:.1f})", flush=True)
    targets = entry["targets"]
    for t in targets:
        i = t["shape"]
        own = whole
        if len(targets) > 1:
            # Only this target's pixels: the others without their displacement (no map, no footprint).
            alone = list(defines)
            for u in targets:
                if u["shape"] != i:
                    s = copy.deepcopy(sj["shapes"][u["shape"]])
                    s.pop("displacement", None)
                    alone.append(f"shapes[{u['shape']}]={json.dumps(s)}")
            own = footprint_stats(a.meso, scene, alone, os.path.join(tmp, f"{name}_s{i}.exr"))
        if own is None:
            bad.append(f"{name}: no pixel sees shapes[{i}]")
            continue
        levels = allowed_levels(info["shapes"][i]["displacement"], t.get("prefilter", []))
        want = called_for(levels, own["median"]) if levels else None
        print(f"  shapes[{i}]: texels/px median {own['median']:.1f} (10th-90th {own['p10']:.1f}-{own['p90']:.1f}); "
              f"level x{t['level']}, the footprint calls for x{want} of {levels}", flush=True)
        if want != t["level"]:
            bad.append(f"{name}: shapes[{i}] level x{t['level']}, but its footprint ({own['median']:.1f} texels a "
                       f"pixel) calls for x{want}")
        check_pixel_band(a, name, i, sj, os.path.dirname(scene), own["median"], tmp, bad)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("suite", nargs="?", default=os.path.join(ROOT, "scenes", "bench", "suite.json"))
    ap.add_argument("--meso", default=os.path.join(ROOT, "build", "meso"))
    ap.add_argument("--out", default="", help="where the aov renders go (default: a temporary directory)")
    ap.add_argument("--min-texels", type=float, default=16.0)
    ap.add_argument("--max-pixel-band", type=float, default=0.02,
                    help="largest fraction of a target's slope energy between P/2 and P texels")
    a = ap.parse_args()
    with open(a.suite) as f:
        suite = json.load(f)
    bad = []
    with tempfile.TemporaryDirectory() as tmpd:
        tmp = a.out or tmpd
        os.makedirs(tmp, exist_ok=True)
        for name, entry in suite["scenes"].items():
            check_scene(a, name, entry, os.path.dirname(os.path.abspath(a.suite)), tmp, bad)
    for b in bad:
        print("FAIL " + b)
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
