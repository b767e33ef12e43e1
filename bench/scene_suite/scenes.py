"""The scene suite's writers (Python standard library only; nothing is downloaded).

Each writer puts its files into a directory and returns a Scene: the tally scene (the
job spec's "scene" object, file names relative to that directory) and what the Cycles
side needs (the glTF file to import, or the JSON scene for the lecture scene, which is
built with bpy; the environment map, if any). docs/lighting.md, "Scene suite", describes
the scenes and the mapping to Cycles.

    python3 bench/scene_suite/scenes.py OUT_DIR   # writes every scene, prints the names
"""
from __future__ import annotations

import glob
import json
import math
import os
import shutil
import struct
import sys
import zlib
from dataclasses import dataclass, field
from typing import Any, Dict, List, Optional

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(os.path.dirname(HERE))
sys.path.insert(0, os.path.join(ROOT, "scripts"))
import gltf_example  # noqa: E402  (the repository's glTF writer: Writer, quad, uv_sphere, box)


@dataclass
class Scene:
    name: str
    what: str
    directory: str
    tally_scene: Dict[str, Any]              # the job spec's "scene"
    gltf: Optional[str] = None               # file Cycles imports (relative to directory)
    lecture_json: Optional[Dict[str, Any]] = None  # JSON scene Cycles builds with bpy
    env: Optional[Dict[str, Any]] = None     # {"file", "intensity", "rotation_deg"}
    notes: List[str] = field(default_factory=list)


# ---------------------------------------------------------------------------- helpers

def write_png(path: str, width: int, height: int, rgb_rows: List[bytes]) -> None:
    """8-bit RGB PNG, no interlace (zlib + struct only)."""
    raw = b"".join(b"\x00" + row for row in rgb_rows)

    def chunk(tag: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + tag + data + struct.pack(">I", zlib.crc32(tag + data) & 0xFFFFFFFF)

    png = b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0))
    png += chunk(b"IDAT", zlib.compress(raw, 9)) + chunk(b"IEND", b"")
    with open(path, "wb") as f:
        f.write(png)


class Writer(gltf_example.Writer):
    """gltf_example.Writer plus TEXCOORD_0 and base-colour textures."""

    def texture(self, uri: str) -> int:
        d = self.doc
        d.setdefault("images", []).append({"uri": uri})
        d.setdefault("samplers", []).append({"magFilter": 9729, "minFilter": 9729, "wrapS": 10497, "wrapT": 10497})
        d.setdefault("textures", []).append({"source": len(d["images"]) - 1, "sampler": len(d["samplers"]) - 1})
        return len(d["textures"]) - 1

    def textured_material(self, name: str, texture: int, metallic: float, roughness: float) -> int:
        m = self.material(name, [1.0, 1.0, 1.0], metallic, roughness)
        self.doc["materials"][m]["pbrMetallicRoughness"]["baseColorTexture"] = {"index": texture}
        return m

    def uv_mesh(self, name: str, positions, uvs, indices, material: int, node=None) -> None:
        attrs = {"POSITION": self._floats(positions, 3), "TEXCOORD_0": self._floats(uvs, 2)}
        prim = {"attributes": attrs, "indices": self._indices(indices), "material": material}
        self.doc["meshes"].append({"name": name, "primitives": [prim]})
        self.node(dict(node or {}, name=name, mesh=len(self.doc["meshes"]) - 1))

    def camera(self, name: str, position, look_at, yfov_deg: float) -> None:
        """A perspective camera at `position` looking at `look_at` with +y up."""
        f = [look_at[i] - position[i] for i in range(3)]
        n = math.sqrt(sum(x * x for x in f))
        f = [x / n for x in f]
        # Rotation taking -z to f with +y kept up: yaw about y, then pitch about x.
        yaw = math.atan2(-f[0], -f[2])
        pitch = math.asin(max(-1.0, min(1.0, f[1])))
        qy = [0.0, math.sin(yaw / 2), 0.0, math.cos(yaw / 2)]
        qx = [math.sin(pitch / 2), 0.0, 0.0, math.cos(pitch / 2)]
        # q = qy * qx (x, y, z, w)
        x1, y1, z1, w1 = qy
        x2, y2, z2, w2 = qx
        q = [w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2, w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
             w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2, w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2]
        self.doc["cameras"].append({"name": name, "type": "perspective",
                                    "perspective": {"yfov": math.radians(yfov_deg), "znear": 0.05, "aspectRatio": 4 / 3}})
        self.node({"name": "camera", "camera": len(self.doc["cameras"]) - 1, "translation": list(position), "rotation": q})


