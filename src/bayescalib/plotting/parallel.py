"""Parallel-axis plot of particles coloured by posterior density
(paper Fig. "papuni").

Each particle is a polyline through one vertical axis per parameter (and,
optionally, a last axis with the density value itself). Axes are normalized
to the parameter bounds and drawn over them only, their ends labelled with the
bounds; tick labels are in user units. Values beyond the bounds are drawn at the
axis' end. Lines are drawn in
order of increasing density so that the highest-density particles are on top.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from matplotlib.collections import LineCollection
from matplotlib.colors import Normalize
from matplotlib.figure import Figure
from matplotlib.ticker import MaxNLocator

from ._validation import (
    PathsLike,
    as_array,
    as_bounds,
    as_names_units,
    as_paths,
    as_samples,
    finish,
)
from .style import axis_label, paper_style

__all__ = ["plot_parallel_axes", "select_lines"]


def select_lines(values: np.ndarray, max_lines: int, seed: int = 0) -> np.ndarray:
    """Indices of the lines to draw, in drawing order (increasing value).

    If there are more than ``max_lines`` particles, the ``max_lines // 10``
    highest-valued particles are always kept and the rest is a uniform random
    subset (seeded) of the others, so the plot shows both the mode and the
    spread of the cloud.

    Parameters
    ----------
    values : numpy.ndarray, shape (N,)
        Colour values (density, weight or log-density).
    max_lines : int
        Maximum number of lines.
    seed : int
        Seed of the random subset.

    Returns
    -------
    numpy.ndarray of int, shape (min(N, max_lines),)
    """
    n = values.size
    if max_lines < 1:
        raise ValueError(f"max_lines: must be >= 1, got {max_lines}")
    if n <= max_lines:
        idx = np.arange(n)
    else:
        order = np.argsort(values)[::-1]
        n_top = max(1, max_lines // 10)
        rest = np.random.default_rng(seed).choice(order[n_top:], max_lines - n_top, replace=False)
        idx = np.concatenate([order[:n_top], rest])
    return idx[np.argsort(values[idx], kind="stable")]


def plot_parallel_axes(
    samples: np.ndarray,
    values: np.ndarray,
    names: Sequence[str],
    units: Sequence[str],
    paths: PathsLike,
    *,
    values_are_log: bool = False,
    value_name: str = "posterior density",
    value_unit: str = "-",
    show_value_axis: bool = True,
    bounds: Sequence[Sequence[float]] | None = None,
    max_lines: int = 2000,
    cmap: str = "viridis",
    seed: int = 0,
    title: str | None = None,
    dpi: float = 200,
    return_figure: bool = False,
):
    """Parallel-axis plot of all particles, coloured by posterior density.

    Parameters
    ----------
    samples : array_like, shape (N, d), d >= 2
        Particles in user units (may include uncertain conditions such as the
        inflow rate as extra columns).
    values : array_like, shape (N,)
        Colour value per particle: posterior density or weight
        (``values_are_log=False``, non-negative) or log-density
        (``values_are_log=True``).
    names, units : sequence of d str
        Parameter names and units.
    paths : path or sequence of paths
        Output files; format from the suffix.
    values_are_log : bool
        ``values`` are log-densities (colour bar labelled "log ..."; no
        second "log" if ``value_name`` already starts with it).
    value_name : str
        Name of the value for the colour bar and value axis.
    value_unit : str
        Unit of the value.
    show_value_axis : bool
        Add a last axis with the value itself.
    bounds : array_like, shape (d, 2), optional
        Axis ranges (e.g. the prior box); default: particle range.
    max_lines : int
        Most lines drawn (see :func:`select_lines`).
    cmap : str
        Colormap of the lines.
    seed : int
        Seed of the line subset.
    title : str, optional
        Axes title.
    dpi : float
        Raster resolution [dots per inch].
    return_figure : bool
        Also return the Figure.

    Returns
    -------
    list of pathlib.Path
        Written files, or ``(paths, Figure)`` if ``return_figure``.
    """
    x = as_samples(samples, min_dim=2)
    n, d = x.shape
    v = as_array(values, "values", shape=(n,))
    if not values_are_log and np.any(v < 0):
        raise ValueError("values: densities/weights must be non-negative "
                         "(pass values_are_log=True for log-densities)")
    names, units = as_names_units(names, units, d)
    out_paths = as_paths(paths)
    b = as_bounds(bounds, d, data=x, pad=0.0)
    max_lines = int(max_lines)

    prefix = "log " if values_are_log and not value_name.lower().startswith("log") else ""
    label_v = prefix + value_name
    # a log-density has no unit of its own (it is a log of 1/(product of units))
    value_label = label_v if values_are_log else f"{label_v} [{value_unit}]"
    idx = select_lines(v, max_lines, seed)
    cols = [(x[:, k] - b[k, 0]) / (b[k, 1] - b[k, 0]) for k in range(d)]
    axis_ranges = [tuple(b[k]) for k in range(d)]
    labels = [axis_label(names[k], units[k]) for k in range(d)]
    if show_value_axis:
        vlo, vhi = float(v[idx].min()), float(v[idx].max())
        if vhi <= vlo:
            vhi = vlo + 1.0
        cols.append((v - vlo) / (vhi - vlo))
        axis_ranges.append((vlo, vhi))
        labels.append(value_label)
    # inside the box: a value beyond its axis range is drawn at the axis' end
    y = np.clip(np.column_stack(cols)[idx], 0.0, 1.0)
    m = y.shape[1]
    xs = np.arange(m, dtype=float)
    segs = np.stack([np.broadcast_to(xs, y.shape), y], axis=-1)

    with paper_style():
        fig = Figure(figsize=(max(5.0, 1.15 * m + 1.6), 3.6), layout="constrained")
        ax = fig.add_subplot()
        # the colour range of the lines drawn, not of every particle
        norm = Normalize(vmin=float(v[idx].min()), vmax=float(v[idx].max()))
        lc = LineCollection(segs, array=v[idx], cmap=cmap, norm=norm,
                            linewidths=0.6 if len(idx) > 300 else 0.9,
                            alpha=0.55 if len(idx) > 300 else 0.8)
        ax.add_collection(lc)
        cb = fig.colorbar(lc, ax=ax, pad=0.01, aspect=30)
        cb.solids.set_alpha(1.0)
        cb.set_label(value_label)
        for k, (lo, hi) in enumerate(axis_ranges):
            # each axis spans its range (the prior box) and no further, its ends labelled
            ax.plot([k, k], [0.0, 1.0], color="k", lw=0.9, zorder=3, solid_capstyle="butt")
            inner = [t for t in MaxNLocator(5).tick_values(lo, hi)
                     if lo + 0.08 * (hi - lo) <= t <= hi - 0.08 * (hi - lo)]
            for t in [lo, *inner, hi]:
                yy = (t - lo) / (hi - lo)
                ax.plot([k - 0.04, k], [yy, yy], color="k", lw=0.8, zorder=3)
                ax.text(k - 0.06, yy, f"{t:.4g}", ha="right", va="center", fontsize=6.5,
                        zorder=4, bbox={"facecolor": "white", "edgecolor": "0.6",
                                        "linewidth": 0.3, "alpha": 1.0, "pad": 0.8})
        ax.set_xlim(-0.45, m - 1 + 0.15)
        ax.set_ylim(-0.04, 1.04)
        ax.set_xticks(xs, labels, rotation=25 if m > 5 else 0,
                      ha="right" if m > 5 else "center")
        ax.set_yticks([])
        for side in ("left", "right", "top", "bottom"):
            ax.spines[side].set_visible(False)
        ax.tick_params(axis="x", length=0)
        shown = f"{len(idx)} of {n} particles" if len(idx) < n else f"{n} particles"
        ax.set_title(title if title else shown, fontsize=8)
        return finish(fig, out_paths, dpi, return_figure)
