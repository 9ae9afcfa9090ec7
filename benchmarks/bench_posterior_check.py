"""How often the posterior check (bayescalib.inference.importance) flags a wrong posterior.

Two parts, both against known truths:

* ``gauss``: 1-D Gaussian target N(0, 1), surrogate posteriors N(shift, s^2) (exact,
  too narrow by 0.85, 0.7, 0.5; shifted by 0.5 and 1 sd), the share of seeds in which
  ``draws`` evaluations flag it (not confirmed);
* ``fixed``: the paper's fixed Sobol design + GP surrogate (Matérn 3/2, the schema's
  other defaults) and SMC (4000 particles) on the analytic problems of
  ``benchmarks/bench_active.py``, then the check at three systematic resamples of 32
  draws each with the exact log-likelihood; printed beside the surrogate posterior's
  largest mean error in reference sd.

Run::

    python benchmarks/bench_posterior_check.py [--parts gauss,fixed] [--seeds 200]
        [--problems ridge2d:64,lobe2d:64,sloppy4d:40,hetero7d:200]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))


def gauss(seeds: int) -> None:
    from bayescalib.inference.importance import importance_check

    cases = [("exact", 1.0, 0.0), ("0.85x as wide", 0.85, 0.0), ("0.7x as wide", 0.7, 0.0),
             ("0.5x as wide", 0.5, 0.0), ("shifted 0.5 sd", 1.0, 0.5),
             ("shifted 1 sd", 1.0, 1.0)]
    print("| surrogate posterior (target N(0, 1)) | 16 draws | 32 draws | 64 draws |")
    print("|---|---|---|---|")
    for label, s_q, shift in cases:
        row = []
        for n in (16, 32, 64):
            flagged = 0
            for seed in range(seeds):
                x = shift + s_q * np.random.default_rng(seed).standard_normal(n)
                res = importance_check(x[:, None], -0.5 * x**2, -0.5 * ((x - shift) / s_q) ** 2)
                flagged += not res["confirmed"]
            row.append(f"{100 * flagged / seeds:.0f} %")
        print(f"| {label} | " + " | ".join(row) + " |")


def fixed(problems: list[tuple[str, int]]) -> None:
    import bench_active as ba

    from bayescalib.config import validate
    from bayescalib.inference.design import sobol_design
    from bayescalib.inference.gp import fit_from_config
    from bayescalib.inference.importance import importance_check
    from bayescalib.inference.resampling import systematic_resample
    from bayescalib.inference.smc import smc_from_config

    print("| problem | solves | surrogate mean err (ref sd) | draw set | check |")
    print("|---|---|---|---|---|")
    for name, n in problems:
        prob = ba.make_problem(name, Path("results/bench_active"), False)
        space = ba.make_space(prob)
        cfg = validate({"surrogate": {"kernel": "matern32"}, "smc": {"n_particles": 4000}},
                       "inference")
        X = sobol_design(space.bounds, n, 0)
        gp = fit_from_config(X, prob.loglik(X), cfg["surrogate"], space.bounds, bound=prob.B)
        res = smc_from_config(gp.predict, space, cfg["smc"])
        W = res.weights / res.weights.sum()
        for k in range(3):
            D = res.particles[systematic_resample(W, np.random.default_rng(k), 32)]
            chk = importance_check(D, prob.loglik(D), gp.predict(D))
            err = np.max(np.abs(np.asarray(chk["mean_q"]) - prob.ref_mean) / prob.ref_sd)
            print(f"| {name} | {n} | {err:.2f} | {k} | {chk['words']} |", flush=True)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--parts", default="gauss,fixed")
    ap.add_argument("--seeds", type=int, default=200)
    ap.add_argument("--problems", default="ridge2d:64,lobe2d:64,sloppy4d:40,hetero7d:200")
    a = ap.parse_args(argv)
    parts = a.parts.split(",")
    if "gauss" in parts:
        gauss(a.seeds)
    if "fixed" in parts:
        fixed([(p.split(":")[0], int(p.split(":")[1])) for p in a.problems.split(",")])
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
