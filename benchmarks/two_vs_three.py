"""2D against 3D: one synthetic 3D recording calibrated with the 3D model and with the
2D model on its mid-plane B-scans (issue 40, item 4).

1. The recording: the 3D model (``forward_model.fsi.geometry.dim: 3``, the half-ellipsoidal
   colony 0.6 x 0.4 x 0.6 mm on the floor of a 2 x 1 x 1 mm channel, no-slip side walls,
   the study's mesh) solved at the truth E = 400 Pa, nu = 0.3 at 50 and 100 mm^3/s,
   plus 2 um Gaussian coordinate noise: the surfaces as ``.vtp`` and their mid-plane
   sections (z = 0.5 mm) as ``.csv``, and the colony at rest
   (:func:`bayescalib.models.fsi.slice2d.write_surface_recording`).
2. The studies, each run by ``snakemake --cores N --configfile <its config>`` with
   ``observations.source: files``: the 3D model on the surfaces, and the 2D model on the
   sections (:func:`bayescalib.models.fsi.slice2d.slice_study_config`) for each inflow
   mapping (mean_velocity: q = Q / W; midplane_flux: the duct flow's flux per unit width
   through the mid-plane, q = 1.44 Q / W) and each 2D colony (half_ellipse: the section
   of the half-ellipsoid at rest, the brief's; scan: the recording's zero-flow section,
   ``geometry.shape: scan``). Same priors, measure (closest-point projection, sigma_N =
   the noise, 2 um), design, surrogate and SMC.
3. The table (truth, posterior mean +- sd, bias in posterior sd; solves, wall time) and
   the figure (marginals and joint posterior over the truth).

Usage::

    OPENBLAS_NUM_THREADS=1 PYTHONPATH=src python benchmarks/two_vs_three.py \
        [--mesh3d very_coarse] [--cores 1] [--out docs/two_vs_three.md] \
        [--figure docs/figures/two_vs_three.png]

Results under ``results/two_vs_three*/`` (recording and configs in
``results/two_vs_three_inputs_<mesh3d>/``); a rerun reuses the studies' results.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import yaml

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

ROOT = Path(__file__).resolve().parents[1]
TRUTH = {"material.E": 400.0, "material.nu": 0.3}
NOMINAL = 100.0  # mm^3/s
FACTORS = [0.5, 1.0]
NOISE = 0.002  # mm
SIGMA_W = 0.1  # mm, the RKHS kernel width (config/fsi3d_smoke.yaml's)


def study_3d(mesh: str, folder: Path, rec: dict, measure: str, sigma_n2: float) -> dict:
    """The 3D study on the recording's surfaces."""
    return {
        "study": f"two_vs_three_3d_{mesh}_{measure}",
        "description": "3D model on the surfaces of a synthetic 3D recording "
                       "(benchmarks/two_vs_three.py)",
        "forward_model": {
            "type": "fsi", "time_limit_s": 300, "warm_start": "prior_centre",
            "loadings": {"parameter": "inflow.rate", "nominal": NOMINAL, "factors": FACTORS},
            "fsi": {"geometry": {"dim": 3}, "mesh": {"preset": mesh},
                    "inflow": {"rate": NOMINAL}}},
        "parameters": [
            {"name": "E", "unit": "Pa", "target": "material.E",
             "prior": {"type": "uniform", "lo": 100.0, "hi": 800.0}, "bounds": [100.0, 800.0]},
            {"name": "nu", "unit": "-", "target": "material.nu",
             "prior": {"type": "uniform", "lo": -0.8, "hi": 0.45}, "bounds": [-0.8, 0.45]}],
        "observations": {
            "source": "files",
            "files": [{"path": str(folder / s["surface"]), "label": s["label"],
                       "load": s["inflow_rate_mm3_per_s"]} for s in rec["snapshots"]],
            "domain": [[0.0, 2.0], [0.0, 1.0], [0.0, 1.0]]},
        "measures": [measure],
        "measure": {"rkhs": {"sigma_w": SIGMA_W}},
        "likelihood": {"sigma_n2": sigma_n2},
        "design": {"strategy": "active", "seed": 1,
                   "active": {"n_initial": 8, "batch_size": 4, "max_solves": 64}},
        "surrogate": {"restarts": 2},
        "smc": {"n_particles": 1000, "n_rej": 5, "zeta": 0.95, "seed": 0},
        "posterior_check": {"draws": 8},
        "plots": {"n_interface_samples": 2, "formats": ["png"], "dpi": 80, "grid": 30},
        "diagnose": {"enabled": False},
    }


