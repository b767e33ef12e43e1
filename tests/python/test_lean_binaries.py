"""Lean binaries: OpenImageIO (through the image module libtally_image.so) is loaded only
when an image is written. The CLI's start-up and an idle server do not map it; image
output still works in the server and through the CLI, and a missing module is a clear
501, not a crash."""

from __future__ import annotations

import os
import re
import subprocess
import sys
import tempfile
import unittest

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from tally_test_support import Server, disk_spec, small_image_spec  # noqa: E402

from tally_client import Client, NotImplementedByServer, decode_exr  # noqa: E402

CLI_BIN = os.environ.get("TALLY_CLI_BIN", "")
IMAGE_LIBS = re.compile(r"libOpenImageIO|libtally_image|libOpenEXR|libpng")


def loaded_libraries(argv, env=None) -> list:
    """Runs a command with LD_DEBUG=libs and returns every shared library the dynamic
    loader opened (at start and by dlopen)."""
    r = subprocess.run(argv, env={**os.environ, **(env or {}), "LD_DEBUG": "libs"},
                       capture_output=True, text=True, timeout=60)
    return sorted(set(re.findall(r"calling init: (\S+)", r.stderr))), r


def mapped_files(pid: int) -> set:
    with open(f"/proc/{pid}/maps", encoding="utf-8") as f:
        return {line.split()[-1] for line in f if "/" in line.split()[-1]}


@unittest.skipUnless(CLI_BIN, "TALLY_CLI_BIN is not set")
class CliStart(unittest.TestCase):
    def test_help_and_list_do_not_load_image_libraries(self) -> None:
        libs, r = loaded_libraries([CLI_BIN, "--help"])
        self.assertEqual(r.returncode, 0, r.stderr[-2000:])
        self.assertIn("submit", r.stdout)
        self.assertTrue(any("libc.so" in x for x in libs), "LD_DEBUG output was read")
        self.assertEqual([x for x in libs if IMAGE_LIBS.search(x)], [])
        server = Server()
        try:
            libs, r = loaded_libraries([CLI_BIN, "list", "--server", server.url])
            self.assertEqual(r.returncode, 0, r.stderr[-2000:])
            self.assertEqual([x for x in libs if IMAGE_LIBS.search(x)], [])
        finally:
            server.stop()

    def test_cli_saves_the_servers_images(self) -> None:
        server = Server()
        try:
            c = Client(server.url)
            job = c.submit(small_image_spec(spp=8, resolution=(24, 16), tile_size=8))
            c.wait(job, timeout=120)
            with tempfile.TemporaryDirectory() as d:
                exr, png = os.path.join(d, "out.exr"), os.path.join(d, "out.png")
                for path in (exr, png):
                    r = subprocess.run([CLI_BIN, "get", job, "--image", path, "--server", server.url],
                                       capture_output=True, text=True, timeout=60)
                    self.assertEqual(r.returncode, 0, r.stderr)
                with open(exr, "rb") as f:
                    img = decode_exr(f.read())
                with open(png, "rb") as f:
                    self.assertEqual(f.read(8), b"\x89PNG\r\n\x1a\n")
            tiles = c.image(job, source="tiles")
            self.assertEqual((img.width, img.height), (24, 16))
            self.assertEqual(img.mean_flat.tobytes(), tiles.mean_flat.tobytes())
            self.assertEqual(set(img.samples_flat), {8.0})
        finally:
            server.stop()


class ServerImageModule(unittest.TestCase):
    def test_idle_server_does_not_map_it_and_the_first_image_loads_it(self) -> None:
        server = Server()
        try:
            c = Client(server.url)
            job = c.submit(small_image_spec(spp=4, resolution=(16, 16), tile_size=8))
            c.wait(job, timeout=120)
            c.list()
            c.tile(job, 0)  # JSON tiles need no image library
            before = mapped_files(server.proc.pid)
            self.assertTrue(any("tally-server" in p for p in before))
            self.assertEqual([p for p in before if IMAGE_LIBS.search(p)], [])
            exr = c.image_bytes(job, "exr")
            self.assertEqual(exr[:4], b"\x76\x2f\x31\x01")  # OpenEXR magic
            after = mapped_files(server.proc.pid)
            self.assertTrue(any("libtally_image.so" in p for p in after), sorted(after))
        finally:
            server.stop()

    def test_missing_module_is_a_clear_501(self) -> None:
        server = Server(env={**os.environ, "TALLY_IMAGE_MODULE": "/nonexistent/libtally_image.so"})
        try:
            c = Client(server.url)
            job = c.submit(small_image_spec(spp=1, resolution=(8, 8), tile_size=8))
            c.wait(job, timeout=120)
            for fmt in ("exr", "png"):
                with self.assertRaises(NotImplementedByServer) as cm:
                    c.image_bytes(job, fmt)
                self.assertEqual(cm.exception.status, 501)
                self.assertIn("/nonexistent/libtally_image.so", cm.exception.detail)
            # The JSON tiles and the rest of the server are unaffected.
            self.assertEqual(c.tile(job, 0)["w"], 8)
            self.assertEqual(c.status(job)["state"], "succeeded")
            j2 = c.submit(disk_spec(1000))
            self.assertEqual(c.wait(j2, timeout=60)["samples"], 1000)
        finally:
            server.stop()


if __name__ == "__main__":
    unittest.main()
