"""Cheap probe for a concealed pair case (issue 39, item 3): does the linearized
attribution select two hidden effects together, and does either single model explain them?

Used to choose the truths of ``config/concealed/pair_unselected.yaml`` before running the
full benchmark (a probe of one pair: about 25 s of real solves, 2-3 min with the fits).
For each pair of hidden effects (their phi, in the candidates' units) at a truth (E, nu)
with Gaussian coordinate noise (sd, seed as ``observations``), on the concealed settings
(``config/concealed/common.yaml``: coarse mesh, three loadings):

1. sizes: RMS interface offset of each effect alone and of both, against the base model at
   the truth (noise-free);
2. the base fit: bounded least squares of (E, nu) on the noisy nodes with real solves (a
   stand-in for the study's calibration, whose posterior mean the diagnosis linearizes at);
3. the attribution: at that fit, finite-difference Jacobian and candidate signatures (the
   diagnosis's steps) and :func:`bayescalib.diagnosis.attribution.attribute` with the
   diagnosis's settings; prints the ranking, the greedy steps, the selection and the two
   singles the diagnosis would calibrate with ``n_extend: 2``;
4. ``--fit``: bounded least-squares fits with real solves of the single models (``first``:
   the first single only, when the attribution selected one effect and the singles are
   the pair; ``all``: both singles and the pair's joint model), their RMS against
   1.5 x the noise (the RMS rule of ``explains_mismatch``).

What it leaves out: the surrogate, SMC and posterior draws (the diagnosis uses the
posterior mean and the check's residual variance, not a least-squares fit), so its
fractions and RMS are indicative only.

Usage::

    python benchmarks/pair_probe.py --truth 300,0.25 --noise-um 0.8 --seed 71 \\
        --pairs '[{"growth": 0.015, "layer": 1.6}]' [--fit first|all] [--out DIR]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np
from scipy.optimize import least_squares

sys.path.insert(0, str(Path(__file__).resolve().parent))
import detection_limits as dl


def main() -> None:
    from bayescalib.diagnosis.attribution import attribute
    from bayescalib.diagnosis.detection import _prediction_variance, linearize, noisy_nodes
    from bayescalib.diagnosis.residuals import offsets
    from bayescalib.diagnosis.stage import resolve_candidates
    from bayescalib.models.forward import solve_points

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--truth", default="300,0.25", help="E,nu")
    ap.add_argument("--noise-um", type=float, default=0.8)
    ap.add_argument("--seed", type=int, default=71)
    ap.add_argument("--pairs", required=True, help="JSON list of {candidate: phi}")
    ap.add_argument("--fit", choices=["none", "first", "all"], default="none")
    ap.add_argument("--out", default="results/pair_probe")
    args = ap.parse_args()
    theta_t = np.array([float(x) for x in args.truth.split(",")])
    sig = args.noise_um * 1e-3
    out = Path(args.out)
    study = dl._study([dl.REPO / "config" / "config.yaml", dl.CONCEALED / "common.yaml",
                       dl.CONCEALED / "null.yaml"])
    cfg, fm = study.config, study.forward_section()
    n_snap = len(fm["loadings"]["factors"])
    cands = resolve_candidates(fm, cfg["diagnose"])
    by = {c.name: c for c in cands}
    targets = study.targets()
    lo, hi = study.space.bounds[:, 0], study.space.bounds[:, 1]
    steps = {c.name: c.step for c in cands}
    ranges = {c.name: c.prior for c in cands}
    sigma_l = float(np.sqrt(cfg["likelihood"]["sigma_n2"]))
    count = [0]

    def point(theta, phis):
        p = dict(zip(targets, map(float, theta), strict=True))
        for n, v in phis.items():
            p[by[n].target] = float(v)
            p.update(by[n].switches)
        return p

    def solve(points, tag):
        count[0] += len(points)
        (out / "solves").mkdir(parents=True, exist_ok=True)
        runs = solve_points(fm, points, [out / "solves" / f"{tag}_{i}.h5" for i in range(len(points))])
        return [dl._curves(r, n_snap) if r.ok else None for r in runs]

    def fit(noisy, names, x0):
        lb = np.array(list(lo) + [ranges[n][0] for n in names])
        ub = np.array(list(hi) + [ranges[n][1] for n in names])

        def res(z):
            x = lb + z * (ub - lb)
            c = solve([point(x[:2], dict(zip(names, x[2:], strict=True)))], "fit")[0]
            if c is None:
                return np.full(sum(len(p) for p in noisy), 50.0)
            return np.concatenate([offsets(p, c[s], [])[0] for s, p in enumerate(noisy)]) / sig

        z0 = np.clip((np.asarray(x0) - lb) / (ub - lb), 1e-3, 1 - 1e-3)
        r = least_squares(res, z0, bounds=(0, 1), diff_step=1e-3, max_nfev=60)
        return lb + r.x * (ub - lb), 1e3 * sig * float(np.sqrt(np.mean(r.fun ** 2)))

    t0 = time.time()
    for pair in json.loads(args.pairs):
        print(f"=== {pair}", flush=True)
        sub = solve([point(theta_t, pair), point(theta_t, {})]
                    + [point(theta_t, {n: v}) for n, v in pair.items()], "truth")
        if sub[0] is None:
            print("  the truth does not solve")
            continue
        def size(c, ref=sub[1]):
            y = np.concatenate([offsets(c[s].points, ref[s], [])[0] for s in range(n_snap)])
            return 1e3 * float(np.sqrt(np.mean(y ** 2)))

        print("  sizes (RMS um): " + ", ".join(
            f"{n} {size(c):.2f}" if c is not None else f"{n} failed"
            for n, c in zip(pair, sub[2:], strict=True)) + f", both {size(sub[0]):.2f}")
        noisy = noisy_nodes([sub[0][s].points for s in range(n_snap)], sig, args.seed)
        xb, rmsb = fit(noisy, [], theta_t)
        print(f"  base fit E {xb[0]:.0f} nu {xb[1]:.3f}: RMS {rmsb:.2f} um (noise {args.noise_um:.2f})")
        h = float(cfg["diagnose"]["fd_step"]) * (hi - lo)
        h = np.where(xb + h > hi, -h, h)
        C = solve([point(xb, {})] + [point(xb + h * (np.arange(2) == i), {}) for i in range(2)]
                  + [point(xb, {c.name: c.step}) for c in cands], "lin")
        cc = {c.name: C[3 + i] for i, c in enumerate(cands) if C[3 + i] is not None}
        y, J, sigs = linearize(noisy, C[0], C[1:3], list(h), cc, steps)
        v = sig ** 2 + _prediction_variance(J, sigma_l)
        d = cfg["diagnose"]
        a = attribute(y, J, sigs, v, alpha=d["alpha"], r2_min=d["r2_min"],
                      max_effects=d["max_effects"], ranges=ranges)
        for t in a["ranking"][:5]:
            print(f"   rank {t['candidate']}: p {t['p_value']:.2g}, explains "
                  f"{t['explained_fraction']:.3f}, phi_hat {t['phi_hat']:.3g} "
                  f"(plausible {t['phi_hat_plausible']}), identifiable {t['identifiable_fraction']:.2f}")
        for s in a["steps"]:
            print(f"   step {s['candidate']}: p {s['p_value']:.2g}, joint {s['joint_explained']:.3f}, "
                  f"accepted {s['accepted']}")
        ranked = [t["candidate"] for t in a["ranking"]
                  if t["phi_hat_plausible"] and t["identifiable_fraction"] > 0.05]
        singles = list(dict.fromkeys(a["selected"] + ranked))[:2]
        print(f"   selected {a['selected']} ({a['explained']:.3f}); singles {singles}", flush=True)
        if args.fit == "none" or (args.fit == "first" and (
                set(singles) != set(pair) or len(a["selected"]) > 1)):
            continue
        models = [singles[:1]] if args.fit == "first" else [[n] for n in singles] + [list(pair)]
        for names in models:
            x, rms = fit(noisy, names, list(xb) + [0.5 * sum(ranges[n]) for n in names])
            print(f"   fit {names}: RMS {rms:.2f} um (explains if <= {1.5 * args.noise_um:.2f}); "
                  f"E {x[0]:.0f}, nu {x[1]:.3f}, phi {np.round(x[2:], 5).tolist()}", flush=True)
    print(f"{count[0]} solves, {time.time() - t0:.0f} s")


if __name__ == "__main__":
    main()
