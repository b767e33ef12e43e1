"""Scene packing against a real tally-server (no --asset-dir: nothing shared but the API):
a .gltf + .bin + PNG texture and an OBJ + .mtl + map_Kd PNG, written here, submitted from
Python (Client.submit) and with `tally submit`, render with the texture's colour; a missing
or broken file is named by the user's path and its format, never by a hash."""

from __future__ import annotations

import json
import os
import shutil
import struct
import subprocess
import sys
import tempfile
import unittest
import zlib
from typing import Any, Dict, List, Tuple

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from tally_test_support import Server  # noqa: E402

from tally_client import Client, InvalidSpec, PackError  # noqa: E402

CLI_BIN = os.environ.get("TALLY_CLI_BIN", "")
W, H = 8, 6


def png_rgb(width: int, height: int, rgb: Tuple[int, int, int]) -> bytes:
    """A one-colour 8-bit RGB PNG (standard library: zlib + struct)."""
    raw = b"".join(b"\x00" + bytes(rgb) * width for _ in range(height))

    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF)

    return (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0))
            + chunk(b"IDAT", zlib.compress(raw)) + chunk(b"IEND", b""))


def quad_gltf(bin_uri: str, image_uri: str) -> Tuple[Dict[str, Any], bytes]:
    """A 2x2 quad at z = 0 facing +z whose emission is its texture (emissiveFactor 1,
    base colour black): the glTF document and its buffer."""
    pos = [-1, -1, 0, 1, -1, 0, 1, 1, 0, -1, 1, 0]
    nrm = [0, 0, 1] * 4
    uv = [0, 1, 1, 1, 1, 0, 0, 0]
    idx = [0, 1, 2, 0, 2, 3]
    buf = struct.pack("<12f", *pos) + struct.pack("<12f", *nrm) + struct.pack("<8f", *uv) + struct.pack("<6I", *idx)
    views = [{"buffer": 0, "byteOffset": 0, "byteLength": 48}, {"buffer": 0, "byteOffset": 48, "byteLength": 48},
             {"buffer": 0, "byteOffset": 96, "byteLength": 32}, {"buffer": 0, "byteOffset": 128, "byteLength": 24}]
    doc = {
        "asset": {"version": "2.0"}, "scene": 0, "scenes": [{"nodes": [0]}], "nodes": [{"mesh": 0}],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0, "NORMAL": 1, "TEXCOORD_0": 2}, "indices": 3,
                                    "material": 0}]}],
        "materials": [{"emissiveFactor": [1, 1, 1], "emissiveTexture": {"index": 0},
                       "pbrMetallicRoughness": {"baseColorFactor": [0, 0, 0, 1], "metallicFactor": 0}}],
        "textures": [{"source": 0}], "images": [{"uri": image_uri}],
        "buffers": [{"byteLength": len(buf), "uri": bin_uri}], "bufferViews": views,
        "accessors": [
            {"bufferView": 0, "componentType": 5126, "count": 4, "type": "VEC3", "min": [-1, -1, 0], "max": [1, 1, 0]},
            {"bufferView": 1, "componentType": 5126, "count": 4, "type": "VEC3"},
            {"bufferView": 2, "componentType": 5126, "count": 4, "type": "VEC2"},
            {"bufferView": 3, "componentType": 5125, "count": 6, "type": "SCALAR"}],
    }
    return doc, buf


def camera() -> Dict[str, Any]:
    return {"position": [0, 0, 3], "look_at": [0, 0, 0], "up": [0, 1, 0], "fov_deg": 40, "resolution": [W, H]}


def gltf_spec(file: str) -> Dict[str, Any]:
    return {"kind": "lighting", "seed": 3, "scene": {"camera": camera(), "shapes": [{"type": "gltf", "file": file}]},
            "query": {"type": "image", "max_depth": 1}, "stop": {"max_samples": 4}}


QUAD_OBJ = ("mtllib mats/quad.mtl\nv -1 -1 0\nv 1 -1 0\nv 1 1 0\nv -1 1 0\n"
            "vt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\nusemtl red\nf 1/1 2/2 3/3\nf 1/1 3/3 4/4\n")
QUAD_MTL = "newmtl red\nKd 1 1 1\nmap_Kd ../tex/red.png\n"


def obj_spec(file: str) -> Dict[str, Any]:
    # A white-lit diffuse quad whose albedo is its map_Kd texture.
    return {"kind": "lighting", "seed": 3,
            "scene": {"camera": camera(), "shapes": [{"type": "mesh", "obj": file}],
                      "lights": [{"type": "point", "position": [0, 0, 2], "intensity": [4, 4, 4]}]},
            "query": {"type": "image", "max_depth": 1}, "stop": {"max_samples": 4}}


