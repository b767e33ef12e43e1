"""`pip install ./client/python` works without a network: the in-tree build backend needs
nothing from a package index. Runs pip with --no-index in a fresh target directory."""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
import unittest

SOURCE_DIR = os.environ.get("TALLY_SOURCE_DIR", os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__)))))


class OfflineInstall(unittest.TestCase):
    def test_pip_install_without_index(self) -> None:
        with tempfile.TemporaryDirectory() as d:
            env = {k: v for k, v in os.environ.items() if not k.startswith("PIP_") and k != "PYTHONPATH"}
            env.update({"PIP_NO_INDEX": "1", "PIP_DISABLE_PIP_VERSION_CHECK": "1", "PIP_NO_CACHE_DIR": "1"})
            target = os.path.join(d, "site")
            r = subprocess.run([sys.executable, "-m", "pip", "install", "--no-index", "--target", target,
                                os.path.join(SOURCE_DIR, "client", "python")],
                               env=env, capture_output=True, text=True, timeout=300)
            self.assertEqual(r.returncode, 0, r.stdout + r.stderr)
            files = sorted(os.listdir(os.path.join(target, "tally_client")))
            for f in ("__init__.py", "client.py", "errors.py", "image.py", "py.typed"):
                self.assertIn(f, files)
            # The installed copy imports on its own (not the source tree).
            r = subprocess.run([sys.executable, "-c",
                                "import tally_client, sys; print(tally_client.__file__); "
                                "print(tally_client.Client('http://127.0.0.1:1').url)"],
                               env={**env, "PYTHONPATH": target}, cwd=d, capture_output=True, text=True, timeout=60)
            self.assertEqual(r.returncode, 0, r.stderr)
            self.assertTrue(r.stdout.startswith(target), r.stdout)
            self.assertIn("http://127.0.0.1:1", r.stdout)


if __name__ == "__main__":
    unittest.main()
