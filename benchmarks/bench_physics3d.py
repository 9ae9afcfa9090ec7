"""Benchmark of the candidate physics in the 3D model (one thread).

For the base model and each candidate of the 3D model
(:data:`bayescalib.models.fsi.model.PHYSICS_3D`), on the chosen 3D mesh preset, at
E = 400 Pa, nu = 0.3 and the default inflow (100 mm^3/s, the developed duct profile):

* the largest interface displacement (um) at the candidate's typical ``phi``
  (:data:`bayescalib.models.fsi.physics.CANDIDATES`) and at one larger value;
* the largest change of the interface against the base model (um);
* the wall time of the solve (cold: from rest, the model built beforehand; the
  build, mesh and compiled forms, is timed apart) and its Newton iterations.

The 2D analogue is ``bench_physics.py``.

Usage::

    OPENBLAS_NUM_THREADS=1 python benchmarks/bench_physics3d.py [--preset coarse]
        [--candidates layer,gravity]

Prints a table and a final one-line JSON summary. No assertions.
"""

from __future__ import annotations

import argparse
import json
import os
import time

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np

TRUTH = {"material.E": 400.0, "material.nu": 0.3}
#: one value beyond the typical one per candidate (the typical: CANDIDATES[...].typical)
LARGER = {"layer": 2.0, "growth": 0.1, "attachment": 1.0e-3, "inflow_skew": 0.8, "stiffening": 60.0,
          "gravity": 200.0, "permeability": 1000.0}


def _shift_um(a, b) -> float:
    return 1e3 * float(np.max(np.linalg.norm(a.interface_current - b.interface_current, axis=1)))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--preset", default="coarse", choices=["very_coarse", "coarse", "paper"])
    ap.add_argument("--candidates", default="",
                    help="comma-separated candidate names (default: all of the 3D model)")
    args = ap.parse_args()

    from bayescalib.models.fsi.model import PHYSICS_3D, FSIModel
    from bayescalib.models.fsi.physics import CANDIDATES

    names = [n.strip() for n in args.candidates.split(",") if n.strip()] or list(PHYSICS_3D)
    unknown = sorted(set(names) - set(PHYSICS_3D))
    if unknown:
        ap.error(f"--candidates: not in the 3D model {unknown}; expected some of {PHYSICS_3D}")
    cfg = {"geometry": {"dim": 3}, "mesh": {"preset": args.preset}}

    def build(name: str | None):
        t0 = time.perf_counter()
        model = FSIModel({**cfg, "physics": {} if name is None else {name: {"enabled": True}}})
        model._build(model.resolved_config())
        return model, time.perf_counter() - t0

    rows = []
    base, t_build = build(None)
    t0 = time.perf_counter()
    ref = base.solve(TRUTH)
    rows.append({"candidate": "base", "phi": 0.0, "status": ref.status,
                 "max_disp_um": 1e3 * ref.max_displacement, "shift_um": 0.0,
                 "t_solve": time.perf_counter() - t0, "t_build": t_build,
                 "newton": ref.newton_iterations, "ndof": ref.stats["ndof"]})
    print(f"3D preset {args.preset}: {ref.stats['ndof']} unknowns, "
          f"{ref.stats['n_interface_nodes']} interface vertices; E = 400 Pa, nu = 0.3, "
          f"inflow {ref.parameters['inflow.rate']:g} mm^3/s")
    for name in names:
        model, t_build = build(name)
        for phi in (CANDIDATES[name].typical, LARGER[name]):
            t0 = time.perf_counter()
            res = model.solve({**TRUTH, f"physics.{name}.phi": phi})
            rows.append({"candidate": name, "phi": phi, "status": res.status,
                         "max_disp_um": 1e3 * res.max_displacement,
                         "shift_um": _shift_um(res, ref), "t_solve": time.perf_counter() - t0,
                         "t_build": t_build, "newton": res.newton_iterations,
                         "ndof": res.stats["ndof"], "reason": res.reason})
            t_build = 0.0

    print(f"{'candidate':<13} {'phi':>9} {'unit':>7} {'status':>6} {'max disp um':>11} "
          f"{'shift um':>9} {'solve s':>8} {'build s':>8} {'Newton':>6}")
    for r in rows:
        unit = CANDIDATES[r["candidate"]].unit if r["candidate"] in CANDIDATES else ""
        print(f"{r['candidate']:<13} {r['phi']:>9.4g} {unit:>7} {r['status']:>6} "
              f"{r['max_disp_um']:>11.2f} {r['shift_um']:>9.2f} {r['t_solve']:>8.1f} "
              f"{r['t_build']:>8.1f} {r['newton']:>6d}")
        if r.get("reason"):
            print(f"    {r['reason']}")
    print(json.dumps({"preset": args.preset, "rows": rows}))


if __name__ == "__main__":
    main()
