"""Make a synthetic OCT recording of an irregular biofilm colony in a flow cell.

The colony is a lobed analytic shape (``bayescalib.geometry.shapes.lobed_colony``) in
the middle of a 3.8 mm x 1 mm channel (``--length``), 1.5 channel heights from its ends,
where the channel's truncation changes the deformation by less than 2 % (a flow cell's
channel is far longer than a colony; ``docs/channel_ends.md``). The fsi model is solved on it at the true E, nu with one
hidden effect switched on, at the inflow loadings 0, 0.5, 1, 1.5 x 100 mm^2/s, on a
finer mesh than the study uses; each deformed state is drawn as an OCT-like B-scan
(speckle, point-spread, noise, the bright flow-cell floor below y = 0) and written as a
16-bit PNG (scan_0.png without flow, scan_1..3.png with flow), with recording.json
(pixel size, origin, units, flow rates, truth, seeds, mesh) and truth_<k>.csv (the
noiseless model interfaces, um). The science is in ``bayescalib.geometry.shapes``
(the colony), ``bayescalib.models.forward.solve_series`` (the series solve, as a
study's ground-truth solve) and ``bayescalib.geometry.recording`` (the scans).

Examples
--------
The committed example (default seeds and truth)::

    PYTHONPATH=src python examples/oct_colony/make_recording.py --out examples/oct_colony

Two more colonies in the 2 mm channel of ``docs/scan_geometry.md``'s rows::

    PYTHONPATH=src python examples/oct_colony/make_recording.py --shape-seed 2 --seed 12 \
        --width 0.7 --height 0.3 --length 2 --centre 0.95 --truth 250 0.2 \
        --hidden attachment 2e-4 --out results/oct_colony_2
    PYTHONPATH=src python examples/oct_colony/make_recording.py --shape-seed 8 --seed 18 \
        --width 0.9 --height 0.44 --length 2 --truth 600 0.35 --hidden layer 1.0 \
        --out results/oct_colony_3
"""

from __future__ import annotations

import argparse
import shlex
import sys
import time
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from bayescalib.geometry.recording import ScanSettings, write_recording
from bayescalib.geometry.shapes import lobed_colony
from bayescalib.io.runrecord import SolveResult
from bayescalib.models.forward import FSIForward, solve_series

FACTORS = [0.0, 0.5, 1.0, 1.5]
#: hidden effects a scan without flow does not absorb (flow-driven)
HIDDEN = ("layer", "attachment", "stiffening", "inflow_skew", "permeability")


