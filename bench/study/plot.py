#!/usr/bin/python3
"""Turns the study's CSVs (tally-study, scipy_peer.py) into PNG plots and
docs/accuracy-vs-time.md. Usage: plot.py DATA_DIR REPORT.md
All fits are least squares on log10-log10 data over the stated ranges."""
import csv
import json
import math
import os
import sys
from collections import defaultdict

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

DATA = sys.argv[1]
REPORT = sys.argv[2]
REL = os.path.relpath(DATA, os.path.dirname(os.path.abspath(REPORT)))
FIGS = []


def rows(name):
    path = os.path.join(DATA, name)
    return list(csv.DictReader(open(path))) if os.path.exists(path) else []


def fit(x, y):
    x, y = np.log10(np.asarray(x, float)), np.log10(np.asarray(y, float))
    s, b = np.polyfit(x, y, 1)
    return s, b


def save(fig, name):
    fig.tight_layout()
    fig.savefig(os.path.join(DATA, name), dpi=110)
    plt.close(fig)
    return f"![{name}]({REL}/{name})"


def ok(measured, theory, tol=0.1):
    return "✓" if abs(measured - theory) <= tol else "✗"


out = []
head = []  # headline lines for the closing note

# ---------------------------------------------------------------- (a) quadrature
Q = rows("quadrature.csv")
TRAP_MIN_N = {1: 9, 2: 9, 3: 9, 4: 9, 5: 5, 6: 5, 8: 4}
cross = {}
if Q:
    out.append("## 1. Trapezoid against Monte Carlo in 1–8 dimensions\n")
    out.append(
        "Integrands: Genz *gaussian* exp(−Σ a_i²(x_i − u_i)²) with a_i = 1.5 and Genz *oscillatory* "
        "cos(2πu_1 + Σ a_i x_i) with a_i = 1 (u_1 chosen so the phase is 0 mod 2π, so |I| is not near 0), "
        "u_i = 0.3 + 0.4·frac(0.618·i); the same per-axis difficulty in every d. Trapezoid: the product's "
        "`quadrature` estimator (tensor-product trapezoid, n points per axis; its work counts the n^d "
        "points of T(n) and the ((n+1)/2)^d of the coarse rule behind its Richardson error estimate). "
        "Monte Carlo: the `uniform` estimator, relative RMSE over 32 seeds at each N. "
        "Time is the runner's compute time for one job on one thread.\n")
    out.append(f"Fit ranges: Monte Carlo all N (2^8 … 2^19); trapezoid n ≥ {TRAP_MIN_N[1]} for d ≤ 4, "
               f"n ≥ 5 for d = 5, 6, n ≥ 4 for d = 8 (n ≤ 8 there: 8^8 = 1.7·10^7 points is the largest "
               "rule run); below that the O(h⁴) term and the n/(n−1) in h = 1/(n−1) still bend the curve.\n")
    out.append("| family | d | trapezoid slope (theory −2/d) | | MC slope (theory −1/2) | | "
               "rel. error at 10⁶ evals: trapezoid | MC | winner |")
    out.append("|---|---|---|---|---|---|---|---|---|")
    for fam in ["gaussian", "oscillatory"]:
        fig, ax = plt.subplots(1, 2, figsize=(12, 4.8))
        cols = plt.cm.viridis(np.linspace(0, 0.9, 7))
        for ci, d in enumerate([1, 2, 3, 4, 5, 6, 8]):
            T = [r for r in Q if r["family"] == fam and int(r["d"]) == d and r["method"] == "trapezoid"]
            M = [r for r in Q if r["family"] == fam and int(r["d"]) == d and r["method"] == "monte_carlo"]
            if not T or not M:
                continue
            tn = np.array([float(r["n_per_dim"]) for r in T])
            tN = np.array([float(r["evaluations"]) for r in T])
            tt = np.array([float(r["seconds"]) for r in T])
            te = np.array([max(float(r["rel_error"]), 1e-16) for r in T])
            mN = np.array([float(r["evaluations"]) for r in M])
            mt = np.array([float(r["seconds"]) for r in M])
            me = np.array([float(r["rel_error"]) for r in M])
            sel = tn >= TRAP_MIN_N[d]
            ts, tb = fit(tN[sel], te[sel])
            ms, mb = fit(mN, me)
            tts, _ = fit(tt[sel], te[sel])
            mts, _ = fit(mt, me)
            e_t = 10 ** (tb + ts * 6)
            e_m = 10 ** (mb + ms * 6)
            cross[(fam, d)] = (e_t, e_m)
            win = "MC" if e_m < e_t else "trapezoid"
            out.append(f"| {fam} | {d} | {ts:.3f} | {ok(ts, -2 / d)} | {ms:.3f} | {ok(ms, -0.5)} | "
                       f"{e_t:.2e} | {e_m:.2e} | {win} |")
            if d in (1, 2, 4, 8):
                c = cols[ci]
                ax[0].loglog(tN, te, "o-", color=c, ms=3, label=f"trapezoid d={d} (slope {ts:.2f})")
                ax[0].loglog(mN, me, "s--", color=c, ms=3, label=f"MC d={d} (slope {ms:.2f})")
                ax[1].loglog(tt, te, "o-", color=c, ms=3, label=f"trapezoid d={d} (slope {tts:.2f})")
                ax[1].loglog(mt, me, "s--", color=c, ms=3, label=f"MC d={d} (slope {mts:.2f})")
        ax[0].set_xlabel("evaluations N")
        ax[1].set_xlabel("compute seconds (1 thread)")
        for a in ax:
            a.set_ylabel("relative error (MC: RMSE over 32 seeds)")
            a.grid(True, which="both", alpha=0.3)
            a.legend(fontsize=7)
        ax[0].set_title(f"Genz {fam}: error against work")
        ax[1].set_title(f"Genz {fam}: error against time")
        FIGS.append(save(fig, f"quadrature_{fam}.png"))
    out.append("")
    out += FIGS[-2:]
    # crossover plot
    fig, ax = plt.subplots(figsize=(6.5, 4.2))
    for fam, mk in [("gaussian", "o"), ("oscillatory", "s")]:
        ds = sorted(d for (f, d) in cross if f == fam)
        ax.semilogy(ds, [cross[(fam, d)][0] for d in ds], mk + "-", label=f"trapezoid ({fam})")
        ax.semilogy(ds, [cross[(fam, d)][1] for d in ds], mk + "--", label=f"Monte Carlo ({fam})")
    ax.set_xlabel("dimension d")
    ax.set_ylabel("relative error at 10⁶ evaluations (fits)")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    ax.set_title("Where Monte Carlo starts to win")
    out.append(save(fig, "quadrature_crossover.png"))
    first_mc = {}
    for fam in ["gaussian", "oscillatory"]:
        mc_dims = [d for (f, d) in sorted(cross) if f == fam and cross[(f, d)][1] < cross[(f, d)][0]]
        first_mc[fam] = min(mc_dims) if mc_dims else None
    out.append(
        f"\n**Crossover, measured:** at a budget of 10⁶ evaluations Monte Carlo beats the trapezoid rule "
        f"from d = {first_mc['gaussian']} on (gaussian) and d = {first_mc['oscillatory']} on (oscillatory). "
        "d = 4 is where the two rates are equal (−2/d = −1/2) and the constants decide; beyond it the "
        "trapezoid falls further behind with every dimension.\n")
    head.append(f"Crossover dimension (10⁶ evaluations): gaussian d = {first_mc['gaussian']}, "
                f"oscillatory d = {first_mc['oscillatory']}.")

