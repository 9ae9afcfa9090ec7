"""``bayescalib distance``: discrepancy D between a model and an observed interface.

Example::

    bayescalib distance --measure rkhs --sigma-w 0.005 model.csv observed.png \\
        --pixel-size 0.004 --origin 0 0 --json

MODEL and OBS are interface files in any format :func:`bayescalib.observations.read_interface`
reads (CSV, VTK, mask image). ``--units``, ``--pixel-size``, ``--origin`` and ``--floor`` apply to
both files (they only matter for the formats that use them). Prints D; with
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
    p.add_argument("--floor", type=float, default=None, metavar="Y",
                   help="mask images: y of a floor inside the image (in --units); the contour part on it is dropped")
    p.add_argument("--units", choices=["mm", "m", "um"], default="mm",
                   help="length unit of the files (default: mm)")
    p.add_argument("--json", action="store_true", help="print D, n and the distance vector as JSON")


def run(args: argparse.Namespace) -> int:
    """Read both interfaces, evaluate the measure, print the result; returns 0."""
    import json

    from bayescalib.measures import compute
    from bayescalib.observations import read_interface, read_points

    opts = {"units": args.units, "pixel_size": args.pixel_size, "origin": args.origin, "floor": args.floor}
    model = read_interface(args.model, **opts)
    obs = read_interface(args.obs, **opts)
    options: dict = {}
    if args.measure == "rkhs":
        options.update(sigma_w=args.sigma_w, spacing=args.spacing)
    elif args.measure == "euclidean":
        options["n_points"] = args.n_points
        if args.points:
            pts, dirs = read_points(args.points, units=args.units)
            options.update(points=pts, directions=dirs)
        if args.reference:
            options["reference"] = read_interface(args.reference, **opts)
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