def solve_states(
    outline: np.ndarray,
    truth: Mapping[str, float],
    hidden: Mapping[str, Any],
    factors: Sequence[float],
    *,
    nominal: float = 100.0,
    mesh: str = "fine",
    length: float = 2.0,
    time_limit_s: float = 1800.0,
) -> SolveResult:
    """Solve the fsi model on a colony at several inflow loadings.

    Parameters
    ----------
    outline : array_like, shape (n, 2)
        Counterclockwise colony outline above the floor, mm (``geometry.shape:
        polyline``); its points become interface mesh vertices.
    truth : mapping
        Model keys and values, e.g. ``{"material.E": 400.0, "material.nu": 0.3}`` (Pa, -).
    hidden : mapping
        Hidden-effect keys, e.g. ``{"physics.layer.enabled": True, "physics.layer.phi": 1.5}``.
    factors : sequence of float
        Loading factors of the inflow rate (0 = no flow).
    nominal : float
        Nominal inflow rate, mm^2/s.
    mesh : str
        Mesh preset of the data (``fine``, ``paper``, ``coarse``).
    length : float
        Channel length, mm.
    time_limit_s : float
        Wall-clock limit of the whole series, s.

    Returns
    -------
    bayescalib.io.runrecord.SolveResult
        With one :class:`~bayescalib.io.runrecord.LoadingResult` per factor.

    Raises
    ------
    RuntimeError
        If a loading did not converge.
    """
    fsi = {"mesh": {"preset": mesh},
           "geometry": {"shape": "polyline", "length": float(length),
                        "outline": np.asarray(outline, dtype=float).tolist()}}
    model = FSIForward(fsi, time_limit_s=time_limit_s)
    res = solve_series(model, {**dict(truth), **dict(hidden)},
                       {"parameter": "inflow.rate", "nominal": float(nominal),
                        "factors": [float(f) for f in factors]})
    if not res.ok:
        raise RuntimeError(f"the data solve failed: {res.reason}")
    return res


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--shape-seed", type=int, default=0, help="seed of the colony shape")
    p.add_argument("--seed", type=int, default=1, help="seed of the speckle and noise")
    p.add_argument("--width", type=float, default=0.8, help="colony width, mm")
    p.add_argument("--height", type=float, default=0.38, help="colony height, mm")
    p.add_argument("--length", type=float, default=3.8,
                   help="channel length, mm (3.8: the colony 1.5 channel heights from both "
                        "ends, where the ends change its deformation by less than 2 %%)")
    p.add_argument("--centre", type=float, default=None,
                   help="x of the colony's centre, mm (default: the channel's middle)")
    p.add_argument("--truth", type=float, nargs=2, default=[400.0, 0.3], metavar=("E", "NU"),
                   help="true Young's modulus (Pa) and Poisson ratio")
    p.add_argument("--hidden", nargs=2, default=["layer", "1.5"], metavar=("EFFECT", "PHI"),
                   help=f"hidden effect ({', '.join(HIDDEN)}) and its phi; 'none 0' for none")
    p.add_argument("--mesh", default="fine", help="mesh preset of the data solve")
    p.add_argument("--points", type=int, default=200, help="points on the colony outline")
    p.add_argument("--pixel-size", type=float, default=4.0, help="pixel size, um")
    p.add_argument("--out", required=True, help="output folder")
    a = p.parse_args(argv)

    if a.centre is None:
        a.centre = 0.5 * a.length
    t0 = time.perf_counter()
    colony = lobed_colony(width=a.width, height=a.height, centre=a.centre, seed=a.shape_seed)
    outline = colony.outline(a.points)
    effect, phi = a.hidden[0], float(a.hidden[1])
    if effect == "none":
        hidden = {}
    elif effect in HIDDEN:
        hidden = {f"physics.{effect}.enabled": True, f"physics.{effect}.phi": phi}
    else:
        p.error(f"--hidden: unknown effect {effect!r} (one of {', '.join(HIDDEN)}, none)")
    truth = {"material.E": float(a.truth[0]), "material.nu": float(a.truth[1])}
    res = solve_states(outline, truth, hidden, FACTORS, mesh=a.mesh, length=a.length)
    t_solve = time.perf_counter() - t0
    settings = ScanSettings(pixel_size=a.pixel_size / 1000.0)
    meta = {
        "command": "python examples/oct_colony/make_recording.py "
                   + " ".join(shlex.quote(x) for x in (sys.argv[1:] if argv is None else argv)),
        "truth": truth,
        "hidden": hidden,
        "colony": {
            "shape_seed": a.shape_seed, "width_mm": colony.width, "height_mm": colony.height,
            "centre_mm": a.centre, "channel_length_mm": a.length, "area_mm2": colony.area, "interface_length_mm": colony.perimeter,
            "foot_angles_deg": list(colony.foot_angles()),
            "curve": {"x0": colony.x0, "y0": colony.y0, "ax": colony.ax, "ay": colony.ay,
                      "modes_k_eps_phase": [list(m) for m in colony.modes]},
            "outline_points": a.points,
        },
        "model": {"type": "fsi", "mesh": a.mesh, "geometry": "polyline of the colony outline",
                  "n_interface_nodes": int(res.stats.get("n_interface_nodes", 0)),
                  "ndof": int(res.stats.get("ndof", 0)),
                  "max_displacement_um": [
                      1000.0 * float(np.max(np.hypot(*(L.current - res.interface_reference).T)))
                      for L in res.loadings]},
    }
    write_recording(a.out, [L.current for L in res.loadings], FACTORS, nominal=100.0,
                    settings=settings, seed=a.seed, metadata=meta)
    print(f"{a.out}: {len(FACTORS)} scans; solve {t_solve:.1f} s, "
          f"all {time.perf_counter() - t0:.1f} s")


if __name__ == "__main__":
    main()
