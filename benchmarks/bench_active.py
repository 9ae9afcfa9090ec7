"""Benchmark: surrogate-based Bayesian inference methods at an equal number of likelihood evaluations.

What is compared
----------------
Each method gets the same analytic log-likelihood, the same uniform prior on a
box and the same budget of log-likelihood evaluations, and returns a posterior
(weighted samples and, where it has one, a density). The posterior is compared
with a reference that is computed from the exact density, independently of
every method:

* ``ridge2d``: a curved ridge (banana), L = -0.5 (x1/s1)^2 - 0.5 ((x2 - b x1^2)/s2)^2.
* ``lobe2d``: a main mode and a weak second lobe with another covariance,
  L = log(w1 N1 + w2 N2) + c; its bound B is the log of an upper bound of the mixture.
* ``bimodal2d``: two narrow modes about 16 sd apart with 73 % and 27 % of the mass
  (``benchmarks/bench_modes.py``: the verdict must never say converged with one missing).
* ``bimodal4d``: the same in four dimensions, about 20 sd apart, rotated covariances
  (reference: the mixture's exact moments).
* ``sloppy4d``: a 4D Gaussian with a rotated covariance and one sloppy direction.
* ``hetero7d``: a made-up 7D calibration shaped like the heterogeneous biofilm
  study: stiffnesses E1..E3 (Pa), Poisson ratios nu1..nu3 and an uncertain
  inflow q; an interface-displacement model at 40 points, synthetic noisy data,
  a Gaussian misfit (B = 0). E2 is poorly identified along a ridge with nu2
  and q.

Every log-likelihood has the misfit form L = B - Phi with Phi >= 0 and a known
upper bound B (passed to the methods that take one). References: a 400 x 400
grid of the exact density (2D); the closed-form mean and covariance
(``sloppy4d``); a long adaptive random-walk Metropolis run on the exact
log-posterior (``hetero7d``; 16 seeded chains, proposal covariance and scale
adapted during burn-in only, then frozen), cached in
``<out>/reference_hetero7d.npz`` (delete it or pass ``--refresh-reference`` to
recompute).

Methods
-------
* ``sobol_gp``: today's pipeline: a scrambled Sobol design of the whole budget,
  the GP surrogate of the log-likelihood (``bayescalib.inference.gp.fit.fit_gp``) and
  SMC on its mean (``bayescalib.inference.smc.run_smc``).
* ``active``: ``bayescalib.inference.rounds.calibrate`` (active design in batches of 8,
  ``max_solves`` = budget, a quarter of the budget as initial design). Reported
  as "not available" when the module does not import. ``active_vbmc``: the same with
  VBMC's prospective uncertainty in the acquisition (``posterior_power`` 2), so that
  both are measured in one run. ``--ard``, ``--nugget-factor``, ``--nugget`` and
  ``--nugget-floor`` set the surrogate of both; ``--trace`` records each round's accuracy (``trace`` in the
  results: Hellinger of that round's surrogate on the grid in 2D, and the moment
  metrics of that round's own SMC, 4000 particles).
* ``emulator`` (least-squares problems only: ``hetero7d``): the emulator of the model's
  outputs (``bayescalib.inference.emulator``: principal output directions, one GP per
  coordinate, the Gaussian likelihood computed from the emulated outputs with the
  emulator's uncertainty integrated out) in rounds of ``EMULATOR_BATCH`` = 16 posterior
  draws, each round's draws the previous posterior's importance check; converged when
  a check confirms it and the posterior moved by at most 0.2 sd (``run_emulator``). Its
  metrics use its own final SMC (8000 particles), not the common 20 000-particle one.
* ``pyvbmc``: PyVBMC (``max_fun_evals`` = budget; hard bounds = box, plausible
  bounds = the central 80 % of the box, start at the box centre); 1e5 samples
  of the variational posterior, ``vp.pdf`` on the grid in 2D.
* ``gpry``: GPry 4.1 (Gammal, Torrado, Lesgourgues 2023) with its defaults: ``Runner``
  with the NORA acquisition (nested sampling of the surrogate, batches of d points),
  an RBF GP with an SVM classifier of the region where the log-posterior is effectively
  -inf, 3d initial points, and its own convergence criteria (CorrectCounter,
  GaussianKL between successive surrogates, TrainAlignment); ``max_total`` = budget.
  Seeded through ``seed`` and NumPy's global generator (its nested sampler, UltraNest
  here, takes no seed). The metrics use 20 000 draws of the same SMC as the other
  surrogate methods on its surrogate log-likelihood; the moments of GPry's own final
  nested sample (50 live points per dimension) are kept in the results as
  ``own_sample``; in 2D its surrogate log-posterior on the grid.

Metrics (per problem and method; medians over the seeds, ``--seeds`` or ``--repeats``)
-------------------------------------------------------------------
* ``evals``: log-likelihood evaluations actually made (counted by a wrapper).
* ``rounds``: sequential rounds of evaluations: 1 for ``sobol_gp`` (one batch);
  ``res.n_rounds`` for ``active``; evaluations for ``pyvbmc`` (sequential);
  for ``gpry`` its batches: the blocks of 3d initial points it drew (it draws another
  block while too few values count as finite) plus its acquisition batches of d points.
* ``wall_s``: wall time of the method (design, fits, sampling), without the
  metric computation.
* ``hellinger`` (2D): Hellinger distance between the reference grid masses and
  the method's density on the same grid (surrogate methods: exp(mean log-lik +
  log prior) normalized on the grid; PyVBMC: ``vp.pdf``; GPry: its surrogate
  log-posterior, or, if that fails, 30 x 30 histograms of samples on both
  sides, marked ``hist30``).
* ``mean_err`` / ``sd_err``: max over parameters of |mean - mean_ref| / sd_ref
  and |sd - sd_ref| / sd_ref, from the method's (weighted) samples. For the surrogate
  methods (``sobol_gp``, ``active``, ``gpry``) these are the draws of one and the same
  sampler, SMC with ``METRIC_PARTICLES`` = 20 000 particles on the final surrogate's
  mean, so that no method is penalized for its own sampler (with 4000 particles the
  KL of ``sloppy4d`` has a floor of 0.002-0.004 from the draws alone, with 20 000
  0.0006-0.0008). The row ``floor`` of each problem: the same SMC on the exact
  log-likelihood, the best these metrics can show.
* ``kl_gauss``: KL(reference || method) between moment-matched Gaussians.
* ``active`` also reports ``converged`` and ``reason``, and on ``hetero7d`` (a
  least-squares likelihood of 40 measurements) the absolute fit check of its best
  evaluation (``fit``).

Run (repository root as working directory)::

    python benchmarks/bench_active.py                       # all problems and methods
    python benchmarks/bench_active.py --problems ridge2d,lobe2d --methods sobol_gp,pyvbmc
    python benchmarks/bench_active.py --budget 128 --repeats 3 --out results/bench_active
    python benchmarks/bench_active.py --methods active --seeds '2d=0-4;4d=0-2;7d=0-2'
    python benchmarks/bench_active.py --problems ridge2d,lobe2d,sloppy4d --methods active,active_vbmc \
        --seeds '2d=0-2;4d=0-2' --trace                    # posterior_power 1 and 2

With several seeds the table gives the median and, in brackets, the range over the
seeds; each ``active`` run's evaluated points are kept in
``<out>/design_<problem>_active_seed<s>.npz`` (X, loglik, kind: initial, acquired,
ascent or check).

Writes ``<out>/table.md`` (the markdown table that is also printed) and
``<out>/results.json`` (all numbers, per repeat). On a shared machine,
``OMP_NUM_THREADS=1`` keeps the timings comparable.

Optional peers (not dependencies of bayescalib); install them into the same
environment without moving the pinned numerical stack::

    pip freeze | grep -iE '^(torch|numpy|scipy)==' > /tmp/constraints.txt
    pip install -c /tmp/constraints.txt pyvbmc gpry

A peer that does not import is reported as "not installed".
"""

from __future__ import annotations

import argparse
import hashlib
import json
import math
import os
import platform
import statistics
import sys
import time
import traceback
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

DEFAULT_BUDGET = {2: 64, 4: 100, 7: 200}
ALL_PROBLEMS = ["ridge2d", "lobe2d", "bimodal2d", "bimodal4d", "sloppy4d", "hetero7d"]
ALL_METHODS = ["sobol_gp", "active", "pyvbmc", "gpry"]

