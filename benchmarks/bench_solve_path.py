"""Benchmark of the one solve path: a new model per point against a kept model.

Solves ``--n`` design points of a study's forward model (default: the smoke study,
coarse mesh, every point warm-started from the base state at the prior centre, as the
workflow does) through :func:`bayescalib.models.forward.solve_points` in two ways:

* ``fresh``: one ``solve_points`` call per point, as the workflow's per-point ``solve``
  jobs do it: a new solve process and a new model (mesh, spaces, forms) for every point,
  forked from this process after it imported what the workflow's point job server
  imports (``jobserver._PRELOAD``: NGSolve included, so no point pays its import);
* ``kept``: one ``solve_points`` call for all points (one worker), as the diagnosis and
  ``bayescalib solve --points`` do it: one solve process keeps its model (mesh, spaces,
  compiled forms) and forgets its solver state before every point.

Printed per mode: the median wall time per point end to end (``fresh``: per call;
``kept``: the call's total / n, the only end-to-end figure of a batch) and the median of
the records' ``wall_time`` (inside the solve process: model build + solve), and the
ratios; then whether the kept model's records equal the fresh ones bit for bit.

For information, a third sequence that the library does *not* use: one model in this
process that also keeps its LU factorization and last state from point to point
(``FSIModel.solve`` with ``solver.keep_factorization``, no ``forget_solves``): its time
per point and how far its interfaces are from the fresh records (Newton's iterates
differ, so results agree only to the solver's tolerance and depend on the order of the
points). It runs last: after an fsi model was built in this process, a forked solve
process would hang in Netgen's mesh generation.

Usage::

    nice -n 5 python benchmarks/bench_solve_path.py [--config config/smoke.yaml] [--n 6]

No assertions.
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "src"))


def _points(study, n: int, seed: int = 3) -> list[dict[str, float]]:
    """``n`` points in the middle half of the design box (no failed solves at low E)."""
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(n):
        p = {}
        for par in study.config["parameters"]:
            lo, hi = (float(b) for b in par["bounds"])
            p[par["target"]] = float(lo + (hi - lo) * rng.uniform(0.25, 0.75))
        out.append(p)
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--config", default=str(ROOT / "config" / "smoke.yaml"))
    ap.add_argument("--n", type=int, default=6)
    args = ap.parse_args(argv)

    import importlib

    from bayescalib.config import load_yaml
    from bayescalib.execution.jobserver import _PRELOAD
    from bayescalib.models.forward import solve_base_state, solve_points
    from bayescalib.study import Study

    for mod in _PRELOAD:  # what the workflow's point server imports before it forks jobs
        importlib.import_module(mod)

    study = Study(load_yaml(args.config), where=args.config)
    fm = study.forward_section()
    pts = _points(study, args.n)
    work = Path(tempfile.mkdtemp(prefix="bench_solve_path_"))
    base = None
    if fm["type"] == "fsi" and fm["warm_start"] in ("auto", "prior_centre"):
        base = work / "base_state.state.npz"
        solve_base_state(fm, study.prior_centre(), work / "base_state.h5", base)

    fresh, fresh_wall = [], []
    for i, p in enumerate(pts):
        t0 = time.perf_counter()
        fresh += solve_points(fm, [p], [work / "fresh" / f"{i}.h5"], warm_start=base,
                              reuse=False)
        fresh_wall.append(time.perf_counter() - t0)
    t0 = time.perf_counter()
    kept = solve_points(fm, pts, [work / "kept" / f"{i}.h5" for i in range(len(pts))],
                        warm_start=base, workers=1, reuse=False)
    kept_total = time.perf_counter() - t0

    med_fresh = statistics.median(fresh_wall)
    med_kept = kept_total / len(pts)
    rec_fresh = statistics.median(r.wall_time for r in fresh)
    rec_kept = statistics.median(r.wall_time for r in kept)
    same = all(a.status == b.status and np.array_equal(a.interface_current, b.interface_current)
               and all(np.array_equal(x.current, y.current)
                       for x, y in zip(a.loadings, b.loadings, strict=True))
               for a, b in zip(fresh, kept, strict=True))
    print(f"study {study.name}: {len(pts)} points, forward model {fm['type']}"
          + (f", mesh {fm['fsi']['mesh']['preset']}" if fm["type"] == "fsi" else "")
          + f", warm start {'base state' if base else 'none'}; statuses "
          + ", ".join(r.status for r in kept))
    print(f"{'':34s}{'fresh':>10s}{'kept':>10s}{'kept/fresh':>12s}")
    print(f"{'s per point, end to end (median)':34s}{med_fresh:10.3f}{med_kept:10.3f}"
          f"{med_kept / med_fresh:12.3f}")
    print(f"{'s per point, in the solve process':34s}{rec_fresh:10.3f}{rec_kept:10.3f}"
          f"{rec_kept / rec_fresh:12.3f}")
    print(f"{'mesh builds (s, median of built)':34s}"
          f"{statistics.median(r.stats['build_time'] for r in fresh):10.3f}"
          f"{statistics.median(r.stats['build_time'] for r in kept if r.stats['build_time']):10.3f}"
          f"   (builds: fresh {sum(1 for r in fresh if r.stats['build_time'])}, "
          f"kept {sum(1 for r in kept if r.stats['build_time'])})")
    print(f"kept records equal to the fresh ones bit for bit: {same}")

    if fm["type"] == "fsi":  # last: an fsi model built in this process (see the docstring)
        from bayescalib.models.fsi.model import FSIModel

        model = FSIModel(fm["fsi"])
        walls, diffs, iters = [], [], []
        for p, ref in zip(pts, fresh, strict=True):
            t0 = time.perf_counter()
            r = model.solve(p, warm_start=base)
            walls.append(time.perf_counter() - t0)
            iters.append((r.newton_iterations, r.stats.get("factorizations"),
                          ref.newton_iterations, ref.stats.get("factorizations")))
            if r.ok and ref.ok:
                diffs.append(float(np.abs(r.interface_current - ref.interface_current).max()))
        print("not used (information): one model keeping its factorization between points, "
              "single loading:")
        print(f"  s per point (median) {statistics.median(walls):.3f}; max |interface - fresh| "
              f"{max(diffs):.3g} mm (median {statistics.median(diffs):.3g}); Newton "
              "iterations/factorizations kept vs fresh: "
              + ", ".join(f"{a}/{b} vs {c}/{d}" for a, b, c, d in iters))
    print(f"(records under {work})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