# ---------------------------------------------------------------- (b) variance
V = rows("variance.csv")
if V:
    out.append("## 2. Variance falls as 1/N\n")
    out.append("Plain Monte Carlo (`uniform`), 64 seeds per N, N = 2^4 … 2^18: the variance of the 64 "
               "estimates against N, and the mean of the engine's own reported std_error². Fit over all N.\n")
    out.append("| integrand | slope of Var[Î_N] across seeds (theory −1) | | slope of reported std_error² |")
    out.append("|---|---|---|---|")
    fig, ax = plt.subplots(figsize=(6.5, 4.2))
    for name in sorted(set(r["integrand"] for r in V)):
        R = [r for r in V if r["integrand"] == name]
        N = [float(r["N"]) for r in R]
        v = [float(r["variance_across_seeds"]) for r in R]
        rv = [float(r["mean_reported_variance"]) for r in R]
        s, _ = fit(N, v)
        s2, _ = fit(N, rv)
        out.append(f"| {name} | {s:.3f} | {ok(s, -1)} | {s2:.3f} |")
        head.append(f"Variance slope ({name}): {s:.3f} (theory −1).")
        ax.loglog(N, v, "o-", label=f"{name}: across seeds (slope {s:.2f})")
        ax.loglog(N, rv, "--", label=f"{name}: reported se² (slope {s2:.2f})")
    ax.set_xlabel("samples N")
    ax.set_ylabel("variance of the estimate")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    out.append("")
    out.append(save(fig, "variance.png"))
    out.append("")

