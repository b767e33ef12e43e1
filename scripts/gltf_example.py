#!/usr/bin/env python3
"""Writes the glTF example scene (Python standard library only): a Cornell-like box
with a rough gold sphere (a UV sphere with vertex normals), a glossy white block, an
emissive ceiling panel (KHR_materials_emissive_strength) and a spot light
(KHR_lights_punctual), as <dir>/cornell.gltf + <dir>/cornell.bin.

    python3 scripts/gltf_example.py out/demo/assets
    tally-server --asset-dir out/demo/assets   # then submit examples/gltf_cornell.json

`make demo` does this (scripts/demo.sh). The mapping from glTF to tally's materials and
lights is in docs/lighting.md, "glTF scenes".
"""
import json
import math
import os
import struct
import sys


class Writer:
    def __init__(self):
        self.bin = bytearray()
        self.doc = {
            "asset": {"version": "2.0", "generator": "tally scripts/gltf_example.py"},
            "extensionsUsed": ["KHR_lights_punctual", "KHR_materials_emissive_strength"],
            "scene": 0, "scenes": [{"nodes": []}], "nodes": [], "meshes": [], "materials": [],
            "accessors": [], "bufferViews": [], "buffers": [], "cameras": [],
            "extensions": {"KHR_lights_punctual": {"lights": []}},
        }

    def _view(self, data):
        while len(self.bin) % 4:
            self.bin.append(0)
        self.doc["bufferViews"].append({"buffer": 0, "byteOffset": len(self.bin), "byteLength": len(data)})
        self.bin += data
        return len(self.doc["bufferViews"]) - 1

    def _floats(self, values, ncomp):
        view = self._view(struct.pack("<%df" % len(values), *values))
        acc = {"bufferView": view, "componentType": 5126, "count": len(values) // ncomp,
               "type": {2: "VEC2", 3: "VEC3"}[ncomp]}
        if ncomp == 3:  # POSITION needs min/max
            acc["min"] = [min(values[i::3]) for i in range(3)]
            acc["max"] = [max(values[i::3]) for i in range(3)]
        self.doc["accessors"].append(acc)
        return len(self.doc["accessors"]) - 1

    def _indices(self, values):
        view = self._view(struct.pack("<%dI" % len(values), *values))
        self.doc["accessors"].append({"bufferView": view, "componentType": 5125, "count": len(values), "type": "SCALAR"})
        return len(self.doc["accessors"]) - 1

    def material(self, name, base, metallic, roughness, emissive=None, strength=1.0):
        m = {"name": name, "pbrMetallicRoughness": {"baseColorFactor": list(base) + [1.0],
                                                    "metallicFactor": metallic, "roughnessFactor": roughness}}
        if emissive:
            m["emissiveFactor"] = list(emissive)
            m["extensions"] = {"KHR_materials_emissive_strength": {"emissiveStrength": strength}}
        self.doc["materials"].append(m)
        return len(self.doc["materials"]) - 1

    def mesh(self, name, positions, indices, material, normals=None, node=None):
        attrs = {"POSITION": self._floats(positions, 3)}
        if normals:
            attrs["NORMAL"] = self._floats(normals, 3)
        prim = {"attributes": attrs, "indices": self._indices(indices), "material": material}
        self.doc["meshes"].append({"name": name, "primitives": [prim]})
        self.node(dict(node or {}, name=name, mesh=len(self.doc["meshes"]) - 1))

    def node(self, n):
        self.doc["nodes"].append(n)
        self.doc["scenes"][0]["nodes"].append(len(self.doc["nodes"]) - 1)

    def light(self, name, light, node):
        lights = self.doc["extensions"]["KHR_lights_punctual"]["lights"]
        lights.append(dict(light, name=name))
        self.node(dict(node, name=name, extensions={"KHR_lights_punctual": {"light": len(lights) - 1}}))

    def save(self, directory, name):
        os.makedirs(directory, exist_ok=True)
        self.doc["buffers"] = [{"byteLength": len(self.bin), "uri": name + ".bin"}]
        with open(os.path.join(directory, name + ".bin"), "wb") as f:
            f.write(self.bin)
        with open(os.path.join(directory, name + ".gltf"), "w") as f:
            json.dump(self.doc, f, indent=1)


def quad(corner, eu, ev):
    """Two triangles; the front (emitting) side is along eu x ev."""
    c = corner
    pts = [c, [c[i] + eu[i] for i in range(3)], [c[i] + eu[i] + ev[i] for i in range(3)], [c[i] + ev[i] for i in range(3)]]
    return [x for p in pts for x in p], [0, 1, 2, 0, 2, 3]


