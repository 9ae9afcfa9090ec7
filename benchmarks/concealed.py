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

Usage::

    python benchmarks/concealed.py [--studies growth,null] [--variants several,one]
        [--cores 2] [--out results/concealed]

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


def _effect_region(root: Path, fm: dict, truth: dict, bounds: dict,
                   fd_step: float = 0.01) -> dict[str, list[np.ndarray]] | None:
    """Per snapshot, the observed nodes where the hidden effect shows.

    ``raw``: where the effect moves the interface by more than half its maximum on that
    snapshot (noise-free truth against the base model at the truth). ``unabsorbable``:
    the same for the effect's *unabsorbable part*, the effect with what the base
    parameters can mimic projected out (least squares on their finite-difference
    Jacobian at the truth, all snapshots together, threshold half the maximum over all
    snapshots): where a calibrated base model can still show it.
    """
    from bayescalib.diagnosis.residuals import offsets
    from bayescalib.geometry.interface import Interface
    from bayescalib.io.runrecord import read_run
    from bayescalib.models.forward import solve_points

    gt = read_run(root / "observations" / "ground_truth_run.h5")
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


def _row(study_file: Path, variant: str, root: Path, regions: dict | None, labels) -> dict:
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
    hidden = diag.get("hidden_truth") or {}
    effect = ", ".join(f"{k}={v}" for k, v in hidden.items() if not isinstance(v, bool)) or "none"
    return {
        "study": study_file.stem, "hidden": effect, "loadings": variant,
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
    ap.add_argument("--cores", type=int, default=2)
    ap.add_argument("--out", default=str(REPO / "results" / "concealed"))
    args = ap.parse_args()
    out = Path(args.out)
    rows = []
    from bayescalib.config import deep_merge
    from bayescalib.io.observation_store import read_observations
    from bayescalib.study import Study

    for sf in _study_files([s for s in args.studies.split(",") if s] or None):
        for variant in args.variants.split(","):
            files, name = _variant_config(sf, variant, out)
            cmd = [sys.executable, "-m", "snakemake", "--cores", str(args.cores), "-q",
                   "--configfile", *map(str, files)]
            print(f"== {name}: {' '.join(cmd[2:])}", flush=True)
            proc = subprocess.run(cmd, cwd=REPO, capture_output=True, text=True, check=False)
            if proc.returncode != 0:
                print(proc.stderr[-3000:])
                rows.append({"study": sf.stem, "loadings": variant, "verdict": "RUN FAILED"})
                continue
            cfg = {}
            for f in [REPO / "config" / "config.yaml", *files]:
                cfg = deep_merge(cfg, yaml.safe_load(Path(f).read_text()))
            study = Study(cfg)
            root = REPO / study.root
            obs = read_observations(root / "observations" / "observations.h5")
            bounds = dict(zip(study.targets(), map(tuple, study.space.bounds), strict=True))
            regions = _effect_region(root, study.forward_section(), study.ground_truth(),
                                     bounds) \
                if (cfg["observations"].get("hidden") or {}) else None
            rows.append(_row(sf, variant, root, regions, obs.labels))
    head = ("| hidden effect | loadings | verdict | top-1 (identifiable) | re-fit p | chosen | "
            "overlap raw/unabsorbable | resid/noise | RMS before/after [um] | ln BF (best) | base solves (converged) | "
            "E err study/chosen | nu err study/chosen |")
    lines = [head, "|" + "---|" * 13]
    for r in rows:
        if r.get("verdict") == "RUN FAILED":
            lines.append(f"| {r['study']} | {r['loadings']} | RUN FAILED |" + " |" * 10)
            continue
        eb, ea = r["err_before"], r["err_after"]
        lines.append(
            f"| {r['hidden']} | {r['loadings']} | {r['verdict']} | {r['top1']} "
            f"({_fmt(r['identifiable_top1'])}) | {_fmt(r['refit_p'], '{:.2g}')} | {r['chosen']} | "
            f"{_fmt(r['overlap'])} / {_fmt(r['overlap_unabsorbable'])} | "
            f"{_fmt(r['residual_to_noise'], '{:.1f}')} | "
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
