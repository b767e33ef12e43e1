#!/usr/bin/env python3
"""The automatic estimator's pilot remembered within one server process (issue 31): a
spec validated and then submitted runs its pilot once. The spec is
examples/vector_parameters_16d.json (1,000 components, d = 16) with
"estimator": {"type": "auto"} and "stop": {"rel_error": 1e-6, "max_samples": 16}; a
tally-server on its embedded defaults (one worker, a temporary data directory) on
127.0.0.1 answers POST /v1/jobs/validate (which compiles the spec: the pilot) and then
POST /v1/jobs with the same spec. Prints both times and their ratio, measured in one run.

    python3 bench/auto_pilot_memo.py [--build build]
"""
import argparse
import json
import os
import subprocess
import tempfile
import time
import urllib.request


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--build", default="build")
    args = ap.parse_args()
    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    with open(os.path.join(root, "examples", "vector_parameters_16d.json")) as f:
        spec = json.load(f)
    spec["estimator"] = {"type": "auto"}
    spec["stop"] = {"rel_error": 1e-6, "max_samples": 16}
    with tempfile.TemporaryDirectory() as d:
        port_file = os.path.join(d, "port")
        server = subprocess.Popen([os.path.join(args.build, "server", "tally-server"), "--listen", "127.0.0.1:0",
                                   "--data-dir", d, "--port-file", port_file, "--workers", "1"],
                                  stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        try:
            for _ in range(600):
                if os.path.exists(port_file) and open(port_file).read().strip():
                    break
                time.sleep(0.05)
            port = open(port_file).read().strip().rsplit(":", 1)[-1]

            def post(path):
                req = urllib.request.Request(f"http://127.0.0.1:{port}{path}", data=json.dumps(spec).encode(),
                                             headers={"Content-Type": "application/json"}, method="POST")
                t = time.monotonic()
                with urllib.request.urlopen(req, timeout=900) as r:
                    body = json.loads(r.read())
                return time.monotonic() - t, body

            t_validate, v = post("/v1/jobs/validate")
            t_submit, s = post("/v1/jobs")
            chosen = v.get("plan", {}).get("estimator", {}).get("type")
            print(f"1,000-component auto spec: validate {t_validate:.2f} s (pilot, chose {chosen}), "
                  f"submit after it {t_submit:.3f} s; submit / validate = {t_submit / t_validate:.4f}")
            print(f"job {s.get('id')}")
        finally:
            server.terminate()
            server.wait()


if __name__ == "__main__":
    main()
