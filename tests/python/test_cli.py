"""The `tally` CLI as a newcomer meets it: exit codes as documented (docs/api.md), a 401
that prints no table and hints --token/TALLY_TOKEN, 503 + Retry-After waited out, JSON
errors with line and column, unreadable files with the reason, --version, image formats
by extension (run and get), validate and the submit prediction, and the server's bind
error naming the address. Servers: the real tally-server, or a scripted one for 401/503."""

from __future__ import annotations

import http.server
import json
import os
import shutil
import socket
import subprocess
import sys
import tempfile
import threading
import time
import unittest
from typing import Any, Dict, List, Tuple

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from tally_test_support import SERVER_BIN, SOURCE_DIR, ServerTestCase, disk_spec, small_image_spec  # noqa: E402

CLI_BIN = os.environ.get("TALLY_CLI_BIN", "")

# client/exit_codes.hpp
USAGE, CONNECTION, AUTH = 4, 5, 6


class Scripted:
    """An HTTP server on 127.0.0.1 answering from a list of (status, headers, body), the
    last one repeated; it records each request's method and path."""

    def __init__(self, answers: List[Tuple[int, Dict[str, str], Dict[str, Any]]]):
        self.answers = answers
        self.seen: List[Tuple[str, str, float]] = []
        outer = self

        class Handler(http.server.BaseHTTPRequestHandler):
            def _answer(self) -> None:
                n = len(outer.seen)
                outer.seen.append((self.command, self.path, time.monotonic()))
                status, headers, body = outer.answers[min(n, len(outer.answers) - 1)]
                data = json.dumps(body).encode()
                self.send_response(status)
                ctype = "application/problem+json" if status >= 400 else "application/json"
                self.send_header("Content-Type", ctype)
                self.send_header("Content-Length", str(len(data)))
                for k, v in headers.items():
                    self.send_header(k, v)
                self.end_headers()
                self.wfile.write(data)

            do_GET = do_POST = do_DELETE = _answer

            def log_message(self, *args: Any) -> None:
                pass

        self.httpd = http.server.ThreadingHTTPServer(("127.0.0.1", 0), Handler)
        self.url = f"http://127.0.0.1:{self.httpd.server_address[1]}"
        self.thread = threading.Thread(target=self.httpd.serve_forever, daemon=True)
        self.thread.start()

    def close(self) -> None:
        self.httpd.shutdown()
        self.httpd.server_close()


def run(*args: str, cwd: str = ".", env: Dict[str, str] | None = None) -> subprocess.CompletedProcess[str]:
    full_env = {k: v for k, v in os.environ.items() if not k.startswith("TALLY_") or k.endswith("_BIN")}
    full_env.update(env or {})
    return subprocess.run([CLI_BIN, *args], capture_output=True, text=True, timeout=120, cwd=cwd, env=full_env)


DONE = {"id": "j1", "state": "succeeded", "stop_reason": "max_samples", "samples": 10, "passes": 1,
        "summary": "3.1 ± 0.1 (95% CI [2.9, 3.3])", "stop_rule": {"max_samples": 10}}


