#!/usr/bin/python3
"""RMSE against time of the image samplers, from sampler_bench's CSV.
Usage: sampler_plot.py sampler_convergence.csv out.png"""
import csv
import sys
from collections import defaultdict

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

rows = list(csv.DictReader(open(sys.argv[1])))
panels = sorted({(r["scene"], int(r["depth"])) for r in rows}, key=lambda p: (p[0] != "lecture", p[0], p[1]))
fig, axes = plt.subplots(1, len(panels), figsize=(4.2 * len(panels), 3.8), squeeze=False)
for ax, (scene, depth) in zip(axes[0], panels):
    curves = defaultdict(list)
    for r in rows:
        if r["scene"] == scene and int(r["depth"]) == depth:
            curves[r["sampler"]].append((float(r["seconds"]), float(r["rmse"]), int(r["spp"])))
    for name, pts in sorted(curves.items(), key=lambda kv: (kv[0] != "independent", kv[0])):
        pts.sort()
        ax.loglog([p[0] for p in pts], [p[1] for p in pts], "o-" if name == "independent" else ".-", label=name)
    ax.set_title(f"{scene}, max_depth {depth}")
    ax.set_xlabel("seconds (1 thread)")
    ax.set_ylabel("RMSE over pixels")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
fig.tight_layout()
fig.savefig(sys.argv[2], dpi=110)
print(f"wrote {sys.argv[2]}")
