"""Benchmark and validation figures of the 3D FSI forward model (one thread).

Per 3D mesh preset (:data:`bayescalib.models.fsi.model.MESH_PRESETS_3D`): the unknowns
(all and free), elements, interface vertices and triangles, the build time (mesh and
compiled forms) and the cold solve from rest at the ground truth (E = 400 Pa,
nu = 0.3, 100 mm^3/s; median wall time over ``--repeats`` solves at E +-1 %, Newton
iterations, LU factorizations, time in factorizations), the largest interface
displacement and the largest interface velocity (slip check), and the peak memory.

Validation against analytic references (:mod:`bayescalib.models.fsi.validation3d`):

* the cantilever (solid alone, l/t = 10, nu = 0) against Timoshenko's and
  Euler–Bernoulli's tip deflection, at maxh = t/2 and t/3;
* developed duct flow (fluid alone, 2 x 1 x 1 mm) against the Fourier series:
  centreline velocity and pressure drop, at maxh = 0.25 and 0.15 mm;
* the 2D model as the limit of the ridge (its half-ellipse extruded across the width,
  slip side walls) on the 3D very_coarse and coarse presets against the 2D coarse one.

Usage::

    OPENBLAS_NUM_THREADS=1 python benchmarks/bench_fsi3d.py [--repeats 3]
        [--presets very_coarse,coarse,paper] [--no-validation]

Prints a table and a final one-line JSON summary. No assertions.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import statistics

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")


def bench_preset(preset: str, repeats: int) -> dict:
    """Build and cold-solve the 3D model on one preset."""
    from bayescalib.models.fsi.model import FSIModel

    model = FSIModel({"geometry": {"dim": 3}, "mesh": {"preset": preset}})
    times, res = [], None
    for k in range(repeats):
        model.forget_solves()
        res = model.solve({"material.E": 400.0 * (1.0 + 0.01 * (k - repeats // 2))})
        if not res.ok:
            raise RuntimeError(f"{preset}: solve failed: {res.reason}")
        times.append(res.wall_time)
        if k == 0:
            build = float(res.stats["build_time"])
    assert res is not None
    s = res.stats
    return {
        "preset": preset, "ndof": s["ndof"], "nfree": s["nfree"], "elements": s["n_elements"],
        "interface_vertices": s["n_interface_nodes"],
        "interface_triangles": s["n_interface_triangles"], "build_s": round(build, 2),
        "solve_median_s": round(statistics.median(times), 2),
        "solve_times_s": [round(t, 2) for t in times], "newton": res.newton_iterations,
        "factorizations": s["factorizations"], "factor_s": round(s["t_factor"], 2),
        "max_displacement_mm": res.max_displacement,
        "max_interface_velocity": s["max_interface_velocity"],
        "peak_rss_mb": round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0),
    }


def validation() -> dict:
    """The cantilever and duct figures at two mesh sizes each."""
    from bayescalib.models.fsi.validation3d import cantilever, duct_flow, plane_limit

    out: dict = {"cantilever": [], "duct": [], "plane_limit": []}
    for h in (0.05, 0.034):
        r = cantilever(maxh=h)
        out["cantilever"].append({
            "maxh": h, "ndof": r.ndof, "ok": r.ok, "deflection": r.deflection,
            "timoshenko": r.timoshenko, "euler_bernoulli": r.euler_bernoulli,
            "rel_err_timoshenko": r.deflection / r.timoshenko - 1.0,
            "rel_diff_euler_bernoulli": r.deflection / r.euler_bernoulli - 1.0})
    for h in (0.25, 0.15):
        r = duct_flow(maxh=h)
        out["duct"].append({
            "maxh_mm": h, "ndof": r.ndof, "ok": r.ok,
            "centre_velocity": r.centre_velocity, "centre_velocity_exact": r.centre_velocity_exact,
            "rel_err_velocity": r.centre_velocity / r.centre_velocity_exact - 1.0,
            "pressure_drop": r.pressure_drop, "pressure_drop_exact": r.pressure_drop_exact,
            "rel_err_pressure_drop": r.pressure_drop / r.pressure_drop_exact - 1.0})
    for preset in ("very_coarse", "coarse"):
        r = plane_limit({"preset": preset}, {"preset": "coarse"})
        out["plane_limit"].append({
            "preset_3d": preset, "ndof_3d": r.ndof_3d, "ndof_2d": r.ndof_2d, "ok": r.ok,
            "max_displacement_2d": r.max_displacement_2d,
            "rel_difference": r.max_difference / r.max_displacement_2d,
            "rel_out_of_plane": r.max_out_of_plane / r.max_displacement_2d,
            "rel_z_variation": r.max_z_variation / r.max_displacement_2d})
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--presets", default="very_coarse,coarse,paper")
    ap.add_argument("--no-validation", action="store_true")
    args = ap.parse_args()
    rows = [bench_preset(p, args.repeats) for p in args.presets.split(",") if p]
    print(f"{'preset':<12} {'ndof':>7} {'free':>7} {'tets':>6} {'if v/tri':>9} {'build s':>8} "
          f"{'solve s':>8} {'Newton':>6} {'LU':>3} {'LU s':>6} {'max d mm':>9} {'MB':>5}")
    for r in rows:
        print(f"{r['preset']:<12} {r['ndof']:>7} {r['nfree']:>7} {r['elements']:>6} "
              f"{r['interface_vertices']:>4}/{r['interface_triangles']:<4} {r['build_s']:>8} "
              f"{r['solve_median_s']:>8} {r['newton']:>6} {r['factorizations']:>3} "
              f"{r['factor_s']:>6} {r['max_displacement_mm']:>9.5f} {r['peak_rss_mb']:>5}")
    summary = {"presets": rows}
    if not args.no_validation:
        val = validation()
        for c in val["cantilever"]:
            print(f"cantilever maxh {c['maxh']}: tip {c['deflection']:.6e} vs Timoshenko "
                  f"{c['timoshenko']:.6e} ({100 * c['rel_err_timoshenko']:+.3f} %), "
                  f"Euler-Bernoulli {100 * c['rel_diff_euler_bernoulli']:+.3f} %, {c['ndof']} DOFs")
        for d in val["duct"]:
            print(f"duct maxh {d['maxh_mm']} mm: centre velocity {100 * d['rel_err_velocity']:+.3f} %,"
                  f" pressure drop {100 * d['rel_err_pressure_drop']:+.3f} %, {d['ndof']} DOFs")
        for q in val["plane_limit"]:
            print(f"ridge, slip walls, 3D {q['preset_3d']} vs 2D coarse: mid-plane displacement "
                  f"{100 * q['rel_difference']:.2f} %, |d_z| {100 * q['rel_out_of_plane']:.2f} %, "
                  f"along z {100 * q['rel_z_variation']:.2f} % of the 2D maximum "
                  f"{q['max_displacement_2d']:.5f} mm ({q['ndof_3d']} / {q['ndof_2d']} DOFs)")
        summary["validation"] = val
    print(json.dumps(summary))


if __name__ == "__main__":
    main()
