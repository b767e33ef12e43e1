#!/usr/bin/env python3
"""Request latency while a large image job crosses its pass boundaries. Standard library
only; prints figures, not a timed test.

    python3 bench/boundary_stall.py [--build build] [--resolution 1920x1080] [--spp 32]

Starts tally-server (127.0.0.1, port 0, a fresh data dir, --log-level debug), submits
examples/preview_image.json at the resolution asked with "stop": {"max_samples": SPP},
and polls GET /v1/jobs/ID and GET /readyz from two threads every 20 ms until the job
ends. Prints each one's request count, median and maximum latency, and the server's own
timing of each pass boundary (its debug line "commit and plan ... ms"): a request that
waited for a merge shows a maximum near that figure.
"""
import argparse
import json
import os
import re
import shutil
import subprocess
import tempfile
import threading
import time
import urllib.request

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--build", default=os.path.join(ROOT, "build"))
    ap.add_argument("--resolution", default="1920x1080")
    ap.add_argument("--spp", type=int, default=32)
    args = ap.parse_args()
    w, h = map(int, args.resolution.split("x"))
    spec = json.load(open(os.path.join(ROOT, "examples", "preview_image.json")))
    spec["scene"]["camera"]["resolution"] = [w, h]
    spec["stop"] = {"max_samples": args.spp}
    tmp = tempfile.mkdtemp(prefix="tally-stall-")
    port_file, log_path = os.path.join(tmp, "port"), os.path.join(tmp, "server.log")
    server = subprocess.Popen([os.path.join(args.build, "server", "tally-server"), "--listen", "127.0.0.1:0",
                               "--data-dir", os.path.join(tmp, "data"), "--port-file", port_file, "--workers", "2",
                               "--log-level", "debug"], stdout=open(log_path, "w"), stderr=subprocess.STDOUT)
    try:
        deadline = time.monotonic() + 60
        while not (os.path.exists(port_file) and open(port_file).read().strip()):
            if time.monotonic() > deadline or server.poll() is not None:
                raise SystemExit(f"tally-server did not start; see {log_path}")
            time.sleep(0.05)
        base = "http://127.0.0.1:" + open(port_file).read().strip().split(":")[-1]
        req = urllib.request.Request(base + "/v1/jobs", data=json.dumps(spec).encode(),
                                     headers={"Content-Type": "application/json"})
        job_id = json.load(urllib.request.urlopen(req, timeout=60))["id"]
        latencies = {"GET /v1/jobs/ID": [], "GET /readyz": []}
        done = threading.Event()

        def poll(name, url):
            end = time.monotonic() + 600
            while not done.is_set() and time.monotonic() < end:
                t = time.monotonic()
                with urllib.request.urlopen(url, timeout=60) as r:
                    body = r.read()
                latencies[name].append(time.monotonic() - t)
                if name.startswith("GET /v1/jobs") and json.loads(body)["state"] in ("succeeded", "failed",
                                                                                    "cancelled"):
                    done.set()
                time.sleep(0.02)

        threads = [threading.Thread(target=poll, args=("GET /v1/jobs/ID", f"{base}/v1/jobs/{job_id}")),
                   threading.Thread(target=poll, args=("GET /readyz", f"{base}/readyz"))]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
        print(f"{w}x{h}, {args.spp} spp, 2 workers")
        for name, v in latencies.items():
            v.sort()
            print(f"  {name:16s} {len(v):5d} requests, median {v[len(v) // 2] * 1e3:7.1f} ms, "
                  f"max {v[-1] * 1e3:7.1f} ms")
        merges = [float(m) for m in re.findall(r"commit and plan ([0-9.]+) ms", open(log_path).read())]
        if merges:
            print(f"  pass boundaries: commit and plan {min(merges):.0f}-{max(merges):.0f} ms ({len(merges)} passes)")
    finally:
        server.terminate()
        try:
            server.wait(timeout=30)
        except subprocess.TimeoutExpired:
            server.kill()
        shutil.rmtree(tmp, ignore_errors=True)


if __name__ == "__main__":
    main()
