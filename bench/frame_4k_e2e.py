#!/usr/bin/env python3
"""A 4K image job end to end against the real server, killed mid-way (issue 28,
"production frames"). Standard library only. A benchmark: it prints figures, it is not a
timed test (it exits 1 only when a step fails outright: no checkpoint, no resume, a
wrong EXR).

    python3 bench/frame_4k_e2e.py [--build build] [--server-bin P] [--client-bin P]
        [--resolution 3840x2160] [--spp 16] [--workers 2] [--checkpoint-interval 0.5]
        [--kill-delay 0] [--keep] [--cluster [--worker-bin P] [--redis-bin P]]

1. `scripts/gltf_example.py DIR` writes cornell.gltf + cornell.bin; the spec is
   examples/gltf_cornell.json with `"resolution"` set and `"stop": {"max_samples": SPP}`,
   written beside the assets so that `tally submit` finds and uploads them
   (PUT /v1/assets/sha256:..., client/scene_packer.cpp).
2. tally-server on 127.0.0.1, port 0 (`--port-file`), a fresh `--data-dir` (SQLite);
   `tally submit --no-predict` (no validate pilot: the server's peak is the job's).
3. Waits until a checkpoint is stored (rows of `checkpoint_pieces` in data/tally.db, read
   read-only) while the job still runs, then `kill -9`. Checkpoint size: the sum of its
   pieces (the encoded checkpoint) and the data dir's bytes on disk. Checkpoint time: the
   server reports none (no metric, no log line), so it is timed from its spool file
   (server/jobs/checkpoint_spool.cpp: an unlinked `.checkpoint-spool-*` in the data dir,
   seen in /proc/PID/fd every 20 ms, open from the first encoded byte) to its pieces
   being visible to a reader (the commit, polled every 0.2 s); the spool closes after
   SQLite's own WAL checkpoint, which the committing thread runs.
4. Restarts on the same data dir: the job must resume from the checkpoint (the server's
   `resumes from its checkpoint (N samples)` line and the status' `samples` > 0 before
   its next pass), and run to `succeeded`.
5. GET /v1/jobs/ID/image.exr: its size, its dataWindow, its channels (R, G, B,
   StdErr.*, SampleCount) and the SampleCount of a few decoded scanline blocks (ZIP).
6. Prints each server's peak RSS (VmHWM, polled), job_state_bytes (the estimate of
   common/engine/job_state.hpp, from the job's plan; `tally_memory_used_bytes` at
   /metrics adds the scene), ratios, and a timeline (status changes, checkpoints, the
   peak's growth, any GET over 1 s).

With --cluster the same flow runs through cluster mode (docs/cluster.md): redis-server on a
Unix socket in the temp dir (no TCP port, no persistence, noeviction), tally-server
--redis as the coordinator (it computes nothing itself; --workers only sizes a validate
pilot, which --no-predict skips) and one tally-worker --threads WORKERS. Only the
coordinator is killed and restarted; the worker and Redis keep running. It also prints
the worker's and redis-server's peak RSS (VmHWM; for Redis also INFO's used_memory_peak)
at the kill, at the job's end and after the EXR, /v1/workers' counters, and their
ratios to job_state_bytes; both are stopped with SIGTERM (then SIGKILL after 15 s).

Needs about 4 GB of memory and 2 GB of disk in $TMPDIR at 3840x2160 (docs/performance.md,
"A 4K frame through the server, killed mid-way").
"""
import argparse
import itertools
import json
import os
import shutil
import signal
import socket
import sqlite3
import struct
import subprocess
import sys
import tempfile
import threading
import time
import urllib.request
import zlib

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
MB = 1e6


class Failed(Exception):
    pass


T0 = [time.monotonic()]  # the submit, once made
TIMELINE = []  # (monotonic seconds, what): printed at the end, and on a failure


def note(what, at=None):
    TIMELINE.append((time.monotonic() if at is None else at, what))


def fmt_bytes(n):
    return f"{n:,} B ({n / MB:.1f} MB)" if n is not None else "n/a"


def wait_for(what, timeout, poll, step):
    """Calls step() every `poll` seconds until it returns something not None."""
    end = time.monotonic() + timeout
    while True:
        got = step()
        if got is not None:
            return got
        if time.monotonic() > end:
            raise Failed(f"timed out after {timeout:.0f} s waiting for {what}")
        time.sleep(poll)


