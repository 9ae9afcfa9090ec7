"""``bayescalib distance``: discrepancy D between a model and an observed interface.

Example::

    bayescalib distance --measure rkhs --sigma-w 0.005 model.csv observed.png \\
        --pixel-size 0.004 --origin 0 0 --json

MODEL and OBS are interface files in any format :func:`bayescalib.io.observations.read_interface`
reads (CSV, VTK, images; in 3D surfaces and OCT volumes), or run records (``.h5``, as
written by ``bayescalib solve`` and the workflow's solves: their deformed interface, in
mm). ``--units``, ``--pixel-size``, ``--origin`` and ``--floor`` apply to both files (they
only matter for the formats that use them); an OCT volume takes ``--voxel-size`` and
``--volume-origin`` instead. A 3D model is
compared above the plane its observed surface was cut at, as in a study
(:func:`bayescalib.io.observations.cut_height`). Interfaces that cannot be flow-cell interfaces in
mm after the unit conversion (larger than 100 mm, smaller than 1 um) are refused as a
unit slip, before any work. Prints D; with
``--json`` one JSON object with the measure, D, n (the number of measurements of
eq:loglik) and the distance vector. Bad input exits with status 2 and a one-line error.
"""

from __future__ import annotations

import argparse


def add_parser(p: argparse.ArgumentParser) -> None:
    """Add the options of ``distance`` to ``p``."""
    p.add_argument("model", metavar="MODEL", help="model interface file")
    p.add_argument("obs", metavar="OBS", help="observed interface file")
    p.add_argument("--measure", choices=["euclidean", "cpp", "rkhs"], default="rkhs",
                   help="discrepancy measure (default: rkhs)")
    p.add_argument("--sigma-w", type=float, default=0.005, metavar="W",
                   help="RKHS kernel width sigma_W in mm (default: 0.005)")
    p.add_argument("--spacing", type=float, default=None, metavar="H",
                   help="RKHS resampling spacing in mm (default: sigma_W / 4)")
    p.add_argument("--points", metavar="FILE", default=None,
                   help="Euclidean: CSV of measurement points x,y[,z] (optional nx,ny[,nz])")
    p.add_argument("--n-points", type=int, default=10, metavar="N",
                   help="Euclidean: number of default measurement points (default: 10)")
    p.add_argument("--reference", metavar="FILE", default=None,
                   help="Euclidean: undeformed interface; default points go where the displacement is large")
    p.add_argument("--pixel-size", type=float, default=None, metavar="S",
                   help="pixel size of mask images (in --units)")
    p.add_argument("--origin", type=float, nargs=2, default=None, metavar=("X", "Y"),
                   help="position of the centre of the bottom-left image pixel (in --units)")
    p.add_argument("--voxel-size", type=float, nargs=3, default=None,
                   metavar=("DX", "DY", "DZ"), help="OCT volumes: the voxel size (in --units)")
    p.add_argument("--volume-origin", type=float, nargs=3, default=None,
                   metavar=("X", "Y", "Z"), help="OCT volumes: the position of the centre of "
                   "the first B-scan's bottom-left pixel (in --units)")
    p.add_argument("--floor", type=float, default=None, metavar="Y",
                   help="mask images: y of a floor inside the image (in --units); the contour part on it is dropped")
    p.add_argument("--units", choices=["mm", "m", "um"], default="mm",
                   help="length unit of the files (default: mm)")
    p.add_argument("--json", action="store_true", help="print D, n and the distance vector as JSON")


#: plausible extent of a flow-cell interface in mm (a unit slip gives 1000x more or less)
MIN_EXTENT_MM, MAX_EXTENT_MM = 1.0e-3, 100.0


def _read(path: str, opts: dict):
    """An interface file and its reading record
    (:func:`bayescalib.io.observations.read_interface_info`), or the deformed interface of
    a run record (``.h5``) and None."""
    from pathlib import Path

    from bayescalib.io.observations import read_interface_info

    if Path(path).suffix.lower() in (".h5", ".hdf5"):
        from bayescalib.geometry.interface import Interface
        from bayescalib.io.runrecord import RunFileError, read_run

        try:
            run = read_run(path)
        except RunFileError as exc:
            raise ValueError(str(exc)) from None
        if not run.ok:
            raise ValueError(f"run record '{path}' is a failed solve ({run.reason}): it has no "
                             "deformed interface to compare")
        return Interface(run.interface_current, run.segments, name=Path(path).name), None
    return read_interface_info(path, **opts)


def run(args: argparse.Namespace) -> int:
    """Read both interfaces, evaluate the measure, print the result; returns 0."""
    import json

    import numpy as np

    from bayescalib.geometry.surface import surface_above
    from bayescalib.io.observations import cut_height, read_interface, read_points
    from bayescalib.measures import compute

    image = {"pixel_size": args.pixel_size, "origin": args.origin}
    volume = {"pixel_size": args.voxel_size, "origin": args.volume_origin}

    def opts(path: str) -> dict:
        from bayescalib.io.volumes import is_volume

        return {"units": args.units, "floor": args.floor,
                **(volume if is_volume(path) else image)}

    model, _ = _read(args.model, opts(args.model))
    obs, info = _read(args.obs, opts(args.obs))
    y = cut_height(obs, info)
    if y is not None and model.dim == 3:  # compared above the observation's cut, as a study
        model = surface_above(model, y)
    for role, iface, path in (("MODEL", model, args.model), ("OBS", obs, args.obs)):
        ext = float(np.max(np.ptp(np.asarray(iface.points), axis=0)))
        if not MIN_EXTENT_MM <= ext <= MAX_EXTENT_MM:
            raise ValueError(
                f"{role} '{path}' spans {ext:.4g} mm with --units {args.units}: not a flow-cell "
                f"interface ({MIN_EXTENT_MM:g} to {MAX_EXTENT_MM:g} mm); check --units (and "
                "--pixel-size for images)")
    if model.dim != obs.dim:
        raise ValueError(
            f"MODEL '{args.model}' is a {model.dim}D interface and OBS '{args.obs}' a "
            f"{obs.dim}D one: give two curves (a run record .h5 or an interface CSV, not the "
            "field file .vtu of a solve)")
    options: dict = {}
    if args.measure == "rkhs":
        options.update(sigma_w=args.sigma_w, spacing=args.spacing)
    elif args.measure == "euclidean":
        options["n_points"] = args.n_points
        if args.points:
            pts, dirs = read_points(args.points, units=args.units)
            options.update(points=pts, directions=dirs)
        if args.reference:
            options["reference"] = read_interface(args.reference, **opts(args.reference))
    res = compute(args.measure, model, obs, **options)
    if args.json:
        print(json.dumps({
            "measure": args.measure,
            "D": res.D,
            "n": res.n,
            "distances": [float(v) for v in res.distances],
        }))
    else:
        print(repr(float(res.D)))
    return 0
