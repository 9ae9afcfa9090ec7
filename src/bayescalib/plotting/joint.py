"""Joint 2-D posterior figure (paper Fig. "sc_posteriors_twodim").

A weighted hexagonal histogram of the particles, weighted-KDE
highest-density contour lines at given probability masses, marginal
histograms with weighted KDEs on the top and right axes (priors dashed),
MAP and posterior-mean crosses, and the ellipses of the global Gaussian and
Laplace approximations.
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
from .gaussian import ellipse_points, mass_outside_box
from .style import COLORS, axis_label, density_unit_label, paper_style

__all__ = ["plot_joint_posterior"]

Gaussian = tuple[Sequence[float], Sequence[Sequence[float]]]


def _validate_gaussian(g: Gaussian | None, name: str) -> tuple[np.ndarray, np.ndarray] | None:
    if g is None:
        return None
    if len(g) != 2:
        raise ValueError(f"{name}: expected a (mean, cov) pair")
    m = as_array(g[0], f"{name} mean", shape=(2,))
    c = as_array(g[1], f"{name} cov", shape=(2, 2))
    return m, c


def plot_joint_posterior(
    samples: np.ndarray,
    weights: np.ndarray | None,
    names: Sequence[str],
    units: Sequence[str],
    paths: PathsLike,
    *,
    prior_pdfs: tuple[Callable | None, Callable | None] | None = None,
    map: Sequence[float] | None = None,
    mean: Sequence[float] | None = None,
    gaussian: Gaussian | None = None,
    laplace: Gaussian | None = None,
    levels: Sequence[float] = (0.5, 0.9, 0.99),
    ellipse_levels: Sequence[float] = (0.9,),
    truth: Sequence[float] | None = None,
    bounds: Sequence[Sequence[float]] | None = None,
    gridsize: int = 30,
    bins: int = 30,
    title: str | None = None,
    dpi: float = 200,
    return_figure: bool = False,
):
    """Joint posterior of two parameters with marginals and approximations.

    Parameters
    ----------
    samples : array_like, shape (N, 2)
        Particles in user units (column order = ``names``).
    weights : array_like, shape (N,) or None
        Non-negative particle weights (normalized internally); None = equal.
    names : sequence of 2 str
        Parameter names, e.g. ``("E", "nu")``.
    units : sequence of 2 str
        Units, e.g. ``("Pa", "-")``.
    paths : path or sequence of paths
        Output files; format from the suffix (``.png``, ``.pdf``, ...).
    prior_pdfs : (callable or None, callable or None), optional
        Marginal prior densities p(x_k) [1/unit], vectorized over a 1-D array;
        drawn dashed on the marginal axes.
    map : array_like, shape (2,), optional
        MAP estimate (green x).
    mean : array_like, shape (2,), optional
        Posterior mean (orange +).
    gaussian : (mean (2,), cov (2, 2)), optional
        Global Gaussian approximation, drawn as orange ellipses.
    laplace : (mean (2,), cov (2, 2)), optional
        Laplace approximation at the MAP, drawn as green ellipses.
    levels : sequence of float in (0, 1)
        Probability masses of the KDE highest-density lines.
    ellipse_levels : sequence of float in (0, 1)
        Probability masses of the approximation ellipses (solid, then dashed,
        dotted for further levels).
    truth : array_like, shape (2,), optional
        Ground truth (vermillion star).
    bounds : array_like, shape (2, 2), optional
        ``((lo_x, hi_x), (lo_y, hi_y))`` plot and histogram ranges, e.g. the
        prior box; default: particle range padded by 5 %.
    gridsize : int
        Hexagons along x.
    bins : int
        Histogram bins of the marginals.
    title : str, optional
        Figure title.
    dpi : float
        Raster resolution [dots per inch].
    return_figure : bool
        Also return the Figure (the caller owns it then).

    Returns
    -------
    list of pathlib.Path
        Written files, or ``(paths, Figure)`` if ``return_figure``.
    """
    x = as_samples(samples, dim=2)
    w = as_weights(weights, x.shape[0])
    names, units = as_names_units(names, units, 2)
    out_paths = as_paths(paths)
    levels = as_levels(levels)
    ell_levels = as_levels(ellipse_levels, "ellipse_levels")
    b = as_bounds(bounds, 2, data=x)
    if prior_pdfs is None:
        prior_pdfs = (None, None)
    if len(prior_pdfs) != 2:
        raise ValueError("prior_pdfs: expected a pair of callables (or None entries)")
    priors = [validate_prior_pdf(p, f"prior_pdfs[{k}]") for k, p in enumerate(prior_pdfs)]
    map_ = None if map is None else as_array(map, "map", shape=(2,))
    mean_ = None if mean is None else as_array(mean, "mean", shape=(2,))
    truth_ = None if truth is None else as_array(truth, "truth", shape=(2,))
    gauss = _validate_gaussian(gaussian, "gaussian")
    lap = _validate_gaussian(laplace, "laplace")

    with paper_style():
        # the hexbin's colour bar lies under the joint panel it belongs to (beside the
        # right-hand marginal it read as that marginal's scale), the legend under both
        fig = Figure(figsize=(5.4, 6.6), layout="constrained")
        gs = fig.add_gridspec(4, 2, width_ratios=(4.0, 1.1),
                              height_ratios=(1.1, 4.0, 0.14, 1.0))
        ax = fig.add_subplot(gs[1, 0])
        ax_top = fig.add_subplot(gs[0, 0], sharex=ax)
        ax_right = fig.add_subplot(gs[1, 1], sharey=ax)
        ax_leg = fig.add_subplot(gs[3, :])
        ax_cb = fig.add_subplot(gs[2, 0])
        ax_leg.axis("off")

        hb = draw_hexbin(ax, x, w, b[0], b[1], gridsize=gridsize)
        cb = fig.colorbar(hb, cax=ax_cb, orientation="horizontal")
        cb.set_label("posterior mass per hexagon [-]")
        handles: list = [Patch(facecolor=hb.cmap(0.65), label="posterior (hexbin)")]

        sup = None if bounds is None else b  # reflect only at bounds that were given
        cs = draw_hpd_contours(ax, x, w, b[0], b[1], levels, support=sup)
        if cs is not None:
            hpd = ", ".join(level_text(p) for p in levels)
            handles.append(Line2D([], [], color=COLORS["kde"], lw=0.9,
                                  label=f"KDE HPD regions {hpd}"))

        styles = ("-", "--", ":", "-.")
        for approx, key, lab in ((gauss, "gaussian", "Gaussian approx."),
                                 (lap, "laplace", "Laplace approx.")):
            if approx is None:
                continue
            for k, p in enumerate(ell_levels):
                pts = ellipse_points(approx[0], approx[1], float(p))
                ax.plot(pts[:, 0], pts[:, 1], color=COLORS[key], lw=1.4, ls=styles[k % 4])
            label = f"{lab} ({', '.join(level_text(p) for p in ell_levels)})"
            out = mass_outside_box(approx[0], approx[1], b)
            if out >= 0.005:
                label += f"\n  {100 * out:.0f} % of its mass outside the box: clipped"
            handles.append(Line2D([], [], color=COLORS[key], lw=1.4, label=label))

        markers = []
        if mean_ is not None:
            markers.append((mean_, "+", COLORS["mean"], 11, "posterior mean"))
        if map_ is not None:
            markers.append((map_, "x", COLORS["map"], 8, "MAP"))
        # the truth under the estimates: a MAP on the truth stays visible on top of it
        truth_handle = None
        if truth_ is not None:
            (truth_handle,) = ax.plot(*truth_, ls="none", marker="*", ms=13,
                                      mfc=COLORS["truth"], mec="k", mew=0.6,
                                      label="ground truth", zorder=4)
        for pt, mk, col, ms, lab in markers:
            (h,) = ax.plot(*pt, ls="none", marker=mk, color=col, ms=ms, mew=2.2, label=lab,
                           zorder=6)
            handles.append(h)
        if truth_handle is not None:
            handles.append(truth_handle)

        top = draw_marginal(ax_top, x[:, 0], w, b[0], bins=bins, prior_pdf=priors[0],
                            support=None if sup is None else b[0])
        right = draw_marginal(ax_right, x[:, 1], w, b[1], horizontal=True, bins=bins,
                              prior_pdf=priors[1], support=None if sup is None else b[1])
        for a, vals, vertical in ((ax_top, (mean_, map_, truth_), True),
                                  (ax_right, (mean_, map_, truth_), False)):
            k = 0 if vertical else 1
            for v, col, ls in zip(vals, (COLORS["mean"], COLORS["map"], COLORS["truth"]),
                                  ("-", "-", ":")):
                if v is not None:
                    (a.axvline if vertical else a.axhline)(v[k], color=col, lw=1.0, ls=ls)
        if any(p is not None for p in priors):
            handles.append(Line2D([], [], color=COLORS["prior"], ls="--", label="prior"))
        if "kde" in top or "kde" in right:
            handles.insert(1, Line2D([], [], color=COLORS["kde"], lw=1.2, label="marginal KDE"))

        ax.set_xlim(*b[0])
        ax.set_ylim(*b[1])
        ax.set_xlabel(axis_label(names[0], units[0]))
        ax.set_ylabel(axis_label(names[1], units[1]))
        ax_top.tick_params(labelbottom=False)
        ax_right.tick_params(labelleft=False)
        ax_top.set_ylabel(density_unit_label(units[0]), fontsize=7.5)
        ax_right.set_xlabel(density_unit_label(units[1]), fontsize=7.5)
        for a in (ax_top, ax_right):
            a.tick_params(labelsize=6.5)
            for side in ("top", "right"):
                a.spines[side].set_visible(False)
        ax_leg.legend(handles=handles, loc="center", frameon=False, fontsize=6.5,
                      handlelength=1.6, borderaxespad=0.0, ncols=2)
        if title:
            fig.suptitle(title)
        return finish(fig, out_paths, dpi, return_figure)