def uv_sphere(radius, stacks=24, slices=48):
    pos, nrm, idx = [], [], []
    for i in range(stacks + 1):
        theta = math.pi * i / stacks
        for j in range(slices + 1):
            phi = 2 * math.pi * j / slices
            n = [math.sin(theta) * math.cos(phi), math.cos(theta), math.sin(theta) * math.sin(phi)]
            nrm += n
            pos += [radius * x for x in n]
    for i in range(stacks):
        for j in range(slices):
            a, b = i * (slices + 1) + j, (i + 1) * (slices + 1) + j
            if i > 0:
                idx += [a, a + 1, b]  # outward (counter-clockwise seen from outside)
            if i < stacks - 1:
                idx += [a + 1, b + 1, b]
    return pos, nrm, idx


def box(sx, sy, sz):
    """An axis-aligned box [0, s] with outward faces (flat: no vertex normals)."""
    pos, idx = [], []
    faces = [([0, 0, 0], [0, sy, 0], [sx, 0, 0]), ([0, 0, sz], [sx, 0, 0], [0, sy, 0]),
             ([0, 0, 0], [0, 0, sz], [0, sy, 0]), ([sx, 0, 0], [0, sy, 0], [0, 0, sz]),
             ([0, 0, 0], [sx, 0, 0], [0, 0, sz]), ([0, sy, 0], [0, 0, sz], [sx, 0, 0])]
    for c, eu, ev in faces:
        p, i = quad(c, eu, ev)
        base = len(pos) // 3
        pos += p
        idx += [base + k for k in i]
    return pos, idx


def build():
    w = Writer()
    white = w.material("white", [0.73, 0.73, 0.73], 0.0, 1.0)
    red = w.material("red", [0.65, 0.05, 0.05], 0.0, 1.0)
    green = w.material("green", [0.12, 0.45, 0.15], 0.0, 1.0)
    gold = w.material("rough gold", [1.0, 0.78, 0.34], 1.0, 0.35)
    glossy = w.material("glossy white", [0.8, 0.8, 0.8], 0.0, 0.2)
    lamp = w.material("lamp", [0.0, 0.0, 0.0], 0.0, 1.0, emissive=[1.0, 0.85, 0.7], strength=12.0)
    # The box: x in [-1, 1], y in [0, 2], z in [-1, 1]; open towards +z (the camera).
    for name, (c, eu, ev), mat in [
        ("floor", ([-1, 0, -1], [0, 0, 2], [2, 0, 0]), white),
        ("ceiling", ([-1, 2, -1], [2, 0, 0], [0, 0, 2]), white),
        ("back", ([-1, 0, -1], [2, 0, 0], [0, 2, 0]), white),
        ("left", ([-1, 0, -1], [0, 2, 0], [0, 0, 2]), red),
        ("right", ([1, 0, -1], [0, 0, 2], [0, 2, 0]), green),
    ]:
        p, i = quad(c, eu, ev)
        w.mesh(name, p, i, mat)
    p, i = quad([-0.3, 1.99, -0.3], [0.6, 0, 0], [0, 0, 0.6])  # facing down
    w.mesh("lamp", p, i, lamp)
    p, n, i = uv_sphere(0.4)
    w.mesh("gold sphere", p, i, gold, normals=n, node={"translation": [0.35, 0.4, 0.2]})
    p, i = box(0.5, 1.1, 0.5)
    w.mesh("block", p, i, glossy, node={"translation": [-0.75, 0.0, -0.6],
                                        "rotation": [0.0, math.sin(0.3), 0.0, math.cos(0.3)]})
    # A spot from the upper front, aimed at the sphere: rotate local -z down by 30 degrees.
    a = -math.radians(30) / 2
    w.light("spot", {"type": "spot", "color": [1.0, 0.95, 0.9], "intensity": 3.0,
                     "spot": {"innerConeAngle": math.radians(6), "outerConeAngle": math.radians(14)}},
            {"translation": [0.35, 1.6, 2.3], "rotation": [math.sin(a), 0.0, 0.0, math.cos(a)]})
    w.doc["cameras"].append({"name": "front", "type": "perspective",
                             "perspective": {"yfov": math.radians(40), "znear": 0.05, "aspectRatio": 4 / 3}})
    w.node({"name": "camera", "camera": 0, "translation": [0.0, 1.0, 3.7]})
    return w


if __name__ == "__main__":
    if len(sys.argv) != 2:
        sys.exit("usage: gltf_example.py <output directory>")
    build().save(sys.argv[1], "cornell")
    print("wrote %s" % os.path.join(sys.argv[1], "cornell.gltf"))
