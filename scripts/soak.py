#!/usr/bin/env python3
"""Soak test of tally-server (on demand; not part of `make test`; docs/soak.md).

Several tenants (an auth file: admin, two users, a user with a queue quota of 0, a
reader) send mixed traffic at a fixed rate while the server is killed with SIGKILL every
--kill-every seconds and restarted on the same data dir:

- normal: submit (Monte Carlo, QMC, quadrature, a small lighting image job whose lamp is
  an uploaded OBJ), watch (event stream), cancel, extend, validate, status, list;
- hostile, each with the status it must get (issue 27's probe): uploaded scene files
  over the readers' limits (deep glTF JSON, too many glTF nodes or primitives, OBJ with
  too many material groups, a long polygon, NaN and huge indices, an EXR with 64
  channels or a string attribute declaring 1.76 GB, a 9000^2 PNG texture), another
  tenant's asset named inside a glTF or OBJ, another tenant's job ids, extend past
  max_queued_jobs, a login flood, duplicate / missing / foreign Host, NaN, 1e400,
  malformed JSON, unknown fields, a depth bomb, smuggling framing, no or a bad token,
  writes by the reader.

Checks (exit status 1 if any fails): the server never dies but by our kill; no
acknowledged (202) job is lost; every job seen succeeded keeps its result bit for bit
(checked after every restart and at the end, unless we extended it); a few finished
deterministic jobs equal `tally run` of the same spec, bit for bit; no tenant sees
another's job; every hostile request gets its expected status; RSS stays under --rss-bound-mb.

Usage: scripts/soak.py [--build build] [--duration 1800] [--rate 10] [--kill-every 180] [--seed 1]
"""
import argparse
import base64
import collections
import hashlib
import http.client
import importlib.util
import json
import os
import random
import re
import secrets
import shutil
import signal
import socket
import struct
import subprocess
import sys
import tempfile
import threading
import time

HERE = os.path.dirname(os.path.abspath(__file__))
_spec = importlib.util.spec_from_file_location("scene_seeds", os.path.join(HERE, "..", "tests", "fuzz", "make_scene_seeds.py"))
seeds = importlib.util.module_from_spec(_spec)  # the hostile scene files of the fuzz corpus
_spec.loader.exec_module(seeds)

# Scene-file limits of the soak's server, small so that small files cross them.
SERVER_LIMITS = ["--max-shapes", "8", "--max-gltf-nodes", "1024"]


def rss_kb(pid):
    try:
        with open(f"/proc/{pid}/status") as f:
            for line in f:
                if line.startswith("VmRSS:"):
                    return int(line.split()[1])
    except OSError:
        pass
    return None


def new_token():
    return "tly_" + base64.urlsafe_b64encode(secrets.token_bytes(32)).rstrip(b"=").decode()


def sha(b):
    return hashlib.sha256(b).hexdigest()


class Tenant:
    def __init__(self, name, role, quotas=None):
        self.name, self.role, self.quotas, self.token = name, role, quotas, new_token()

    def entry(self):
        e = {"name": self.name, "role": self.role, "token_sha256": sha(self.token.encode())}
        if self.quotas:
            e["quotas"] = self.quotas
        return e


class Server:
    def __init__(self, binary, data_dir, workdir, extra):
        self.binary, self.data_dir, self.workdir, self.extra = binary, data_dir, workdir, extra
        self.proc = None
        self.port = None
        self.starts = 0

    def start(self):
        port_file = os.path.join(self.workdir, "port")
        if os.path.exists(port_file):
            os.remove(port_file)
        log = open(os.path.join(self.workdir, f"server-{self.starts}.log"), "w")
        self.proc = subprocess.Popen(
            [self.binary, "--listen", "127.0.0.1:0", "--port-file", port_file, "--data-dir", self.data_dir,
             "--workers", "2", "--checkpoint-interval", "0.2", "--max-body", "65536"] + self.extra,
            stdout=log, stderr=subprocess.STDOUT)
        self.starts += 1
        deadline = time.time() + 60
        while time.time() < deadline:
            if os.path.exists(port_file):
                with open(port_file) as f:
                    txt = f.read().strip()
                if txt:
                    self.port = int(txt)
                    break
            if self.proc.poll() is not None:
                raise RuntimeError(f"server exited with {self.proc.returncode} at start")
            time.sleep(0.05)
        while time.time() < deadline:
            try:
                if request(self.port, "GET", "/readyz", timeout=2)[0] == 200:
                    return
            except OSError:
                pass
            time.sleep(0.05)
        raise RuntimeError("server not ready within 60 s")

    def kill9(self):
        self.proc.send_signal(signal.SIGKILL)
        return self.proc.wait()

    def stop(self):
        self.proc.send_signal(signal.SIGTERM)
        try:
            return self.proc.wait(timeout=30)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            return -1


def request(port, method, path, body=None, headers=None, timeout=10, token=None):
    c = http.client.HTTPConnection("127.0.0.1", port, timeout=timeout)
    try:
        h = dict(headers or {})
        if token:
            h["Authorization"] = "Bearer " + token
        if body is not None and "Content-Type" not in h:
            h["Content-Type"] = "application/json"
        c.request(method, path, body=body, headers=h)
        r = c.getresponse()
        return r.status, r.read()
    finally:
        c.close()


