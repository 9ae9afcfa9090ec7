"""Convergence of the GP surrogate over the number of training points
(paper Figs. "sc_scaling" and "6p_gp_e"): test error, and optionally the
leave-one-out error, on log-log axes."""

from __future__ import annotations

import numpy as np
from matplotlib.figure import Figure

from ._validation import PathsLike, as_array, as_paths, finish
from .style import COLORS, paper_style

__all__ = ["plot_gp_convergence"]


def plot_gp_convergence(
    n_train: np.ndarray,
    l2_error: np.ndarray,
    loo_error: np.ndarray | None,
    paths: PathsLike,
    *,
    relative: bool = False,
    quantity: str = "log-likelihood",
    reference_rate: float | None = None,
    title: str | None = None,
    dpi: float = 200,
    return_figure: bool = False,
):
    """Log-log plot of the surrogate error over the training-set size.

    Parameters
    ----------
    n_train : array_like, shape (m,)
        Numbers of training points (positive; sorted internally).
    l2_error : array_like, shape (m,)
        Error on held-out test points (positive), e.g. the RMS error of the
        GP mean of the log-likelihood.
    loo_error : array_like, shape (m,) or None
        Leave-one-out error (positive), drawn dashed with squares.
    paths : path or sequence of paths
        Output files; format from the suffix.
    relative : bool
        Errors are relative (labelled "relative ... error [-]").
    quantity : str
        Name of the approximated quantity in the y label.
    reference_rate : float, optional
        Draw a grey reference slope ``n^-rate`` through the first test error.
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
    n = as_array(n_train, "n_train", ndim=1)
    m = n.size
    if m < 1:
        raise ValueError("n_train: need at least one entry")
    e = as_array(l2_error, "l2_error", ndim=1)
    loo = None if loo_error is None else as_array(loo_error, "loo_error", ndim=1)
    for arr, nm in ((e, "l2_error"), (loo, "loo_error")):
        if arr is not None and arr.size != m:
            raise ValueError(f"{nm}: length {arr.size} does not match n_train ({m})")
    if np.any(n <= 0):
        raise ValueError("n_train: must be positive")
    for arr, nm in ((e, "l2_error"), (loo, "loo_error")):
        if arr is not None and np.any(arr <= 0):
            raise ValueError(f"{nm}: errors must be positive for a log scale")
    out_paths = as_paths(paths)
    order = np.argsort(n)
    n, e = n[order], e[order]
    loo = None if loo is None else loo[order]

    with paper_style():
        fig = Figure(figsize=(4.2, 3.2), layout="constrained")
        ax = fig.add_subplot()
        ax.loglog(n, e, "o-", color=COLORS["hist"], label="test error (L2)")
        if loo is not None:
            ax.loglog(n, loo, "s--", color=COLORS["mean"], label="leave-one-out error")
        if reference_rate is not None:
            ax.loglog(n, e[0] * (n / n[0]) ** (-reference_rate), color="0.55", lw=0.9,
                      ls=":", label=f"$n^{{-{reference_rate:g}}}$")
        ax.set_xlabel("number of training points $n_{train}$ [-]")
        kind = "relative L2 error" if relative else "L2 error"
        ax.set_ylabel(f"{kind} of {quantity} [-]")
        ax.grid(True, which="major", lw=0.4, alpha=0.5)
        ax.grid(True, which="minor", lw=0.3, alpha=0.25)
        ax.legend()
        if title:
            ax.set_title(title)
        return finish(fig, out_paths, dpi, return_figure)
