"""How the diagnosis's predictive check sees a colony surface segmented from an OCT
volume when the model is right: the example recording's volumes (``examples/oct_colony3d``,
made by its ``make_recording.py``) against the true surfaces they were rendered from.

Prints two tables:

1. the segmented surface's mean signed distance from the true one (+: outside, into the
   fluid) per 6 um layer above the cut, with the floor found (``floor: auto``) and given
   36 um up: where the foot next to the cut is biased;
2. the predictive check (:func:`bayescalib.diagnosis.residuals.predictive_check`) of the
   segmented surfaces' diagnosis nodes (:func:`bayescalib.diagnosis.context.diagnosis_nodes`:
   the Poisson-disk subset, the layer of voxels above the cut left out) against 12
   "posterior draws" (the true surfaces scaled in height by 0.3 % sd, sharing their
   nodes), for three noise settings: estimated from the data alone, and with the
   segmentation's positional uncertainty (``sigma_mm`` of the reading record) as a lower
   bound, each for both noise models. A right model should pass.

3. with ``--mesh-check``: the example study's model (its mesh preset, coarse) solved at
   the recording's truth, against the true surfaces (solved on the paper mesh) and the
   observed nodes: the forward model's own discretization error, which the diagnosis
   sees as a mismatch when it exceeds the noise (about 20 s a solve on one core).

Usage::

    PYTHONPATH=src python benchmarks/volume_check.py [--recording examples/oct_colony3d]
        [--mesh-check]
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]


def _read(rec: Path, k: int, floor):
    from bayescalib.geometry.volume import volume_surface
    from bayescalib.io.volumes import read_volume

    meta = json.loads((rec / "recording.json").read_text())
    vol, _ = read_volume(rec / f"volume_{k}.tif")
    return volume_surface(vol, voxel_size=meta["voxel_size"], origin=meta["origin"],
                          units=meta["units"], floor=floor)


def main() -> None:
    from bayescalib.diagnosis.context import diagnosis_nodes
    from bayescalib.diagnosis.residuals import predictive_check
    from bayescalib.geometry.interface import Interface
    from bayescalib.geometry.projection import closest_points
    from bayescalib.io.observation_store import StoredObservations
    from bayescalib.io.surfaces import read_surface

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--recording", default=str(REPO / "examples" / "oct_colony3d"))
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--mesh-check", action="store_true",
                    help="also solve the example study's model at the truth (table 3)")
    args = ap.parse_args()
    rec = Path(args.recording)
    loads = [k for k in (1, 2) if (rec / f"volume_{k}.tif").is_file()]
    if not loads:
        raise SystemExit(f"{rec}: no volume_1.tif / volume_2.tif: make the recording first "
                         "(examples/oct_colony3d/README.md)")
    truths = [read_surface(rec / f"truth_{k}.vtp", units="mm")[0] for k in loads]

    print("1. segmented minus true surface, mean signed distance per layer above the cut [um]")
    for floor in ("auto", 36.0):
        for k, truth in zip(loads, truths, strict=True):
            s, info = _read(rec, k, floor)
            d, _, cell = closest_points(s.points, truth)
            side = np.sign(np.einsum("ij,ij->i", s.points - truth.centres[cell],
                                     truth.normals[cell]))
            d = 1e3 * d * side
            y = 1e3 * s.points[:, 1]
            cut = 1e3 * info["floor"]["y_mm"]
            bands = [f"{lo:.0f}-{lo + 6:.0f}: {d[(y >= lo) & (y < lo + 6)].mean():+.2f}"
                     for lo in np.arange(cut, cut + 24, 6.0) if np.any((y >= lo) & (y < lo + 6))]
            print(f"   volume {k}, floor {floor} (cut at {cut:.0f} um): " + "; ".join(bands)
                  + f"; above {cut + 24:.0f}: {d[y >= cut + 24].mean():+.2f} "
                  f"(RMS {np.sqrt(np.mean(d[y >= cut + 24] ** 2)):.2f})")

    snaps, recs = [], []
    for k in loads:
        s, info = _read(rec, k, "auto")
        snaps.append(s)
        recs.append({**info, "kind": "volume"})
    obs = StoredObservations(snapshots=snaps, labels=[f"volume_{k}" for k in loads],
                             loads=[None] * len(loads), segmentation=recs)
    lag = 5.0 * max(recs[0]["voxel_size_mm"])  # the diagnosis's noise lag for volumes
    nodes, spacing = diagnosis_nodes(obs, lag, 0.05)
    seg = obs.segmentation_sigma()
    print(f"\n2. predictive check of the right model: {[len(n) for n in nodes]} nodes "
          f"({spacing * 1e3:.0f} um apart); segmentation sigma {1e3 * seg:.2f} um "
          f"(quantisation {1e3 * recs[0]['sigma_quantisation_mm']:.2f}, noise "
          f"{1e3 * (recs[0]['sigma_noise_mm'] or 0):.2f})")
    print("   seed | noise model | sigma floor | adequate | p (chi2, max, max smooth) | "
          "sigma [um] | regions located")
    for seed in range(args.seeds):
        rng = np.random.default_rng(seed)
        draws = [[Interface(t.points * [1.0, f, 1.0], t.cells) for t in truths]
                 for f in 1.0 + 0.003 * rng.standard_normal(12)]
        for model in ("gaussian", "bootstrap"):
            for floor in (None, seg):
                chk = predictive_check(nodes, draws, noise_model=model, noise_lag=lag,
                                       segmentation_sigma=floor,
                                       rng=np.random.default_rng(seed + 1))
                p = chk.p_values
                print(f"   {seed} | {model} | {'segmentation' if floor else 'none'} | "
                      f"{chk.adequate} | {p['chi2']:.3g}, {p['max_abs']:.3g}, "
                      f"{p['max_abs_smooth']:.3g} | {1e3 * chk.sigma:.2f} | "
                      f"{len(chk.located)}")


    if args.mesh_check:
        _mesh_check(rec, truths, nodes, loads)


def _mesh_check(rec: Path, truths, nodes, loads) -> None:
    """Table 3 of the module docstring."""
    import tempfile

    import yaml

    from bayescalib.diagnosis.residuals import offsets
    from bayescalib.models.forward import solve_points
    from bayescalib.stages.discrepancy import model_interfaces
    from bayescalib.study import Study

    meta = json.loads((rec / "recording.json").read_text())
    truth = meta.get("truth") or {"material.E": 400.0, "material.nu": 0.3}
    study = Study(yaml.safe_load((REPO / "examples" / "oct_colony3d" / "study.yaml").read_text()))
    with tempfile.TemporaryDirectory() as tmp:
        run = solve_points(study.forward_section(), [dict(truth)], [Path(tmp) / "truth.h5"])[0]
    if not run.ok:
        raise SystemExit(f"the solve at the truth failed: {run.reason}")
    preset = study.forward_section()["fsi"]["mesh"]["preset"]
    print(f"\n3. the model on the {preset} mesh at the truth {truth}: signed distance of the true "
          "(paper-mesh) surface and of the observed nodes from it [um]")
    models = model_interfaces(run, len(truths))  # the study loads 0.5 and 1 x: volumes 1, 2
    for k, t, m, nd in zip(loads, truths, models, nodes, strict=True):
        pts = t.points[t.points[:, 1] > 0.042]  # above the volumes' cut (36 um) and its layer
        y, _ = offsets(pts, m, [])
        yo, _ = offsets(nd, m, [])
        top = pts[:, 1] > 0.75 * pts[:, 1].max()
        print(f"   volume {k}: true surface RMS {1e3 * np.sqrt(np.mean(y ** 2)):.2f} (mean "
              f"{1e3 * y.mean():+.2f}, top quarter {1e3 * y[top].mean():+.2f}, largest "
              f"{1e3 * np.abs(y).max():.2f}); observed nodes RMS "
              f"{1e3 * np.sqrt(np.mean(yo ** 2)):.2f} (mean {1e3 * yo.mean():+.2f})")


if __name__ == "__main__":
    main()