def raw(port, data, timeout=5):
    s = socket.create_connection(("127.0.0.1", port), timeout=timeout)
    try:
        s.sendall(data)
        out = b""
        while True:
            try:
                b = s.recv(65536)
            except ConnectionResetError:
                break
            if not b:
                break
            out += b
        return out
    finally:
        s.close()


# ---- job specs ------------------------------------------------------------------------

def lamp_obj(rows):
    """A 1x1 emitting square at z = 1.5 facing down, in `rows` strips (tests/assets)."""
    out = ""
    for i in range(rows + 1):
        y = -0.5 + i / rows
        out += f"v -0.5 {y} 1.5\nv 0.5 {y} 1.5\n"
    for i in range(rows):
        a = 2 * i + 1
        out += f"f {a} {a + 2} {a + 3}\nf {a} {a + 3} {a + 1}\n"
    return out.encode()


def lighting_spec(seed, shape, lights=None, materials=None):
    """A 16x12 image of a floor and `shape` (None: the floor alone), 16 samples a pixel."""
    mats = {"floor": {"type": "diffuse", "albedo": [0.8, 0.8, 0.8]}, "lamp": {"type": "emissive", "radiance": [4, 4, 4]}}
    mats.update(materials or {})
    shapes = [{"type": "quad", "corner": [-2, -2, 0], "edge_u": [4, 0, 0], "edge_v": [0, 4, 0], "material": "floor"}]
    if shape:
        shapes.append(shape)
    scene = {"camera": {"position": [0, -3, 0.75], "look_at": [0, 0, 0.75], "up": [0, 0, 1], "fov_deg": 60,
                        "resolution": [16, 12]},
             "materials": mats, "shapes": shapes}
    if lights:
        scene["lights"] = lights
    return {"kind": "lighting", "seed": seed, "scene": scene, "query": {"type": "image", "max_depth": 2},
            "estimators": ["mis"], "stop": {"max_samples": 16}}


def obj_shape(data):
    return {"type": "mesh", "obj": "sha256:" + sha(data), "material": "lamp"}


def gltf_shape(data):
    return {"type": "gltf", "file": "sha256:" + sha(data)}


def sky(data):
    return [{"type": "sky", "map": "sha256:" + sha(data), "intensity": 2}]


def job_spec(rng, lamp):
    """A normal job. `deterministic`: stopped by a sample count alone, so `tally run` of
    the same spec gives the same bits."""
    kind = rng.random()
    seed = rng.randrange(1, 10**6)
    if kind < 0.4:
        return {"kind": "integrate", "seed": seed, "integrand": {"builtin": "unit_disk"},
                "stop": {"max_samples": rng.choice([200000, 2000000, 10000000])}}, True
    if kind < 0.6:
        return {"kind": "integrate", "seed": seed, "integrand": {"expression": "exp(-x0*x0) * cos(x1)"},
                "domain": {"type": "box", "lower": [0, 0], "upper": [1, 1]},
                "estimator": {"type": "qmc", "points": 1024}, "stop": {"rel_error": 1e-6, "time_budget_s": 0.5}}, False
    if kind < 0.8:
        return {"kind": "integrate", "seed": seed, "integrand": {"expression": "x0 * x1 + sin(x0)"},
                "domain": {"type": "box", "lower": [0, 0], "upper": [1, 1]},
                "estimator": {"type": "quadrature", "points_per_dim": rng.choice([65, 513, 2049])},
                "stop": {"max_samples": 1}}, True
    return lighting_spec(seed, obj_shape(lamp)), True


# ---- hostile files (issue 27, N1-N5, N14), each a few KB ------------------------------

