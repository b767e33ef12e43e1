"""tally_client's assets: upload_asset (streamed PUT, HEAD first) and upload_scene_assets."""

from __future__ import annotations

import hashlib
import os
import sys
import tempfile
import unittest

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from tally_test_support import Server, small_image_spec  # noqa: E402

from tally_client import Client, InvalidSpec  # noqa: E402

LAMP = "v -0.5 -0.5 1.5\nv -0.5 0.5 1.5\nv 0.5 0.5 1.5\nv 0.5 -0.5 1.5\nf 1 2 3\nf 1 3 4\n"


class Assets(unittest.TestCase):
    def setUp(self) -> None:
        self.server = Server()
        self.client = Client(self.server.url, timeout=30)
        self.dir = tempfile.mkdtemp(prefix="tally_py_assets_")

    def tearDown(self) -> None:
        self.server.stop()

    def write(self, name: str, text: str) -> str:
        path = os.path.join(self.dir, name)
        os.makedirs(os.path.dirname(path), exist_ok=True)
        with open(path, "w", encoding="utf-8") as f:
            f.write(text)
        return path

    def test_upload_once_then_head_only(self) -> None:
        path = self.write("lamp.obj", LAMP)
        ref = "sha256:" + hashlib.sha256(LAMP.encode()).hexdigest()
        self.assertFalse(self.client.has_asset(ref))
        self.assertEqual(self.client.upload_asset(path), ref)
        self.assertTrue(self.client.has_asset(ref))
        self.assertEqual(self.client.upload_asset(path), ref)  # HEAD says it is there: not sent again
        self.assertEqual(self.server.log().count(f"asset {ref} stored"), 1)
        self.assertEqual(self.server.log().count(f"asset {ref} already stored"), 0)

    def test_scene_assets_are_uploaded_and_named_by_hash(self) -> None:
        self.write("meshes/lamp.obj", LAMP)
        spec = small_image_spec(spp=2, resolution=(8, 6))
        spec["scene"]["shapes"].append({"type": "mesh", "obj": "meshes/lamp.obj", "material": "lamp"})
        with self.assertRaises(InvalidSpec):  # the server has no --asset-dir: a path is refused
            self.client.submit(spec)
        sent = self.client.upload_scene_assets(spec, self.dir)
        self.assertEqual(sent["scene"]["shapes"][-1]["obj"], "sha256:" + hashlib.sha256(LAMP.encode()).hexdigest())
        self.assertEqual(spec["scene"]["shapes"][-1]["obj"], "meshes/lamp.obj")  # the original is unchanged
        status = self.client.wait(self.client.submit(sent), timeout=120)
        self.assertEqual(status["state"], "succeeded")


if __name__ == "__main__":
    unittest.main()
