"""Concealed-effect benchmark of the model-form diagnosis: runs every study of
``config/concealed/`` (synthetic data with one hidden effect, a null study and an
out-of-library effect), each with several loadings (as configured) and with the
nominal loading only, and writes a table.

Columns: hidden effect, loadings, verdict, top-ranked candidate (with the identifiable
fraction of its signature: the part E and nu cannot mimic), p-value of the re-fit test,
chosen model,
localization overlap (Jaccard index, over the observed nodes, between the located
intervals and the region where the hidden effect moves the interface by more than
half its maximum), residual-to-noise ratio (RMS of the base model's residual over the
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


def _effect_region(root: Path, fm: dict, truth: dict) -> list[np.ndarray] | None:
    """Per snapshot, observed nodes where the hidden effect moves the interface by more
    than half its maximum (noise-free truth against the base model at the truth)."""
    from bayescalib.diagnosis.residuals import offsets
    from bayescalib.geometry.interface import Interface
    from bayescalib.io.runrecord import read_run
    from bayescalib.models.forward import solve_points

    gt = read_run(root / "observations" / "ground_truth_run.h5")
    if not gt.ok:
        return None
    (base,) = solve_points(fm, [truth], [root / "diagnosis" / "base_at_truth.h5"])
    if not base.ok:
        return None
    gts = [ld.current for ld in gt.loadings] or [gt.interface_current]
    bs = [ld.current for ld in base.loadings] or [base.interface_current]
    regions = []
    for g, b in zip(gts, bs, strict=True):
        y, _ = offsets(g, Interface.polyline(b, base.segments), [])
        regions.append(np.abs(y) >= 0.5 * np.max(np.abs(y)) if np.max(np.abs(y)) > 0
                       else np.zeros(len(y), dtype=bool))
    return regions


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


def _row(study_file: Path, variant: str, root: Path, regions, labels) -> dict:
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
        "overlap": _overlap(diag, regions, labels),
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
            regions = _effect_region(root, study.forward_section(), study.ground_truth()) \
                if (cfg["observations"].get("hidden") or {}) else None
            rows.append(_row(sf, variant, root, regions, obs.labels))
    head = ("| hidden effect | loadings | verdict | top-1 (identifiable) | re-fit p | chosen | "
            "overlap | resid/noise | RMS before/after [um] | ln BF (best) | base solves (converged) | "
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
            f"{_fmt(r['overlap'])} | {_fmt(r['residual_to_noise'], '{:.1f}')} | "
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
