"""Drawing primitives shared by the posterior figures.

Weighted 1-D marginals (histogram + KDE + optional prior), weighted hexbins
and KDE highest-density contour lines on an existing axes. These are internal
building blocks of :mod:`.joint`, :mod:`.marginals`; they do not save figures.
"""

from __future__ import annotations

import hashlib
import warnings
from collections import OrderedDict
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
from matplotlib.axes import Axes
from matplotlib.collections import PolyCollection

from bayescalib.inference.weights import hpd_thresholds, kde_on_grid, weighted_kde

from ._validation import as_array
from .style import COLORS, DENSITY_CMAP

__all__ = [
    "draw_hexbin",
    "draw_hpd_contours",
    "draw_marginal",
    "level_text",
    "validate_prior_pdf",
]

_MAX_KDE_EVAL = 3000  # particles used to estimate HPD thresholds (random subset)
_MAX_KDE_BUILD = 5000  # particles in a 2-D KDE (random subset, weights renormalized)

#: the last few KDE results of this process (:func:`_memo`): the posterior figures of one
#: job draw the same KDEs several times (the joint figure's marginals and contours again
#: in the marginals and pairs figures), and KDE evaluations were a third of that job
_MEMO: OrderedDict[tuple, Any] = OrderedDict()
_MEMO_SIZE = 16


def _memo(kind: str, arrays: Sequence[np.ndarray], params: tuple, compute: Callable[[], Any]):
    """``compute()``, or its result of an earlier call with bitwise the same arrays and
    the same parameters (a deterministic function of them: seeded subsets). Results
    are shared, never modified by the callers."""
    h = hashlib.sha1()
    for a in arrays:
        a = np.ascontiguousarray(a)
        h.update(repr((a.dtype.str, a.shape)).encode())
        h.update(a.tobytes())
    key = (kind, h.hexdigest(), repr(params))
    if key in _MEMO:
        _MEMO.move_to_end(key)
        return _MEMO[key]
    out = compute()
    _MEMO[key] = out
    while len(_MEMO) > _MEMO_SIZE:
        _MEMO.popitem(last=False)
    return out


def level_text(p: float) -> str:
    """Probability level as a percentage string, e.g. ``0.9`` -> ``"90 %"``."""
    return f"{100 * p:.3g} %"


def validate_prior_pdf(pdf: Callable | None, name: str) -> Callable | None:
    """Wrap a marginal prior density so that bad outputs raise ValueError."""
    if pdf is None:
        return None
    if not callable(pdf):
        raise TypeError(f"{name}: expected a callable density or None, got {type(pdf).__name__}")

    def wrapped(x: np.ndarray) -> np.ndarray:
        y = np.asarray(pdf(x), dtype=float)
        y = np.broadcast_to(y, x.shape) if y.ndim == 0 else y
        if y.shape != x.shape:
            raise ValueError(f"{name}: returned shape {y.shape} for input shape {x.shape}")
        if not np.all(np.isfinite(y)) or np.any(y < 0):
            raise ValueError(f"{name}: density values must be finite and non-negative")
        return y

    return wrapped


