"""Small helpers shared by meso's experiment scripts (scripts/experiments/bench, scripts/experiments/prefilter_appearance):
running meso, PFM image I/O, scene files with // comment lines, `-D` overrides applied to a
parsed scene, and `meso prefilter` options from a displacement's map."""
import hashlib
import json
import os
import re
import subprocess
import sys

import numpy as np


def read_scene(path):
    """The scene JSON without its // comment lines (the scenes keep comments on lines of their own)."""
    with open(path) as f:
        text = "".join(line for line in f if not line.lstrip().startswith("//"))
    return json.loads(text)


def write_pfm(path, img):
    h, w = img.shape[:2]
    with open(path, "wb") as f:
        f.write(b"PF\n%d %d\n-1.0\n" % (w, h))
        f.write(np.ascontiguousarray(img[::-1].astype("<f4")).tobytes())


def read_pfm(path):
    with open(path, "rb") as f:
        kind = f.readline().strip()
        w, h = map(int, f.readline().split())
        scale = float(f.readline())
        data = np.frombuffer(f.read(), dtype="<f4" if scale < 0 else ">f4")
    c = 3 if kind == b"PF" else 1
    return data.reshape(h, w, c)[::-1].astype(np.float64)


def run(cmd, quiet=True):
    """Runs a command; on failure prints it with its output and exits naming the subcommand."""
    r = subprocess.run(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    if r.returncode in (130, -2):
        # Ctrl-C reaches the whole process group: the child stopped (meso exits 130 after
        # keeping its passes). Stop too; callers stage results in *.partial and never rename them.
        sys.stderr.write("interrupted\n")
        raise SystemExit(130)
    if r.returncode != 0:
        sys.stderr.write(" ".join(cmd) + "\n" + r.stdout + r.stderr)
        raise SystemExit(f"command failed ({r.returncode}): {cmd[1] if len(cmd) > 1 else cmd[0]}")
    return r.stdout


def load_exr(meso, exr):
    """An EXR as a float64 (h, w, 3) array (through `meso convert` to PFM next to it)."""
    pfm = exr[:-4] + ".pfm"
    run([meso, "convert", exr, pfm])
    return read_pfm(pfm)


def gen_args(mapobj):
    """`meso prefilter` generator options from a displacement's inline generator object."""
    args = ["--generator", mapobj["generator"]]
    for k, v in mapobj.items():
        if k == "generator":
            continue
        if k == "size":
            args += ["--size", str(v)]
        elif k == "seed":
            args += ["--map-seed", str(v)]
        else:
            args += ["-p", f"{k}={v}"]
    return args


_TOKEN = re.compile(r"([^.\[\]]+)|\[(\d+)\]")


def apply_define(obj, define):
    """Applies one `-D key=json` override (as `meso render -D` does: dotted keys, [i] indices,
    the value parsed as JSON, else taken as a string) to a parsed scene, in place."""
    key, eq, value = define.partition("=")
    if not eq:
        raise ValueError(f"-D {define}: expected key=value")
    try:
        val = json.loads(value)
    except json.JSONDecodeError:
        val = value
    path = [m.group(1) if m.group(1) is not None else int(m.group(2)) for m in _TOKEN.finditer(key)]
    cur = obj
    for p in path[:-1]:
        cur = cur[p]
    cur[path[-1]] = val
    return obj


def file_sha1(path, cache={}):
    if path not in cache:
        h = hashlib.sha1()
        with open(path, "rb") as f:
            for chunk in iter(lambda: f.read(1 << 20), b""):
                h.update(chunk)
        cache[path] = h.hexdigest()
    return cache[path]


def referenced_files(obj, base_dir):
    """Every string in a parsed scene that names an existing file (relative to base_dir or
    absolute): the assets whose contents a cache key must include."""
    out = set()

    def walk(o):
        if isinstance(o, dict):
            for v in o.values():
                walk(v)
        elif isinstance(o, list):
            for v in o:
                walk(v)
        elif isinstance(o, str) and len(o) < 4096:
            p = o if os.path.isabs(o) else os.path.join(base_dir, o)
            if os.path.isfile(p):
                out.add(os.path.normpath(p))

    walk(obj)
    return sorted(out)


def absolutize(obj, base_dir):
    """A copy of a scene fragment with relative file names made absolute (so that it can be
    passed with -D or to `meso prefilter` from any directory)."""
    if isinstance(obj, dict):
        return {k: absolutize(v, base_dir) for k, v in obj.items()}
    if isinstance(obj, list):
        return [absolutize(v, base_dir) for v in obj]
    if isinstance(obj, str) and not os.path.isabs(obj) and len(obj) < 4096:
        p = os.path.join(base_dir, obj)
        if os.path.isfile(p):
            return os.path.normpath(p)
    return obj


def slope_fractions(h, footprints, divisors=(1, 2, 4, 8)):
    """{P: [fraction of slope energy at wavelength > P / d for d in divisors]} of height map h."""
    h = np.asarray(h, dtype=np.float64)
    H = np.fft.fft2(h - h.mean())
    ky = np.fft.fftfreq(h.shape[0])[:, None]
    kx = np.fft.fftfreq(h.shape[1])[None, :]
    k2 = kx * kx + ky * ky
    energy = k2 * np.abs(H) ** 2
    total = energy.sum()
    lam = np.full(k2.shape, np.inf)
    np.divide(1.0, np.sqrt(k2), out=lam, where=k2 > 0)
    out = {}
    for p in footprints:
        out[p] = [float(energy[lam > p / d].sum() / total) if total > 0 else 0.0 for d in divisors]
    return out
