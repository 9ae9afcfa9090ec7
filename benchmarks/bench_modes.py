"""Benchmark: does "converged" ever come with a mode missing?

The active design's verdict (``bayescalib.inference.active``) is run over many design
seeds on problems with a known posterior (``benchmarks/bench_active.py``), and every
run is scored against the reference:

* ``missed``: for problems with separated modes (``bimodal2d``), a mode is missing when
  the run's final posterior holds less than half of its reference mass (the modes split
  by which component's weighted density is larger);
* ``hellinger`` (2D): the final surrogate's posterior on the 400 x 400 grid against the
  exact density; ``mean_err``: max over parameters of |mean - reference| / reference sd;
* ``false``: the verdict said converged and the run is wrong: a mode missing, or (for
  problems without separated modes) Hellinger above ``--false-hellinger`` (2D) or a mean
  error above ``--false-mean`` reference sd (higher dimensions); ``kl_gauss``: KL(reference ||
  run) between moment-matched Gaussians.

Variants, side by side in one run on the same seeds:

* ``audit``: the schema's stop rule (the basin audit of
  ``bayescalib.inference.exploration``: never converged while the solves' basins that the
  posterior does not hold could carry more than ``stop.unexplored_mass``, and probes
  sent there);
* ``no_audit``: the same with the audit switched off (``stop.unexplored_mass`` 1,
  ``probes`` 0): the stop rule as it was before it;
* ``one_look``: the schema's stop rule with the posterior check in one look of
  ``posterior_check.draws`` draws (``posterior_check.batch`` 0), not sequential.

Usage::

    python benchmarks/bench_modes.py --problems bimodal2d --seeds 0-19 --budget 128
    python benchmarks/bench_modes.py --problems ridge2d,lobe2d,sloppy4d --seeds 0-19 \\
        --budget 128 --variants audit

prints a row per run, then per problem and variant: runs, converged, false converged,
missed modes at the verdict, median evaluations and accuracy; ``--out`` writes the rows
as JSON.
"""

from __future__ import annotations

import argparse
import json
import logging
import sys
import time
import warnings
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import bench_active as ba

VARIANTS: dict[str, dict[str, Any]] = {
    "audit": {},
    "no_audit": {"probes": 0, "stop": {"unexplored_mass": 1.0}},
    # the posterior check in one look of posterior_check.draws (with the mass test)
    "one_look": {"posterior_check": {"batch": 0}},
}