#: surrogate.kernel of the active method (--kernel; "auto" fits every kernel each round)
ACTIVE_KERNEL = "auto"
#: surrogate.frame of the active method (--frame; "auto": axes and principal axes, each round)
ACTIVE_FRAME = "auto"
#: surrogate.mean of the active method (--mean; None: the schema's default)
ACTIVE_MEAN: str | None = None
#: surrogate.reselect_growth of the active method (None: the schema's default); set per
#: variant by --reselect-growth (methods named ``active[rg=<value>]``)
ACTIVE_RESELECT: float | None = None
#: further surrogate settings of the active methods (--ard, --nugget-factor, --nugget,
#: --nugget-floor; empty: the schema's defaults)
ACTIVE_SURROGATE: dict[str, Any] = {}
#: design.active settings of the method ``active`` (the schema's) and ``active_vbmc`` (VBMC's
#: prospective uncertainty: the surrogate posterior squared in the score), so that both run in
#: the same benchmark run
ACQUISITIONS: dict[str, dict[str, Any]] = {
    "active": {},
    "active_vbmc": {"posterior_power": 2.0},
}
#: record the active design's accuracy after every round (--trace)
TRACE = False
GRID_N = 400
#: particles of the SMC run on each surrogate method's final surrogate (sobol_gp, active, gpry)
#: whose draws the moment metrics use: the same sampler for every method, so that a method is
#: not penalized for its own sampler (GPry's own final nested sample, 50 live points per
#: dimension, has an effective size of a few hundred to a few thousand; active's own final SMC
#: has 4000 particles; their metrics are kept in the results as ``own_sample``). The floor of
#: the metrics with this sampler, SMC on the exact log-likelihood, is reported per problem.
METRIC_PARTICLES = 20000
GPRY_SMC_PARTICLES = METRIC_PARTICLES
HIST_N = 30


class NotAvailable(Exception):
    """The method cannot run here (module missing); the message says why."""


# ---------------------------------------------------------------------------
# problems
# ---------------------------------------------------------------------------


@dataclass
class Problem:
    name: str
    names: list[str]
    bounds: np.ndarray  # (d, 2)
    loglik: Callable[[np.ndarray], np.ndarray]  # (q, d) -> (q,)
    B: float  # upper bound of loglik
    ref_mean: np.ndarray | None = None
    ref_cov: np.ndarray | None = None
    grid_axes: tuple[np.ndarray, np.ndarray] | None = None  # 2D only: cell centres
    ref_grid: np.ndarray | None = None  # 2D only: (n1, n2) cell masses, sum 1
    ref_info: dict[str, Any] = field(default_factory=dict)
    # least-squares problems: the model's outputs and the data in noise units, so that
    # loglik = B - 1/2 |y - outputs(X)|^2 (the ``emulator`` method needs them)
    outputs: Callable[[np.ndarray], np.ndarray] | None = None
    y: np.ndarray | None = None
    # problems with separated modes: (q, d) points -> (q,) index of the mode each is in
    component: Callable[[np.ndarray], np.ndarray] | None = None

    @property
    def d(self) -> int:
        return self.bounds.shape[0]

    @property
    def ref_sd(self) -> np.ndarray:
        return np.sqrt(np.diag(self.ref_cov))

    def grid_points(self) -> np.ndarray:
        g1, g2 = self.grid_axes
        G1, G2 = np.meshgrid(g1, g2, indexing="ij")
        return np.column_stack([G1.ravel(), G2.ravel()])


def _mvn_logpdf(X: np.ndarray, m: np.ndarray, S: np.ndarray) -> np.ndarray:
    L = np.linalg.cholesky(S)
    Z = np.linalg.solve(L, (X - m).T)
    return -0.5 * np.sum(Z * Z, axis=0) - np.log(np.diag(L)).sum() - 0.5 * len(m) * np.log(2 * np.pi)


def _cov2(sd1: float, sd2: float, rho: float) -> np.ndarray:
    return np.array([[sd1**2, rho * sd1 * sd2], [rho * sd1 * sd2, sd2**2]])


def _grid_reference(prob: Problem) -> None:
    """Fill the grid, the grid masses and the moments of a 2D problem from its exact density."""
    b = prob.bounds
    axes = []
    for lo, hi in b:
        h = (hi - lo) / GRID_N
        axes.append(lo + h * (np.arange(GRID_N) + 0.5))
    prob.grid_axes = (axes[0], axes[1])
    P = _normalize_log(prob.loglik(prob.grid_points())).reshape(GRID_N, GRID_N)
    prob.ref_grid = P
    X = prob.grid_points()
    w = P.ravel()
    m = w @ X
    C = (X - m).T @ ((X - m) * w[:, None])
    prob.ref_mean, prob.ref_cov = m, C
    prob.ref_info = {"kind": f"exact density on a {GRID_N}x{GRID_N} grid (cell centres)"}


def _two_modes(w1: float, m1: np.ndarray, S1: np.ndarray, w2: float, m2: np.ndarray,
               S2: np.ndarray) -> tuple[Callable, Callable]:
    """The log-likelihood log(w1 N(m1, S1) + w2 N(m2, S2)) and the mode of a point (the
    larger weighted density: 0 or 1), of the two-mode problems."""

    def loglik(X):
        X = np.atleast_2d(X)
        return np.logaddexp(np.log(w1) + _mvn_logpdf(X, m1, S1),
                            np.log(w2) + _mvn_logpdf(X, m2, S2))

    def component(X):
        X = np.atleast_2d(X)
        return (np.log(w2) + _mvn_logpdf(X, m2, S2) > np.log(w1) + _mvn_logpdf(X, m1, S1)
                ).astype(int)

    return loglik, component


def make_ridge2d() -> Problem:
    s1, b, s2 = 1.0, 0.6, 0.25

    def loglik(X):
        X = np.atleast_2d(X)
        return -0.5 * (X[:, 0] / s1) ** 2 - 0.5 * ((X[:, 1] - b * X[:, 0] ** 2) / s2) ** 2

    prob = Problem("ridge2d", ["x1", "x2"], np.array([[-4.0, 4.0], [-3.0, 8.0]]), loglik, 0.0)
    _grid_reference(prob)
    return prob


def make_lobe2d() -> Problem:
    w1, w2 = 0.88, 0.12
    m1, S1 = np.array([-1.0, -0.5]), _cov2(0.7, 0.5, 0.6)
    m2, S2 = np.array([2.2, 2.3]), _cov2(0.35, 0.6, -0.5)
    c = 0.0
    peak1 = 1.0 / (2 * np.pi * np.sqrt(np.linalg.det(S1)))
    peak2 = 1.0 / (2 * np.pi * np.sqrt(np.linalg.det(S2)))
    B = float(np.log(w1 * peak1 + w2 * peak2) + c)

    def loglik(X):
        X = np.atleast_2d(X)
        a = np.log(w1) + _mvn_logpdf(X, m1, S1)
        bb = np.log(w2) + _mvn_logpdf(X, m2, S2)
        return np.logaddexp(a, bb) + c

    def component(X):  # which mode a point belongs to: the larger weighted density
        X = np.atleast_2d(X)
        return (np.log(w2) + _mvn_logpdf(X, m2, S2) > np.log(w1) + _mvn_logpdf(X, m1, S1)
                ).astype(int)

    prob = Problem("lobe2d", ["x1", "x2"], np.array([[-5.0, 5.0], [-5.0, 5.0]]), loglik, B)
    _grid_reference(prob)
    prob.ref_info["modes"] = {"weights": [w1, w2], "means": [m1.tolist(), m2.tolist()]}
    prob.component = component
    return prob


def make_bimodal2d() -> Problem:
    """Two narrow modes, 1.8 apart in a box of 10 x 10 (about 16 sd of either), with 73 %
    and 27 % of the mass: a Sobol design of 32 points often lands no point near one of
    them, and the surrogate of the other's bowl predicts it low and confidently."""
    w1, w2 = 0.73, 0.27
    m1, S1 = np.array([-1.0, -0.5]), _cov2(0.1, 0.08, 0.3)
    m2, S2 = np.array([0.6, 0.4]), _cov2(0.08, 0.12, -0.4)
    peak1 = 1.0 / (2 * np.pi * np.sqrt(np.linalg.det(S1)))
    peak2 = 1.0 / (2 * np.pi * np.sqrt(np.linalg.det(S2)))
    B = float(np.log(w1 * peak1 + w2 * peak2))
    loglik, component = _two_modes(w1, m1, S1, w2, m2, S2)
    prob = Problem("bimodal2d", ["x1", "x2"], np.array([[-5.0, 5.0], [-5.0, 5.0]]), loglik, B)
    _grid_reference(prob)
    prob.ref_info["modes"] = {"weights": [w1, w2], "means": [m1.tolist(), m2.tolist()]}
    prob.component = component
    return prob


