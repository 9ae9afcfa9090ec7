"""The 3D model's scanned colony against the analytic one (one thread).

The default half-ellipsoid (width 0.6, height 0.4, depth 0.6 mm, centre (1, 0, 0.5) in
the 2 x 1 x 1 mm channel) meshed two ways: ``shape: half_ellipse`` (the exact
OpenCascade ellipsoid) and ``shape: scan`` (its surface triangulated, 24 rings x 96
points, written as an STL file, read back and taken as a height field,
:mod:`bayescalib.models.fsi.scan3d`, default grid and smoothing). Per mesh preset and
shape: the time to make the height field (scan only), the mesh time
(:func:`bayescalib.models.fsi.geometry3d.build_mesh_3d`), the model's build (mesh and
compiled forms) and the cold solve from rest at E = 400 Pa, nu = 0.3 and the default
inflow (medians of ``--repeats``, each a fresh model), the tetrahedra, the colony's
volume and interface area, and the largest displacement.

Usage::

    OPENBLAS_NUM_THREADS=1 python benchmarks/bench_scan3d.py [--repeats 3]
        [--presets very_coarse,coarse]

Prints one line per case and a final JSON summary. No assertions.
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

A, B, C, XC, ZC = 0.3, 0.4, 0.3, 1.0, 0.5


def _dome(x, z):
    r2 = ((x - XC) / A) ** 2 + ((z - ZC) / C) ** 2
    return np.where(r2 < 1, B * np.sqrt(np.clip(1 - r2, 0, None)), -1.0)


def _write_stl(path: Path, surface) -> None:
    import vtk
    from vtk.util.numpy_support import numpy_to_vtk, numpy_to_vtkIdTypeArray

    pts = vtk.vtkPoints()
    pts.SetData(numpy_to_vtk(surface.points, deep=True))
    conn = np.column_stack([np.full(len(surface.cells), 3), surface.cells]).astype(np.int64)
    cells = vtk.vtkCellArray()
    cells.ImportLegacyFormat(numpy_to_vtkIdTypeArray(conn.ravel(), deep=True))
    poly = vtk.vtkPolyData()
    poly.SetPoints(pts)
    poly.SetPolys(cells)
    w = vtk.vtkSTLWriter()
    w.SetFileName(str(path))
    w.SetInputData(poly)
    w.Write()


def main() -> None:
    import ngsolve as ng

    from bayescalib.config import validate
    from bayescalib.models.fsi.geometry3d import build_mesh_3d
    from bayescalib.models.fsi.model import MESH_PRESETS_3D, FSIModel
    from bayescalib.models.fsi.scan3d import scan_height_field, star_surface

    ap = argparse.ArgumentParser()
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--presets", default="very_coarse,coarse")
    args = ap.parse_args()
    ng.SetNumThreads(1)
    tmp = Path(tempfile.mkdtemp())
    stl = tmp / "dome.stl"
    _write_stl(stl, star_surface(_dome, (XC, ZC), n_rings=24, n_angles=96))
    params = {"material.E": 400.0, "material.nu": 0.3}
    rows = []
    for preset in args.presets.split(","):
        mesh_cfg = {**MESH_PRESETS_3D[preset], "curve_order": 2}
        for shape in ("half_ellipse", "scan"):
            geo = {"dim": 3, "shape": shape}
            field_s = []
            if shape == "scan":
                for _ in range(args.repeats):
                    g = validate({"geometry": {**geo, "scan": {"path": str(stl)}}},
                                 "fsi")["geometry"]
                    t0 = time.perf_counter()
                    hf = scan_height_field(g, min_gap=mesh_cfg["h_interface"])
                    field_s.append(time.perf_counter() - t0)
                geo["height_field"] = hf.to_config()
            cfg = validate({"geometry": geo, "mesh": {"preset": preset}}, "fsi")
            mesh_s, build_s, solve_s = [], [], []
            for _ in range(args.repeats):
                t0 = time.perf_counter()
                bm = build_mesh_3d(cfg["geometry"], mesh_cfg)
                mesh_s.append(time.perf_counter() - t0)
                model = FSIModel(cfg)
                t0 = time.perf_counter()
                res = model.solve(params)
                total = time.perf_counter() - t0
                build_s.append(model.build_time)
                solve_s.append(total - model.build_time)
            m = bm.mesh
            row = {
                "preset": preset, "shape": shape, "status": res.status,
                "field_s": statistics.median(field_s) if field_s else None,
                "mesh_s": statistics.median(mesh_s), "build_s": statistics.median(build_s),
                "solve_s": statistics.median(solve_s), "tets": m.ne,
                "interface_triangles": len(bm.segments),
                "volume_mm3": ng.Integrate(1.0, m, definedon=m.Materials("biofilm")),
                "area_mm2": ng.Integrate(1.0, m, definedon=m.Boundaries("interface")),
                "max_displacement_mm": res.max_displacement,
            }
            rows.append(row)
            print(json.dumps(row), flush=True)
    for preset in args.presets.split(","):
        a, s = [r for r in rows if r["preset"] == preset]
        print(f"{preset}: scan/analytic volume {s['volume_mm3'] / a['volume_mm3'] - 1:+.2%}, "
              f"area {s['area_mm2'] / a['area_mm2'] - 1:+.2%}, max displacement "
              f"{s['max_displacement_mm'] / a['max_displacement_mm'] - 1:+.2%}")
    print(json.dumps({"rows": rows}))


if __name__ == "__main__":
    main()