class Proc:
    """A child process and a thread that polls its /proc entry every 20 ms: VmHWM (the
    kernel's peak RSS, so exact whenever it is read while the process lives), VmRSS, and
    whatever _poll_more() adds."""

    def __init__(self, name, args, log_path):
        self.name = name
        self.log_path = log_path
        self.log = open(log_path, "w")
        self.t_start = time.monotonic()
        self.proc = subprocess.Popen(args, stdout=self.log, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL)
        self.hwm_kb = 0
        self.noted_hwm_kb = 0
        self.rss_kb = 0
        self._stop = threading.Event()
        self._mon = threading.Thread(target=self._monitor, daemon=True)
        self._mon.start()

    def _read_status(self):
        hwm = rss = None
        with open(f"/proc/{self.proc.pid}/status") as f:
            for line in f:
                if line.startswith("VmHWM:"):
                    hwm = int(line.split()[1])
                elif line.startswith("VmRSS:"):
                    rss = int(line.split()[1])
        if hwm is not None:
            self.hwm_kb = max(self.hwm_kb, hwm)
            if hwm > self.noted_hwm_kb * 1.1 + 32 * 1024:  # the peak's growth, in the timeline
                self.noted_hwm_kb = hwm
                note(f"{self.name}: VmHWM {hwm / 1024:.0f} MiB")
        if rss is not None:
            self.rss_kb = rss

    def _poll_more(self):
        pass

    def _monitor(self):
        while not self._stop.is_set() and self.proc.poll() is None:
            try:
                self._read_status()
                self._poll_more()
            except (OSError, ValueError):
                break  # the process is gone
            time.sleep(0.02)

    def peak_rss_kb(self):
        """VmHWM now (the process must be alive), merged with what the monitor saw."""
        try:
            self._read_status()
        except (OSError, ValueError):
            pass
        return self.hwm_kb

    def log_lines(self, *needles):
        with open(self.log_path) as f:
            return [line.rstrip() for line in f if any(n in line for n in needles)]

    def alive(self):
        return self.proc.poll() is None

    def _ended(self):
        self._stop.set()
        self._mon.join(timeout=5)
        self.log.close()

    def kill9(self):
        if self.proc.poll() is None:
            os.kill(self.proc.pid, signal.SIGKILL)
        self.proc.wait(timeout=30)
        self._ended()

    def stop(self, timeout=15):
        """SIGTERM, then SIGKILL if it has not exited within `timeout` seconds; its exit code."""
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            try:
                self.proc.wait(timeout=timeout)
            except subprocess.TimeoutExpired:
                print(f"({self.name} did not exit {timeout:.0f} s after SIGTERM: kill -9)")
                self.proc.kill()
                self.proc.wait(timeout=30)
        self._ended()
        return self.proc.returncode


class Server(Proc):
    """One tally-server process (in process, or the coordinator with --redis), its /proc
    entry polled for the peak and for the checkpoint's spool file."""

    def __init__(self, name, binary, data_dir, workers, checkpoint_interval, log_path, redis_url=None):
        self.data_dir = data_dir
        self.port_file = port_file = os.path.join(os.path.dirname(data_dir), f"port-{name}")
        if os.path.exists(port_file):
            os.unlink(port_file)
        args = [binary, "--listen", "127.0.0.1:0", "--data-dir", data_dir, "--port-file", port_file,
                "--workers", str(workers), "--checkpoint-interval", str(checkpoint_interval)]
        if redis_url:
            args += ["--redis", redis_url]
        self.spools = []  # [start, end or None, max bytes seen], monotonic seconds
        super().__init__(name, args, log_path)

    def wait_ready(self):
        """Until the port file is written (the server writes it once jobs are recovered)."""
        name, port_file, log_path = self.name, self.port_file, self.log_path

        def ready():
            if self.proc.poll() is not None:
                raise Failed(f"{name}: tally-server exited with {self.proc.returncode}; see {log_path}")
            try:
                with open(port_file) as f:
                    text = f.read().strip()
            except OSError:
                return None
            return int(text) if text.isdigit() else None

        self.port = wait_for(f"{name}'s port file (recovery)", 300, 0.05, ready)
        self.ready_s = time.monotonic() - self.t_start
        self.url = f"http://127.0.0.1:{self.port}"

    def _spool_sizes(self):
        fd_dir = f"/proc/{self.proc.pid}/fd"
        sizes = []
        for fd in os.listdir(fd_dir):
            try:
                target = os.readlink(os.path.join(fd_dir, fd))
            except OSError:
                continue
            if "/.checkpoint-spool-" in target and target.startswith(self.data_dir):
                try:
                    sizes.append(os.stat(os.path.join(fd_dir, fd)).st_size)
                except OSError:
                    sizes.append(0)
        return sizes

    def _poll_more(self):
        sizes = self._spool_sizes()
        now = time.monotonic()
        open_spool = self.spools and self.spools[-1][1] is None
        if sizes and not open_spool:
            self.spools.append([now, None, max(sizes)])
            note(f"{self.name}: checkpoint spool opened", now)
        elif sizes and open_spool:
            self.spools[-1][2] = max(self.spools[-1][2], max(sizes))
        elif not sizes and open_spool:
            self.spools[-1][1] = now
            note(f"{self.name}: checkpoint spool closed ({self.spools[-1][2] / MB:.1f} MB spooled)", now)

    # HTTP
    def get(self, path, timeout=60):
        t0 = time.monotonic()
        with urllib.request.urlopen(self.url + path, timeout=timeout) as r:
            body = r.read()
        took = time.monotonic() - t0
        if took > 1.0:
            note(f"{self.name}: GET {path} took {took:.2f} s", t0)
        return body

    def status(self, job):
        return json.loads(self.get(f"/v1/jobs/{job}"))

    def metric(self, name):
        for line in self.get("/metrics").decode().splitlines():
            if line.startswith(name + " ") or line.startswith(name + "{"):
                return float(line.rsplit(" ", 1)[1])
        return None