def run_study(cfg: dict, configs: Path, cores: int) -> dict:
    """Write the config, run snakemake on it, read the summary."""
    from bayescalib.inference.posterior import read_particles_h5

    path = configs / f"{cfg['study']}.yaml"
    path.write_text(yaml.safe_dump(cfg, sort_keys=False))
    t0 = time.time()
    proc = subprocess.run(["snakemake", "--cores", str(cores), "--configfile",
                           str(path.relative_to(ROOT))], cwd=ROOT, capture_output=True, text=True,
                          check=False)
    wall = time.time() - t0
    res = ROOT / "results" / cfg["study"]
    summary = res / "summary.json"
    if proc.returncode != 0 or not summary.is_file():
        (configs / f"{cfg['study']}.log").write_text(proc.stdout + proc.stderr)
        raise RuntimeError(f"{cfg['study']}: snakemake failed (log in {configs})")
    s = json.loads(summary.read_text())
    smc = read_particles_h5(res / s["measure"] / "particles.h5")
    solve_s = sum(v["total_s"] for k, v in s["timings_s"].items() if k in ("solve", "solves"))
    return {"study": cfg["study"], "config": str(path.relative_to(ROOT)),
            "mean": s["posterior_mean"], "sd": s["posterior_sd"],
            "n_solves": s["design"]["n_solves"], "n_failed": s["n_failed"],
            "converged": s["design"]["converged"], "fit": s.get("fit") or {},
            "wall_s": round(wall, 1), "solve_s": round(solve_s, 1),
            "sigma_n2": cfg["likelihood"]["sigma_n2"], "particles": smc.particles, "weights": smc.weights}


def table(rows: list[dict]) -> str:
    names = [("E", "material.E", "Pa"), ("nu", "material.nu", "-")]
    out = ["| model | inflow mapping | 2D colony | " + " | ".join(
        f"{n}: mean +- sd (truth {TRUTH[t]:g}) | {n} bias (sd)" for n, t, _ in names)
        + " | fit (best misfit / expected) | converged | solves | wall (min) |",
        "|---|---|---|" + "---|---|" * len(names) + "---|---|---|---|"]
    for r in rows:
        cells = []
        for n, t, _ in names:
            m, sd = r["mean"][n], r["sd"][n]
            cells += [f"{m:.4g} +- {sd:.2g}", f"{(m - TRUTH[t]) / sd:+.1f}"]
        fit = r["fit"]
        ratio = fit["misfit_nats"] / fit["expected_nats"] if fit else float("nan")
        words = {True: "within noise", False: "worse than noise"}.get(fit.get("consistent"), "-")
        out.append(f"| {r['model']} | {r['mapping']} | {r['colony']} | " + " | ".join(cells)
                   + f" | {words} ({ratio:.3g}) | {r['converged']} | {r['n_solves']} "
                   f"| {r['wall_s'] / 60:.1f} |")
    return "\n".join(out)


