#!/usr/bin/python3
"""SciPy's qmc_quad on the study's Genz instances (instances.json from
`tally-study peers`), driven to the same target as tally and the GSL peers: the
reported 95% half-width (Student t with n_estimates - 1 degrees of freedom on
qmc_quad's standard error) <= rel_target * |estimate|. A user does not know the
points needed, so n_points doubles from 1024 (Sobol: powers of 2) and every call
starts afresh; seconds and evaluations are cumulative over the calls, as the user
pays them.

scipy.integrate.qmc_quad arrived in SciPy 1.11; Debian 12 ships 1.10.1, so when it is
missing this uses the same algorithm written with scipy.stats.qmc.Sobol: n_estimates
independently scrambled Sobol point sets, the mean of their estimates and the standard
error of that mean (std with ddof=1 / sqrt(n_estimates)), as qmc_quad does.
Usage: scipy_peer.py DIR  (reads DIR/instances.json, writes DIR/peers_scipy.csv)
       scipy_peer.py DIR --hard  (the hard regime, `tally-study hard`: reads
       DIR/hard_instances.json, each instance with its own target; writes DIR/hard_scipy.csv
       with hard.csv's columns)
"""
import csv
import json
import sys
import time

import numpy as np
import scipy
from scipy import stats

try:
    from scipy.integrate import qmc_quad
    QMC_QUAD = "scipy.integrate.qmc_quad"
except ImportError:  # SciPy < 1.11
    QMC_QUAD = "qmc_quad equivalent on scipy.stats.qmc.Sobol"

    class _Result:
        def __init__(self, integral, standard_error):
            self.integral = integral
            self.standard_error = standard_error

    def qmc_quad(func, a, b, n_estimates, n_points, qrng):
        d = len(a)
        vol = float(np.prod(np.asarray(b) - np.asarray(a)))
        seeds = qrng.rng.spawn(n_estimates) if hasattr(qrng.rng, "spawn") else [
            np.random.default_rng(qrng.rng.integers(2**63)) for _ in range(n_estimates)]
        est = np.empty(n_estimates)
        for i, s in enumerate(seeds):
            x = stats.qmc.Sobol(d, scramble=True, seed=s).random(n_points)
            x = np.asarray(a) + (np.asarray(b) - np.asarray(a)) * x
            est[i] = vol * np.mean(func(x.T))
        return _Result(np.mean(est), np.std(est, ddof=1) / np.sqrt(n_estimates))


def genz(fi, a, u):
    a = np.asarray(a)[:, None]
    u = np.asarray(u)[:, None]
    d = a.shape[0]
    if fi == 0:
        return lambda x: np.cos(2 * np.pi * u[0, 0] + np.sum(a * x, axis=0))
    if fi == 1:
        return lambda x: np.prod(1.0 / (a ** -2 + (x - u) ** 2), axis=0)
    if fi == 2:
        return lambda x: (1.0 + np.sum(a * x, axis=0)) ** (-(d + 1))
    if fi == 3:
        return lambda x: np.exp(-np.sum(a * a * (x - u) ** 2, axis=0))
    if fi == 4:
        return lambda x: np.exp(-np.sum(a * np.abs(x - u), axis=0))

    def disc(x):
        inside = (x[0] <= u[0, 0]) & (x[1] <= u[1, 0])
        return np.where(inside, np.exp(np.sum(a * x, axis=0)), 0.0)

    return disc


def main():
    out = sys.argv[1]
    hard = sys.argv[2:] == ["--hard"]
    spec = json.load(open(f"{out}/{'hard_instances' if hard else 'instances'}.json"))
    max_evals = spec["max_evaluations"]
    max_seconds = spec["max_seconds"]
    n_estimates = 8
    tq = stats.t.ppf(0.975, n_estimates - 1)
    cols = ["family", "d"] + (["target"] if hard else []) + [
        "instance", "method", "estimate", "exact", "rel_error", "reported_half_width", "seconds",
        "evaluations", "converged", "correct", "covered", "note"]
    with open(f"{out}/{'hard_scipy' if hard else 'peers_scipy'}.csv", "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(cols)
        for inst in spec["instances"]:
            target = inst["target"] if hard else spec["rel_target"]
            d = inst["d"]
            f = genz(inst["family_index"], inst["a"], inst["u"])
            exact = inst["exact"]
            rng = np.random.default_rng(inst["instance"] + 1)
            t0 = time.perf_counter()
            evals, n_points, converged = 0, 1024, False
            while True:
                qrng = stats.qmc.Sobol(d, scramble=True, seed=rng)
                res = qmc_quad(f, np.zeros(d), np.ones(d), n_estimates=n_estimates, n_points=n_points, qrng=qrng)
                evals += n_estimates * n_points
                est, hw = float(res.integral), float(tq * res.standard_error)
                if hw <= target * abs(est):
                    converged = True
                    break
                if evals >= max_evals or time.perf_counter() - t0 >= max_seconds:
                    break
                n_points *= 2
            secs = time.perf_counter() - t0
            err = abs(est - exact)
            w.writerow([inst["family"], d] + ([repr(target)] if hard else []) + [
                inst["instance"], "scipy_qmc_quad", repr(est), repr(exact), repr(err / abs(exact)), repr(hw),
                repr(secs), evals, int(converged), int(err <= target * abs(exact)), int(err <= hw),
                "" if converged else "cap"])
            if hard:
                print(f"[study] hard {inst['family']} {d} {target:g} scipy_qmc_quad: "
                      f"{'reached' if converged and err <= target * abs(exact) else 'not reached'} "
                      f"in {secs:.3g} s, covered {int(err <= hw)}", file=sys.stderr)
    print(f"[study] scipy {scipy.__version__} ({QMC_QUAD}): {len(spec['instances'])} instances done", file=sys.stderr)


if __name__ == "__main__":
    main()
