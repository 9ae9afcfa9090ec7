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
        [--only-finished] [--doc docs/diagnosis.md] [--set concealed3d]

``--set concealed3d`` runs the cases of ``config/concealed3d/`` instead: the 3D model
(observed surfaces; the diagnosis's nodes a Poisson-disk subset of each surface, the
localization scored on them), rows stored in ``benchmarks/data/concealed3d_rows.json``.

``--only-finished`` runs no study: it tabulates the studies (of those asked for) whose
diagnosis has finished, so the doc can be regenerated from what has been run (the
overlaps' solves of the base model at the truth, a few coarse solves per case, are made
where their records are missing).
``--doc`` writes the published page (:func:`write_doc`): the method in short, the
columns, the table, the aims of issue 15 checked row by row (:func:`aims`), the plain
words of the held-back-style cases, the residual figures of three cases (``--figures``; copied to
``docs/diagnosis/``), the commands and the wall times. Wall time: the elapsed time of
the Snakemake run that did the work (kept in ``<out>/wall/<study>.txt``; a resumed or
reused run keeps the first record) and the sum of the jobs' own times (Snakemake
``benchmarks/``; the diagnosis job is one of them).

Each study is a Snakemake run (``--configfile config/concealed/common.yaml
config/concealed/<name>.yaml``); finished runs are reused, so the command resumes.
Prints the table (Markdown) and writes ``<out>/table.md`` and ``<out>/table.json``.

Rows outlive the runs: every row tabulated is stored, with the commit and date it was
measured at and its wall time, in ``--rows`` (default ``benchmarks/data/<set>_rows.json``,
kept in git; one row per study, loadings and observation mode, a new measurement
replacing the old one). The page (``--doc``) shows the stored rows merged with those
just tabulated, so a page regenerated after some cases were rerun keeps the others'
last measured rows (with their commits, listed under the table) instead of dropping
them; a residual figure whose study is not under ``results/`` keeps its copy in
``docs/diagnosis/``.
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
CONCEALED = REPO / "config" / "concealed"


def _study_files(names: list[str] | None, folder: Path = CONCEALED) -> list[Path]:
    files = sorted(p for p in folder.glob("*.yaml") if p.stem != "common")
    if names:
        files = [p for p in files if p.stem in names]
    return files


def _variant_config(study_file: Path, variant: str, out: Path) -> tuple[list[Path], str]:
    cfg = yaml.safe_load(study_file.read_text())
    name = cfg["study"]
    files = [study_file.parent / "common.yaml", study_file]
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
    misreg = (cfg.get("observations") or {}).get("misregistration")
    if misreg:  # the images are misplaced as the synthetic observations are
        from bayescalib.geometry.registration import misplace

        centre = np.asarray(curves[0], dtype=float).mean(axis=0)
        curves = [misplace(np.asarray(c, dtype=float), misreg, centre) for c in curves]
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


def _effect_region(root: Path, fm: dict, truth: dict, bounds: dict,
                   fd_step: float = 0.01, gt_path: Path | None = None,
                   observed: list | None = None,
                   misregistration: dict | None = None):
    """Per snapshot, the observed nodes where the hidden effect shows
    (:func:`bayescalib.diagnosis.localization.effect_regions`; its run records under
    ``<root>/diagnosis/``).

    ``gt_path``: the ground-truth run (default: the study's own); ``observed``: the
    observed nodes the diagnosis used, per snapshot, where they are not the ground
    truth's (images; 3D surfaces' Poisson-disk subsets). ``misregistration``: the
    hidden rigid misplacement of the observations (``observations.misregistration``),
    applied to the ground truth as the observation stage does (about the first
    snapshot's centroid), so that the "effect" of a misregistered study is the
    misplacement itself.
    """
    from bayescalib.diagnosis.localization import effect_regions
    from bayescalib.io.runrecord import read_run

    gt = read_run(gt_path or root / "observations" / "ground_truth_run.h5")
    if not gt.ok:
        return None
    gts = [np.asarray(ld.current, dtype=float) for ld in gt.loadings] \
        or [np.asarray(gt.interface_current, dtype=float)]
    if misregistration:
        from bayescalib.geometry.registration import misplace

        centre = gts[0].mean(axis=0)
        gts = [misplace(g, misregistration, centre) for g in gts]
    return effect_regions(fm, truth, bounds, gts, root / "diagnosis", fd_step=fd_step,
                          observed=None if observed is None
                          else [np.asarray(o) for o in observed])


def _overlap(diag: dict, regions: list[np.ndarray] | None, labels: list[str],
             core: bool = False) -> float | None:
    """IoU of the located intervals (``core``: their cores) against ``regions``
    (:func:`bayescalib.diagnosis.localization.located_overlap`)."""
    from bayescalib.diagnosis.localization import located_overlap

    return located_overlap(diag["check"]["located"], regions, labels, core=core)


def _key_unit(key: str) -> str:
    """Unit of a hidden config key: a candidate's phi in its library unit (``-``:
    dimensionless, none written), geometry in mm (the config's length unit)."""
    from bayescalib.models.fsi.physics import CANDIDATES

    parts = key.split(".")
    if parts[0] == "physics" and parts[-1] == "phi" and parts[1] in CANDIDATES:
        unit = CANDIDATES[parts[1]].unit
        return "" if unit == "-" else unit
    return "mm" if parts[0] == "geometry" else ""


#: units of the misregistration's fields (observations.misregistration)
_MISREG_UNITS = {"shift_x": "mm", "shift_y": "mm", "rotation": "rad", "scale": ""}


