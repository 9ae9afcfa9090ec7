"""Space-filling experimental design: scrambled Sobol sequences (paper Sec. 3.2).

The training inputs of the GP surrogate are the first ``n`` points of one
scrambled (Owen-scrambled, seeded) Sobol sequence over the box of (x, theta).

Prefix property
    Points are drawn with ``scipy.stats.qmc.Sobol(d, scramble=True, seed=seed)``
    and ``random(n)``; the sequence is a deterministic function of ``seed``, so
    the first ``n`` points are identical for every larger ``n``. A study that
    raises ``n_train`` reuses all earlier forward solves.

Powers of two
    The balance (net) properties of Sobol points hold for n = 2^m (and for
    consecutive blocks of 2^m points). Other ``n`` are allowed -- the points
    are still a prefix of the same low-discrepancy sequence -- but lose those
    balance guarantees; scipy's warning about it is silenced here on purpose.

Held-out test points
    :func:`sobol_test_points` returns indices ``n_offset .. n_offset + n_test``
    of the *same* sequence ("later" Sobol points), used in the GP convergence
    study: they never coincide with training points as long as
    ``n_offset >= max(n_train)``.
"""

from __future__ import annotations

import warnings

import numpy as np
from scipy.stats import qmc

__all__ = ["scale_to_box", "sobol_design", "sobol_test_points", "sobol_unit"]


def _check_bounds(bounds: np.ndarray) -> np.ndarray:
    b = np.asarray(bounds, dtype=float)
    if b.ndim != 2 or b.shape[1] != 2 or b.shape[0] < 1:
        raise ValueError(f"bounds must have shape (d, 2), got {b.shape}")
    if not np.all(np.isfinite(b)) or np.any(b[:, 0] >= b[:, 1]):
        raise ValueError(f"bounds must be finite with lo < hi in every row, got {b.tolist()}")
    return b


def sobol_unit(d: int, n: int, seed: int) -> np.ndarray:
    """First ``n`` points of the scrambled Sobol sequence in [0, 1)^d, shape (n, d)."""
    if n < 0:
        raise ValueError(f"n must be >= 0, got {n}")
    engine = qmc.Sobol(d=d, scramble=True, seed=np.random.default_rng(seed))
    if n == 0:
        return np.empty((0, d))
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message=".*balance properties.*")
        return engine.random(n)


def scale_to_box(U: np.ndarray, bounds: np.ndarray) -> np.ndarray:
    """Map unit-box points ``U`` (n, d) to the box ``bounds`` (d, 2)."""
    b = _check_bounds(bounds)
    return b[:, 0] + np.asarray(U, dtype=float) * (b[:, 1] - b[:, 0])


def sobol_design(bounds: np.ndarray, n: int, seed: int) -> np.ndarray:
    """Scrambled Sobol design of ``n`` points over the box ``bounds``.

    Parameters
    ----------
    bounds
        (d, 2) lower/upper bounds in user units.
    n
        Number of points (powers of two keep the balance properties).
    seed
        Scrambling seed; the first ``n`` points never change when ``n`` grows.

    Returns
    -------
    np.ndarray
        (n, d) design points in user units.
    """
    b = _check_bounds(bounds)
    return scale_to_box(sobol_unit(b.shape[0], n, seed), b)


def sobol_test_points(bounds: np.ndarray, n_offset: int, n_test: int, seed: int) -> np.ndarray:
    """Points ``n_offset .. n_offset + n_test - 1`` of the same Sobol sequence, (n_test, d)."""
    b = _check_bounds(bounds)
    U = sobol_unit(b.shape[0], n_offset + n_test, seed)[n_offset:]
    return scale_to_box(U, b)
