#!/usr/bin/python3
"""The scene suite: tally and Blender Cycles side by side on five scenes written by
bench/scene_suite/scenes.py (nothing downloaded). docs/lighting.md, "Scene suite".

    /usr/bin/python3 bench/scene_suite/suite.py --build build            # the full table
    /usr/bin/python3 bench/scene_suite/suite.py --build build --quick    # < ~3 minutes

For each scene and depth: a high-spp reference with tally (all threads), then, interleaved,
tally and Cycles at each spp level with one thread and with all threads, and a high-spp
Cycles image. Printed per level: RMSE against the common reference (tally's), wall time,
and tally's time / the time Cycles needs for tally's RMSE (log-log interpolation of
Cycles' RMSE-time curve; '>' / '<' mark extrapolation); the same ratio against each
renderer's own high-spp image (noise only, model differences removed). Per scene and
depth a correctness line: Cycles' high-spp mean / tally's reference mean (± its standard
error), and the sd (and mean) of per-pixel z of tally's images against the reference
from tally's own StdErr channels.

Needs numpy and OpenImageIO's Python bindings (Debian: python3-numpy,
python3-openimageio; hence /usr/bin/python3), tally's CLI, and `blender` on PATH for the
Cycles columns (without it only tally's columns are printed).
"""
from __future__ import annotations

import argparse
import json
import math
import os
import shutil
import subprocess
import sys
import time
from typing import Dict, List, Optional, Tuple

try:
    import numpy as np
    import OpenImageIO as oiio
except ImportError:
    # A python3 on PATH without Debian's numpy/OpenImageIO bindings (e.g. pyenv's): run
    # again with the system interpreter, which has them (python3-numpy, python3-openimageio).
    if os.path.exists("/usr/bin/python3") and os.path.realpath(sys.executable) != os.path.realpath("/usr/bin/python3"):
        os.execv("/usr/bin/python3", ["/usr/bin/python3"] + sys.argv)
    raise

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(os.path.dirname(HERE))
sys.path.insert(0, HERE)
import scenes  # noqa: E402


def read_exr(path: str) -> Dict[str, np.ndarray]:
    inp = oiio.ImageInput.open(path)
    if inp is None:
        raise RuntimeError("cannot read %s: %s" % (path, oiio.geterror()))
    spec = inp.spec()
    data = inp.read_image("float")
    inp.close()
    return {name: np.asarray(data[..., k], dtype=np.float64) for k, name in enumerate(spec.channelnames)}


def rgb(img: Dict[str, np.ndarray]) -> np.ndarray:
    return np.stack([img["R"], img["G"], img["B"]], axis=-1)


def stderr(img: Dict[str, np.ndarray]) -> np.ndarray:
    return np.stack([img["StdErr.R"], img["StdErr.G"], img["StdErr.B"]], axis=-1)


def clean_map(path: str) -> int:
    """Clamps negative texels to 0 in place (tally refuses them; Blender's courtyard.exr
    has a few tiny ones from compression). Returns how many were clamped."""
    inp = oiio.ImageInput.open(path)
    spec = inp.spec()
    data = np.array(inp.read_image("float"))
    inp.close()
    neg = int((data < 0).sum())
    if neg:
        data[data < 0] = 0.0
        out = oiio.ImageOutput.create(path)
        s = oiio.ImageSpec(spec.width, spec.height, spec.nchannels, "float")
        s.channelnames = spec.channelnames
        out.open(path, s)
        out.write_image(data)
        out.close()
    return neg


def blender_env() -> Dict[str, str]:
    """The environment for Blender: Debian's Blender embeds the system Python and finds
    its prefix through PATH, so a pyenv (or other) python3 ahead of /usr/bin makes it lose
    the system's numpy, which its glTF importer needs. Drop such entries."""
    env = {k: v for k, v in os.environ.items() if not k.startswith("PYENV") and k not in ("PYTHONHOME", "PYTHONPATH")}
    env["PATH"] = os.pathsep.join(d for d in os.environ.get("PATH", "").split(os.pathsep)
                                  if d and ".pyenv" not in d and "virtualenv" not in d and "/venv" not in d)
    return env