def make_bimodal4d() -> Problem:
    """``bimodal2d`` in four dimensions: two narrow correlated modes about 20 sd apart
    (sds 0.05-0.14, rotated), with 73 % and 27 % of the mass, in [-5, 5]^4. Above 3
    dimensions the exploration audit's first pass fits diagonal quadratics. Reference: the
    mixture's exact moments and mode masses (the box cuts off nothing of either mode)."""
    w1, w2 = 0.73, 0.27
    rng = np.random.default_rng(20261128)

    def cov(sds):
        Q, R = np.linalg.qr(rng.standard_normal((4, 4)))
        Q = Q * np.sign(np.diag(R))
        return Q @ np.diag(np.square(sds)) @ Q.T

    S1, S2 = cov([0.06, 0.08, 0.1, 0.12]), cov([0.05, 0.08, 0.1, 0.14])
    m1, m2 = np.array([-1.0, -0.5, 0.4, 0.8]), np.array([0.6, 0.4, -0.5, -0.3])
    peak1 = 1.0 / np.sqrt(np.linalg.det(2 * np.pi * S1))
    peak2 = 1.0 / np.sqrt(np.linalg.det(2 * np.pi * S2))
    B = float(np.log(w1 * peak1 + w2 * peak2))
    loglik, component = _two_modes(w1, m1, S1, w2, m2, S2)
    m = w1 * m1 + w2 * m2
    C = w1 * (S1 + np.outer(m1, m1)) + w2 * (S2 + np.outer(m2, m2)) - np.outer(m, m)
    prob = Problem("bimodal4d", ["x1", "x2", "x3", "x4"], np.tile([-5.0, 5.0], (4, 1)),
                   loglik, B, m, C)
    prob.ref_info = {"kind": "exact moments of the Gaussian mixture",
                     "modes": {"weights": [w1, w2], "means": [m1.tolist(), m2.tolist()]}}
    prob.component = component
    return prob


def make_sloppy4d() -> Problem:
    sds = np.array([0.04, 0.12, 0.35, 1.0])  # stiffest : sloppiest = 1 : 25
    rng = np.random.default_rng(20240601)
    Q, R = np.linalg.qr(rng.standard_normal((4, 4)))
    Q = Q * np.sign(np.diag(R))
    C = Q @ np.diag(sds**2) @ Q.T
    m = np.array([0.3, -0.2, 0.5, 0.1])
    P = np.linalg.inv(C)

    def loglik(X):
        X = np.atleast_2d(X)
        D = X - m
        return -0.5 * np.einsum("ij,jk,ik->i", D, P, D)

    prob = Problem(
        "sloppy4d", ["x1", "x2", "x3", "x4"], np.tile([-5.0, 5.0], (4, 1)), loglik, 0.0, m, C
    )
    prob.ref_info = {
        "kind": "closed-form Gaussian mean and covariance (box truncation beyond 4.5 sd ignored)",
        "sd_ratio": float(sds[-1] / sds[0]),
    }
    return prob


# hetero7d: made-up interface-displacement model --------------------------------

H7_NAMES = ["E1", "E2", "E3", "nu1", "nu2", "nu3", "q"]
H7_BOUNDS = np.array(
    [[100.0, 800.0]] * 3 + [[-0.5, 0.49]] * 3 + [[85.0, 115.0]]
)
H7_TRUTH = np.array([400.0, 200.0, 600.0, 0.3, 0.2, 0.3, 100.0])
H7_SIGMA = 0.004
H7_NOISE_SEED = 12345
H7_K = 40
H7_RWM = {"chains": 16, "burn": 20000, "steps": 40000, "thin": 4, "seed": 7}


def _h7_patterns() -> tuple[np.ndarray, np.ndarray]:
    s = np.linspace(0.0, 1.0, H7_K)
    centres, width = np.array([0.2, 0.5, 0.8]), 0.14
    weight = np.array([1.0, 0.35, 1.0])  # region 2 is seen weakly
    A = np.exp(-0.5 * ((s[:, None] - centres) / width) ** 2) * weight
    C = 0.6 * np.exp(-0.5 * ((s[:, None] - centres - 0.08) / (0.7 * width)) ** 2) * weight
    return A, C


def h7_model(X: np.ndarray) -> np.ndarray:
    """Interface displacement u (q, K): confined-compression and shear compliances, saturating."""
    X = np.atleast_2d(X)
    A, C = _h7_patterns()
    E, nu, q = X[:, 0:3], X[:, 3:6], X[:, 6:7]
    g = (1 + nu) * (1 - 2 * nu) / (1 - nu)  # 1 / (P-wave modulus) * E
    h = 2 * (1 + nu) / 3  # shear compliance * E (scaled)
    w = q * ((g / E) @ A.T + (h / E) @ C.T)
    return w / (1.0 + w)


def make_hetero7d(out: Path, refresh: bool) -> Problem:
    rng = np.random.default_rng(H7_NOISE_SEED)
    y = h7_model(H7_TRUTH)[0] + H7_SIGMA * rng.standard_normal(H7_K)

    def loglik(X):
        r = (h7_model(X) - y) / H7_SIGMA
        return -0.5 * np.sum(r * r, axis=1)

    prob = Problem("hetero7d", list(H7_NAMES), H7_BOUNDS.copy(), loglik, 0.0,
                   outputs=lambda X: h7_model(X) / H7_SIGMA, y=y / H7_SIGMA)
    ref = _h7_reference(prob, out / "reference_hetero7d.npz", refresh)
    prob.ref_mean, prob.ref_cov = ref["mean"], ref["cov"]
    prob.ref_info = {
        "kind": "adaptive random-walk Metropolis on the exact log-posterior",
        "chains": int(ref["chains"]),
        "samples": int(ref["n_samples"]),
        "acceptance": float(ref["acceptance"]),
        "rhat_max": float(np.max(ref["rhat"])),
        "cache": str(out / "reference_hetero7d.npz"),
    }
    return prob


def _h7_key() -> str:
    spec = repr((H7_BOUNDS.tolist(), H7_TRUTH.tolist(), H7_SIGMA, H7_NOISE_SEED, H7_K, H7_RWM, 2))
    return hashlib.sha256(spec.encode()).hexdigest()[:16]