def _hidden_words(hidden: dict, misregistration: dict | None) -> str:
    """The hidden effect(s) of a study in a few words, with units (``none``: nothing
    hidden)."""
    parts = [f"{k}={v:g} {_key_unit(k)}".strip() for k, v in hidden.items()
             if not isinstance(v, bool)]
    if misregistration:
        parts.append("misregistration(" + ", ".join(
            f"{k}={v:g} {_MISREG_UNITS.get(k, '')}".strip()
            for k, v in misregistration.items()) + ")")
    return ", ".join(parts) or "none"


def _hidden_candidates(hidden: dict) -> list[str]:
    """Names of the library candidates hidden in the data (``physics.<name>.phi`` keys)."""
    return [k.split(".")[1] for k in hidden
            if k.startswith("physics.") and k.endswith(".phi")]


def _job_seconds(root: Path) -> float:
    """Sum of the jobs' own wall times (the ``s`` column of Snakemake's benchmark files)."""
    total = 0.0
    for f in (root / "benchmarks").rglob("*.tsv"):
        lines = f.read_text().splitlines()
        total += sum(float(line.split("\t")[0]) for line in lines[1:] if line.strip())
    return total


def _wall_span(root: Path) -> float | None:
    """Seconds from the study's first output (its observations) to its diagnosis.json:
    the elapsed time of the run where no record of the run itself is kept (it includes
    the time between a run and a resumed or repeated diagnosis)."""
    first = [f.stat().st_mtime for f in (root / "observations").glob("*") if f.is_file()]
    diag = root / "diagnosis" / "diagnosis.json"
    if not first or not diag.is_file():
        return None
    # the ground-truth solve ran before its record was written
    gt = root / "benchmarks" / "ground_truth.tsv"
    lead = float(gt.read_text().splitlines()[1].split("\t")[0]) if gt.is_file() else 0.0
    return diag.stat().st_mtime - min(first) + lead


def _row(study_file: Path, variant: str, root: Path, regions, labels,
         mode: str = "synthetic", hidden: dict | None = None,
         misregistration: dict | None = None, factors: list[float] | None = None) -> dict:
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
    effect = _hidden_words(hidden, misregistration)
    reg = diag.get("registration") or {}
    return {
        "study": study_file.stem, "name": root.name, "hidden": effect,
        "hidden_candidates": _hidden_candidates(hidden),
        "hidden_misregistration": misregistration or None,
        "loadings": variant, "observations": mode,
        # the loading factors (x the nominal inflow) of the snapshots
        "factors": [float(f) for f in factors] if factors else None,
        "sigma_um": 1e3 * chk["sigma_mm"], "sigma_source": chk["sigma_source"],
        # the one noise level the re-checks are judged against (estimated noise: the
        # smallest estimate; bayescalib.diagnosis.stage.reference_noise)
        "noise_ref_um": 1e3 * diag.get("noise_reference_mm", chk["sigma_mm"]),
        "noise_model": (chk.get("noise_model") or {}).get("name", "gaussian"),
        "verdict": diag["verdict"],
        "top1": diag["attribution"]["ranking"][0]["candidate"] if diag["attribution"]["ranking"] else None,
        "identifiable_top1": diag["attribution"]["ranking"][0]["identifiable_fraction"]
        if diag["attribution"]["ranking"] else None,
        "refit_p": (diag.get("refit") or {}).get("p_value"),
        "selected": diag["attribution"]["selected"], "chosen": diag["chosen_model"],
        "overlap": _overlap(diag, regions and regions.raw, labels),
        "overlap_unabsorbable": _overlap(diag, regions and regions.unabsorbable, labels),
        "core_overlap": _overlap(diag, regions and regions.raw, labels, core=True),
        "core_overlap_unabsorbable": _overlap(diag, regions and regions.unabsorbable,
                                              labels, core=True),
        "unabsorbable_fraction": regions and regions.unabsorbable_fraction,
        # snapshots left out of the overlaps (the base model at the truth has no
        # solution there, so the effect is not defined): label -> the solver's reason
        "overlap_excluded": dict(regions.excluded) if regions else {},
        "snapshot_labels": list(labels),
        "residual_to_noise": chk["residual_rms_mm"] / chk["sigma_mm"],
        "rms_before_um": 1e3 * chk["residual_rms_mm"],
        "rms_after_um": 1e3 * chosen["check_after"]["residual_rms_mm"] if chosen else None,
        "log_bf": best["log_bayes_factor"] if best else None,
        "best_extended": best["candidate"] if best else None,
        "base_solves": design.get("n_solves"), "base_converged": design.get("converged"),
        "err_before": {k: v["relative_error"] for k, v in before.items()},
        "err_after": {k: v["relative_error"] for k, v in after.items()},
        # |posterior mean - truth| / posterior sd of the chosen model's base parameters
        "z_after": {k: abs(v["posterior_mean"] - v["truth"])
                    / chosen["posterior"]["std"][k]
                    for k, v in after.items()
                    if chosen and (chosen.get("posterior") or {}).get("std", {}).get(k)},
        # a misregistration that explains the mismatch: the base parameters re-fitted
        # jointly with it (the diagnosis's Gauss-Newton with real solves)
        "err_registered": {k: abs(reg["refit_parameters"][k] - v["truth"]) / abs(v["truth"])
                           for k, v in before.items() if k in reg["refit_parameters"]}
        if reg.get("explains") and reg.get("refit_parameters") else {},
        "chosen_explains": bool(chosen["explains"]) if chosen else None,
        "n_located": len(chk["located"]),
        "located_snapshots": sorted({loc["snapshot"] for loc in chk["located"]}),
        "zero_load_snapshot": diag.get("zero_load_snapshot"),
        "failed_signatures": diag.get("failed_signatures") or {},
        "registration": {"significant": reg.get("significant"), "explains": reg.get("explains"),
                         "estimate": reg.get("estimate"), "p_value": reg.get("p_value")}
        if reg else None,
        "extended": [{"candidate": e["candidate"], "log_bf": e["log_bayes_factor"],
                      "rms_after_um": 1e3 * e["check_after"]["residual_rms_mm"]
                      if e["check_after"] else None,
                      # the spread of that RMS over its draws, and which draws (fresh:
                      # solved for the report, not those that chose the round)
                      "rms_spread": (e["check_after"] or {}).get("residual_rms_spread"),
                      "rms_draws": (e.get("check_after_draws") or {}).get("draws"),
                      "explains": e["explains"],
                      "converged": e["converged"], "phi": {k: v["mean"] for k, v in e["phi"].items()},
                      "phi_unit": {k: v.get("unit", "-") for k, v in e["phi"].items()}}
                     for e in ext],
        # candidates the diagnosis set aside (issue 39): why, the estimate, the range
        "set_aside": [{"candidate": e["candidate"], "reason": e["reason"],
                       "estimate": e.get("estimate"), "range": e.get("range"),
                       "unit": e.get("unit", "-")} for e in diag.get("set_aside") or []],
        # the joint model of the single extensions, when one was calibrated (issue 39)
        "joint_of_singles": {k: (diag.get("joint_of_singles") or {}).get(k)
                             for k in ("candidate", "why")}
        if diag.get("joint_of_singles") else None,
        "plain_words": diag.get("plain_words") or [],
        "job_s": _job_seconds(root),
    }


