"""Helpers of the Python client tests: a real tally-server on an ephemeral loopback port,
and a TCP proxy that can cut connections. Every wait is bounded."""

from __future__ import annotations

import os
import select
import shutil
import signal
import socket
import subprocess
import tempfile
import threading
import time
import unittest
from typing import List, Optional

SERVER_BIN = os.environ.get("TALLY_SERVER_BIN", "")
SOURCE_DIR = os.environ.get("TALLY_SOURCE_DIR", os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__)))))


def disk_spec(max_samples: int, seed: int = 1, **extra) -> dict:
    spec = {"kind": "integrate", "integrand": {"builtin": "unit_disk"}, "seed": seed,
            "stop": {"max_samples": max_samples}}
    spec.update(extra)
    return spec


def small_image_spec(spp: int = 16, resolution=(40, 24), tile_size: int = 16) -> dict:
    import json
    with open(os.path.join(SOURCE_DIR, "examples", "lecture_lighting_image.json"), encoding="utf-8") as f:
        spec = json.load(f)
    spec["scene"]["camera"]["resolution"] = list(resolution)
    spec["query"] = {"type": "image", "max_depth": 2, "tile_size": tile_size}
    spec["stop"] = {"max_samples": spp}
    return spec


class Server:
    """tally-server on 127.0.0.1 with port 0, a temporary data dir; stop() with SIGTERM."""

    def __init__(self, *extra: str, env: Optional[dict] = None):
        if not SERVER_BIN:
            raise RuntimeError("TALLY_SERVER_BIN is not set (ctest sets it)")
        self.dir = tempfile.mkdtemp(prefix="tally_py_")
        port_file = os.path.join(self.dir, "port")
        self.log_path = os.path.join(self.dir, "server.log")
        self._log = open(self.log_path, "wb")
        self.proc = subprocess.Popen(
            [SERVER_BIN, "--listen", "127.0.0.1:0", "--port-file", port_file, "--data-dir",
             os.path.join(self.dir, "data"), "--workers", "1", *extra],
            stdout=self._log, stderr=subprocess.STDOUT, env=env)
        deadline = time.monotonic() + 30
        self.port = 0
        while time.monotonic() < deadline:
            if self.proc.poll() is not None:
                break
            try:
                with open(port_file, encoding="utf-8") as f:
                    text = f.read().strip()
                if text:
                    self.port = int(text)
                    break
            except FileNotFoundError:
                pass
            time.sleep(0.02)
        if not self.port:
            self.stop()
            raise RuntimeError(f"tally-server did not start: {self.log()}")
        self.url = f"http://127.0.0.1:{self.port}"

    def log(self) -> str:
        with open(self.log_path, encoding="utf-8", errors="replace") as f:
            return f.read()

    def stop(self) -> None:
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            try:
                self.proc.wait(timeout=20)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(timeout=10)
        self._log.close()
        shutil.rmtree(self.dir, ignore_errors=True)


class ServerTestCase(unittest.TestCase):
    """Tests against one real tally-server started for the class and stopped after it."""

    server: Server

    @classmethod
    def setUpClass(cls) -> None:
        cls.server = Server()

    @classmethod
    def tearDownClass(cls) -> None:
        cls.server.stop()


def _shutdown(*socks: socket.socket) -> None:
    """Shuts both directions of each socket down (a peer that has gone is fine)."""
    for s in socks:
        try:
            s.shutdown(socket.SHUT_RDWR)
        except OSError:
            pass


class _LoopbackProxy:
    """A listener on 127.0.0.1 (an ephemeral port) whose accept thread hands every
    connection to `_serve` on a thread of its own; close() stops and joins them (bounded).
    Subclasses set their own fields before calling __init__ (it starts accepting)."""

    def __init__(self, scheme: str):
        self._listener = socket.create_server(("127.0.0.1", 0))
        self._listener.settimeout(0.2)
        self.port = self._listener.getsockname()[1]
        self.url = f"{scheme}://127.0.0.1:{self.port}"
        self._stop = threading.Event()
        self._threads: List[threading.Thread] = []
        self._accept_thread = threading.Thread(target=self._accept, daemon=True)
        self._accept_thread.start()

    def close(self) -> None:
        self._stop.set()
        self._accept_thread.join(timeout=5)
        self._listener.close()
        for t in self._threads:
            t.join(timeout=5)

    def _accept(self) -> None:
        while not self._stop.is_set():
            try:
                conn, _ = self._listener.accept()
            except socket.timeout:
                continue
            except OSError:
                return
            t = threading.Thread(target=self._serve, args=(conn,), daemon=True)
            self._threads.append(t)
            t.start()

    def _serve(self, conn: socket.socket) -> None:
        raise NotImplementedError