def quad_uv(corner, eu, ev, repeat=1.0):
    p, i = gltf_example.quad(corner, eu, ev)
    return p, [0, 0, repeat, 0, repeat, repeat, 0, repeat], i


def quads(items):
    """Many quads (corner, eu, ev) as one triangle list."""
    pos, idx = [], []
    for c, eu, ev in items:
        p, i = gltf_example.quad(c, eu, ev)
        base = len(pos) // 3
        pos += p
        idx += [base + k for k in i]
    return pos, idx


def lambert_variant(doc: Dict[str, Any]) -> Dict[str, Any]:
    """The model check: every non-emissive dielectric (metallicFactor 0) gets
    KHR_materials_specular specularFactor 0, a pure Lambertian surface in tally (docs/lighting.md,
    Glossy materials); the Cycles side makes those a Diffuse BSDF. Metals are unchanged."""
    doc = json.loads(json.dumps(doc))
    for m in doc["materials"]:
        if m["pbrMetallicRoughness"].get("metallicFactor", 1.0) == 0.0 and "emissiveFactor" not in m:
            m.setdefault("extensions", {})["KHR_materials_specular"] = {"specularFactor": 0.0}
    doc["extensionsUsed"] = sorted(set(doc.get("extensionsUsed", [])) | {"KHR_materials_specular"})
    return doc


def emitters_variant(doc: Dict[str, Any]) -> Optional[Dict[str, Any]]:
    """The emitter mask's scene: every non-emissive material black (base colour 0, no
    texture, KHR_materials_specular specularFactor 0: a pure Lambertian surface of albedo
    0), emitters unchanged. At depth 1 its image is the emission the camera sees directly
    and nothing else, so its non-zero pixels are those that see an emitter. None when the
    scene has no emissive material."""
    doc = json.loads(json.dumps(doc))
    if not any("emissiveFactor" in m for m in doc["materials"]):
        return None
    for m in doc["materials"]:
        if "emissiveFactor" in m:
            continue
        m["pbrMetallicRoughness"] = {"baseColorFactor": [0.0, 0.0, 0.0, 1.0], "metallicFactor": 0.0,
                                     "roughnessFactor": 1.0}
        m.setdefault("extensions", {})["KHR_materials_specular"] = {"specularFactor": 0.0}
    doc["extensionsUsed"] = sorted(set(doc.get("extensionsUsed", [])) | {"KHR_materials_specular"})
    return doc


def gltf_scene(name: str, what: str, directory: str, w: Writer, resolution, **kw) -> Scene:
    os.makedirs(directory, exist_ok=True)
    w.save(directory, name)
    with open(os.path.join(directory, name + ".gltf")) as f:
        doc = json.load(f)
    with open(os.path.join(directory, name + "_lambert.gltf"), "w") as f:
        json.dump(lambert_variant(doc), f, indent=1)
    em = emitters_variant(doc)
    if em is not None:
        with open(os.path.join(directory, name + "_emitters.gltf"), "w") as f:
            json.dump(em, f, indent=1)
    shape = {"type": "gltf", "file": name + ".gltf", "camera": "view", "resolution": list(resolution)}
    return Scene(name, what, directory, {"shapes": [shape]}, gltf=name + ".gltf", **kw)


def variant(scene: Scene, suffix: str, what: str, **kw) -> Optional[Scene]:
    """The scene with its glTF file swapped for NAME_SUFFIX.gltf (written by gltf_scene),
    or None for a scene without a glTF file or without that variant."""
    if not scene.gltf:
        return None
    gl = scene.gltf.replace(".gltf", "_%s.gltf" % suffix)
    if not os.path.exists(os.path.join(scene.directory, gl)):
        return None
    t = json.loads(json.dumps(scene.tally_scene))
    t["shapes"][0]["file"] = gl
    return Scene("%s_%s" % (scene.name, suffix), "%s (%s)" % (scene.what, what), scene.directory, t, gltf=gl, **kw)


def emitters(scene: Scene) -> Optional[Scene]:
    """The scene's emitter-mask variant, or None (no emissive material, or not a glTF scene)."""
    return variant(scene, "emitters", "emitters only")


