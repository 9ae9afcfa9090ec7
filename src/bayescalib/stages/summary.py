"""Stage ``summary`` (rule ``summary``, job function :func:`bayescalib.stages.jobs.summary`):
``summary.json``, the study's results in the user's units, and what is read back from it.

:func:`summary` writes the calibration measure's posterior (MAP, mean, covariance,
intervals, evidence), every measure's line, the failed solves and the absolute fit check;
the job adds the ``design`` block (:func:`design_summary`: how the solves were chosen and
whether the calibration converged), the timings (:func:`collect_timings`) and the
posterior check (:func:`posterior_check_summary`,
:func:`round_posterior_check_summary`); the diagnosis (``scripts/diagnose.py``) reads its
design block from :func:`design_summary` too (the terms: docs/glossary.md). Read back:
:func:`run_line`, the line that ends a run (the Snakefile's ``onsuccess``) and starts
``bayescalib summary``, and :func:`front_page`, the key numbers of the report's front
page.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from bayescalib.stages.errors import PipelineError
from bayescalib.stages.files import read_json, read_stage_file, write_json

__all__ = ["collect_timings", "design_summary", "front_page", "posterior_check_summary",
           "round_posterior_check_summary", "run_line", "summary"]

log = logging.getLogger("bayescalib")


def summary(study_name: str, parameters: Sequence[Mapping[str, Any]], measures: Sequence[str],
            posterior_paths: Sequence[str | Path], training_paths: Sequence[str | Path],
            particles_paths: Sequence[str | Path], figures: Mapping[str, Any],
            out_path: str | Path, *, extra: Mapping[str, Any] | None = None) -> dict[str, Any]:
    """Write ``summary.json``: the study's results in the user's units.

    The first measure is the calibration measure: its results are the top-level
    ``map``, ``posterior_mean``, ``posterior_cov`` and ``log_evidence``; every
    measure's results are also listed under ``measures``. ``fit`` is the absolute
    check of the calibration measure's best solve against the likelihood's noise
    model (:func:`bayescalib.inference.likelihood.fit_check`; per measure as well).
    """
    from bayescalib.inference.likelihood import fit_check

    names = [p["name"] for p in parameters]
    targets = [p["target"] for p in parameters]
    per_measure: dict[str, Any] = {}
    posts: dict[str, Any] = {}
    failed_runs: list[dict[str, Any]] = []
    for m, pp, tp, parts in zip(measures, posterior_paths, training_paths, particles_paths,
                                strict=True):
        post = posts[m] = read_stage_file(pp, "posterior summary")
        tab = read_stage_file(tp, "training table")
        res = read_stage_file(parts, "SMC particle file")
        tr = tab["is_train"].astype(bool)
        # one line per measure; the full posterior analysis is in its posterior.json
        per_measure[m] = {
            "posterior_json": str(pp),
            "posterior_mean": post["mean"], "posterior_sd": post["std"], "map": post["map"],
            "log_evidence": float(res.log_evidence),
            "n_smc_steps": int(res.n_steps),
            "n_train": int(tr.sum()),
            "n_failed": int((tab["status"][tr] == 0).sum()),
            "fit": fit_check(tab["loglik"][tr], tab["bound"][tr], tab["n_measurements"][tr]),
        }
        if m == measures[0]:
            from bayescalib.inference.feasibility import marks_infeasible

            marks = marks_infeasible(tab["status"] != 0, tab["reason"]) & tr
            failed_runs = [
                {"point": int(i), "parameters": dict(zip(names, map(float, tab["X"][i]),
                                                         strict=True)),
                 "reason": tab["reason"][i] or "no reason recorded",
                 "marks_infeasible": bool(marks[i])}
                for i in np.flatnonzero(tab["status"] == 0)]
    primary = per_measure[measures[0]]
    post = posts[measures[0]]
    truth = {p["name"]: p.get("ground_truth") for p in parameters}
    lap = post.get("laplace") or {}
    out = {
        "study": study_name,
        "measure": measures[0],
        "parameters": [
            {"name": n, "unit": p["unit"], "target": t,
             "uncertain": bool(p.get("uncertain")), "bounds": p.get("bounds")}
            for n, t, p in zip(names, targets, parameters, strict=True)
        ],
        "units": {"length": "mm", **{p["name"]: p["unit"] for p in parameters}},
        "map": post["map"],
        "map_marginal": post.get("map_marginal"),
        "posterior_mean": post["mean"],
        "posterior_sd": post["std"],
        "posterior_cov": post["cov"],
        "credible_interval_type": "equal-tailed (weighted quantiles of the SMC particles)",
        "credible_intervals": post.get("intervals"),
        "laplace": {"names": lap.get("names"), "mean": lap.get("mean"), "cov": lap.get("cov"),
                    "positive_definite": lap.get("positive_definite"),
                    "hessian_convention": lap.get("hessian_convention")} if lap else None,
        "log_evidence": primary["log_evidence"],
        "n_train": primary["n_train"],
        "n_failed": primary["n_failed"],
        "n_failed_infeasible": sum(r["marks_infeasible"] for r in failed_runs),
        "failed_runs": failed_runs,
        # only where every parameter has one (real data: no ground truth, no key)
        **({"ground_truth": truth} if all(v is not None for v in truth.values()) else {}),
        "converged": (extra or {}).get("design", {}).get("converged"),
        "fit": primary["fit"],
        # parameters whose posterior an end of its box cuts (the data favour beyond it)
        "against_bounds": post.get("against_bounds") or [],
        "measures": per_measure,
        "figures": dict(figures),
    }
    if extra:
        out.update(extra)
    write_json(out_path, out)
    log.info("summary of %s (%s) -> %s", study_name, ", ".join(names), out_path)
    return out


def posterior_check_summary(path: str | Path) -> dict[str, Any]:
    """The ``posterior_check`` block of summary.json: the check's file without its
    per-draw records (which stay in the file, named here)."""
    rec = read_stage_file(path, "posterior check")
    return {"file": str(path), **{k: v for k, v in rec.items() if k != "draws"}}


def round_posterior_check_summary(acquire_paths: Sequence[str | Path]) -> dict[str, Any] | None:
    """The ``posterior_check`` block of summary.json for an active design: the last
    check round's verdict (:func:`bayescalib.inference.active.round_posterior_check`, ``round``:
    the round whose posterior was checked), with the record it is in; None when the
    rounds ran no check."""
    for path in reversed(list(acquire_paths)):
        rec = read_stage_file(path, "active round record")
        if rec.get("posterior_check") is not None:
            return {"file": str(path), **rec["posterior_check"]}
    return None


def design_summary(strategy: str, acquire_paths: Sequence[str | Path],
                   n_solves: int, max_solves: int | None = None,
                   check_draws: int | None = None) -> dict[str, Any]:
    """The ``design`` block of summary.json: how the solves were chosen and whether
    the calibration converged (active design), with the per-round history.

    A fixed design has no convergence check: ``converged`` is None and the reason
    says so. ``max_solves`` (design.active.max_solves) and ``check_draws`` (the size of
    a check round) are the budget the verdict speaks of (active design only).
    """
    from bayescalib.inference.active import history_table

    if strategy != "active":
        return {"strategy": strategy, "n_solves": int(n_solves), "converged": None,
                "reason": "fixed design (design.strategy: fixed): the surrogate was not "
                          "checked against solves placed where the posterior lives, so "
                          "nothing says whether this posterior has converged",
                "rounds": []}
    rounds = [read_stage_file(p, "active round record") for p in acquire_paths]
    last = rounds[-1]
    return {"strategy": "active", "n_solves": int(last["n_solves"]),
            "n_failed": int(last["n_failed"]), "n_rounds": len(rounds),
            "converged": bool(last["converged"]), "reason": last["reason"],
            "max_solves": None if max_solves is None else int(max_solves),
            "check_draws": None if check_draws is None else int(check_draws),
            "surrogate_output": last.get("surrogate_output"),
            "rounds": history_table(rounds)}


def collect_timings(root: str | Path) -> dict[str, Any]:
    """Wall time per stage from Snakemake's benchmark files under ``root/benchmarks``.

    Returns the summed seconds per stage (``solve``, ``discrepancy``, ...) and,
    for solves, the median and count. Stages without benchmark files are absent.
    """
    import csv

    base = Path(root) / "benchmarks"
    out: dict[str, Any] = {}
    if not base.is_dir():
        return out
    for tsv in sorted(base.rglob("*.tsv")):
        stage = tsv.relative_to(base).parts[0]
        stage = stage.removesuffix(".tsv")
        try:
            with open(tsv) as fh:
                rows = list(csv.DictReader(fh, delimiter="\t"))
            seconds = float(rows[-1]["s"])
        except (OSError, KeyError, ValueError, IndexError):
            continue
        out.setdefault(stage, []).append(seconds)
    summary: dict[str, Any] = {}
    for stage, values in out.items():
        summary[stage] = {"total_s": float(np.sum(values)), "median_s": float(np.median(values)),
                          "count": len(values)}
    return summary


def run_line(summary_json: Mapping[str, Any]) -> str:
    """One plain line for the end of a run: posterior mean +- sd with units, solves used
    and failed. Whether it converged, and whether the best fit is within the noise, is
    the verdict that follows it (:func:`bayescalib.stages.verdict.verdict`)."""
    names = [p["name"] for p in summary_json["parameters"]]
    units = {p["name"]: p.get("unit", "-") for p in summary_json["parameters"]}
    cov = np.asarray(summary_json["posterior_cov"], float)
    sd = np.sqrt(np.maximum(np.diag(cov), 0.0))
    mean = summary_json["posterior_mean"]
    parts = []
    for k, name in enumerate(names):
        unit = "" if units[name] in ("-", "") else f" {units[name]}"
        parts.append(f"{name} = {mean[name]:.4g} +- {sd[k]:.2g}{unit}")
    design = summary_json.get("design") or {}
    n_solves = design.get("n_solves", summary_json.get("n_train"))
    n_failed = design.get("n_failed", summary_json.get("n_failed"))
    n_region = summary_json.get("n_failed_infeasible") or 0
    region = (f" ({n_region} mark where the model cannot be solved: the posterior excludes "
              f"their neighbourhood)") if n_region else ""
    return (f"bayescalib {summary_json['study']}: {', '.join(parts)}; "
            f"{n_solves} solves, {n_failed} failed{region}")


def _front_figure(s: Mapping[str, Any]) -> str | None:
    """The figure of the posterior for the report's front page: the primary measure's
    joint posterior (the marginals with one parameter), as a PNG that exists; None
    when there is none (PNG not among plots.formats, or not yet drawn)."""
    figures = s.get("figures") or {}
    for family in ("joint", "marginals"):
        for f in figures.get(f"{s.get('measure')}/{family}") or []:
            if str(f).endswith(".png") and Path(f).is_file():
                return str(f)
    return None


def front_page(summary_path: str | Path, embed_figure: bool = False) -> dict[str, Any] | None:
    """The key numbers of a finished study for the report's front page: the run line,
    the verdict (:func:`bayescalib.stages.verdict.verdict`), the figure of the posterior
    (``figure``: a PNG path, or None; with ``embed_figure``, when a report is made,
    ``figure_uri``: the PNG as a data URI, which the report's self-contained page shows,
    in lines of 76 characters: docutils refuses longer lines, and removes the breaks),
    whether it converged and why in full, and per
    parameter MAP, mean, sd, the 90 % equal-tailed
    interval and, where the study has one (``truth_known``), the ground truth (strings,
    in the user's units). None before the study has a summary.json (or when it cannot
    be read)."""
    path = Path(summary_path)
    if not path.is_file():
        return None
    try:
        s = read_json(path)
    except PipelineError:
        return None

    def fmt(v) -> str:
        return "-" if v is None else f"{float(v):.4g}"

    truth = s.get("ground_truth") or {}
    ci = s.get("credible_intervals") or {}
    rows = []
    for p in s["parameters"]:
        n = p["name"]
        lohi = (ci.get(n) or {}).get("0.9")
        rows.append([n, p.get("unit", "-"), fmt(s["map"].get(n)), fmt(s["posterior_mean"].get(n)),
                     fmt((s.get("posterior_sd") or {}).get(n)),
                     "-" if not lohi else f"[{fmt(lohi[0])}, {fmt(lohi[1])}]"]
                    + ([fmt(truth.get(n))] if truth else []))
    design = s.get("design") or {}
    fit = s.get("fit") or {}
    posterior_check = s.get("posterior_check") or {}
    from bayescalib.stages.verdict import verdict

    figure = _front_figure(s)
    uri = None
    if figure is not None and embed_figure:
        import base64

        text = "data:image/png;base64," + base64.b64encode(Path(figure).read_bytes()).decode()
        uri = [text[k:k + 76] for k in range(0, len(text), 76)]
    return {"line": run_line(s), "verdict": verdict(s), "figure": figure, "figure_uri": uri,
            "reason": design.get("reason", ""), "rows": rows,
            "truth_known": bool(truth),
            "converged": design.get("converged"), "measure": s.get("measure"),
            "fit": fit.get("words", ""), "fit_consistent": fit.get("consistent"),
            "check": posterior_check.get("words", ""),
            "check_confirmed": posterior_check.get("confirmed")}
