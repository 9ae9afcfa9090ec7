"""Reading a grid reference posterior and comparing a surrogate posterior with it.

The reference file is written by ``benchmarks/fsi_reference.py``: log-likelihood
values of real forward solves on cell-centred grids over the parameter box (and
optionally on a zoomed grid around the mode). With a uniform prior the grid
posterior is proportional to ``exp(loglik)``; every cell of a grid has the same
area, so normalized grid densities are plain normalized weights.

Use from a benchmark (the ``benchmarks`` folder on ``sys.path``)::

    from _reference import hellinger_to_reference, load_reference
    h = hellinger_to_reference(lambda X: gp.predict(X), "benchmarks/data/fsi_reference_smoke.npz")

Only numpy is needed (no NGSolve, no bayescalib).
"""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

__all__ = [
    "DEFAULT_PATH",
    "grid_moments",
    "grid_points",
    "hellinger",
    "hellinger_to_reference",
    "load_reference",
    "normalized_weights",
]

#: the smoke study's reference, next to this module
DEFAULT_PATH = Path(__file__).resolve().parent / "data" / "fsi_reference_smoke.npz"


def load_reference(path: str | Path = DEFAULT_PATH, grid: str | None = None) -> dict[str, Any]:
    """One grid of a reference file.

    Parameters
    ----------
    path
        The ``.npz`` written by ``fsi_reference.py``.
    grid
        ``"box"`` (the whole parameter box), ``"zoom"`` (around the mode, when the
        file has one) or ``None``: the grid the file recommends.

    Returns
    -------
    dict
        ``grid`` (its name), ``E`` (nE,), ``nu`` (nnu,), ``loglik`` (nE, nnu) with -inf
        where the solve failed, ``failed`` (nE, nnu) bool, ``inferred`` (nE, nnu) bool
        (failed cells that were not solved: see ``fsi_reference.py``), ``D`` (nE, nnu), ``box``
        [[E_lo, E_hi], [nu_lo, nu_hi]] (the cells' outer edges), ``recommended``,
        ``names`` (parameter names, in the order of the grid axes) and ``meta`` (dict).
    """
    with np.load(path, allow_pickle=False) as f:
        data = {k: f[k] for k in f.files}
    meta = json.loads(str(data["meta"]))
    recommended = str(data["recommended"])
    name = recommended if grid is None else grid
    prefix = {"box": "", "zoom": "zoom_"}.get(name)
    if prefix is None:
        raise ValueError(f"grid must be 'box', 'zoom' or None, got {grid!r}")
    if prefix + "loglik" not in data:
        raise ValueError(f"reference file '{path}' has no {name!r} grid")
    return {
        "grid": name,
        "E": data[prefix + "E"],
        "nu": data[prefix + "nu"],
        "loglik": data[prefix + "loglik"],
        "failed": data[prefix + "failed"].astype(bool),
        "inferred": (data[prefix + "inferred"].astype(bool) if prefix + "inferred" in data
                     else np.zeros(data[prefix + "loglik"].shape, bool)),
        "D": data[prefix + "D"],
        "box": data[prefix + "box"],
        "recommended": recommended,
        "names": list(meta["names"]),
        "meta": meta,
    }


def grid_points(E: np.ndarray, nu: np.ndarray) -> np.ndarray:
    """(nE * nnu, 2) points (E, nu), row-major: point ``i * nnu + j`` is ``(E[i], nu[j])``,
    so ``values.reshape(nE, nnu)`` matches the reference's ``loglik`` layout."""
    EE, NN = np.meshgrid(np.asarray(E, float), np.asarray(nu, float), indexing="ij")
    return np.column_stack([EE.ravel(), NN.ravel()])


def normalized_weights(logvals: np.ndarray, mask: np.ndarray | None = None) -> np.ndarray:
    """``exp(logvals)`` normalized to sum 1 over the cells where ``mask`` is True
    (all cells when ``None``); cells outside the mask and -inf values get 0.

    Raises
    ------
    ValueError
        NaN or +inf values in the mask, or no cell with a finite value.
    """
    lv = np.asarray(logvals, float)
    use = np.ones(lv.shape, bool) if mask is None else np.asarray(mask, bool)
    vals = lv[use]
    if np.any(np.isnan(vals)) or np.any(vals == np.inf):
        raise ValueError("log-density values must be finite or -inf (found NaN or +inf)")
    if not np.any(np.isfinite(vals)):
        raise ValueError("no cell has a finite log-density")
    w = np.zeros(lv.shape)
    w[use] = np.exp(vals - np.max(vals[np.isfinite(vals)]))
    return w / w.sum()