class Packing(unittest.TestCase):
    def setUp(self) -> None:
        self.server = Server()
        self.client = Client(self.server.url, timeout=60)
        self.dir = tempfile.mkdtemp(prefix="tally_py_pack_")

    def tearDown(self) -> None:
        self.client.close()
        self.server.stop()
        shutil.rmtree(self.dir, ignore_errors=True)

    def write(self, name: str, data: bytes) -> str:
        path = os.path.join(self.dir, name)
        os.makedirs(os.path.dirname(path), exist_ok=True)
        with open(path, "wb") as f:
            f.write(data)
        return path

    def write_gltf_scene(self) -> None:
        doc, buf = quad_gltf("quad.bin", "tex/red%20tile.png")  # a percent-encoded name, as glTF URIs are
        self.write("scene/quad.gltf", json.dumps(doc).encode())
        self.write("scene/quad.bin", buf)
        self.write("scene/tex/red tile.png", png_rgb(4, 4, (255, 0, 0)))

    def write_obj_scene(self) -> None:
        self.write("scene/quad.obj", QUAD_OBJ.encode())
        self.write("scene/mats/quad.mtl", QUAD_MTL.encode())
        self.write("scene/tex/red.png", png_rgb(4, 4, (255, 0, 0)))

    def assert_red(self, job: str, centre_r: float = -1.0) -> None:
        """The image is lit only through the red texture: R > 0 at the centre (= centre_r
        when given), G and B exactly 0 everywhere (an untextured quad would be white)."""
        status = self.client.wait(job, timeout=120)
        self.assertEqual(status.state, "succeeded", status.get("error_message"))
        img = self.client.image(job, source="tiles")
        r, g, b = img.pixel(W // 2, H // 2)[0]
        self.assertGreater(r, 0.05)
        if centre_r >= 0:
            self.assertAlmostEqual(r, centre_r, places=5)
        self.assertEqual(max(img.mean_flat[1::3]), 0.0)
        self.assertEqual(max(img.mean_flat[2::3]), 0.0)

    def test_python_submit_packs_gltf_bin_and_texture(self) -> None:
        self.write_gltf_scene()
        spec = gltf_spec("scene/quad.gltf")
        with self.assertRaises(InvalidSpec):  # as it is, the server has no such file
            self.client.submit(spec, upload=False)
        job = self.client.submit(spec, base_dir=self.dir)
        self.assertEqual(spec["scene"]["shapes"][0]["file"], "scene/quad.gltf")  # the caller's spec is unchanged
        sent = self.client.status(job)["spec"]["scene"]["shapes"][0]["file"]
        self.assertTrue(sent.startswith("sha256:"), sent)
        # Emission = emissiveFactor 1 x the texel (sRGB 255 -> 1.0): exactly 1 at the centre.
        self.assert_red(job, centre_r=1.0)
        # The packed glTF names its buffer and image by hash.
        packed = self.client.upload_scene_assets(spec, self.dir)["scene"]["shapes"][0]["file"]
        self.assertEqual(packed, sent)

    def test_python_submit_packs_glb_with_external_image(self) -> None:
        doc, buf = quad_gltf("quad.bin", "red.png")
        del doc["buffers"][0]["uri"]  # the buffer is the GLB's BIN chunk; the image stays outside
        js = json.dumps(doc).encode()
        js += b" " * (-len(js) % 4)
        buf += b"\0" * (-len(buf) % 4)
        glb = struct.pack("<III", 0x46546C67, 2, 12 + 8 + len(js) + 8 + len(buf))
        glb += struct.pack("<II", len(js), 0x4E4F534A) + js + struct.pack("<II", len(buf), 0x004E4942) + buf
        self.write("scene/quad.glb", glb)
        self.write("scene/red.png", png_rgb(2, 2, (255, 0, 0)))
        self.assert_red(self.client.submit(gltf_spec("scene/quad.glb"), base_dir=self.dir), centre_r=1.0)

    def test_python_submit_packs_obj_mtl_and_map_kd(self) -> None:
        self.write_obj_scene()
        self.assert_red(self.client.submit(obj_spec("scene/quad.obj"), base_dir=self.dir))

    def test_missing_buffer_names_the_user_path_and_format(self) -> None:
        self.write_gltf_scene()
        os.remove(os.path.join(self.dir, "scene", "quad.bin"))
        with self.assertRaises(PackError) as cm:
            self.client.submit(gltf_spec("scene/quad.gltf"), base_dir=self.dir)
        msg = str(cm.exception)
        self.assertIn(os.path.join(self.dir, "scene", "quad.gltf") + " (glTF): buffers[0] names 'quad.bin'", msg)
        self.assertIn("No such file or directory", msg)
        self.assertNotIn("sha256:", msg)
        self.assertNotIn("OBJ", msg)

    def test_server_error_about_a_packed_file_names_the_user_path(self) -> None:
        self.write_gltf_scene()
        self.write("scene/tex/red tile.png", b"this is not a PNG")
        with self.assertRaises(InvalidSpec) as cm:
            self.client.submit(gltf_spec("scene/quad.gltf"), base_dir=self.dir)
        detail = cm.exception.detail
        self.assertIn(os.path.join(self.dir, "scene", "quad.gltf"), detail)
        self.assertNotIn("sha256:", detail)

    def run_cli(self, *args: str) -> subprocess.CompletedProcess[str]:
        return subprocess.run([CLI_BIN, *args, "--server", self.server.url], capture_output=True, text=True,
                              timeout=120, cwd=self.dir)

    @unittest.skipUnless(CLI_BIN, "TALLY_CLI_BIN is not set")
    def test_cli_submit_packs_gltf_bin_and_texture(self) -> None:
        self.write_gltf_scene()
        with open(os.path.join(self.dir, "job.json"), "w", encoding="utf-8") as f:
            json.dump(gltf_spec("scene/quad.gltf"), f)
        r = self.run_cli("submit", "job.json")
        self.assertEqual(r.returncode, 0, r.stderr)
        self.assertIn("3 uploaded, 0 already on the server", r.stderr)  # .gltf (rewritten), .bin, .png
        job = r.stdout.strip()
        self.assert_red(job, centre_r=1.0)
        # Again: everything is there already (HEAD only), and the same spec is sent.
        r2 = self.run_cli("submit", "--no-predict", "job.json")
        self.assertEqual(r2.returncode, 0, r2.stderr)
        self.assertIn("0 uploaded, 3 already on the server", r2.stderr)
        self.assertEqual(self.client.status(r2.stdout.strip())["spec"], self.client.status(job)["spec"])

    @unittest.skipUnless(CLI_BIN, "TALLY_CLI_BIN is not set")
    def test_cli_submit_packs_obj_mtl_and_map_kd(self) -> None:
        self.write_obj_scene()
        with open(os.path.join(self.dir, "scene", "job.json"), "w", encoding="utf-8") as f:
            json.dump(obj_spec("quad.obj"), f)
        r = self.run_cli("submit", "scene/job.json")  # names are relative to the spec's directory
        self.assertEqual(r.returncode, 0, r.stderr)
        self.assert_red(r.stdout.strip())

    @unittest.skipUnless(CLI_BIN, "TALLY_CLI_BIN is not set")
    def test_cli_errors_name_the_user_path_and_format(self) -> None:
        self.write_obj_scene()
        os.remove(os.path.join(self.dir, "scene", "tex", "red.png"))
        with open(os.path.join(self.dir, "job.json"), "w", encoding="utf-8") as f:
            json.dump(obj_spec("scene/quad.obj"), f)
        r = self.run_cli("submit", "job.json")
        self.assertEqual(r.returncode, 4, r.stderr)
        self.assertIn("scene/mats/quad.mtl (MTL): map_Kd names \"../tex/red.png\", which cannot be read", r.stderr)
        self.assertNotIn("sha256:", r.stderr)
        # A broken texture reaches the server: its 422 names the file, not its hash.
        self.write("scene/tex/red.png", b"not a PNG at all")
        r = self.run_cli("submit", "job.json")
        self.assertEqual(r.returncode, 4, r.stderr)
        self.assertIn("422", r.stderr)
        self.assertIn("scene/tex/red.png", r.stderr)
        self.assertNotIn("sha256:", r.stderr)


class PackerUnit(unittest.TestCase):
    """The packer without a server: what it stores and how it rewrites."""

    def test_rewrites_and_stores_each_file_once(self) -> None:
        d = tempfile.mkdtemp(prefix="tally_py_packer_")
        try:
            doc, buf = quad_gltf("quad.bin", "quad.bin")  # the same file twice: stored once
            with open(os.path.join(d, "a.gltf"), "w", encoding="utf-8") as f:
                json.dump(doc, f)
            with open(os.path.join(d, "quad.bin"), "wb") as f:
                f.write(buf)
            files: List[str] = []
            stored: Dict[str, bytes] = {}
            from tally_client import ScenePacker
            p = ScenePacker(lambda ref, path: files.append(path), lambda ref, data, origin: stored.update({ref: data}), d)
            out = p.pack_spec({"scene": {"shapes": [{"type": "gltf", "file": "a.gltf"}, {"type": "gltf", "file": "a.gltf"}]}})
            refs = [s["file"] for s in out["scene"]["shapes"]]
            self.assertEqual(refs[0], refs[1])
            self.assertEqual(files, [os.path.join(d, "quad.bin")])
            packed = json.loads(stored[refs[0]])
            import hashlib
            bin_ref = "sha256:" + hashlib.sha256(buf).hexdigest()
            self.assertEqual(packed["buffers"][0]["uri"], bin_ref)
            self.assertEqual(packed["images"][0]["uri"], bin_ref)
            self.assertEqual(p.with_user_paths(f"cannot read \"{refs[0]}\""), f"cannot read \"{os.path.join(d, 'a.gltf')}\"")
        finally:
            shutil.rmtree(d, ignore_errors=True)


if __name__ == "__main__":
    unittest.main()
