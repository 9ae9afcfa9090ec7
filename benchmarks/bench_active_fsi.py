"""The active pipeline on real FSI solves, judged against a dense-grid reference.

Runs the smoke study (coarse FSI mesh, E and nu, RKHS measure; config/smoke.yaml
over config/config.yaml) through the Snakemake workflow with the active design,
in a scratch folder, and compares the surrogate posterior of every round with the
reference posterior computed from real solves on a dense grid
(``benchmarks/fsi_reference.py``, stored in ``benchmarks/data/``): Hellinger
distance on the reference grid, posterior mean and sd against the reference's.
Prints one row per round (solves used, Hellinger, the stop rule's checks) and
the number of solves after which the Hellinger distance first stays at or below
0.1.

Run (a few minutes on 2 cores)::

    python benchmarks/bench_active_fsi.py [--max-solves 96] [--out results/bench_active_fsi]

``--surrogate KEY=VALUE`` (repeatable) sets a key of the study's ``surrogate`` section
(YAML values, e.g. ``--surrogate nugget=fit --surrogate ard=true``), to compare
surrogate settings on the same study.

``--seed N`` sets ``design.seed`` (the smoke study's is 1).

``--strict`` sets the stop tolerances so tight that every round up to the
budget runs (the whole convergence curve); without it the study stops where the
pipeline's stop rule stops it.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import yaml

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "benchmarks"))


def _config(max_solves: int, strict: bool, surrogate: dict | None = None,
            seed: int | None = None) -> dict:
    from bayescalib.config import deep_merge, load_yaml

    cfg = deep_merge(load_yaml(REPO / "config" / "config.yaml"),
                     load_yaml(REPO / "config" / "smoke.yaml"))
    cfg["study"] = "bench_active_fsi"
    cfg["design"]["active"]["max_solves"] = int(max_solves)
    cfg["plots"]["n_interface_samples"] = 0
    cfg["surrogate"] = {**cfg.get("surrogate", {}), **(surrogate or {})}
    if seed is not None:
        cfg["design"]["seed"] = int(seed)
    if strict:
        cfg["design"]["active"]["stop"] = {"shift_tol": 1e-9, "sd_tol": 1e-9, "gp_tol": 1e-9}
    return cfg


def main(argv: list[str] | None = None) -> int:
    from _reference import grid_moments, grid_points, hellinger_to_reference, load_reference

    from bayescalib.inference.gp import GPSurrogate

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--ref", default=str(REPO / "benchmarks/data/fsi_reference_smoke.npz"))
    ap.add_argument("--max-solves", type=int, default=96)
    ap.add_argument("--strict", action="store_true")
    ap.add_argument("--out", default=str(REPO / "results/bench_active_fsi"))
    ap.add_argument("--seed", type=int, default=None,
                    help="design.seed (the Sobol round 0 and the acquisition; default: the "
                         "smoke study's, 1)")
    ap.add_argument("--surrogate", action="append", default=[], metavar="KEY=VALUE",
                    help="a key of the study's surrogate section (YAML value); repeatable")
    args = ap.parse_args(argv)
    surrogate = {}
    for item in args.surrogate:
        key, sep, value = item.partition("=")
        if not sep:
            ap.error(f"--surrogate takes KEY=VALUE, got {item!r}")
        value = yaml.safe_load(value)
        if isinstance(value, str):  # YAML 1.1 reads 1e-8 as a string
            try:
                value = float(value)
            except ValueError:
                pass
        surrogate[key.strip()] = value

    work = Path(args.out)
    (work / "config").mkdir(parents=True, exist_ok=True)
    (work / "config" / "config.yaml").write_text(yaml.safe_dump(_config(args.max_solves,
                                                                        args.strict, surrogate,
                                                                        args.seed)))
    t0 = time.perf_counter()
    proc = subprocess.run([sys.executable, "-m", "snakemake", "-s", str(REPO / "Snakefile"),
                           "--directory", str(work), "--cores", "2", "--quiet"],
                          check=False, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    if proc.returncode != 0:
        print(proc.stdout[-3000:], proc.stderr[-5000:])
        return 1
    root = work / "results" / "bench_active_fsi"
    summary = json.loads((root / "summary.json").read_text())
    ref = load_reference(args.ref)
    G = grid_points(ref["E"], ref["nu"])
    mom = grid_moments(ref["E"], ref["nu"], ref["loglik"])
    m_ref, sd_ref = np.array(mom["mean"]), np.array(mom["sd"])
    print(f"reference: E = {m_ref[0]:.1f} +- {sd_ref[0]:.1f} Pa, nu = {m_ref[1]:.3f} +- "
          f"{sd_ref[1]:.3f} ({ref['E'].size * ref['nu'].size} real solves on a grid)")
    rows = []
    for rec in summary["design"]["rounds"]:
        gp = GPSurrogate.load(root / "active" / str(rec["round"]) / "surrogate.h5")
        v = gp.predict(G).reshape(ref["loglik"].shape)  # uniform prior: log-posterior
        mo = grid_moments(ref["E"], ref["nu"], v)
        m, sd = np.array(mo["mean"]), np.array(mo["sd"])
        rows.append({"round": rec["round"], "n_solves": rec["n_solves"],
                     "hellinger": hellinger_to_reference(v, args.ref),
                     "mean_err_sd": (np.abs(m - m_ref) / sd_ref).tolist(),
                     "sd_ratio": (sd / sd_ref).tolist(),
                     "gp_max_error_nats": rec["gp_max_error_nats"],
                     "shift_sd": rec["shift_sd"], "settled": rec["settled"],
                     "posterior_check_confirmed": rec["posterior_check_confirmed"]})
    print("| round | solves | Hellinger | mean err E, nu [ref sd] | sd ratio E, nu | "
          "GP err [nats] | shift [sd] | settled | posterior check |")
    print("|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        ge = "-" if r["gp_max_error_nats"] is None else f"{r['gp_max_error_nats']:.3g}"
        sh = "-" if r["shift_sd"] is None else f"{r['shift_sd']:.3g}"
        print(f"| {r['round']} | {r['n_solves']} | {r['hellinger']:.3f} | "
              f"{r['mean_err_sd'][0]:.2f}, {r['mean_err_sd'][1]:.2f} | "
              f"{r['sd_ratio'][0]:.2f}, {r['sd_ratio'][1]:.2f} | {ge} | {sh} | "
              f"{'yes' if r['settled'] else '-'} | "
              f"{ {None: '-', True: 'confirmed', False: 'NOT confirmed'}[r['posterior_check_confirmed']] } |")
    reach = next((r["n_solves"] for k, r in enumerate(rows)
                  if all(x["hellinger"] <= 0.1 for x in rows[k:])), None)
    d = summary["design"]
    print(f"stopped after {d['n_solves']} solves, converged = {d['converged']}: {d['reason']}")
    print(f"Hellinger <= 0.1 from {reach} solves on" if reach else
          "Hellinger never stayed <= 0.1 within the budget")
    print(f"wall time of the whole study: {wall:.0f} s")
    (work / "bench.json").write_text(json.dumps({"rows": rows, "reach_0.1": reach,
                                                 "surrogate": surrogate,
                                                 "design": d, "wall_s": wall}, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
