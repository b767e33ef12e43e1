#!/usr/bin/python3
"""RMSE against time of the image samplers, from sampler_bench's CSV
(columns scene, depth, sampler, spp, rmse, seconds; seconds = spp x pixels x the
sampler's measured time per sample).
Usage: sampler_plot.py sampler_convergence.csv out.png [out.md]
bench/study/plot.py calls section() to put the same table into docs/accuracy-vs-time.md."""
import csv
import math
import os
import sys
from collections import defaultdict


def load(path):
    data = defaultdict(lambda: defaultdict(list))  # (scene, depth) -> sampler -> [(spp, rmse, s)]
    for r in csv.DictReader(open(path)):
        data[(r["scene"], int(r["depth"]))][r["sampler"]].append(
            (int(r["spp"]), float(r["rmse"]), float(r["seconds"])))
    for curves in data.values():
        for pts in curves.values():
            pts.sort()
    return data


def sampler_order(kv):
    name = kv[0]
    return (name != "independent", int(name.split("=")[1]) if "=" in name else 0, name)


def ordered(data):
    return sorted(data, key=lambda p: (p[0] != "lecture", p[0], p[1]))


def slope(pts):
    xs = [math.log(p[0]) for p in pts]
    ys = [math.log(p[1]) for p in pts]
    mx, my = sum(xs) / len(xs), sum(ys) / len(ys)
    return sum((x - mx) * (y - my) for x, y in zip(xs, ys)) / sum((x - mx) ** 2 for x in xs)


def time_to(pts, target):
    """Seconds at which (seconds, rmse) reaches target, log-log interpolation."""
    i = 0
    while i + 2 < len(pts) and pts[i + 1][1] > target:
        i += 1
    (_, e0, t0), (_, e1, t1) = pts[i], pts[i + 1]
    f = (math.log(target) - math.log(e0)) / (math.log(e1) - math.log(e0))
    return math.exp(math.log(t0) + f * (math.log(t1) - math.log(t0)))


def plot(path, png):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    data = load(path)
    panels = ordered(data)
    fig, axes = plt.subplots(1, len(panels), figsize=(4.2 * len(panels), 3.8), squeeze=False)
    for ax, key in zip(axes[0], panels):
        for name, pts in sorted(data[key].items(), key=sampler_order):
            ax.loglog([p[2] for p in pts], [p[1] for p in pts], "o-" if name == "independent" else ".-", label=name)
        ax.set_title(f"{key[0]}, max_depth {key[1]}")
        ax.set_xlabel("seconds (1 thread)")
        ax.set_ylabel("RMSE over pixels")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(png, dpi=110)


def section(path, png_link):
    data = load(path)
    out = ["## 8. Image samplers: independent against sobol (RQMC with K replicates)\n",
           "bench/sampler_bench.cpp (one run, samplers interleaved; MIS, one thread, 48×36 pixels, RMSE over all "
           "pixels and channels against a sobol reference at 4096 spp with its own variance subtracted, mean of 2 "
           "seeds; time = spp × pixels × the sampler's time per sample, the fastest of three interleaved "
           "96×72 × 64 spp renders). Slopes are fits of log RMSE on log spp over 8–256 spp. *Speed-up* is "
           "independent's time to its own 16- or 256-spp RMSE over the sampler's time to the same RMSE. "
           "See docs/lighting.md (Samplers) for the sampler and why its error bars need the replicates. "
           "Measured on the shared 2-core VM under heavy load (load average 18-20 in the committed run): only "
           "the interleaved ratios mean anything. The default is sobol with K = 8: K = 4 converges faster at a "
           "fixed spp (fewer, longer sequences) but its intervals use t with 3 degrees of freedom (35% wider "
           "than K = 8's t7) and its per-pixel error estimates are too noisy for adaptive tiles; K = 16 gives "
           "up too much of the stratification.\n",
           png_link + "\n"]
    for key in ordered(data):
        curves = data[key]
        ind = curves["independent"]
        e16 = next(p[1] for p in ind if p[0] == 16)
        e256 = ind[-1][1]
        t16 = next(p[2] for p in ind if p[0] == 16)
        t256 = ind[-1][2]
        spps = [p[0] for p in ind]
        out.append(f"**{key[0]}, max_depth {key[1]}**\n")
        out.append("| sampler | " + " | ".join(f"RMSE @{s}" for s in spps) +
                   " | slope | speed-up @16 spp level | speed-up @256 spp level |")
        out.append("|---" * (len(spps) + 4) + "|")
        for name, pts in sorted(curves.items(), key=sampler_order):
            cells = " | ".join(f"{p[1]:.3g}" for p in pts)
            out.append(f"| {name} | {cells} | {slope(pts):.3f} | {t16 / time_to(pts, e16):.2f}× | "
                       f"{t256 / time_to(pts, e256):.2f}× |")
        out.append("")
    return "\n".join(out)


def headline(path, k="sobol K=8"):
    data = load(path)
    parts, slopes = [], []
    for key in ordered(data):
        ind, q = data[key]["independent"], data[key][k]
        e256 = ind[-1][1]
        parts.append(f"{ind[-1][2] / time_to(q, e256):.2f}× ({key[0]}, depth {key[1]})")
        slopes.append(f"{slope(q):.2f} vs {slope(ind):.2f} ({key[0]}, depth {key[1]})")
    return (f"Images, {k.replace('K=', 'K = ')} against independent sampling: RMSE slopes " + ", ".join(slopes[:1]) +
            "; time to independent's 256-spp RMSE " + ", ".join(parts) + " — section 8.")


if __name__ == "__main__":
    plot(sys.argv[1], sys.argv[2])
    print(f"wrote {sys.argv[2]}")
    if len(sys.argv) > 3:
        rel = os.path.relpath(sys.argv[2], os.path.dirname(os.path.abspath(sys.argv[3])))
        with open(sys.argv[3], "w") as fh:
            fh.write(section(sys.argv[1], f"![{os.path.basename(sys.argv[2])}]({rel})"))
        print(f"wrote {sys.argv[3]}")