def draw_marginal(ax: Axes, x: np.ndarray, w: np.ndarray, lims: Sequence[float], *,
                  horizontal: bool = False, bins: int = 30, prior_pdf: Callable | None = None,
                  bw_method: str | float = "scott", kde: bool = True,
                  support: Sequence[float] | None = None) -> dict[str, object]:
    """Weighted histogram, weighted KDE and prior of one parameter.

    Parameters
    ----------
    ax : Axes
        Target axes.
    x : numpy.ndarray, shape (N,)
        Particle values of the parameter (user units).
    w : numpy.ndarray, shape (N,)
        Normalized weights.
    lims : (float, float)
        Range of the histogram and KDE.
    horizontal : bool
        Draw along the y axis (right-hand marginal of a joint plot).
    bins : int
        Number of histogram bins inside ``lims``.
    prior_pdf : callable, optional
        Marginal prior density, vectorized; drawn dashed.
    bw_method : str or float
        KDE bandwidth rule.
    kde : bool
        Draw the KDE line.
    support : (float, float), optional
        Bounds of the parameter (its prior box): the KDE is corrected by reflection
        there instead of dropping towards them.

    Returns
    -------
    dict
        Artists keyed ``"hist"``, ``"kde"``, ``"prior"`` (missing if not drawn).
    """
    out: dict[str, object] = {}
    edges = np.linspace(lims[0], lims[1], bins + 1)
    mass, _ = np.histogram(x, bins=edges, weights=w)
    dens_hist = mass / np.diff(edges)  # density [1/unit]; mass outside lims is not shown
    out["hist"] = ax.stairs(dens_hist, edges, fill=True,
                            orientation="horizontal" if horizontal else "vertical",
                            color=COLORS["hist"], alpha=0.35, linewidth=0)
    ax.stairs(dens_hist, edges, fill=False, orientation="horizontal" if horizontal else "vertical",
              color=COLORS["hist"], linewidth=0.7)
    grid = np.linspace(lims[0], lims[1], 400)
    if kde:
        try:
            sup = None if support is None else [support]
            dens = _memo("marginal", (x, w, grid), (bw_method, sup),
                         lambda: weighted_kde(x, w, bw_method, support=sup)(grid[None, :]))
            args = (dens, grid) if horizontal else (grid, dens)
            (out["kde"],) = ax.plot(*args, color=COLORS["kde"], lw=1.2)
        except ValueError as exc:
            warnings.warn(f"marginal KDE skipped: {exc}", stacklevel=3)
    if prior_pdf is not None:
        p = prior_pdf(grid)
        args = (p, grid) if horizontal else (grid, p)
        (out["prior"],) = ax.plot(*args, color=COLORS["prior"], ls="--", lw=1.2)
    if horizontal:
        ax.set_xlim(left=0)
        ax.set_ylim(*lims)
    else:
        ax.set_ylim(bottom=0)
        ax.set_xlim(*lims)
    return out


def draw_hexbin(ax: Axes, xy: np.ndarray, w: np.ndarray, xlim: Sequence[float],
                ylim: Sequence[float], gridsize: int = 30) -> PolyCollection:
    """Weighted hexagonal histogram: each hexagon shows the summed weight inside.

    Parameters
    ----------
    ax : Axes
        Target axes.
    xy : numpy.ndarray, shape (N, 2)
        Particles.
    w : numpy.ndarray, shape (N,)
        Normalized weights.
    xlim, ylim : (float, float)
        Extent of the hexagon grid.
    gridsize : int
        Hexagons along x.

    Returns
    -------
    PolyCollection
        The hexbin (use as mappable for a colour bar; values are probability
        masses per hexagon; particles outside the box are left out).
    """
    inside = ((xy[:, 0] >= xlim[0]) & (xy[:, 0] <= xlim[1])
              & (xy[:, 1] >= ylim[0]) & (xy[:, 1] <= ylim[1]))
    xy, w = xy[inside], w[inside]  # particles outside the plotted box are not binned
    return ax.hexbin(xy[:, 0], xy[:, 1], C=w, reduce_C_function=np.sum, gridsize=gridsize,
                     extent=(xlim[0], xlim[1], ylim[0], ylim[1]), cmap=DENSITY_CMAP,
                     linewidths=0.15, edgecolors="face", mincnt=1)