class Redis(Proc):
    """redis-server on a Unix socket only (no TCP port), no persistence, noeviction
    (docs/cluster.md)."""

    def __init__(self, binary, sock, log_path):
        self.sock = sock
        super().__init__("redis", [binary, "--port", "0", "--unixsocket", sock, "--save", "", "--appendonly", "no",
                                   "--maxmemory-policy", "noeviction"], log_path)

    def wait_ready(self):
        def pong():
            if self.proc.poll() is not None:
                raise Failed(f"redis-server exited with {self.proc.returncode}; see {self.log_path}")
            try:
                return redis_call(self.sock, "PING", timeout=1)
            except OSError:
                return None

        wait_for("redis-server's PONG", 30, 0.05, pong)

    def info(self, section="memory"):
        """INFO SECTION as a dict of strings; {} when Redis does not answer."""
        try:
            text = redis_call(self.sock, "INFO", section)
        except (OSError, Failed):
            return {}
        return dict(line.split(":", 1) for line in text.splitlines() if ":" in line and not line.startswith("#"))


def redis_call(sock_path, *args, timeout=10):
    """One command over Redis's Unix socket (RESP2): a simple or bulk string or an integer
    reply. OSError when Redis cannot be reached, Failed on an error reply."""
    with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as c:
        c.settimeout(timeout)
        c.connect(sock_path)
        req = [f"*{len(args)}\r\n".encode()]
        for arg in args:
            b = arg.encode()
            req.append(f"${len(b)}\r\n".encode() + b + b"\r\n")
        c.sendall(b"".join(req))
        f = c.makefile("rb")
        line = f.readline()
        if not line:
            raise OSError("redis-server closed the connection")
        kind, rest = line[:1], line[1:].rstrip(b"\r\n")
        if kind == b"+":
            return rest.decode()
        if kind == b":":
            return int(rest)
        if kind == b"$":
            n = int(rest)
            return None if n < 0 else f.read(n + 2)[:n].decode()
        raise Failed(f"redis-server answered {line.decode(errors='replace').strip()}")


def stored_checkpoint(db_path, job):
    """(pieces, bytes) of the job's stored checkpoint, from a short read-only transaction;
    None when it cannot be read now (no table yet, busy)."""
    if not os.path.exists(db_path):
        return None
    t0 = time.monotonic()
    try:
        con = sqlite3.connect(f"file:{db_path}?mode=ro", uri=True, timeout=5)
        try:
            n, size = con.execute("SELECT count(*), COALESCE(SUM(length(bytes)), 0) FROM checkpoint_pieces"
                                  " WHERE id = ?", (job,)).fetchone()
        finally:
            con.close()
    except sqlite3.Error:
        return None
    took = time.monotonic() - t0
    if took > 1.0:
        note(f"reading the stored checkpoint's size took {took:.2f} s", t0)
    return n, size


def job_state_bytes(plan, pixels):
    """common/engine/job_state.hpp's estimate for an image job, from its plan: K > 1
    replicates keep 3 x K float sums a pixel and a count a tile; K = 1, 3 tallies a pixel."""
    k, tiles = plan["sampler"]["replicates"], plan["image"]["tiles"]
    channels, sums = (0, 3 * k * pixels) if k > 1 else (3 * pixels, 0)
    return 2 * (channels * 24 + tiles * 8) + sums * (4 + 8)


def disk_bytes(directory):
    """Bytes the data dir's files take on disk (allocated blocks), assets excluded."""
    total = {}
    for name in os.listdir(directory):
        p = os.path.join(directory, name)
        if os.path.isfile(p):
            total[name] = os.stat(p).st_blocks * 512
    return total


# ---------------------------------------------------------------- EXR

