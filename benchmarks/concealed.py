"""Concealed-effect benchmark of the model-form diagnosis: runs every study of
``config/concealed/`` (synthetic data with one hidden effect, a null study and an
out-of-library effect), each with several loadings (as configured) and with the
nominal loading only, and writes a table.

Columns: hidden effect, loadings, verdict, top-ranked candidate (with the identifiable
fraction of its signature: the part E and nu cannot mimic), p-value of the re-fit test,
chosen model,
localization overlap (Jaccard index, over the observed nodes, between the located
intervals and the region where the hidden effect moves the interface by more than
half its maximum; and against the region of the effect's unabsorbable part, what is
left of it after the base parameters' Jacobian is projected out, where a calibrated
model can show it), residual-to-noise ratio (RMS of the base model's residual over the
noise sd), residual RMS before/after (the chosen model, or the best extended one),
log Bayes factor of the best extended model, the study's own calibration (solves used,
converged or not) and the relative error of E and nu: in the study's calibration (what
summary.json reports, which the diagnosis starts from) and in the chosen model.

Observation modes (``--observations``): ``synthetic`` (the studies as written: the
ground-truth interface plus 1 um Gaussian coordinate noise) and ``images`` (study name
suffix ``_images``): the noise-free ground-truth interface of every loading (the
synthetic study's ``observations/ground_truth_run.h5``) is rendered as an OCT-like scan
at 5 um pixels (Gaussian PSF of 1 pixel, 4-look speckle, additive noise) and segmented
into a mask (Gaussian pre-smoothing of 1 pixel, threshold at half the contrast, specks
and holes under 16 pixels removed), see :func:`bayescalib.geometry.imaging.render_mask`;
the study then reads one PNG per loading (``observations.source: files`` with
``pixel_size`` and ``origin``), and the diagnosis estimates the noise from the data
(``diagnose.noise_sigma: null``) and resamples it for the predictive check
(``diagnose.noise_model``: ``bootstrap``, the default for images). Masks, their sidecars and the scans are written to
``<out>/images/<study>/``. The localization overlap maps the effect region from the
ground-truth nodes to the observed (traced) nodes the diagnosis used (thinned to one per
5 pixels of arc length, the segmentation error's correlation length) by nearest node.

Usage::

    python benchmarks/concealed.py [--studies growth,null] [--variants several,one]
        [--observations synthetic,images] [--cores 2] [--out results/concealed]

Each study is a Snakemake run (``--configfile config/concealed/common.yaml
config/concealed/<name>.yaml``); finished runs are reused, so the command resumes.
Prints the table (Markdown) and writes ``<out>/table.md`` and ``<out>/table.json``.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import yaml

REPO = Path(__file__).resolve().parents[1]
CONCEALED = REPO / "config" / "concealed"


def _study_files(names: list[str] | None) -> list[Path]:
    files = sorted(p for p in CONCEALED.glob("*.yaml") if p.stem != "common")
    if names:
        files = [p for p in files if p.stem in names]
    return files


def _variant_config(study_file: Path, variant: str, out: Path) -> tuple[list[Path], str]:
    cfg = yaml.safe_load(study_file.read_text())
    name = cfg["study"]
    files = [CONCEALED / "common.yaml", study_file]
    if variant == "one":
        name = f"{name}_one_loading"
        extra = out / "configs" / f"{study_file.stem}_one.yaml"
        extra.parent.mkdir(parents=True, exist_ok=True)
        extra.write_text(yaml.safe_dump({"study": name, "forward_model": {
            "loadings": {"parameter": "inflow.rate", "factors": [1.0]}}}))
        files.append(extra)
    return files, name


#: image mode: pixel size (mm), OCT-like rendering and segmentation (see the docstring)
PIXEL_SIZE = 0.005
RENDER = {"psf_sigma": 1.0, "looks": 4.0, "noise": 0.05, "smooth": 1.0, "threshold": 0.5,
          "min_size": 16}
#: image mode: margin of the field of view around the interface, mm (none below the floor)
MARGIN = 0.05
#: image mode: likelihood noise sigma_N^2, mm^2. The segmentation error of these masks is
#: 1.5-2.2 um RMS (0.3-0.45 pixel; tests/test_imaging.py), so sigma_N = 2 um, the value
#: of the synthetic studies, still describes the data: the same likelihood in both modes
SIGMA_N2_IMAGES = 4.0e-6


def _image_config(files: list[Path], name: str, gt_path: Path, out: Path, seed: int) -> Path:
    """Render the ground truth of every loading to masks and write a study config that
    reads them (``observations.source: files``); returns the config's path."""
    from bayescalib.config import deep_merge
    from bayescalib.geometry.imaging import pixel_grid, render_scan, segment_scan
    from bayescalib.geometry.interface import Interface
    from bayescalib.io.observations import write_mask_png
    from bayescalib.io.runrecord import read_run

    cfg: dict = {}
    for f in files:
        cfg = deep_merge(cfg, yaml.safe_load(Path(f).read_text()))
    gt = read_run(gt_path)
    if not gt.ok:
        raise RuntimeError(f"{gt_path}: the ground-truth solve failed ({gt.reason})")
    lds = gt.loadings or []
    curves = [ld.current for ld in lds] or [gt.interface_current]
    labels = [ld.label for ld in lds] or ["ground_truth"]
    loads = [ld.value for ld in lds] or [gt.parameters.get("inflow.rate")]
    folder = out / "images" / f"{name}_images"
    folder.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(seed)
    entries = []
    for pts, label, load in zip(curves, labels, loads, strict=True):
        curve = Interface.polyline(pts, gt.segments)
        if not curve.is_chain():
            raise RuntimeError(f"{gt_path}: the interface of {label} is not an ordered chain")
        shape, origin = pixel_grid(curve.bounds, PIXEL_SIZE, margin=MARGIN, floor=0.0)
        scan = render_scan(curve.points, pixel_size=PIXEL_SIZE, origin=origin, shape=shape,
                           rng=rng, psf_sigma=RENDER["psf_sigma"], looks=RENDER["looks"],
                           noise=RENDER["noise"])
        mask = segment_scan(scan, smooth=RENDER["smooth"], threshold=RENDER["threshold"],
                            min_size=RENDER["min_size"])
        path = folder / f"{label}.png"
        write_mask_png(path, mask, pixel_size=PIXEL_SIZE, origin=origin, units="mm",
                       metadata={"rendered_from": str(gt_path), "loading": label, "load": load,
                                 "seed": seed, **RENDER})
        from skimage import io  # the scan itself, 8-bit, to look at

        io.imsave(folder / f"{label}_scan.png",
                  (255 * np.clip(scan / 1.5, 0, 1)).astype(np.uint8), check_contrast=False)
        entries.append({"path": str(path), "label": label, "load": load, "units": "mm",
                        "pixel_size": PIXEL_SIZE, "origin": [float(v) for v in origin]})
    obs = {"source": "files", "files": entries,
           "domain": [[0.0, float(cfg["forward_model"].get("fsi", {}).get("geometry", {})
                                  .get("length", 2.0))], [0.0, 1.0]]}
    cfg["observations"] = obs
    cfg["study"] = f"{name}_images"
    cfg["likelihood"] = {"sigma_n2": SIGMA_N2_IMAGES}
    diag = dict(cfg.get("diagnose") or {})
    diag["noise_sigma"] = None  # estimated from the residual (the data), not the generator
    cfg["diagnose"] = diag
    cfg["description"] = (f"{cfg.get('description', '')} Observed as segmented images "
                          f"({1e3 * PIXEL_SIZE:g} um pixels), benchmarks/concealed.py.").strip()
    path = out / "configs" / f"{name}_images.yaml"
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(yaml.safe_dump(cfg, sort_keys=False))
    return path


