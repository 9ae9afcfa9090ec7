"""Benchmark: SMC settings of the active rounds (``design.active.smc``) against the
study's, on a 7D surrogate shaped like the paper's heterogeneous case.

The rounds' posteriors only place the next batch and feed the stop rule (mean shift
<= 0.2 sd, sd change <= 20 %), so they need less accuracy than the posterior a study
reports. This script measures what lighter settings cost and how far their posterior
is from the one of the study's settings on the *same* surrogate:

* problem: ``hetero7d`` of ``benchmarks/bench_active.py`` (seven parameters, one of
  them an uncertain inflow, 40 noisy measurements; likelihood bound B = 0);
* surrogate: the heterogeneous study's (``config/heterogeneous.yaml``: Matérn 3/2,
  per-input length scales, ``output``/``frame``/``inputs`` auto, SCG, 2 restarts),
  fitted by ``fit_from_config`` with the bound, on ``--n-train`` points: half a
  scrambled Sobol design over the box, half Gaussian around the exact mode (0.05 of
  the box per parameter), as an active design concentrates its solves;
* SMC settings (``--settings``, ``N/n_rej/zeta`` separated by commas): each run once
  (seed 0) on that surrogate, with its CPU time (one BLAS thread), tempering steps,
  log evidence, and the largest differences to the last setting (the reference) of
  the posterior means (in the reference's sd) and sds (relative).

Run: ``python benchmarks/bench_round_smc.py [--n-train 300]
[--settings 2000/10/0.99,4000/20/0.995,10000/30/0.998]``

Measured 2026-11-24 (defaults; shared 2-core machine, CPU times): surrogate fit (the
study's auto choices, 8 fits) 173 s;

| N/n_rej/zeta | steps | CPU [s] | CPU / reference | max mean diff [ref sd] | max sd diff |
|---|---|---|---|---|---|
| 2000/10/0.99 | 229 | 13.0 | 0.042 | 0.035 | 0.046 |
| 4000/20/0.995 | 267 | 59.9 | 0.193 | 0.037 | 0.027 |
| 10000/30/0.998 (paper) | 379 | 310.1 | 1 | 0 | 0 |

The light setting is what ``config/heterogeneous.yaml`` gives its rounds.
"""

from __future__ import annotations

import argparse
import importlib.util
import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent


def _bench_active():
    spec = importlib.util.spec_from_file_location("bench_active", HERE / "bench_active.py")
    mod = importlib.util.module_from_spec(spec)
    sys.modules["bench_active"] = mod
    spec.loader.exec_module(mod)
    return mod


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--n-train", type=int, default=300)
    ap.add_argument("--settings", default="2000/10/0.99,4000/20/0.995,10000/30/0.998",
                    help="N/n_rej/zeta per run, comma-separated; the last is the reference")
    args = ap.parse_args()

    import yaml

    from bayescalib.inference.design import sobol_design
    from bayescalib.inference.gp import fit_from_config
    from bayescalib.inference.smc import run_smc

    ba = _bench_active()
    rng = np.random.default_rng(ba.H7_NOISE_SEED)
    y_obs = ba.h7_model(ba.H7_TRUTH)[0] + ba.H7_SIGMA * rng.standard_normal(ba.H7_K)

    def loglik(X):
        r = (ba.h7_model(X) - y_obs) / ba.H7_SIGMA
        return -0.5 * np.sum(r * r, axis=1)

    box = ba.H7_BOUNDS
    lo, hi = box[:, 0], box[:, 1]
    n = args.n_train
    rng = np.random.default_rng(0)
    X = np.vstack([sobol_design(box, n // 2, 0),
                   np.clip(ba.H7_TRUTH + 0.05 * (hi - lo) * rng.standard_normal((n - n // 2, 7)),
                           lo, hi)])
    L = loglik(X)
    cfg = yaml.safe_load((HERE.parent / "config" / "heterogeneous.yaml").read_text())
    from bayescalib.config import validate

    surrogate = validate({"surrogate": cfg["surrogate"]}, "inference")["surrogate"]
    t0 = time.process_time()
    gp = fit_from_config(X, L, surrogate, box, bound=0.0)
    print(f"hetero7d, {n} training points (best {L.max():.1f} nats; bound 0): surrogate fitted "
          f"in {time.process_time() - t0:.1f} s CPU")
    space = ba.make_space(ba.Problem("hetero7d", list(ba.H7_NAMES), box.copy(), loglik, 0.0))

    rows = []
    for spec in args.settings.split(","):
        N, R, z = spec.split("/")
        N, R, z = int(N), int(R), float(z)
        t0 = time.process_time()
        res = run_smc(gp.predict, space, n_particles=N, n_rej=R, zeta=z,
                      rng=np.random.default_rng(0))
        cpu = time.process_time() - t0
        W = res.weights / res.weights.sum()
        m = W @ res.particles
        s = np.sqrt(W @ (res.particles - m) ** 2)
        rows.append((spec, res.n_steps, cpu, float(res.log_evidence), m, s))
        print(f"  {spec}: {res.n_steps} steps, {cpu:.1f} s CPU", flush=True)
    ref_m, ref_s = rows[-1][4], rows[-1][5]
    print("\n| N/n_rej/zeta | steps | CPU [s] | CPU / reference | log evidence | "
          "max mean diff [ref sd] | max sd diff |")
    print("|---|---|---|---|---|---|---|")
    for spec, steps, cpu, logz, m, s in rows:
        print(f"| {spec} | {steps} | {cpu:.1f} | {cpu / rows[-1][2]:.3f} | {logz:.2f} | "
              f"{np.max(np.abs(m - ref_m) / ref_s):.3f} | {np.max(np.abs(s / ref_s - 1)):.3f} |")
    print("\nreference posterior (last setting): mean "
          + ", ".join(f"{k} {v:.4g}" for k, v in zip(ba.H7_NAMES, ref_m, strict=True))
          + "; sd " + ", ".join(f"{v:.3g}" for v in ref_s))


if __name__ == "__main__":
    main()
