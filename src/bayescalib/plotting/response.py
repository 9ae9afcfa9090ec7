"""Response surfaces of the GP log-likelihood surrogate over a 2-D design space.

Three panels (paper Figs. "likexamples", "loglikexamples", "stdexamples"), each
with its title and both axes labelled: the likelihood relative to its maximum,
``exp(L - max L)``, the log-likelihood L in nats (natural log), and the GP standard
deviation of L in nats. Every panel shows the training inputs (open circles),
failed forward-model runs (grey crosses) and optionally the ground truth.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from matplotlib.axes import Axes
from matplotlib.figure import Figure

from ._validation import PathsLike, as_array, as_names_units, as_paths, as_points, finish
from .style import COLORS, axis_label, paper_style

__all__ = ["plot_response_surface"]


def _overlay(ax: Axes, X_train: np.ndarray, X_failed: np.ndarray, truth: np.ndarray | None,
             ) -> list:
    handles = []
    if X_train.shape[0]:
        # black halo under the white circles: readable on both ends of the colormap
        ax.scatter(X_train[:, 0], X_train[:, 1], s=14, facecolors="none", edgecolors="k",
                   linewidths=1.5, zorder=3)
        handles.append(ax.scatter(X_train[:, 0], X_train[:, 1], s=14, facecolors="none",
                                  edgecolors=COLORS["train"], linewidths=0.6,
                                  label=f"training runs ({X_train.shape[0]})", zorder=3))
    if X_failed.shape[0]:
        handles.append(ax.scatter(X_failed[:, 0], X_failed[:, 1], s=18, marker="x",
                                  c="0.45", linewidths=1.1,
                                  label=f"failed runs ({X_failed.shape[0]})", zorder=3))
    if truth is not None:
        (h,) = ax.plot(*truth, ls="none", marker="*", ms=11, mfc=COLORS["truth"], mec="k",
                       mew=0.6, label="ground truth", zorder=4)
        handles.append(h)
    return handles


def plot_response_surface(
    grid_x: np.ndarray,
    grid_y: np.ndarray,
    loglik: np.ndarray,
    std: np.ndarray | None,
    X_train: np.ndarray,
    X_failed: np.ndarray | None,
    names: Sequence[str],
    units: Sequence[str],
    paths: PathsLike,
    *,
    truth: Sequence[float] | None = None,
    loglik_range: float | None = None,
    title: str | None = None,
    dpi: float = 200,
    return_figure: bool = False,
):
    """Likelihood, log-likelihood and GP standard deviation over a 2-D grid.

    Parameters
    ----------
    grid_x : array_like, shape (nx,)
        Strictly increasing grid of the first parameter (user units).
    grid_y : array_like, shape (ny,)
        Strictly increasing grid of the second parameter.
    loglik : array_like, shape (ny, nx)
        GP mean of the log-likelihood; ``loglik[j, i]`` at ``(grid_x[i], grid_y[j])``.
    std : array_like, shape (ny, nx) or None
        GP standard deviation of the log-likelihood; None drops the third panel.
    X_train : array_like, shape (n, 2)
        Inputs of successful forward runs (open circles).
    X_failed : array_like, shape (k, 2) or None
        Inputs of failed runs (grey crosses).
    names, units : sequence of 2 str
        Parameter names and units for the axis labels.
    paths : path or sequence of paths
        Output files; format from the suffix.
    truth : array_like, shape (2,), optional
        Ground truth marker.
    loglik_range : float, optional
        If given, the log-likelihood colour scale spans ``[max L - loglik_range,
        max L]`` (lower values saturate), which keeps the high-likelihood
        region readable when L spans orders of magnitude.
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
    gx = as_array(grid_x, "grid_x", ndim=1)
    gy = as_array(grid_y, "grid_y", ndim=1)
    for g, nm in ((gx, "grid_x"), (gy, "grid_y")):
        if g.size < 2 or np.any(np.diff(g) <= 0):
            raise ValueError(f"{nm}: need at least 2 strictly increasing values")
    L = as_array(loglik, "loglik", shape=(gy.size, gx.size))
    S = None if std is None else as_array(std, "std", shape=(gy.size, gx.size))
    if S is not None and np.any(S < 0):
        raise ValueError("std: standard deviations must be non-negative")
    Xt = as_points(X_train, "X_train")
    Xf = as_points(X_failed, "X_failed")
    names, units = as_names_units(names, units, 2)
    out_paths = as_paths(paths)
    tr = None if truth is None else as_array(truth, "truth", shape=(2,))
    if loglik_range is not None and not loglik_range > 0:
        raise ValueError(f"loglik_range: must be positive, got {loglik_range}")

    # (values, panel title, colour-bar label, vmin, vmax, extend): log-likelihoods are
    # natural logs, in nats; the likelihood ratio exp(L - max L) has no unit
    panels = [(np.exp(L - L.max()), "likelihood (surrogate), relative to its maximum",
               "exp(L - max L) [-]", None, None, "neither"),
              (L, "log-likelihood L (surrogate mean)", "L [nats]",
               None if loglik_range is None else L.max() - loglik_range, None,
               "neither" if loglik_range is None else "min")]
    if S is not None:
        panels.append((S, "surrogate uncertainty: sd of L", "sd of L [nats]", 0.0, None,
                       "neither"))

    with paper_style():
        fig = Figure(figsize=(3.4 * len(panels), 3.3), layout="constrained")
        axes = fig.subplots(1, len(panels), sharex=True, sharey=True, squeeze=False)[0]
        for k, (ax, (Z, head, label, vmin, vmax, extend)) in enumerate(zip(axes, panels)):
            if vmin is not None:
                Z = np.maximum(Z, vmin)
            mesh = ax.pcolormesh(gx, gy, Z, shading="gouraud", vmin=vmin, vmax=vmax,
                                 rasterized=True)
            cb = fig.colorbar(mesh, ax=ax, shrink=0.9, pad=0.02, extend=extend)
            cb.set_label(label)
            handles = _overlay(ax, Xt, Xf, tr)
            ax.set_xlim(gx[0], gx[-1])
            ax.set_ylim(gy[0], gy[-1])
            ax.set_title(f"({chr(ord('a') + k)}) {head}", fontsize=8)
            ax.set_xlabel(axis_label(names[0], units[0]))
            ax.set_ylabel(axis_label(names[1], units[1]))
            ax.tick_params(labelleft=True)
        if handles:
            leg = fig.legend(handles=handles, loc="outside lower center", ncols=len(handles),
                             frameon=False)
            for h in leg.legend_handles:
                if hasattr(h, "set_edgecolor") and h.get_label().startswith("training"):
                    h.set_edgecolor("k")
        if title:
            fig.suptitle(title)
        return finish(fig, out_paths, dpi, return_figure)