# ---------------------------------------------------------------- (c) disk
D = rows("disk.csv")
if D:
    out.append("## 3. The unit disk: five ways to place points\n")
    out.append(
        "E = ∫_disk (x² + y²) dA = π/2. `box_uniform`: the product's uniform estimator on [−1, 1]² "
        "with an indicator; `rejection`: the product's rejection estimator on the disk domain; "
        "`concentric`: the product's disk domain (Shirley–Chiu map); `polar_sqrt` (r = √ξ) and the "
        "lecture's WRONG `wrong_polar` (r = ξ) are tiny kernels in bench/study/disk_study.cpp run "
        "through the same JobRunner (the wrong one is not in the product). 16 seeds per N.\n")
    methods = ["box_uniform", "rejection", "polar_sqrt", "concentric", "wrong_polar"]
    P = rows("disk_points.csv")
    fig, ax = plt.subplots(1, 5, figsize=(15, 3.2))
    for a, m in zip(ax, methods):
        pts = np.array([[float(r["x"]), float(r["y"])] for r in P if r["method"] == m])
        if m == "box_uniform":
            inside = (pts ** 2).sum(1) < 1
            a.scatter(pts[inside, 0], pts[inside, 1], s=1)
            a.scatter(pts[~inside, 0], pts[~inside, 1], s=1, c="lightgrey")
        else:
            a.scatter(pts[:, 0], pts[:, 1], s=1, c="crimson" if m == "wrong_polar" else None)
        a.set_aspect("equal")
        a.set_title(m + (" (WRONG)" if m == "wrong_polar" else ""), fontsize=9)
        a.set_xticks([])
        a.set_yticks([])
    out.append(save(fig, "disk_points.png"))
    fig, ax = plt.subplots(1, 2, figsize=(12, 4.2))
    out.append("\n| method | estimate at N = 2^20 (mean of 16 seeds) | RMSE | RMSE slope (theory −1/2; wrong: 0) |")
    out.append("|---|---|---|---|")
    for m in methods:
        R = [r for r in D if r["method"] == m]
        N = np.array([float(r["N"]) for r in R])
        mean = np.array([float(r["mean"]) for r in R])
        se = np.array([float(r["mean_reported_se"]) for r in R])
        rm = np.array([float(r["rmse"]) for r in R])
        s, _ = fit(N, rm)
        ax[0].semilogx(N, mean, "o-", label=m)
        ax[0].fill_between(N, mean - 1.96 * se, mean + 1.96 * se, alpha=0.2)
        ax[1].loglog(N, rm, "o-", label=f"{m} (slope {s:.2f})")
        out.append(f"| {m} | {mean[-1]:.5f} | {rm[-1]:.2e} | {s:.3f} |")
    ax[0].axhline(math.pi / 2, color="k", lw=0.8, label="π/2 (exact)")
    ax[0].axhline(math.pi / 3, color="crimson", lw=0.8, ls=":", label="π/3 (what r = ξ converges to)")
    ax[0].set_xlabel("samples N")
    ax[0].set_ylabel("estimate ± its reported 95% interval")
    ax[1].set_xlabel("samples N")
    ax[1].set_ylabel("RMSE against π/2")
    for a in ax:
        a.grid(True, which="both", alpha=0.3)
        a.legend(fontsize=8)
    out.append("")
    out.append(save(fig, "disk_convergence.png"))
    wrong = [r for r in D if r["method"] == "wrong_polar"][-1]
    out.append(
        f"\nThe wrong map puts as many points in every ring of width dr whatever its area, so the centre "
        f"is crowded: E[r²] under r = ξ is 1/3 instead of 1/2, and the estimator converges, with a "
        f"confident and shrinking error bar, to π/3 = 1.0472 (measured {float(wrong['mean']):.5f} at N = "
        f"{int(float(wrong['N']))}), 33% below the truth. Its RMSE stops falling; the other four fall as "
        "N^−1/2 and differ only in their constants (rejection pays 4/π proposals per point).\n")