def _nearest(points: np.ndarray, nodes: np.ndarray) -> np.ndarray:
    """Index of the nearest of ``nodes`` (m, 2) for each of ``points`` (n, 2)."""
    d2 = np.sum((points[:, None, :] - nodes[None, :, :]) ** 2, axis=2)
    return np.argmin(d2, axis=1)


def _effect_region(root: Path, fm: dict, truth: dict, bounds: dict,
                   fd_step: float = 0.01, gt_path: Path | None = None,
                   observed: list | None = None) -> dict | None:
    """Per snapshot, the observed nodes where the hidden effect shows.

    ``raw``: where the effect moves the interface by more than half its maximum on that
    snapshot (noise-free truth against the base model at the truth). ``unabsorbable``:
    the same for the effect's *unabsorbable part*, the effect with what the base
    parameters can mimic projected out (least squares on their finite-difference
    Jacobian at the truth, all snapshots together, threshold half the maximum over all
    snapshots): where a calibrated base model can still show it.

    ``gt_path``: the ground-truth run (default: the study's own); ``observed``: observed
    interfaces whose nodes are not the ground truth's (images): each takes the value of
    its nearest ground-truth node.
    """
    from bayescalib.diagnosis.residuals import offsets
    from bayescalib.geometry.interface import Interface
    from bayescalib.io.runrecord import read_run
    from bayescalib.models.forward import solve_points

    gt = read_run(gt_path or root / "observations" / "ground_truth_run.h5")
    if not gt.ok:
        return None
    pts = [truth]
    steps = {}
    for t, (lo, hi) in bounds.items():
        h = fd_step * (hi - lo)
        h = -h if truth[t] + h > hi else h
        steps[t] = h
        pts.append({**truth, t: truth[t] + h})
    runs = solve_points(fm, pts, [root / "diagnosis" / "base_at_truth.h5"]
                        + [root / "diagnosis" / f"base_at_truth_fd_{t}.h5" for t in steps])
    if not runs[0].ok:
        return None

    def curves(run):
        return [ld.current for ld in run.loadings] or [run.interface_current]

    gts, bs = curves(gt), curves(runs[0])
    fd = [(k, h) for k, h in enumerate(steps.values(), start=1) if runs[k].ok]
    ys, cols = [], []
    for s, (g, b) in enumerate(zip(gts, bs, strict=True)):
        y, o = offsets(g, Interface.polyline(b, runs[0].segments),
                       [Interface.polyline(curves(runs[k])[s], runs[k].segments)
                        for k, _ in fd])
        ys.append(y)
        cols.append(o / np.array([h for _, h in fd])[:, None] if fd else o)
    raw = [np.abs(y) >= 0.5 * np.max(np.abs(y)) if np.max(np.abs(y)) > 0
           else np.zeros(len(y), dtype=bool) for y in ys]
    y_all = np.concatenate(ys)
    J = np.concatenate(cols, axis=1).T  # (n, p)
    u = y_all - J @ np.linalg.lstsq(J, y_all, rcond=None)[0] if J.size else y_all
    cut = 0.5 * np.max(np.abs(u))
    splits = np.cumsum([len(y) for y in ys])[:-1]
    unabs = [np.abs(part) >= cut if cut > 0 else np.zeros(len(part), dtype=bool)
             for part in np.split(u, splits)]
    if observed is not None:
        raw, unabs = ([r[_nearest(np.asarray(o.points), np.asarray(g))]
                       for r, o, g in zip(regions, observed, gts, strict=True)]
                      for regions in (raw, unabs))
    return {"raw": raw, "unabsorbable": unabs,
            "unabsorbable_fraction": float(np.linalg.norm(u) / np.linalg.norm(y_all))
            if np.linalg.norm(y_all) > 0 else None}