def hellinger(p: np.ndarray, q: np.ndarray) -> float:
    """Hellinger distance sqrt(1 - sum sqrt(p q)) of two normalized weight arrays
    (0: identical, 1: disjoint supports)."""
    bc = float(np.sum(np.sqrt(np.asarray(p, float) * np.asarray(q, float))))
    return float(np.sqrt(max(0.0, 1.0 - bc)))


def grid_moments(E: np.ndarray, nu: np.ndarray, logpost: np.ndarray,
                 mask: np.ndarray | None = None) -> dict[str, Any]:
    """Mean, sd, covariance, correlation and mode of (E, nu) under the normalized grid
    density, and ``sd_conditional``: per parameter, sqrt of the mean (over the other
    parameter's marginal) of its conditional variance."""
    w = normalized_weights(logpost, mask)
    X = grid_points(E, nu)
    wf = w.ravel()
    mean = wf @ X
    cov = (X - mean).T @ ((X - mean) * wf[:, None])
    sd = np.sqrt(np.diag(cov))
    k = int(np.argmax(wf))
    # sd of each parameter given the other, averaged over the other's marginal: the
    # width across a ridge along each grid axis (what the grid spacing must resolve)
    axes = (np.asarray(E, float), np.asarray(nu, float))
    sd_cond = []
    for d in range(2):
        wd = w if d == 0 else w.T  # (n_d, n_other)
        marg = wd.sum(axis=0)
        use = marg > 0
        c = wd[:, use] / marg[use]
        m = axes[d] @ c
        var = ((axes[d][:, None] - m) ** 2 * c).sum(axis=0)
        sd_cond.append(float(np.sqrt(marg[use] @ var)))
    return {"mean": mean.tolist(), "sd": sd.tolist(), "cov": cov.tolist(),
            "corr": float(cov[0, 1] / (sd[0] * sd[1])) if sd.all() else float("nan"),
            "sd_conditional": sd_cond, "mode": X[k].tolist()}


def hellinger_to_reference(
    logpost_fn_or_values: Callable[[np.ndarray], Any] | np.ndarray,
    ref_path: str | Path = DEFAULT_PATH,
    *,
    grid: str | None = None,
    exclude_failed: bool = True,
) -> float:
    """Hellinger distance between a posterior and the reference, on the reference grid.

    Parameters
    ----------
    logpost_fn_or_values
        Either a callable taking an ``(M, 2)`` array of points (columns E, nu in user
        units, as :func:`grid_points`) and returning their ``(M,)`` unnormalized log
        posterior (with the study's uniform prior the log-likelihood will do, e.g. a
        surrogate's ``gp.predict``; a returned tuple's first item is used), or the
        values already evaluated on the grid, shape ``(nE, nnu)`` or ``(nE * nnu,)``.
    ref_path
        The reference ``.npz``.
    grid
        Which grid of the file (see :func:`load_reference`); ``None``: the recommended one.
    exclude_failed
        Leave out the cells where the reference solve failed, from both densities
        (their likelihood is unknown, not zero). With ``False`` they count as zero
        reference density.

    Returns
    -------
    float
        In [0, 1]. On a zoomed grid both densities are normalized on the zoom box
        (their mass outside it is ignored).
    """
    ref = load_reference(ref_path, grid)
    shape = ref["loglik"].shape
    if callable(logpost_fn_or_values):
        out = logpost_fn_or_values(grid_points(ref["E"], ref["nu"]))
        if isinstance(out, tuple):
            out = out[0]
        values = np.asarray(out, float)
    else:
        values = np.asarray(logpost_fn_or_values, float)
    if values.size != int(np.prod(shape)):
        raise ValueError(f"expected {int(np.prod(shape))} values on the {shape} grid, "
                         f"got shape {values.shape}")
    values = values.reshape(shape)
    mask = ~ref["failed"] if exclude_failed else None
    p = normalized_weights(ref["loglik"], mask)
    q = normalized_weights(values, mask)
    return hellinger(p, q)