# ---------------------------------------------------------------- (e) rqmc
Rq = rows("rqmc.csv")
if Rq:
    out.append("## 5. Randomized QMC against plain Monte Carlo\n")
    out.append(
        "The product's `qmc` estimator with `scramble: owen` (nested uniform scramble of Sobol) with P points per randomization, RMSE of one "
        "randomization over 32 independent scrambles (one job with max_samples = 32); plain MC with N = P "
        "evaluations, RMSE over 32 seeds. Instances: a_i = 1 (oscillatory), 1.5 (gaussian), 2 (product "
        "peak), 0.5 (corner peak); u_i as in section 1. Fit range N = 2^8 … 2^16. Theory for smooth f: "
        "MC N^−1/2; scrambled nets N^−3/2 (log N)^((d−1)/2) (Owen 1997), so the raw log-log slope over a "
        "finite range is shallower by about (d−1)/(2 ln N); the 'log-corrected' slope fits "
        "RMSE/(ln N)^((d−1)/2) and should be −3/2.\n")
    out.append("| family | d | RQMC slope raw (theory −1.5) | | RQMC slope log-corrected (theory −1.5) | | "
               "MC slope (theory −0.5) | | RMSE ratio MC/RQMC at N = 2^16 |")
    out.append("|---|---|---|---|---|---|---|---|---|")
    fig, axs = plt.subplots(1, 2, figsize=(12, 4.5))
    for ai, d in enumerate(["2", "4"]):
        for fi, fam in enumerate(["oscillatory", "gaussian", "product_peak", "corner_peak"]):
            c = f"C{fi}"
            R = [r for r in Rq if r["family"] == fam and r["d"] == d and r["method"] == "rqmc"]
            M = [r for r in Rq if r["family"] == fam and r["d"] == d and r["method"] == "monte_carlo"]
            if not R:
                continue
            N = np.array([float(r["N"]) for r in R])
            e = np.array([float(r["rel_rmse"]) for r in R])
            mN = np.array([float(r["N"]) for r in M])
            me = np.array([float(r["rel_rmse"]) for r in M])
            sel = N >= 256
            s, _ = fit(N[sel], e[sel])
            sc, _ = fit(N[sel], e[sel] / np.log(N[sel]) ** ((int(d) - 1) / 2))
            ms, _ = fit(mN[mN >= 256], me[mN >= 256])
            out.append(f"| {fam} | {d} | {s:.3f} | {ok(s, -1.5)} | {sc:.3f} | {ok(sc, -1.5)} | {ms:.3f} | {ok(ms, -0.5)} | "
                       f"{me[-1] / e[-1]:.0f} |")
            axs[ai].loglog(N, e, "o-", color=c, ms=3, label=f"RQMC {fam} ({s:.2f})")
            axs[ai].loglog(mN, me, "s--", color=c, ms=3, label=f"MC {fam} ({ms:.2f})")
        axs[ai].set_title(f"d = {d}")
        axs[ai].set_xlabel("evaluations per estimate")
        axs[ai].set_ylabel("relative RMSE")
        axs[ai].grid(True, which="both", alpha=0.3)
        axs[ai].legend(fontsize=7)
    out.append("")
    out.append(save(fig, "rqmc.png"))
    out.append("")
    # The default scramble of the product (affine: random linear scramble + digital shift).
    aff = []
    for d in ["2", "4"]:
        for fam in ["oscillatory", "gaussian", "product_peak", "corner_peak"]:
            R = [r for r in Rq if r["family"] == fam and r["d"] == d and r["method"] == "rqmc_affine"]
            O = [r for r in Rq if r["family"] == fam and r["d"] == d and r["method"] == "rqmc"]
            if not R or not O:
                continue
            N = np.array([float(r["N"]) for r in R])
            e = np.array([float(r["rel_rmse"]) for r in R])
            sel = N >= 256
            s_aff, _ = fit(N[sel], e[sel])
            t_aff = float(R[-1]["seconds_per_estimate"])
            t_owen = float(O[-1]["seconds_per_estimate"])
            aff.append(f"| {fam} | {d} | {s_aff:.3f} | {float(O[-1]['rel_rmse']) / e[-1]:.2g} | {t_owen / t_aff:.1f} |")
    if aff:
        out.append(
            "The product's default scramble (`scramble: affine`: a random lower-triangular binary matrix and a "
            "digital shift applied once to the direction numbers, then one XOR per coordinate in Gray-code "
            "order) is unbiased by construction and its error bars cover (tests/statistical/coverage_test.cpp). "
            "Measured on the same instances its RMSE is comparable to the nested scramble's in 4-D "
            "(ratio owen/affine about 0.8–4) and much smaller in 2-D, where it converges faster than the "
            "N^−3/2 theory for nested scrambling (so its slopes are reported, not checked against that "
            "theory); it costs far less per point set:\n")
        out.append("| family | d | affine RMSE slope | RMSE owen / affine at N = 2^16 | time per set owen / affine |")
        out.append("|---|---|---|---|---|")
        out.extend(aff)
        out.append("")

# ---------------------------------------------------------------- (d) lighting
L = rows("lighting_convergence.csv")
E = rows("lighting_efficiency.csv")
I = rows("lighting_images.csv")
if L:
    ref = float(L[0]["reference"])
    out.append("## 4. The reflection equation on the lecture's scene\n")
    out.append(
        "Scene (bench/study/scenes/lecture_scene.json): a 6×6 white diffuse floor (albedo 0.8), a 1×1 "
        "area light (L = 5) facing down at height 2, a grey 0.7×0.7 occluder at height 1 half in the way. "
        f"Receiver: the floor point at the origin, direct light (max_depth 1). Reference L_o = {ref:.6f} "
        f"(± {float(L[0]['reference_se']):.1e}, 2^22 samples each of light sampling and MIS, combined). "
        "16 seeds per N; each estimator in its own job so its time is its own.\n")
    fig, ax = plt.subplots(figsize=(6.5, 4.2))
    for m in ["uniform_hemisphere", "cosine_hemisphere", "light_area", "mis"]:
        R = [r for r in L if r["estimator"] == m]
        t = [float(r["seconds"]) for r in R]
        e = [float(r["rel_rmse"]) for r in R]
        s, _ = fit([float(r["N"]) for r in R], e)
        ax.loglog(t, e, "o-", label=f"{m} (slope in N {s:.2f})")
    ax.set_xlabel("compute seconds per estimate (1 thread)")
    ax.set_ylabel("relative RMSE")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    out.append(save(fig, "lighting_rmse_time.png"))
    if E:
        base = float(E[0]["efficiency"])
        out.append("\n| estimator | σ² per sample | seconds per sample | efficiency 1/(σ²t) | relative to uniform | "
                   "the job's own efficiency field (all four in one job) |")
        out.append("|---|---|---|---|---|---|")
        for r in E:
            out.append(f"| {r['estimator']} | {float(r['sigma2']):.4g} | {float(r['seconds_per_sample']):.3g} | "
                       f"{float(r['efficiency']):.3g} | {float(r['efficiency']) / base:.1f}× | "
                       f"{float(r['job_efficiency']):.3g} |")
        head.append("Lighting efficiency relative to uniform hemisphere: " + ", ".join(
            f"{r['estimator']} {float(r['efficiency']) / base:.1f}×" for r in E[1:]) + ".")
    if I:
        from matplotlib.image import imread
        fig, ax = plt.subplots(1, len(I), figsize=(4 * len(I), 3.4))
        for a, r in zip(ax, I):
            a.imshow(imread(os.path.join(DATA, r["png"])))
            a.set_title(f"{r['estimator']}\n{float(r['seconds']):.1f} s, {r['spp']} spp, "
                        f"mean rel. error {float(r['mean_rel_error']):.3f}", fontsize=9)
            a.axis("off")
        out.append("\nThe same scene at equal compute time per estimator (image query, one thread):\n")
        out.append(save(fig, "lighting_equal_time.png"))
    out.append("")