def exr_header(path):
    with open(path, "rb") as f:
        head = f.read(1 << 16)
    if head[:4] != b"\x76\x2f\x31\x01":
        raise Failed(f"{path} is not an OpenEXR file")
    attrs, i = {}, 8
    while head[i] != 0:
        j = head.index(0, i)
        k = head.index(0, j + 1)
        name, typ = head[i:j].decode(), head[j + 1:k].decode()
        size = struct.unpack_from("<i", head, k + 1)[0]
        attrs[name] = (typ, head[k + 5:k + 5 + size])
        i = k + 5 + size
    channels = []
    raw = attrs["channels"][1]
    p = 0
    while raw[p] != 0:
        q = raw.index(0, p)
        channels.append((raw[p:q].decode(), struct.unpack_from("<i", raw, q + 1)[0]))
        p = q + 17  # name\0, pixel type, pLinear + 3 reserved, xSampling, ySampling
    x0, y0, x1, y1 = struct.unpack("<4i", attrs["dataWindow"][1])
    return {"attrs": attrs, "channels": channels, "window": (x0, y0, x1, y1), "header_end": i + 1,
            "compression": attrs["compression"][1][0]}


def exr_block(path, h, index):
    """Decodes scanline block `index` of a ZIP (16 lines) or uncompressed EXR of FLOAT
    channels: {channel: [floats of the block's pixels]}."""
    x0, y0, x1, y1 = h["window"]
    width, height = x1 - x0 + 1, y1 - y0 + 1
    lines = {0: 1, 3: 16}.get(h["compression"])
    if lines is None or any(t != 2 for _, t in h["channels"]):
        raise Failed(f"cannot decode compression {h['compression']} / channel types {h['channels']}")
    blocks = (height + lines - 1) // lines
    with open(path, "rb") as f:
        f.seek(h["header_end"] + 8 * index)
        offset = struct.unpack("<Q", f.read(8))[0]
        f.seek(offset)
        y, size = struct.unpack("<ii", f.read(8))
        data = f.read(size)
    n_lines = min(lines, y1 - y + 1)
    full = n_lines * width * 4 * len(h["channels"])
    if size < full:
        t = zlib.decompress(data)
        t = bytes(itertools.accumulate(t, lambda a, b: (a + b - 128) & 0xFF))  # undo the predictor
        half = (len(t) + 1) // 2
        out = bytearray(len(t))
        out[0::2], out[1::2] = t[:half], t[half:]  # undo the interleave
        data = bytes(out)
    assert len(data) == full, (len(data), full, blocks)
    per = {name: [] for name, _ in h["channels"]}
    at = 0
    for _ in range(n_lines):
        for name, _ in h["channels"]:
            per[name].extend(struct.unpack_from(f"<{width}f", data, at))
            at += 4 * width
    return per, blocks


# ---------------------------------------------------------------- the run

def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--build", default=os.path.join(ROOT, "build"))
    ap.add_argument("--server-bin", help="default: BUILD/server/tally-server")
    ap.add_argument("--client-bin", help="default: BUILD/client/tally")
    ap.add_argument("--resolution", default="3840x2160")
    ap.add_argument("--spp", type=int, default=16, help="stop: max_samples (samples a pixel)")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--checkpoint-interval", type=float, default=0.5)
    ap.add_argument("--kill-delay", type=float, default=0.0,
                    help="seconds after the checkpoint is stored before kill -9")
    ap.add_argument("--timeout", type=float, default=1800, help="bound on each wait (seconds)")
    ap.add_argument("--keep", action="store_true", help="keep the temp dir (data dir, logs, EXR)")
    ap.add_argument("--cluster", action="store_true",
                    help="cluster mode: redis-server on a Unix socket in the temp dir, tally-server --redis (the "
                         "coordinator, computing nothing itself) and one tally-worker --threads WORKERS, which "
                         "keeps running across the coordinator's kill -9 and restart")
    ap.add_argument("--worker-bin", help="default: BUILD/server/cluster/tally-worker (with --cluster)")
    ap.add_argument("--redis-bin", default="redis-server", help="redis-server (with --cluster)")
    a = ap.parse_args()
    server_bin = a.server_bin or os.path.join(a.build, "server", "tally-server")
    client_bin = a.client_bin or os.path.join(a.build, "client", "tally")
    a.worker_bin = a.worker_bin or os.path.join(a.build, "server", "cluster", "tally-worker")
    w, h = (int(v) for v in a.resolution.lower().split("x"))

    tmp = tempfile.mkdtemp(prefix="frame4k-")
    servers = []  # tally-server runs, killed with kill -9 at the end
    helpers = []  # with --cluster: redis-server, then tally-worker; stopped (SIGTERM, bounded) in reverse
    t_begin = time.monotonic()
    ok = False
    try:
        ok = run(a, server_bin, client_bin, w, h, tmp, servers, helpers, t_begin)
    except Failed as e:
        print(f"FAILED: {e}")
    finally:
        for s in servers:
            try:
                s.kill9()
            except Exception as e:  # noqa: BLE001 - keep killing the others
                print(f"(killing {s.name}: {e})")
        for p in reversed(helpers):
            try:
                p.stop()
            except Exception as e:  # noqa: BLE001 - keep stopping the others
                print(f"(stopping {p.name}: {e})")
        print("timeline (seconds after submit)")
        for at, what in sorted(TIMELINE):
            print(f"  {at - T0[0]:8.2f}  {what}")
        if not ok:
            for s in servers + helpers:
                print(f"--- tail of {s.log_path}")
                with open(s.log_path) as f:
                    print("".join(f.readlines()[-15:]), end="")
        if a.keep or not ok:
            print(f"kept {tmp}")
        else:
            shutil.rmtree(tmp, ignore_errors=True)
    return 0 if ok else 1