def lambert(scene: Scene) -> Optional[Scene]:
    """The scene's Lambert variant, or None (the lecture scene is Lambert already)."""
    return variant(scene, "lambert", "dielectrics Lambert", env=scene.env, notes=list(scene.notes))


# ---------------------------------------------------------------------------- the scenes

def lecture(directory: str, resolution) -> Scene:
    """The lecture scene: area light, grey occluder, white receiver (Lambert only)."""
    with open(os.path.join(ROOT, "bench", "study", "scenes", "lecture_scene.json")) as f:
        scene = json.load(f)
    scene["camera"]["resolution"] = list(resolution)
    os.makedirs(directory, exist_ok=True)
    return Scene("lecture", "lecture scene: 1x1 area light, grey occluder, white floor (Lambert)",
                 directory, scene, lecture_json=scene)


def cornell(directory: str, resolution) -> Scene:
    """scripts/gltf_example.py's box with a checker-textured floor and without the spot."""
    os.makedirs(directory, exist_ok=True)
    n, cells = 64, 8
    rows = []
    for y in range(n):
        row = bytearray()
        for x in range(n):
            dark = ((x * cells // n) + (y * cells // n)) % 2
            row += bytes((60, 70, 90) if dark else (200, 190, 170))
        rows.append(bytes(row))
    write_png(os.path.join(directory, "checker.png"), n, n, rows)
    w = Writer()
    white = w.material("white", [0.73, 0.73, 0.73], 0.0, 1.0)
    red = w.material("red", [0.65, 0.05, 0.05], 0.0, 1.0)
    green = w.material("green", [0.12, 0.45, 0.15], 0.0, 1.0)
    floor = w.textured_material("checker floor", w.texture("checker.png"), 0.0, 0.6)
    gold = w.material("rough gold", [1.0, 0.78, 0.34], 1.0, 0.35)
    glossy = w.material("glossy white", [0.8, 0.8, 0.8], 0.0, 0.2)
    lamp = w.material("lamp", [0.0, 0.0, 0.0], 0.0, 1.0, emissive=[1.0, 0.85, 0.7], strength=12.0)
    p, uv, i = quad_uv([-1, 0, -1], [0, 0, 2], [2, 0, 0])
    w.uv_mesh("floor", p, uv, i, floor)
    for name, (c, eu, ev), mat in [
        ("ceiling", ([-1, 2, -1], [2, 0, 0], [0, 0, 2]), white),
        ("back", ([-1, 0, -1], [2, 0, 0], [0, 2, 0]), white),
        ("left", ([-1, 0, -1], [0, 2, 0], [0, 0, 2]), red),
        ("right", ([1, 0, -1], [0, 0, 2], [0, 2, 0]), green),
    ]:
        p, i = gltf_example.quad(c, eu, ev)
        w.mesh(name, p, i, mat)
    p, i = gltf_example.quad([-0.3, 1.99, -0.3], [0.6, 0, 0], [0, 0, 0.6])
    w.mesh("lamp", p, i, lamp)
    p, nrm, i = gltf_example.uv_sphere(0.4)
    w.mesh("gold sphere", p, i, gold, normals=nrm, node={"translation": [0.35, 0.4, 0.2]})
    p, i = gltf_example.box(0.5, 1.1, 0.5)
    w.mesh("block", p, i, glossy, node={"translation": [-0.75, 0.0, -0.6],
                                        "rotation": [0.0, math.sin(0.3), 0.0, math.cos(0.3)]})
    w.camera("view", [0.0, 1.0, 3.7], [0.0, 1.0, 0.0], 40.0)
    return gltf_scene("cornell", "glTF Cornell box: rough gold sphere (metal, r 0.35), checker-textured floor "
                      "(dielectric, r 0.6), glossy white block (r 0.2), emissive panel (strength 12)",
                      directory, w, resolution,
                      notes=["scripts/gltf_example.py's spot light is left out (Cycles' spot blend is not glTF's falloff)"])


def find_world_map(name: str = "courtyard.exr") -> Optional[str]:
    """Blender's CC0 world maps (Debian: /usr/share/blender/[VERSION/]datafiles/studiolights/world)."""
    pats = ["/usr/share/blender/datafiles/studiolights/world/" + name,
            "/usr/share/blender/*/datafiles/studiolights/world/" + name,
            "/usr/lib/blender/*/datafiles/studiolights/world/" + name]
    for p in pats:
        hits = sorted(glob.glob(p))
        if hits:
            return hits[0]
    return None


def envlight(directory: str, resolution) -> Optional[Scene]:
    """Blender's courtyard.exr around a rough silver sphere, a glossy red plastic sphere,
    a diffuse box and a grey ground disk."""
    src = find_world_map()
    if src is None:
        return None
    os.makedirs(directory, exist_ok=True)
    shutil.copyfile(src, os.path.join(directory, "world.exr"))  # tally reads scene files inside its asset dir
    w = Writer()
    ground = w.material("ground", [0.5, 0.5, 0.5], 0.0, 1.0)
    silver = w.material("rough silver", [0.95, 0.93, 0.88], 1.0, 0.3)
    plastic = w.material("red plastic", [0.7, 0.08, 0.05], 0.0, 0.15)
    clay = w.material("clay", [0.75, 0.6, 0.45], 0.0, 1.0)
    p, i = gltf_example.quad([-4, 0, -4], [0, 0, 8], [8, 0, 0])
    w.mesh("ground", p, i, ground)
    p, nrm, i = gltf_example.uv_sphere(0.5)
    w.mesh("silver sphere", p, i, silver, normals=nrm, node={"translation": [-0.6, 0.5, 0.0]})
    p, nrm, i = gltf_example.uv_sphere(0.35)
    w.mesh("plastic sphere", p, i, plastic, normals=nrm, node={"translation": [0.55, 0.35, 0.35]})
    p, i = gltf_example.box(0.5, 0.5, 0.5)
    w.mesh("box", p, i, clay, node={"translation": [0.3, 0.0, -0.9],
                                    "rotation": [0.0, math.sin(0.4), 0.0, math.cos(0.4)]})
    w.camera("view", [0.0, 1.3, 3.4], [0.0, 0.35, 0.0], 40.0)
    s = gltf_scene("envlight", "environment light (Blender's CC0 courtyard.exr, 1024x512): rough silver sphere "
                   "(r 0.3), red plastic sphere (r 0.15), diffuse box and ground", directory, w, resolution,
                   env={"file": "world.exr", "intensity": 1.0, "rotation_deg": 0.0, "source": src})
    s.tally_scene["lights"] = [{"type": "sky", "map": "world.exr", "intensity": 1.0, "rotation_deg": 0.0}]
    return s


def lcg(seed: int):
    state = seed & 0xFFFFFFFF
    while True:
        state = (1664525 * state + 1013904223) & 0xFFFFFFFF
        yield state / 2**32


def many_lights(directory: str, resolution, count: int = 1200) -> Scene:
    """A 12 x 3 x 12 room (diffuse walls, eight box pillars) with `count` emissive squares
    of side 0.06 (radiance 15-60, four colours) at pseudo-random points of the upper half,
    facing down; most are far from any one shading point."""
    w = Writer()
    wall = w.material("wall", [0.7, 0.7, 0.7], 0.0, 1.0)
    floor = w.material("floor", [0.45, 0.4, 0.35], 0.0, 1.0)
    pillar = w.material("pillar", [0.6, 0.62, 0.7], 0.0, 1.0)
    X, Y, Z = 6.0, 3.0, 6.0
    for name, (c, eu, ev), mat in [
        ("floor", ([-X, 0, -Z], [0, 0, 2 * Z], [2 * X, 0, 0]), floor),
        ("ceiling", ([-X, Y, -Z], [2 * X, 0, 0], [0, 0, 2 * Z]), wall),
        ("back", ([-X, 0, -Z], [2 * X, 0, 0], [0, Y, 0]), wall),
        ("front", ([-X, 0, Z], [0, Y, 0], [2 * X, 0, 0]), wall),
        ("left", ([-X, 0, -Z], [0, Y, 0], [0, 0, 2 * Z]), wall),
        ("right", ([X, 0, -Z], [0, 0, 2 * Z], [0, Y, 0]), wall),
    ]:
        p, i = gltf_example.quad(c, eu, ev)
        w.mesh(name, p, i, mat)
    for k, (px, pz) in enumerate([(-3, -3), (0, -3), (3, -3), (-3, 0), (3, 0), (-3, 3), (0, 3), (3, 3)]):
        p, i = gltf_example.box(0.4, Y, 0.4)
        w.mesh("pillar %d" % k, p, i, pillar, node={"translation": [px - 0.2, 0.0, pz - 0.2]})
    colours = [([1.0, 0.9, 0.7], 40.0), ([0.7, 0.85, 1.0], 30.0), ([1.0, 0.6, 0.3], 60.0), ([0.9, 1.0, 0.8], 15.0)]
    mats = [w.material("lamp %d" % k, [0.0, 0.0, 0.0], 0.0, 1.0, emissive=c, strength=s) for k, (c, s) in enumerate(colours)]
    groups: List[list] = [[] for _ in colours]
    r = lcg(29)
    side = 0.06
    for k in range(count):
        x = -X + 0.2 + (2 * X - 0.4) * next(r)
        z = -Z + 0.2 + (2 * Z - 0.4) * next(r)
        y = Y / 2 + (Y / 2 - 0.1) * next(r)
        # Facing down (normal -y): eu x ev = -y with eu along +x, ev along +z.
        groups[k % len(colours)].append(([x, y, z], [side, 0, 0], [0, 0, side]))
    for k, g in enumerate(groups):
        p, i = quads(g)
        w.mesh("lamps %d" % k, p, i, mats[k])
    w.camera("view", [-5.2, 1.6, 5.2], [1.0, 1.0, -2.0], 60.0)
    return gltf_scene("many_lights", "many lights: %d emissive squares (side %.2f, 4 colours, strength 15-60) in a "
                      "12x3x12 room with 8 pillars (%d emitter triangles)" % (count, side, 2 * count),
                      directory, w, resolution)


def glossy(directory: str, resolution) -> Scene:
    """Metals facing each other: a polished silver wall and a rough copper wall face each
    other across a floor, with a gold sphere between them, lit by a ceiling panel."""
    w = Writer()
    floor = w.material("floor", [0.6, 0.6, 0.6], 0.0, 1.0)
    back = w.material("back", [0.5, 0.55, 0.6], 0.0, 1.0)
    silver = w.material("polished silver", [0.97, 0.96, 0.91], 1.0, 0.08)
    copper = w.material("rough copper", [0.95, 0.64, 0.54], 1.0, 0.25)
    gold = w.material("gold", [1.0, 0.78, 0.34], 1.0, 0.15)
    lamp = w.material("lamp", [0.0, 0.0, 0.0], 0.0, 1.0, emissive=[1.0, 0.95, 0.9], strength=10.0)
    p, i = gltf_example.quad([-1.5, 0, -2], [0, 0, 4], [3, 0, 0])
    w.mesh("floor", p, i, floor)
    p, i = gltf_example.quad([-1.5, 0, -2], [3, 0, 0], [0, 2.5, 0])
    w.mesh("back", p, i, back)
    # Left wall at x = -1 facing +x, right wall at x = +1 facing -x.
    p, i = gltf_example.quad([-1.0, 0, -2], [0, 2.0, 0], [0, 0, 3.5])
    w.mesh("silver wall", p, i, silver)
    p, i = gltf_example.quad([1.0, 0, -2], [0, 0, 3.5], [0, 2.0, 0])
    w.mesh("copper wall", p, i, copper)
    p, nrm, i = gltf_example.uv_sphere(0.35)
    w.mesh("gold sphere", p, i, gold, normals=nrm, node={"translation": [0.1, 0.35, -0.4]})
    p, i = gltf_example.quad([-0.4, 2.3, -1.2], [0.8, 0, 0], [0, 0, 0.8])
    w.mesh("lamp", p, i, lamp)
    w.camera("view", [0.0, 1.2, 3.2], [0.0, 0.7, -0.8], 45.0)
    return gltf_scene("glossy", "glossy interreflection: polished silver wall (r 0.08) facing a rough copper wall "
                      "(r 0.25), gold sphere (r 0.15) between them, diffuse floor and back, ceiling panel",
                      directory, w, resolution)


WRITERS = {"lecture": lecture, "cornell": cornell, "envlight": envlight, "many_lights": many_lights, "glossy": glossy}


def write_all(out: str, resolution, names=None) -> List[Scene]:
    scenes = []
    for name, fn in WRITERS.items():
        if names and name not in names:
            continue
        s = fn(os.path.join(out, name), resolution)
        if s is not None:
            scenes.append(s)
    return scenes


if __name__ == "__main__":
    if len(sys.argv) != 2:
        sys.exit("usage: scenes.py OUT_DIR")
    for s in write_all(sys.argv[1], (96, 72)):
        print(s.name, s.directory)