def main(argv: list[str] | None = None) -> int:
    from bayescalib.io.observations import read_interface
    from bayescalib.measures import noise_floor
    from bayescalib.models.forward import FSIForward, solve_series
    from bayescalib.models.fsi.slice2d import (
        INFLOW_MAPPINGS,
        midplane_section,
        slice_inflow_rate,
        slice_study_config,
        write_surface_recording,
    )
    from bayescalib.plotting.comparison import plot_posterior_comparison

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--mesh3d", default="very_coarse", help="3D mesh preset (data and model)")
    ap.add_argument("--mesh2d", default="coarse", help="2D mesh preset")
    ap.add_argument("--mappings", default=",".join(INFLOW_MAPPINGS))
    ap.add_argument("--colonies", default="half_ellipse,scan")
    ap.add_argument("--measure", default="rkhs", choices=["rkhs", "cpp"])
    ap.add_argument("--cores", type=int, default=1)
    ap.add_argument("--out", type=Path, help="write the table to this markdown file")
    ap.add_argument("--figure", type=Path, default=ROOT / "docs/figures/two_vs_three.png")
    ap.add_argument("--json", type=Path, help="write the rows (no particles) as JSON")
    a = ap.parse_args(argv)

    inputs = ROOT / "results" / f"two_vs_three_inputs_{a.mesh3d}"
    folder, configs = inputs / "recording", inputs / "configs"
    configs.mkdir(parents=True, exist_ok=True)
    t0 = time.time()
    probe = study_3d(a.mesh3d, folder, {"snapshots": []}, a.measure, 1.0)
    fm = probe["forward_model"]
    if not (folder / "recording.json").is_file():
        model = FSIForward(fm["fsi"], time_limit_s=1800.0)
        run = solve_series(model, TRUTH, {**fm["loadings"]})
        if not run.ok:
            raise RuntimeError(f"the recording's solve failed: {run.reason}")
        write_surface_recording(run, fm["fsi"]["geometry"], folder, noise_sigma=NOISE, seed=7,
                                truth=TRUTH)
        print(f"recording written to {folder} in {time.time() - t0:.1f} s", flush=True)
    rec = json.loads((folder / "recording.json").read_text())
    # the same noise for every study: sigma_N^2 is what the recording's noise alone gives
    # the measure, on the colony at rest (3D: its surface; 2D: the mid-plane section cut
    # from the noisy surface, as the recording's sections are)
    rest = read_interface(folder / rec["rest"]["truth"])
    opts = {"sigma_w": SIGMA_W} if a.measure == "rkhs" else {}
    geo = fm["fsi"]["geometry"]
    floor3 = noise_floor(a.measure, rest, NOISE, draws=32, seed=11, **opts)
    floor2 = noise_floor(a.measure, rest, NOISE, draws=32, seed=11,
                         transform=lambda s: midplane_section(s, geo), **opts)
    print(f"sigma_N^2 ({a.measure}, noise {NOISE * 1e3:g} um): 3D {floor3:.4g}, "
          f"2D {floor2:.4g} mm^2", flush=True)
    cfg3 = study_3d(a.mesh3d, folder, rec, a.measure, floor3)
    sections = [folder / s["section"] for s in rec["snapshots"]]

    rows = []
    r = run_study(cfg3, configs, a.cores)
    rows.append({**r, "model": f"3D ({a.mesh3d})", "mapping": "-", "colony": "-"})
    print(json.dumps({k: v for k, v in rows[-1].items() if k not in ("particles", "weights")}),
          flush=True)
    for mapping in a.mappings.split(","):
        for colony in a.colonies.split(","):
            cfg2 = slice_study_config(
                cfg3, sections, mapping, mesh=a.mesh2d,
                study=f"two_vs_three_2d_{a.mesh3d}_{a.measure}_{mapping}_{colony}",
                scan=folder / rec["rest"]["section"] if colony == "scan" else None)
            cfg2["likelihood"] = {"sigma_n2": floor2}
            r = run_study(cfg2, configs, a.cores)
            rows.append({**r, "model": f"2D ({a.mesh2d})", "mapping": mapping, "colony": colony})
            print(json.dumps({k: v for k, v in rows[-1].items()
                              if k not in ("particles", "weights")}), flush=True)

    text = table(rows)
    print(text)
    rates = {m: [slice_inflow_rate(geo, s["inflow_rate_mm3_per_s"], m) for s in rec["snapshots"]]
             for m in a.mappings.split(",")}
    print("2D inflow rates (mm^2/s) per mapping:", json.dumps(rates))
    a.figure.parent.mkdir(parents=True, exist_ok=True)
    posts = {(f"{r['model']}" if r["mapping"] == "-" else
              f"{r['model']} {r['mapping']}, {r['colony']}"): (r["particles"], r["weights"])
             for r in rows}
    plot_posterior_comparison(posts, ["E", "nu"], ["Pa", "-"],
                              [TRUTH["material.E"], TRUTH["material.nu"]], a.figure,
                              title=f"one 3D recording ({a.measure}, 3D mesh {a.mesh3d}): the 3D model "
                                    "against 2D mid-plane slices")
    print(f"figure: {a.figure}; total {time.time() - t0:.0f} s")
    if a.json:
        a.json.write_text(json.dumps(
            {"rows": [{k: v for k, v in r.items() if k not in ("particles", "weights")}
                      for r in rows], "rates_2d": rates, "recording": rec}, indent=1) + "\n")
    if a.out:
        a.out.write_text(text + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