class CuttingProxy(_LoopbackProxy):
    """A loopback TCP proxy in front of `port`. It records each connection's request bytes.

    The first `cut_streams` event-stream connections (requests whose first line has
    /events) are cut mid-event: the proxy forwards the response up to 10 bytes into the
    `cut_after + 1`-th SSE event and then closes both sides."""

    def __init__(self, port: int, cut_streams: int = 1, cut_after: int = 3):
        self.upstream = port
        self.cut_streams = cut_streams
        self.cut_after = cut_after
        self.requests: List[bytes] = []
        self.cuts = 0
        self._lock = threading.Lock()
        super().__init__("http")

    def _serve(self, client: socket.socket) -> None:
        try:
            server = socket.create_connection(("127.0.0.1", self.upstream), timeout=5)
        except OSError:
            client.close()
            return
        request = b""
        held = b""
        recorded = False
        cut_here = False
        try:
            while not self._stop.is_set():
                readable, _, _ = select.select([client, server], [], [], 0.2)
                if client in readable:
                    data = client.recv(65536)
                    if not data:
                        break
                    request += data
                    if not recorded and b"\r\n\r\n" in request:
                        recorded = True
                        with self._lock:
                            self.requests.append(request)
                            first_line = request.split(b"\r\n", 1)[0]
                            if b"/events" in first_line and self.cuts < self.cut_streams:
                                self.cuts += 1
                                cut_here = True
                    server.sendall(data)
                if server in readable:
                    data = server.recv(65536)
                    if not data:
                        if held:
                            client.sendall(held)  # the stream ended before the cut point
                        break
                    if not cut_here:
                        client.sendall(data)
                        continue
                    held += data
                    pos = -1
                    for _ in range(self.cut_after + 1):
                        pos = held.find(b"event: ", pos + 1)
                        if pos < 0:
                            break
                    if pos >= 0 and len(held) >= pos + 10:
                        client.sendall(held[:pos + 10])
                        break  # cut: close both sides mid-event
        except OSError:
            pass
        finally:
            _shutdown(client, server)
            client.close()
            server.close()

    def request_heads(self, needle: bytes) -> List[bytes]:
        with self._lock:
            return [r for r in self.requests if needle in r.split(b"\r\n", 1)[0]]


def header_value(request: bytes, name: str) -> Optional[str]:
    for line in request.split(b"\r\n\r\n", 1)[0].split(b"\r\n")[1:]:
        k, _, v = line.partition(b":")
        if k.strip().lower() == name.lower().encode():
            return v.strip().decode()
    return None


def free_port() -> int:
    s = socket.create_server(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()
    return port


class TlsProxy(_LoopbackProxy):
    """A TLS-terminating loopback proxy in front of `port`, with a throw-away self-signed
    certificate for 127.0.0.1 made by the openssl command (cafile: the certificate)."""

    def __init__(self, port: int):
        import ssl
        self.upstream = port
        self.dir = tempfile.mkdtemp(prefix="tally_tls_")
        self.cafile = os.path.join(self.dir, "cert.pem")
        key = os.path.join(self.dir, "key.pem")
        subprocess.run(["openssl", "req", "-x509", "-newkey", "rsa:2048", "-nodes", "-keyout", key,
                        "-out", self.cafile, "-days", "1", "-subj", "/CN=127.0.0.1",
                        "-addext", "subjectAltName=IP:127.0.0.1"],
                       check=True, capture_output=True, timeout=60)
        self._ctx = ssl.SSLContext(ssl.PROTOCOL_TLS_SERVER)
        self._ctx.load_cert_chain(self.cafile, key)
        super().__init__("https")

    def close(self) -> None:
        super().close()
        shutil.rmtree(self.dir, ignore_errors=True)

    def _serve(self, raw: socket.socket) -> None:
        try:
            raw.settimeout(10)
            client = self._ctx.wrap_socket(raw, server_side=True)
        except OSError:
            raw.close()  # e.g. a client that rejected the certificate
            return
        try:
            server = socket.create_connection(("127.0.0.1", self.upstream), timeout=10)
        except OSError:
            client.close()
            return

        def pump(src: socket.socket, dst: socket.socket) -> None:
            try:
                while not self._stop.is_set():
                    data = src.recv(65536)
                    if not data:
                        break
                    dst.sendall(data)
            except OSError:
                pass
            finally:
                _shutdown(src, dst)

        back = threading.Thread(target=pump, args=(server, client), daemon=True)
        back.start()
        pump(client, server)
        back.join(timeout=10)
        client.close()
        server.close()