def _fmt(v, f="{:.2f}") -> str:
    return "-" if v is None else f.format(v)


def _loadings_words(r: dict) -> str:
    """The loading factors of a row (x the nominal inflow), e.g. ``0, 0.5, 1 x``; the
    variant's name where they were not recorded."""
    f = r.get("factors")
    return ", ".join(f"{x:g}" for x in f) + " x" if f else r["loadings"]


#: mark of an overlap scored on part of the snapshots (listed under the table)
_PART = " (†)"


def _part_mark(r: dict) -> str:
    return _PART if r.get("overlap_excluded") else ""


def _excluded_words(r: dict) -> str:
    """Which snapshots the overlaps of a row leave out, and why (short)."""
    ex = r.get("overlap_excluded") or {}
    why = sorted({v.split(" (iteration")[0].removeprefix("loading ") for v in ex.values()})
    kept = [x for x in r.get("snapshot_labels", []) if x not in ex]
    return (f"{r['name']}: scored on {', '.join(kept) or 'no snapshot'}; "
            f"{', '.join(ex)} left out: the base model at the true parameters could not "
            f"be solved there, so the effect is not defined ({'; '.join(why)})")


def _spread_words(e: dict) -> str:
    """The RMS after's draws and spread (diagnosis.json ``residual_rms_spread``), short."""
    sp = e.get("rms_spread")
    if not sp:
        return ""
    src = "fresh draws" if e.get("rms_draws") == "fresh" else "draws"
    return (f" ({sp['n_draws']} {src}; bootstrap 16-84 % {1e3 * sp['bootstrap_q16_mm']:.2f}-"
            f"{1e3 * sp['bootstrap_q84_mm']:.2f}, per draw {1e3 * sp['per_draw_q16_mm']:.2f}-"
            f"{1e3 * sp['per_draw_q84_mm']:.2f} um)")


#: verdict of a misregistration that explains the mismatch (bayescalib.diagnosis.stage)
_MISREG_PREFIX = "mismatch explained by a misregistration"