# ---------------------------------------------------------------- peers
Pr = rows("peers.csv") + rows("peers_scipy.csv")
if Pr:
    inst = json.load(open(os.path.join(DATA, "instances.json")))
    nd = sorted(set(int(r["d"]) for r in Pr))
    ninst = len(set(r["instance"] for r in Pr))
    out.append("## 6. Peers side by side on the Genz suite\n")
    out.append(
        f"Cuba's protocol (genz_random_instance: u ~ U(0,1)^d, a = w·h/Σw, h = (6, 18, 2.2, 15.2, 16.1, "
        f"16.4)), six families, d ∈ {nd}, {ninst} instances per family and dimension (Cuba uses 20"
        + ("" if ninst >= 20 else "; fewer to keep the section short on a shared 2-core machine") + "). Every method stops by its own "
        "reported error: 95% half-width ≤ 5·10⁻⁴·|estimate| (GSL and tally: 1.96σ; SciPy: Student t with "
        "7 degrees of freedom on its 8 randomizations). **3 correct digits** means |Î − I| ≤ 5·10⁻⁴·|I|. "
        "**Time to 3 digits** is the method's wall time to its stop if it stopped by its own rule with 3 "
        "correct digits, else ∞ (caps: "
        f"{inst['max_evaluations']:.3g} evaluations or {inst['max_seconds']} s). **Coverage**: the fraction "
        "of runs that stopped by their own rule whose reported 95% half-width covered the true error "
        "(promised: 95%).\n")
    out.append(
        "Methods: tally's `cubature` estimator (hcubature_v inside a tally job: one bounded block, evaluation "
        "cap 2^22 = its stop rule's max_samples, stopped by its error *estimate* like the hcubature peer) on "
        "oscillatory, product peak, corner peak and gaussian; its `qmc` estimator (1024 points per randomization "
        "in d ≤ 3, 4096 above) on continuous (cubature's estimate was too optimistic on the kinks: 46/60 in a "
        "first run of this suite, whose continuous rows were then rerun with qmc, peers again interleaved); "
        "and its `vegas` estimator with `stratify: true` (VEGAS+: adaptive separable "
        "grid, 200 bins, 3 warm-up passes, hypercube allocation ∝ σ^0.75, later passes weighted by n / previous "
        "pass's variance) on the discontinuous one (the job's own rel_error stop rule); the earlier choice "
        "(`qmc`, plain `vegas`) came from `tally-study peers-tune` and `vegas-tune` on instance seeds 101–105, "
        "disjoint from the seeds evaluated here; Steven G. Johnson's hcubature "
        "(h-adaptive Genz–Malik) and pcubature (p-adaptive Clenshaw–Curtis) from Debian's libcubature "
        "via bench/peers/cubature_peer.cpp, stopped by their own error *estimate* ≤ 5·10⁻⁴·|value| (not a "
        "confidence interval; their coverage column is that estimate's); GSL 2.7 plain, MISER and VEGAS via "
        "bench/peers/gsl_peers.cpp (a scalar C integrand; batches aimed at the predicted need like "
        "tally's runner, plain/MISER batches pooled by call counts, VEGAS after a discarded warm-up with "
        "iterations accumulated and chi²/dof ≤ 1.5 required); SciPy's qmc_quad algorithm "
        "(bench/peers/scipy_peer.py; SciPy 1.10.1 has no qmc_quad, so the same algorithm on "
        "scipy.stats.qmc.Sobol, n_points doubling from 1024, 8 randomizations). tally and GSL run "
        "interleaved per instance in one process, one thread each; SciPy runs right after in its own "
        "process. Times from one run on a shared machine: read the ratios.\n")
    methods = ["tally", "gsl_plain", "gsl_miser", "gsl_vegas", "scipy_qmc_quad", "hcubature", "pcubature"]
    by = defaultdict(dict)
    for r in Pr:
        key = (r["family"], int(r["d"]), int(r["instance"]))
        t = float(r["seconds"]) if (r["converged"] == "1" and r["correct"] == "1") else math.inf
        by[key][r["method"]] = (t, float(r["evaluations"]), r)

    def summarize(keys):
        res = {}
        for m in methods:
            ts = [by[k][m][0] for k in keys if m in by[k]]
            ev = [by[k][m][1] if by[k][m][0] < math.inf else math.inf for k in keys if m in by[k]]
            conv = [by[k][m][2] for k in keys if m in by[k] and by[k][m][2]["converged"] == "1"]
            cov = sum(int(r["covered"]) for r in conv) / len(conv) if conv else float("nan")
            res[m] = dict(t=float(np.median(ts)) if ts else math.inf, ev=float(np.median(ev)) if ev else math.inf,
                          ok=sum(1 for t in ts if t < math.inf), n=len(ts), cov=cov, nconv=len(conv))
        return res

    def fmt_t(t):
        return "∞" if t == math.inf else f"{t * 1e3:.3g} ms"

    def fmt_e(e):
        return "∞" if e == math.inf else f"{e:.3g}"

    families = ["oscillatory", "product_peak", "corner_peak", "gaussian", "continuous", "discontinuous"]
    out.append("| family | d | " + " | ".join(methods) + " | tally / best peer (median times) |")
    out.append("|---|---|" + "---|" * len(methods) + "---|")
    ratio_rows = []
    for fam in families:
        for d in nd:
            keys = [k for k in by if k[0] == fam and k[1] == d]
            s = summarize(keys)
            best = min(s[m]["t"] for m in methods[1:])
            ratio = s["tally"]["t"] / best if best < math.inf else (0.0 if s["tally"]["t"] < math.inf else math.nan)
            ratio_rows.append(ratio)
            cells = [f"{fmt_t(s[m]['t'])} ({s[m]['ok']}/{s[m]['n']})" for m in methods]
            rtxt = "tally only" if ratio == 0.0 else ("—" if math.isnan(ratio) else f"{ratio:.2f}")
            out.append(f"| {fam} | {d} | " + " | ".join(cells) + f" | {rtxt} |")
    out.append("\nCells: median time to 3 correct digits over the instances (∞ when fewer than half got there) "
               "and, in brackets, how many instances got there.\n")
    out.append("**Per family (all dimensions), against the goals** (tally reaches 3 digits on ≥ 175/180 "
               "instances overall; coverage of its stopped runs in [0.93, 0.97]; its median time ≤ 0.25× the "
               "best peer's):\n")
    out.append("| family | tally estimator | tally: 3 digits | tally coverage | tally median time | best peer | "
               "its median time | ratio | ≤ 0.25? |")
    out.append("|---|---|---|---|---|---|---|---|---|")
    fam_verdicts = []
    for fam in families:
        keys = [k for k in by if k[0] == fam]
        if not keys:
            continue
        s = summarize(keys)
        bm = min(methods[1:], key=lambda m: s[m]["t"])
        ratio = s["tally"]["t"] / s[bm]["t"] if s[bm]["t"] < math.inf else (0.0 if s["tally"]["t"] < math.inf else math.nan)
        notes = sorted(set(by[k]["tally"][2]["note"].split(" ")[-1] for k in keys if "tally" in by[k]))
        ok = ratio <= 0.25
        fam_verdicts.append((fam, ratio, s["tally"]["cov"]))
        out.append(f"| {fam} | {', '.join(notes)} | {s['tally']['ok']}/{s['tally']['n']} | "
                   f"{s['tally']['cov'] * 100:.1f}% of {s['tally']['nconv']} | {fmt_t(s['tally']['t'])} | {bm} | "
                   f"{fmt_t(s[bm]['t'])} | {ratio:.2f} | {'yes' if ok else 'no'} |")
    # The three goals of the study (issue 15), judged on all instances and per family.
    s_all = summarize(list(by))
    ok_all, n_all, cov_all = s_all["tally"]["ok"], s_all["tally"]["n"], s_all["tally"]["cov"]
    digits_met = n_all > 0 and ok_all / n_all >= 175 / 180
    cov_met = 0.93 <= cov_all <= 0.97
    missed = [(fam, r) for fam, r, _ in fam_verdicts if not r <= 0.25]
    time_txt = ("met in every family" if not missed else
                "met in " + ", ".join(f for f, r, _ in fam_verdicts if r <= 0.25) + "; missed in " +
                ", ".join(f"{f} ({r:.2f}, {r / 0.25:.1f}× the goal)" for f, r in missed))
    goals_line = (f"3 digits on {ok_all}/{n_all} instances (goal ≥ 175/180 = 97.2%: "
                  f"{'met' if digits_met else 'not met'}); coverage {cov_all * 100:.1f}% (goal [93%, 97%]: "
                  f"{'met' if cov_met else 'not met'}); median time ≤ 0.25× the best peer's: {time_txt}")
    out.append(f"\n**Against the goals:** {goals_line}.\n")
    out.append(
        "Coverage with few instances: a family has 3 × (instances) runs, so a correct 95% interval "
        "covers all 30 of 30 runs with probability 0.95³⁰ = 0.21; the earlier run's 100% for RQMC on three "
        "families was within chance. tests/statistical/coverage_test.cpp "
        "(`Coverage.RandomizedQmcAtTheStudysStopRule`) measures RQMC's coverage at this study's own stop "
        "rule (rel_error 5·10⁻⁴, 4096 points × ≥ 16 randomizations, d = 4, 1000 seeds): oscillatory 0.949, "
        "corner peak 0.955, continuous 0.949 — honest, not conservative. The `cubature` rows' coverage is "
        "that of hcubature's error *estimate* (no confidence is promised): it is conservative on smooth "
        "integrands (the estimate compares the degree-7 rule with the embedded degree-5 one).\n")
    out.append("")
    allk = list(by)
    s = summarize(allk)
    best_m = min(methods[1:], key=lambda m: s[m]["t"])
    out.append("**All instances together:**\n")
    out.append("| method | instances reaching 3 digits | median time to 3 digits | median evaluations | "
               "coverage of the reported 95% error (stopped runs) |")
    out.append("|---|---|---|---|---|")
    for m in methods:
        out.append(f"| {m} | {s[m]['ok']}/{s[m]['n']} | {fmt_t(s[m]['t'])} | {fmt_e(s[m]['ev'])} | "
                   f"{s[m]['cov'] * 100:.1f}% of {s[m]['nconv']} |")
    # per-instance ratio against the best peer on that instance
    per = []
    for k in allk:
        if "tally" not in by[k]:
            continue
        bp = min(by[k][m][0] for m in methods[1:] if m in by[k])
        tt = by[k]["tally"][0]
        if tt < math.inf and bp < math.inf:
            per.append(tt / bp)
        elif tt < math.inf:
            per.append(0.0)
        elif bp < math.inf:
            per.append(math.inf)
    med_ratio = s["tally"]["t"] / s[best_m]["t"] if s[best_m]["t"] < math.inf else 0.0
    gsl_best = min(["gsl_plain", "gsl_miser", "gsl_vegas"], key=lambda m: s[m]["t"])
    gsl_ratio = s["tally"]["t"] / s[gsl_best]["t"] if s[gsl_best]["t"] < math.inf else 0.0
    per_med = float(np.median(per)) if per else math.nan
    verdict = "met" if med_ratio <= 0.5 else "not met"
    out.append(
        f"\nMedian-instance ratio, tally / best peer ({best_m}): **{med_ratio:.2f}** (median times over all "
        f"instances); the median over instances of tally's time divided by the fastest peer's time on that "
        f"same instance: **{per_med:.2f}** (instances where only tally reached 3 digits count as 0, "
        f"where only a peer did as ∞) (the earlier round's goal, ≤ 0.5 over all instances: **{verdict}**); against the best GSL "
        f"integrator ({gsl_best}) the median-time ratio is {gsl_ratio:.2f}.\n")
    out.append(
        "How (smooth families): tally's `cubature` estimator is hcubature_v itself inside a job, so it needs "
        "the hcubature peer's evaluations plus the job's fixed cost (compile the spec, plan one pass, one "
        "block, the result): its time ratio against hcubature cannot go far below 1. Earlier (RQMC): "
        "tally and SciPy need about as many evaluations (same algorithm family, see the median "
        "evaluations); tally's randomized Sobol points cost one XOR per coordinate. Each randomization is "
        "a random linear (matrix) scramble plus digital shift applied once to the direction numbers "
        "(common/sampling/qmc.hpp, ScrambledSobolSet; Owen 2003: same variance as the nested uniform "
        "scramble), points are enumerated in Gray-code order, and the integrand is evaluated in batches of "
        "256 by the compiled integrand. An earlier version hashed every bit of every coordinate (Owen's "
        "nested scramble, 64 mixes per coordinate) and was 8× slower than SciPy on the same suite.\n")
    head.append(f"Peers, against the study's goals (section 6): {goals_line}. "
                f"Median-instance time ratio tally / best peer ({best_m}) = {med_ratio:.2f}, "
                f"tally / best GSL ({gsl_best}) = {gsl_ratio:.2f}; per-instance median "
                f"ratio vs fastest peer = {per_med:.2f}; coverage tally {s['tally']['cov'] * 100:.0f}%, "
                + ", ".join(f"{m} {s[m]['cov'] * 100:.0f}%" for m in methods[1:]) + ".")
    # plot: time to 3 digits per method, all instances (cdf)
    fig, ax = plt.subplots(figsize=(6.5, 4.2))
    for m in methods:
        ts = sorted(by[k][m][0] for k in allk if m in by[k])
        fin = [t for t in ts if t < math.inf]
        if fin:
            ax.step(fin, np.arange(1, len(fin) + 1) / len(ts), where="post", label=m)
    ax.set_xscale("log")
    ax.set_xlabel("wall seconds to 3 correct digits")
    ax.set_ylabel("fraction of instances done")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    out.append(save(fig, "peers_time_cdf.png"))
    out.append("")

