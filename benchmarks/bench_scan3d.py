"""The 3D model's scanned colony against the analytic one (one thread).

The default half-ellipsoid (width 0.6, height 0.4, depth 0.6 mm, centre (1, 0, 0.5) in
the 2 x 1 x 1 mm channel) meshed two ways: ``shape: half_ellipse`` (the exact
OpenCascade ellipsoid) and ``shape: scan``: its surface triangulated (24 rings x 96
points), written as an STL file, read back and taken as a height field
(:mod:`bayescalib.models.fsi.scan3d`, default grid of 10 um) smoothed at the default
two grid spacings (``scan``) and at one (``scan_s1``); and ``scan_voxels``, the
marching-cubes surface of a 10 um voxel mask of the colony
(:func:`bayescalib.geometry.volume.volume_surface`, as an OCT volume would give it) at
the default smoothing. Per mesh preset and case: the time to make the height field (scan only), the mesh time
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
    from bayescalib.geometry.volume import volume_surface
    from bayescalib.models.fsi.geometry3d import build_mesh_3d
    from bayescalib.models.fsi.model import MESH_PRESETS_3D, FSIModel
    from bayescalib.models.fsi.scan3d import height_field, scan_height_field, star_surface

    ap = argparse.ArgumentParser()
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--presets", default="very_coarse,coarse")
    args = ap.parse_args()
    ng.SetNumThreads(1)
    tmp = Path(tempfile.mkdtemp())
    stl = tmp / "dome.stl"
    _write_stl(stl, star_surface(_dome, (XC, ZC), n_rings=24, n_angles=96))
    params = {"material.E": 400.0, "material.nu": 0.3}
    v = 0.01  # voxel, mm
    x, y, z = (np.arange(0.6, 1.4 + 1e-9, v), np.arange(-0.05, 0.5, v),
               np.arange(0.1, 0.9 + 1e-9, v))
    Z, Y, X = np.meshgrid(z, y[::-1], x, indexing="ij")  # (nz, ny, nx), row 0 at the top
    mask = (((X - XC) / A) ** 2 + (Y / B) ** 2 + ((Z - ZC) / C) ** 2 <= 1) | (Y < 0)
    voxel_surface, _ = volume_surface(mask, voxel_size=v, units="mm",
                                      origin=(x[0], y[0], z[0]), floor=-0.5 * v)
    rows = []
    for preset in args.presets.split(","):
        mesh_cfg = {**MESH_PRESETS_3D[preset], "curve_order": 2}
        for case in ("half_ellipse", "scan", "scan_s1", "scan_voxels"):
            shape = "half_ellipse" if case == "half_ellipse" else "scan"
            geo = {"dim": 3, "shape": shape}
            field_s = []
            if case in ("scan", "scan_s1"):
                for _ in range(args.repeats):
                    g = validate({"geometry": {**geo, "scan": {
                        "path": str(stl), "smoothing": 0.01 if case == "scan_s1" else None}}},
                        "fsi")["geometry"]
                    t0 = time.perf_counter()
                    hf = scan_height_field(g, min_gap=mesh_cfg["h_interface"])
                    field_s.append(time.perf_counter() - t0)
                geo["height_field"] = hf.to_config()
            elif case == "scan_voxels":
                for _ in range(args.repeats):
                    t0 = time.perf_counter()
                    hf = height_field(voxel_surface)
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
                "preset": preset, "case": case, "status": res.status,
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
        a, *scans = [r for r in rows if r["preset"] == preset]
        for s in scans:
            print(f"{preset} {s['case']}: against the analytic colony: volume "
                  f"{s['volume_mm3'] / a['volume_mm3'] - 1:+.2%}, area "
                  f"{s['area_mm2'] / a['area_mm2'] - 1:+.2%}, max displacement "
                  f"{s['max_displacement_mm'] / a['max_displacement_mm'] - 1:+.2%}; mesh "
                  f"{s['mesh_s']:.1f} s against {a['mesh_s']:.1f} s, solve {s['solve_s']:.1f} s "
                  f"against {a['solve_s']:.1f} s")
    print(json.dumps({"rows": rows}))


if __name__ == "__main__":
    main()
