"""The exact likelihood landscape of bench_active.py's 7D problem (hetero7d): its modes,
the profile over nu1, and how far a given point lies below the mode.

Prints (i) the end points of local searches (L-BFGS-B in the box-scaled
coordinates, then Nelder-Mead) from ``--starts`` uniform random starts: the distinct
maxima of the exact log-likelihood and how many starts reach each; (ii) the profile
log-likelihood over nu1 (the other six maximized, from the best maximum and from
``--point``); (iii) for ``--point`` (seven comma-separated values, e.g. an active run's
posterior mean), its exact log-likelihood and the end of a local search from it.
This is what docs/bench_active.md's "no second branch" rests on.

Run (repository root)::

    python benchmarks/h7_landscape.py --point 518.6,211.2,726.8,0.1123,-0.1428,0.1195,109.5
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
from scipy.optimize import minimize

sys.path.insert(0, str(Path(__file__).resolve().parent))
import bench_active as B


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--starts", type=int, default=40)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--point", default=None, help="7 comma-separated parameter values")
    ap.add_argument("--out", default="results/bench_active", help="where the reference cache lives")
    args = ap.parse_args(argv)
    p = B.make_hetero7d(Path(args.out), False)
    lo, hi = p.bounds[:, 0], p.bounds[:, 1]
    names = p.names

    def neg(u: np.ndarray) -> float:
        return -float(p.loglik(lo + np.clip(u, 0.0, 1.0) * (hi - lo))[0])

    def search(u0: np.ndarray, fixed: int | None = None, value: float | None = None):
        if fixed is None:
            f, x0 = neg, u0
        else:
            def f(v):
                return neg(np.insert(v, fixed, value))
            x0 = np.delete(u0, fixed)
        r = minimize(f, x0, method="L-BFGS-B", bounds=[(0.0, 1.0)] * len(x0))
        r = minimize(f, r.x, method="Nelder-Mead",
                     options={"maxiter": 20000, "xatol": 1e-9, "fatol": 1e-10})
        u = np.clip(r.x if fixed is None else np.insert(r.x, fixed, value), 0.0, 1.0)
        return -float(r.fun), lo + u * (hi - lo)

    rng = np.random.default_rng(args.seed)
    ends = [search(rng.random(p.d)) for _ in range(args.starts)]
    ends.sort(key=lambda t: -t[0])
    print(f"(i) local searches from {args.starts} uniform random starts:")
    groups: list[tuple[float, np.ndarray, int]] = []
    for L, x in ends:
        for k, (Lg, xg, c) in enumerate(groups):
            if abs(L - Lg) < 0.1 and np.allclose(x[3:6], xg[3:6], atol=0.01):
                groups[k] = (Lg, xg, c + 1)
                break
        else:
            groups.append((L, x, 1))
    for L, x, c in groups:
        print(f"    L = {L:9.3f} reached by {c:3d} starts; nu = {np.round(x[3:6], 3)}; "
              f"E_i / q = {np.round(x[:3] / x[6], 3)}")
    L_max, x_max = ends[0]
    point = None if args.point is None else np.array([float(v) for v in args.point.split(",")])
    print("(ii) profile log-likelihood over nu1 (others maximized):")
    k = names.index("nu1")
    for nu in np.linspace(lo[k], hi[k], 20):
        v = (nu - lo[k]) / (hi[k] - lo[k])
        starts = [x_max] + ([point] if point is not None else [])
        best = max(search((s - lo) / (hi - lo), k, v)[0] for s in starts)
        print(f"    nu1 = {nu:6.3f}: {best:9.2f}")
    if point is not None:
        L0 = float(p.loglik(point[None])[0])
        L1, x1 = search((point - lo) / (hi - lo))
        print(f"(iii) at the point: L = {L0:.2f} ({L_max - L0:.1f} below the mode {L_max:.2f}); "
              f"a local search from it ends at L = {L1:.2f}, {dict(zip(names, np.round(x1, 3)))}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