def _overlap(diag: dict, regions: list[np.ndarray] | None, labels: list[str]) -> float | None:
    if regions is None:
        return None
    located = [np.zeros(len(r), dtype=bool) for r in regions]
    for loc in diag["check"]["located"]:
        k = labels.index(loc["snapshot"])
        a, b = loc["nodes"]
        located[k][a:b + 1] = True
    loc_all, reg_all = np.concatenate(located), np.concatenate(regions)
    union = np.sum(loc_all | reg_all)
    return float(np.sum(loc_all & reg_all) / union) if union else None


def _row(study_file: Path, variant: str, root: Path, regions: dict | None, labels,
         mode: str = "synthetic", hidden: dict | None = None) -> dict:
    diag = json.loads((root / "diagnosis" / "diagnosis.json").read_text())
    chk = diag["check"]
    ext = diag["extended"]
    best = max(ext, key=lambda e: e["log_bayes_factor"]) if ext else None
    solved = [e for e in ext if e["check_after"] is not None]
    chosen = next((e for e in ext if e["candidate"] == diag["chosen_model"]),
                  max(solved, key=lambda e: e["log_bayes_factor"]) if solved else None)
    before = diag.get("bias_before") or {}
    design = diag.get("base_calibration") or {}
    after = (chosen or {}).get("bias_after") or {}
    hidden = hidden if hidden is not None else (diag.get("hidden_truth") or {})
    effect = ", ".join(f"{k}={v}" for k, v in hidden.items() if not isinstance(v, bool)) or "none"
    return {
        "study": study_file.stem, "hidden": effect, "loadings": variant, "observations": mode,
        "sigma_um": 1e3 * chk["sigma_mm"], "sigma_source": chk["sigma_source"],
        "noise_model": (chk.get("noise_model") or {}).get("name", "gaussian"),
        "verdict": diag["verdict"],
        "top1": diag["attribution"]["ranking"][0]["candidate"] if diag["attribution"]["ranking"] else None,
        "identifiable_top1": diag["attribution"]["ranking"][0]["identifiable_fraction"]
        if diag["attribution"]["ranking"] else None,
        "refit_p": (diag.get("refit") or {}).get("p_value"),
        "selected": diag["attribution"]["selected"], "chosen": diag["chosen_model"],
        "overlap": _overlap(diag, regions and regions["raw"], labels),
        "overlap_unabsorbable": _overlap(diag, regions and regions["unabsorbable"], labels),
        "unabsorbable_fraction": regions and regions["unabsorbable_fraction"],
        "residual_to_noise": chk["residual_rms_mm"] / chk["sigma_mm"],
        "rms_before_um": 1e3 * chk["residual_rms_mm"],
        "rms_after_um": 1e3 * chosen["check_after"]["residual_rms_mm"] if chosen else None,
        "log_bf": best["log_bayes_factor"] if best else None,
        "best_extended": best["candidate"] if best else None,
        "base_solves": design.get("n_solves"), "base_converged": design.get("converged"),
        "err_before": {k: v["relative_error"] for k, v in before.items()},
        "err_after": {k: v["relative_error"] for k, v in after.items()},
    }


