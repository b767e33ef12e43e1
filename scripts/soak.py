#!/usr/bin/env python3
"""Soak test of tally-server (on demand; not part of `make test`).

Mixed traffic at a fixed rate -- submit, watch (event stream), cancel, extend,
validate, status/list, and bad requests (malformed JSON, 1e400, unknown methods,
smuggling framing, oversize bodies) -- while the server is killed with SIGKILL every
--kill-every seconds and restarted on the same data dir.

Reports requests, errors by class, the server's RSS at start and end, and jobs lost:
an id the server acknowledged (202) that is missing afterwards, or a job seen
finished that later reads as unfinished or with a different result. Must be 0.

Usage: scripts/soak.py [--build build] [--duration 600] [--rate 20] [--kill-every 60]
Exit status 1 if any acknowledged job was lost.
"""
import argparse
import collections
import http.client
import json
import os
import random
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time


def rss_kb(pid):
    try:
        with open(f"/proc/{pid}/status") as f:
            for line in f:
                if line.startswith("VmRSS:"):
                    return int(line.split()[1])
    except OSError:
        pass
    return None


class Server:
    def __init__(self, binary, data_dir, workdir):
        self.binary, self.data_dir, self.workdir = binary, data_dir, workdir
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
             "--workers", "2", "--checkpoint-interval", "0.2", "--max-body", "65536"],
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
        self.proc.wait()

    def stop(self):
        self.proc.send_signal(signal.SIGTERM)
        try:
            return self.proc.wait(timeout=30)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            return -1


def request(port, method, path, body=None, headers=None, timeout=10):
    c = http.client.HTTPConnection("127.0.0.1", port, timeout=timeout)
    try:
        h = dict(headers or {})
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


def job_spec(rng):
    kind = rng.random()
    seed = rng.randrange(1, 10**6)
    if kind < 0.5:
        return {"kind": "integrate", "seed": seed, "integrand": {"builtin": "unit_disk"},
                "stop": {"max_samples": rng.choice([200000, 2000000, 20000000])}}
    if kind < 0.8:
        return {"kind": "integrate", "seed": seed, "integrand": {"expression": "exp(-x0*x0) * cos(x1)"},
                "domain": {"type": "box", "lower": [0, 0], "upper": [1, 1]},
                "estimator": {"type": "qmc", "points": 1024}, "stop": {"rel_error": 1e-6, "time_budget_s": 3}}
    return {"kind": "integrate", "seed": seed, "integrand": {"expression": "x0 * x1 + sin(x0)"},
            "domain": {"type": "box", "lower": [0, 0], "upper": [1, 1]},
            "estimator": {"type": "quadrature", "points_per_dim": rng.choice([65, 513, 2049])},
            "stop": {"max_samples": 1}}


