"""Benchmark of the candidate physics and of series of loadings (one thread).

For each candidate of :mod:`bayescalib.models.fsi.physics`, on the chosen mesh preset:

* cold solve (from rest) with the candidate switched on at ``phi = 0``, against the
  base model: the median over ``--repeats`` parameter points near the ground truth
  (E = 400 Pa, nu = 0.3, +-5 %) of the time ratio of the two solves, timed back to
  back (the target is at most ~1.1);
* the same at the candidate's typical ``phi`` (:data:`CANDIDATES`);
* warm-started solves at the typical ``phi`` (from the model's own state at the
  ground truth, the factorization kept), paired in the same way with warm-started
  base solves: the cost of a candidate inside a calibration, where most solves are
  warm (the permeable biofilm adds a pore-pressure block: more unknowns);
* the largest change of the interface at the typical ``phi`` and the ground truth, mm
  (compare with the mesh error, ~1e-4 mm on the paper mesh: NOTES-fsi.md);
* nestedness: the largest interface difference between ``phi = 0`` and the base, mm.

Then a series of three loadings (0, 0.5, 1 x the nominal inflow, by continuation)
against one loading, cold and warm-started from a state at the prior centre.

Usage::

    OPENBLAS_NUM_THREADS=1 python benchmarks/bench_physics.py [--preset paper] [--repeats 5]
        [--candidates permeability,growth] [--no-loadings]

Prints a table and a final one-line JSON summary. No assertions.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import tempfile
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np

TRUTH = {"material.E": 400.0, "material.nu": 0.3}


def _near_truth(n: int, seed: int = 1) -> list[dict[str, float]]:
    rng = np.random.default_rng(seed)
    return [{"material.E": 400.0 * (1 + 0.05 * rng.uniform(-1, 1)),
             "material.nu": 0.3 * (1 + 0.05 * rng.uniform(-1, 1))} for _ in range(n)]


def _median_solve(model, points, extra) -> tuple[float, list]:
    times, results = [], []
    for p in points:
        t0 = time.perf_counter()
        res = model.solve({**p, **extra})
        times.append(time.perf_counter() - t0)
        results.append(res)
    return statistics.median(times), results


def _paired_ratios(base, model, points, extra) -> dict:
    """Median over points of t(model)/t(base), the two solves timed back to back (so
    that a load change of the machine affects both), and the median model time."""
    ratios, times, ok = [], [], True
    for p in points:
        t0 = time.perf_counter()
        base.solve(p)
        t1 = time.perf_counter()
        res = model.solve({**p, **extra})
        t2 = time.perf_counter()
        ratios.append((t2 - t1) / (t1 - t0))
        times.append(t2 - t1)
        ok &= res.ok
    return {"ratio": statistics.median(ratios), "t": statistics.median(times), "ok": ok}


def _paired_warm_ratios(base, model, points, extra) -> dict:
    """As :func:`_paired_ratios` for warm-started solves: each model first solves the
    ground truth (untimed), then the point from that state (``warm_start="last"``)."""
    ratios, times, base_times, ok = [], [], [], True
    for p in points:
        base.solve(TRUTH)
        t0 = time.perf_counter()
        base.solve(p, warm_start="last")
        t1 = time.perf_counter()
        model.solve({**TRUTH, **extra})
        t2 = time.perf_counter()
        res = model.solve({**p, **extra}, warm_start="last")
        t3 = time.perf_counter()
        ratios.append((t3 - t2) / (t1 - t0))
        times.append(t3 - t2)
        base_times.append(t1 - t0)
        ok &= res.ok
    return {"ratio": statistics.median(ratios), "t": statistics.median(times),
            "t_base": statistics.median(base_times), "ok": ok}


def _shift(a, b) -> float:
    return float(np.max(np.hypot(*(a.interface_current - b.interface_current).T)))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--preset", default="paper", choices=["paper", "coarse", "fine"])
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--candidates", default="",
                    help="comma-separated candidate names (default: all)")
    ap.add_argument("--no-loadings", action="store_true",
                    help="skip the series-of-loadings benchmark")
    args = ap.parse_args()

    from bayescalib.models.fsi.model import FSIModel
    from bayescalib.models.fsi.physics import CANDIDATES

    names = [n.strip() for n in args.candidates.split(",") if n.strip()] or list(CANDIDATES)
    unknown = sorted(set(names) - set(CANDIDATES))
    if unknown:
        ap.error(f"--candidates: unknown {unknown}; expected some of {sorted(CANDIDATES)}")
    mesh = {"mesh": {"preset": args.preset}}
    points = _near_truth(args.repeats)
    base = FSIModel(mesh)
    base.solve(TRUTH)  # build + first solve (not timed)
    t_base, _ = _median_solve(base, points, {})
    ref = base.solve(TRUTH)
    rows = []
    print(f"mesh preset {args.preset}: base cold solve median {t_base:.3f} s "
          f"over {args.repeats} solves ({ref.stats['nfree']} free unknowns)")
    print(f"{'candidate':12s} {'phi':>9s} {'t(phi=0)/base':>14s} {'t(phi)/base':>12s} "
          f"{'t(phi) s':>9s} {'warm/base':>10s} {'warm s':>7s} {'base warm s':>12s} "
          f"{'nfree':>6s} {'|shift| mm':>11s} {'nested mm':>10s} {'ok':>3s}")
    for name in names:
        cand = CANDIDATES[name]
        model = FSIModel({**mesh, "physics": {name: {"enabled": True}}})
        model.solve(TRUTH)
        key = cand.key
        r0 = _paired_ratios(base, model, points, {})
        nested = _shift(model.solve(TRUTH), ref)
        # attachment: phi > 0 switches the clamp to springs (new spaces): build first
        model.solve({**TRUTH, key: cand.typical})
        r1 = _paired_ratios(base, model, points, {key: cand.typical})
        rw = _paired_warm_ratios(base, model, points, {key: cand.typical})
        at_truth = model.solve({**TRUTH, key: cand.typical})
        ok = r1["ok"] and rw["ok"] and at_truth.ok
        shift = _shift(at_truth, ref) if at_truth.ok else float("nan")
        nfree = int(at_truth.stats["nfree"])
        rows.append({"candidate": name, "phi": cand.typical, "unit": cand.unit,
                     "ratio_phi0": r0["ratio"], "ratio_phi": r1["ratio"],
                     "t_phi": r1["t"], "ratio_warm": rw["ratio"], "t_warm": rw["t"],
                     "t_base_warm": rw["t_base"], "nfree": nfree,
                     "newton_phi": at_truth.newton_iterations,
                     "shift_mm": shift, "nested_mm": nested, "ok": ok})
        print(f"{name:12s} {cand.typical:9.3g} {r0['ratio']:14.3f} {r1['ratio']:12.3f} "
              f"{r1['t']:9.3f} {rw['ratio']:10.3f} {rw['t']:7.3f} {rw['t_base']:12.3f} "
              f"{nfree:6d} {shift:11.2e} {nested:10.1e} {'yes' if ok else 'NO':>3s}")
    if args.no_loadings:
        print(json.dumps({"preset": args.preset, "repeats": args.repeats, "t_base": t_base,
                          "candidates": rows}))
        return

    # series of loadings
    factors = [0.0, 0.5, 1.0]
    m = FSIModel(mesh)
    m.solve(TRUTH)
    t1, _ = _median_solve(m, points, {})
    t3 = []
    for p in points:
        t = time.perf_counter()
        out = m.solve_loadings(p, factors)
        t3.append(time.perf_counter() - t)
        assert all(r.ok for r in out)
    t3m = statistics.median(t3)
    with tempfile.TemporaryDirectory() as tmp:
        m.solve({"material.E": 450.0, "material.nu": -0.15})
        state = Path(tmp) / "centre.npz"
        m.save_state(state)
        w1, w3 = [], []
        for p in points:
            fresh = FSIModel(mesh)
            fresh.solve(TRUTH)  # build
            t = time.perf_counter()
            fresh.solve(p, warm_start=state)
            w1.append(time.perf_counter() - t)
            fresh = FSIModel(mesh)
            fresh.solve(TRUTH)
            t = time.perf_counter()
            fresh.solve_loadings(p, factors, warm_start=state)
            w3.append(time.perf_counter() - t)
    w1m, w3m = statistics.median(w1), statistics.median(w3)
    print(f"loadings {factors}: cold 1 loading {t1:.3f} s, 3 loadings {t3m:.3f} s "
          f"(ratio {t3m / t1:.2f}); warm-started from the prior centre: 1 loading "
          f"{w1m:.3f} s, 3 loadings {w3m:.3f} s (ratio {w3m / w1m:.2f})")
    print(json.dumps({"preset": args.preset, "repeats": args.repeats, "t_base": t_base,
                      "candidates": rows,
                      "loadings": {"factors": factors, "cold_1": t1, "cold_3": t3m,
                                   "warm_1": w1m, "warm_3": w3m}}))


if __name__ == "__main__":
    main()
