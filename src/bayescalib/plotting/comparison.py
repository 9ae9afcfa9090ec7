"""Several posteriors of the same parameters over one truth (e.g. a 3D model against
its 2D slice): :func:`plot_posterior_comparison`."""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np
from matplotlib.figure import Figure

from ._validation import PathsLike, as_paths, finish
from .style import paper_style

__all__ = ["plot_posterior_comparison"]


def _weighted(samples: np.ndarray, weights: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    w = np.asarray(weights, dtype=float)
    w = w / w.sum()
    mean = w @ samples
    d = samples - mean
    return mean, (d * w[:, None]).T @ d


def plot_posterior_comparison(
    posteriors: Mapping[str, tuple[np.ndarray, np.ndarray]],
    names: Sequence[str],
    units: Sequence[str],
    truth: Sequence[float],
    paths: PathsLike = None,
    *,
    title: str | None = None,
    dpi: int = 120,
) -> list:
    """Marginals of two parameters and their joint posterior, one colour per posterior.

    Parameters
    ----------
    posteriors : mapping
        Label -> ``(samples (n, 2), weights (n,))`` (e.g. the SMC particles).
    names, units : sequence of str
        The two parameters' names and units.
    truth : sequence of float
        The true values (dashed black lines, a star in the joint panel).
    paths : path or sequence of paths, optional
        Files to save the figure to.
    title : str, optional
        The figure's title.
    dpi : int
        Resolution of saved bitmaps.

    Returns
    -------
    list of pathlib.Path
        The files written. Three panels: each parameter's weighted histogram per posterior over the truth,
        and the joint posterior (a subsample of the particles, the mean and the 2-sd
        ellipse of each).
    """
    if len(names) != 2 or len(units) != 2 or len(truth) != 2:
        raise ValueError("plot_posterior_comparison: two parameters")
    if not posteriors:
        raise ValueError("plot_posterior_comparison: no posterior")
    out = as_paths(paths)
    colours = ["#1b6ca8", "#d1495b", "#edae49", "#8d6a9f", "#66a182", "#00798c"]
    items = [(label, np.asarray(s, dtype=float), np.asarray(w, dtype=float))
             for label, (s, w) in posteriors.items()]
    # one set of bins per parameter, over all the posteriors' particles
    edges = []
    for j in range(2):
        lo = min(float(s[:, j].min()) for _, s, _ in items)
        hi = max(float(s[:, j].max()) for _, s, _ in items)
        lo, hi = min(lo, float(truth[j])), max(hi, float(truth[j]))
        edges.append(np.linspace(lo, hi, 41))
    with paper_style():
        fig = Figure(figsize=(13.0, 4.9))
        axes = fig.subplots(1, 3)
        for k, (label, s, w) in enumerate(items):
            c = colours[k % len(colours)]
            w = w / w.sum()
            mean, cov = _weighted(s, w)
            for j in range(2):
                axes[j].hist(s[:, j], bins=edges[j], weights=w, density=True,
                             histtype="stepfilled", alpha=0.25, color=c)
                axes[j].hist(s[:, j], bins=edges[j], weights=w, density=True,
                             histtype="step", color=c, lw=1.5)
            idx = np.random.default_rng(0).choice(len(w), size=min(400, len(w)), p=w)
            axes[2].scatter(s[idx, 0], s[idx, 1], s=4, alpha=0.3, color=c)
            vals, vecs = np.linalg.eigh(cov)
            t = np.linspace(0, 2 * np.pi, 200)
            ell = mean[:, None] + 2.0 * vecs @ (np.sqrt(np.maximum(vals, 0))[:, None]
                                                * np.vstack([np.cos(t), np.sin(t)]))
            axes[2].plot(ell[0], ell[1], color=c, lw=1.6, label=label)
            axes[2].plot(*mean, "o", color=c, ms=6, mec="k", mew=0.6)
        for j in range(2):
            axes[j].axvline(truth[j], color="k", ls="--", lw=1.2)
            axes[j].set_xlabel(f"{names[j]} ({units[j]})" if units[j] not in ("", "-")
                               else names[j])
            axes[j].set_ylabel("posterior density")
        axes[2].plot(truth[0], truth[1], "k*", ms=14, label="truth")
        axes[2].set_xlabel(f"{names[0]} ({units[0]})" if units[0] not in ("", "-") else names[0])
        axes[2].set_ylabel(f"{names[1]} ({units[1]})" if units[1] not in ("", "-") else names[1])
        axes[2].set_title("joint: particles, mean (dot), 2-sd ellipse", fontsize=10)
        handles, labels = axes[2].get_legend_handles_labels()
        fig.legend(handles, labels, loc="lower center", ncol=min(len(labels), 3), fontsize=9,
                   frameon=False)
        if title:
            fig.suptitle(title, fontsize=11)
        fig.tight_layout(rect=(0, 0.1 + 0.04 * (len(labels) > 3), 1, 1))
        return finish(fig, out, dpi, False)
