#!/usr/bin/env python3
"""Writes the small glTF fixtures used by tests/test_gltf.cpp (run from anywhere):

  quad.gltf / quad.glb  a unit quad (2 triangles, uint16 indices, normals, uvs) moved to
                        z = -1, a perspective camera at z = 5, a KHR_lights_punctual
                        point light and a red plastic-like material (metallic 0, rough 0.5)
  mixed.gltf            no camera, no punctual lights; one mesh with a triangle strip (no
                        indices), a POINTS primitive (skipped), and uint8-indexed
                        triangles with normalised uint8 texcoords and an emissive
                        material; instanced twice: by a mirroring node (scale -1 in x)
                        and by its child (translated by +3 in y, so mirrored too)
  textured.gltf / .glb  the quad at z = 0 seen from z = 10 (narrow fov), no lights, material
                        "checker": gltf_pbr inputs from textures: baseColorTexture a 2x2
                        sRGB checker (checker.png: top-left red, top-right green, bottom-left
                        blue, bottom-right sRGB 188 grey = linear 0.503), metallicRoughness
                        texture mr.png (uniform G = 255 roughness, B = 0 metallic), factors
                        1; the .gltf refers to the PNGs by URI, the .glb embeds them as
                        bufferView images
  normal_up.png         a 1x1 tangent-space normal map tilted towards +y (test of the
                        normal-map direction in tests/test_gltf.cpp)
  alpha_half.png        a 2x1 RGBA image: left texel sRGB 188 grey with alpha 255, right
                        texel the same grey with alpha 0 (alphaMode MASK tests)
"""
import base64, json, os, struct, zlib

HERE = os.path.dirname(os.path.abspath(__file__))


class Buf:
    def __init__(self):
        self.data = bytearray()
        self.views = []
        self.accessors = []

    def add(self, fmt, values, ctype, atype, count, normalized=False, minmax=None):
        while len(self.data) % 4:
            self.data.append(0)
        off = len(self.data)
        raw = struct.pack("<" + fmt * len(values), *values)
        self.data += raw
        self.views.append({"buffer": 0, "byteOffset": off, "byteLength": len(raw)})
        acc = {"bufferView": len(self.views) - 1, "componentType": ctype, "type": atype, "count": count}
        if normalized:
            acc["normalized"] = True
        if minmax:
            acc["min"], acc["max"] = minmax
        self.accessors.append(acc)
        return len(self.accessors) - 1


FLOAT, UBYTE, USHORT = 5126, 5121, 5123


def quad():
    b = Buf()
    pos = b.add("f", [-1, -1, 0, 1, -1, 0, 1, 1, 0, -1, 1, 0], FLOAT, "VEC3", 4, minmax=([-1, -1, 0], [1, 1, 0]))
    nor = b.add("f", [0, 0, 1] * 4, FLOAT, "VEC3", 4)
    uv = b.add("f", [0, 1, 1, 1, 1, 0, 0, 0], FLOAT, "VEC2", 4)
    idx = b.add("H", [0, 1, 2, 0, 2, 3], USHORT, "SCALAR", 6)
    g = {
        "asset": {"version": "2.0", "generator": "meso make_gltf_fixtures.py"},
        "extensionsUsed": ["KHR_lights_punctual"],
        "extensions": {"KHR_lights_punctual": {"lights": [{"type": "point", "color": [1, 1, 1], "intensity": 20}]}},
        "scene": 0,
        "scenes": [{"nodes": [0, 1, 2]}],
        "nodes": [
            {"name": "quad", "mesh": 0, "translation": [0, 0, -1]},
            {"name": "camera", "camera": 0, "translation": [0, 0, 5]},
            {"name": "light", "translation": [0, 3, 0], "extensions": {"KHR_lights_punctual": {"light": 0}}},
        ],
        "cameras": [{"type": "perspective", "perspective": {"yfov": 0.6, "aspectRatio": 1.5, "znear": 0.1}}],
        "materials": [{"name": "red plastic",
                       "pbrMetallicRoughness": {"baseColorFactor": [0.8, 0.1, 0.1, 1], "metallicFactor": 0.0,
                                                "roughnessFactor": 0.5}}],
        "meshes": [{"name": "quad", "primitives": [
            {"attributes": {"POSITION": pos, "NORMAL": nor, "TEXCOORD_0": uv}, "indices": idx, "material": 0}]}],
        "accessors": b.accessors,
        "bufferViews": b.views,
    }
    return g, bytes(b.data)


