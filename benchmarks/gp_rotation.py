"""Experiment: does fitting the GP surrogate in the posterior's principal axes help in 7D?

Question (issue 17). On ``hetero7d`` (benchmarks/bench_active.py) a GP of the
log-likelihood fitted on an *ideal* design still errs by about 1 nat in the
posterior region and its SMC posterior is off by 1-1.6 sd. The problem has
strongly correlated directions (a ridge of E2 with nu2 and q), while the ARD
kernel's length scales are axis-aligned. Does a linear change of the GP's
inputs to the posterior's principal axes help?

Frames of the GP inputs (u = unit-box coordinates, C_u = a posterior covariance
in them, C_u = V diag(s) V^T):

* ``axis``: u itself (today's surrogate).
* ``rotate``: z = u V (orthogonal: principal axes, box-sized).
* ``whiten``: z = u V diag(s^-1/2) * gm(s)^1/2 (PCA whitening, rescaled to keep
  the unit box's volume so that the optimizer's starting length scales fit).

with C_u from the reference posterior (``ref``) or a rough estimate (``rough``:
the moments of SMC on the axis-aligned GP's mean), regularized as
C_u + (0.01)^2 I; and ``train``: ``bayescalib.inference.gp.inputs.principal_frame``,
the frame the surrogate uses (principal axes of the training points weighted by
their tempered likelihood, no reference needed). Since the kernel is stationary the centre of the frame does
not matter, only its linear map.

Design ("ideal"): ``n_sobol`` scrambled Sobol points over the box plus ``n_post``
draws from the reference posterior; test set: 500 other reference draws.
Metrics: median and 90 % |GP mean - L| (nats) at the test draws; SMC (4000
particles) on the GP mean: max over parameters of |mean - mean_ref| / sd_ref
and |sd / sd_ref - 1|, and KL(ref || SMC) between moment-matched Gaussians.

Problems: ``hetero7d`` (reference: the cached random-walk Metropolis samples of
bench_active.py) and ``sloppy4d`` (closed-form Gaussian, draws truncated to the
box).

Run (repository root)::

    python benchmarks/gp_rotation.py                       # both problems, Matern 3/2 and 5/2
    python benchmarks/gp_rotation.py --problems hetero7d --kernels matern32 --seeds 0,1
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

import bench_active as ba

from bayescalib.inference.active import posterior_moments
from bayescalib.inference.design import sobol_design
from bayescalib.inference.gp import fit_gp, principal_frame
from bayescalib.inference.smc import run_smc

REG_SD = 0.01  # regularization of C_u, in box units


def frame(C_u: np.ndarray, kind: str) -> np.ndarray:
    """Linear map A (d, d) of unit-box coordinates to GP inputs z = u A."""
    d = C_u.shape[0]
    if kind == "axis":
        return np.eye(d)
    s, V = np.linalg.eigh(C_u + REG_SD**2 * np.eye(d))
    if kind == "rotate":
        return V
    if kind == "whiten":
        return V * (s ** -0.5) * np.exp(0.5 * np.mean(np.log(s)))
    raise ValueError(kind)


def posterior_draws(prob, n: int, rng: np.random.Generator) -> np.ndarray:
    if prob.name == "hetero7d":
        with np.load(Path("results/bench_active/reference_hetero7d.npz")) as z:
            S = z["samples"]
        return S[rng.choice(len(S), n, replace=False)]
    lo, hi = prob.bounds[:, 0], prob.bounds[:, 1]
    out = np.empty((0, prob.d))
    while len(out) < n:
        Z = rng.multivariate_normal(prob.ref_mean, prob.ref_cov, 2 * n)
        out = np.vstack([out, Z[np.all((Z >= lo) & (Z <= hi), 1)]])
    return out[:n]


def run_case(prob, X, L, Xt, Lt, A, kernel, seed):
    lo, w = prob.bounds[:, 0], prob.bounds[:, 1] - prob.bounds[:, 0]

    def to_z(Y):
        return ((np.atleast_2d(Y) - lo) / w) @ A

    Z = to_z(X)
    zb = np.column_stack([Z.min(0), Z.max(0)])  # fixed shift/scale: identity up to translation
    zb[:, 1] = zb[:, 0] + 1.0
    gp = fit_gp(Z, L, ard=True, bounds=zb, restarts=3, seed=seed, bound=prob.B, warp=True,
                kernel=kernel, nugget="fixed", mean="constant")
    err = np.abs(gp.predict(to_z(Xt)) - Lt)
    space = ba.make_space(prob)
    smc = run_smc(lambda Y: gp.predict(to_z(Y)), space, n_particles=4000, n_rej=20, zeta=0.95,
                  rng=np.random.default_rng(seed))
    mo = posterior_moments(smc.particles, smc.weights)
    rsd = prob.ref_sd
    return {
        "med_err": float(np.median(err)), "p90_err": float(np.quantile(err, 0.9)),
        "mean_err": float(np.max(np.abs(mo["mean"] - prob.ref_mean) / rsd)),
        "sd_err": float(np.max(np.abs(mo["sd"] / rsd - 1.0))),
        "kl": ba.kl_gauss(prob.ref_mean, prob.ref_cov, mo["mean"], mo["cov"]),
        "cov_u": mo["cov"] / np.outer(w, w), "lml": gp.log_marginal_likelihood,
    }


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--problems", default="hetero7d,sloppy4d")
    ap.add_argument("--kernels", default="matern32,matern52")
    ap.add_argument("--seeds", default="0")
    args = ap.parse_args(argv)
    sizes = {"hetero7d": (50, 150), "sloppy4d": (25, 75)}
    rows = []
    for name in args.problems.split(","):
        prob = ba.make_problem(name, Path("results/bench_active"), False)
        w = prob.bounds[:, 1] - prob.bounds[:, 0]
        C_ref_u = prob.ref_cov / np.outer(w, w)
        for seed in (int(s) for s in args.seeds.split(",")):
            rng = np.random.default_rng([seed, 17])
            n_sobol, n_post = sizes[name]
            P = posterior_draws(prob, n_post + 500, rng)
            X = np.vstack([sobol_design(prob.bounds, n_sobol, seed), P[:n_post]])
            Xt = P[n_post:]
            L, Lt = prob.loglik(X), prob.loglik(Xt)
            for kernel in args.kernels.split(","):
                t0 = time.perf_counter()
                base = run_case(prob, X, L, Xt, Lt, np.eye(prob.d), kernel, seed)
                rows.append((name, seed, kernel, "axis", "-", base, time.perf_counter() - t0))
                for src, C, kinds in (("ref", C_ref_u, ("rotate", "whiten")),
                                      ("rough", base["cov_u"], ("rotate",)),
                                      ("train", None, ("rotate",))):
                    for kind in kinds:
                        t0 = time.perf_counter()
                        A = principal_frame(X, L, prob.bounds) if C is None else frame(C, kind)
                        r = run_case(prob, X, L, Xt, Lt, A, kernel, seed)
                        rows.append((name, seed, kernel, kind, src, r, time.perf_counter() - t0))
                for row in rows[-5:]:
                    _print(row)
    print("\n| problem | seed | kernel | frame | C from | GP log evidence | median abs err (nats) | 90% abs err | "
          "mean err (sd) | sd err (rel) | KL | s |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|")
    for row in rows:
        _print(row, md=True)
    return 0


def _print(row, md=False):
    name, seed, kernel, kind, src, r, t = row
    vals = (f"{r['lml']:.1f}", f"{r['med_err']:.3f}", f"{r['p90_err']:.3f}", f"{r['mean_err']:.3f}",
            f"{r['sd_err']:.3f}", f"{r['kl']:.4f}", f"{t:.0f}")
    if md:
        print("| " + " | ".join([name, str(seed), kernel, kind, src, *vals]) + " |")
    else:
        print(f"{name} seed {seed} {kernel} {kind:6s} C={src:5s} " + " ".join(vals), flush=True)


if __name__ == "__main__":
    raise SystemExit(main())
