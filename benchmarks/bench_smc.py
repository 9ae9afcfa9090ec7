"""Benchmark: SMC on a GP surrogate with the fast batched predictor vs. naive GPy calls.

Cases (paper Sec. 4):

* ``2d``: (E, nu) box [100, 800] Pa x [-0.8, 0.5]; GP on n_train = 1000 Sobol
  points of an analytic banana-shaped log-likelihood (a curved band where low E
  goes with low nu, like the paper's posterior); SMC with N = 5000,
  n_rej = 20, zeta = 0.995.
* ``7d``: six material parameters plus an uncertain inflow, ARD GP on
  n_train = 2000 points of an analytic correlated log-likelihood; SMC with
  N = 10000, n_rej = 30, zeta = 0.998 (the paper's 6+1D setting).

For each case: GP training time (once), then ``--repeats`` SMC runs with the
fast predictor (``GPSurrogate.predict``; median wall time, tempering steps,
surrogate evaluations per second). The naive variant calls GPy's
``model.predict`` (mean and variance, as GPy always computes both) on every
batch; it is timed on the first ``--naive-steps`` tempering steps only and
extrapolated to the full number of steps of the fast run (time per step x
steps) in the 2D case; in the 7D case (a naive step takes minutes) GPy's
predict is timed on ``--naive-batches`` batches of N prior draws and the naive
run is extrapolated as fast wall time + evaluations x (GPy - fast time per
point). The report says which.

Run: ``python benchmarks/bench_smc.py [--cases 2d,7d] [--repeats 3] [--gp-cache /tmp]``

Measured 2026-11-21 on the shared 2-core development VM (load average 4-6 from
other jobs; NumPy backend, 1 thread):

* 2d (``--cases 2d --repeats 3``): median 14.0 s (runs 11.3-14.4 s), 47 steps,
  3.62e6 surrogate evaluations, 2.6e5 evaluations/s; naive GPy 5.0 s/step
  (first 2 steps) -> 236 s extrapolated: 16.8x. GP training (1 start,
  200 iterations) 33-94 s depending on load.
* 7d (``--cases 7d --repeats 1 --max-iters 50``): 374 s (one run), 139 steps,
  2.77e7 evaluations, 7.4e4 evaluations/s; naive GPy 2.62 s per batch of
  10000 vs 0.139 s -> 7258 s extrapolated: 19.4x. GP training 80 s.
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import time

import numpy as np

from bayescalib.inference.design import sobol_design
from bayescalib.inference.gp import GPSurrogate, fit_gp
from bayescalib.inference.parameters import Parameter, ParameterSpace, Uniform
from bayescalib.inference.smc import run_smc


class _Stop(Exception):
    pass


def banana_2d(X: np.ndarray) -> np.ndarray:
    e = (X[:, 0] - 100.0) / 700.0
    n = (X[:, 1] + 0.8) / 1.3
    return -0.5 * ((n - 0.25 - 0.8 * e**1.5) / 0.04) ** 2 - 0.5 * ((e - 0.4) / 0.2) ** 2


BOX_7D = np.array(
    [[100, 800], [-0.8, 0.5], [100, 800], [-0.8, 0.5], [300, 1500], [-0.8, 0.5], [0, 110]],
    dtype=float,
)


def _loglik_7d_factory():
    rng = np.random.default_rng(123)
    A = rng.normal(size=(7, 7))
    prec = A @ A.T / 7 + np.eye(7)
    prec *= 40.0
    centre = np.array([0.57, 0.77, 0.14, 0.69, 0.58, 0.85, 0.91])

    def loglik(X: np.ndarray) -> np.ndarray:
        U = (X - BOX_7D[:, 0]) / (BOX_7D[:, 1] - BOX_7D[:, 0])
        D = U - centre
        D[:, 1] += 0.3 * D[:, 0] ** 2  # mild curvature
        return -0.5 * np.einsum("ni,ij,nj->n", D, prec, D)

    return loglik


def _space(box: np.ndarray, uncertain_last: bool) -> ParameterSpace:
    ps = []
    for j, (lo, hi) in enumerate(box):
        ps.append(
            Parameter(
                f"p{j}", "-", Uniform(lo, hi), lo, hi, uncertain=uncertain_last and j == len(box) - 1
            )
        )
    return ParameterSpace(ps)


def run_case(name, space, true_loglik, n_train, N, n_rej, zeta, ard, repeats, naive_mode, naive_k,
             max_iters, threads=1, gp_cache=None):
    print(f"\n=== case {name}: d = {space.dim}, n_train = {n_train}, N = {N}, n_rej = {n_rej}, "
          f"zeta = {zeta}, ARD = {ard}")
    X = sobol_design(space.bounds, n_train, 0)
    y = true_loglik(X)
    cache = None if gp_cache is None else os.path.join(gp_cache, f"bench_gp_{name}_{max_iters}.h5")
    if cache is not None and os.path.exists(cache):
        gp = GPSurrogate.load(cache)
        print(f"GP loaded from {cache}")
    else:
        t = time.perf_counter()
        gp = fit_gp(X, y, bounds=space.bounds, ard=ard, restarts=1, seed=0, max_iters=max_iters,
                    kernel="matern32", nugget="fixed", mean="constant")
        print(f"GP training (1 start, max_iters = {max_iters}): {time.perf_counter() - t:.1f} s")
        if cache is not None:
            gp.save(cache)
    gp.threads = threads
    print(f"lengthscale = {np.round(gp.lengthscale, 3).tolist()}, device = {gp.device}")

    walls, steps, evals = [], [], []
    for r in range(repeats):
        t = time.perf_counter()
        res = run_smc(gp.predict, space, n_particles=N, n_rej=n_rej, zeta=zeta,
                      rng=np.random.default_rng(r))
        walls.append(time.perf_counter() - t)
        steps.append(res.n_steps)
        evals.append(res.n_loglik_evals)
        print(f"  fast run {r}: {walls[-1]:.2f} s, {res.n_steps} steps, "
              f"{res.n_loglik_evals} surrogate evaluations, log Z = {res.log_evidence:.4f}")
    wall = statistics.median(walls)
    n_steps = int(statistics.median(steps))
    n_eval = int(statistics.median(evals))
    print(f"fast: median wall {wall:.2f} s, median steps {n_steps}, "
          f"{n_eval / wall:.3g} surrogate evaluations / s")

    model = gp.gpy_model()

    def naive(Xb: np.ndarray) -> np.ndarray:
        return model.predict(gp.scale_inputs(Xb))[0][:, 0]

    if naive_mode == "steps":
        stamps: list[float] = []

        def cb(info):
            stamps.append(time.perf_counter())
            if len(stamps) >= naive_k:
                raise _Stop

        t0 = time.perf_counter()
        try:
            run_smc(naive, space, n_particles=N, n_rej=n_rej, zeta=zeta,
                    rng=np.random.default_rng(0), callback=cb)
        except _Stop:
            pass
        per_step = (stamps[-1] - t0) / len(stamps)
        naive_total = per_step * n_steps
        print(f"naive GPy predict: {per_step:.2f} s per step over the first {len(stamps)} steps "
              f"(includes the initial prior evaluation), extrapolated to {n_steps} steps: "
              f"{naive_total:.1f} s")
    else:
        Xb = space.sample_prior(N, np.random.default_rng(99))
        t_gpy, t_fast = [], []
        for _ in range(naive_k):
            t = time.perf_counter()
            naive(Xb)
            t_gpy.append(time.perf_counter() - t)
            t = time.perf_counter()
            gp.predict(Xb)
            t_fast.append(time.perf_counter() - t)
        g, f = statistics.median(t_gpy) / N, statistics.median(t_fast) / N
        naive_total = wall + n_eval * (g - f)
        print(f"naive GPy predict: {g * N:.2f} s per batch of {N} (fast: {f * N:.3f} s), median of "
              f"{naive_k} batches; extrapolated: fast wall + {n_eval} evaluations x difference "
              f"= {naive_total:.1f} s")
    print(f"speed-up (naive / fast): {naive_total / wall:.1f}x")
    return {"wall": wall, "steps": n_steps, "evals_per_s": n_eval / wall,
            "naive": naive_total, "speedup": naive_total / wall}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--cases", default="2d,7d")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--naive-steps", type=int, default=2,
                    help="2d: time the naive SMC on this many tempering steps")
    ap.add_argument("--naive-batches", type=int, default=3,
                    help="7d: time GPy predict on this many batches of N points")
    ap.add_argument("--gp-cache", default=None, help="folder to save/load the trained benchmark GPs")
    ap.add_argument("--max-iters", type=int, default=200, help="GP optimizer iterations")
    ap.add_argument("--threads", type=int, default=1, help="CPU threads of the fast predictor")
    a = ap.parse_args()
    print(f"host: {platform.node()} ({platform.processor() or platform.machine()}), "
          f"numpy {np.__version__}, {os.cpu_count()} CPUs, load average {os.getloadavg()}")
    cases = a.cases.split(",")
    if "2d" in cases:
        box = np.array([[100.0, 800.0], [-0.8, 0.5]])
        run_case("2d", _space(box, False), banana_2d, 1000, 5000, 20, 0.995, False,
                 a.repeats, "steps", a.naive_steps, a.max_iters, a.threads, a.gp_cache)
    if "7d" in cases:
        run_case("7d", _space(BOX_7D, True), _loglik_7d_factory(), 2000, 10000, 30, 0.998, True,
                 a.repeats, "batches", a.naive_batches, a.max_iters, a.threads, a.gp_cache)


if __name__ == "__main__":
    main()