def run(prob: ba.Problem, variant: str, seed: int, budget: int) -> dict[str, Any]:
    """One active calibration of ``prob`` with design seed ``seed``, scored."""
    from bayescalib.inference.rounds import calibrate

    space = ba.make_space(prob)
    f = ba.Counter(prob.loglik)
    t0 = time.perf_counter()
    v = dict(VARIANTS[variant])
    check = v.pop("posterior_check", None)
    res = calibrate(f, space, bound=prob.B,
                    active={"n_initial": max(2 * prob.d + 2, budget // 4), "batch_size": 8,
                            "max_solves": budget, **v},
                    smc={"n_particles": 4000}, posterior_check=check, seed=seed)
    wall = time.perf_counter() - t0
    X, w = res.smc.particles, res.smc.weights / res.smc.weights.sum()
    m, C = ba.weighted_moments(X, w)
    row: dict[str, Any] = {
        "problem": prob.name, "variant": variant, "seed": seed, "evals": f.n,
        "rounds": len(res.rounds), "converged": res.converged, "wall_s": round(wall, 1),
        "check_draws": sum(k == "posterior_check" for rec in res.rounds
                           for k in (rec.get("next") or {}).get("kind", [])),
        "mean_err": float(np.max(np.abs(m - prob.ref_mean) / prob.ref_sd)),
        "kl_gauss": ba.kl_gauss(prob.ref_mean, prob.ref_cov, m, C),
        "unexplored_mass": res.rounds[-1]["exploration"]["unexplored_mass"]
        if "exploration" in res.rounds[-1] else None,
    }
    if prob.d == 2:
        G = prob.grid_points()
        Q = ba._normalize_log(res.surrogate.loglik(G) + space.logprior(G))
        row["hellinger"] = ba.hellinger(prob.ref_grid, Q.reshape(ba.GRID_N, ba.GRID_N))
    if prob.component is not None:
        ref = (np.bincount(prob.component(G), weights=prob.ref_grid.ravel(), minlength=2)
               if prob.d == 2 else np.asarray(prob.ref_info["modes"]["weights"], float))
        got = np.bincount(prob.component(X), weights=w, minlength=len(ref))
        row["mode_mass"] = got.tolist()
        row["ref_mode_mass"] = ref.tolist()
        row["missed"] = int(np.sum(got < 0.5 * ref))
    return row


def is_false(row: dict[str, Any], false_hellinger: float, false_mean: float) -> bool:
    """The verdict said converged and the run is wrong (the module docstring)."""
    if not row["converged"]:
        return False
    if "missed" in row:
        return row["missed"] > 0
    if "hellinger" in row:
        return row["hellinger"] > false_hellinger
    return row["mean_err"] > false_mean


def summary(rows: list[dict[str, Any]], false_hellinger: float,
            false_mean: float) -> list[dict[str, Any]]:
    out = []
    for key in dict.fromkeys((r["problem"], r["variant"]) for r in rows):
        rs = [r for r in rows if (r["problem"], r["variant"]) == key]
        conv = [r for r in rs if r["converged"]]
        s = {"problem": key[0], "variant": key[1], "runs": len(rs), "converged": len(conv),
             "false_converged": sum(is_false(r, false_hellinger, false_mean) for r in rs),
             "median_evals": float(np.median([r["evals"] for r in rs])),
             "median_evals_converged": float(np.median([r["evals"] for r in conv]))
             if conv else None,
             "median_mean_err": float(np.median([r["mean_err"] for r in rs]))}
        if "hellinger" in rs[0]:
            s["median_hellinger"] = float(np.median([r["hellinger"] for r in rs]))
        if "missed" in rs[0]:
            s["missed_at_verdict"] = sum(r["missed"] > 0 for r in rs)
        out.append(s)
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--problems", default="bimodal2d")
    ap.add_argument("--variants", default="audit,no_audit")
    ap.add_argument("--seeds", default="0-19", help="'0-19' or '0,3,5'")
    ap.add_argument("--budget", type=int, default=128)
    ap.add_argument("--false-hellinger", type=float, default=0.2)
    ap.add_argument("--false-mean", type=float, default=1.0)
    ap.add_argument("--out", type=Path, default=None)
    args = ap.parse_args(argv)
    seeds = ba._parse_seeds(args.seeds, 1)[None]
    logging.disable(logging.WARNING)
    warnings.filterwarnings("ignore")
    rows = []
    for name in args.problems.split(","):
        prob = ba.make_problem(name, Path("results/bench_modes"), False)
        for variant in args.variants.split(","):
            for seed in seeds:
                row = run(prob, variant, seed, args.budget)
                rows.append(row)
                print(json.dumps(row), flush=True)
    print("\n| problem | variant | runs | converged | false converged | missed mode at verdict "
          "| median evals | median evals (converged) | median Hellinger | median mean err |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for s in summary(rows, args.false_hellinger, args.false_mean):
        conv_evals = s["median_evals_converged"]
        print(f"| {s['problem']} | {s['variant']} | {s['runs']} | {s['converged']} | "
              f"{s['false_converged']} | {s.get('missed_at_verdict', '-')} | "
              f"{s['median_evals']:.0f} | {'-' if conv_evals is None else f'{conv_evals:.0f}'} | "
              f"{s.get('median_hellinger', float('nan')):.3g} | {s['median_mean_err']:.3g} |")
    if args.out:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(json.dumps({"rows": rows, "summary": summary(
            rows, args.false_hellinger, args.false_mean)}, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
