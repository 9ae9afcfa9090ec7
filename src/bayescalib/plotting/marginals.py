"""One-dimensional marginals and corner (pair) plots of weighted particles.

* :func:`plot_marginals_1d` -- one panel per parameter: weighted histogram,
  weighted KDE, prior dashed, vertical MAP / mean / truth markers (paper Fig.
  "heteronoiseuniuia_margs").
* :func:`plot_pair_marginals` -- corner plot for d = 2..7: 1-D marginals on the
  diagonal, weighted hexbins with KDE highest-density lines below it (paper
  Fig. "heteronoiseuniuia2dofmargs").
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from matplotlib.patches import Patch

from ._draw import draw_hexbin, draw_hpd_contours, draw_marginal, level_text, validate_prior_pdf
from ._validation import (
    PathsLike,
    as_array,
    as_bounds,
    as_levels,
    as_names_units,
    as_paths,
    as_samples,
    as_weights,
    finish,
)
from .style import COLORS, axis_label, density_unit_label, paper_style

__all__ = ["plot_marginals_1d", "plot_pair_marginals"]

_MAX_DIM = 7


def _opt_vector(v, name: str, d: int) -> np.ndarray | None:
    return None if v is None else as_array(v, name, shape=(d,))


def _markers(map_, mean_, truth_):
    return [(v, col, ls, lab) for v, col, ls, lab in (
        (mean_, COLORS["mean"], "-", "posterior mean"),
        (map_, COLORS["map"], "-", "MAP"),
        (truth_, COLORS["truth"], ":", "ground truth")) if v is not None]


def plot_marginals_1d(
    samples: np.ndarray,
    weights: np.ndarray | None,
    names: Sequence[str],
    units: Sequence[str],
    paths: PathsLike,
    *,
    prior_pdfs: Sequence[Callable | None] | None = None,
    map: Sequence[float] | None = None,
    mean: Sequence[float] | None = None,
    truth: Sequence[float] | None = None,
    bounds: Sequence[Sequence[float]] | None = None,
    bins: int = 30,
    ncols: int | None = None,
    title: str | None = None,
    dpi: float = 200,
    return_figure: bool = False,
):
    """One panel per parameter with the weighted marginal posterior.

    Parameters
    ----------
    samples : array_like, shape (N, d)
        Particles in user units, d >= 1.
    weights : array_like, shape (N,) or None
        Non-negative particle weights (normalized internally).
    names, units : sequence of d str
        Parameter names and units.
    paths : path or sequence of paths
        Output files; format from the suffix.
    prior_pdfs : sequence of d callables (or None entries), optional
        Marginal prior densities [1/unit], vectorized; drawn dashed.
    map, mean, truth : array_like, shape (d,), optional
        Vertical markers: MAP (green), posterior mean (orange), truth (purple, dotted).
    bounds : array_like, shape (d, 2), optional
        Histogram / axis ranges; default: padded particle range.
    bins : int
        Histogram bins per panel.
    ncols : int, optional
        Panels per row (default: min(d, 3)).
    title : str, optional
        Figure title.
    dpi : float
        Raster resolution [dots per inch].
    return_figure : bool
        Also return the Figure.

    Returns
    -------
    list of pathlib.Path
        Written files, or ``(paths, Figure)`` if ``return_figure``.
    """
    x = as_samples(samples)
    n, d = x.shape
    w = as_weights(weights, n)
    names, units = as_names_units(names, units, d)
    out_paths = as_paths(paths)
    b = as_bounds(bounds, d, data=x)
    if prior_pdfs is None:
        prior_pdfs = [None] * d
    if len(prior_pdfs) != d:
        raise ValueError(f"prior_pdfs: expected {d} entries, got {len(prior_pdfs)}")
    priors = [validate_prior_pdf(p, f"prior_pdfs[{k}]") for k, p in enumerate(prior_pdfs)]
    marks = _markers(_opt_vector(map, "map", d), _opt_vector(mean, "mean", d),
                     _opt_vector(truth, "truth", d))
    ncols = min(d, 3) if ncols is None else int(ncols)
    if ncols < 1:
        raise ValueError(f"ncols: must be >= 1, got {ncols}")
    nrows = -(-d // ncols)

    with paper_style():
        fig = Figure(figsize=(2.6 * ncols, 2.1 * nrows + 0.4), layout="constrained")
        axes = fig.subplots(nrows, ncols, squeeze=False).ravel()
        for k in range(d):
            ax = axes[k]
            draw_marginal(ax, x[:, k], w, b[k], bins=bins, prior_pdf=priors[k],
                          support=None if bounds is None else b[k])
            for v, col, ls, _ in marks:
                ax.axvline(v[k], color=col, ls=ls, lw=1.2)
            ax.set_xlabel(axis_label(names[k], units[k]))
            ax.set_ylabel(density_unit_label(units[k]))
            for side in ("top", "right"):
                ax.spines[side].set_visible(False)
        for ax in axes[d:]:
            ax.set_visible(False)
        handles = [Patch(facecolor=COLORS["hist"], alpha=0.35, edgecolor=COLORS["hist"],
                         label="weighted histogram"),
                   Line2D([], [], color=COLORS["kde"], label="weighted KDE")]
        if any(p is not None for p in priors):
            handles.append(Line2D([], [], color=COLORS["prior"], ls="--", label="prior"))
        handles += [Line2D([], [], color=col, ls=ls, label=lab) for _, col, ls, lab in marks]
        fig.legend(handles=handles, loc="outside lower center", ncols=min(len(handles), 6),
                   frameon=False)
        if title:
            fig.suptitle(title)
        return finish(fig, out_paths, dpi, return_figure)


def plot_pair_marginals(
    samples: np.ndarray,
    weights: np.ndarray | None,
    names: Sequence[str],
    units: Sequence[str],
    paths: PathsLike,
    *,
    truth: Sequence[float] | None = None,
    map: Sequence[float] | None = None,
    mean: Sequence[float] | None = None,
    bounds: Sequence[Sequence[float]] | None = None,
    levels: Sequence[float] = (0.5, 0.9),
    prior_pdfs: Sequence[Callable | None] | None = None,
    gridsize: int = 20,
    bins: int = 25,
    kde_grid: int = 60,
    title: str | None = None,
    dpi: float = 200,
    return_figure: bool = False,
):
    """Corner plot: 1-D marginals on the diagonal, 2-D marginals below it.

    Parameters
    ----------
    samples : array_like, shape (N, d), 2 <= d <= 7
        Particles in user units.
    weights : array_like, shape (N,) or None
        Non-negative particle weights (normalized internally).
    names, units : sequence of d str
        Parameter names and units.
    paths : path or sequence of paths
        Output files; format from the suffix.
    truth, map, mean : array_like, shape (d,), optional
        Markers: lines on the diagonal, points in the pair panels.
    bounds : array_like, shape (d, 2), optional
        Axis ranges; default: padded particle range.
    levels : sequence of float in (0, 1)
        Probability masses of the weighted-KDE highest-density lines.
    prior_pdfs : sequence of d callables (or None entries), optional
        Marginal priors drawn dashed on the diagonal.
    gridsize : int
        Hexagons along x in each pair panel.
    bins : int
        Histogram bins on the diagonal.
    kde_grid : int
        KDE evaluation points per axis for the contour lines.
    title : str, optional
        Figure title.
    dpi : float
        Raster resolution [dots per inch].
    return_figure : bool
        Also return the Figure.

    Returns
    -------
    list of pathlib.Path
        Written files, or ``(paths, Figure)`` if ``return_figure``.
    """
    x = as_samples(samples, min_dim=2, max_dim=_MAX_DIM)
    n, d = x.shape
    w = as_weights(weights, n)
    names, units = as_names_units(names, units, d)
    out_paths = as_paths(paths)
    b = as_bounds(bounds, d, data=x)
    levels = as_levels(levels)
    if prior_pdfs is None:
        prior_pdfs = [None] * d
    if len(prior_pdfs) != d:
        raise ValueError(f"prior_pdfs: expected {d} entries, got {len(prior_pdfs)}")
    priors = [validate_prior_pdf(p, f"prior_pdfs[{k}]") for k, p in enumerate(prior_pdfs)]
    marks = _markers(_opt_vector(map, "map", d), _opt_vector(mean, "mean", d),
                     _opt_vector(truth, "truth", d))
    point_style = {"posterior mean": ("+", 9), "MAP": ("x", 7), "ground truth": ("*", 10)}

    with paper_style():
        size = 1.55 * d + 0.9
        fig = Figure(figsize=(size, size), layout="constrained")
        axes = fig.subplots(d, d, squeeze=False)
        hb = None
        drew_kde = False
        for i in range(d):
            for j in range(d):
                ax = axes[i, j]
                if j > i:
                    ax.set_visible(False)
                    continue
                if i == j:
                    draw_marginal(ax, x[:, i], w, b[i], bins=bins, prior_pdf=priors[i],
                                  support=None if bounds is None else b[i])
                    for v, col, ls, _ in marks:
                        ax.axvline(v[i], color=col, ls=ls, lw=1.1)
                    ax.set_yticks([])
                    for side in ("top", "right", "left"):
                        ax.spines[side].set_visible(False)
                else:
                    xy = x[:, [j, i]]
                    hb = draw_hexbin(ax, xy, w, b[j], b[i], gridsize=gridsize)
                    cs = draw_hpd_contours(ax, xy, w, b[j], b[i], levels, n_grid=kde_grid,
                                           label_lines=d <= 3,
                                           support=None if bounds is None else [b[j], b[i]])
                    drew_kde = drew_kde or cs is not None
                    for v, col, _, lab in marks:
                        mk, ms = point_style[lab]
                        ax.plot(v[j], v[i], ls="none", marker=mk, ms=ms, color=col,
                                mew=0.6 if mk == "*" else 1.8,
                                mec="k" if mk == "*" else col, zorder=5)
                    ax.set_xlim(*b[j])
                    ax.set_ylim(*b[i])
                if i == d - 1:
                    ax.set_xlabel(axis_label(names[j], units[j]))
                else:
                    ax.tick_params(labelbottom=False)
                if j == 0 and i > 0:
                    ax.set_ylabel(axis_label(names[i], units[i]))
                elif i != j:
                    ax.tick_params(labelleft=False)
                ax.tick_params(labelsize=6.5 if d > 3 else 7.5)
                for lab in ax.get_xticklabels():
                    lab.set_rotation(45 if d > 3 else 0)
        # diagonal shares x with the column below: keep the ranges aligned
        for k in range(d):
            axes[k, k].set_xlim(*b[k])
        if hb is not None:
            cb = fig.colorbar(hb, ax=axes[:, -1].tolist(), shrink=0.5, location="right",
                              aspect=25)
            cb.set_label("posterior mass per hexagon [-]")
        handles = [Patch(facecolor=COLORS["hist"], alpha=0.35, label="weighted histogram"),
                   Line2D([], [], color=COLORS["kde"], label="weighted KDE")]
        if drew_kde:
            handles.append(Line2D([], [], color=COLORS["kde"], lw=0.9,
                                  label="KDE HPD " + ", ".join(level_text(p) for p in levels)))
        if any(p is not None for p in priors):
            handles.append(Line2D([], [], color=COLORS["prior"], ls="--", label="prior"))
        for _, col, _, lab in marks:
            mk, ms = point_style[lab]
            handles.append(Line2D([], [], ls="none", marker=mk, ms=ms, color=col,
                                  mew=0.6 if mk == "*" else 1.8,
                                  mec="k" if mk == "*" else col, label=lab))
        fig.legend(handles=handles, loc="outside upper center",
                   ncols=min(len(handles), 3 if d <= 3 else 4), frameon=False)
        if title:
            fig.suptitle(title)
        return finish(fig, out_paths, dpi, return_figure)