def aims(r: dict) -> list[dict]:
    """The aims of issue 15 that apply to one row, each ``{"aim", "met", "note"}``.

    ``met`` is True, False or None (not applicable / not measurable). The kinds of
    case: nothing hidden (null), a hidden misregistration, library candidate(s) hidden
    (one or two at once) and an effect outside the library. Common to all: the verdict
    and the chosen model agree, and every candidate that could not be evaluated is named
    in the plain words. Tolerances are the issue's: RMS after within 1.5 x the noise sd,
    base-parameter error at least halved, localization IoU against the unabsorbable
    part >= 0.5. Beside the halving (an error small by chance before need not halve), a
    row says whether the truth lies within 2 posterior sd of the chosen model's base
    parameters (not an aim of the issue; counted among the aims met).
    """
    out: list[dict] = []

    def add(aim: str, met: bool | None, note: str = "") -> None:
        out.append({"aim": aim, "met": met, "note": note})

    verdict, chosen = r["verdict"], r["chosen"]
    explained_by = verdict.startswith("mismatch explained by ") and \
        not verdict.startswith(_MISREG_PREFIX)
    agree = (chosen in verdict) if chosen != "base" else not explained_by
    add("verdict and chosen model agree", agree, f"chosen: {chosen}")
    words = " ".join(r.get("plain_words") or [])
    failed = sorted(r.get("failed_signatures") or {})
    add("untestable candidates named", all(f"Not testable: {n}" in words for n in failed)
        if failed else None, ", ".join(failed) or "none untestable")
    aside = r.get("set_aside")
    if aside:  # issue 39: nothing set aside unseen (rows before it have no record)
        add("candidates set aside named", all(
            f"Set aside: {e['candidate']}" in words or f"Not calibrated: {e['candidate']}"
            in words or f"Not testable: {e['candidate']}" in words for e in aside),
            ", ".join(f"{e['candidate']} ({e['reason']})" for e in aside))
    hid = r.get("hidden_candidates") or []
    sigma = r.get("noise_ref_um", r["sigma_um"])
    if not hid and r["hidden"] == "none":
        add("nothing claimed (null)", chosen == "base" and not r["selected"]
            and not verdict.startswith("mismatch attributed"),
            f"selected {r['selected'] or 'none'}")
        return out
    if r.get("hidden_misregistration"):
        add("called registration, not physics", verdict.startswith(_MISREG_PREFIX),
            verdict)
        add("no physics candidate chosen", chosen == "base" and not r["selected"],
            f"selected {r['selected'] or 'none'}")
        zero = r.get("zero_load_snapshot")
        add("mismatch at zero load said", "present at zero load" in words
            if zero is not None else None,
            f"located on {', '.join(r['located_snapshots']) or 'no snapshot'}")
        eb, eg = r["err_before"], r.get("err_registered") or {}
        add("base-parameter error halved (re-fit with the registration)",
            all(eg[k] <= 0.5 * eb[k] for k in eb if k in eg) if eg else None,
            ", ".join(f"{k} {eb[k]:.1%} -> {eg[k]:.1%}" for k in eb if k in eg)
            or "not re-fitted")
        _add_iou(add, r)
        return out
    if not hid:  # outside the library
        add("located", r["n_located"] > 0 or not verdict.startswith("no significant"),
            f"{r['n_located']} interval(s)")
        add("not attributed", chosen == "base" and not verdict.startswith("mismatch attributed")
            and not explained_by, f"chosen {chosen}")
        return out
    if len(hid) == 1:
        add("top-1", r["top1"] == hid[0], f"top-1 {r['top1']}")
    else:
        add("all selected", set(hid) <= set(r["selected"]), f"selected {r['selected']}")
    members = set(chosen.split(" + ")) if chosen != "base" else set()
    add("modelled (chosen)", members == set(hid), f"chosen {chosen}")
    ra = r["rms_after_um"]
    add("RMS after <= 1.5 x noise", None if ra is None else ra <= 1.5 * sigma,
        f"{_fmt(ra)} um vs 1.5 x {sigma:.2f} um" + ("" if chosen != "base" or ra is None
                                                   else " (best extension, not chosen)"))
    eb, ea = r["err_before"], r["err_after"]
    if chosen != "base" and eb and ea:
        ok = all(ea[k] <= 0.5 * eb[k] for k in eb if k in ea)
        za = r.get("z_after") or {}
        add("base-parameter error halved", ok, ", ".join(
            f"{k} {eb[k]:.1%} -> {ea[k]:.1%}" + (f" ({za[k]:.1f} sd)" if k in za else "")
            for k in eb if k in ea))
        # an error that was small by chance need not halve: what a calibrated model owes
        # is the truth inside its posterior
        if za:
            add("base parameters' truth within 2 posterior sd (chosen model)",
                all(z <= 2.0 for z in za.values()),
                ", ".join(f"{k} {z:.1f} sd" for k, z in za.items()))
    else:
        add("base-parameter error halved", None, "no extension chosen")
    _add_iou(add, r)
    return out


def _add_iou(add, r: dict) -> None:
    """The localization aim: the located core's IoU against the unabsorbable region
    (the located intervals' where the diagnosis recorded no cores, said so)."""
    ov, src = r.get("core_overlap_unabsorbable"), "core"
    if ov is None:
        ov, src = r["overlap_unabsorbable"], "intervals (no core recorded)"
    ex = r.get("overlap_excluded") or {}
    if ex:
        src += "; " + ", ".join(x for x in r.get("snapshot_labels", []) if x not in ex) \
            + " only, (†)"
    add("IoU (unabsorbable) >= 0.5", None if ov is None else ov >= 0.5, f"{_fmt(ov)} ({src})")


def _mark(met: bool | None) -> str:
    return {True: "yes", False: "**no**", None: "n/a"}[met]


def table_markdown(rows: list[dict]) -> str:
    """The full table of the benchmark (every column, one row per study run)."""
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
            f"| {r['hidden']} | {_loadings_words(r)} | {r['observations']} | {r['verdict']} | {r['top1']} "
            f"({_fmt(r['identifiable_top1'])}) | {_fmt(r['refit_p'], '{:.2g}')} | {r['chosen']} | "
            f"{_fmt(r['overlap'])} / {_fmt(r['overlap_unabsorbable'])}{_part_mark(r)} | "
            f"{_fmt(r['residual_to_noise'], '{:.1f}')} | "
            f"{_fmt(r['sigma_um'])} ({r['sigma_source']}, {r['noise_model']}) | "
            f"{_fmt(r['rms_before_um'])} / {_fmt(r['rms_after_um'])} | "
            f"{_fmt(r['log_bf'], '{:.1f}')} ({r['best_extended'] or '-'}) | "
            f"{r['base_solves']} ({r['base_converged']}) | "
            f"{_fmt(eb.get('E'), '{:.1%}')} / {_fmt(ea.get('E'), '{:.1%}')} | "
            f"{_fmt(eb.get('nu'), '{:.1%}')} / {_fmt(ea.get('nu'), '{:.1%}')} |")
    lines += [f"\n†: {_excluded_words(r)}." for r in rows if r.get("overlap_excluded")]
    return "\n".join(lines)


