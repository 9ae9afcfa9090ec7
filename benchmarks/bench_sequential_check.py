"""Benchmark: error rates of the sequential posterior check against the fixed one.

The posterior check of the active rounds (``bayescalib.inference.importance``:
``sequential_check``; the rounds call it through ``active.round_posterior_check``) is
given a surrogate posterior q that is known to be right or wrong, and the real
log-likelihood is analytic, so no GP or solve is needed and each replicate costs
milliseconds:

* the particles are 4000 exact draws of q (equal weights), clustered once per case by
  ``active.posterior_clusters`` as in the rounds;
* each replicate (seed) draws the check's ``draws`` points from them as the rounds do
  (``active.posterior_draws``, stratified by cluster, one systematic resample per look),
  the surrogate's log-likelihood at a draw is log q(x) + noise (iid normal, sd
  ``noise`` nats: the GP's error at the draws) and the real one log pi(x);
* three checks read the same draws: ``fixed`` (``importance_check`` on all of them: the
  check before), ``one_look`` (``sequential_check`` with one look: the fixed tests plus
  the mass test) and ``sequential`` (looks of ``batch`` draws, stopping when decided).

Cases (pi is the real posterior, q the surrogate's; 2-D):

* ``gauss_right``: q = pi = N(0, I);
* ``gauss_shift``: q = N((0.5, 0), I) (mean off by 0.5 sd, the tolerance 0.2);
* ``gauss_narrow``: q = N(0, 0.67^2 I) (sd too small by a factor 1.5, tolerance 1.2);
* ``bimodal_right``: pi = q = 0.73 N((-1, -0.5), 0.1^2) + 0.27 N((0.6, 0.4), 0.12^2)
  (``bench_active.py``'s bimodal2d);
* ``bimodal_shift5`` / ``bimodal_shift10``: q with masses 0.68 / 0.32 and 0.63 / 0.37.

A right case counts as an error when refuted (false refutation), a wrong one when
confirmed (false confirmation). Usage::

    python benchmarks/bench_sequential_check.py --seeds 400 --noise 0.1,0.3
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
from scipy.special import logsumexp

from bayescalib.inference.active import posterior_clusters, posterior_draws
from bayescalib.inference.importance import importance_check, sequential_check

M1, M2 = np.array([-1.0, -0.5]), np.array([0.6, 0.4])
S1, S2 = 0.10, 0.12


def gauss(mean, sd):
    mean = np.asarray(mean, float)

    def logpdf(X):
        return -0.5 * np.sum(((X - mean) / sd) ** 2, axis=1) - 2 * np.log(sd)

    def sample(rng, n):
        return mean + sd * rng.standard_normal((n, 2))
    return logpdf, sample


def mixture(w1):
    l1, s1 = gauss(M1, S1)
    l2, s2 = gauss(M2, S2)

    def logpdf(X):
        return logsumexp([np.log(w1) + l1(X), np.log(1 - w1) + l2(X)], axis=0)

    def sample(rng, n):
        k = rng.random(n) < w1
        return np.where(k[:, None], s1(rng, n), s2(rng, n))
    return logpdf, sample


#: case -> (pi, q, right?)
CASES = {
    "gauss_right": (gauss([0, 0], 1.0), gauss([0, 0], 1.0), True),
    "gauss_shift": (gauss([0, 0], 1.0), gauss([0.5, 0], 1.0), False),
    "gauss_narrow": (gauss([0, 0], 1.0), gauss([0, 0], 1 / 1.5), False),
    "bimodal_right": (mixture(0.73), mixture(0.73), True),
    "bimodal_shift5": (mixture(0.73), mixture(0.68), False),
    "bimodal_shift10": (mixture(0.73), mixture(0.63), False),
}
#: the posterior_check section as the schema's defaults give it
CHECK = {"min_ess_fraction": 0.5, "shift_tol": 0.2, "sd_tol": 0.2, "max_log_weight_sd": 1.0,
         "max_failed_fraction": 0.1, "mass_tol": 0.05, "alpha": 0.05}


def replicate(case, particles, labels, masses, pm, psd, seed, noise, draws, batch):
    """One seed: the three checks' verdicts on the same draws, and the draws used."""
    (log_pi, _), (log_q, _), _ = CASES[case]
    rng = np.random.default_rng([seed, 0xC0FF])
    W = np.ones(len(particles))
    D, lab = posterior_draws(particles, W, draws, rng, labels=labels, batch=batch)
    L = log_pi(D)
    mu = log_q(D) + noise * rng.standard_normal(draws)
    kw = {k: CHECK[k] for k in ("min_ess_fraction", "shift_tol", "sd_tol",
                                "max_log_weight_sd", "max_failed_fraction")}
    fixed = importance_check(D, L, mu, posterior_mean=pm, posterior_sd=psd, **kw)["confirmed"]
    one = sequential_check(D, L, mu, labels=lab, cluster_mass=masses, mass_tol=CHECK["mass_tol"],
                           alpha=CHECK["alpha"], posterior_mean=pm, posterior_sd=psd, **kw)
    n_looks = -(-draws // batch)
    for look in range(1, n_looks + 1):
        n = min(look * batch, draws)
        seq = sequential_check(D[:n], L[:n], mu[:n], labels=lab[:n], cluster_mass=masses,
                               look=look, n_looks=n_looks, final=n >= draws, max_draws=draws,
                               mass_tol=CHECK["mass_tol"], alpha=CHECK["alpha"],
                               posterior_mean=pm, posterior_sd=psd, **kw)
        if seq["decision"] != "continue":
            break
    return {"fixed": bool(fixed), "one_look": bool(one["confirmed"]),
            "sequential": bool(seq["confirmed"]), "draws_used": n}


def run_case(case, seeds, noise, draws=32, batch=8, n_particles=4000):
    """Rates over ``seeds`` replicates of one case: the share confirmed by each check,
    the error rate (refuted if right, confirmed if wrong) and the sequential check's
    mean draws."""
    _, (_, sample_q), right = CASES[case]
    P = sample_q(np.random.default_rng([7, len(case)]), n_particles)
    W = np.ones(n_particles)
    labels, masses = posterior_clusters(P, W)
    pm, psd = P.mean(axis=0), P.std(axis=0)
    reps = [replicate(case, P, labels, masses, pm, psd, s, noise, draws, batch)
            for s in range(seeds)]
    out = {"case": case, "right": right, "noise": noise, "seeds": seeds, "draws": draws,
           "batch": batch, "clusters": len(masses), "cluster_mass": np.round(masses, 3).tolist()}
    for k in ("fixed", "one_look", "sequential"):
        conf = float(np.mean([r[k] for r in reps]))
        out[f"{k}_confirmed"] = conf
        out[f"{k}_error"] = 1 - conf if right else conf
    out["sequential_mean_draws"] = float(np.mean([r["draws_used"] for r in reps]))
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seeds", type=int, default=400)
    ap.add_argument("--noise", default="0.1,0.3")
    ap.add_argument("--cases", default=",".join(CASES))
    ap.add_argument("--draws", type=int, default=32)
    ap.add_argument("--batch", type=int, default=8)
    ap.add_argument("--out", type=Path, default=None)
    args = ap.parse_args(argv)
    rows = []
    print("| case | right? | noise (nats) | clusters (q's masses) | error: fixed | error: one look "
          "+ mass | error: sequential | sequential mean draws |")
    print("|---|---|---|---|---|---|---|---|")
    for noise in [float(v) for v in args.noise.split(",")]:
        for case in args.cases.split(","):
            t0 = time.perf_counter()
            r = run_case(case, args.seeds, noise, args.draws, args.batch)
            r["wall_s"] = round(time.perf_counter() - t0, 1)
            rows.append(r)
            kind = "false refutation" if r["right"] else "false confirmation"
            print(f"| {case} | {'yes' if r['right'] else 'no'} | {noise:g} | "
                  f"{r['clusters']} ({', '.join(f'{m:.3f}' for m in r['cluster_mass'])}) | "
                  f"{r['fixed_error']:.3f} | {r['one_look_error']:.3f} | "
                  f"{r['sequential_error']:.3f} ({kind}) | {r['sequential_mean_draws']:.1f} |",
                  flush=True)
    if args.out:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(json.dumps(rows, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
