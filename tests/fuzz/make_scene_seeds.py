#!/usr/bin/env python3
"""Writes the seed corpus of fuzz_scene_files (tests/fuzz/corpus/scene_files): one small
valid file of each kind and the shapes of issue 27's N1-N4 and N14, each at most 8 KB
(scripts/fuzz.sh runs with -max_len=8192). Input layout (fuzz_scene_files.cpp): byte 0
picks the reader (0 .gltf, 1 .glb, 2 OBJ, 3 texture, 4 environment map); then the file;
after a NUL, the bytes every other name reads. Run: python3 tests/fuzz/make_scene_seeds.py"""
import json
import os
import struct
import zlib

OUT = os.path.join(os.path.dirname(os.path.abspath(__file__)), "corpus", "scene_files")


def seed(name, reader, main, other=b""):
    data = bytes([reader]) + main + (b"\0" + other if other else b"")
    assert len(data) <= 8192, (name, len(data))
    with open(os.path.join(OUT, name), "wb") as f:
        f.write(data)


def gltf_doc(prims, bin_len, uri=True):
    buf = {"byteLength": bin_len}
    if uri:
        buf["uri"] = "s.bin"
    return {"asset": {"version": "2.0"}, "buffers": [buf], "bufferViews": [], "accessors": [],
            "meshes": [{"primitives": prims}], "nodes": [{"mesh": 0}], "scenes": [{"nodes": [0]}], "scene": 0}


def shared_accessor(nv, nprims):
    """N2: one-triangle primitives sharing one POSITION accessor of nv vertices."""
    pos = b"".join(struct.pack("<3f", i, 2 * i, 3 * i) for i in range(nv))
    bin_ = pos
    views = [{"buffer": 0, "byteOffset": 0, "byteLength": len(pos)}]
    accs = [{"bufferView": 0, "componentType": 5126, "count": nv, "type": "VEC3"}]
    prims = []
    for p in range(nprims):
        b = (3 * p * 7) % (nv - 3)
        idx = struct.pack("<3I", b + 2, b, b + 1)
        views.append({"buffer": 0, "byteOffset": len(bin_), "byteLength": 12})
        bin_ += idx
        accs.append({"bufferView": len(views) - 1, "componentType": 5125, "count": 3, "type": "SCALAR"})
        prims.append({"attributes": {"POSITION": 0}, "indices": len(accs) - 1})
    doc = gltf_doc(prims, len(bin_))
    doc["bufferViews"], doc["accessors"] = views, accs
    return doc, bin_


def glb(doc, bin_):
    js = json.dumps(doc, separators=(",", ":")).encode()
    js += b" " * (-len(js) % 4)
    bin_ += b"\0" * (-len(bin_) % 4)
    out = struct.pack("<III", 0x46546C67, 2, 12 + 8 + len(js) + 8 + len(bin_))
    return out + struct.pack("<II", len(js), 0x4E4F534A) + js + struct.pack("<II", len(bin_), 0x004E4942) + bin_


def png(w, h, rgba=True, ihdr_only=False):
    def chunk(t, d):
        return struct.pack(">I", len(d)) + t + d + struct.pack(">I", zlib.crc32(t + d) & 0xFFFFFFFF)
    out = b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 8, 6 if rgba else 2, 0, 0, 0))
    if ihdr_only:
        return out
    nc = 4 if rgba else 3
    raw = b"".join(b"\0" + bytes((x * 16 + y) % 256 for x in range(w * nc)) for y in range(h))
    return out + chunk(b"IDAT", zlib.compress(raw)) + chunk(b"IEND", b"")


