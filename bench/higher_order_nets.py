#!/usr/bin/env python3
"""Higher-order (interlaced) scrambled Sobol' nets against the plain scrambled net
(issue 31): the relative sd of one randomization (64 per cell, seed 3) of the `qmc`
estimator with "interlacing" 1, 2 and 3, at 2^12 and 2^16 points, on Genz instances in
d = 2 .. 16, through `tally run --json`. Ratios come from one run; the sd is a property
of the point set, not of the machine, so the figures repeat exactly.

    python3 bench/higher_order_nets.py [--build build] [--threads 2]

Instances: a_j uniform in [0.3, 2.0], u_j uniform in [0.1, 0.9] from Python's
random.seed(1), drawn in the order the rows are printed.
"""
import argparse
import json
import math
import os
import subprocess
import tempfile

ROWS = [("product_peak", 2), ("gaussian", 4), ("gaussian", 8), ("product_peak", 8), ("oscillatory", 8),
        ("corner_peak", 8), ("gaussian", 16), ("oscillatory", 16)]


def main():
    import random
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--build", default="build")
    ap.add_argument("--threads", type=int, default=2)
    args = ap.parse_args()
    tally = os.path.join(args.build, "client", "tally")
    random.seed(1)
    print(f"relative sd of one randomization (64 randomizations), tally run --threads {args.threads}")
    print(f"{'family':13s} {'d':>3s} | {'2^12: plain':>11s} {'x2/plain':>8s} {'x3/plain':>8s} |"
          f" {'2^16: plain':>11s} {'x2/plain':>8s} {'x3/plain':>8s}")
    with tempfile.TemporaryDirectory() as tmp:
        path = os.path.join(tmp, "spec.json")
        for fam, d in ROWS:
            a = [random.uniform(0.3, 2.0) for _ in range(d)]
            u = [random.uniform(0.1, 0.9) for _ in range(d)]
            sd = {}
            for m in (12, 16):
                for il in (1, 2, 3):
                    spec = {"kind": "integrate", "seed": 3,
                            "integrand": {"builtin": "genz", "family": fam, "a": a, "u": u},
                            "estimator": {"type": "qmc", "points": 2 ** m, "interlacing": il},
                            "stop": {"max_samples": 64}}
                    with open(path, "w") as f:
                        json.dump(spec, f)
                    out = subprocess.run([tally, "run", "--json", "--threads", str(args.threads), path],
                                         capture_output=True, text=True, check=True)
                    e = json.loads(out.stdout)["estimate"]
                    sd[m, il] = math.sqrt(e["variance"]) / abs(e["mean"])
            cells = " | ".join(f"{sd[m, 1]:11.2e} {sd[m, 2] / sd[m, 1]:8.3f} {sd[m, 3] / sd[m, 1]:8.3f}" for m in (12, 16))
            print(f"{fam:13s} {d:3d} | {cells}", flush=True)


if __name__ == "__main__":
    main()