# ---------------------------------------------------------------- eta
eta = os.path.join(DATA, "eta_example.json")
ETA = rows("eta.csv")
if os.path.exists(eta) and ETA:
    ex = json.load(open(eta))
    out.append("## 7. Reading a job's ETA and cost curve\n")
    out.append(
        "Every running job reports, from its current σ (per-sample standard deviation) and throughput, "
        "`prediction.samples_needed` = (z·σ/ε)² for its target ε (z from the confidence, ε = rel_error·|mean| "
        "or abs_error), `prediction.samples_remaining` (needed minus done) and "
        "`prediction.seconds_remaining` (remaining / samples_per_second), and a `cost_curve`: the samples and "
        "seconds the same arithmetic predicts for relative errors 10⁻², 10⁻³, 10⁻⁴. Because the error of "
        "a Monte Carlo mean falls as N^−1/2, each extra digit costs 100× the samples: the three points "
        "of the curve are two decades apart in cost, and a curve that does not look like that means the "
        "job is not in its N^−1/2 regime yet (RQMC and other sweep estimators count point sets as samples). "
        "`POST /v1/jobs/validate` runs a short pilot and reports the same figures before the job starts. "
        "How to read them:\n")
    out.append(
        "- Early passes: σ is itself an estimate from few samples, so samples_needed moves between passes; "
        "it settles within a few passes (the table below). seconds_remaining also carries the throughput "
        "of the first passes, which includes start-up cost, so it is the noisier of the two.\n"
        "- A job with a heavy-tail warning (`heavy_tail`, e.g. 1/√x under uniform sampling) has no "
        "trustworthy σ: ignore its ETA and change the estimator.\n"
        "- Time scales with the workers a job gets; samples do not.\n")
    out.append("Example (bench/study/eta_study.cpp): Genz gaussian in 4-D, uniform estimator, rel_error 10⁻³ at 95%:\n")
    out.append("| pass | samples so far | rel. error so far | predicted samples needed | predicted seconds remaining |")
    out.append("|---|---|---|---|---|")
    for r in ETA:
        out.append(f"| {r['pass']} | {int(float(r['samples']))} | {float(r['rel_error']):.2e} | "
                   f"{float(r['predicted_samples_needed']):.4g} | {float(r['predicted_seconds_remaining']):.3g} |")
    fin = ex["final"]
    out.append(f"\nThe run then took {fin['samples']} samples and {fin['compute_seconds']:.3g} s "
               f"(stop: {fin['stop_reason']}). Final cost curve: " + "; ".join(
                   f"{c['rel_error']:g} → {c['samples']:.3g} samples, {c['seconds']:.3g} s" for c in ex["cost_curve"])
               + ".\n")
    out.append("tests/study/prediction_test.cpp checks that a short pilot's prediction of the samples a "
               "target needs lands within a factor of 2 of what the real run takes, on several integrands "
               "and a lighting job.\n")