@unittest.skipUnless(CLI_BIN, "TALLY_CLI_BIN is not set")
class Offline(unittest.TestCase):
    def setUp(self) -> None:
        self.dir = tempfile.mkdtemp(prefix="tally_cli_")

    def tearDown(self) -> None:
        shutil.rmtree(self.dir, ignore_errors=True)

    def test_version(self) -> None:
        r = run("--version")
        self.assertEqual(r.returncode, 0, r.stderr)
        self.assertEqual(r.stdout.strip(), "tally 0.1.0")

    def test_unreadable_file_gives_the_reason(self) -> None:
        for cmd in (["submit"], ["validate"], ["run"]):
            r = run(*cmd, "no_such.json", "--server", "http://127.0.0.1:1") if cmd != ["run"] else run("run", "no_such.json")
            self.assertEqual(r.returncode, USAGE, (cmd, r.stderr))
            self.assertIn("cannot read no_such.json: No such file or directory", r.stderr)

    def test_malformed_json_has_line_and_column(self) -> None:
        path = os.path.join(self.dir, "bad.json")
        with open(path, "w", encoding="utf-8") as f:
            f.write('{\n  "kind": "integrate",\n}\n')
        for cmd in (["submit", path, "--server", "http://127.0.0.1:1"], ["run", path]):
            r = run(*cmd)
            self.assertEqual(r.returncode, USAGE, r.stderr)
            self.assertIn("is not valid JSON: at line 3, column 1: syntax error", r.stderr)
            self.assertNotIn("json.exception", r.stderr)

    def test_unknown_image_extension_is_refused_before_any_work(self) -> None:
        out = os.path.join(self.dir, "x.jpg")
        r = run("get", "someid", "--image", out, "--server", "http://127.0.0.1:1")  # no server needed
        self.assertEqual(r.returncode, USAGE, r.stderr)
        self.assertIn('cannot tell the image format of "' + out + '": use a .exr', r.stderr)
        self.assertFalse(os.path.exists(out))
        spec = os.path.join(self.dir, "img.json")
        with open(spec, "w", encoding="utf-8") as f:
            json.dump(small_image_spec(spp=1, resolution=(8, 6)), f)
        r = run("run", spec, "--image", out)
        self.assertEqual(r.returncode, USAGE, r.stderr)
        self.assertIn("cannot tell the image format", r.stderr)
        self.assertFalse(os.path.exists(out))

    def test_run_writes_exr_and_png_by_extension(self) -> None:
        spec = os.path.join(self.dir, "img.json")
        with open(spec, "w", encoding="utf-8") as f:
            json.dump(small_image_spec(spp=2, resolution=(8, 6)), f)
        for name, magic in (("out.exr", b"\x76\x2f\x31\x01"), ("out.PNG", b"\x89PNG\r\n\x1a\n")):
            out = os.path.join(self.dir, name)
            r = run("run", spec, "--image", out, "--threads", "1")
            self.assertEqual(r.returncode, 0, r.stderr)
            self.assertRegex(r.stdout, r"\npeak memory [0-9]+\.[0-9] MB\n")
            with open(out, "rb") as f:
                self.assertEqual(f.read(len(magic)), magic, name)
        # An integration job has no image: said, not a silent empty file.
        disk = os.path.join(self.dir, "disk.json")
        with open(disk, "w", encoding="utf-8") as f:
            json.dump(disk_spec(1000), f)
        r = run("run", disk, "--image", os.path.join(self.dir, "none.png"))
        self.assertEqual(r.returncode, USAGE, r.stderr)
        self.assertIn("this job makes no image", r.stderr)

    def test_run_reads_scene_files_next_to_the_spec(self) -> None:
        # `tally run` takes a scene's file names relative to the spec (or --asset-dir).
        os.makedirs(os.path.join(self.dir, "meshes"))
        with open(os.path.join(self.dir, "meshes", "lamp.obj"), "w", encoding="utf-8") as f:
            f.write("v -0.5 -0.5 1.5\nv -0.5 0.5 1.5\nv 0.5 0.5 1.5\nv 0.5 -0.5 1.5\nf 1 2 3\nf 1 3 4\n")
        spec = small_image_spec(spp=1, resolution=(8, 6))
        spec["scene"]["shapes"].append({"type": "mesh", "obj": "meshes/lamp.obj", "material": spec["scene"]["shapes"][0]["material"]})
        with open(os.path.join(self.dir, "job.json"), "w", encoding="utf-8") as f:
            json.dump(spec, f)
        r = run("run", os.path.join(self.dir, "job.json"), "--threads", "1")
        self.assertEqual(r.returncode, 0, r.stderr)
        other = tempfile.mkdtemp(prefix="tally_cli_other_")
        try:
            r = run("run", os.path.join(self.dir, "job.json"), "--asset-dir", other, "--threads", "1")
            self.assertEqual(r.returncode, USAGE, r.stderr)
            self.assertIn("meshes/lamp.obj", r.stderr)
        finally:
            shutil.rmtree(other, ignore_errors=True)


