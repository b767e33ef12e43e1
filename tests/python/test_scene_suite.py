"""The scene suite's writers (bench/scene_suite/scenes.py) produce scenes tally accepts:
each suite scene, and its Lambert variant, renders at 8x6, 8 spp, depth 4 with `tally run`
(in-process, no server) to a finite, positive image; the glTF scenes bring their camera,
the many-light scene turns the light tree on; a scene with emitters has an emitters-only
variant (the suite's emitter mask) that renders darker than the scene itself. The environment-lit scene needs one of
Blender's world maps (skipped without it, and without OpenImageIO's Python bindings, which
clean its negative texels). A few seconds in all."""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
import tempfile
import unittest

HERE = os.path.dirname(os.path.abspath(__file__))
SOURCE_DIR = os.environ.get("TALLY_SOURCE_DIR") or os.path.dirname(os.path.dirname(HERE))
sys.path.insert(0, os.path.join(SOURCE_DIR, "bench", "scene_suite"))
import scenes  # noqa: E402

CLI_BIN = os.environ.get("TALLY_CLI_BIN", "")


def oiio_available() -> bool:
    try:
        import numpy  # noqa: F401
        import OpenImageIO  # noqa: F401
        return True
    except ImportError:
        return False


@unittest.skipUnless(CLI_BIN and os.access(CLI_BIN, os.X_OK), "TALLY_CLI_BIN (the tally CLI) is not built")
class SceneSuiteScenes(unittest.TestCase):
    def render(self, scene: scenes.Scene, image: bool = False, depth: int = 4) -> dict:
        spec = {"kind": "lighting", "seed": 1, "scene": scene.tally_scene,
                "query": {"type": "image", "max_depth": depth, "russian_roulette": depth > 1},
                "estimators": ["mis"], "stop": {"max_samples": 8}}
        path = os.path.join(scene.directory, "test_job.json")
        with open(path, "w") as f:
            json.dump(spec, f)
        cmd = [CLI_BIN, "run", path, "--json", "--threads", "1"]
        out = os.path.join(scene.directory, "test.exr")
        if image:
            cmd += ["--image", out]
        r = subprocess.run(cmd, capture_output=True, text=True, timeout=60)
        self.assertEqual(r.returncode, 0, "%s: %s" % (scene.name, r.stderr))
        res = json.loads(r.stdout[r.stdout.index("{"):])
        self.assertEqual(res["diagnostics"]["nonfinite"], 0, scene.name)
        mean = res["estimate"]["mean"]
        self.assertTrue(math.isfinite(mean) and mean >= 0, "%s: image mean %r" % (scene.name, mean))
        if not scene.name.endswith("_emitters"):
            self.assertGreater(mean, 0, scene.name)
        self.assertEqual(res["plan"]["image"]["width"], 8)
        self.assertEqual(res["plan"]["image"]["height"], 6)
        if image:
            self.assertGreater(os.path.getsize(out), 0)
        return res

    def test_every_suite_scene_and_its_lambert_variant_renders(self) -> None:
        with tempfile.TemporaryDirectory() as tmp:
            for name, writer in scenes.WRITERS.items():
                with self.subTest(scene=name):
                    if name == "envlight" and (scenes.find_world_map() is None or not oiio_available()):
                        self.skipTest("no Blender world map or no OpenImageIO Python bindings")
                    s = writer(os.path.join(tmp, name), (8, 6))
                    self.assertIsNotNone(s)
                    if s.env:
                        sys.path.insert(0, os.path.join(SOURCE_DIR, "bench", "scene_suite"))
                        import suite
                        suite.clean_map(os.path.join(s.directory, s.env["file"]))
                    res = self.render(s, image=(name == "cornell"))
                    effects = {e["effect"]: e for e in res["plan"]["plan"]["effects"]}
                    if name == "many_lights":
                        self.assertTrue(effects.get("light_tree", {}).get("on"), res["plan"]["plan"])
                    if name == "envlight":
                        self.assertTrue(effects["sky"]["on"])
                    lam = scenes.lambert(s)
                    if lam is not None:
                        self.render(lam)
                    # The emitter mask's variant: every scene with an emissive material has
                    # one, with every other surface black, so at depth 1 its image is the
                    # directly seen emission alone: less than the scene's own depth-1 image.
                    em = scenes.emitters(s)
                    self.assertEqual(em is None, name in ("lecture", "envlight"), name)
                    if em is not None:
                        whole = self.render(s, depth=1)["estimate"]["mean"]
                        only = self.render(em, depth=1)["estimate"]["mean"]
                        self.assertLess(only, whole, name)
                        if name in ("cornell", "many_lights"):  # their camera sees the panel / lamps
                            self.assertGreater(only, 0, name)


if __name__ == "__main__":
    unittest.main()
