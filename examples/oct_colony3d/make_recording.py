"""Make a synthetic OCT volume recording of a biofilm colony in a 3D flow cell.

The colony is the 3D model's half-ellipsoid (0.6 mm along the flow, 0.4 mm high,
0.6 mm across) in the 2 x 1 x 1 mm channel. The 3D fsi model is solved on it at the
true E, nu at the inflow loadings 0, 0.5 and 1 x 100 mm^3/s by continuation, on a
finer mesh than the study uses; each deformed surface is drawn as an OCT-like volume
(B-scans of 6 um pixels every 8 um across the channel: speckle, a Gaussian
point-spread function, noise, the bright flow-cell floor below y = 0) and written as a
multi-page 16-bit TIFF (volume_0.tif without flow, volume_1..2.tif with flow), with
recording.json (voxel size and origin in um, flow rates, truth, seeds, mesh) and
truth_<k>.vtp (the noiseless model surfaces, mm). It then reads each volume the way a
study does and prints how far the segmented surface lies from the truth (mean and 99th
percentile distance, and the RKHS distance above the plane the volume's surface is cut
at, as a study compares them).

The science is in ``bayescalib.models.forward.solve_series`` (the series solve, as a
study's ground-truth solve), ``bayescalib.geometry.recording3d`` (the volumes) and
``bayescalib.io.observations.read_interface`` (reading them back).

Example (the committed files)::

    PYTHONPATH=src python examples/oct_colony3d/make_recording.py --out examples/oct_colony3d
"""

from __future__ import annotations

import argparse
import shlex
import sys
import time

import numpy as np

from bayescalib.geometry.interface import Interface
from bayescalib.geometry.projection import closest_points
from bayescalib.geometry.recording import ScanSettings
from bayescalib.geometry.surface import surface_above
from bayescalib.io.observations import cut_height, read_interface_info
from bayescalib.io.volumes import write_volume_recording
from bayescalib.measures import rkhs
from bayescalib.models.forward import FSIForward, solve_series

FACTORS = [0.0, 0.5, 1.0]


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--seed", type=int, default=1, help="seed of the speckle and noise")
    p.add_argument("--truth", type=float, nargs=2, default=[400.0, 0.3], metavar=("E", "NU"),
                   help="true Young's modulus (Pa) and Poisson ratio")
    p.add_argument("--mesh", default="coarse", help="mesh preset of the data solve")
    p.add_argument("--pixel-size", type=float, default=6.0, help="B-scan pixel size, um")
    p.add_argument("--slice-spacing", type=float, default=8.0, help="B-scan spacing, um")
    p.add_argument("--sigma-w", type=float, default=0.1, help="the study's RKHS sigma_W, mm")
    p.add_argument("--out", required=True, help="output folder")
    a = p.parse_args(argv)

    t0 = time.perf_counter()
    truth = {"material.E": float(a.truth[0]), "material.nu": float(a.truth[1])}
    model = FSIForward({"geometry": {"dim": 3}, "mesh": {"preset": a.mesh}}, time_limit_s=3600)
    res = solve_series(model, truth, {"parameter": "inflow.rate", "nominal": 100.0,
                                      "factors": FACTORS})
    if not res.ok:
        raise SystemExit(f"the data solve failed: {res.reason}")
    t_solve = time.perf_counter() - t0
    surfaces = [Interface.surface(ld.current, res.segments) for ld in res.loadings]
    um = 1000.0
    s = a.pixel_size / um
    settings = ScanSettings(pixel_size=s, margin=0.06, substrate_thickness=4 * s,
                            below_substrate=2 * s, supersample=4)
    meta = {
        "command": "python examples/oct_colony3d/make_recording.py "
                   + " ".join(shlex.quote(x) for x in (sys.argv[1:] if argv is None else argv)),
        "truth": truth,
        "colony": "half-ellipsoid, semi-axes 0.3 (x) x 0.4 (y) x 0.3 (z) mm, centre (1, 0, 0.5) mm",
        "model": {"type": "fsi", "dim": 3, "mesh": a.mesh, "ndof": int(res.stats.get("ndof", 0)),
                  "max_displacement_um": [
                      um * float(np.max(np.linalg.norm(ld.current - res.interface_reference,
                                                       axis=1))) for ld in res.loadings]},
    }
    rec = write_volume_recording(a.out, surfaces, FACTORS, nominal=100.0, settings=settings,
                                 slice_spacing=a.slice_spacing / um, seed=a.seed, metadata=meta)
    print(f"{a.out}: {len(FACTORS)} volumes of {rec['volume_shape']} voxels; solve "
          f"{t_solve:.1f} s, all {time.perf_counter() - t0:.1f} s")
    for k, surf in enumerate(surfaces):
        seen, info = read_interface_info(f"{a.out}/{rec['volumes'][k]['file']}", units="um",
                                         pixel_size=rec["voxel_size"], origin=rec["origin"],
                                         floor="auto")
        d = np.abs(closest_points(seen.points, surf)[0]) * um
        cut = cut_height(seen, info)
        D = rkhs(surf if cut is None else surface_above(surf, cut), seen, sigma_w=a.sigma_w).D
        print(f"volume_{k}: segmented surface from the truth: mean {d.mean():.2f} um, 99 % "
              f"{np.quantile(d, 0.99):.2f} um, max {d.max():.2f} um; cut at y = "
              f"{um * (cut or 0.0):.1f} um; RKHS D above the cut = {D:.3g} "
              f"(sigma_W {a.sigma_w} mm)")


if __name__ == "__main__":
    main()
