"""A posterior cut by a region where the model cannot be solved: before and after the
failed region (bayescalib.inference.feasibility).

The problem: a Gaussian log-likelihood (x0 ~ N(0.4, 0.3^2), x1 ~ N(-0.3, 0.4^2),
independent, box [-3, 3]^2) whose model cannot be solved for x0 > 0.5 (every
evaluation there fails), so 37 % of the untruncated posterior lies where nothing can be
solved. Taking the failures as infeasible, the answer is the posterior restricted to
x0 <= 0.5: a truncated normal in x0 (mean 0.220, sd 0.200) with closed-form moments.

Modes, each on the same design seeds (the in-process active design,
:func:`bayescalib.inference.rounds.calibrate`, as ``tests/test_active.py``):

* ``before``: the failures reach the surrogate as NaN (no value and no region: the
  surrogate extrapolates across the cut, as before the region existed) and the
  posterior check leaves failed draws out (``max_failed_fraction: 1``);
* ``check``: the same, with the check counting failed draws (the default 0.1);
* ``region``: failures are -inf (the region), no boundary points;
* ``default``: the region and ``boundary_points`` (the default 2).

Per run: converged or not, evaluations, the error of x0's mean in reference sd, the
relative error of its sd, the posterior mass beyond the cut, and the last check's share
of failed draws.

Usage::

    python benchmarks/bench_feasibility.py [--seeds 0,1,2] [--modes before,check,region,default]
        [--json benchmarks/data/bench_feasibility.json]

No assertions; prints a table and one JSON line.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
from scipy.stats import truncnorm

from bayescalib.inference.parameters import ParameterSpace
from bayescalib.inference.rounds import calibrate

MEAN, SD, CUT = np.array([0.4, -0.3]), np.array([0.3, 0.4]), 0.5


def _space() -> ParameterSpace:
    return ParameterSpace.from_config([
        {"name": f"x{k}", "prior": {"type": "uniform", "lo": -3.0, "hi": 3.0},
         "bounds": [-3.0, 3.0]} for k in range(2)])


def _loglik(failed_value: float):
    def f(X):
        X = np.atleast_2d(X)
        L = -0.5 * np.sum(((X - MEAN) / SD) ** 2, axis=1)
        return np.where(X[:, 0] > CUT, failed_value, L)
    return f


MODES = {
    "before": (np.nan, {"boundary_points": 0}, {"max_failed_fraction": 1.0}),
    "check": (np.nan, {"boundary_points": 0}, {}),
    "region": (-np.inf, {"boundary_points": 0}, {}),
    "default": (-np.inf, {}, {}),
}


def run(mode: str, seed: int) -> dict:
    failed_value, active, check = MODES[mode]
    t0 = time.perf_counter()
    res = calibrate(_loglik(failed_value), _space(), bound=0.0, seed=seed,
                    active={"n_initial": 16, "batch_size": 8, "max_solves": 200, **active},
                    surrogate={"restarts": 2},
                    smc={"n_particles": 2000, "zeta": 0.95, "n_rej": 10},
                    posterior_check=check)
    t = truncnorm(-np.inf, (CUT - MEAN[0]) / SD[0], loc=MEAN[0], scale=SD[0])
    W = res.smc.weights / res.smc.weights.sum()
    P = res.smc.particles
    m = W @ P[:, 0]
    s = float(np.sqrt(W @ (P[:, 0] - m) ** 2))
    chk = res.posterior_check or {}
    return {"mode": mode, "seed": seed, "converged": bool(res.converged),
            "evaluations": len(res.loglik),
            "mean_err_sd": float((m - t.mean()) / t.std()),
            "sd_rel_err": float(s / t.std() - 1.0),
            "mass_beyond_cut": float(W[P[:, 0] > CUT].sum()),
            "check_failed_fraction": chk.get("failed_fraction"),
            "wall_s": round(time.perf_counter() - t0, 1),
            "reason": res.reason}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seeds", default="0,1,2")
    ap.add_argument("--modes", default=",".join(MODES))
    ap.add_argument("--json", default=None, help="also write the rows here")
    args = ap.parse_args()
    rows = [run(mode, int(seed)) for mode in args.modes.split(",")
            for seed in args.seeds.split(",")]
    head = ["mode", "seed", "converged", "evals", "x0 mean err [sd]", "x0 sd err",
            "mass beyond cut", "check: failed draws"]
    print(" | ".join(head))
    for r in rows:
        ff = r["check_failed_fraction"]
        print(" | ".join([r["mode"], str(r["seed"]), "yes" if r["converged"] else "NO",
                          str(r["evaluations"]), f"{r['mean_err_sd']:+.2f}",
                          f"{100 * r['sd_rel_err']:+.0f} %",
                          f"{100 * r['mass_beyond_cut']:.0f} %",
                          "-" if ff is None else f"{100 * ff:.0f} %"]))
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=1) + "\n")
    print(json.dumps({"rows": len(rows)}))


if __name__ == "__main__":
    main()