# ---------------------------------------------------------------- image samplers
# bench/sampler_bench writes sampler_convergence.csv (not part of tally-study: it needs a
# few minutes of its own); its section is kept whenever the CSV is there.
SAMPLER_CSV = os.path.join(DATA, "sampler_convergence.csv")
if os.path.exists(SAMPLER_CSV):
    sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))
    import sampler_plot  # noqa: E402

    sampler_plot.plot(SAMPLER_CSV, os.path.join(DATA, "sampler_rmse_time.png"))
    out.append(sampler_plot.section(SAMPLER_CSV, f"![sampler_rmse_time.png]({REL}/sampler_rmse_time.png)"))
    head.append(sampler_plot.headline(SAMPLER_CSV))

# ---------------------------------------------------------------- write
# Section 9 (`tally-study hard`, issue 31) is run on its own (about 20 minutes) and written
# from its CSVs by hand: keep it as it stands in the report.
KEPT = ""
if os.path.exists(REPORT):
    with open(REPORT) as fh:
        old_report = fh.read()
    at = old_report.find("\n## 9. The hard regime")
    if at >= 0:
        KEPT = old_report[at:]
with open(REPORT, "w") as fh:
    fh.write("# What accuracy costs in time\n\n")
    fh.write("Generated by `make study` (scripts/study.sh → build-study/bench/study/tally-study, "
             "bench/peers/scipy_peer.py, bench/study/plot.py) from a fixed, seeded suite run through the "
             "production path (compile_job → JobRunner → run_local). The CSVs behind every plot are in "
             f"[{REL}/]({REL}/). Slopes are least-squares fits on log-log axes over the stated ranges; ✓ marks "
             "a measured slope within ±0.1 of theory.\n\n")
    fh.write("**Headline figures**\n\n")
    for h in head:
        fh.write(f"- {h}\n")
    fh.write("\n")
    fh.write("\n".join(out))
    fh.write("\n")
    fh.write(KEPT)
print(f"[study] wrote {REPORT}", file=sys.stderr)