@unittest.skipUnless(CLI_BIN, "TALLY_CLI_BIN is not set")
class AgainstScriptedServer(unittest.TestCase):
    def test_401_prints_no_table_exits_auth_and_hints_the_token(self) -> None:
        s = Scripted([(401, {"WWW-Authenticate": "Bearer"}, {"title": "Unauthorized", "status": 401,
                                                             "detail": "a bearer token is required"})])
        try:
            for args in (["list"], ["get", "j1"], ["submit", os.path.join(SOURCE_DIR, "examples", "unit_disk.json")]):
                r = run(*args, "--server", s.url)
                self.assertEqual(r.returncode, AUTH, (args, r.stderr))
                self.assertEqual(r.stdout, "", args)  # no table header before the refusal
                self.assertIn("--token", r.stderr)
                self.assertIn("TALLY_TOKEN", r.stderr)
                self.assertIn("a bearer token is required", r.stderr)
        finally:
            s.close()

    def test_403_exits_auth(self) -> None:
        s = Scripted([(403, {}, {"title": "Forbidden", "status": 403, "detail": "role reader may not submit"})])
        try:
            r = run("cancel", "j1", "--server", s.url)
            self.assertEqual(r.returncode, AUTH, r.stderr)
            self.assertIn("role reader may not submit", r.stderr)
        finally:
            s.close()

    def test_503_with_retry_after_is_retried_with_backoff(self) -> None:
        busy = (503, {"Retry-After": "1"}, {"title": "Service Unavailable", "status": 503,
                                            "detail": "the server is starting: jobs are being recovered"})
        s = Scripted([busy, busy, (200, {}, DONE)])
        try:
            r = run("get", "j1", "--server", s.url)
            self.assertEqual(r.returncode, 0, r.stderr)
            self.assertIn("3.1 ± 0.1", r.stdout)
            self.assertEqual(len(s.seen), 3)
            gaps = [b[2] - a[2] for a, b in zip(s.seen, s.seen[1:])]
            self.assertGreaterEqual(min(gaps), 0.95)  # Retry-After: 1 was honoured each time
            self.assertEqual(r.stderr.count("retrying in"), 2)
        finally:
            s.close()

    def test_503_without_retry_after_is_not_retried(self) -> None:
        s = Scripted([(503, {}, {"title": "Service Unavailable", "status": 503, "detail": "shutting down"})])
        try:
            r = run("get", "j1", "--server", s.url)
            self.assertEqual(r.returncode, CONNECTION, r.stderr)
            self.assertEqual(len(s.seen), 1)
        finally:
            s.close()