def mixed():
    b = Buf()
    # Triangle strip: 4 vertices in the z = 0 plane -> 2 triangles.
    spos = b.add("f", [0, 0, 0, 1, 0, 0, 0, 1, 0, 1, 1, 0], FLOAT, "VEC3", 4, minmax=([0, 0, 0], [1, 1, 0]))
    ppos = b.add("f", [5, 5, 5], FLOAT, "VEC3", 1, minmax=([5, 5, 5], [5, 5, 5]))
    tpos = b.add("f", [0, 0, 1, 1, 0, 1, 0, 1, 1], FLOAT, "VEC3", 3, minmax=([0, 0, 1], [1, 1, 1]))
    tuv = b.add("B", [0, 0, 255, 0, 0, 255], UBYTE, "VEC2", 3, normalized=True)
    tidx = b.add("B", [0, 1, 2], UBYTE, "SCALAR", 3)
    g = {
        "asset": {"version": "2.0", "generator": "meso make_gltf_fixtures.py"},
        "scenes": [{"nodes": [0]}],
        "nodes": [
            {"name": "mirrored", "mesh": 0, "scale": [-1, 1, 1], "children": [1]},
            {"name": "moved", "mesh": 0, "translation": [0, 3, 0]},
        ],
        "materials": [
            {"name": "grey", "pbrMetallicRoughness": {"baseColorFactor": [0.5, 0.5, 0.5, 1], "metallicFactor": 0,
                                                      "roughnessFactor": 1}},
            {"name": "lamp", "emissiveFactor": [1, 0.5, 0.25],
             "extensions": {"KHR_materials_emissive_strength": {"emissiveStrength": 4}},
             "pbrMetallicRoughness": {"baseColorFactor": [1, 1, 1, 1], "metallicFactor": 1,
                                      "roughnessFactor": 0.2}},
        ],
        "extensionsUsed": ["KHR_materials_emissive_strength"],
        "meshes": [{"name": "mixed", "primitives": [
            {"attributes": {"POSITION": spos}, "mode": 5, "material": 0},
            {"attributes": {"POSITION": ppos}, "mode": 0},
            {"attributes": {"POSITION": tpos, "TEXCOORD_0": tuv}, "indices": tidx, "material": 1},
        ]}],
        "accessors": b.accessors,
        "bufferViews": b.views,
    }
    return g, bytes(b.data)


def png(w, h, rows):
    """An 8-bit RGB PNG; rows: h lists of w (r, g, b), or of (r, g, b, a) for RGBA (not
    premultiplied, as PNG stores it)."""
    raw = b"".join(b"\0" + bytes(c for px in row for c in px) for row in rows)
    colour_type = 6 if len(rows[0][0]) == 4 else 2

    def chunk(tag, body):
        return struct.pack(">I", len(body)) + tag + body + struct.pack(">I", zlib.crc32(tag + body) & 0xFFFFFFFF)

    return (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 8, colour_type, 0, 0, 0)) +
            chunk(b"IDAT", zlib.compress(raw)) + chunk(b"IEND", b""))


CHECKER = png(2, 2, [[(255, 0, 0), (0, 255, 0)], [(0, 0, 255), (188, 188, 188)]])
MR = png(1, 1, [[(0, 255, 0)]])
# A constant tangent-space normal tilted towards +y (glTF: green = +y = the bitangent,
# towards decreasing v): (128, 220, 255) -> (0.004, 0.725, 1), normalised (0.003, 0.587, 0.810).
NORMAL_UP = png(1, 1, [[(128, 220, 255)]])
ALPHA_HALF = png(2, 1, [[(188, 188, 188, 255), (188, 188, 188, 0)]])


def textured(embed):
    g, data = quad()
    b = Buf()
    b.data = bytearray(data)
    b.views, b.accessors = g["bufferViews"], g["accessors"]
    del g["extensionsUsed"], g["extensions"]
    g["scenes"] = [{"nodes": [0, 1]}]
    g["nodes"] = [{"name": "quad", "mesh": 0}, {"name": "camera", "camera": 0, "translation": [0, 0, 10]}]
    g["cameras"] = [{"type": "perspective", "perspective": {"yfov": 0.2, "aspectRatio": 1.0, "znear": 0.1}}]
    g["materials"] = [{"name": "checker", "pbrMetallicRoughness": {
        "baseColorTexture": {"index": 0}, "metallicRoughnessTexture": {"index": 1}}}]
    g["samplers"] = [{"magFilter": 9728, "minFilter": 9728, "wrapS": 33071, "wrapT": 33071}]
    g["textures"] = [{"source": 0, "sampler": 0}, {"source": 1, "sampler": 0}]
    if embed:
        images = []
        for blob in (CHECKER, MR):
            while len(b.data) % 4:
                b.data.append(0)
            b.views.append({"buffer": 0, "byteOffset": len(b.data), "byteLength": len(blob)})
            b.data += blob
            images.append({"bufferView": len(b.views) - 1, "mimeType": "image/png"})
        g["images"] = images
    else:
        g["images"] = [{"uri": "checker.png"}, {"uri": "mr.png"}]
    return g, bytes(b.data)


def write_gltf(name, g, data):
    g = dict(g)
    g["buffers"] = [{"byteLength": len(data),
                     "uri": "data:application/octet-stream;base64," + base64.b64encode(data).decode()}]
    with open(os.path.join(HERE, name), "w") as f:
        json.dump(g, f, indent=1)
        f.write("\n")


def write_glb(name, g, data):
    g = dict(g)
    g["buffers"] = [{"byteLength": len(data)}]
    js = json.dumps(g).encode()
    js += b" " * (-len(js) % 4)
    data = data + b"\0" * (-len(data) % 4)
    chunks = struct.pack("<II", len(js), 0x4E4F534A) + js + struct.pack("<II", len(data), 0x004E4942) + data
    with open(os.path.join(HERE, name), "wb") as f:
        f.write(struct.pack("<III", 0x46546C67, 2, 12 + len(chunks)) + chunks)


if __name__ == "__main__":
    g, d = quad()
    write_gltf("quad.gltf", g, d)
    write_glb("quad.glb", g, d)
    g, d = mixed()
    write_gltf("mixed.gltf", g, d)
    for name, blob in (("checker.png", CHECKER), ("mr.png", MR), ("normal_up.png", NORMAL_UP),
                       ("alpha_half.png", ALPHA_HALF)):
        with open(os.path.join(HERE, name), "wb") as f:
            f.write(blob)
    g, d = textured(False)
    write_gltf("textured.gltf", g, d)
    g, d = textured(True)
    write_glb("textured.glb", g, d)
