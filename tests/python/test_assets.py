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

# A lower bound on the mean red of the lamp-lit image (16x12, 4 samples a pixel, the
# example's fixed seed: measured 0.041); the same scene without the lamp is exactly 0.
MIN_MEAN_RED = 0.01
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

    def test_uploaded_lamp_is_what_lights_the_scene(self) -> None:
        # The scene without its own lamp: the uploaded OBJ (a 1x1 emitter at z = 1.5
        # facing down, radiance 5) is its only light. Were the asset ignored, the image
        # would be black, every mean exactly 0; the floor below the lamp alone reflects
        # about 0.8/pi * 5 * 1/1.5^2 = 0.57 at its centre.
        self.write("meshes/lamp.obj", LAMP)
        spec = small_image_spec(spp=4, resolution=(16, 12))
        del spec["scene"]["shapes"][1]  # the example's own lamp quad
        spec["scene"]["shapes"].append({"type": "mesh", "obj": "meshes/lamp.obj", "material": "lamp"})
        sent = self.client.upload_scene_assets(spec, self.dir)
        job = self.client.submit(sent)
        self.assertEqual(self.client.wait(job, timeout=120)["state"], "succeeded")
        dark = dict(sent, scene=dict(sent["scene"], shapes=sent["scene"]["shapes"][:-1]))
        dark_job = self.client.submit(dark)
        self.assertEqual(self.client.wait(dark_job, timeout=120)["state"], "succeeded")

        def red(job_id: str) -> list:
            tiles = int(self.client.status(job_id)["plan"]["image"]["tiles"])
            return [v for n in range(tiles) for v in self.client.tile(job_id, n)["mean"][0::3]]

        self.assertEqual(max(red(dark_job)), 0.0)  # no light without the asset
        lit = red(job)
        print(f"lamp-lit image: mean R {sum(lit) / len(lit):.4f}, max R {max(lit):.4f}")
        self.assertGreater(sum(lit) / len(lit), MIN_MEAN_RED)


if __name__ == "__main__":
    unittest.main()