class Runner:
    def __init__(self, args, work: str):
        self.args = args
        self.work = work
        self.tally = args.tally or os.path.join(args.build, "client", "tally")
        self.blender = shutil.which("blender") if not args.no_cycles else None
        self.log = open(os.path.join(work, "runs.jsonl"), "a")
        self.masks: Dict[str, Optional[np.ndarray]] = {}

    def emitter_mask(self, scene: scenes.Scene) -> Optional[np.ndarray]:
        """Pixels that see an emitter directly (bool, height x width), from the scene's
        emitters-only variant at depth 1 (scenes.emitters_variant); None for a scene
        without one. Those pixels' noise is the camera's (how much of a pixel a small lamp
        covers), which no light sampling changes, and on a scene of many small lamps it
        is most of the RMSE: the suite reports the RMSE off them as well."""
        if scene.name not in self.masks:
            em = scenes.emitters(scene)
            mask = None
            if em is not None:
                spp = max(64, self.args.ref_spp // 8)
                d = os.path.join(self.work, "images", scene.name)
                os.makedirs(d, exist_ok=True)
                p = os.path.join(d, "emitters_%d.exr" % spp)
                self.tally_run(em, 1, spp, self.args.threads_all, 1000, p)
                mask = rgb(read_exr(p)).max(axis=-1) > 0
            self.masks[scene.name] = mask
        return self.masks[scene.name]

    def tally_run(self, scene: scenes.Scene, depth: int, spp: int, threads: int, seed: int, out: str) -> float:
        spec = {"kind": "lighting", "seed": seed, "scene": scene.tally_scene,
                "query": {"type": "image", "max_depth": depth, "russian_roulette": depth > 1},
                "estimators": ["mis"], "stop": {"max_samples": spp}}
        if self.args.replicates is not None:
            spec["replicates"] = self.args.replicates
        path = os.path.join(scene.directory, "job_d%d_s%d_%d.json" % (depth, spp, seed))
        with open(path, "w") as f:
            json.dump(spec, f)
        cmd = [self.tally, "run", path, "--image", out, "--json"]
        if threads:
            cmd += ["--threads", str(threads)]
        t0 = time.perf_counter()
        r = subprocess.run(cmd, capture_output=True, text=True)
        wall = time.perf_counter() - t0
        if r.returncode != 0:
            raise RuntimeError("tally run failed (%d): %s" % (r.returncode, r.stderr.strip()[:500]))
        res = json.loads(r.stdout)
        self.log.write(json.dumps({"who": "tally", "scene": scene.name, "depth": depth, "spp": spp, "threads": threads,
                                   "seed": seed, "wall": wall, "compute": res.get("compute_seconds")}) + "\n")
        self.log.flush()
        return wall, float(res.get("compute_seconds") or 0.0)

    def cycles_run(self, scene: scenes.Scene, depth: int, spp: int, threads: int, seed: int, out: str) -> float:
        w, h = self.args.resolution
        job = {"gltf": os.path.join(scene.directory, scene.gltf) if scene.gltf else None,
               "lecture": scene.lecture_json, "width": w, "height": h, "spp": spp, "depth": depth,
               "threads": threads, "seed": seed, "out": out,
               "env": dict(scene.env, file=os.path.join(scene.directory, scene.env["file"])) if scene.env else None}
        path = os.path.join(scene.directory, "cycles_d%d_s%d_%d.json" % (depth, spp, seed))
        with open(path, "w") as f:
            json.dump(job, f)
        r = subprocess.run([self.blender, "-b", "--factory-startup", "-noaudio", "-P",
                            os.path.join(HERE, "cycles_render.py"), "--", path], capture_output=True, text=True,
                           env=blender_env())
        secs = None
        for line in r.stdout.splitlines():
            if line.startswith("SUITE_RENDER_SECONDS"):
                secs = float(line.split()[1])
        if r.returncode != 0 or secs is None or not os.path.exists(out):
            tail = "\n".join((r.stdout + r.stderr).splitlines()[-15:])
            raise RuntimeError("blender failed (%d): %s" % (r.returncode, tail))
        self.log.write(json.dumps({"who": "cycles", "scene": scene.name, "depth": depth, "spp": spp, "threads": threads,
                                   "seed": seed, "render": secs}) + "\n")
        self.log.flush()
        return secs


# Student t quantiles for a two-sided 95% interval with K - 1 degrees of freedom: tally's
# per-pixel error bars come from K replicate means (K = 4, an image's default, unless --replicates).
# An image's default replicates (common/lighting/pixel_sampler.hpp, kDefaultImageReplicates).
DEFAULT_REPLICATES = 4
T_975 = {2: 12.706205, 3: 4.302653, 4: 3.182446, 8: 2.364624, 16: 2.131450}


def coverage(img: Dict[str, np.ndarray], ref_rgb: np.ndarray, ref_se: np.ndarray,
             t975: float, where: Optional[np.ndarray] = None) -> float:
    """The fraction of pixel values whose 95% interval (t with K - 1 dof x the standard error
    from the image's StdErr channels, combined with the reference's) holds the reference:
    0.95 for honest error bars (a little less, as the reference's own error bar has K - 1
    dof too). `where`: only those pixels (a boolean image)."""
    den = np.sqrt(stderr(img) ** 2 + ref_se ** 2)
    inside = np.abs(rgb(img) - ref_rgb) <= t975 * den
    return float(np.mean(inside if where is None else inside[where]))


def rmse(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.sqrt(np.mean((a - b) ** 2)))


def time_at(curve: List[Tuple[float, float]], target: float) -> Tuple[Optional[float], str]:
    """Time at which the RMSE-time curve [(t, rmse)] reaches `target`: log-log linear
    interpolation between levels, extrapolation along the end segment outside ('>' if
    beyond the slowest level, '<' if before the fastest); None if the curve does not fall."""
    pts = sorted(curve)
    lt = [math.log(t) for t, _ in pts]
    le = [math.log(max(e, 1e-300)) for _, e in pts]
    y = math.log(target)
    for k in range(len(pts) - 1):
        lo, hi = min(le[k], le[k + 1]), max(le[k], le[k + 1])
        if lo <= y <= hi and le[k] != le[k + 1]:
            f = (y - le[k]) / (le[k + 1] - le[k])
            return math.exp(lt[k] + f * (lt[k + 1] - lt[k])), ""
    k = len(pts) - 2 if y < le[-1] else 0
    slope = (le[k + 1] - le[k]) / (lt[k + 1] - lt[k])
    if slope >= 0:
        return None, "n/a"
    x = lt[k] + (y - le[k]) / slope
    if x > lt[-1] + math.log(4) or x < lt[0] - math.log(4):
        return None, "far"  # more than 4x outside the measured times: not worth a number
    return math.exp(x), (">" if y < le[-1] else "<")


def fmt_ratio(t: float, tc: Optional[float], mark: str) -> str:
    if tc is None:
        return "n/a" if mark != "far" else "(far)"
    return "%s%.2f" % ({">": "<", "<": ">"}.get(mark, ""), t / tc)


def run_scene_depth(run: Runner, scene: scenes.Scene, depth: int, args) -> Dict:
    d = os.path.join(run.work, "images", scene.name, "d%d" % depth)
    os.makedirs(d, exist_ok=True)
    threads_all = args.threads_all
    modes = [("1 thread", 1), ("%d threads" % threads_all, threads_all)]
    res: Dict = {"scene": scene.name, "depth": depth, "levels": []}
    # The common reference: tally, all threads.
    ref_path = os.path.join(d, "tally_ref.exr")
    res["ref_seconds"], _ = run.tally_run(scene, depth, args.ref_spp, threads_all, 1000, ref_path)
    ref = read_exr(ref_path)
    ref_rgb, ref_se = rgb(ref), stderr(ref)
    cyc = run.blender is not None
    tally_imgs, cyc_imgs = {}, {}
    curves = {m: {"tally": [], "cycles": [], "tally_own": [], "cycles_own": [], "cycles_off": [], "cycles_own_off": []}
              for m, _ in modes}
    mask = run.emitter_mask(scene)
    off = None if mask is None or not mask.any() else ~mask
    for spp in args.spp:
        for mi, (mode, thr) in enumerate(modes):
            seed = 1 + mi
            tp = os.path.join(d, "tally_%d_%s.exr" % (spp, thr))
            tt, tc = run.tally_run(scene, depth, spp, thr, seed, tp)
            tally_imgs[(spp, thr)] = read_exr(tp)
            ct = None
            if cyc:
                cp = os.path.join(d, "cycles_%d_%s.exr" % (spp, thr))
                ct = run.cycles_run(scene, depth, spp, thr, seed, cp)
                cyc_imgs[(spp, thr)] = rgb(read_exr(cp))
            res["levels"].append({"spp": spp, "mode": mode, "threads": thr, "tally_s": tt, "tally_compute_s": tc,
                                  "cycles_s": ct})
    cyc_ref = None
    top = max(args.spp)
    # The references' own noise (per value, squared): tally's from its StdErr channels,
    # Cycles' from its two independent top-level images (seeds 1 and 2), scaled by 1/n to
    # its high-spp image (RQMC converges faster than 1/n, so this errs towards a larger
    # noise: it favours Cycles in the noise-only columns).
    ref_noise2 = float(np.mean(ref_se ** 2))
    if cyc:
        cp = os.path.join(d, "cycles_ref.exr")
        res["cycles_ref_seconds"] = run.cycles_run(scene, depth, args.cycles_ref_spp, threads_all, 1000, cp)
        cyc_ref = rgb(read_exr(cp))
        var_top = (cyc_imgs[(top, 1)] - cyc_imgs[(top, threads_all)]) ** 2 / 2.0
        cyc_ref_noise2 = float(np.mean(var_top)) * top / args.cycles_ref_spp
        res["ref_noise"], res["cycles_ref_noise"] = math.sqrt(ref_noise2), math.sqrt(cyc_ref_noise2)
    if off is not None:
        res["emitter_pixels"], res["pixels"] = int(mask.sum()), int(mask.size)
        ref_noise2_off = float(np.mean(ref_se[off] ** 2))
        if cyc:
            cyc_ref_noise2_off = float(np.mean(var_top[off])) * top / args.cycles_ref_spp
    for lv in res["levels"]:
        key = (lv["spp"], lv["threads"])
        ti = rgb(tally_imgs[key])
        lv["tally_rmse"] = rmse(ti, ref_rgb)
        t975 = T_975[args.replicates or DEFAULT_REPLICATES]
        lv["tally_coverage"] = coverage(tally_imgs[key], ref_rgb, ref_se, t975)
        lv["tally_noise"] = math.sqrt(max(lv["tally_rmse"] ** 2 - ref_noise2, 1e-30))
        curves[lv["mode"]]["tally"].append((lv["tally_s"], lv["tally_rmse"]))
        if off is not None:
            lv["tally_coverage_off"] = coverage(tally_imgs[key], ref_rgb, ref_se, t975, off)
            lv["tally_rmse_off"] = rmse(ti[off], ref_rgb[off])
            lv["tally_noise_off"] = math.sqrt(max(lv["tally_rmse_off"] ** 2 - ref_noise2_off, 1e-30))
            # The share of tally's squared error in the pixels that see an emitter.
            lv["emitter_error_share"] = float(((ti - ref_rgb)[mask] ** 2).sum() / max(((ti - ref_rgb) ** 2).sum(), 1e-300))
        if cyc:
            ci = cyc_imgs[key]
            lv["cycles_rmse"] = rmse(ci, ref_rgb)
            lv["cycles_rmse_own"] = rmse(ci, cyc_ref)
            lv["cycles_noise"] = math.sqrt(max(lv["cycles_rmse_own"] ** 2 - cyc_ref_noise2, 1e-30))
            curves[lv["mode"]]["cycles"].append((lv["cycles_s"], lv["cycles_rmse"]))
            curves[lv["mode"]]["cycles_own"].append((lv["cycles_s"], lv["cycles_noise"]))
            if off is not None:
                lv["cycles_rmse_off"] = rmse(ci[off], ref_rgb[off])
                lv["cycles_noise_off"] = math.sqrt(max(rmse(ci[off], cyc_ref[off]) ** 2 - cyc_ref_noise2_off, 1e-30))
                curves[lv["mode"]]["cycles_off"].append((lv["cycles_s"], lv["cycles_rmse_off"]))
                curves[lv["mode"]]["cycles_own_off"].append((lv["cycles_s"], lv["cycles_noise_off"]))
    if cyc:
        for lv in res["levels"]:
            c = curves[lv["mode"]]
            tc, mark = time_at(c["cycles"], lv["tally_rmse"])
            lv["ratio"] = fmt_ratio(lv["tally_s"], tc, mark)
            lv["ratio_compute"] = fmt_ratio(lv["tally_compute_s"], tc, mark)
            tc, mark = time_at(c["cycles_own"], lv["tally_noise"])
            lv["ratio_own"] = fmt_ratio(lv["tally_s"], tc, mark)
            if off is not None:
                tc, mark = time_at(c["cycles_off"], lv["tally_rmse_off"])
                lv["ratio_off"] = fmt_ratio(lv["tally_s"], tc, mark)
                tc, mark = time_at(c["cycles_own_off"], lv["tally_noise_off"])
                lv["ratio_own_off"] = fmt_ratio(lv["tally_s"], tc, mark)
    # Slopes of RMSE against spp (log-log least squares), per renderer and mode.
    res["slopes"] = {}
    for mode, _ in modes:
        lv = [x for x in res["levels"] if x["mode"] == mode]
        xs = np.log([x["spp"] for x in lv])
        for who, key in (("tally", "tally_noise"), ("cycles", "cycles_noise")):
            if key in lv[0] and len(lv) > 1:
                res["slopes"]["%s %s" % (who, mode)] = float(np.polyfit(xs, np.log([x[key] for x in lv]), 1)[0])
    # Correctness.
    n = ref_rgb.size
    ref_mean = float(ref_rgb.mean())
    ref_mean_se = float(np.sqrt((ref_se ** 2).sum()) / n)
    zs, zimg = [], []
    for thr in (1, threads_all):
        img = tally_imgs[(top, thr)]
        den = np.sqrt(stderr(img) ** 2 + ref_se ** 2)
        ok = den > 0
        zs.append(((rgb(img) - ref_rgb)[ok] / den[ok]))
        # The image mean against the reference's: unbiasedness, free of per-pixel skew.
        zimg.append(float((rgb(img).mean() - ref_rgb.mean()) / (np.sqrt((den ** 2).sum()) / n)))
    z = np.concatenate(zs)
    res["z_sd"], res["z_mean"], res["z_n"] = float(z.std()), float(z.mean()), int(z.size)
    res["z_image_mean"] = zimg
    res["ref_mean"], res["ref_mean_se"] = ref_mean, ref_mean_se
    if cyc:
        cyc_mean = float(cyc_ref.mean())
        cyc_mean_se = float(np.sqrt((var_top * top / args.cycles_ref_spp).sum()) / n)
        ratio = cyc_mean / ref_mean
        res["mean_ratio"] = ratio
        res["mean_ratio_se"] = ratio * math.hypot(cyc_mean_se / cyc_mean, ref_mean_se / ref_mean)
        res["cycles_ref_rmse_vs_tally_ref"] = rmse(cyc_ref, ref_rgb)
        # A per-channel view of the model difference, and the relative RMS difference.
        res["mean_ratio_rgb"] = [float(cyc_ref[..., c].mean() / ref_rgb[..., c].mean()) for c in range(3)]
    return res


def model_check(run: Runner, scene: scenes.Scene, args) -> Optional[Dict]:
    """The Lambert variant (dielectrics Lambert in both renderers, metals unchanged) at one
    depth: tally's reference against two Cycles images of half the Cycles spp each."""
    lam = scenes.lambert(scene)
    if lam is None or run.blender is None:
        return None
    depth = args.check_depth
    d = os.path.join(run.work, "images", lam.name, "d%d" % depth)
    os.makedirs(d, exist_ok=True)
    run.tally_run(lam, depth, args.ref_spp, args.threads_all, 1000, os.path.join(d, "tally_ref.exr"))
    ref = read_exr(os.path.join(d, "tally_ref.exr"))
    ref_rgb, ref_se = rgb(ref), stderr(ref)
    half = max(1, args.cycles_ref_spp // 2)
    imgs = []
    for seed in (2000, 2001):
        p = os.path.join(d, "cycles_%d.exr" % seed)
        run.cycles_run(lam, depth, half, args.threads_all, seed, p)
        imgs.append(rgb(read_exr(p)))
    n = ref_rgb.size
    cyc = (imgs[0] + imgs[1]) / 2
    cyc_se = float(np.sqrt(((imgs[0] - imgs[1]) ** 2 / 4).sum()) / n)
    ref_mean, ref_mean_se = float(ref_rgb.mean()), float(np.sqrt((ref_se ** 2).sum()) / n)
    ratio = float(cyc.mean()) / ref_mean
    return {"depth": depth, "ratio": ratio, "se": ratio * math.hypot(cyc_se / float(cyc.mean()), ref_mean_se / ref_mean),
            "rgb": [float(cyc[..., c].mean() / ref_rgb[..., c].mean()) for c in range(3)],
            "rmse": rmse(cyc, ref_rgb)}


def contact_sheet(work: str, names: List[str], depth: int, path: str) -> Optional[str]:
    """One row per scene at `depth`: tally's reference | Cycles' high-spp image, each scene
    exposed so that tally's mean is 0.18, clamped, sRGB-encoded, 2x nearest upscale."""
    rows = []
    for name in names:
        d = os.path.join(work, "images", name, "d%d" % depth)
        t, c = os.path.join(d, "tally_ref.exr"), os.path.join(d, "cycles_ref.exr")
        if not (os.path.exists(t) and os.path.exists(c)):
            continue
        a, b = rgb(read_exr(t)), rgb(read_exr(c))
        k = 0.18 / max(float(a.mean()), 1e-9)
        row = np.concatenate([a * k, np.ones((a.shape[0], 2, 3)), b * k], axis=1)
        rows += [row, np.ones((2, row.shape[1], 3))]
    if not rows:
        return None
    img = np.concatenate(rows[:-1], axis=0)
    img = np.clip(img, 0, 1)
    img = np.where(img <= 0.0031308, 12.92 * img, 1.055 * img ** (1 / 2.4) - 0.055)
    img = np.repeat(np.repeat(img, 2, 0), 2, 1)
    out = oiio.ImageOutput.create(path)
    out.open(path, oiio.ImageSpec(img.shape[1], img.shape[0], 3, "uint8"))
    out.write_image(np.ascontiguousarray((img * 255 + 0.5).astype(np.uint8)))
    out.close()
    return path


def summary(results: List[Dict], out) -> None:
    """A Markdown table of the run: per scene and depth, tally's time / Cycles' time to
    tally's RMSE (wall, common reference) at each level, one thread and all threads; the
    RMSE slopes; the correctness figures."""
    if not results:
        return
    levels = sorted({lv["spp"] for r in results for lv in r["levels"]})
    modes = []
    for lv in results[0]["levels"]:
        if lv["mode"] not in modes:
            modes.append(lv["mode"])
    head = ["scene", "depth"] + ["t/C %s" % m for m in modes] + ["t/C noise-only %s" % m for m in modes] + [
        "t/C noise-only off emitters, %s" % modes[0],
        "slope tally / Cycles (1 thread)",
                                                                  "Cycles/tally mean", "Lambert check", "tally z sd", "tally coverage (1 thread)"]
    print("| " + " | ".join(head) + " |", file=out)
    print("|" + "---|" * len(head), file=out)
    for r in results:
        cells = [r["scene"], str(r["depth"])]
        for m in modes:
            by = {lv["spp"]: lv for lv in r["levels"] if lv["mode"] == m}
            cells.append(" / ".join(by[s].get("ratio", "-") for s in levels if s in by))
        for m in modes:
            by = {lv["spp"]: lv for lv in r["levels"] if lv["mode"] == m}
            cells.append(" / ".join(by[s].get("ratio_own", "-") for s in levels if s in by))
        by = {lv["spp"]: lv for lv in r["levels"] if lv["mode"] == modes[0]}
        cells.append(" / ".join(by[s].get("ratio_own_off", "-") for s in levels if s in by)
                     if "emitter_pixels" in r else "")
        sl = r["slopes"]
        cells.append("%.2f / %s" % (sl.get("tally 1 thread", float("nan")),
                                    ("%.2f" % sl["cycles 1 thread"]) if "cycles 1 thread" in sl else "-"))
        cells.append("%.4f ± %.2g" % (r["mean_ratio"], r["mean_ratio_se"]) if "mean_ratio" in r else "-")
        mc = r.get("model_check")
        cells.append("%.4f ± %.2g" % (mc["ratio"], mc["se"]) if mc else "")
        cells.append("%.3f" % r["z_sd"])
        cells.append(" / ".join("%.2f" % by[s]["tally_coverage"] for s in levels if s in by and "tally_coverage" in by[s]))
        print("| " + " | ".join(cells) + " |", file=out)
    print("\n(t/C: at %s spp; '<'/'>' extrapolated, '(far)' beyond 4x the measured times; 'off emitters': "
          "the pixels that see no emitter directly)" % "/".join(str(x) for x in levels), file=out, flush=True)


def print_result(res: Dict, scene: scenes.Scene, args, out) -> None:
    p = lambda s="": print(s, file=out, flush=True)  # noqa: E731
    p("\n%s, depth %d (tally max_depth %d = Cycles max_bounces %d), %dx%d, reference: tally %d spp (%.1f s)%s"
      % (scene.name, res["depth"], res["depth"], res["depth"] - 1, args.resolution[0], args.resolution[1], args.ref_spp,
         res["ref_seconds"], (", Cycles %d spp (%.1f s)" % (args.cycles_ref_spp, res["cycles_ref_seconds"]))
         if "cycles_ref_seconds" in res else ""))
    cyc = "mean_ratio" in res
    if cyc:
        p("  %-10s %5s | %9s %7s %7s | %9s %7s | %8s %8s | %8s %8s %8s" % (
            "threads", "spp", "tally RMSE", "wall s", "comp s", "Cyc RMSE", "Cyc s", "t/C wall", "t/C comp", "tally nz",
            "Cyc nz", "t/C nz"))
    else:
        p("  %-10s %5s | %9s %7s %7s" % ("threads", "spp", "tally RMSE", "wall s", "comp s"))
    for lv in res["levels"]:
        if cyc:
            p("  %-10s %5d | %9.5f %7.3f %7.3f | %9.5f %7.3f | %8s %8s | %8.5f %8.5f %8s" % (
                lv["mode"], lv["spp"], lv["tally_rmse"], lv["tally_s"], lv["tally_compute_s"], lv["cycles_rmse"],
                lv["cycles_s"], lv["ratio"], lv["ratio_compute"], lv["tally_noise"], lv["cycles_noise"],
                lv["ratio_own"]))
        else:
            p("  %-10s %5d | %9.5f %7.3f %7.3f" % (lv["mode"], lv["spp"], lv["tally_rmse"], lv["tally_s"],
                                                  lv["tally_compute_s"]))
    if "emitter_pixels" in res:
        p("  off the emitters: %d of %d pixels see an emitter directly (the camera's noise there: how much of the "
          "pixel a lamp covers); without them:" % (res["emitter_pixels"], res["pixels"]))
        for lv in res["levels"]:
            if cyc:
                p("  %-10s %5d | %9.5f %7s %7s | %9.5f %7s | %8s %8s | %8.5f %8.5f %8s   (emitter pixels: %.0f%% of "
                  "tally's squared error)" % (lv["mode"], lv["spp"], lv["tally_rmse_off"], "", "", lv["cycles_rmse_off"],
                                             "", lv["ratio_off"], "", lv["tally_noise_off"], lv["cycles_noise_off"],
                                             lv["ratio_own_off"], 100 * lv["emitter_error_share"]))
            else:
                p("  %-10s %5d | %9.5f   (emitter pixels: %.0f%% of tally's squared error)"
                  % (lv["mode"], lv["spp"], lv["tally_rmse_off"], 100 * lv["emitter_error_share"]))
    if "ref_noise" in res:
        p("  noise of the references (RMS per value): tally %.2g, Cycles %.2g (subtracted in the 'nz' columns)"
          % (res["ref_noise"], res["cycles_ref_noise"]))
    p("  slopes of the noise-only RMSE vs spp: " + ", ".join("%s %.2f" % (k, v) for k, v in res["slopes"].items()))
    line = "  correctness: "
    if cyc:
        line += ("Cycles/tally mean %.4f +- %.2g (R %.3f G %.3f B %.3f), Cycles ref vs tally ref RMSE %.5f; "
                 % (res["mean_ratio"], res["mean_ratio_se"], *res["mean_ratio_rgb"], res["cycles_ref_rmse_vs_tally_ref"]))
    nu = (args.replicates or DEFAULT_REPLICATES) - 1  # the error bars' degrees of freedom
    expected_sd = "%.2f" % math.sqrt(nu / (nu - 2)) if nu > 2 else "unbounded"
    line += ("tally %d spp vs ref: per-pixel z sd %.3f mean %+.3f over %d values (t%d errors: sd %s expected), "
             "z of the image mean %s" % (max(lv["spp"] for lv in res["levels"]), res["z_sd"], res["z_mean"], res["z_n"],
                                         nu, expected_sd, " / ".join("%+.2f" % x for x in res["z_image_mean"])))
    p(line)
    p("  coverage of tally's 95%% error bars (t%d) against the reference: " % nu + ", ".join(
        "%d spp %s %.3f%s" % (lv["spp"], lv["mode"], lv["tally_coverage"],
                              " (%.3f off the emitters)" % lv["tally_coverage_off"] if "tally_coverage_off" in lv else "")
        for lv in res["levels"]))
    mc = res.get("model_check")
    if mc:
        p("  model check (dielectrics Lambert in both, depth %d): Cycles/tally mean %.4f +- %.2g (R %.3f G %.3f B %.3f), "
          "RMSE between the two %.5f" % (mc["depth"], mc["ratio"], mc["se"], *mc["rgb"], mc["rmse"]))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--build", default=os.path.join(ROOT, "build"), help="tally's build directory")
    ap.add_argument("--tally", help="tally CLI (default BUILD/client/tally)")
    ap.add_argument("--out", help="work directory (default out/scene_suite, --quick: out/scene_suite_quick)")
    ap.add_argument("--scenes", default=",".join(scenes.WRITERS), help="comma-separated: " + ",".join(scenes.WRITERS))
    ap.add_argument("--depths", default="1,4,8")
    ap.add_argument("--spp", default="16,64,256")
    ap.add_argument("--ref-spp", type=int, default=2048, help="tally's reference spp")
    ap.add_argument("--cycles-ref-spp", type=int, default=2048, help="Cycles' high-spp image")
    ap.add_argument("--resolution", default="96x72")
    ap.add_argument("--threads-all", type=int, default=os.cpu_count() or 1)
    ap.add_argument("--no-cycles", action="store_true")
    ap.add_argument("--replicates", type=int, choices=sorted(T_975), help=f"tally's replicates K (default: the spec's, {DEFAULT_REPLICATES})")
    ap.add_argument("--quick", action="store_true",
                    help="64x48, depth 4, 16/64 spp, references 256 spp: under ~3 minutes")
    ap.add_argument("--json", help="also write the results here")
    ap.add_argument("--check-depth", type=int, default=4, help="depth of the Lambert model check")
    ap.add_argument("--no-model-check", action="store_true")
    ap.add_argument("--summary", metavar="JSON", help="print the summary table of an earlier run's --json and exit")
    args = ap.parse_args()
    if args.summary:
        with open(args.summary) as f:
            summary(json.load(f), sys.stdout)
        return 0
    if args.quick:
        args.resolution, args.depths, args.spp, args.ref_spp, args.cycles_ref_spp = "64x48", "4", "16,64", 256, 256
    if args.out is None:
        args.out = os.path.join(ROOT, "out", "scene_suite_quick" if args.quick else "scene_suite")
    args.resolution = tuple(int(x) for x in args.resolution.split("x"))
    args.depths = [int(x) for x in args.depths.split(",")]
    args.spp = [int(x) for x in args.spp.split(",")]
    os.makedirs(args.out, exist_ok=True)
    run = Runner(args, args.out)
    if not os.access(run.tally, os.X_OK):
        print("scene suite: no tally CLI at %s" % run.tally, file=sys.stderr)
        return 1
    names = args.scenes.split(",")
    suite = scenes.write_all(os.path.join(args.out, "scenes"), args.resolution, names)
    for s in suite:
        if s.env:
            neg = clean_map(os.path.join(s.directory, s.env["file"]))
            s.notes.append("map %s: %d negative texel values clamped to 0 (tally refuses them)" % (s.env["source"], neg))
    missing = [n for n in names if n not in [s.name for s in suite]]
    print("scene suite: %s; %s; resolution %dx%d, depths %s, spp %s, tally reference %d spp, Cycles %d spp"
          % (", ".join(s.name for s in suite), "Cycles: " + (run.blender or "not run (blender not on PATH)"),
             args.resolution[0], args.resolution[1], args.depths, args.spp, args.ref_spp, args.cycles_ref_spp), flush=True)
    if missing:
        print("scene suite: not written: %s (no Blender world map found)" % ", ".join(missing), flush=True)
    for s in suite:
        print("  %s: %s%s" % (s.name, s.what, "".join("; " + n for n in s.notes)), flush=True)
    results = []
    failed = []
    t0 = time.perf_counter()
    for s in suite:
        for depth in args.depths:
            try:
                res = run_scene_depth(run, s, depth, args)
            except Exception as e:  # one scene failing must not hide the others
                import traceback
                traceback.print_exc()
                print("\n%s, depth %d: FAILED: %s" % (s.name, depth, e), flush=True)
                failed.append("%s/d%d" % (s.name, depth))
                continue
            if depth == args.check_depth and not args.no_model_check:
                try:
                    res["model_check"] = model_check(run, s, args)
                except Exception as e:
                    print("\n%s: model check FAILED: %s" % (s.name, e), flush=True)
                    failed.append("%s/model_check" % s.name)
            results.append(res)
            print_result(res, s, args, sys.stdout)
    print("\nscene suite: %.0f s in all%s" % (time.perf_counter() - t0, ("; failed: " + ", ".join(failed)) if failed else ""))
    print()
    summary(results, sys.stdout)
    if run.blender is not None and args.check_depth in args.depths:
        sheet = contact_sheet(args.out, [s.name for s in suite], args.check_depth,
                              os.path.join(args.out, "suite_d%d.png" % args.check_depth))
        if sheet:
            print("scene suite: tally's references | Cycles' images at depth %d: %s" % (args.check_depth, sheet))
    if args.json:
        with open(args.json, "w") as f:
            json.dump(results, f, indent=1)
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
