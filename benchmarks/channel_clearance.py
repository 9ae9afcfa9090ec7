"""How far from the channel's inlet and outlet must the modelled colony sit?

The 2D model's channel is a truncated piece of the flow cell: a parabolic inflow is
imposed at x = 0 and the outflow is free at x = L. A colony disturbs the flow over a
few channel heights H up- and downstream; where an end of the channel lies inside that
reach, the model's flow, and so the colony's deformation, differs from the flow cell's.
A recording fixes the colony's place in the model through the scan's ``origin`` and
``geometry.length``, so a user can put it anywhere.

This script (``--dim 3``: the 3D model's default half-ellipsoid in its duct instead)
solves the colony of ``examples/oct_colony`` (its zero-flow scan,
``geometry.shape: scan``; E 400 Pa, nu 0.3, 100 mm^2/s) with its upstream foot at a
clearance c from the inlet (the downstream end ``--far`` away), then with its
downstream foot at c from the outlet, and compares the interface's displacement with
that of the same colony ``--far`` from both ends: the largest difference (um) and the
RMS difference relative to the reference's RMS displacement. It prints a Markdown
table (docs/channel_ends.md); the thresholds of
:func:`bayescalib.models.fsi.geometry.end_effect` come from it.

Usage::

    python benchmarks/channel_clearance.py [--preset coarse] [--height 1.0] [--far 2.0]
"""

from __future__ import annotations

import argparse
import copy
import tempfile
import time
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

from bayescalib.config import load_yaml, merge_layers
from bayescalib.models.forward import solve_points
from bayescalib.study import Study

ROOT = Path(__file__).resolve().parents[1]


def _example_model(args: argparse.Namespace) -> dict:
    """The example study's validated ``forward_model`` section (the colony's outline
    filled from its zero-flow scan), one loading at the nominal flow, the preset and
    channel height asked for."""
    study = load_yaml(ROOT / "examples" / "oct_colony" / "study.yaml")
    study["forward_model"]["fsi"]["mesh"]["preset"] = args.preset
    study["forward_model"]["fsi"]["geometry"]["channel_height"] = args.height
    st = Study(merge_layers([load_yaml(ROOT / "config" / "config.yaml"), study]))
    fm = copy.deepcopy(st.config["forward_model"])
    fm["loadings"] = {**fm["loadings"], "factors": [1.0]}
    return fm


def _duct_model(args: argparse.Namespace) -> dict:
    """The 3D model's validated ``forward_model`` section: its default half-ellipsoid
    (0.6 mm along the flow, 0.4 mm high, 0.6 mm across) in the 1 x 1 mm duct."""
    from bayescalib.config import validate

    fm = {"type": "fsi", "fsi": {"geometry": {"dim": 3, "channel_height": args.height},
                                 "mesh": {"preset": args.preset}}}
    fm = validate({"study": "channel_clearance", "forward_model": fm}, "study")["forward_model"]
    fm["fsi"] = validate(fm["fsi"], "fsi")  # the section's defaults in
    return fm


def solve(fm: dict, up: float, down: float) -> tuple:
    """The example's colony with its feet ``up`` mm from the inlet and ``down`` mm from
    the outlet (placed in the model directly: the study's reading refuses the nearest
    ones): (undeformed interface in the colony's frame, displacement, seconds) or (None,
    reason, seconds) for a failed solve."""
    fm = copy.deepcopy(fm)
    geo = fm["fsi"]["geometry"]
    if geo["dim"] == 3:
        half = 0.5 * float(geo["width"])
        geo["centre"], geo["length"] = up + half, up + 2.0 * half + down
    else:
        outline = np.asarray(geo["outline"], dtype=float)
        x0, x1 = outline[:, 0].min(), outline[:, 0].max()
        geo["outline"] = (outline + [up - x0, 0.0]).tolist()
        geo["length"] = up + (x1 - x0) + down
    t = time.perf_counter()
    with tempfile.TemporaryDirectory() as d:
        res = solve_points(fm, [{"material.E": 400.0, "material.nu": 0.3}], [f"{d}/r.h5"])[0]
    if res.status != "ok":
        return None, res.reason, time.perf_counter() - t
    frame = res.interface_reference.copy()
    frame[:, 0] -= up
    return frame, res.interface_current - res.interface_reference, \
        time.perf_counter() - t


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--preset", default="coarse", help="mesh preset (default coarse)")
    p.add_argument("--height", type=float, default=1.0, help="channel height H, mm")
    p.add_argument("--far", type=float, default=2.0, help="the reference's clearance, mm")
    p.add_argument("--dim", type=int, default=2, choices=(2, 3),
                   help="2: the example's scanned colony; 3: the 3D model's half-ellipsoid")
    p.add_argument("--clearances", default="0.1,0.15,0.2,0.3,0.5,0.75,1.0,1.5",
                   help="clearances c / H to solve")
    args = p.parse_args()
    h = args.height
    fm = _example_model(args) if args.dim == 2 else _duct_model(args)
    ref_p, ref_u, t = solve(fm, args.far, args.far)
    rms = float(np.sqrt((ref_u ** 2).sum(1).mean()))
    print(f"{'the 3D model, ' if args.dim == 3 else ''}channel height {h:g} mm, mesh "
          f"{args.preset}; reference: the colony {args.far:g} mm "
          f"from both ends, displacement max {np.abs(ref_u).max() * 1e3:.2f} um, RMS "
          f"{rms * 1e3:.2f} um ({t:.1f} s)\n")
    print("| end | clearance c / H | c (mm) | largest difference (um) | RMS difference / RMS "
          "displacement |")
    print("|---|---|---|---|---|")
    tree = cKDTree(ref_p)
    for end in ("inlet", "outlet"):
        for r in map(float, args.clearances.split(",")):
            c = r * h
            pts, u, t = solve(fm, c, args.far) if end == "inlet" else solve(fm, args.far, c)
            if pts is None:
                print(f"| {end} | {r:g} | {c:.3g} | solve failed: {u.split(' (step')[0]} | |",
                      flush=True)
                continue
            _, j = tree.query(pts)
            d = np.sqrt(((u - ref_u[j]) ** 2).sum(1))
            print(f"| {end} | {r:g} | {c:.3g} | {d.max() * 1e3:.2f} | "
                  f"{100 * np.sqrt((d ** 2).mean()) / rms:.1f} % |", flush=True)


if __name__ == "__main__":
    main()
