#!/usr/bin/python3
"""Writes scenes/assets/sky.hdr: a procedural lat-long sky (blue gradient, warm horizon,
dark ground, a small bright sun) as a Radiance RGBE file, which OpenImageIO reads.
Deterministic; run `/usr/bin/python3 scripts/make_sky.py` to regenerate.

Lat-long convention (meso's envmap): row 0 = straight up (+y), u = phi / 2pi across.
"""
import sys
import numpy as np

W, H = 512, 256
out = sys.argv[1] if len(sys.argv) > 1 else "scenes/assets/sky.hdr"
v = (np.arange(H) + 0.5) / H
u = (np.arange(W) + 0.5) / W
theta = v[:, None] * np.pi            # 0 = up
phi = u[None, :] * 2 * np.pi
up = np.cos(theta)                     # elevation sine
img = np.zeros((H, W, 3))
sky_t = np.clip(up, 0, 1) ** 0.5
zenith = np.array([0.25, 0.45, 0.95])
horizon = np.array([1.0, 0.9, 0.75])
ground = np.array([0.18, 0.16, 0.14])
img[:] = np.where(up[..., None] > 0, horizon * (1 - sky_t[..., None]) + zenith * sky_t[..., None], ground)
# Sun: 3 degrees wide, 35 degrees elevation, phi = 60 degrees.
sd = np.array([np.cos(np.radians(35)) * np.sin(np.radians(60)), np.sin(np.radians(35)),
               -np.cos(np.radians(35)) * np.cos(np.radians(60))])
dirs = np.stack([np.sin(theta) * np.sin(phi), np.cos(theta) * np.ones_like(phi), -np.sin(theta) * np.cos(phi)], -1)
cosang = dirs @ sd
img[cosang > np.cos(np.radians(1.5))] = np.array([400.0, 360.0, 300.0])

def rgbe(c):
    m = c.max(-1)
    e = np.zeros(m.shape, dtype=np.int32)
    mant, e = np.frexp(m)
    scale = np.where(m > 1e-32, mant * 256.0 / np.maximum(m, 1e-32), 0)
    b = np.zeros(c.shape[:-1] + (4,), dtype=np.uint8)
    b[..., :3] = np.clip(c * scale[..., None], 0, 255).astype(np.uint8)
    b[..., 3] = np.where(m > 1e-32, e + 128, 0).astype(np.uint8)
    return b

with open(out, "wb") as f:
    f.write(b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n")
    f.write(("-Y %d +X %d\n" % (H, W)).encode())
    f.write(rgbe(img).tobytes())
print("wrote", out)
