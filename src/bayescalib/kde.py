"""Weighted kernel density estimates and highest-density levels for posterior plots.

Marginals of the SMC particle approximation (paper eq. smcdirac) are smoothed
with Gaussian KDEs (``scipy.stats.gaussian_kde`` with particle weights; Scott's
bandwidth rule with the Kish effective sample size). Highest-density
"percentile" levels are the density thresholds t_l whose super-level set
{x : f(x) >= t_l} holds probability mass l (e.g. l = 0.5, 0.9, 0.99); the
paper's joint posterior figures draw these contours (Sec. 4.3).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from scipy.stats import gaussian_kde

__all__ = ["hpd_levels", "kde_1d", "kde_2d", "weighted_quantile"]


def weighted_quantile(x: np.ndarray, w: np.ndarray | None, q: np.ndarray | float) -> np.ndarray:
    """Quantiles ``q`` in [0, 1] of samples ``x`` (N,) with weights ``w`` (N,).

    The weighted ECDF is interpolated linearly between the mid-points of the
    sorted samples' weights (for equal weights this is the "Hazen" quantile).
    """
    x = np.asarray(x, float)
    w = np.ones_like(x) if w is None else np.asarray(w, float)
    order = np.argsort(x, kind="stable")
    xs, ws = x[order], w[order]
    keep = ws > 0
    xs, ws = xs[keep], ws[keep]
    cw = (np.cumsum(ws) - 0.5 * ws) / ws.sum()
    return np.interp(np.asarray(q, float), cw, xs)


def _grid(x: np.ndarray, bounds: Sequence[float] | None, n: int, pad: float = 0.1) -> np.ndarray:
    if bounds is not None:
        lo, hi = float(bounds[0]), float(bounds[1])
    else:
        lo, hi = float(np.min(x)), float(np.max(x))
        span = hi - lo if hi > lo else 1.0
        lo, hi = lo - pad * span, hi + pad * span
    return np.linspace(lo, hi, n)


def kde_1d(
    x: np.ndarray,
    weights: np.ndarray | None = None,
    *,
    grid: np.ndarray | None = None,
    n_grid: int = 256,
    bounds: Sequence[float] | None = None,
    bw_method: str | float | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Weighted 1D Gaussian KDE.

    Parameters
    ----------
    x : (N,) samples (user units).
    weights : (N,) non-negative weights (normalized or not); None = equal.
    grid : evaluation points; default ``n_grid`` points over ``bounds`` (or the
        sample range padded by 10 %).
    bw_method : passed to ``scipy.stats.gaussian_kde`` (default Scott).

    Returns
    -------
    grid : (G,)
    density : (G,) in 1 / unit of x.
    """
    x = np.asarray(x, float)
    kde = gaussian_kde(x, weights=weights, bw_method=bw_method)
    g = _grid(x, bounds, n_grid) if grid is None else np.asarray(grid, float)
    return g, kde(g)


def kde_2d(
    x: np.ndarray,
    y: np.ndarray,
    weights: np.ndarray | None = None,
    *,
    n_grid: int = 128,
    bounds: Sequence[Sequence[float]] | None = None,
    bw_method: str | float | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Weighted 2D Gaussian KDE on a regular grid.

    Parameters
    ----------
    x, y : (N,) samples of the two parameters.
    weights : (N,) weights; None = equal.
    n_grid : grid points per axis.
    bounds : ((xlo, xhi), (ylo, yhi)); default sample ranges padded by 10 %.

    Returns
    -------
    gx : (G,) grid of x; gy : (G,) grid of y;
    density : (G, G) with ``density[i, j]`` at (gx[j], gy[i]) (matplotlib's
        contour convention), in 1 / (unit x * unit y).
    """
    x = np.asarray(x, float)
    y = np.asarray(y, float)
    kde = gaussian_kde(np.vstack([x, y]), weights=weights, bw_method=bw_method)
    gx = _grid(x, None if bounds is None else bounds[0], n_grid)
    gy = _grid(y, None if bounds is None else bounds[1], n_grid)
    XX, YY = np.meshgrid(gx, gy)
    dens = kde(np.vstack([XX.ravel(), YY.ravel()])).reshape(XX.shape)
    return gx, gy, dens


def hpd_levels(
    density: np.ndarray,
    levels: Sequence[float] = (0.5, 0.9, 0.99),
    weights: np.ndarray | None = None,
) -> np.ndarray:
    """Density thresholds t_l whose super-level sets hold mass l.

    Two modes:

    * ``weights is None``: ``density`` is a density evaluated on a *regular*
      grid (any shape); cell masses are proportional to the density values, so
      t_l is the smallest density among the highest cells that together hold a
      fraction l of the grid mass.
    * ``weights`` given: ``density`` holds f(x_i) at weighted samples x_i of the
      same distribution; t_l is the weighted (1 - l)-quantile of f(x_i), since
      P(f(X) >= t_l) = l.

    Returns
    -------
    (len(levels),) thresholds, in the order of ``levels`` (higher level ->
    lower threshold).
    """
    lv = np.asarray(levels, float)
    if np.any((lv <= 0) | (lv >= 1)):
        raise ValueError(f"levels must lie in (0, 1), got {list(levels)}")
    d = np.asarray(density, float).ravel()
    if weights is not None:
        return weighted_quantile(d, np.asarray(weights, float).ravel(), 1.0 - lv)
    order = np.argsort(d)[::-1]
    ds = d[order]
    cm = np.cumsum(ds)
    cm /= cm[-1]
    idx = np.searchsorted(cm, lv, side="left")
    return ds[np.minimum(idx, ds.size - 1)]
