"""``bayescalib solve``: one forward FSI solve, one-line JSON summary on stdout.

Example::

    bayescalib solve --set material.E=250 --set material.nu=0.2 --out results/run1 --vtu

The config file may be an fsi section or a whole study config (its
``forward_model.fsi`` subsection is used). ``--set KEY=VALUE`` overrides use dotted keys
of the fsi section. The run record is written to ``OUT/run.h5`` (HDF5, see
:mod:`bayescalib.io.runrecord`), a converged state to ``OUT/run.state.npz`` (usable with
``--warm-start``) and, with ``--vtu``, the fields to ``OUT/run.vtu``. A failed solve is
a normal outcome (status "failed" in the record and the summary, exit code 0);
configuration errors exit with code 2.
"""

from __future__ import annotations

import argparse
import json


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


def run(args: argparse.Namespace) -> int:
    """Run one solve and print the JSON summary; returns 0 once the run record is written
    (a failed solve is recorded data, not an error of the command)."""
    from bayescalib.config import apply_overrides, load_yaml, validate
    from bayescalib.models.fsi.model import fsi_section, solve_to_file

    cfg = fsi_section(load_yaml(args.config)) if args.config else {}
    where = args.config or "config"
    cfg = validate(cfg, "fsi", where=where)
    cfg = apply_overrides(cfg, args.overrides)
    cfg = validate(cfg, "fsi", where="--set")
    res = solve_to_file(cfg, None, args.out, vtu=args.vtu, warm_start=args.warm_start, name=args.name)
    summary = {
        "status": res.status,
        "reason": res.reason,
        "newton_iterations": res.newton_iterations,
        "load_fraction": res.load_fraction,
        "max_displacement_mm": res.max_displacement,
        "wall_time_s": round(res.wall_time, 4),
        "output": res.stats.get("output"),
    }
    print(json.dumps(summary))
    return 0