def _h7_reference(prob: Problem, path: Path, refresh: bool) -> dict[str, Any]:
    key = _h7_key()
    if path.exists() and not refresh:
        with np.load(path) as z:
            if str(z["key"]) == key:
                return {k: z[k] for k in z.files}
        print(f"[hetero7d] reference cache {path} is for another problem definition; recomputing")
    print("[hetero7d] computing the reference (adaptive random-walk Metropolis) ...", flush=True)
    t0 = time.perf_counter()
    lo, hi = prob.bounds[:, 0], prob.bounds[:, 1]
    d = prob.d
    n_ch, n_burn, n_steps, thin = H7_RWM["chains"], H7_RWM["burn"], H7_RWM["steps"], H7_RWM["thin"]
    rng = np.random.default_rng(H7_RWM["seed"])

    def logpost(X):
        out = np.full(X.shape[0], -np.inf)
        ok = np.all((X >= lo) & (X <= hi), axis=1)
        if ok.any():
            out[ok] = prob.loglik(X[ok])  # uniform prior: constant
        return out

    x = np.clip(H7_TRUTH + 1e-3 * (hi - lo) * rng.standard_normal((n_ch, d)), lo, hi)
    lp = logpost(x)
    Lc = np.diag(0.01 * (hi - lo))
    lam = 1.0
    burn_hist = np.empty((n_burn, n_ch, d))
    acc_burn = np.empty(n_burn)
    for t in range(n_burn):
        if t >= 2000 and t % 500 == 0:
            H = burn_hist[t // 2 : t].reshape(-1, d)  # second half of the burn-in so far
            cov = np.cov(H.T) * (2.38**2 / d) * lam + 1e-12 * np.diag((hi - lo) ** 2)
            Lc = np.linalg.cholesky(cov)
        prop = x + rng.standard_normal((n_ch, d)) @ Lc.T
        lpp = logpost(prop)
        a = np.log(rng.random(n_ch)) < lpp - lp
        x[a], lp[a] = prop[a], lpp[a]
        burn_hist[t] = x
        acc_burn[t] = a.mean()
        if t >= 2000 and t % 500 == 499:
            lam *= math.exp(float(acc_burn[t - 499 : t + 1].mean()) - 0.25)
    # frozen proposal from here on: a valid Metropolis chain
    chain = np.empty((n_steps, n_ch, d))
    n_acc = 0.0
    for t in range(n_steps):
        prop = x + rng.standard_normal((n_ch, d)) @ Lc.T
        lpp = logpost(prop)
        a = np.log(rng.random(n_ch)) < lpp - lp
        x[a], lp[a] = prop[a], lpp[a]
        chain[t] = x
        n_acc += a.sum()
    flat = chain.reshape(-1, d)
    mean, cov = flat.mean(0), np.cov(flat.T)
    cm = chain.mean(0)  # (chains, d)
    W = chain.var(0, ddof=1).mean(0)
    Bv = n_steps * cm.var(0, ddof=1)
    rhat = np.sqrt(((n_steps - 1) / n_steps * W + Bv / n_steps) / W)
    ref = {
        "key": np.array(key),
        "mean": mean,
        "cov": cov,
        "rhat": rhat,
        "acceptance": np.array(n_acc / (n_steps * n_ch)),
        "chains": np.array(n_ch),
        "n_samples": np.array(n_steps * n_ch),
        "samples": chain[::thin].reshape(-1, d),
    }
    path.parent.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(path, **ref)
    print(
        f"[hetero7d] reference: {n_steps * n_ch} samples, acceptance {float(ref['acceptance']):.3f}, "
        f"max R-hat {rhat.max():.4f}, {time.perf_counter() - t0:.1f} s",
        flush=True,
    )
    if rhat.max() > 1.02:
        print("[hetero7d] WARNING: R-hat above 1.02; the reference may not have converged")
    return ref


def make_problem(name: str, out: Path, refresh: bool) -> Problem:
    if name == "ridge2d":
        return make_ridge2d()
    if name == "lobe2d":
        return make_lobe2d()
    if name == "bimodal2d":
        return make_bimodal2d()
    if name == "sloppy4d":
        return make_sloppy4d()
    if name == "bimodal4d":
        return make_bimodal4d()
    if name == "hetero7d":
        return make_hetero7d(out, refresh)
    raise SystemExit(f"unknown problem {name!r}; choose from {ALL_PROBLEMS}")


# ---------------------------------------------------------------------------
# helpers
# ---------------------------------------------------------------------------


def _normalize_log(logp: np.ndarray) -> np.ndarray:
    logp = np.asarray(logp, float)
    logp = np.where(np.isnan(logp), -np.inf, logp)
    m = np.max(logp)
    if not np.isfinite(m):
        raise ValueError("density is zero (or NaN) on the whole grid")
    p = np.exp(logp - m)
    return p / p.sum()


class Counter:
    """Wraps a vectorized log-likelihood and counts the points it is asked for."""

    def __init__(self, f: Callable[[np.ndarray], np.ndarray]) -> None:
        self.f, self.n, self.calls = f, 0, 0
        self.best = -math.inf  # the largest finite value seen

    def __call__(self, X: np.ndarray) -> np.ndarray:
        X = np.atleast_2d(np.asarray(X, float))
        self.n += X.shape[0]
        self.calls += 1
        y = np.asarray(self.f(X), float).reshape(-1)
        if np.isfinite(y).any():
            self.best = max(self.best, float(np.max(y[np.isfinite(y)])))
        return y

    def scalar(self, x: np.ndarray) -> float:
        return float(self(np.asarray(x, float).reshape(1, -1))[0])


def make_space(prob: Problem):
    from bayescalib.inference.parameters import ParameterSpace

    return ParameterSpace.from_config(
        [
            {"name": n, "prior": {"type": "uniform", "lo": float(lo), "hi": float(hi)}, "bounds": [float(lo), float(hi)]}
            for n, (lo, hi) in zip(prob.names, prob.bounds)
        ]
    )


def _log_uniform(prob: Problem) -> float:
    return -float(np.sum(np.log(prob.bounds[:, 1] - prob.bounds[:, 0])))


# ---------------------------------------------------------------------------
# methods: each returns a dict with
#   samples (n, d), weights (n,) or None, grid_logpdf (callable on (M, 2) or None),
#   grid_kind (str), n_evals, n_rounds, extra (dict)
# ---------------------------------------------------------------------------


def metric_smc(loglik: Callable[[np.ndarray], np.ndarray], prob: Problem, seed: int):
    """The draws the moment metrics use: the same SMC (``METRIC_PARTICLES`` particles,
    20 rejuvenation steps, zeta 0.95) for every surrogate method and for the floor."""
    from bayescalib.inference.smc import run_smc

    return run_smc(loglik, make_space(prob), n_particles=METRIC_PARTICLES, n_rej=20, zeta=0.95,
                   rng=np.random.default_rng(seed))


def sampler_floor(prob: Problem, seed: int = 0) -> dict[str, Any]:
    """The metrics of :func:`metric_smc` on the exact log-likelihood: what no surrogate
    method can beat with these draws (in 2D the Hellinger distance uses no draws)."""
    res = metric_smc(prob.loglik, prob, seed)
    return {"particles": METRIC_PARTICLES, **moment_metrics(prob, res.particles, res.weights)}


def _round_metrics(prob: Problem, gp, rec: dict[str, Any]) -> dict[str, float]:
    """Accuracy of one round's surrogate: Hellinger on the grid (2D; no draws), and the
    moment metrics of that round's own SMC (its particles; floor of the round sampler)."""
    space = make_space(prob)
    m = np.asarray(rec["posterior"]["mean"], float)
    C = np.asarray(rec["posterior"]["cov"], float)
    sd = np.sqrt(np.diag(C))
    out = {"n_solves": rec["n_solves"],
           "mean_err": float(np.max(np.abs(m - prob.ref_mean) / prob.ref_sd)),
           "sd_err": float(np.max(np.abs(sd - prob.ref_sd) / prob.ref_sd)),
           "kl_gauss": kl_gauss(prob.ref_mean, prob.ref_cov, m, C),
           "surrogate": f"{gp.kernel} of {'log-misfit' if gp.warped else 'L'}"
                        + ("" if gp.rotation is None else ", principal axes")}
    if prob.d == 2:
        G = prob.grid_points()
        Q = _normalize_log(gp.predict(G) + space.logprior(G)).reshape(GRID_N, GRID_N)
        out["hellinger"] = hellinger(prob.ref_grid, Q)
    return out


def run_sobol_gp(prob: Problem, budget: int, seed: int) -> dict[str, Any]:
    from bayescalib.inference.design import sobol_design
    from bayescalib.inference.gp import fit_gp

    f = Counter(prob.loglik)
    space = make_space(prob)
    X = sobol_design(prob.bounds, budget, seed)
    y = f(X)
    gp = fit_gp(X, y, ard=prob.d > 2, bounds=prob.bounds, restarts=3, seed=seed,
                kernel="matern32", nugget="fixed", mean="constant")
    smc = metric_smc(gp.predict, prob, seed)
    return {
        "samples": smc.particles,
        "weights": smc.weights,
        "grid_logpdf": lambda G: gp.predict(G) + space.logprior(G),
        "grid_kind": "surrogate",
        "n_evals": f.n,
        "n_rounds": 1,
        "extra": {"smc_steps": int(smc.n_steps)},
    }


def run_active(prob: Problem, budget: int, seed: int, variant: str = "active") -> dict[str, Any]:
    # Adapter for bayescalib.inference.rounds.calibrate; kept small so that names can follow the API.
    try:
        from bayescalib.inference.rounds import calibrate
    except ImportError as e:
        raise NotAvailable(f"not available (bayescalib.inference.active: {e})") from None
    f = Counter(prob.loglik)
    space = make_space(prob)
    n0 = max(2 * prob.d + 2, budget // 4)
    history: list[dict[str, Any]] = []
    trace: list[dict[str, Any]] = []
    fitted: list[Any] = []  # each round's surrogate (--trace), in the order calibrate fits them
    import bayescalib.inference.gp.selection as surrogate_module

    fit_orig = surrogate_module.fit_round  # each round's surrogate: a search or a refit
    fit_cpu, depth = [0.0], [0]  # CPU s of the surrogate fits (searches and refits)

    def cpu_now() -> float:  # this process's and its waited-for children's (forked fits)
        t = os.times()
        return t.user + t.system + t.children_user + t.children_system

    def timed(fn):
        def run(*args, **kwargs):
            depth[0] += 1
            c0 = cpu_now()
            try:
                return fn(*args, **kwargs)
            finally:
                depth[0] -= 1
                if depth[0] == 0:  # a search inside fit_round counted once
                    fit_cpu[0] += cpu_now() - c0
        return run

    def fit_recorded(*args, **kwargs):
        gp = timed(fit_orig)(*args, **kwargs)
        fitted.append(gp)
        return gp

    def per_round(rec: dict[str, Any]) -> None:  # what the stop rule saw, round by round
        if TRACE:
            trace.append(_round_metrics(prob, fitted[-1], rec))
            tr = trace[-1]
            print(f"    trace: {tr['n_solves']} evals"
                  + (f", Hellinger {tr['hellinger']:.4f}" if "hellinger" in tr else "")
                  + f", KL {tr['kl_gauss']:.4g}, mean err {tr['mean_err']:.3g}, "
                  f"sd err {tr['sd_err']:.3g} ({tr['surrogate']})", flush=True)
        t = rec.get("trust") or {}
        history.append({"round": rec["round"], "n_solves": rec["n_solves"],
                        "trusted": rec["trusted"], "settled": rec["settled"],
                        "max_abs_error": t.get("max_abs_error"),
                        "check_max_underprediction": t.get("check_max_underprediction"),
                        "mean": rec["posterior"]["mean"], "sd": rec["posterior"]["sd"]})
        err = t.get("max_abs_error")
        print(f"    round {rec['round']}: {rec['n_solves']} evals, best {f.best:.4g}, "
              f"trust err {'-' if err is None else f'{err:.3g}'}, "
              f"mean err {np.max(np.abs(np.asarray(rec['posterior']['mean']) - prob.ref_mean) / prob.ref_sd):.3g} ref sd",
              flush=True)

    import bayescalib.inference.gp.selection as sur

    searches = [0]
    full_search = sur.fit_from_config

    def counted(*args: Any, **kwargs: Any) -> Any:  # full searches of the discrete choices
        searches[0] += 1
        return timed(full_search)(*args, **kwargs)

    sur.fit_from_config = counted
    sur.fit_round = fit_recorded
    try:
        res = calibrate(
            f, space, bound=prob.B,
            active={"n_initial": n0, "batch_size": 8, "max_solves": budget,
                    **ACQUISITIONS[variant]},
            surrogate={"kernel": ACTIVE_KERNEL, "frame": ACTIVE_FRAME,
                       **({} if ACTIVE_MEAN is None else {"mean": ACTIVE_MEAN}),
                       **({} if ACTIVE_RESELECT is None else
                          {"reselect_growth": ACTIVE_RESELECT}),
                       **ACTIVE_SURROGATE},
            smc={"n_particles": 4000},
            seed=seed,
            # hetero7d is a least-squares likelihood of H7_K measurements: check the best fit
            n_measurements=H7_K if prob.name == "hetero7d" else None,
            callback=per_round,
        )
    finally:
        sur.fit_from_config = full_search
        sur.fit_round = fit_orig
    gp = res.surrogate
    if int(res.n_evaluations) != f.n:
        print(f"  [active] note: res.n_evaluations={res.n_evaluations} but the counter saw {f.n}")
    pc = res.posterior_check  # the last check round's verdict (its draws are evaluations)
    if pc is not None:
        print(f"    posterior check (round {pc['round']}): {pc['words']}",
              flush=True)
    smc = metric_smc(gp.predict, prob, seed)
    return {
        "samples": smc.particles,
        "weights": smc.weights,
        "grid_logpdf": lambda G: gp.predict(G) + space.logprior(G),
        "grid_kind": "surrogate",
        "n_evals": f.n,
        "n_rounds": int(res.n_rounds),
        "extra": {
            "converged": bool(res.converged),
            "check_confirmed": None if pc is None else bool(pc["confirmed"]),
            "check": None if pc is None else pc["words"],
            "check_evals": sum(len(r["next"]["points"]) for r in res.rounds
                               if "posterior_check" in r.get("next", {}).get("kind", [])),
            "reason": str(res.reason),
            "n_evaluations_reported": int(res.n_evaluations),
            "fit": None if res.fit is None else res.fit["words"],
            "n_initial": n0,
            "n_searches": searches[0],
            "fit_cpu_s": fit_cpu[0],
            # each round's surrogate: why its choices were searched or refitted, and the
            # previous round's largest error at the new values in the posterior region
            "selection": [{"reason": g.selection_reason,
                           "error": None if not np.isfinite(g.selection_error)
                           else float(g.selection_error)}
                          for g in fitted[:res.n_rounds]],  # not the result's search after them
            "acquisition": variant,
            "rounds": history,
            "trace": trace,
            "own_sample": {"particles": len(res.smc.weights),
                           **moment_metrics(prob, res.smc.particles, res.smc.weights)},
        },
        "design": {"X": res.X, "loglik": res.loglik,
                   "kind": np.asarray(_point_kinds(res.rounds, res.n_evaluations))},
    }


def _point_kinds(rounds: list[dict[str, Any]], n: int) -> list[str]:
    """How each evaluated point was chosen: 'initial', then each batch's 'kind' labels."""
    kinds = ["initial"] * (n - sum(len(r["next"]["points"]) for r in rounds if "next" in r))
    for r in rounds:
        if "next" in r:
            kinds += list(r["next"].get("kind", ["acquired"] * len(r["next"]["points"])))
    return kinds


def run_pyvbmc(prob: Problem, budget: int, seed: int) -> dict[str, Any]:
    try:
        from pyvbmc import VBMC
    except ImportError as e:
        raise NotAvailable(f"not installed (pyvbmc: {e})") from None
    f = Counter(prob.loglik)
    lo, hi = prob.bounds[:, 0], prob.bounds[:, 1]
    width = hi - lo
    lp0 = _log_uniform(prob)
    # PyVBMC checks max_fun_evals only at the end of an iteration (5 new points each),
    # so it can overshoot; start with a design that makes the budget come out exactly.
    n_start = 10 * math.ceil((prob.d + 1) / 10)
    n_start += (budget - n_start) % 5
    vbmc = VBMC(
        lambda x: f.scalar(x) + lp0,  # log joint: log-likelihood + uniform log prior
        0.5 * (lo + hi),
        lo,
        hi,
        lo + 0.1 * width,
        hi - 0.1 * width,
        options={
            "max_fun_evals": budget, "fun_eval_start": n_start, "display": "off", "show_tips": False,
        },
        seed=seed,
    )
    vp, results = vbmc.optimize()
    S = vp.sample(100000)
    S = S[0] if isinstance(S, tuple) else S
    return {
        "samples": np.asarray(S),
        "weights": None,
        "grid_logpdf": lambda G: vp.pdf(G, log_flag=True).reshape(-1),
        "grid_kind": "vp.pdf",
        "n_evals": f.n,
        "n_rounds": f.n,
        "extra": {
            "success_flag": bool(results.get("success_flag", False)),
            "message": str(results.get("message", "")).strip()[:200],
            "iterations": int(results.get("iterations", -1)),
            "func_count": int(results.get("func_count", -1)),
        },
    }


def _gpry_rounds(progress: Any) -> tuple[int, int]:
    """Batches of truth evaluations of a GPry run: (initial-design evaluations, acquisition batches).

    GPry's progress table has one row for the initial design and one per iteration of its
    loop; an iteration evaluates one batch of ``n_points_per_acq`` points (a row without
    evaluations is an iteration whose acquisition found no candidate and was redone).
    """
    ev = progress.data["evals_truth"].astype(float).fillna(0).to_numpy()
    return int(ev[0]), int(np.sum(ev[1:] > 0))


def _gpry_once(prob: Problem, budget: int, seed: int, surrogate: Any, f: Counter) -> dict[str, Any]:
    import warnings

    from gpry import Runner

    def loglike(x):  # one argument: GPry passes the point as one vector
        return f.scalar(x)

    d = prob.d
    n_initial = 3 * d  # GPry's default
    # The initial design is drawn in blocks of n_initial until enough "finite" values
    # are found, up to max_initial: keep max_initial a multiple of n_initial so that
    # this phase cannot overshoot the budget.
    max_initial = n_initial * max(1, min(budget, round(30 * d**1.5)) // n_initial)
    # GPry's nested sampler (UltraNest, in its acquisition NORA and in the final sample)
    # takes no seed: it draws from NumPy's global generator, so seed that.
    np.random.seed(seed)
    runner = Runner(
        loglike,
        bounds=prob.bounds.tolist(),
        params=list(prob.names),
        surrogate=surrogate,
        options={"n_initial": n_initial, "max_initial": max_initial, "max_total": budget},
        seed=seed,
        plots=False,
        verbose=1,
    )
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message="Seeded runs are not supported for UltraNest")
        runner.run()  # ends with GPry's own nested sample of its surrogate posterior
        n_run = f.n
        if runner.last_mc_samples() is None:  # (a run that stopped in its first iteration)
            runner.generate_mc_sample()
    mc = runner.last_mc_samples()
    w_own = mc.get("w")
    X_own = np.asarray(mc["X"], float)
    w_own = (np.full(len(X_own), 1.0 / len(X_own)) if w_own is None
             else np.asarray(w_own, float) / np.sum(w_own))
    # The draws for the metrics: the same SMC as sobol_gp and active, on GPry's surrogate
    # log-likelihood (its mean; -inf where its classifier rules a point out). runner.logp is
    # the surrogate log-posterior (vectorized); its uniform prior is -log(prior volume).
    log_volume = float(runner.truth.log_prior_volume)
    t0 = time.perf_counter()
    smc = metric_smc(lambda Z: np.asarray(runner.logp(Z), float).reshape(-1) + log_volume,
                     prob, seed)
    t_smc = time.perf_counter() - t0
    n_init_evals, n_batches = _gpry_rounds(runner.progress)
    # the initial design: blocks of n_initial drawn one after the other (each block a batch)
    n_init_blocks = math.ceil(n_init_evals / n_initial)
    crit = {
        type(cc).__name__: {"value": float(cc.last_value), "limit": float(cc.limit),
                            "policy": str(getattr(cc, "convergence_policy", ""))}
        for cc in runner.convergence
    }

    def grid_logpdf(G):
        return np.asarray(runner.logp(G), float).reshape(-1)

    return {
        "samples": smc.particles,
        "weights": smc.weights,
        "grid_logpdf": grid_logpdf,
        "grid_kind": "surrogate",
        "n_evals": n_run,
        "n_rounds": n_init_blocks + n_batches,
        "extra": {
            "converged": bool(runner.has_converged),
            "criteria": crit,
            "n_initial_evals": n_init_evals,
            "n_initial_blocks": n_init_blocks,
            "n_acquisition_batches": n_batches,
            "n_points_per_acq": int(runner.n_points_per_acq),
            "smc_particles": GPRY_SMC_PARTICLES,
            "smc_wall_s": t_smc,
            "own_sample": {"draws": len(w_own), "ess": float(1.0 / np.sum(w_own**2)),
                           **moment_metrics(prob, X_own, w_own)},
            "mc_evals_after_run": f.n - n_run,
            "gpry_version": _gpry_version(),
        },
    }


def _gpry_version() -> str:
    from importlib.metadata import version

    return version("gpry")


def run_gpry(prob: Problem, budget: int, seed: int) -> dict[str, Any]:
    try:
        import gpry  # noqa: F401
    except ImportError as e:
        raise NotAvailable(f"not installed (gpry: {e})") from None
    f = Counter(prob.loglik)
    try:
        out = _gpry_once(prob, budget, seed, "RBF", f)  # GPry's default surrogate
        out["extra"]["gpry_config"] = "default"
        return out
    except RuntimeError as e:
        if "finite initial samples" not in str(e):
            raise
        # GPry's default classifier counts as "finite" only values within ~200 of the
        # best one (20 sigma), so a wide prior box can leave it without an initial design.
        print(f"  [gpry] default run failed in its initial design ({str(e).splitlines()[0][:120]}); "
              "running again with the classifier's threshold at infinity")
    # (None or False for "infinities_classifier" is refused by the merge with the defaults,
    # and {} gets the default SVM back; an infinite threshold marks every value finite.)
    n_failed = f.n
    f = Counter(prob.loglik)
    out = _gpry_once(prob, budget, seed, {"infinities_classifier": {"svm": {"threshold": np.inf}}}, f)
    out["extra"]["gpry_config"] = (
        f"infinite classifier threshold (the default run found no initial design in {n_failed} evaluations)"
    )
    return out


#: batch of the ``emulator`` method: equally weighted draws of the current posterior,
#: solved together; they are the next round's design points and its posterior check
EMULATOR_BATCH = 16
#: SMC of the ``emulator`` rounds (light, as the active design's round SMC) and of its
#: final posterior (the metrics use that sample: 20 000 particles of the common metric
#: SMC cost ~10 min here on a 7D emulator; 8000 add sampling noise only)
EMULATOR_ROUND_SMC = {"n_particles": 2000, "n_rej": 10, "zeta": 0.99}
EMULATOR_FINAL_SMC = {"n_particles": 8000, "n_rej": 20, "zeta": 0.95}


def run_emulator(prob: Problem, budget: int, seed: int) -> dict[str, Any]:
    """Output emulator in rounds of posterior draws
    (``bayescalib.inference.rounds.calibrate_outputs``, the pipeline's rounds with
    ``surrogate.target: outputs``): a Sobol design of a quarter of the budget (as
    ``active``), then rounds of ``EMULATOR_BATCH`` posterior draws, each the previous
    posterior's check, with the pipeline's stop rule. Least-squares problems only
    (``outputs``)."""
    if prob.outputs is None:
        raise NotAvailable("not applicable (needs the model's outputs: a least-squares problem)")
    from bayescalib.inference.rounds import calibrate_outputs

    f = Counter(prob.loglik)  # counts the evaluations (each gives outputs and loglik)

    def outputs(X: np.ndarray) -> np.ndarray:
        f(X)
        return prob.outputs(X)

    def per_round(rec: dict[str, Any]) -> None:
        err = np.max(np.abs(np.asarray(rec["posterior"]["mean"]) - prob.ref_mean) / prob.ref_sd)
        pc = rec["posterior_check"]
        print(f"    round {rec['round']}: {rec['n_solves']} evals, best {f.best:.4g}, mean "
              f"err {err:.3g} ref sd"
              + ("" if pc is None else
                 f", check: log-weight sd {pc['log_weight_sd']:.3g}, "
                 f"{'confirmed' if pc['confirmed'] else 'not confirmed'}, moved "
                 f"{rec['change']['shift_sd']:.2g} sd"), flush=True)

    space = make_space(prob)
    n0 = max(2 * prob.d + 2, budget // 4)
    res = calibrate_outputs(outputs, prob.y, space, offset=prob.B,
                            active={"n_initial": n0, "batch_size": EMULATOR_BATCH,
                                    "max_solves": budget, "smc": EMULATOR_ROUND_SMC},
                            posterior_check={"draws": EMULATOR_BATCH},
                            smc=EMULATOR_FINAL_SMC, seed=seed, callback=per_round)
    lik, n = res.surrogate, len(res.loglik)
    kinds = ["initial"] * n0 + [k for r in res.rounds[:-1] for k in r["next"]["kind"]]
    return {
        "samples": res.smc.particles,
        "weights": res.smc.weights,
        "grid_logpdf": lambda G: lik.predict(G) + space.logprior(G),
        "grid_kind": "surrogate",
        "n_evals": f.n,
        "n_rounds": len(res.rounds),
        "extra": {"converged": res.converged, "reason": res.reason, "rounds": res.rounds,
                  "components": lik.emulator.n_components, "final_smc": EMULATOR_FINAL_SMC},
        "design": {"X": res.X, "loglik": res.loglik, "kind": np.asarray(kinds[:n])},
    }


def run_active_vbmc(prob: Problem, budget: int, seed: int) -> dict[str, Any]:
    return run_active(prob, budget, seed, "active_vbmc")


METHODS = {"sobol_gp": run_sobol_gp, "active": run_active, "active_vbmc": run_active_vbmc,
           "emulator": run_emulator, "pyvbmc": run_pyvbmc, "gpry": run_gpry}


# ---------------------------------------------------------------------------
# metrics
# ---------------------------------------------------------------------------


def weighted_moments(X: np.ndarray, w: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
    X = np.asarray(X, float)
    w = np.full(X.shape[0], 1.0 / X.shape[0]) if w is None else np.asarray(w, float) / np.sum(w)
    m = w @ X
    D = X - m
    C = D.T @ (D * w[:, None])
    return m, C


def kl_gauss(m0, C0, m1, C1) -> float:
    """KL(N(m0, C0) || N(m1, C1))."""
    d = len(m0)
    C1i = np.linalg.inv(C1)
    dm = m1 - m0
    s0, ld0 = np.linalg.slogdet(C0)
    s1, ld1 = np.linalg.slogdet(C1)
    if s0 <= 0 or s1 <= 0:
        return float("inf")
    return float(0.5 * (np.trace(C1i @ C0) + dm @ C1i @ dm - d + ld1 - ld0))


def hellinger(P: np.ndarray, Q: np.ndarray) -> float:
    bc = float(np.sum(np.sqrt(P * Q)))
    return math.sqrt(max(0.0, 1.0 - bc))


def hist2d(prob: Problem, X: np.ndarray, w: np.ndarray | None) -> np.ndarray:
    (l1, h1), (l2, h2) = prob.bounds
    H, _, _ = np.histogram2d(X[:, 0], X[:, 1], bins=HIST_N, range=[[l1, h1], [l2, h2]], weights=w)
    return H / H.sum()


def ref_hist2d(prob: Problem) -> np.ndarray:
    # aggregate the reference grid masses into the 30x30 bins, by cell centre
    g1, g2 = prob.grid_axes
    (l1, h1), (l2, h2) = prob.bounds
    i1 = np.minimum(((g1 - l1) / (h1 - l1) * HIST_N).astype(int), HIST_N - 1)
    i2 = np.minimum(((g2 - l2) / (h2 - l2) * HIST_N).astype(int), HIST_N - 1)
    H = np.zeros((HIST_N, HIST_N))
    np.add.at(H, (i1[:, None].repeat(GRID_N, 1), i2[None, :].repeat(GRID_N, 0)), prob.ref_grid)
    return H / H.sum()


def moment_metrics(prob: Problem, X: np.ndarray, w: np.ndarray | None) -> dict[str, Any]:
    """mean_err, sd_err (in reference sd), kl_gauss, mean and sd of (weighted) draws X (n, d)."""
    m, C = weighted_moments(X, w)
    sd = np.sqrt(np.diag(C))
    rsd = prob.ref_sd
    return {
        "mean_err": float(np.max(np.abs(m - prob.ref_mean) / rsd)),
        "sd_err": float(np.max(np.abs(sd - rsd) / rsd)),
        "kl_gauss": kl_gauss(prob.ref_mean, prob.ref_cov, m, C),
        "mean": m.tolist(),
        "sd": sd.tolist(),
    }


def evaluate(prob: Problem, out: dict[str, Any]) -> dict[str, Any]:
    X = np.asarray(out["samples"], float)
    w = out.get("weights")
    met = moment_metrics(prob, X, w)
    if prob.d == 2:
        kind = out.get("grid_kind", "")
        H = None
        if out.get("grid_logpdf") is not None:
            try:
                Q = _normalize_log(out["grid_logpdf"](prob.grid_points())).reshape(GRID_N, GRID_N)
                H = hellinger(prob.ref_grid, Q)
            except Exception as e:  # noqa: BLE001 - fall back to histograms, and say so
                print(f"  grid density failed ({type(e).__name__}: {e}); using {HIST_N}x{HIST_N} histograms")
                H = None
        if H is None:
            H = hellinger(ref_hist2d(prob), hist2d(prob, X, w))
            kind = f"hist{HIST_N}"
        met["hellinger"] = H
        met["hellinger_from"] = kind
    return met


# ---------------------------------------------------------------------------
# driver
# ---------------------------------------------------------------------------


def _variant(method: str) -> tuple[str, float | None]:
    """``active[rg=0.5]`` -> ("active", 0.5); any other name -> (name, None)."""
    if method.startswith("active[rg=") and method.endswith("]"):
        return "active", float(method[len("active[rg="):-1])
    return method, None


def run_one(prob: Problem, method: str, budget: int, seed: int) -> dict[str, Any]:
    global ACTIVE_RESELECT
    base, growth = _variant(method)
    if growth is not None:
        ACTIVE_RESELECT = growth
    t0, c0 = time.perf_counter(), time.process_time()
    try:
        out = METHODS[base](prob, budget, seed)
    except NotAvailable as e:
        return {"status": str(e)}
    except Exception as e:  # noqa: BLE001 - a failing method must not stop the benchmark
        traceback.print_exc()
        return {"status": f"failed: {type(e).__name__}: {str(e).splitlines()[0][:160] if str(e) else ''}"}
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    rec = {"status": "ok", "wall_s": wall, "cpu_s": cpu, "n_evals": int(out["n_evals"]), "n_rounds": int(out["n_rounds"])}
    rec.update(out.get("extra", {}))
    if out.get("design") is not None:
        rec["design"] = out["design"]
    try:
        rec.update(evaluate(prob, out))
    except Exception as e:  # noqa: BLE001
        traceback.print_exc()
        rec["status"] = f"metrics failed: {type(e).__name__}: {e}"
    return rec


NUMERIC = ["n_evals", "n_rounds", "n_searches", "fit_cpu_s", "wall_s", "cpu_s", "hellinger", "mean_err", "sd_err", "kl_gauss"]


def summarize(runs: list[dict[str, Any]]) -> dict[str, Any]:
    ok = [r for r in runs if r.get("status") == "ok"]
    if not ok:
        return {"status": runs[0].get("status", "no run") if runs else "no run"}
    s: dict[str, Any] = {"status": "ok" if len(ok) == len(runs) else f"ok in {len(ok)}/{len(runs)}"}
    for k in NUMERIC:
        vals = [r[k] for r in ok if k in r and r[k] is not None and np.isfinite(r[k])]
        if vals:
            s[k] = float(statistics.median(vals))
            if len(vals) > 1:  # the spread over seeds
                s[k + "_range"] = [float(min(vals)), float(max(vals))]
    conv = [bool(r["converged"]) for r in ok if "converged" in r]
    if len(conv) > 1:
        s["n_converged"] = f"{sum(conv)}/{len(conv)}"
    checks = [bool(r["check_confirmed"]) for r in ok if r.get("check_confirmed") is not None]
    if checks:
        s["n_check_confirmed"] = f"{sum(checks)}/{len(checks)}"
    for k in ("converged", "reason", "fit", "hellinger_from", "success_flag", "gpry_config"):
        vals = [r[k] for r in ok if k in r]
        if vals:
            s[k] = vals[0] if len(set(map(str, vals))) == 1 else "/".join(map(str, vals))
    return s


def _short(text: str, n: int = 90) -> str:
    """First sentence of a long message, at most n characters (the full text is in the JSON)."""
    t = str(text).split(". ")[0]
    head = t.split(": ", 1)[0]
    if len(head) > 15:
        t = head
    return t if len(t) <= n else t[: n - 3] + "..."


def _fmt(v, nd=3) -> str:
    if v is None:
        return "-"
    if isinstance(v, float):
        if not np.isfinite(v):
            return "inf"
        if abs(v) >= 1e4:
            return f"{v:.3g}"
        if abs(v) >= 100:
            return f"{v:.0f}"
        return f"{v:.{nd}g}"
    return str(v)


def cell_of(s: dict[str, Any], k: str, nd: int = 3) -> str:
    """A summary's median of ``k`` with its range over seeds in brackets."""
    v = _fmt(s.get(k), nd)
    rng = s.get(k + "_range")
    return v if rng is None else f"{v} ({_fmt(rng[0], nd)}-{_fmt(rng[1], nd)})"


def table(
    results: dict[str, Any], problems: list[str], methods: list[str], seeds: str, partial: bool = False
) -> str:
    head = (
        "| problem | d | budget | method | evals | rounds | wall s | cpu s | Hellinger | mean err "
        "| sd err | KL gauss | notes |\n|---|---|---|---|---|---|---|---|---|---|---|---|---|\n"
    )
    rows = []
    for p in problems:
        pr = results["problems"][p]
        fl = pr.get("floor")
        if fl is not None:  # the sampler's floor: the same SMC draws on the exact log-likelihood
            rows.append(f"| {p} | {pr['d']} | {pr['budget']} | floor | - | - | - | - "
                        f"| {_fmt(fl['mean_err'])} | {_fmt(fl['sd_err'])} | {_fmt(fl['kl_gauss'])} "
                        f"| exact log-likelihood, {fl['particles']} SMC particles |")
        for m in methods:
            if m not in pr["methods"]:
                if partial:
                    rows.append(f"| {p} | {pr['d']} | {pr['budget']} | {m} | - | - | - | - | - | - | - | - | (not run yet) |")
                continue
            s = pr["methods"][m]["summary"]
            if s["status"] != "ok" and not s["status"].startswith("ok in"):
                rows.append(f"| {p} | {pr['d']} | {pr['budget']} | {m} | - | - | - | - | - | - | - | - | {s['status']} |")
                continue
            notes = []
            if s["status"] != "ok":
                notes.append(s["status"])
            if "n_converged" in s:
                notes.append(f"converged in {s['n_converged']} seeds")
            elif "converged" in s and _variant(m)[0].startswith("active"):
                reason = _short(s.get("reason", ""))
                for prefix in ("NOT converged: ", "not converged: "):
                    reason = reason.removeprefix(prefix)
                notes.append(f"converged={s['converged']}: {reason}")
            elif "converged" in s:
                notes.append(f"converged={s['converged']}")
            if "n_check_confirmed" in s:
                notes.append(f"last posterior check of the rounds confirmed in "
                             f"{s['n_check_confirmed']} (its draws counted in evals)")
            if "n_searches" in s:
                notes.append(f"{_fmt(s['n_searches'], 3)} full searches of the surrogate's choices")
            if "fit_cpu_s" in s:
                notes.append(f"surrogate fits {cell_of(s, 'fit_cpu_s')} CPU s")
            if s.get("fit"):
                notes.append("fit: " + _short(s["fit"].split(" (p = ")[0], 120))
            if s.get("gpry_config", "default") != "default":
                notes.append(s["gpry_config"])
            if "success_flag" in s:
                notes.append(f"stable={s['success_flag']}")
            if s.get("hellinger_from", "").startswith("hist"):
                notes.append(f"Hellinger from {s['hellinger_from']} histograms")
            def cell(k: str, nd: int = 3, s: dict[str, Any] = s) -> str:
                return cell_of(s, k, nd)

            hel = cell("hellinger") if pr["d"] == 2 else "-"
            rows.append(
                f"| {p} | {pr['d']} | {pr['budget']} | {m} | {cell('n_evals')} | {cell('n_rounds')} "
                f"| {_fmt(s.get('wall_s'), 2)} | {_fmt(s.get('cpu_s'), 2)} | {hel} | {cell('mean_err')} | {cell('sd_err')} "
                f"| {cell('kl_gauss')} | {'; '.join(notes)} |"
            )
    legend = (
        f"\nMedians over the seeds ({seeds}), with the range over seeds in brackets. Hellinger: 2D only, on a "
        f"{GRID_N}x{GRID_N} grid against the exact density. mean err / sd err: max over parameters of "
        "|error| / reference sd. KL gauss: KL(reference || method) between moment-matched Gaussians. "
        "rounds: sequential rounds of evaluations (sobol_gp 1; pyvbmc = evaluations; gpry: "
        "initial-design blocks of 3d + acquisition batches of d).\n"
    )
    return head + "\n".join(rows) + "\n" + legend


def _jsonable(o):
    if isinstance(o, dict):
        return {str(k): _jsonable(v) for k, v in o.items()}
    if isinstance(o, (list, tuple)):
        return [_jsonable(v) for v in o]
    if isinstance(o, np.ndarray):
        return _jsonable(o.tolist())
    if isinstance(o, (np.floating, float)):
        return float(o) if np.isfinite(o) else str(float(o))
    if isinstance(o, (np.integer,)):
        return int(o)
    if isinstance(o, np.bool_):
        return bool(o)
    return o


def _parse_seeds(text: str | None, repeats: int) -> dict[int | None, list[int]]:
    """Seeds per problem dimension ({None: default}); '0,1,2', '0-4' or '2d=0-4;7d=0,1'."""
    def one(spec: str) -> list[int]:
        out: list[int] = []
        for part in spec.split(","):
            part = part.strip()
            if "-" in part:
                a, b = part.split("-")
                out += list(range(int(a), int(b) + 1))
            elif part:
                out.append(int(part))
        return out

    if not text:
        return {None: list(range(repeats))}
    res: dict[int | None, list[int]] = {}
    for chunk in text.split(";"):
        if "=" in chunk:
            dim, spec = chunk.split("=")
            res[int(dim.strip().rstrip("dD"))] = one(spec)
        else:
            res[None] = one(chunk)
    res.setdefault(None, list(range(repeats)))
    return res


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--problems", default=",".join(ALL_PROBLEMS))
    ap.add_argument("--methods", default=",".join(ALL_METHODS))
    ap.add_argument("--budget", type=int, default=None, help="evaluations per problem (default: 2D 64, 4D 100, 7D 200)")
    ap.add_argument("--repeats", type=int, default=1, help="seeds 0..repeats-1 (unless --seeds)")
    ap.add_argument("--seeds", default=None,
                    help="comma-separated seeds per problem size, e.g. '0,1,2' (all problems) or "
                         "'2d=0-4;4d=0-2;7d=0-2' (ranges allowed); overrides --repeats")
    ap.add_argument("--out", default="results/bench_active")
    ap.add_argument("--refresh-reference", action="store_true", help="recompute the cached hetero7d reference")
    ap.add_argument("--kernel", default="auto", choices=["auto", "matern32", "matern52", "rbf"],
                    help="surrogate.kernel of the active method (default auto: all, each round)")
    ap.add_argument("--frame", default="auto", choices=["auto", "axes", "principal"],
                    help="surrogate.frame of the active method (default auto: ARD kernels in the "
                         "parameter axes and in the principal axes, the larger evidence wins)")
    ap.add_argument("--ard", default=None, choices=["true", "false", "auto"],
                    help="surrogate.ard of the active methods (default: the schema's auto, one "
                         "length scale per input from two dimensions on)")
    ap.add_argument("--nugget-factor", type=float, default=None,
                    help="surrogate.nugget_factor of the active methods (default: the schema's)")
    ap.add_argument("--nugget", default=None, choices=["fixed", "fit"],
                    help="surrogate.nugget of the active methods: fixed (nugget_factor times the "
                         "range of the GP's targets) or fit (by the evidence, at least "
                         "--nugget-floor); default: the schema's")
    ap.add_argument("--nugget-floor", type=float, default=None,
                    help="surrogate.nugget_floor (nats^2) of the active methods (default: the "
                         "schema's)")
    ap.add_argument("--trace", action="store_true",
                    help="active methods: record the accuracy after every round (results.json: trace)")
    ap.add_argument("--mean", default=None, choices=["auto", "constant", "quadratic"],
                    help="surrogate.mean of the active method (default: the schema's, constant; "
                         "quadratic: the misfit-shaped mean; auto: quadratic from 3 parameters on)")
    ap.add_argument("--reselect-growth", default=None,
                    help="comma-separated values of surrogate.reselect_growth: the active method "
                         "runs once per value, named active[rg=<value>] (e.g. '0,0.5': today's "
                         "search every round, and a search when the data grew by half); default: "
                         "the schema's, one run")
    args = ap.parse_args(argv)
    global ACTIVE_KERNEL, ACTIVE_FRAME, ACTIVE_MEAN, TRACE
    TRACE = args.trace
    if args.ard is not None:
        ACTIVE_SURROGATE["ard"] = {"true": True, "false": False}.get(args.ard, args.ard)
    if args.nugget_factor is not None:
        ACTIVE_SURROGATE["nugget_factor"] = args.nugget_factor
    if args.nugget is not None:
        ACTIVE_SURROGATE["nugget"] = args.nugget
    if args.nugget_floor is not None:
        ACTIVE_SURROGATE["nugget_floor"] = args.nugget_floor
    ACTIVE_MEAN = args.mean
    ACTIVE_KERNEL = args.kernel
    ACTIVE_FRAME = args.frame
    seeds_by_dim = _parse_seeds(args.seeds, args.repeats)
    seeds_text = "; ".join(f"{'all' if k is None else f'{k}D'}: {','.join(map(str, v))}"
                           for k, v in seeds_by_dim.items())
    problems = [p.strip() for p in args.problems.split(",") if p.strip()]
    methods = [m.strip() for m in args.methods.split(",") if m.strip()]
    for p in problems:
        if p not in ALL_PROBLEMS:
            ap.error(f"unknown problem {p!r}; choose from {ALL_PROBLEMS}")
    for m in methods:
        if m not in METHODS:
            ap.error(f"unknown method {m!r}; choose from {list(METHODS)}")
    if args.reselect_growth is not None and "active" in methods:
        k = methods.index("active")
        methods[k:k + 1] = [f"active[rg={float(v):g}]" for v in args.reselect_growth.split(",")
                            if v.strip()]
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)

    results: dict[str, Any] = {
        "config": {
            "problems": problems, "methods": methods, "budget_override": args.budget, "active_kernel": args.kernel,
            "active_surrogate": dict(ACTIVE_SURROGATE),
            "active_frame": args.frame, "active_mean": args.mean,
            "active_reselect_growth": args.reselect_growth,
            "repeats": args.repeats, "seeds": args.seeds, "grid": GRID_N, "python": platform.python_version(),
            "machine": platform.platform(), "cpus": os.cpu_count(),
            "omp_num_threads": os.environ.get("OMP_NUM_THREADS"),
            "started": time.strftime("%Y-%m-%d %H:%M:%S"),
        },
        "problems": {},
    }
    for pname in problems:
        prob = make_problem(pname, out, args.refresh_reference)
        budget = args.budget or DEFAULT_BUDGET[prob.d]
        pr = {
            "d": prob.d, "budget": budget, "names": prob.names, "bounds": prob.bounds,
            "B": prob.B, "reference": {**prob.ref_info, "mean": prob.ref_mean, "sd": prob.ref_sd},
            "methods": {},
        }
        seeds = seeds_by_dim.get(prob.d, seeds_by_dim[None])
        pr["seeds"] = seeds
        pr["floor"] = sampler_floor(prob)
        print(f"[{pname}] floor of the moment metrics ({METRIC_PARTICLES} SMC particles on the exact "
              f"log-likelihood): mean err {pr['floor']['mean_err']:.3g}, sd err "
              f"{pr['floor']['sd_err']:.3g}, KL {pr['floor']['kl_gauss']:.3g}", flush=True)
        for mname in methods:
            runs = []
            for r in seeds:
                print(f"[{pname}] {mname} (budget {budget}, seed {r}) ...", flush=True)
                rec = run_one(prob, mname, budget, seed=r)
                rec["seed"] = r
                design = rec.pop("design", None)
                if design is not None:  # the evaluated points, for diagnosis
                    np.savez_compressed(out / f"design_{pname}_{mname}_seed{r}.npz", **design)
                runs.append(rec)
                if rec["status"] == "ok":
                    print(
                        f"  evals {rec['n_evals']}, rounds {rec['n_rounds']}, {rec['wall_s']:.1f} s, "
                        + (f"Hellinger {rec['hellinger']:.3f}, " if "hellinger" in rec else "")
                        + f"mean err {rec['mean_err']:.3g}, sd err {rec['sd_err']:.3g}, KL {rec['kl_gauss']:.3g}",
                        flush=True,
                    )
                else:
                    print(f"  {rec['status']}", flush=True)
                    if rec["status"].startswith("not "):
                        break  # not installed / not available: no point repeating
                # partial results after every run, so that an interrupted run keeps them
                pr["methods"][mname] = {"summary": summarize(runs), "runs": runs}
                results["problems"][pname] = pr
                (out / "results.json").write_text(json.dumps(_jsonable(results), indent=1))
                done = [p for p in problems if p in results["problems"]]
                (out / "table.md").write_text(
                    table(results, done, methods, seeds_text, partial=True)
                )

    md = table(results, problems, methods, seeds_text)
    print()
    print(md)
    (out / "table.md").write_text(md)
    (out / "results.json").write_text(json.dumps(_jsonable(results), indent=1))
    print(f"wrote {out / 'table.md'} and {out / 'results.json'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
