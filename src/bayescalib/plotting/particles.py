"""SMC particle cloud with the weight shown as marker size and colour
(paper Fig. "sc_particles")."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from matplotlib.figure import Figure

from bayescalib.inference.weights import ess

from ._validation import (
    PathsLike,
    as_array,
    as_bounds,
    as_names_units,
    as_paths,
    as_samples,
    as_weights,
    finish,
)
from .style import COLORS, axis_label, paper_style

__all__ = ["plot_particles"]


def plot_particles(
    samples: np.ndarray,
    weights: np.ndarray | None,
    names: Sequence[str],
    units: Sequence[str],
    paths: PathsLike,
    *,
    bounds: Sequence[Sequence[float]] | None = None,
    truth: Sequence[float] | None = None,
    max_marker_size: float = 60.0,
    title: str | None = None,
    dpi: float = 200,
    return_figure: bool = False,
):
    """Scatter plot of weighted particles, weight as marker area and colour.

    Particles are drawn in order of increasing weight, so the heaviest are on
    top. Marker area grows linearly from 3 pt^2 (weight 0) to
    ``max_marker_size`` pt^2 (largest weight).

    Parameters
    ----------
    samples : array_like, shape (N, 2)
        Particles in user units.
    weights : array_like, shape (N,) or None
        Non-negative weights (normalized internally to sum to one).
    names, units : sequence of 2 str
        Parameter names and units.
    paths : path or sequence of paths
        Output files; format from the suffix.
    bounds : array_like, shape (2, 2), optional
        Axis ranges; default: padded particle range.
    truth : array_like, shape (2,), optional
        Ground truth marker.
    max_marker_size : float
        Marker area of the heaviest particle [pt^2].
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
    x = as_samples(samples, dim=2)
    w = as_weights(weights, x.shape[0])
    names, units = as_names_units(names, units, 2)
    out_paths = as_paths(paths)
    b = as_bounds(bounds, 2, data=x)
    tr = None if truth is None else as_array(truth, "truth", shape=(2,))
    if not max_marker_size > 3:
        raise ValueError(f"max_marker_size: must exceed 3 pt^2, got {max_marker_size}")

    order = np.argsort(w, kind="stable")
    xs, ws = x[order], w[order]
    sizes = 3.0 + (max_marker_size - 3.0) * ws / ws.max()
    with paper_style():
        fig = Figure(figsize=(4.6, 3.8), layout="constrained")
        ax = fig.add_subplot()
        sc = ax.scatter(xs[:, 0], xs[:, 1], s=sizes, c=ws, cmap="viridis", vmin=0.0,
                        vmax=ws.max(), alpha=0.85, edgecolors="k", linewidths=0.2,
                        label=f"particles (N = {x.shape[0]})")
        cb = fig.colorbar(sc, ax=ax, pad=0.02)
        cb.set_label("particle weight [-]")
        if tr is not None:
            ax.plot(*tr, ls="none", marker="*", ms=12, mfc=COLORS["truth"], mec="k", mew=0.6,
                    label="ground truth", zorder=5)
        ax.set_xlim(*b[0])
        ax.set_ylim(*b[1])
        ax.set_xlabel(axis_label(names[0], units[0]))
        ax.set_ylabel(axis_label(names[1], units[1]))
        n_eff = ess(w)
        ax.legend(loc="best", title=f"ESS = {n_eff:.0f}", title_fontsize=7.5)
        if title:
            ax.set_title(title)
        return finish(fig, out_paths, dpi, return_figure)