BAD = [
    ("POST", "/v1/jobs", "{not json", "malformed"),
    ("POST", "/v1/jobs", '{"kind": "integrate", "stop": {"max_samples": 1e400}}', "out-of-range"),
    ("POST", "/v1/jobs", '{"kind": "integrate", "integrand": {"expression": "0/0"}}', "ok-or-422"),
    ("POST", "/v1/jobs/validate", '{"kind": "integrate", "integrand": {"expression": "0/0"}}', "pilot-fails"),
    ("POST", "/v1/jobs", "[" * 5000, "depth"),
    ("GET", "/v1/jobs/nope", None, "404"),
    ("BREW", "/v1/jobs", None, "method"),
]


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--build", default="build")
    ap.add_argument("--duration", type=float, default=600)
    ap.add_argument("--rate", type=float, default=20, help="requests per second")
    ap.add_argument("--kill-every", type=float, default=60)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--keep", action="store_true", help="keep the data dir and logs")
    a = ap.parse_args()
    binary = os.path.join(a.build, "server", "tally-server")
    work = tempfile.mkdtemp(prefix="tally-soak-")
    rng = random.Random(a.seed)
    srv = Server(binary, os.path.join(work, "data"), work)
    srv.start()
    rss_start = rss_kb(srv.proc.pid)

    counts = collections.Counter()
    errors = collections.Counter()
    idle = collections.Counter()                # not errors: see watch()
    latency = collections.defaultdict(list)     # op -> seconds, outside restarts
    odd_answers = []                            # first bytes of unexpected smuggling answers
    acked = {}          # id -> True
    deleted = set()     # ids our DELETE removed (204: DELETE of a finished job deletes it)
    finished = {}       # id -> state, once seen finished
    extended = set()    # ids we extended (they may run again)
    regressed = set()   # finished jobs seen unfinished again (not extended)
    lock = threading.Lock()
    restarting = threading.Event()
    stop = threading.Event()

    def classify_exc(e, op):
        return "connection (during restart)" if restarting.is_set() else f"{op}: {type(e).__name__}"

    def watch(job_id, port):
        # A stream whose headers arrived and then stays quiet for the socket timeout is
        # idle, not stalled: a queued job sends nothing until it starts or the heartbeat
        # (15 s). Only a timeout before the headers counts as an error.
        headers_in = False
        try:
            c = http.client.HTTPConnection("127.0.0.1", port, timeout=5)
            t_req = time.time()
            c.request("GET", f"/v1/jobs/{job_id}/events", headers={"Accept": "text/event-stream"})
            r = c.getresponse()
            headers_in = True
            with lock:
                latency["watch (headers)"].append(time.time() - t_req)
            end = time.time() + rng.uniform(0.2, 2.0)
            while time.time() < end:
                if not r.read1(4096):
                    break
            c.close()
            with lock:
                counts["watch"] += 1
                if r.status != 200:
                    if r.status == 404 and job_id in deleted:
                        idle["watch 404 after our DELETE of the job"] += 1
                    else:
                        errors[f"watch {r.status}"] += 1
        except (OSError, http.client.HTTPException) as e:
            with lock:
                if headers_in and isinstance(e, TimeoutError) and not restarting.is_set():
                    counts["watch"] += 1
                    idle["watch: stream idle for 5 s after its headers (queued job)"] += 1
                else:
                    errors[classify_exc(e, "watch")] += 1

    def one(op):
        port = srv.port
        ids = [i for i in acked if i not in deleted]
        t_op = time.time()

        def bad_status(what, jid, st):
            # A 404 for a job our own DELETE removed meanwhile is expected, not an error.
            with lock:
                if st == 404 and jid in deleted:
                    idle[f"{what} 404 after our DELETE of the job"] += 1
                else:
                    errors[f"{what} {st}"] += 1

        try:
            if op == "submit":
                st, body = request(port, "POST", "/v1/jobs", json.dumps(job_spec(rng)))
                if st == 202:
                    with lock:
                        acked[json.loads(body)["id"]] = True
                elif st != 503:
                    errors[f"submit {st}"] += 1
            elif op == "watch" and ids:
                threading.Thread(target=watch, args=(rng.choice(ids), port), daemon=True).start()
                return
            elif op == "cancel" and ids:
                jid = rng.choice(ids)
                st, _ = request(port, "DELETE", f"/v1/jobs/{jid}")
                if st == 204:  # it had finished: deleted (docs/api.md)
                    with lock:
                        deleted.add(jid)
                elif st not in (200, 202, 409):
                    bad_status("cancel", jid, st)
            elif op == "extend" and ids:
                jid = rng.choice(ids)
                with lock:
                    extended.add(jid)
                st, _ = request(port, "POST", f"/v1/jobs/{jid}/extend", json.dumps({"max_samples": 40000000}))
                if st not in (202, 409):
                    bad_status("extend", jid, st)
            elif op == "validate":
                st, _ = request(port, "POST", "/v1/jobs/validate", json.dumps(job_spec(rng)))
                if st != 200:
                    errors[f"validate {st}"] += 1
            elif op == "status" and ids:
                jid = rng.choice(ids)
                st, body = request(port, "GET", f"/v1/jobs/{jid}")
                if st != 200:
                    bad_status("status", jid, st)
                else:
                    check_finished(jid, json.loads(body))
            elif op == "list":
                st, _ = request(port, "GET", "/v1/jobs")
                if st != 200:
                    errors[f"list {st}"] += 1
            elif op == "bad":
                m, p, b, what = rng.choice(BAD)
                st, _ = request(port, m, p, b)
                ok = {"malformed": {400}, "out-of-range": {400}, "ok-or-422": {202, 422}, "pilot-fails": {422},
                      "depth": {400}, "404": {404}, "method": {405}}[what]
                if st not in ok:
                    errors[f"bad {what} -> {st}"] += 1
            elif op == "smuggle":
                out = raw(port, b"POST /v1/jobs HTTP/1.1\r\nHost: x\r\nTransfer-Encoding: chunked, identity\r\n\r\n"
                                b"GET /livez HTTP/1.1\r\nHost: x\r\n\r\n")
                if out.count(b"HTTP/1.1 ") > 1 or (out and not out.startswith(b"HTTP/1.1 400")):
                    errors["smuggle: answered twice or not 400"] += 1
                    with lock:
                        if len(odd_answers) < 5:
                            odd_answers.append(out[:200].decode("latin-1"))
                elif not out:
                    errors["smuggle: no answer"] += 1
            else:
                return
            with lock:
                counts[op] += 1
                if not restarting.is_set():
                    latency[op].append(time.time() - t_op)
        except (OSError, http.client.HTTPException) as e:
            with lock:
                errors[classify_exc(e, op)] += 1

    def check_finished(jid, s):
        # A job seen finished must never read as queued/running again, unless we extended it.
        state = s.get("state")
        with lock:
            if state in ("succeeded", "failed", "cancelled"):
                finished[jid] = state
            elif jid in finished and jid not in extended and state in ("queued", "running"):
                regressed.add(jid)

    ops = ["submit"] * 4 + ["watch"] * 2 + ["cancel", "extend", "validate", "list"] + ["status"] * 4 + \
          ["bad"] * 2 + ["smuggle"]
    t0 = time.time()
    next_kill = t0 + a.kill_every
    kills = 0
    period = 1.0 / a.rate
    tick = t0
    pool = []
    while time.time() - t0 < a.duration:
        now = time.time()
        if now >= next_kill:
            restarting.set()
            srv.kill9()
            kills += 1
            srv.start()
            restarting.clear()
            next_kill = time.time() + a.kill_every
        th = threading.Thread(target=one, args=(rng.choice(ops),), daemon=True)
        th.start()
        pool.append(th)
        pool = [t for t in pool if t.is_alive()]
        tick += period
        time.sleep(max(0.0, tick - time.time()))
    for t in pool:
        t.join(timeout=30)
    rss_end = rss_kb(srv.proc.pid)

    # Every acknowledged job must still exist; one seen succeeded/failed must not be unfinished now.
    lost = []
    for jid in acked:
        if jid in deleted:
            continue
        try:
            st, body = request(srv.port, "GET", f"/v1/jobs/{jid}", timeout=30)
        except OSError:
            st, body = 0, b""
        if st == 404:
            lost.append(jid)
        elif st == 200:
            check_finished(jid, json.loads(body))
    exit_code = srv.stop()

    total = sum(counts.values())

    def pct(xs, q):
        xs = sorted(xs)
        return round(xs[min(len(xs) - 1, int(q * len(xs)))], 3) if xs else None
    report = {
        "duration_s": round(time.time() - t0, 1), "rate_per_s": a.rate, "kills": kills,
        "requests": total, "requests_by_op": dict(counts), "errors_by_class": dict(errors),
        "not_errors": dict(idle),
        "latency_s_p50_p99_max": {op: [pct(v, 0.5), pct(v, 0.99), pct(v, 1.0)] for op, v in sorted(latency.items())},
        "unexpected_smuggling_answers": odd_answers,
        "jobs_acknowledged": len(acked), "jobs_deleted_by_us": len(deleted), "jobs_lost": len(lost), "finished_jobs_regressed": len(regressed),
        "rss_kb_start": rss_start, "rss_kb_end": rss_end, "sigterm_exit": exit_code,
    }
    print(json.dumps(report, indent=2))
    if lost:
        print("lost:", lost[:20], file=sys.stderr)
    if not a.keep:
        shutil.rmtree(work, ignore_errors=True)
    else:
        print("kept", work, file=sys.stderr)
    return 1 if lost or regressed else 0


if __name__ == "__main__":
    sys.exit(main())
