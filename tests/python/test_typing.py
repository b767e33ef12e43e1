"""tally_client is typed (py.typed): mypy --strict finds nothing in it or its build backend."""

from __future__ import annotations

import os
import subprocess
import sys
import unittest

SOURCE_DIR = os.environ.get("TALLY_SOURCE_DIR", os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__)))))


class Typing(unittest.TestCase):
    def test_mypy_strict(self) -> None:
        pkg = os.path.join(SOURCE_DIR, "client", "python")
        r = subprocess.run([sys.executable, "-m", "mypy", "--strict", "--no-incremental", "--cache-dir", os.devnull,
                            "tally_client", "_backend/tally_backend.py"],
                           cwd=pkg, capture_output=True, text=True, timeout=300)
        self.assertEqual(r.returncode, 0, r.stdout + r.stderr)
        self.assertIn("Success", r.stdout)


if __name__ == "__main__":
    unittest.main()
