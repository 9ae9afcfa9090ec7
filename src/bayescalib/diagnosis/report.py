"""Outputs of the diagnosis stage: ``diagnosis.json``, figures and an HTML section in
plain words for the Snakemake report (side effects only; the numbers come from
:func:`bayescalib.diagnosis.stage.run_diagnosis`)."""

from __future__ import annotations

import html
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from scipy.stats import chi2

from bayescalib.io._atomic_write import atomic_path

__all__ = ["write_diagnosis"]


def _panels(check, located: Sequence[Mapping[str, Any]]) -> list[dict]:
    out = []
    for sn in check.snapshots:
        if sn.s is None:  # a 3D surface's nodes (plot_surface_residuals)
            mine = [loc for loc in located if loc["snapshot"] == sn.label]
            out.append({"points": sn.xy, "z_s": sn.z_s, "c_smooth": check.c_smooth,
                        "label": sn.label,
                        "located": [i for loc in mine for i in loc["node_indices"]],
                        "cores": [i for loc in mine for i in loc["core_node_indices"]]})
            continue
        out.append({
            "s": sn.s, "r": sn.y - sn.mu, "r_smooth": sn.y_s - sn.mu_s,
            "sd": np.sqrt(sn.v), "sd_smooth": np.sqrt(sn.v_s), "c_pw": check.c_pointwise,
            "c_sim": check.c_simultaneous, "c_smooth": check.c_smooth, "label": sn.label,
            "intervals": [loc["arc_length_mm"] for loc in located
                          if loc["snapshot"] == sn.label],
            "cores": [c for loc in located if loc["snapshot"] == sn.label
                      for c in loc.get("core_arc_length_mm", [])],
        })
    return out


def write_diagnosis(diagnosis: Mapping[str, Any], checks: Mapping[str, Any], *,
                    json_path: str | Path, html_path: str | Path, figdir: str | Path,
                    formats: Sequence[str], dpi: float) -> list[str]:
    """Write the JSON, the figures (one per family and format) and the HTML section.

    Returns
    -------
    list of str
        The written figure paths.
    """
    from bayescalib.plotting import plot_interface_residual
    from bayescalib.plotting.diagnosis import (
        plot_candidate_ranking,
        plot_residual_bands,
        plot_surface_residuals,
    )
    from bayescalib.stages.files import write_json

    fig = Path(figdir)
    written: list[str] = []
    base = checks["base"]
    rows, panels = ["calibrated model"], _panels(base, diagnosis["check"]["located"])
    chosen = diagnosis["chosen_model"]
    solved = [e["candidate"] for e in diagnosis["extended"] if e["check_after"] is not None]
    shown = chosen if chosen != "base" else (solved[0] if solved else None)
    disc = diagnosis.get("discretization") or {}
    if chosen == "base" and disc.get("explains") and "discretization" in checks:
        # the mesh explains the mismatch: the observations corrected for it, not a candidate
        rows.append(f"corrected for the {disc['finer_preset']} mesh")
        panels += _panels(checks["discretization"], disc["check_after"]["located"])
    elif shown is not None:
        rows.append(f"with {shown}")
        after = next(e for e in diagnosis["extended"] if e["candidate"] == shown)
        panels += _panels(checks[shown], after["check_after"]["located"])
    sn = base.snapshots[-1]
    if sn.s is None:  # 3D: the nodes seen from above, and the last snapshot from the side
        written += map(str, plot_surface_residuals(
            panels, [fig / f"residuals.{e}" for e in formats], row_titles=rows, dpi=dpi))
        written += map(str, plot_surface_residuals(
            [panels[len(base.snapshots) - 1]],
            [fig / f"interface_residual.{e}" for e in formats], view="side",
            row_titles=["where the calibrated model misses the observed surface"], dpi=dpi))
    else:
        written += map(str, plot_residual_bands(
            panels, [fig / f"residuals.{e}" for e in formats], row_titles=rows, dpi=dpi))
        written += map(str, plot_interface_residual(
            sn.xy, sn.z_s, [fig / f"interface_residual.{e}" for e in formats],
            label=f"standardized smoothed residual ({sn.label})", unit="sd",
            title="where the calibrated model misses the observed interface", dpi=dpi))
    rank = diagnosis["attribution"]["ranking"]
    thr = float(chi2.isf(diagnosis["attribution"]["threshold"], 1))
    written += map(str, plot_candidate_ranking(
        [r["candidate"] for r in rank], [r["score_statistic"] for r in rank],
        [r["explained_fraction"] for r in rank], thr,
        [fig / f"candidates.{e}" for e in formats],
        selected=diagnosis["attribution"]["selected"], dpi=dpi))
    write_json(json_path, {**diagnosis, "figures": written})
    with atomic_path(html_path, suffix=".html") as tmp:
        tmp.write_text(_html(diagnosis))
    return written