def _err(r: dict, k: str) -> str:
    """Relative error of parameter ``k``: study -> chosen model (or -> re-fitted with an
    explaining misregistration, marked ``reg.``)."""
    eb, ea, eg = r["err_before"], r["err_after"], r.get("err_registered") or {}
    if r["chosen"] == "base" and k in eg:
        return f"{_fmt(eb.get(k), '{:.1%}')} -> {_fmt(eg[k], '{:.1%}')} (reg.)"
    return (f"{_fmt(eb.get(k), '{:.1%}')} -> "
            f"{_fmt(ea.get(k), '{:.1%}') if r['chosen'] != 'base' else '-'}")


def _copy_figure(src: Path, dst: Path, width: int = 900) -> bool:
    """Copy a PNG, scaled down to at most ``width`` pixels wide and stored with a small
    palette (a figure for the docs, kept in git); False if absent."""
    if not src.is_file():
        return False
    dst.parent.mkdir(parents=True, exist_ok=True)
    from PIL import Image

    with Image.open(src) as im:
        if im.width > width:
            im = im.resize((width, round(im.height * width / im.width)), Image.LANCZOS)
        # a 64-colour palette: line plots stay legible at a fraction of the size
        im.convert("RGB").quantize(colors=64).save(dst, optimize=True)
    return True


def _row_key(r: dict) -> tuple[str, str, str]:
    return (r["study"], r["loadings"], r["observations"])


def merge_rows(stored: list[dict], new: list[dict]) -> list[dict]:
    """The stored rows with the new ones in place of those of the same study, loadings
    and observation mode (a failed run replaces nothing), ordered as the benchmark
    tabulates them (study, then loadings, then observations)."""
    merged = {_row_key(r): r for r in stored}
    for r in new:
        if r.get("verdict") != "RUN FAILED" or _row_key(r) not in merged:
            merged[_row_key(r)] = r
    rank = {"several": 0, "one": 1, "synthetic": 0, "images": 1}
    return [merged[k] for k in sorted(merged, key=lambda k: (k[0], rank.get(k[1], 2),
                                                              rank.get(k[2], 2)))]


def _measured_at() -> dict[str, str]:
    """The commit (short hash, ``+dirty`` with uncommitted changes) and UTC date of now."""
    def git(*a: str) -> str:
        return subprocess.run(["git", "-C", str(REPO), *a], capture_output=True, text=True,
                              check=False).stdout.strip()
    commit = git("rev-parse", "--short", "HEAD") or "unknown"
    if git("status", "--porcelain", "--untracked-files=no"):
        commit += "+dirty"
    return {"commit": commit, "date": time.strftime("%Y-%m-%d", time.gmtime())}


def _record_stamp(out: Path, root: Path, started: float) -> None:
    """Keep the commit and date of a run whose diagnosis was (re)computed since
    ``started`` (epoch seconds); a reused run keeps its record."""
    diag = root / "diagnosis" / "diagnosis.json"
    if diag.is_file() and diag.stat().st_mtime >= started:
        f = out / "measured" / f"{root.name}.json"
        f.parent.mkdir(parents=True, exist_ok=True)
        f.write_text(json.dumps(_measured_at()))


def _read_stamp(out: Path, root: Path) -> dict[str, str]:
    """The run's record of :func:`_record_stamp`, else the date of its diagnosis.json
    (commit unknown)."""
    f = out / "measured" / f"{root.name}.json"
    if f.is_file():
        return json.loads(f.read_text())
    diag = root / "diagnosis" / "diagnosis.json"
    date = (time.strftime("%Y-%m-%d", time.gmtime(diag.stat().st_mtime))
            if diag.is_file() else "unknown")
    return {"commit": "unknown", "date": date}