@unittest.skipUnless(CLI_BIN, "TALLY_CLI_BIN is not set")
class AgainstRealServer(ServerTestCase):
    def test_validate_prints_the_prediction(self) -> None:
        r = run("validate", os.path.join(SOURCE_DIR, "examples", "unit_disk.json"), "--server", self.server.url)
        self.assertEqual(r.returncode, 0, r.stderr)
        lines = r.stdout.splitlines()
        self.assertEqual(lines[0], "valid")
        self.assertTrue(lines[1].startswith("predicted: stops by "), r.stdout)
        self.assertIn("rel. error 0.01:", r.stdout)
        r = run("validate", "-", "--server", self.server.url)  # stdin, empty: not JSON
        self.assertEqual(r.returncode, USAGE)
        self.assertIn("the spec on stdin is not valid JSON", r.stderr)

    def test_validate_names_a_faster_estimator(self) -> None:
        d = tempfile.mkdtemp(prefix="tally_cli_")
        try:
            path = os.path.join(d, "smooth.json")
            with open(path, "w", encoding="utf-8") as f:
                json.dump({"kind": "integrate", "integrand": {"expression": "exp(-x*x)"},
                           "domain": {"type": "box", "lower": [0], "upper": [1]},
                           "stop": {"rel_error": 1e-5}}, f)
            r = run("validate", path, "--server", self.server.url)
            self.assertEqual(r.returncode, 0, r.stderr)
            faster = [ln for ln in r.stdout.splitlines() if ln.startswith("faster: ")]
            self.assertEqual(len(faster), 1, r.stdout)
            self.assertTrue(faster[0].startswith('faster: add "estimator": {"type": "auto"}; it would choose '),
                            faster[0])
            self.assertIn("fewer integrand evaluations", faster[0])
            # A spec that names its estimator gets no such line.
            r = run("validate", os.path.join(SOURCE_DIR, "examples", "unit_disk.json"), "--server", self.server.url)
            self.assertNotIn("faster: ", r.stdout)
        finally:
            shutil.rmtree(d, ignore_errors=True)

    def test_validate_names_the_field_of_an_invalid_spec(self) -> None:
        d = tempfile.mkdtemp(prefix="tally_cli_")
        try:
            path = os.path.join(d, "bad.json")
            with open(path, "w", encoding="utf-8") as f:
                json.dump(disk_spec(-3), f)
            r = run("validate", path, "--server", self.server.url)
            self.assertEqual(r.returncode, USAGE, r.stderr)
            self.assertIn("422: /stop/max_samples", r.stderr)
        finally:
            shutil.rmtree(d, ignore_errors=True)

    def test_submit_warns_when_the_prediction_exceeds_the_threshold(self) -> None:
        d = tempfile.mkdtemp(prefix="tally_cli_")
        try:
            path = os.path.join(d, "slow.json")
            spec = disk_spec(10**11)
            spec["stop"]["time_budget_s"] = 3600
            with open(path, "w", encoding="utf-8") as f:
                json.dump(spec, f)
            r = run("submit", path, "--warn-seconds", "30", "--server", self.server.url)
            self.assertEqual(r.returncode, 0, r.stderr)
            job = r.stdout.strip()
            self.assertIn("predicted: stops by ", r.stderr)
            self.assertIn("more than --warn-seconds 30", r.stderr)
            self.assertEqual(run("cancel", job, "--server", self.server.url).returncode, 0)
            # A cheap job: the prediction, no warning.
            with open(path, "w", encoding="utf-8") as f:
                json.dump(disk_spec(1000), f)
            r = run("submit", path, "--server", self.server.url)
            self.assertEqual(r.returncode, 0, r.stderr)
            self.assertIn("predicted: stops by max_samples", r.stderr)
            self.assertNotIn("warning", r.stderr)
        finally:
            shutil.rmtree(d, ignore_errors=True)

    def test_priority_changes_a_running_job_and_refuses_a_finished_one(self) -> None:
        d = tempfile.mkdtemp(prefix="tally_cli_")
        try:
            path = os.path.join(d, "long.json")
            with open(path, "w", encoding="utf-8") as f:
                json.dump(disk_spec(10**11), f)
            r = run("submit", path, "--no-predict", "--server", self.server.url)
            self.assertEqual(r.returncode, 0, r.stderr)
            job = r.stdout.strip()
            r = run("priority", job, "4", "--server", self.server.url)
            self.assertEqual(r.returncode, 0, r.stderr)
            self.assertEqual(r.stdout, f"{job} priority 4\n")
            r = run("get", job, "--json", "--server", self.server.url)
            self.assertEqual(json.loads(r.stdout)["priority"], 4)
            r = run("priority", job, "6", "--server", self.server.url)  # refused before any request
            self.assertEqual(r.returncode, USAGE, r.stderr)
            self.assertEqual(run("cancel", job, "--server", self.server.url).returncode, 0)
            for _ in range(100):
                if json.loads(run("get", job, "--json", "--server", self.server.url).stdout)["state"] == "cancelled":
                    break
                time.sleep(0.1)
            r = run("priority", job, "1", "--server", self.server.url)
            self.assertEqual(r.returncode, USAGE, r.stderr)  # 409: a 4xx is a usage error (docs/api.md)
            self.assertIn("409", r.stderr)
            self.assertIn("has already finished (cancelled)", r.stderr)
        finally:
            shutil.rmtree(d, ignore_errors=True)


@unittest.skipUnless(SERVER_BIN, "TALLY_SERVER_BIN is not set")
class BindError(unittest.TestCase):
    def test_bind_error_names_the_address(self) -> None:
        with socket.socket() as taken:
            taken.bind(("127.0.0.1", 0))
            taken.listen(1)
            port = taken.getsockname()[1]
            d = tempfile.mkdtemp(prefix="tally_bind_")
            try:
                r = subprocess.run([SERVER_BIN, "--listen", f"127.0.0.1:{port}", "--data-dir", os.path.join(d, "data")],
                                   capture_output=True, text=True, timeout=60)
            finally:
                shutil.rmtree(d, ignore_errors=True)
        self.assertNotEqual(r.returncode, 0)
        self.assertIn(f"cannot listen on 127.0.0.1:{port}: Address already in use", r.stdout + r.stderr)


if __name__ == "__main__":
    unittest.main()
