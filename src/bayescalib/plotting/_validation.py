"""Input validation and figure output shared by the plotting modules.

All public plotting functions take plain arrays; the helpers here turn them
into validated float arrays and raise :class:`ValueError` with a message that
names the offending argument (shape mismatch, NaN/inf, negative weights,
inverted bounds, unknown output format). :func:`save_figure` writes one figure
to any number of paths, the format taken from each suffix.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib.figure import Figure

from bayescalib.inference.weights import normalize_weights
from bayescalib.io._atomic_write import atomic_path

__all__ = [
    "PathsLike",
    "as_array",
    "as_bounds",
    "as_levels",
    "as_names_units",
    "as_paths",
    "as_points",
    "as_samples",
    "as_weights",
    "finish",
    "save_figure",
]

PathsLike = str | os.PathLike | Sequence[str | os.PathLike]

_SUPPORTED = {"png", "pdf", "svg", "eps", "ps", "jpg", "jpeg", "tif", "tiff", "webp", "pgf"}


def as_array(x: Any, name: str, *, ndim: int | None = None, shape: tuple | None = None,
             finite: bool = True) -> np.ndarray:
    """Convert ``x`` to a float array and check its dimensions and values.

    Parameters
    ----------
    x : array_like
        Input.
    name : str
        Argument name used in error messages.
    ndim : int, optional
        Required number of dimensions.
    shape : tuple, optional
        Required shape; ``None`` entries are free.
    finite : bool
        Reject NaN and infinite entries.

    Returns
    -------
    numpy.ndarray
        Float array.
    """
    try:
        a = np.asarray(x, dtype=float)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name}: cannot convert to a float array ({exc})") from None
    if ndim is not None and a.ndim != ndim:
        raise ValueError(f"{name}: expected a {ndim}-D array, got shape {a.shape}")
    if shape is not None and (
            a.ndim != len(shape) or any(s is not None and s != t for s, t in zip(shape, a.shape))):
        want = "(" + ", ".join("*" if s is None else str(s) for s in shape) + \
            ("," if len(shape) == 1 else "") + ")"
        raise ValueError(f"{name}: expected shape {want}, got {a.shape}")
    if finite and not np.all(np.isfinite(a)):
        raise ValueError(f"{name}: contains NaN or infinite values")
    return a


def as_points(x: Any, name: str, *, allow_empty: bool = True) -> np.ndarray:
    """Validate an (n, 2) array of 2-D points; ``None`` gives an empty (0, 2) array."""
    if x is None:
        return np.zeros((0, 2))
    a = np.asarray(x, dtype=float) if np.size(x) else np.zeros((0, 2))
    a = as_array(a, name, shape=(None, 2))
    if not allow_empty and a.shape[0] == 0:
        raise ValueError(f"{name}: must contain at least one point")
    return a


def as_samples(samples: Any, name: str = "samples", *, dim: int | None = None,
               min_dim: int = 1, max_dim: int | None = None) -> np.ndarray:
    """Validate particle positions of shape (N, d).

    Parameters
    ----------
    samples : array_like, shape (N, d)
        Particles, one row per particle, in user units.
    name : str
        Argument name for error messages.
    dim : int, optional
        Required d.
    min_dim, max_dim : int
        Allowed range of d.

    Returns
    -------
    numpy.ndarray, shape (N, d)
    """
    a = as_array(samples, name, ndim=2)
    n, d = a.shape
    if n < 2:
        raise ValueError(f"{name}: need at least 2 particles, got {n}")
    if dim is not None and d != dim:
        raise ValueError(f"{name}: expected {dim} columns (parameters), got {d}")
    if d < min_dim or (max_dim is not None and d > max_dim):
        raise ValueError(f"{name}: number of parameters {d} outside [{min_dim}, {max_dim}]")
    return a


def as_weights(weights: Any, n: int, name: str = "weights") -> np.ndarray:
    """Validate particle weights and normalize them to sum to one.

    Parameters
    ----------
    weights : array_like, shape (N,) or None
        Non-negative weights; ``None`` means equal weights.
    n : int
        Number of particles N.
    name : str
        Argument name for error messages.

    Returns
    -------
    numpy.ndarray, shape (N,)
        Weights summing to one.
    """
    return normalize_weights(weights, n, name)


def as_names_units(names: Sequence[str], units: Sequence[str],
                   d: int) -> tuple[list[str], list[str]]:
    """Check that there is one name and one unit per parameter."""
    if isinstance(names, str) or isinstance(units, str):
        raise TypeError("names and units must be sequences of strings, one per parameter")
    names, units = [str(s) for s in names], [str(s) for s in units]
    if len(names) != d:
        raise ValueError(f"names: expected {d} names, got {len(names)}")
    if len(units) != d:
        raise ValueError(f"units: expected {d} units, got {len(units)}")
    return names, units


def as_bounds(bounds: Any, d: int, data: np.ndarray | None = None,
              pad: float = 0.05) -> np.ndarray:
    """Validate per-parameter bounds or derive them from data.

    Parameters
    ----------
    bounds : array_like, shape (d, 2) or None
        ``(lo, hi)`` per parameter in user units, ``lo < hi``.
    d : int
        Number of parameters.
    data : numpy.ndarray, shape (N, d), optional
        Used when ``bounds`` is None: data range padded by ``pad`` of its width.
    pad : float
        Relative padding for data-derived bounds.

    Returns
    -------
    numpy.ndarray, shape (d, 2)
    """
    if bounds is None:
        if data is None:
            raise ValueError("bounds: required when no data are given")
        lo, hi = data.min(axis=0), data.max(axis=0)
        width = hi - lo
        width = np.where(width > 0, width, np.maximum(np.abs(lo), 1.0))
        return np.column_stack([lo - pad * width, hi + pad * width])
    b = as_array(bounds, "bounds", shape=(d, 2))
    if np.any(b[:, 1] <= b[:, 0]):
        raise ValueError(f"bounds: every row must satisfy lo < hi, got {b.tolist()}")
    return b


def as_paths(paths: PathsLike) -> list[Path]:
    """Normalize one path or a sequence of paths and check their formats.

    Parameters
    ----------
    paths : str, os.PathLike or sequence of them
        Output files; the suffix selects the format (``.png``, ``.pdf``, ...).

    Returns
    -------
    list of pathlib.Path
    """
    if isinstance(paths, (str, os.PathLike)):
        paths = [paths]
    out = [Path(p) for p in paths]
    for p in out:
        fmt = p.suffix.lower().lstrip(".")
        if fmt not in _SUPPORTED:
            raise ValueError(f"paths: unsupported output format {p.suffix!r} for {p} "
                             f"(use one of {sorted(_SUPPORTED)})")
    return out


def as_levels(levels: Sequence[float], name: str = "levels") -> np.ndarray:
    """Validate probability levels: strictly inside (0, 1), returned sorted ascending."""
    lv = as_array(levels, name, ndim=1)
    if lv.size == 0:
        raise ValueError(f"{name}: need at least one probability level")
    if np.any((lv <= 0) | (lv >= 1)):
        raise ValueError(f"{name}: probability levels must lie in (0, 1), got {lv.tolist()}")
    return np.sort(lv)


def save_figure(fig: Figure, paths: PathsLike, dpi: float = 200) -> list[Path]:
    """Write ``fig`` to every path (parent folders are created).

    Parameters
    ----------
    fig : matplotlib.figure.Figure
        Figure to write.
    paths : str, os.PathLike or sequence of them
        Output files; the format follows the suffix.
    dpi : float
        Resolution for raster formats [dots per inch].

    Returns
    -------
    list of pathlib.Path
        The written paths.
    """
    out = as_paths(paths)
    for p in out:
        with atomic_path(p, suffix=p.suffix) as tmp:
            fig.savefig(tmp, dpi=dpi, format=p.suffix.lower().lstrip("."))
    return out


def finish(fig: Figure, paths: PathsLike, dpi: float, return_figure: bool):
    """Save, then either release the figure or hand it back.

    Returns
    -------
    list of pathlib.Path, or (list of pathlib.Path, Figure) when ``return_figure``
    """
    out = save_figure(fig, paths, dpi)
    if return_figure:
        return out, fig
    fig.clear()
    return out