def write_doc(rows: list[dict], path: Path, *, command: str, figures: list[str],
              notes: Path | None, wall: dict[str, float]) -> None:
    """Write the published page of the benchmark (see the module docstring)."""
    ok_rows = [r for r in rows if r.get("verdict") != "RUN FAILED"]
    figdir = path.parent / path.stem
    L = ["# Model-form diagnosis: the concealed-effect benchmark", "",
         (f"Generated by `{command}` (benchmarks/concealed.py) from the studies under "
         "`results/` and the rows stored in `benchmarks/data/concealed_rows.json` (the "
         "commit and date of each row are listed under the table); do not edit by hand "
         "(the notes come from `benchmarks/concealed_notes.md`)."), "",
         "## The method in short", "",
         ("Each case is a study of `config/concealed/` (with `common.yaml`): synthetic "
         "observations of the FSI model (coarse mesh) at the loadings of the *loadings* "
         "column, in multiples of the nominal inflow rate of 100 mm^2/s (0, 0.5 and 1 x "
         "as set in `common.yaml`; the one-loading variant: 1 x only; "
         "`stiffening_loadings.yaml`: 0, 1, 2 and 3 x) with something hidden in the "
         "data that the calibrated model (E, nu) does not have (one library effect, two "
         "at once, an effect outside the library, a misregistration of the observations, "
         "or nothing: the null case), and Gaussian coordinate noise (1 um; 1.5 um for "
         "two_effects). The study calibrates E and nu by its active design, then the diagnosis "
         "(`src/bayescalib/diagnosis/`) starts from that posterior: it solves posterior "
         "draws and checks the observed interface against the predictive bands (check), "
         "locates where the smoothed residual leaves its simultaneous band (locate), "
         "ranks the library candidates by the part of the residual each explains once E "
         "and nu have absorbed what they can (attribute; a rigid misregistration is "
         "tested as a block too), calibrates the best extended models through the same "
         "active-design chain and compares them by log Bayes factor (model), and "
         "re-checks the extended posteriors with real solves (show). An extension is "
         "chosen only when its real solves explain the mismatch (check passes or RMS "
         "within 1.5 x the noise) and ln B > ln 3. `images`: the same truth rendered as "
         "OCT-like scans (5 um pixels, blur, speckle), segmented to masks and read as "
         "files; the noise is then estimated from the data."), "",
         "## How to read the columns", "",
         ("- **hidden effect**: what the data hide: `physics.<candidate>.phi` in the "
         "candidate's unit (none written: dimensionless, e.g. the growth strain or the "
         "Fung exponent of stiffening), a geometry change outside the library (mm), or a "
         "misregistration of the observations (shifts mm, rotation rad)."),
         ("- **loadings**: the snapshots' inflow rates in multiples of the nominal "
         "100 mm^2/s."),
         ("- **verdict**: the diagnosis's verdict; **top-1**: the best-ranked candidate "
         "(identifiable fraction of its signature: the part E and nu cannot mimic); "
         "**chosen**: the model the diagnosis keeps."),
         ("- **overlap raw / unabs.**: Jaccard index (IoU), over the observed nodes, of the "
         "located intervals against the nodes where the hidden effect moves the interface "
         "by more than half its maximum (raw), and where its *unabsorbable part* (the "
         "effect with the base parameters' Jacobian projected out) does (unabs.). "
         "In brackets the same for the located *cores* (the located nodes whose smoothed "
         "residual is at least half its largest value: the half-maximum rule of the "
         "regions; the aim is judged on the core's unabs. IoU; `-`: the diagnosis was "
         "run before cores were recorded). `-` for both: nothing hidden. (†): scored "
         "only on the snapshots where the base model at the true parameters could be "
         "solved (the effect is not defined on the others); which, and why, is listed "
         "under the table. A snapshot where the effect is nil (a flow-driven effect at "
         "zero load) has no region."),
         ("- **RMS before/after**: residual RMS of the base model and of the chosen (else "
         "best-evidence solved) extension at real solves of 16 posterior draws (against "
         "their mean prediction); for an extension whose round was chosen by real solves "
         "(unconverged: the better confirmed of its last two rounds), at 16 fresh draws "
         "solved for the report only. Its spread over the draws (bootstrap and per-draw "
         "16-84 %) is listed under the table; **noise**: "
         "the noise sd the check used (given for synthetic, estimated for images). "
         "RMS after `-`: no extension calibrated (no significant mismatch, or a "
         "misregistration explains it)."),
         ("- **ln B (best)**: natural log of the Bayes factor of the best extended model "
         "(named in brackets) against the base; `-`: no extension calibrated."),
         ("- **E / nu err**: relative error of the posterior mean against the truth, in the "
         "study's calibration -> in the chosen model (`-`: no extension chosen; `reg.`: "
         "the base parameters re-fitted jointly with a misregistration that explains the "
         "mismatch)."),
         ("- **solves**: the study's calibration solves (conv.: its active design "
         "converged)."), "",
         "## The concealed table", ""]
    head = ("| case | loadings | obs. | verdict | top-1 | chosen | overlap raw / unabs. | "
            "RMS before / after [um] (noise) | ln B (best) | E err | nu err | solves |")
    L += [head, "|" + "---|" * 12]
    for r in rows:
        if r.get("verdict") == "RUN FAILED":
            L.append(f"| {r['study']} | {r['loadings']} | {r['observations']} | RUN FAILED |"
                     + " |" * 8)
            continue

        L.append(
            f"| {r['study']}: {r['hidden']} | {_loadings_words(r)} | {r['observations']} | "
            f"{r['verdict']} | {r['top1']} ({_fmt(r['identifiable_top1'])}) | {r['chosen']} | "
            f"{_fmt(r['overlap'])} / {_fmt(r['overlap_unabsorbable'])} "
            f"({_fmt(r.get('core_overlap'))} / {_fmt(r.get('core_overlap_unabsorbable'))})"
            f"{_part_mark(r)} | "
            f"{_fmt(r['rms_before_um'])} / {_fmt(r['rms_after_um'])} ({_fmt(r['sigma_um'])}) | "
            f"{_fmt(r['log_bf'], '{:.1f}')} ({r['best_extended'] or '-'}) | {_err(r, 'E')} | "
            f"{_err(r, 'nu')} | {r['base_solves']} ({'conv.' if r['base_converged'] else 'not conv.'}) |")
    part = [r for r in ok_rows if r.get("overlap_excluded")]
    if part:
        L += [""] + [f"(†) {_excluded_words(r)}." for r in part]
    stamps: dict[str, list[str]] = {}
    for r in ok_rows:
        m = r.get("measured_at") or {"commit": "unknown", "date": "unknown"}
        stamps.setdefault(f"commit {m['commit']}, {m['date']}", []).append(r["name"])
    L += ["", "Measured at (the code's commit and the date of each row's diagnosis):", ""]
    L += [f"- {k}: {', '.join(v)}" for k, v in sorted(stamps.items(), key=lambda kv: kv[0])]
    L += ["", ("Every extended model calibrated, per case (ln B, RMS after at real solves, "
          "explains the mismatch or not, posterior mean of phi):"), ""]
    for r in ok_rows:
        if r["extended"]:
            L.append(f"- {r['name']}: " + "; ".join(
                f"{e['candidate']}: ln B {e['log_bf']:.1f}, RMS {_fmt(e['rms_after_um'])} um"
                f"{_spread_words(e)}, "
                f"{'explains' if e['explains'] else 'does not explain'}"
                f"{'' if e['converged'] else ' (not converged)'}, "
                + ", ".join(f"phi_{k} = {v:.3g}"
                            + ("" if (e.get("phi_unit") or {}).get(k, "-") == "-"
                               else f" {e['phi_unit'][k]}")
                            for k, v in e["phi"].items())
                for e in r["extended"]))
        if r["failed_signatures"]:
            L.append(f"- {r['name']}: not testable: " + "; ".join(
                f"{k} ({v})" for k, v in r["failed_signatures"].items()))
    L += ["", ("The full table with every column (re-fit p, residual-to-noise ratio, noise "
          "source and model) is written by the same command to "
          "`results/concealed/table.md`."), "",
          "## The aims (issue 15), row by row", "",
          ("The aims are stated for several loadings; the one-loading and image rows are "
          "checked against the same aims for information."), "",
          "| case | loadings | obs. | aim | met | measured |", "|---|---|---|---|---|---|"]
    missed = []
    for r in ok_rows:
        for a in aims(r):
            L.append(f"| {r['study']} | {_loadings_words(r)} | {r['observations']} | {a['aim']} | "
                     f"{_mark(a['met'])} | {a['note']} |")
            if a["met"] is False:
                missed.append(f"{r['name']}: {a['aim']} ({a['note']})")
    n_aims = sum(a["met"] is not None for r in ok_rows for a in aims(r))
    L += ["", f"{n_aims - len(missed)} of {n_aims} applicable aims met; missed: "
          + ("none." if not missed else ""), ""]
    L += [f"- {m}" for m in missed]
    if notes is not None and notes.is_file():
        L += ["", notes.read_text().strip()]
    shown = [r for r in ok_rows if r["name"] in figures]
    if shown:
        L += ["", "## Residual figures", ""]
        for r in shown:
            src = REPO / "results" / r["name"] / "figures" / "diagnosis" / "residuals.png"
            dst = figdir / f"{r['name']}_residuals.png"
            if _copy_figure(src, dst) or dst.is_file():
                # the extension the figure shows (bayescalib.diagnosis.report): the
                # chosen one, else the first calibrated and re-checked (the top-ranked)
                solved = [e["candidate"] for e in r["extended"]
                          if e["rms_after_um"] is not None]
                ext = r["chosen"] if r["chosen"] != "base" else (solved[0] if solved else None)
                below = ("" if ext is None else
                         f", and below it for the model with {ext} ("
                         + ("chosen" if ext == r["chosen"] else
                            "not chosen: the first extension calibrated, the top-ranked "
                            "candidate's") + ")")
                L += [(f"**{r['name']}** ({r['hidden']}; loadings {_loadings_words(r)}): the "
                       "residual (observed minus predicted interface along the normal, um, "
                       "+ into the fluid) against the arc length (mm) in each snapshot, for "
                       f"the calibrated base model{below}. Dots: the residual at the "
                       "observed nodes; orange: its smoothed curve; blue: the pointwise "
                       "band; dashed: the band of the smoothed residual; dotted: the "
                       "simultaneous band; shaded: the located intervals (darker: their "
                       "cores, where recorded)."), "",
                      f"![{r['name']} residuals]({figdir.name}/{dst.name})", ""]
    words = [r for r in ok_rows if r["study"] in ("two_effects", "misregistration",
                                                  "permeability_layer", "growth_out_of_range")
             and r["observations"] == "synthetic" and r["loadings"] == "several"]
    if words:
        L += ["## Plain words of the held-back-style cases", ""]
        for r in words:
            L += [f"**{r['name']}** ({r['hidden']}):", ""]
            L += [f"> {w}  " for w in r["plain_words"]] + [""]
    L += ["## Commands and wall time", "",
          ("Every case of the benchmark, several loadings and one, from coordinates and from "
          "images (each study a Snakemake run on 2 cores; finished runs are reused, so the "
          "command resumes; `--studies a,b` runs a subset, as was done for this page: the "
          "table lists what has been run):"), "",
          "```bash",
          "python benchmarks/concealed.py --variants several,one --observations synthetic,images",
          "```", "",
          ("This page, from the finished studies under `results/` (runs no study; for the "
           "overlaps it solves the base model at the true parameters, a few coarse solves "
           "per case, where `results/<study>/diagnosis/base_at_truth*.h5` are not there "
           "yet):"), "",
          "```bash", command, "```", "",
          ("Wall time per study (the Snakemake run that did the work, or else the span from "
           "its observations to its diagnosis.json; on a 2-core machine shared with other "
           "jobs) and the sum of its jobs' own times (Snakemake benchmark files):"), "",
          "| study | wall [min] | jobs [min] |", "|---|---|---|"]
    wall = {**{r["name"]: r["wall_s"] for r in ok_rows if r.get("wall_s")}, **wall}
    for r in ok_rows:
        L.append(f"| {r['name']} | {_fmt(wall.get(r['name']) and wall[r['name']] / 60, '{:.1f}')}"
                 f" | {r['job_s'] / 60:.1f} |")
    total = sum(wall.get(r["name"], 0.0) for r in ok_rows)
    L += ["", f"Total wall time of the runs tabulated: {total / 3600:.2f} h.", ""]
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("\n".join(L) + "\n")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--studies", default="", help="comma-separated study names (default: all)")
    ap.add_argument("--variants", default="several,one")
    ap.add_argument("--observations", default="synthetic",
                    help="comma-separated observation modes: synthetic, images")
    ap.add_argument("--cores", type=int, default=2)
    ap.add_argument("--out", default=str(REPO / "results" / "concealed"))
    ap.add_argument("--only-finished", action="store_true",
                    help="run no study; tabulate the studies whose diagnosis has finished")
    ap.add_argument("--doc", default=None, help="write the published page here (Markdown)")
    ap.add_argument("--set", default="concealed",
                    help="the folder of config/ whose cases run: concealed (2D) or concealed3d "
                         "(the 3D model, observed surfaces)")
    ap.add_argument("--rows", default=None,
                    help="the stored rows (JSON; read, updated with the rows tabulated, written)")
    ap.add_argument("--figures", default="concealed_two_effects,concealed_misregistration,"
                    "concealed_stiffening_loadings",
                    help="studies whose residual figure the doc shows (comma-separated)")
    args = ap.parse_args()
    folder = REPO / "config" / args.set
    if not (folder / "common.yaml").is_file():
        ap.error(f"--set {args.set}: no config/{args.set}/common.yaml")
    if args.rows is None:
        args.rows = str(REPO / "benchmarks" / "data" / f"{args.set}_rows.json")
    out = Path(args.out)
    rows = []
    from bayescalib.config import deep_merge
    from bayescalib.diagnosis.context import diagnosis_nodes
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

    walldir = out / "wall"

    def record_wall(name: str, seconds: float) -> None:
        # the first run that did the work keeps its record; a reused run takes seconds
        f = walldir / f"{name}.txt"
        if seconds > 60 and not f.is_file():
            walldir.mkdir(parents=True, exist_ok=True)
            f.write_text(f"{seconds:.1f}\n")

    modes = [m for m in args.observations.split(",") if m]
    if set(modes) - {"synthetic", "images"}:
        ap.error(f"--observations: unknown mode(s) {sorted(set(modes) - {'synthetic', 'images'})}")
    for sf in _study_files([s for s in args.studies.split(",") if s] or None, folder):
        for variant in args.variants.split(","):
            files, name = _variant_config(sf, variant, out)
            syn = merged(files)
            syn_root = REPO / Study(syn).root
            gt_path = syn_root / "observations" / "ground_truth_run.h5"
            hidden = dict(syn["observations"].get("hidden") or {})
            misreg = dict(syn["observations"].get("misregistration") or {})
            for mode in modes:
                run_files = files
                if args.only_finished:
                    if mode == "images":
                        run_files = [out / "configs" / f"{name}_images.yaml"]
                        if not run_files[0].is_file():
                            continue
                    if not (REPO / Study(merged(run_files)).root / "diagnosis"
                            / "diagnosis.json").is_file():
                        continue
                else:
                    t0, t0_wall = time.monotonic(), time.time()
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
                if not args.only_finished:
                    record_wall(root.name, time.monotonic() - t0)
                    _record_stamp(out, root, t0_wall)
                obs = read_observations(root / "observations" / "observations.h5")
                # the nodes the diagnosis used (images: thinned to the noise's correlation
                # length; 3D surfaces: a Poisson-disk subset)
                diag = json.loads((root / "diagnosis" / "diagnosis.json").read_text())
                used_nodes = diag.get("observed_nodes") or {}
                lag = used_nodes.get("noise_lag_mm", used_nodes.get("spacing_mm")) or 0.0
                nodes, _ = diagnosis_nodes(obs, lag, float(study.config["diagnose"]["smoothing"]))
                bounds = dict(zip(study.targets(), map(tuple, study.space.bounds), strict=True))
                regions = _effect_region(
                    root, study.forward_section(), study.ground_truth(), bounds,
                    gt_path=gt_path,
                    observed=nodes if mode == "images" or nodes[0].shape[1] == 3 else None,
                    misregistration=misreg or None) if hidden or misreg else None
                rows.append(_row(sf, variant, root, regions, obs.labels, mode, hidden, misreg,
                                 (cfg["forward_model"].get("loadings") or {}).get("factors")))
    table = table_markdown(rows)
    print(table)
    out.mkdir(parents=True, exist_ok=True)
    (out / "table.md").write_text(table + "\n")
    (out / "table.json").write_text(json.dumps(rows, indent=2))
    wall = {f.stem: float(f.read_text()) for f in walldir.glob("*.txt")} \
        if walldir.is_dir() else {}
    for r in rows:  # no record of the run itself: from its files
        if r.get("name") and r["name"] not in wall:
            span = _wall_span(REPO / "results" / r["name"])
            if span is not None:
                wall[r["name"]] = span
    for r in rows:
        if r.get("verdict") != "RUN FAILED":
            r["measured_at"] = _read_stamp(out, REPO / "results" / r["name"])
            if r.get("name") in wall:
                r["wall_s"] = wall[r["name"]]
    store = Path(args.rows)
    stored = json.loads(store.read_text()) if store.is_file() else []
    rows = merge_rows(stored, rows)
    store.parent.mkdir(parents=True, exist_ok=True)
    store.write_text(json.dumps(rows, indent=1) + "\n")
    print(f"{len(rows)} rows stored in {store}")
    if args.doc:
        command = "python benchmarks/concealed.py " + " ".join(
            a for a in sys.argv[1:])
        write_doc(rows, Path(args.doc), command=command,
                  figures=[f for f in args.figures.split(",") if f],
                  notes=REPO / "benchmarks" / "concealed_notes.md", wall=wall)
        print(f"wrote {args.doc}")


if __name__ == "__main__":
    main()