def _hpd_kde(xy: np.ndarray, w: np.ndarray, levels: np.ndarray, bw_method: str | float,
             seed: int, support) -> tuple[Any, np.ndarray]:
    """The KDE of :func:`draw_hpd_contours` and its thresholds of the masses ``levels``
    (descending with ascending mass); ValueError for a degenerate cloud."""
    rng = np.random.default_rng(seed)
    if xy.shape[0] > _MAX_KDE_BUILD:
        idx = rng.choice(xy.shape[0], _MAX_KDE_BUILD, replace=False)
        if w[idx].sum() > 0:
            xy, w = xy[idx], w[idx] / w[idx].sum()
    kde = weighted_kde(xy, w, bw_method, support=support)
    n = xy.shape[0]
    if n > _MAX_KDE_EVAL:
        idx = rng.choice(n, _MAX_KDE_EVAL, replace=False)
        sub, wsub = xy[idx], w[idx]
        if wsub.sum() <= 0:
            sub, wsub = xy, w
    else:
        sub, wsub = xy, w
    return kde, hpd_thresholds(kde(sub.T), wsub, levels)


def draw_hpd_contours(ax: Axes, xy: np.ndarray, w: np.ndarray, xlim: Sequence[float],
                      ylim: Sequence[float], levels: Sequence[float], *,
                      n_grid: int = 100, color: str = COLORS["kde"],
                      bw_method: str | float = "scott", label_lines: bool = True,
                      seed: int = 0, support: Sequence[Sequence[float]] | None = None):
    """Weighted-KDE highest-density contour lines holding the given masses.

    The thresholds are weighted quantiles of the KDE evaluated at the
    particles (see :func:`.kde.hpd_thresholds`); at most 3000 particles,
    drawn at random, are used for that estimate. For speed, the KDE itself
    is built from at most 5000 particles drawn uniformly at random (their
    weights renormalized), an unbiased thinning of the weighted cloud.

    Parameters
    ----------
    ax : Axes
        Target axes.
    xy : numpy.ndarray, shape (N, 2)
        Particles (user units).
    w : numpy.ndarray, shape (N,)
        Normalized weights.
    xlim, ylim : (float, float)
        Grid extent for the contour evaluation.
    levels : sequence of float in (0, 1)
        Probability masses; lines are labelled ``"90 %"`` etc.
    n_grid : int
        Grid points per axis.
    color : str
        Line colour.
    bw_method : str or float
        KDE bandwidth rule.
    label_lines : bool
        Write the mass on each line.
    seed : int
        Seed of the particle subset.
    support : ((float, float), (float, float)), optional
        Bounds of the two parameters (their prior box): the KDE is corrected by
        reflection at the box's faces.

    Returns
    -------
    matplotlib.contour.QuadContourSet or None
        None (with a warning) when the KDE is degenerate or the thresholds
        coincide.
    """
    levels = np.sort(as_array(levels, "levels", ndim=1))
    sup = None if support is None else np.asarray(support, float).tolist()
    try:
        kde, thr = _memo("hpd", (xy, w, levels), (bw_method, seed, sup),
                         lambda: _hpd_kde(xy, w, levels, bw_method, seed, sup))
    except ValueError as exc:
        warnings.warn(f"KDE contours skipped: {exc}", stacklevel=3)
        return None
    gx, gy, dens = _memo("hpd_grid", (xy, w, levels),
                         (bw_method, seed, sup, list(xlim), list(ylim), n_grid),
                         lambda: kde_on_grid(kde, xlim, ylim, n_grid))
    order = np.argsort(thr)
    t_sorted, p_sorted = thr[order], levels[order]
    keep = np.concatenate([[True], np.diff(t_sorted) > 0])
    if not np.all(keep):
        warnings.warn("KDE contours: some probability levels share a threshold; "
                      "drawing the distinct ones", stacklevel=3)
    t_sorted, p_sorted = t_sorted[keep], p_sorted[keep]
    cs = ax.contour(gx, gy, dens, levels=t_sorted, colors=color, linewidths=0.9)
    if label_lines:
        fmt = {lev: level_text(p) for lev, p in zip(cs.levels, p_sorted)}
        ax.clabel(cs, fmt=fmt, fontsize=6.5, inline=True, inline_spacing=2)
    return cs