def exr(w, h, channels, extra_attrs=b""):
    """Uncompressed scanline OpenEXR, half channels (sorted by name), every value 0.5."""
    def attr(name, type_, value):
        return name + b"\0" + type_ + b"\0" + struct.pack("<i", len(value)) + value
    chans = sorted(channels)
    chlist = b"".join(c.encode() + b"\0" + struct.pack("<iBBBBii", 1, 0, 0, 0, 0, 1, 1) for c in chans) + b"\0"
    box = struct.pack("<iiii", 0, 0, w - 1, h - 1)
    head = b"\x76\x2f\x31\x01" + struct.pack("<I", 2)
    head += attr(b"channels", b"chlist", chlist) + attr(b"compression", b"compression", b"\0")
    head += attr(b"dataWindow", b"box2i", box) + attr(b"displayWindow", b"box2i", box)
    head += attr(b"lineOrder", b"lineOrder", b"\0") + attr(b"pixelAspectRatio", b"float", struct.pack("<f", 1))
    head += attr(b"screenWindowCenter", b"v2f", struct.pack("<ff", 0, 0))
    head += attr(b"screenWindowWidth", b"float", struct.pack("<f", 1)) + extra_attrs + b"\0"
    line = struct.pack("<H", 0x3800) * (w * len(chans))  # half 0.5
    start = len(head) + 8 * h
    offsets = b"".join(struct.pack("<Q", start + y * (8 + len(line))) for y in range(h))
    blocks = b"".join(struct.pack("<ii", y, len(line)) + line for y in range(h))
    return head + offsets + blocks


def hdr(w, h):
    head = b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y %d +X %d\n" % (h, w)
    return head + bytes([128, 128, 128, 129]) * (w * h)


def main():
    os.makedirs(OUT, exist_ok=True)
    tri, tri_bin = shared_accessor(8, 1)
    seed("gltf_triangle", 0, json.dumps(tri).encode(), tri_bin)
    seed("glb_triangle", 1, glb(dict(tri, buffers=[{"byteLength": len(tri_bin)}]), tri_bin))
    # N1: deep nesting (the probe's 14,600 levels do not fit 8 KB; 3,000 are far over 64).
    seed("gltf_deep_extras", 0, b'{"asset":{"version":"2.0"},"extras":' + b"[" * 3000 + b"]" * 3000 + b"}")
    # N2: many empty nodes (over the fuzz target's 1,024), primitives sharing an accessor.
    seed("gltf_empty_nodes", 0, b'{"asset":{"version":"2.0"},"nodes":[' + b",".join([b"{}"] * 1100) + b"]}")
    shared, shared_bin = shared_accessor(200, 16)
    seed("glb_shared_accessor", 1, glb(dict(shared, buffers=[{"byteLength": len(shared_bin)}]), shared_bin))
    # OBJ: material groups, a long polygon (N4), non-finite numbers and huge indices (N14).
    verts = "".join("v %d %d 0\n" % (i, i % 5) for i in range(40))
    groups = "mtllib g.mtl\n" + verts + "".join("usemtl m%d\nf %d %d %d\n" % (g, 3 * g + 1, 3 * g + 2, 3 * g + 3) for g in range(8))
    mtl = "".join("newmtl m%d\nKd 0.5 0.5 0.5\nKs 0.1 0 0\nNs 10\n" % g for g in range(8))
    seed("obj_groups", 2, groups.encode(), mtl.encode())
    seed("obj_textured", 2, b"mtllib t.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nvt 1 0\nvt 0 1\nusemtl t\nf 1/1 2/2 3/3\n",
         b"newmtl t\nKd 1 1 1\nmap_Kd t.png\n")
    poly = "".join("v %d %d 0\n" % (i % 17, i // 17) for i in range(300)) + "f " + " ".join(str(i + 1) for i in range(300)) + "\n"
    seed("obj_long_polygon", 2, poly.encode())
    seed("obj_nan", 2, b"v nan 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    seed("obj_huge_index", 2, b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 99999999999999999999\n")
    # Images: valid small files, and the N3 headers.
    seed("png_rgba", 3, png(8, 4))
    seed("png_9000_header", 3, png(9000, 9000, ihdr_only=True))
    seed("exr_rgb", 4, exr(4, 2, ["R", "G", "B"]))
    seed("exr_64_channels", 4, exr(2, 1, ["c%02d" % i for i in range(64)]))
    big_string = b"comments\0string\0" + struct.pack("<i", 1760000000) + b"x"
    seed("exr_huge_attribute", 4, exr(2, 2, ["R", "G", "B"], big_string))
    seed("hdr_rgb", 4, hdr(4, 3))


if __name__ == "__main__":
    main()
