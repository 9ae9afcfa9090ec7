"""Figures of the model-form diagnosis, from plain arrays.

* :func:`plot_residual_bands` — residual along the arc length of each snapshot with
  the pointwise and simultaneous predictive bands, before and (optionally) after
  the model extension;
* :func:`plot_candidate_ranking` — score statistics of the candidates with the
  significance threshold and the explained fractions;
* :func:`plot_surface_residuals` — the 3D model's analogue of the residual bands: each
  snapshot's observed nodes seen from above (or from the side), coloured by the
  standardized smoothed residual, the located regions and their cores marked.

The interface coloured by the standardized residual is
:func:`bayescalib.plotting.interfaces.plot_interface_residual`.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from matplotlib.colors import TwoSlopeNorm
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from matplotlib.patches import Patch

from ._validation import PathsLike, as_paths, finish
from .style import COLORS, DIVERGING_CMAP, paper_style

__all__ = ["plot_candidate_ranking", "plot_residual_bands", "plot_surface_residuals"]


def plot_residual_bands(
    panels: Sequence[dict],
    paths: PathsLike,
    *,
    row_titles: Sequence[str] = ("calibrated model",),
    dpi: float = 200,
    return_figure: bool = False,
):
    """Residual along the interface with its predictive bands.

    Parameters
    ----------
    panels : sequence of dict
        One dict per (row, snapshot), row-major; keys ``s`` (n,) arc length [mm],
        ``r`` (n,) residual minus predictive mean [mm], ``r_smooth`` (n,) smoothed,
        ``sd`` (n,) and ``sd_smooth`` (n,) predictive standard deviations [mm],
        ``c_pw``, ``c_sim``, ``c_smooth`` band half-widths in sd, ``label``
        (snapshot), and optional ``intervals`` [[s0, s1], ...] located mismatch [mm]
        and ``cores`` [[s0, s1], ...] where it is largest (drawn darker) [mm].
    row_titles : sequence of str
        Title of each row (e.g. before / after).
    """
    out_paths = as_paths(paths)
    rows = len(row_titles)
    if rows < 1 or len(panels) % rows:
        raise ValueError("panels: the number of panels must be a multiple of the rows")
    cols = len(panels) // rows
    with paper_style():
        fig = Figure(figsize=(3.6 * cols + 0.6, 2.6 * rows + 0.4), layout="constrained")
        axes = np.atleast_2d(fig.subplots(rows, cols, squeeze=False, sharey=True))
        shaded = False
        for k, pan in enumerate(panels):
            ax = axes[k // cols, k % cols]
            s = np.asarray(pan["s"], dtype=float)
            um = 1e3
            sd, sds = np.asarray(pan["sd"]) * um, np.asarray(pan["sd_smooth"]) * um
            ax.fill_between(s, -pan["c_pw"] * sd, pan["c_pw"] * sd, color=COLORS["samples"],
                            alpha=0.35, lw=0, label="pointwise band")
            ax.plot(s, pan["c_sim"] * sd, color="0.45", lw=0.8, ls=":",
                    label="simultaneous band")
            ax.plot(s, -pan["c_sim"] * sd, color="0.45", lw=0.8, ls=":")
            ax.plot(s, pan["c_smooth"] * sds, color="0.2", lw=0.8, ls="--",
                    label="band of smoothed")
            ax.plot(s, -pan["c_smooth"] * sds, color="0.2", lw=0.8, ls="--")
            ax.plot(s, np.asarray(pan["r"]) * um, ".", ms=3, color=COLORS["observed"],
                    label="residual")
            ax.plot(s, np.asarray(pan["r_smooth"]) * um, "-", lw=1.6, color=COLORS["mean"],
                    label="smoothed residual")
            for a, b in pan.get("intervals", []):
                ax.axvspan(a, b, color=COLORS["truth"], alpha=0.15, lw=0)
            for a, b in pan.get("cores", []):
                ax.axvspan(a, b, color=COLORS["truth"], alpha=0.25, lw=0)
            shaded |= bool(pan.get("intervals"))
            ax.axhline(0.0, color="k", lw=0.5)
            ax.set_title(f"{row_titles[k // cols]}: {pan['label']}", fontsize="medium")
            if k // cols == rows - 1:
                ax.set_xlabel("arc length s [mm]")
            if k % cols == 0:
                ax.set_ylabel("residual [µm]")
        handles, labels = axes[0, 0].get_legend_handles_labels()
        if shaded:  # the spans of any panel, named once
            handles += [Patch(color=COLORS["truth"], alpha=0.15, lw=0),
                        Patch(color=COLORS["truth"], alpha=0.15 + 0.25 * 0.85, lw=0)]
            labels += ["located mismatch", "its core (>= half the largest)"]
        axes[0, 0].legend(handles, labels, loc="best", fontsize="x-small")
        return finish(fig, out_paths, dpi, return_figure)


def plot_candidate_ranking(
    names: Sequence[str],
    statistics: Sequence[float],
    explained: Sequence[float],
    threshold_statistic: float,
    paths: PathsLike,
    *,
    selected: Sequence[str] = (),
    dpi: float = 200,
    return_figure: bool = False,
):
    """Horizontal bars of the score statistics (log scale) of the candidates.

    Parameters
    ----------
    names, statistics, explained
        Candidate names, score statistics (chi2_1 under "no effect") and the
        fraction of the residual beyond noise each explains.
    threshold_statistic
        Statistic at the (Bonferroni-corrected) significance level.
    selected
        Names of the selected candidates (highlighted).
    """
    out_paths = as_paths(paths)
    stat = np.maximum(np.asarray(statistics, dtype=float), 1e-3)
    order = np.argsort(stat)
    with paper_style():
        fig = Figure(figsize=(6.0, 0.45 * len(names) + 1.3), layout="constrained")
        ax = fig.add_subplot()
        y = np.arange(len(names))
        colors = [COLORS["map"] if names[i] in selected else COLORS["samples"] for i in order]
        ax.barh(y, stat[order], color=colors, edgecolor="k", lw=0.4)
        for yi, i in zip(y, order, strict=True):
            ax.text(stat[i] * 1.15, yi, f"{100 * explained[i]:.0f} % explained",
                    va="center", fontsize="x-small")
        ax.axvline(threshold_statistic, color=COLORS["truth"], ls="--", lw=1.0,
                   label="significance threshold")
        ax.set_yticks(y, [names[i] for i in order])
        ax.set_xscale("log")
        ax.set_xlim(1e-3, max(stat.max(), threshold_statistic) * 8)
        ax.set_xlabel("score statistic S (chi-square, 1 dof, under 'no effect')")
        ax.legend(loc="lower right", fontsize="x-small")
        return finish(fig, out_paths, dpi, return_figure)


def plot_surface_residuals(
    panels: Sequence[dict],
    paths: PathsLike,
    *,
    row_titles: Sequence[str] = ("calibrated model",),
    view: str = "top",
    dpi: float = 200,
    return_figure: bool = False,
):
    """Observed nodes of 3D surfaces coloured by the standardized smoothed residual.

    Parameters
    ----------
    panels : sequence of dict
        One dict per (row, snapshot), row-major; keys ``points`` (n, 3) observed nodes
        [mm] (x along the flow, y up, z across), ``z_s`` (n,) standardized smoothed
        residual [sd], ``c_smooth`` the half-width of its simultaneous band [sd],
        ``label`` (snapshot), and optional ``located`` and ``cores`` (node indices of the
        located regions and of their cores).
    row_titles : sequence of str
        Title of each row (e.g. before / after).
    view : str
        ``"top"`` (x against z, seen from above) or ``"side"`` (x against y, seen across
        the channel; the nodes drawn back to front).
    """
    if view not in ("top", "side"):
        raise ValueError(f"view: 'top' or 'side', got {view!r}")
    out_paths = as_paths(paths)
    rows = len(row_titles)
    if rows < 1 or len(panels) % rows:
        raise ValueError("panels: the number of panels must be a multiple of the rows")
    cols = len(panels) // rows
    lim = max([float(np.max(np.abs(p["z_s"]))) for p in panels] +
              [float(p["c_smooth"]) for p in panels]) or 1.0
    norm = TwoSlopeNorm(vcenter=0.0, vmin=-lim, vmax=lim)
    axis = 2 if view == "top" else 1
    with paper_style():
        fig = Figure(figsize=(3.4 * cols + 0.8, 2.9 * rows + 0.8), layout="constrained")
        axes = np.atleast_2d(fig.subplots(rows, cols, squeeze=False))
        sc = None
        for k, pan in enumerate(panels):
            ax = axes[k // cols, k % cols]
            p = np.asarray(pan["points"], dtype=float)
            z = np.asarray(pan["z_s"], dtype=float)
            order = np.argsort(-p[:, 2]) if view == "side" else np.argsort(p[:, 1])
            # dots sized to the nodes' number: a very coarse mesh's 45 nodes stay visible
            dot = float(np.clip(3000.0 / max(len(p), 1), 8.0, 60.0))
            sc = ax.scatter(p[order, 0], p[order, axis], c=z[order], cmap=DIVERGING_CMAP,
                            norm=norm, s=dot, lw=0)
            loc = np.asarray(pan.get("located", []), dtype=int)
            core = np.asarray(pan.get("cores", []), dtype=int)
            if loc.size:
                ax.scatter(p[loc, 0], p[loc, axis], s=2.2 * dot, facecolors="none",
                           edgecolors="0.35", lw=0.5)
            if core.size:
                ax.scatter(p[core, 0], p[core, axis], s=2.8 * dot, facecolors="none",
                           edgecolors="k", lw=0.9)
            ax.set_aspect("equal")
            ax.set_title(f"{row_titles[k // cols]}: {pan['label']}", fontsize="medium")
            ax.set_xlabel("x (along the flow) [mm]")
            ax.set_ylabel("z (across) [mm]" if view == "top" else "y (up) [mm]")
        handles = [Line2D([], [], ls="", marker="o", mfc="none", mec="0.35", mew=0.5),
                   Line2D([], [], ls="", marker="o", mfc="none", mec="k", mew=0.9)]
        axes[0, 0].legend(handles, ["located mismatch", "its core (>= half the largest)"],
                          loc="best", fontsize="x-small")
        c_s = float(panels[0]["c_smooth"])
        cb = fig.colorbar(sc, ax=axes, location="bottom", shrink=0.6, aspect=35)
        cb.set_label(f"standardized smoothed residual [sd] (simultaneous band ±{c_s:.2f}; "
                     "+: observed outside the prediction)")
        return finish(fig, out_paths, dpi, return_figure)