def hostile_files():
    """name -> bytes of scene files over the soak server's limits, and the spec naming each."""
    f = {}
    f["deep.gltf"] = b'{"asset":{"version":"2.0"},"extras":' + b"[" * 3000 + b"]" * 3000 + b"}"  # N1
    f["nodes.gltf"] = b'{"asset":{"version":"2.0"},"nodes":[' + b",".join([b"{}"] * 1100) + b"]}"  # N2, > 1024
    doc, bin_ = seeds.shared_accessor(200, 16)  # N2: 16 primitives sharing one accessor, > max_shapes 8
    f["shared.glb"] = seeds.glb(dict(doc, buffers=[{"byteLength": len(bin_)}]), bin_)
    verts = "".join("v %d %d 0\n" % (i, i % 5) for i in range(60))
    f["groups.obj"] = (verts + "".join("usemtl m%d\nf %d %d %d\n" % (g, 3 * g + 1, 3 * g + 2, 3 * g + 3)
                                       for g in range(16))).encode()  # N2: 16 material groups > 8
    f["polygon.obj"] = ("".join("v %d %d 0\n" % (i % 17, i // 17) for i in range(300)) + "f " +
                        " ".join(str(i + 1) for i in range(300)) + "\n").encode()  # N4: 300 corners > 256
    f["nan.obj"] = b"v nan 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n"  # N14
    f["index.obj"] = b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 99999999999999999999\n"  # N14
    f["channels.exr"] = seeds.exr(2, 1, ["c%02d" % i for i in range(64)])  # N3: 64 channels > 8
    f["attribute.exr"] = seeds.exr(2, 2, ["R", "G", "B"], b"comments\0string\0" + struct.pack("<i", 1760000000) + b"x")
    f["big.png"] = seeds.png(9000, 9000, ihdr_only=True)  # N3: 9000^2 RGBA, 1.9 GB to decode > 1 GiB
    f["big.mtl"] = b"newmtl t\nKd 1 1 1\nmap_Kd sha256:" + sha(f["big.png"]).encode() + b"\n"
    f["textured.obj"] = (b"mtllib sha256:" + sha(f["big.mtl"]).encode() +
                         b"\nv 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nvt 1 0\nvt 0 1\nusemtl t\nf 1/1 2/2 3/3\n")
    specs = {
        "N1 deep glTF JSON": lighting_spec(1, gltf_shape(f["deep.gltf"])),
        "N2 glTF nodes": lighting_spec(1, gltf_shape(f["nodes.gltf"])),
        "N2 glTF primitives sharing an accessor": lighting_spec(1, gltf_shape(f["shared.glb"])),
        "N2 OBJ material groups": lighting_spec(1, obj_shape(f["groups.obj"])),
        "N4 OBJ long polygon": lighting_spec(1, obj_shape(f["polygon.obj"])),
        "N14 OBJ nan": lighting_spec(1, obj_shape(f["nan.obj"])),
        "N14 OBJ huge index": lighting_spec(1, obj_shape(f["index.obj"])),
        "N3 EXR 64 channels": lighting_spec(1, None, sky(f["channels.exr"])),
        "N3 EXR huge attribute": lighting_spec(1, None, sky(f["attribute.exr"])),
        "N3 PNG 9000^2 texture": lighting_spec(1, obj_shape(f["textured.obj"])),
    }
    del specs["N3 PNG 9000^2 texture"]["scene"]["shapes"][1]["material"]  # the OBJ's own material
    return f, specs


def nested_foreign(other_bin, other_mtl):
    """N5: a glTF whose buffer and an OBJ whose mtllib are another tenant's assets."""
    doc = {"asset": {"version": "2.0"},
           "buffers": [{"byteLength": len(other_bin), "uri": "sha256:" + sha(other_bin)}],
           "bufferViews": [{"buffer": 0, "byteOffset": 0, "byteLength": 36}],
           "accessors": [{"bufferView": 0, "componentType": 5126, "count": 3, "type": "VEC3",
                          "min": [-1, -1, 1.5], "max": [1, 1, 1.5]}],
           "meshes": [{"primitives": [{"attributes": {"POSITION": 0}}]}], "nodes": [{"mesh": 0}],
           "scenes": [{"nodes": [0]}], "scene": 0}
    gltf = json.dumps(doc).encode()
    obj = b"mtllib sha256:" + sha(other_mtl).encode() + b"\nusemtl glow\n" + lamp_obj(1)
    obj_spec = lighting_spec(1, obj_shape(obj))
    del obj_spec["scene"]["shapes"][1]["material"]
    return {"glTF": (gltf, lighting_spec(1, gltf_shape(gltf))), "OBJ": (obj, obj_spec)}


def plain_spec(rng):
    return {"kind": "integrate", "seed": rng.randrange(1, 10**6), "integrand": {"builtin": "unit_disk"},
            "stop": {"max_samples": 100000}}


def result_of(status):
    """What must stay bit-identical in a finished job's status: its result bits and estimate
    (integrate), or its result section (lighting)."""
    keep = {k: status[k] for k in ("bits", "estimate", "result", "samples", "passes", "stop_reason") if k in status}
    return json.dumps(keep, sort_keys=True)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--build", default="build")
    ap.add_argument("--duration", type=float, default=1800)
    ap.add_argument("--rate", type=float, default=10, help="requests per second")
    ap.add_argument("--kill-every", type=float, default=180)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--memory-budget-mib", type=int, default=256, help="the server's --memory-budget")
    ap.add_argument("--rss-bound-mb", type=float, default=0,
                    help="fail when the server's RSS passes this (default: memory budget + 256 MB)")
    ap.add_argument("--rerun", type=int, default=6, help="finished deterministic jobs to compare with `tally run`")
    ap.add_argument("--keep", action="store_true", help="keep the data dir and logs")
    a = ap.parse_args()
    rss_bound_kb = 1000 * (a.rss_bound_mb or (a.memory_budget_mib * 1.048576 + 256))
    binary = os.path.join(a.build, "server", "tally-server")
    cli = os.path.join(a.build, "client", "tally")
    work = tempfile.mkdtemp(prefix="tally-soak-")
    rng = random.Random(a.seed)

    admin, ann, bob = Tenant("root", "admin"), Tenant("ann", "user"), Tenant("bob", "user")
    carol = Tenant("carol", "user", {"max_running_jobs": 1, "max_queued_jobs": 0})
    rex = Tenant("rex", "reader")
    tenants = [admin, ann, bob, carol, rex]
    users = [ann, bob]
    auth = os.path.join(work, "auth.json")
    with open(auth, "w") as f:
        json.dump({"principals": [t.entry() for t in tenants]}, f)
    srv = Server(binary, os.path.join(work, "data"), work,
                 ["--auth-file", auth, "--memory-budget", f"{a.memory_budget_mib}MiB"] + SERVER_LIMITS)
    srv.start()
    try:
        return soak(a, srv, work, cli, rng, tenants, rss_bound_kb)
    finally:
        if srv.proc.poll() is None:
            srv.proc.kill()
            srv.proc.wait()
        if not a.keep:
            shutil.rmtree(work, ignore_errors=True)
        else:
            print("kept", work, file=sys.stderr)


def soak(a, srv, work, cli, rng, tenants, rss_bound_kb):
    admin, ann, bob, carol, rex = tenants
    users = [ann, bob]
    counts = collections.Counter()       # requests by kind
    statuses = collections.Counter()     # "kind status" -> n
    errors = collections.Counter()       # what fails the soak (and connection errors during restarts)
    mismatches = []                      # first hostile answers with the wrong status
    leaks = []                           # cross-tenant answers that were not 404 / lists with foreign ids
    idle = collections.Counter()         # not errors
    lock = threading.Lock()
    restarting = threading.Event()
    owner = {}            # job id -> tenant that got its 202
    spec_of = {}          # job id -> (spec, deterministic)
    deleted = set()       # ids our DELETE may have removed (204, or no answer)
    extended = set()      # ids we extended (their result may change; they may run again)
    results = {}          # job id -> result_of(status) once seen succeeded (not extended since)
    changed = []          # (id, before, after)
    gen = collections.Counter()  # job id -> extends started + finished (a status read across one is not recorded)
    kill_times = []
    rss = {"start": rss_kb(srv.proc.pid), "lives": [], "max": 0}

    def put_asset(t, data):
        st, body = request(srv.port, "PUT", "/v1/assets/sha256:" + sha(data), data,
                           {"Content-Type": "application/octet-stream"}, token=t.token)
        if st not in (200, 201):
            raise RuntimeError(f"asset upload by {t.name}: {st} {body[:200]}")

    # Setup: each user's lamp; ann's hostile files; bob's assets that ann's files name (N5).
    lamps = {t.name: lamp_obj(i + 1) for i, t in enumerate(users)}
    for t in users:
        put_asset(t, lamps[t.name])
    files, hostile_specs = hostile_files()
    for data in files.values():
        put_asset(ann, data)
    bob_bin = struct.pack("<9f", -1, -1, 1.5, 1, -1, 1.5, -1, 1, 1.5)
    bob_mtl = b"newmtl glow\nKd 0 0 0\nKe 4 4 4\n"
    for data in (bob_bin, bob_mtl):
        put_asset(bob, data)
    foreign = nested_foreign(bob_bin, bob_mtl)
    for data, _ in foreign.values():
        put_asset(ann, data)

    # carol: two finished jobs to extend, then one that runs for the whole soak, so that her
    # extend is always past max_queued_jobs 0 (N7).
    carol_done = []
    for s in (11, 12):  # one at a time: her queue holds none
        st, body = request(srv.port, "POST", "/v1/jobs", json.dumps(
            {"kind": "integrate", "seed": s, "integrand": {"builtin": "unit_disk"}, "stop": {"max_samples": 100000}}),
            token=carol.token)
        if st != 202:
            raise RuntimeError(f"carol's submit: {st} {body[:200]}")
        jid = json.loads(body)["id"]
        while json.loads(request(srv.port, "GET", f"/v1/jobs/{jid}", token=carol.token)[1])["state"] != "succeeded":
            time.sleep(0.1)
        carol_done.append(jid)
    # A slow integrand: 10^11 samples take hours at her share of the workers.
    st, body = request(srv.port, "POST", "/v1/jobs", json.dumps(
        {"kind": "integrate", "seed": 13, "domain": {"type": "box", "lower": [0, 0], "upper": [1, 1]},
         "integrand": {"expression": "sin(x0) * cos(x1) * exp(-x0 * x1) + sqrt(x0 + x1) * log(2 + x0)"},
         "stop": {"max_samples": 10**11}}), token=carol.token)
    if st != 202:
        raise RuntimeError(f"carol's long submit: {st} {body[:200]}")
    carol_forever = json.loads(body)["id"]

    admin_cookie, last_flood = [""], [0.0]

    def admin_login():
        """The admin's browser session, which a reader's login flood must not end (N8)."""
        c = http.client.HTTPConnection("127.0.0.1", srv.port, timeout=10)
        c.request("POST", "/v1/session", body=json.dumps({"token": admin.token}),
                  headers={"Content-Type": "application/json"})
        r = c.getresponse()
        r.read()
        c.close()
        if r.status != 200:
            raise RuntimeError(f"admin login: {r.status}")
        admin_cookie[0] = r.getheader("Set-Cookie").split(";")[0]

    admin_login()

    def carol_running():
        st, body = request(srv.port, "GET", f"/v1/jobs/{carol_forever}", token=carol.token)
        return st == 200 and json.loads(body)["state"] == "running"

    def queue_full(st, body):
        """503 with the server's queue full (--max-queued): the load's answer, not an error."""
        return st == 503 and b"the job queue is full" in body

    def count(kind, st):
        with lock:
            counts[kind] += 1
            statuses[f"{kind} {st}"] += 1

    def expect(kind, st, ok, body=b""):
        count(kind, st)
        if st not in ok:
            with lock:
                errors[f"{kind}: {st}, expected {sorted(ok)}"] += 1
                if len(mismatches) < 20:
                    mismatches.append(f"{kind}: {st} {body[:200]!r}")

    def classify_exc(e, op):
        return "connection (during restart)" if restarting.is_set() else f"{op}: {type(e).__name__}"

    def ids_of(t):
        with lock:
            return [i for i, o in owner.items() if o is t and i not in deleted]

    def record(jid, g0, status):
        """A status read: the job seen succeeded keeps its result from then on."""
        with lock:
            if status.get("state") != "succeeded" or gen[jid] != g0 or g0 % 2:
                return
            now = result_of(status)
            if jid in results and results[jid] != now:
                changed.append((jid, results[jid], now))
            results[jid] = now

    def watch(t, job_id, port):
        headers_in = False
        try:
            c = http.client.HTTPConnection("127.0.0.1", port, timeout=5)
            c.request("GET", f"/v1/jobs/{job_id}/events",
                      headers={"Accept": "text/event-stream", "Authorization": "Bearer " + t.token})
            r = c.getresponse()
            headers_in = True
            end = time.time() + rng.uniform(0.2, 2.0)
            while time.time() < end:
                if not r.read1(4096):
                    break
            c.close()
            count("watch", r.status)
            if r.status != 200 and not (r.status == 404 and job_id in deleted):
                with lock:
                    errors[f"watch {r.status}"] += 1
        except (OSError, http.client.HTTPException) as e:
            with lock:
                if headers_in and isinstance(e, TimeoutError) and not restarting.is_set():
                    counts["watch"] += 1
                    idle["watch: stream idle for 5 s after its headers (queued job)"] += 1
                else:
                    errors[classify_exc(e, "watch")] += 1

    def normal(op):
        port = srv.port
        t = rng.choice(users)
        ids = ids_of(t)
        if op == "submit":
            spec, det = job_spec(rng, lamps[t.name])
            st, body = request(port, "POST", "/v1/jobs", json.dumps(spec), token=t.token)
            count(op, st)
            if st == 202:
                jid = json.loads(body)["id"]
                with lock:
                    owner[jid], spec_of[jid] = t, (spec, det)
            elif not queue_full(st, body):
                with lock:
                    errors[f"submit {st}"] += 1
        elif op == "watch" and ids:
            threading.Thread(target=watch, args=(t, rng.choice(ids), port), daemon=True).start()
        elif op == "cancel" and ids:
            jid = rng.choice(ids)
            with lock:
                deleted.add(jid)  # until answered: a lost answer may have deleted it
            st, _ = request(port, "DELETE", f"/v1/jobs/{jid}", token=t.token)
            count(op, st)
            with lock:
                if st == 204:  # it had finished: deleted (docs/api.md)
                    results.pop(jid, None)
                elif st in (200, 202, 409):
                    deleted.discard(jid)
                else:
                    errors[f"cancel {st}"] += 1
        elif op == "extend" and ids:
            jid = rng.choice(ids)
            with lock:
                extended.add(jid)
                results.pop(jid, None)
                gen[jid] += 1
            try:
                st, body = request(port, "POST", f"/v1/jobs/{jid}/extend", json.dumps({"max_samples": 4000000}),
                                   token=t.token)
            finally:
                with lock:
                    gen[jid] += 1
            count(op, st)
            if st not in (202, 409) and not (st == 404 and jid in deleted) and not queue_full(st, body):
                with lock:
                    errors[f"extend {st}"] += 1
        elif op == "validate":
            st, body = request(port, "POST", "/v1/jobs/validate", json.dumps(job_spec(rng, lamps[t.name])[0]),
                               token=t.token)
            count(op, st)
            if st != 200 and not queue_full(st, body):
                with lock:
                    errors[f"validate {st}"] += 1
        elif op == "status" and ids:
            jid = rng.choice(ids)
            with lock:
                g0 = gen[jid]
            st, body = request(port, "GET", f"/v1/jobs/{jid}", token=t.token)
            count(op, st)
            if st == 200:
                record(jid, g0, json.loads(body))
            elif not (st == 404 and jid in deleted):
                with lock:
                    errors[f"status {st}"] += 1
        elif op == "list":
            st, body = request(port, "GET", "/v1/jobs?limit=1000", token=t.token)
            count(op, st)
            if st != 200:
                with lock:
                    errors[f"list {st}"] += 1
            else:
                with lock:
                    theirs = [j["id"] for j in json.loads(body)["jobs"] if owner.get(j["id"], t) is not t]
                    if theirs:
                        leaks.append(f"{t.name}'s list holds {theirs[:3]}")

    def hostile(kind):
        port = srv.port
        t = rng.choice(users)
        other = bob if t is ann else ann
        if kind == "scene file":
            name, spec = rng.choice(sorted(hostile_specs.items()))
            route = rng.choice(["/v1/jobs", "/v1/jobs/validate"])
            st, body = request(port, "POST", route, json.dumps(spec), token=ann.token)
            expect(name, st, {422}, body)
        elif kind == "nested foreign asset":  # N5
            name = rng.choice(sorted(foreign))
            st, body = request(port, "POST", rng.choice(["/v1/jobs", "/v1/jobs/validate"]),
                               json.dumps(foreign[name][1]), token=ann.token)
            expect(f"N5 another tenant's asset inside a {name}", st, {422}, body)
        elif kind == "foreign job":
            theirs = ids_of(other)
            if not theirs:
                return
            jid = rng.choice(theirs)
            m, p, b = rng.choice([("GET", f"/v1/jobs/{jid}", None), ("DELETE", f"/v1/jobs/{jid}", None),
                                  ("POST", f"/v1/jobs/{jid}/extend", '{"max_samples": 40000000}'),
                                  ("GET", f"/v1/jobs/{jid}/events", None)])
            st, body = request(port, m, p, b, token=t.token, timeout=5)
            count("another tenant's job", st)
            if st != 404:
                with lock:
                    leaks.append(f"{t.name} {m} {p}: {st} {body[:120]!r}")
            # The reader: not its job either (404); a write is 403 for any id, there or not.
            st, body = request(port, m, p, b, token=rex.token, timeout=5)
            count("another tenant's job (reader)", st)
            if st != (404 if m == "GET" else 403):
                with lock:
                    leaks.append(f"rex {m} {p}: {st} {body[:120]!r}")
        elif kind == "reader":
            st, body = request(port, "GET", "/v1/jobs", token=rex.token)
            expect("reader list", st, {200}, body)
            if st == 200 and json.loads(body)["jobs"]:
                with lock:
                    leaks.append(f"rex's list holds {[j['id'] for j in json.loads(body)['jobs']][:3]}")
            st, body = request(port, "POST", "/v1/jobs", json.dumps(plain_spec(rng)), token=rex.token)
            expect("reader submit", st, {403}, body)
        elif kind == "extend past max_queued":  # N7
            if not carol_running():
                idle["carol's extend skipped: her long job not running"] += 1
                return
            # The server's own queue being full comes first (503): then her quota is not tried.
            st, body = request(port, "POST", f"/v1/jobs/{rng.choice(carol_done)}/extend", '{"max_samples": 400000}',
                               token=carol.token)
            expect("N7 extend past max_queued_jobs", st, {403} | ({503} if queue_full(st, body) else set()), body)
            st, body = request(port, "POST", "/v1/jobs", json.dumps(plain_spec(rng)), token=carol.token)
            expect("N7 submit past max_queued_jobs", st, {403} | ({503} if queue_full(st, body) else set()), body)
        elif kind == "login flood":  # N8: 12 logins at once (the burst is 10), every 10 s at most
            with lock:
                if time.time() < last_flood[0] + 10:
                    return
                last_flood[0] = time.time()
            got = collections.Counter()
            for _ in range(12):
                st, body = request(port, "POST", "/v1/session", json.dumps({"token": rex.token}))
                expect("N8 login flood", st, {200, 429}, body)
                got[st] += 1
            if got[429] == 0:
                with lock:
                    errors["N8 login flood: 12 logins, none refused"] += 1
            st, body = request(port, "GET", "/v1/session", headers={"Cookie": admin_cookie[0]})
            expect("N8 the admin's session after a reader's login flood", st, {200}, body)
        elif kind == "host":  # N14
            tok = ("Authorization: Bearer " + t.token + "\r\n").encode()
            for what, head in [("duplicate Host", b"Host: 127.0.0.1\r\nHost: attacker.example\r\n"),
                               ("no Host", b"")]:
                out = raw(port, b"GET /v1/jobs HTTP/1.1\r\n" + head + tok + b"Connection: close\r\n\r\n")
                st = int(out[9:12]) if out.startswith(b"HTTP/1.1 ") else 0
                expect(f"N14 {what}", st, {400}, out)
            st, body = request(port, "GET", "/v1/jobs", headers={"Host": "attacker.example"})
            expect("N14 foreign Host without a token", st, {401}, body)
        elif kind == "bad spec":
            what, body_, ok = rng.choice([
                ("NaN in a spec", '{"kind": "integrate", "seed": NaN, "integrand": {"builtin": "unit_disk"}}', {400}),
                ("1e400 in a spec", '{"kind": "integrate", "integrand": {"builtin": "unit_disk"}, '
                                    '"stop": {"max_samples": 1e400}}', {400}),
                ("malformed JSON", "{not json", {400}),
                ("unknown field", '{"kind": "integrate", "bogus": 1, "integrand": {"builtin": "unit_disk"}, '
                                  '"stop": {"max_samples": 1000}}', {422}),
                ("depth bomb", "[" * 5000, {400}),
                ("0/0 integrand", '{"kind": "integrate", "integrand": {"expression": "0/0"}, '
                                  '"stop": {"max_samples": 1000}}', {422}),
            ])
            st, body = request(port, "POST", rng.choice(["/v1/jobs", "/v1/jobs/validate"]), body_, token=t.token)
            expect(what, st, ok, body)
        elif kind == "no token":
            st, body = request(port, "GET", "/v1/jobs", headers={})
            expect("no token", st, {401}, body)
            st, body = request(port, "GET", "/v1/jobs", token=new_token())
            expect("unknown token", st, {401}, body)
        elif kind == "method":
            st, body = request(port, "BREW", "/v1/jobs", token=t.token)
            expect("unknown method", st, {405}, body)
        elif kind == "smuggle":
            out = raw(port, b"POST /v1/jobs HTTP/1.1\r\nHost: 127.0.0.1\r\nTransfer-Encoding: chunked, identity\r\n\r\n"
                            b"GET /livez HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n")
            st = int(out[9:12]) if out.startswith(b"HTTP/1.1 ") and out.count(b"HTTP/1.1 ") == 1 else 0
            expect("smuggling framing (0: answered twice or not at all)", st, {400}, out)

    normal_ops = ["submit"] * 4 + ["watch"] * 2 + ["cancel", "extend", "validate", "list"] + ["status"] * 4
    hostile_ops = ["scene file"] * 4 + ["nested foreign asset", "foreign job", "foreign job", "reader",
                                        "extend past max_queued", "host", "bad spec", "bad spec", "no token",
                                        "method", "smuggle"]
    ops = [("n", o) for o in normal_ops] + [("h", o) for o in hostile_ops] + [("h", "login flood")]

    def one(op):
        side, name = op
        try:
            (normal if side == "n" else hostile)(name)
        except (OSError, http.client.HTTPException) as e:
            with lock:
                errors[classify_exc(e, name)] += 1

    def check_results(when):
        """Every job seen succeeded still reads so, with the same result."""
        with lock:
            snap = [(j, r, gen[j]) for j, r in results.items() if j not in deleted]
        missing = 0
        for jid, before, g0 in snap:
            try:
                st, body = request(srv.port, "GET", f"/v1/jobs/{jid}", token=owner[jid].token, timeout=30)
            except (OSError, http.client.HTTPException) as e:
                with lock:
                    errors[f"check of finished jobs {when}: {type(e).__name__}"] += 1
                continue
            if st == 404:
                missing += 1
                with lock:
                    errors[f"finished job missing {when}"] += 1
                continue
            record(jid, g0, json.loads(body))
        return len(snap), missing

    crashes = []
    checks_after_restart = []
    t0 = time.time()
    next_kill = t0 + a.kill_every
    kill_bait = [False]
    period = 1.0 / a.rate
    tick = t0
    pool = []
    life = {"start_kb": rss["start"], "steady_kb": None, "max_kb": rss["start"], "t": t0}
    next_rss = t0
    while time.time() - t0 < a.duration:
        now = time.time()
        if now >= next_rss:
            kb = rss_kb(srv.proc.pid) or 0
            life["max_kb"] = max(life["max_kb"], kb)
            if life["steady_kb"] is None and now - life["t"] >= 60:
                life["steady_kb"] = kb  # a minute after (re)start
            next_rss = now + 1.0
        if now >= next_kill - 2 and not kill_bait[0]:
            # A job the coming kill is sure to find running (10^8 samples take seconds),
            # so that the bits compared with `tally run` below cross a kill.
            kill_bait[0] = True
            spec = {"kind": "integrate", "seed": rng.randrange(1, 10**6), "integrand": {"builtin": "unit_disk"},
                    "stop": {"max_samples": 100000000}}
            try:
                st, body = request(srv.port, "POST", "/v1/jobs", json.dumps(spec), token=ann.token)
                count("submit before a kill", st)
                if st == 202:
                    with lock:
                        jid = json.loads(body)["id"]
                        owner[jid], spec_of[jid] = ann, (spec, True)
            except (OSError, http.client.HTTPException) as e:
                errors[f"submit before a kill: {type(e).__name__}"] += 1
        crashed = srv.proc.poll()
        if crashed is not None or now >= next_kill:
            restarting.set()
            life["end_kb"] = rss_kb(srv.proc.pid)
            if crashed is not None:
                crashes.append(f"server exited by itself with {crashed} at {now - t0:.0f} s "
                               f"(log: server-{srv.starts - 1}.log)")
            else:
                code = srv.kill9()
                if code != -signal.SIGKILL:
                    crashes.append(f"server ended with {code} before our SIGKILL landed")
                kill_times.append(time.time())
            rss["lives"].append(life)
            time.sleep(0.5)  # let in-flight requests fail while restarting is set
            srv.start()
            waited = time.time()
            while not carol_running():
                if time.time() - waited > 60:
                    errors["carol's long job not running 60 s after a restart"] += 1
                    break
                time.sleep(0.1)
            admin_login()
            restarting.clear()
            n, missing = check_results(f"after restart {len(kill_times)}")
            checks_after_restart.append({"jobs": n, "missing": missing})
            life = {"start_kb": rss_kb(srv.proc.pid), "steady_kb": None, "max_kb": 0, "t": time.time()}
            next_kill = time.time() + a.kill_every
            kill_bait[0] = False
            tick = time.time()
        th = threading.Thread(target=one, args=(rng.choice(ops),), daemon=True)
        th.start()
        pool.append(th)
        pool = [t for t in pool if t.is_alive()]
        tick += period
        time.sleep(max(0.0, tick - time.time()))
    for th in pool:
        th.join(timeout=30)
    life["end_kb"] = rss_kb(srv.proc.pid)
    rss["lives"].append(life)
    if srv.proc.poll() is not None:
        crashes.append(f"server exited by itself with {srv.proc.returncode} near the end")
        srv.start()

    # Every acknowledged job must still exist, and every job seen succeeded keep its result.
    lost = []
    for jid, t in list(owner.items()):
        if jid in deleted:
            continue
        st, body = request(srv.port, "GET", f"/v1/jobs/{jid}", token=t.token, timeout=30)
        if st == 404:
            lost.append(jid)
        elif st == 200:
            with lock:
                g0 = gen[jid]
            record(jid, g0, json.loads(body))
    jobs_checked = len([j for j in results if j not in deleted])

    # Bits across kills: finished deterministic jobs, first those whose server life (log
    # file) that finished them is a later one than the life that took them, equal
    # `tally run` of the same spec in process.
    life_of = collections.defaultdict(dict)   # job id -> {"submitted"/"succeeded": life}
    warnings = collections.Counter()          # the servers' warning and error lines, ids blanked
    for life in range(srv.starts):
        with open(os.path.join(work, f"server-{life}.log"), errors="replace") as f:
            for line in f:
                m = re.search(r" (info|warning|error) (?:job=([0-9a-f]+) )?(submitted|succeeded)?", line)
                if m and m.group(2) and m.group(3):
                    life_of[m.group(2)].setdefault(m.group(3), life)
                if m and m.group(1) != "info":
                    warnings[re.sub(r"\d+(\.\d+)?", "N", re.sub(r"[0-9a-f]{16,64}", "<id>", line[25:]))[:160].strip()] += 1

    def spanned_kill(jid):
        lf = life_of.get(jid, {})
        return lf.get("succeeded", -1) > lf.get("submitted", 1 << 30)
    cands = [j for j in results if j not in deleted and j not in extended and spec_of[j][1]
             and spec_of[j][0]["kind"] == "integrate"]
    cands.sort(key=lambda j: (not spanned_kill(j), j))
    rerun = []
    for jid in cands[:a.rerun]:
        spec_path = os.path.join(work, f"rerun-{jid}.json")
        with open(spec_path, "w") as f:
            json.dump(spec_of[jid][0], f)
        out = subprocess.run([cli, "run", "--json", "--threads", "2", spec_path], capture_output=True, timeout=600)
        mine = json.loads(out.stdout)["estimate"]
        theirs = json.loads(results[jid])["estimate"]
        same = all(mine[k] == theirs[k] for k in ("mean", "variance", "n"))
        rerun.append({"id": jid, "across_a_kill": spanned_kill(jid), "n": mine["n"], "bit_identical": same})
    exit_code = srv.stop()
    rss_max = max(max(l["max_kb"], l.get("end_kb") or 0) for l in rss["lives"])

    report = {
        "command": " ".join(sys.argv), "duration_s": round(time.time() - t0, 1), "rate_per_s": a.rate,
        "kills": len(kill_times), "crashes": crashes,
        "requests": sum(counts.values()), "requests_by_kind": dict(sorted(counts.items())),
        "statuses": dict(sorted(statuses.items())),
        "errors": dict(errors), "wrong_status_examples": mismatches, "cross_tenant_leaks": leaks[:20],
        "not_errors": dict(idle),
        "jobs_acknowledged": len(owner), "jobs_deleted_by_us": len(deleted), "jobs_lost": len(lost),
        "finished_jobs_checked": jobs_checked, "results_changed": len(changed),
        "checks_after_restarts": checks_after_restart, "rerun_in_process": rerun,
        "server_warnings_and_errors": dict(warnings.most_common(20)),
        "rss_mb": {"start": round((rss["start"] or 0) / 1000, 1),
                   "lives_start_steady_max": [[round((l["start_kb"] or 0) / 1000, 1),
                                               round((l["steady_kb"] or 0) / 1000, 1),
                                               round(l["max_kb"] / 1000, 1)] for l in rss["lives"]],
                   "max": round(rss_max / 1000, 1), "bound": round(rss_bound_kb / 1000, 1)},
        "sigterm_exit": exit_code,
    }
    print(json.dumps(report, indent=2))
    for jid, before, after in changed[:5]:
        print("changed:", jid, before[:300], "->", after[:300], file=sys.stderr)
    if lost:
        print("lost:", lost[:20], file=sys.stderr)
    failed = {
        "crash": bool(crashes), "lost": bool(lost), "changed": bool(changed), "leak": bool(leaks),
        "wrong status or error": any(not k.startswith("connection (during restart)") for k in errors),
        "rss over the bound": rss_max > rss_bound_kb, "rerun differs": any(not r["bit_identical"] for r in rerun),
        "sigterm": exit_code != 0,
    }
    failed = [k for k, v in failed.items() if v]
    print("PASS" if not failed else "FAIL: " + ", ".join(failed), file=sys.stderr)
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