def run(a, server_bin, client_bin, w, h, tmp, servers, helpers, t_begin):
    assets = os.path.join(tmp, "assets")
    data = os.path.join(tmp, "data")
    subprocess.run([sys.executable, os.path.join(ROOT, "scripts", "gltf_example.py"), assets],
                   check=True, stdout=subprocess.DEVNULL, timeout=60)
    with open(os.path.join(ROOT, "examples", "gltf_cornell.json")) as f:
        spec = json.load(f)
    shape = next(s for s in spec["scene"]["shapes"] if s.get("type") == "gltf")
    shape["resolution"] = [w, h]
    spec["stop"] = {"max_samples": a.spp}
    spec_path = os.path.join(assets, "spec_frame.json")  # beside cornell.gltf: submit resolves it there
    with open(spec_path, "w") as f:
        json.dump(spec, f, indent=1)
    pixels = w * h
    load0 = os.getloadavg()
    mode = (f"cluster: redis-server on a Unix socket, tally-server --redis, one tally-worker --threads {a.workers}"
            if a.cluster else f"{a.workers} workers")
    print(f"frame_4k_e2e: examples/gltf_cornell.json at {w}x{h}, stop max_samples {a.spp}, "
          f"{mode}, --checkpoint-interval {a.checkpoint_interval}, data in {data}")

    redis = worker = redis_url = None
    if a.cluster:
        sock = os.path.join(tmp, "redis.sock")
        if len(sock) > 100:
            raise Failed(f"the Redis socket path {sock} is too long for a Unix socket: set a shorter TMPDIR")
        if not shutil.which(a.redis_bin):
            raise Failed(f"{a.redis_bin} not found (Debian: apt-get install redis-server)")
        redis = Redis(a.redis_bin, sock, os.path.join(tmp, "redis.log"))
        helpers.append(redis)
        redis.wait_ready()
        redis_url = "unix://" + sock

    # ---- run 1: submit, wait for a stored checkpoint mid-way, kill -9
    def start(name):  # a server on the same data dir; killed in the finally below
        srv = Server(name, server_bin, data, a.workers, a.checkpoint_interval, os.path.join(tmp, f"{name}.log"),
                     redis_url)
        servers.append(srv)
        srv.wait_ready()
        return srv

    s1 = start("run1")
    if a.cluster:  # one worker for the whole job: it keeps running across the coordinator's restart
        worker = Proc("worker", [a.worker_bin, "--redis", redis_url, "--threads", str(a.workers), "--name", "w1",
                                 "--cache-dir", os.path.join(tmp, "worker-cache")], os.path.join(tmp, "worker.log"))
        helpers.append(worker)
    t_submit = time.monotonic()
    T0[0] = t_submit
    sub = subprocess.run([client_bin, "submit", "--no-predict", spec_path, "--server", s1.url],
                         capture_output=True, text=True, timeout=300)
    if sub.returncode != 0:
        raise Failed(f"tally submit: exit {sub.returncode}: {sub.stderr.strip()}")
    job = sub.stdout.strip().splitlines()[-1]
    note(f"submitted {job}")
    print(f"submitted job {job} ({sub.stderr.strip()}) in {time.monotonic() - t_submit:.2f} s")

    db = os.path.join(data, "tally.db")
    state_bytes = [0.0]
    last = {}
    commits = {"run1": [], "run2": []}  # when a new stored checkpoint was first seen (polled)

    def track(server, st):
        now = (st["state"], st.get("samples", 0), st.get("passes", 0))
        if last.get(server.name) != now:
            last[server.name] = now
            note(f"{server.name}: status {now[0]}, {now[1]} spp, {now[2]} passes")
        got = stored_checkpoint(db, job)
        if got is None:
            return
        n, size = got
        if last.get(server.name + "ckpt") != (n, size):
            last[server.name + "ckpt"] = (n, size)
            note(f"{server.name}: stored checkpoint {n} pieces, {size / MB:.1f} MB")
            if n > 0:
                commits[server.name].append(time.monotonic())

    def spool_lines(server):
        out = []
        for i, (start, end, size) in enumerate(server.spools):
            seen = next((c for c in commits[server.name] if c >= start and (end is None or c <= end + 0.5)), None)
            line = f"  checkpoint {i + 1}: spool opened {start - t_submit:.1f} s after submit, {fmt_bytes(size)}"
            if seen is not None:
                line += (f"; stored (its pieces visible, polled every 0.2 s) {seen - start:.2f} s later "
                         f"({size / MB / max(seen - start, 1e-9):.0f} MB/s)")
            else:
                line += "; never seen stored"
            line += (f"; spool closed {end - start:.2f} s after it opened (+ SQLite's WAL checkpoint)"
                     if end is not None else "; still open at the kill")
            out.append(line)
        return out

    def helpers_alive():
        for p in helpers:
            if not p.alive():
                raise Failed(f"{p.name} exited with {p.proc.returncode}; see {p.log_path}")

    cluster_at = {}  # with --cluster: what the helpers and /v1/workers say at the kill and at the job's end

    def cluster_figures(server, when):
        if not a.cluster:
            return
        helpers_alive()
        try:
            workers = json.loads(server.get("/v1/workers"))
        except (OSError, ValueError) as e:
            workers = {"error": str(e)}
        cluster_at[when] = {"worker_kb": worker.peak_rss_kb(), "redis_kb": redis.peak_rss_kb(),
                            "redis_info": redis.info("memory"), "workers": workers}

    def checkpoint_mid_way():
        helpers_alive()
        st = s1.status(job)
        track(s1, st)
        if st["state"] not in ("queued", "running"):
            raise Failed(f"the job ended ({st['state']}, {st.get('samples')} samples) before a checkpoint was "
                         "seen mid-way")
        used = s1.metric("tally_memory_used_bytes")
        if used:
            state_bytes[0] = max(state_bytes[0], used)
        n, size = stored_checkpoint(db, job) or (0, 0)
        if n > 0 and size > 0 and st["state"] == "running" and st.get("samples", 0) < a.spp:
            return n, size
        return None

    pieces, ckpt_bytes = wait_for("a stored checkpoint while the job runs", a.timeout, 0.2, checkpoint_mid_way)
    t_ckpt_seen = time.monotonic() - t_submit
    time.sleep(a.kill_delay)
    st = s1.status(job)
    if st["state"] != "running" or st.get("samples", 0) >= a.spp:
        raise Failed(f"the job is {st['state']} at {st.get('samples')} spp at the kill")
    samples_at_kill, passes_at_kill = st.get("samples", 0), st.get("passes", 0)
    pieces, ckpt_bytes = stored_checkpoint(db, job) or (pieces, ckpt_bytes)  # the one the restart will read
    peak1 = s1.peak_rss_kb()
    cluster_figures(s1, "kill")
    disk1 = disk_bytes(data)
    t_kill = time.monotonic() - t_submit
    s1.kill9()
    note("run1: kill -9")
    print(f"kill -9 at {t_kill:.1f} s after submit (checkpoint seen at {t_ckpt_seen:.1f} s): "
          f"job at {samples_at_kill} spp, {passes_at_kill} passes")

    # ---- run 2: restart on the same data dir, resume, finish
    s2 = start("run2")
    hwm_ready2 = s2.peak_rss_kb()
    note(f"run2: ready (port file written) after {s2.ready_s:.2f} s")
    first = s2.status(job)
    resumed_lines = s2.log_lines("resumes from its checkpoint", "recovered ")
    resumed_samples = None
    for line in resumed_lines:
        if "resumes from its checkpoint (" in line:
            resumed_samples = int(line.split("resumes from its checkpoint (")[1].split()[0])
    print(f"restarted: ready in {s2.ready_s:.2f} s; status: {first['state']}, {first.get('samples', 0)} spp, "
          f"{first.get('passes', 0)} passes; log: {' | '.join(l.split(' info ', 1)[-1] for l in resumed_lines)}")
    if not resumed_samples or first.get("samples", 0) <= 0:
        raise Failed(f"the job did not resume from its checkpoint (log: {resumed_samples} samples, status "
                     f"{first.get('samples')} samples)")

    def done():
        helpers_alive()
        st = s2.status(job)
        track(s2, st)
        used = s2.metric("tally_memory_used_bytes")
        if used:
            state_bytes[0] = max(state_bytes[0], used)
        if st["state"] in ("queued", "running"):
            return None
        return st

    final = wait_for("the resumed job to finish", a.timeout, 0.5, done)
    t_done = time.monotonic() - t_submit
    hwm_done2 = s2.peak_rss_kb()
    cluster_figures(s2, "end")
    if final["state"] != "succeeded":
        raise Failed(f"the job ended {final['state']}: {final.get('error_message')}")
    # The final save (with its checkpoint) is stored before the job reads as finished;
    # wait for its spool to be gone, for the spool figures.
    wait_for("the final checkpoint's spool to close", 60, 0.1,
             lambda: True if not (s2.spools and s2.spools[-1][1] is None) else None)
    final_pieces, final_ckpt = wait_for("the stored checkpoint", 60, 0.5, lambda: stored_checkpoint(db, job))

    # ---- the EXR
    exr = os.path.join(tmp, "frame.exr")
    t0 = time.monotonic()
    with urllib.request.urlopen(f"{s2.url}/v1/jobs/{job}/image.exr", timeout=a.timeout) as r, open(exr, "wb") as f:
        shutil.copyfileobj(r, f, 1 << 20)
    t_exr = time.monotonic() - t0
    hwm_exr2 = s2.peak_rss_kb()
    cluster_figures(s2, "exr")
    worker_exit = redis_exit = None
    if a.cluster:  # both ran the whole job; their peaks are read above, while they live
        worker_exit = worker.stop()
        redis_exit = redis.stop()
    exr_bytes = os.path.getsize(exr)
    hd = exr_header(exr)
    x0, y0, x1, y1 = hd["window"]
    names = [n for n, _ in hd["channels"]]
    problems = []
    if (x1 - x0 + 1, y1 - y0 + 1) != (w, h):
        problems.append(f"dataWindow {hd['window']} is not {w}x{h}")
    for need in ("R", "G", "B", "StdErr.R", "StdErr.G", "StdErr.B", "SampleCount"):
        if need not in names:
            problems.append(f"no {need} channel")
    counts = set()
    if not problems:
        _, blocks = exr_block(exr, hd, 0)
        for b in sorted({0, blocks // 2, blocks - 1}):
            per, _ = exr_block(exr, hd, b)
            counts |= set(per["SampleCount"])
            if any(v != v for v in per["R"] + per["StdErr.R"]) or min(per["StdErr.R"]) < 0:
                problems.append(f"block {b}: a NaN mean or a negative StdErr")
        if counts != {float(a.spp)}:
            problems.append(f"SampleCount values {sorted(counts)[:5]}, expected {a.spp}")
    t_total = time.monotonic() - t_begin

    # ---- figures
    used = int(state_bytes[0])
    jsb = job_state_bytes(final["plan"], pixels)
    log1 = s1.log_lines("abandoned")
    print()
    print(f"job {job}: {w}x{h} = {pixels:,} pixels, {final['samples']} spp in {final['passes']} passes, "
          f"stop_reason {final['stop_reason']}; trace (compute s, spp): "
          f"{[(round(t[0], 1), t[1]) for t in final.get('trace', [])]}")
    print(f"job_state_bytes (from the plan: {final['plan']['sampler']['replicates']} replicates, "
          f"{final['plan']['image']['tiles']} tiles): {fmt_bytes(jsb)}, {jsb / pixels:.1f} B/pixel; "
          f"tally_memory_used_bytes while it ran (the state and the scene the budget charges): {fmt_bytes(used)}")
    print()
    role = "the coordinator, tally-server --redis" if a.cluster else "tally-server"
    print(f"run 1 (killed; {role})")
    print(f"  peak RSS (VmHWM just before kill -9): {peak1 * 1024:,} B ({peak1 / 1024:.1f} MiB), "
          f"{peak1 * 1024 / pixels:.1f} B/pixel")
    print(f"  checkpoint stored: {pieces} pieces, {fmt_bytes(ckpt_bytes)}, {ckpt_bytes / pixels:.1f} B/pixel")
    print("  data dir on disk at the kill: " + ", ".join(f"{k} {v / MB:.1f} MB" for k, v in sorted(disk1.items()))
          + f"; total {sum(disk1.values()) / MB:.1f} MB")
    print("\n".join(spool_lines(s1)))
    if log1:
        print("  " + "\n  ".join(l.split(' info ', 1)[-1] for l in log1))
    print(f"  samples at kill: {samples_at_kill} spp, {passes_at_kill} passes (status); the work since the stored "
          "checkpoint is lost" + ("; a later save (the next checkpoint or the final one) was being written at the kill"
                                  if s1.spools and s1.spools[-1][1] is None else ""))
    print()
    print(f"run 2 (restarted on the same data dir{' and Redis' if a.cluster else ''}; {role})")
    print(f"  ready (recovery: checkpoint read back) in {s2.ready_s:.2f} s; VmHWM then {hwm_ready2 / 1024:.1f} MiB")
    print(f"  samples at resume: {resumed_samples} spp (server log), status {first.get('samples')} spp, "
          f"{first.get('passes')} passes -> resumed, not restarted from 0: yes"
          + ("" if resumed_samples == samples_at_kill else f" (but not at the {samples_at_kill} spp seen at the kill)"))
    print(f"  peak RSS: {hwm_done2 * 1024:,} B ({hwm_done2 / 1024:.1f} MiB) at the job's end, "
          f"{hwm_exr2 * 1024:,} B ({hwm_exr2 / 1024:.1f} MiB) after the EXR GET")
    print("\n".join(spool_lines(s2)))
    print(f"  final stored checkpoint: {final_pieces} pieces, {fmt_bytes(final_ckpt)}")
    print()
    print(f"EXR: {fmt_bytes(exr_bytes)} ({exr_bytes / pixels:.1f} B/pixel) in {t_exr:.1f} s; dataWindow "
          f"{hd['window']} -> {x1 - x0 + 1}x{y1 - y0 + 1}; compression {hd['compression']}; channels {names}; "
          f"SampleCount in 3 decoded blocks: {sorted(counts)}")
    print(f"wall: submit to succeeded {t_done:.1f} s (kill at {t_kill:.1f} s; job compute_seconds "
          f"{final.get('compute_seconds', 0):.1f} after the resume, wall_seconds {final['timing'].get('wall_seconds', 0):.1f}); "
          f"whole script {t_total:.1f} s; load average at start {load0[0]:.2f}, at end {os.getloadavg()[0]:.2f} "
          f"({os.cpu_count()} CPUs)")
    print()
    if a.cluster:
        print()
        print("cluster (the worker and redis-server ran from before the submit to the end, across the restart)")
        for when, what in (("kill", "at the kill"), ("end", "at the job's end"), ("exr", "after the EXR GET")):
            c = cluster_at[when]
            info = c["redis_info"]
            used, used_peak = int(info.get("used_memory", 0)), int(info.get("used_memory_peak", 0))
            print(f"  {what}: tally-worker VmHWM {c['worker_kb'] * 1024:,} B ({c['worker_kb'] / 1024:.1f} MiB); "
                  f"redis-server VmHWM {c['redis_kb'] * 1024:,} B ({c['redis_kb'] / 1024:.1f} MiB), its "
                  f"used_memory {fmt_bytes(used)}, used_memory_peak {fmt_bytes(used_peak)}")
            wk = c["workers"]
            if "results" in wk:
                print(f"    /v1/workers: results {wk['results']}; workers "
                      f"{[(x['name'], x['threads'], x['blocks_done']) for x in wk.get('workers', [])]}")
            else:
                print(f"    /v1/workers: {wk}")
        print(f"  stopped with SIGTERM: tally-worker exit {worker_exit}, redis-server exit {redis_exit}")
    print("ratios")
    if jsb:
        print(f"  peak RSS / job_state_bytes: run 1 {peak1 * 1024 / jsb:.2f}, run 2 {hwm_done2 * 1024 / jsb:.2f} "
              f"(job end), {hwm_exr2 * 1024 / jsb:.2f} (after the EXR)")
        if a.cluster:
            c = cluster_at["exr"]
            used_peak = int(c["redis_info"].get("used_memory_peak", 0))
            print(f"  tally-worker peak RSS / job_state_bytes: {c['worker_kb'] * 1024 / jsb:.3f} (whole job)")
            print(f"  redis-server peak RSS / job_state_bytes: {c['redis_kb'] * 1024 / jsb:.3f}; its "
                  f"used_memory_peak / job_state_bytes: {used_peak / jsb:.3f} (whole job)")
        print(f"  checkpoint / job_state_bytes: {ckpt_bytes / jsb:.3f}")
    k = final["plan"]["sampler"]["replicates"]
    print(f"  checkpoint / state floats (3 x {k} replicates x 4 B a pixel = {3 * k * 4 * pixels:,} B): "
          f"{ckpt_bytes / (3 * k * 4 * pixels):.3f}")
    print(f"  EXR / pixels: {exr_bytes / pixels:.1f} B; EXR / checkpoint: {exr_bytes / ckpt_bytes:.3f}")
    print(f"  samples kept by the checkpoint: {resumed_samples} of {final['samples']} spp "
          f"({resumed_samples / final['samples']:.0%})")
    if problems:
        raise Failed("; ".join(problems))
    print("ok")
    return True


if __name__ == "__main__":
    sys.exit(main())