def _fmt(v, f="{:.2f}") -> str:
    return "-" if v is None else f.format(v)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--studies", default="", help="comma-separated study names (default: all)")
    ap.add_argument("--variants", default="several,one")
    ap.add_argument("--observations", default="synthetic",
                    help="comma-separated observation modes: synthetic, images")
    ap.add_argument("--cores", type=int, default=2)
    ap.add_argument("--out", default=str(REPO / "results" / "concealed"))
    args = ap.parse_args()
    out = Path(args.out)
    rows = []
    from bayescalib.config import deep_merge
    from bayescalib.diagnosis.stage import thinned_observations
    from bayescalib.io.observation_store import read_observations
    from bayescalib.study import Study

    def snakemake(files: list[Path], *targets: str) -> subprocess.CompletedProcess:
        cmd = [sys.executable, "-m", "snakemake", "--cores", str(args.cores), "-q", "--rerun-incomplete",
               "--configfile", *map(str, files), *(["--", *targets] if targets else [])]
        print(f"== {' '.join(cmd[2:])}", flush=True)
        return subprocess.run(cmd, cwd=REPO, capture_output=True, text=True, check=False)

    def merged(files: list[Path]) -> dict:
        cfg = {}
        for f in [REPO / "config" / "config.yaml", *files]:
            cfg = deep_merge(cfg, yaml.safe_load(Path(f).read_text()))
        return cfg

    modes = [m for m in args.observations.split(",") if m]
    if set(modes) - {"synthetic", "images"}:
        ap.error(f"--observations: unknown mode(s) {sorted(set(modes) - {'synthetic', 'images'})}")
    for sf in _study_files([s for s in args.studies.split(",") if s] or None):
        for variant in args.variants.split(","):
            files, name = _variant_config(sf, variant, out)
            syn = merged(files)
            syn_root = REPO / Study(syn).root
            gt_path = syn_root / "observations" / "ground_truth_run.h5"
            hidden = dict(syn["observations"].get("hidden") or {})
            for mode in modes:
                run_files = files
                if mode == "images":
                    proc = snakemake(files, str(gt_path.relative_to(REPO)))
                    if proc.returncode == 0:
                        run_files = [_image_config(files, name, gt_path, out,
                                                   int(syn["observations"]["seed"]))]
                if mode == "synthetic" or proc.returncode == 0:
                    proc = snakemake(run_files)
                if proc.returncode != 0:
                    print(proc.stderr[-3000:])
                    rows.append({"study": sf.stem, "loadings": variant, "observations": mode,
                                 "verdict": "RUN FAILED"})
                    continue
                cfg = merged(run_files)
                study = Study(cfg)
                root = REPO / study.root
                obs = read_observations(root / "observations" / "observations.h5")
                # the nodes the diagnosis used (images: thinned to the noise's correlation length)
                diag = json.loads((root / "diagnosis" / "diagnosis.json").read_text())
                spacing = (diag.get("observed_nodes") or {}).get("spacing_mm") or 0.0
                used = thinned_observations(obs, spacing)
                bounds = dict(zip(study.targets(), map(tuple, study.space.bounds), strict=True))
                regions = _effect_region(
                    root, study.forward_section(), study.ground_truth(), bounds,
                    gt_path=gt_path,
                    observed=used.snapshots if mode == "images" else None) if hidden else None
                rows.append(_row(sf, variant, root, regions, obs.labels, mode, hidden))
    head = ("| hidden effect | loadings | observations | verdict | top-1 (identifiable) | re-fit p | "
            "chosen | overlap raw/unabsorbable | resid/noise | noise sd [um] (source, model) | RMS before/after [um] | "
            "ln BF (best) | base solves (converged) | E err study/chosen | nu err study/chosen |")
    lines = [head, "|" + "---|" * 15]
    for r in rows:
        if r.get("verdict") == "RUN FAILED":
            lines.append(f"| {r['study']} | {r['loadings']} | {r['observations']} | RUN FAILED |"
                         + " |" * 11)
            continue
        eb, ea = r["err_before"], r["err_after"]
        lines.append(
            f"| {r['hidden']} | {r['loadings']} | {r['observations']} | {r['verdict']} | {r['top1']} "
            f"({_fmt(r['identifiable_top1'])}) | {_fmt(r['refit_p'], '{:.2g}')} | {r['chosen']} | "
            f"{_fmt(r['overlap'])} / {_fmt(r['overlap_unabsorbable'])} | "
            f"{_fmt(r['residual_to_noise'], '{:.1f}')} | "
            f"{_fmt(r['sigma_um'])} ({r['sigma_source']}, {r['noise_model']}) | "
            f"{_fmt(r['rms_before_um'])} / {_fmt(r['rms_after_um'])} | "
            f"{_fmt(r['log_bf'], '{:.1f}')} ({r['best_extended'] or '-'}) | "
            f"{r['base_solves']} ({r['base_converged']}) | "
            f"{_fmt(eb.get('E'), '{:.1%}')} / {_fmt(ea.get('E'), '{:.1%}')} | "
            f"{_fmt(eb.get('nu'), '{:.1%}')} / {_fmt(ea.get('nu'), '{:.1%}')} |")
    table = "\n".join(lines)
    print(table)
    out.mkdir(parents=True, exist_ok=True)
    (out / "table.md").write_text(table + "\n")
    (out / "table.json").write_text(json.dumps(rows, indent=2))


if __name__ == "__main__":
    main()