def _html(d: Mapping[str, Any]) -> str:
    rows = "".join(
        f"<tr><td>{html.escape(r['candidate'])}</td><td>{r['score_statistic']:.3g}</td>"
        f"<td>{r['p_value']:.2g}</td><td>{100 * r['explained_fraction']:.0f} %</td>"
        f"<td>{100 * r['identifiable_fraction']:.0f} %</td><td>{r['phi_hat']:.3g} "
        f"{html.escape(r.get('unit', ''))}</td></tr>"
        for r in d["attribution"]["ranking"])
    ext = "".join(
        f"<tr><td>{html.escape(e['candidate'])}</td>"
        f"<td>{html.escape(_ORIGIN.get(e.get('origin'), ''))}</td>"
        f"<td>{e['log_bayes_factor']:.2f}</td>"
        + "<td>" + "<br>".join(f"{html.escape(n)}: {p['mean']:.3g} &plusmn; {p['std']:.2g} "
                               f"{html.escape(p['unit'])}" for n, p in e["phi"].items())
        + "</td>"
        + (f"<td>{1e3 * e['check_after']['residual_rms_mm']:.2f} &micro;m</td>"
           f"<td>{100 * e['check_after']['pointwise_band_coverage']:.0f} %</td>"
           f"<td>{'yes' if e.get('explains') else 'no'}</td></tr>"
           if e["check_after"] is not None else
           "<td colspan='3'>not solvable at its posterior draws</td></tr>")
        for e in d["extended"])
    aside = "".join(_set_aside_row(e) for e in d.get("set_aside") or [])
    words = "".join(f"<p>{html.escape(s)}</p>" for s in d["plain_words"])
    return (
        "<!DOCTYPE html><html><head><meta charset='utf-8'><title>Model-form diagnosis</title>"
        "</head><body><h1>Model-form diagnosis</h1>"
        f"<p><b>Verdict:</b> {html.escape(d['verdict'])}</p>{words}"
        "<h2>Candidate physics, ranked</h2><table border='1' cellpadding='3'>"
        "<tr><th>candidate</th><th>score S</th><th>p-value</th><th>explains</th>"
        "<th>not absorbed by E, nu, ...</th><th>estimated phi</th></tr>"
        f"{rows}</table>"
        + ("<h2>Candidates set aside</h2><p>Not in any extended model, each with what "
           "could be done about it.</p><table border='1' cellpadding='3'>"
           "<tr><th>candidate</th><th>why</th><th>estimated phi</th><th>plausible range</th>"
           "<th>p-value</th><th>explains</th><th>what to do</th></tr>"
           f"{aside}</table>" if aside else "")
        + ("<h2>Extended models</h2><table border='1' cellpadding='3'><tr><th>candidate</th>"
           "<th>calibrated because</th><th>ln Bayes factor</th><th>phi</th>"
           "<th>residual RMS after</th>"
           f"<th>band coverage after</th><th>explains the mismatch</th></tr>{ext}</table>"
           if ext else "")
        + "</body></html>\n")


#: why an extended model was calibrated (``origin`` of its record), for the report
_ORIGIN = {
    "ranking": "ranked among the best by the attribution",
    "attribution": "selected together by the attribution",
    "joint of singles": "its effects each fit significantly better alone",
}


def _set_aside_row(e: Mapping[str, Any]) -> str:
    """A candidate set aside as a table row: why, estimate, range, p, share, advice."""
    p = "" if e.get("p_value") is None else f"{e['p_value']:.2g}"
    share = ("" if e.get("explained_fraction") is None else
             f"{100 * e['explained_fraction']:.0f} %")
    held = e.get("calibrated_within_range_in")
    held = f"calibrated within its range only in {', '.join(held)} (not chosen)" if held else ""
    todo = "; ".join(x for x in (e.get("failure"), held, e["advice"]) if x)
    return (f"<tr><td>{html.escape(e['candidate'])}</td><td>{html.escape(e['reason'])}</td>"
            f"<td>{_num(e.get('estimate'), e['unit'])}</td>"
            f"<td>[{e['range'][0]:.3g}, {e['range'][1]:.3g}] {html.escape(_unit(e['unit']))}"
            f"</td><td>{p}</td><td>{share}</td><td>{html.escape(todo)}</td></tr>")


def _unit(unit: str) -> str:
    return "" if unit in ("", "-") else unit


def _num(x: float | None, unit: str) -> str:
    return "" if x is None else f"{x:.3g} {html.escape(_unit(unit))}".rstrip()
