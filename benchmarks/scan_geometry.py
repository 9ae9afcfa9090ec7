"""The model's geometry from the zero-flow scan against the default half-ellipse.

For each synthetic OCT recording (folders written by
``examples/oct_colony/make_recording.py``) two studies calibrate E and nu from the
same scans at three flow rates: one takes the model's biofilm from the recording's
zero-flow scan (``geometry.shape: scan``), the other keeps the default half-ellipse
(0.6 mm x 0.4 mm) at the colony's centre, both in the recording's channel. Both use the example's settings
(``examples/oct_colony/study.yaml``: coarse mesh, CPP measure, sigma_N 2 um, active
design) without the diagnosis. The table gives each posterior mean +- sd against the
truth (in posterior sd), the fit check (best fit within the noise or not) and whether
the run converged.

Usage::

    python benchmarks/scan_geometry.py examples/oct_colony results/oct_colony_2 \
        results/oct_colony_3 [--out docs/scan_geometry.md]

Each study runs with ``snakemake --cores 2`` (results under
``results/scan_geometry_<name>_<geometry>/``; reruns reuse them).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

import yaml

ROOT = Path(__file__).resolve().parents[1]
EXAMPLE = ROOT / "examples" / "oct_colony" / "study.yaml"


def study_config(folder: Path, geometry: str) -> dict:
    """The example study on another recording, with the given geometry."""
    rec = json.loads((folder / "recording.json").read_text())
    cfg = yaml.safe_load(EXAMPLE.read_text())
    name = folder.name if folder.name != "oct_colony" else "example"
    cfg["study"] = f"scan_geometry_{name}_{geometry}"
    cfg.pop("description", None)
    image = {"units": rec["units"], "pixel_size": rec["pixel_size"], "origin": rec["origin"],
             "floor": "auto"}
    fsi = cfg["forward_model"]["fsi"]
    # the recording's channel (2 mm before the recordings said: make_recording.py)
    length = rec["colony"].get("channel_length_mm", 2.0)
    if geometry == "scan":
        fsi["geometry"] = {"shape": "scan", "length": length,
                           "scan": {"path": str(folder / rec["scans"][0]["file"]), **image}}
    else:  # the default half-ellipse, at the colony's centre
        fsi["geometry"] = {"length": length, "centre": rec["colony"]["centre_mm"]}
    cfg["observations"]["domain"] = [[0.0, length], [0.0, 1.0]]
    cfg["observations"]["files"] = [
        {"path": str(folder / s["file"]), "label": f"load_{s['loading_factor']:g}",
         "load": s["inflow_rate_mm2_per_s"], **image} for s in rec["scans"][1:]]
    cfg["diagnose"] = {"enabled": False}
    cfg["plots"]["fields"] = False
    return cfg


def run(folder: Path, geometry: str, work: Path) -> dict:
    cfg = study_config(folder, geometry)
    path = work / f"{cfg['study']}.yaml"
    path.write_text(yaml.safe_dump(cfg, sort_keys=False))
    t0 = time.time()
    proc = subprocess.run(["snakemake", "--cores", "2", "--configfile", str(path)], cwd=ROOT,
                          capture_output=True, text=True, check=False)
    wall = time.time() - t0
    name = str(folder.relative_to(ROOT)) if folder.is_relative_to(ROOT) else str(folder)
    row = {"recording": name, "geometry": geometry, "wall_s": round(wall, 1)}
    summary = ROOT / "results" / cfg["study"] / "summary.json"
    if proc.returncode != 0 or not summary.is_file():
        lines = (proc.stderr or proc.stdout).strip().splitlines()
        row["error"] = next((ln for ln in lines if "bayescalib" in ln or "Error" in ln),
                            lines[-1] if lines else "failed")
        return row
    s = json.loads(summary.read_text())
    truth = json.loads((folder / "recording.json").read_text())["truth"]
    names = [p["name"] for p in s["parameters"]]
    targets = [p["target"] for p in s["parameters"]]
    sd = [s["posterior_cov"][k][k] ** 0.5 for k in range(len(names))]
    row.update(
        converged=s["design"]["converged"], n_solves=s["design"]["n_solves"],
        fit_consistent=(s.get("fit") or {}).get("consistent"),
        misfit_ratio=(s["fit"]["misfit_nats"] / s["fit"]["expected_nats"]) if s.get("fit") else None,
        n_failed=s["n_failed"],
        hidden=json.loads((folder / "recording.json").read_text()).get("hidden") or {},
        params={n: {"truth": truth[t], "mean": s["posterior_mean"][n], "sd": sd[k],
                    "z": (s["posterior_mean"][n] - truth[t]) / sd[k] if sd[k] > 0 else None}
                for k, (n, t) in enumerate(zip(names, targets))})
    return row


def table(rows: list[dict]) -> str:
    out = [("| recording | hidden effect | geometry | E (Pa): mean +- sd (truth), z | "
            "nu: mean +- sd (truth), z | fit check (best misfit / expected) | "
            "converged (solves, failed) |"),
           "|---|---|---|---|---|---|---|"]
    for r in rows:
        if "error" in r:
            out.append(f"| {Path(r['recording']).name} | | {r['geometry']} | refused or failed: "
                       f"{r['error']} | | | |")
            continue
        cells = []
        for n in ("E", "nu"):
            p = r["params"][n]
            cells.append(f"{p['mean']:.4g} +- {p['sd']:.2g} ({p['truth']:g}), "
                         f"{p['z']:+.1f} sd")
        hidden = ", ".join(f"{k.split('.')[1]} {v:g}" for k, v in r["hidden"].items()
                           if k.endswith(".phi")) or "none"
        fit = {True: "within the noise", False: "WORSE THAN THE NOISE", None: "-"}[
            r["fit_consistent"]]
        out.append(f"| {Path(r['recording']).name} | {hidden} | {r['geometry']} | {cells[0]} | "
                   f"{cells[1]} | {fit} ({r['misfit_ratio']:.3g}) | {r['converged']} "
                   f"({r['n_solves']}, {r['n_failed']}) |")
    return "\n".join(out)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("recordings", nargs="+", type=Path)
    ap.add_argument("--geometries", default="scan,half_ellipse")
    ap.add_argument("--out", type=Path, help="write the table and the command to this file")
    ap.add_argument("--json", type=Path, help="write the rows as JSON")
    a = ap.parse_args(argv)
    work = ROOT / "results" / "scan_geometry_configs"
    work.mkdir(parents=True, exist_ok=True)
    rows = []
    for folder in a.recordings:
        for geometry in a.geometries.split(","):
            rows.append(run(folder.resolve(), geometry, work))
            print(json.dumps(rows[-1]), flush=True)
    text = table(rows)
    print(text)
    if a.json:
        a.json.write_text(json.dumps(rows, indent=1) + "\n")
    if a.out:
        cmd = "python benchmarks/scan_geometry.py " + " ".join(map(str, a.recordings))
        intro = __doc__.split("\n\n")[1].replace("\n", " ")
        a.out.write_text(
            f"# The model's geometry from the zero-flow scan, against the default half-ellipse\n\n"
            f"Made by `{cmd}`. {intro} z: (posterior mean - truth) / posterior sd. The fit "
            "check compares the best solve's misfit with what the likelihood's noise model "
            "expects (ratio in brackets). Wall: this run's time (a rerun reuses the "
            f"solves of an earlier one).\n\nThe recordings were made by:\n\n"
            + "".join(f"- `{json.loads((r / 'recording.json').read_text())['command']}`\n"
                      for r in a.recordings)
            + f"\n{text}\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
