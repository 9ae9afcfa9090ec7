"""``bayescalib solve``: forward FSI solves, one-line JSON summary per point on stdout.

Example::

    bayescalib solve --set material.E=250 --set material.nu=0.2 --out results/run1 --vtu

The config file may be an fsi section or a whole study config (its ``forward_model``
section is used: the fsi subsection, ``time_limit_s`` and ``loadings``; a study whose
forward model is not ``fsi`` is refused). ``--set KEY=VALUE`` overrides use dotted keys
of the fsi section. The solve is the package's one solve path
(:func:`bayescalib.models.forward.solve_points`): in a forked, time-limited process,
every loading of ``forward_model.loadings`` solved and recorded.

The run record is written to ``OUT/run.h5`` (HDF5, see :mod:`bayescalib.io.runrecord`),
a converged state to ``OUT/run.state.npz`` (usable with ``--warm-start``; only for a
single loading: the state a series of loadings ends in is not at the nominal load) and,
with ``--vtu``, the fields to ``OUT/run.vtu`` (on success). ``--points FILE`` solves
several points, one per row of a CSV file whose header names dotted fsi keys (e.g.
``material.E,material.nu``): ``OUT/run_<row>.h5`` and so on, one summary line per point,
``--workers`` at a time; a solve process keeps its mesh from one point to the next.
A failed solve is a normal outcome (status "failed" in the record and the summary, exit
code 0); configuration errors exit with code 2.
"""

from __future__ import annotations

import argparse
import csv
import json
from pathlib import Path
from typing import Any


def add_parser(p: argparse.ArgumentParser) -> None:
    """Add the options of ``solve`` to ``p``."""
    p.add_argument("--config", metavar="FILE", help="YAML config (fsi section or whole study config)")
    p.add_argument("--set", dest="overrides", metavar="KEY=VALUE", action="append", default=[],
                   help="override a dotted fsi config key, e.g. material.E=250 (repeatable)")
    p.add_argument("--out", metavar="DIR", required=True, help="output directory")
    p.add_argument("--vtu", action="store_true", help="also write the fields as VTU")
    p.add_argument("--warm-start", metavar="FILE", default=None,
                   help="state file (.state.npz) of an earlier solve to start from")
    p.add_argument("--name", default="run", help="base name of the output files (default: run)")
    p.add_argument("--points", metavar="CSV", default=None,
                   help="solve one point per row: a CSV file with a header of dotted fsi "
                        "keys (outputs NAME_<row>.h5, ...)")
    p.add_argument("--workers", type=int, default=1,
                   help="solve processes at a time with --points (default: 1)")


def _forward_section(config: dict[str, Any], fsi: dict[str, Any]) -> dict[str, Any]:
    """The validated ``forward_model`` section to solve: the study config's (an fsi
    section alone: the schema's defaults) with ``fsi`` as its fsi section."""
    from bayescalib.config import ConfigError, validate

    fm = dict(config["forward_model"]) if "forward_model" in config else {}
    fm["fsi"] = fsi
    fm = validate({"study": "solve", "forward_model": fm}, "study",
                  where="forward_model")["forward_model"]
    if fm["type"] != "fsi":
        raise ConfigError(f"forward_model.type: bayescalib solve solves the fsi model, this "
                          f"config's forward model is {fm['type']!r}")
    return fm


def _read_points(path: str) -> list[dict[str, float]]:
    with open(path, newline="") as fh:
        rows = list(csv.reader(fh))
    rows = [r for r in rows if any(c.strip() for c in r)]
    if len(rows) < 2:
        raise ValueError(f"--points {path}: a header of dotted fsi keys and at least one row "
                         "of values are needed")
    keys = [k.strip() for k in rows[0]]
    points = []
    for n, row in enumerate(rows[1:], start=2):
        if len(row) != len(keys):
            raise ValueError(f"--points {path}, line {n}: {len(row)} values for {len(keys)} keys")
        try:
            points.append({k: float(v) for k, v in zip(keys, row, strict=True)})
        except ValueError as exc:
            raise ValueError(f"--points {path}, line {n}: {exc}") from None
    return points


def _validate_warm_start(path: str) -> None:
    import numpy as np

    p = Path(path)
    if not p.is_file():
        raise ValueError(f"--warm-start: file '{p}' does not exist")
    try:
        with np.load(p, allow_pickle=False) as data:
            data["state"], data["key"]
    except (OSError, KeyError, ValueError) as exc:
        raise ValueError(f"--warm-start: '{p}' is not a saved FSI state ({exc})") from None


def run(args: argparse.Namespace) -> int:
    """Solve and print one JSON summary line per point; returns 0 once the run records
    are written (a failed solve is recorded data, not an error of the command)."""
    from bayescalib.config import apply_overrides, load_yaml, validate
    from bayescalib.models.forward import loading_factors, solve_points
    from bayescalib.models.fsi.model import FSIModel, fsi_section

    config = load_yaml(args.config) if args.config else {}
    where = args.config or "config"
    cfg = validate(fsi_section(config), "fsi", where=where)
    cfg = apply_overrides(cfg, args.overrides)
    cfg = validate(cfg, "fsi", where="--set")
    fm = _forward_section(config, cfg)
    if args.points:
        points = _read_points(args.points)
        for p in points:  # a misspelt or out-of-range key: exit 2 before any solve
            FSIModel(cfg).resolved_config(p)
        names = [f"{args.name}_{i}" for i in range(len(points))]
    else:
        points, names = [{}], [args.name]
    if args.warm_start:
        _validate_warm_start(args.warm_start)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    series = len(loading_factors(fm)) > 1
    extras = [{**({} if series else {"state": str(out / f"{n}.state.npz")}),
               **({"vtu": str(out / f"{n}.vtu")} if args.vtu else {})} for n in names]
    paths = [out / f"{n}.h5" for n in names]
    results = solve_points(fm, points, paths, workers=args.workers,
                           warm_start=args.warm_start, extra_outputs=extras, reuse=False)
    for res, path in zip(results, paths, strict=True):
        summary = {
            "status": res.status,
            "reason": res.reason,
            "newton_iterations": res.newton_iterations,
            "load_fraction": res.load_fraction,
            "max_displacement_mm": res.max_displacement,
            "wall_time_s": round(res.wall_time, 4),
            "output": str(path),
        }
        if res.loadings:
            summary["loadings"] = [ld.label for ld in res.loadings]
        print(json.dumps(summary))
    return 0
