"""Space-filling experimental design: scrambled Sobol sequences (paper Sec. 3.2).

The training inputs of the GP surrogate are the first ``n`` points of one
scrambled (Owen-scrambled, seeded) Sobol sequence over the box of (x, theta).

Prefix property
    Points are those of ``scipy.stats.qmc.Sobol(d, scramble=True, seed=seed)``
    and ``random(n)`` (bitwise: :func:`sobol_unit` computes them with NumPy alone,
    tested against scipy); the sequence is a deterministic function of ``seed``, so
    the first ``n`` points are identical for every larger ``n``. A study that
    raises ``n_train`` reuses all earlier forward solves.

Why not scipy.stats itself
    The workflow computes the design while Snakemake builds its DAG, before any job
    can start; importing ``scipy.stats`` there took 1-1.8 s on the development
    machine, most of the time of a dry run. :func:`sobol_unit` reproduces scipy's
    algorithm with NumPy: the direction numbers of Joe & Kuo (2008, criterion D(6),
    read from scipy's data file), the recurrence of Bratley & Fox (1988, Sec. 2),
    scipy's left linear matrix scramble and digital shift (Matousek 1998) drawn from
    a generator spawned from ``default_rng(seed)`` in scipy's order, and the Gray-code
    order of Antonov & Saleev (1979) for the points.

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

import importlib.util
import os
from functools import cache

import numpy as np

__all__ = ["scale_to_box", "sobol_design", "sobol_test_points", "sobol_unit"]


def _validate_bounds(bounds: np.ndarray) -> np.ndarray:
    b = np.asarray(bounds, dtype=float)
    if b.ndim != 2 or b.shape[1] != 2 or b.shape[0] < 1:
        raise ValueError(f"bounds must have shape (d, 2), got {b.shape}")
    if not np.all(np.isfinite(b)) or np.any(b[:, 0] >= b[:, 1]):
        raise ValueError(f"bounds must be finite with lo < hi in every row, got {b.tolist()}")
    return b


#: bits of the integers of the sequence (scipy's default): at most 2^30 points
_BITS = 30


@cache
def _direction_numbers() -> tuple[np.ndarray, np.ndarray]:
    """scipy's table of primitive polynomials (21201,) and initial direction numbers
    (21201, 18) (Joe & Kuo 2008, D(6)), read from its data file without importing
    scipy.stats."""
    spec = importlib.util.find_spec("scipy")
    if spec is None or spec.origin is None:  # pragma: no cover - scipy is a dependency
        raise ImportError("scipy is needed for the Sobol direction numbers")
    path = os.path.join(os.path.dirname(spec.origin), "stats", "_sobol_direction_numbers.npz")
    with np.load(path) as f:
        return f["poly"].astype(np.int64), f["vinit"].astype(np.int64)


def _direction_matrix(d: int, bits: int) -> np.ndarray:
    """Direction numbers v (d, bits) as integers of ``bits`` bits (scipy's
    ``_initialize_v``: the recurrence of Bratley & Fox 1988, Sec. 2)."""
    poly, vinit = _direction_numbers()
    if d > poly.shape[0]:
        raise ValueError(f"Sobol designs support at most {poly.shape[0]} dimensions, got {d}")
    v = np.zeros((d, bits), dtype=np.int64)
    if d == 0:
        return v
    v[0, :] = 1
    for k in range(1, d):
        p = int(poly[k])
        m = p.bit_length() - 1
        row = [int(x) for x in vinit[k, :m]] + [0] * (bits - m)
        for j in range(m, bits):
            new = row[j - m]
            pow2 = 1
            for i in range(m):
                pow2 <<= 1
                if (p >> (m - 1 - i)) & 1:
                    new ^= pow2 * row[j - i - 1]
            row[j] = new
        v[k] = row
    return v << (bits - 1 - np.arange(bits))


def sobol_unit(d: int, n: int, seed: int) -> np.ndarray:
    """First ``n`` points of the scrambled Sobol sequence in [0, 1)^d, shape (n, d).

    Bitwise the points of ``scipy.stats.qmc.Sobol(d, scramble=True,
    seed=np.random.default_rng(seed)).random(n)`` (module docstring), computed without
    importing scipy.stats.
    """
    if n < 0:
        raise ValueError(f"n must be >= 0, got {n}")
    if n > 2**_BITS:
        raise ValueError(f"at most 2**{_BITS} Sobol points, got n = {n}")
    bits = _BITS
    sv = _direction_matrix(d, bits)
    # scipy's engine draws its scrambling from a child of the generator it is given
    bg = np.random.default_rng(seed).bit_generator
    rng = np.random.Generator(type(bg)(bg.seed_seq.spawn(1)[0]))
    shift = (rng.integers(2, size=(d, bits), dtype=np.uint32).astype(np.int64)
             @ (1 << np.arange(bits, dtype=np.int64)))
    ltm = np.tril(rng.integers(2, size=(d, bits, bits), dtype=np.uint32)).astype(np.int64)
    ltm[:, np.arange(bits), np.arange(bits)] = 1
    # left linear matrix scramble: each direction number's bits (most significant
    # first) multiplied by the lower-triangular matrix, mod 2
    msb = bits - 1 - np.arange(bits)
    B = (sv[:, None, :] >> msb[None, :, None]) & 1  # (d, bit, direction number)
    sv = np.sum((np.einsum("dpk,dkj->dpj", ltm, B) % 2) << msb[None, :, None], axis=1)
    # point k is the shift XOR the direction numbers of the bits of k's Gray code
    k = np.arange(n, dtype=np.int64)
    gray = k ^ (k >> 1)
    q = np.repeat(shift[None, :], n, axis=0)
    for b in range(int(max(n - 1, 0)).bit_length()):
        on = ((gray >> b) & 1).astype(bool)
        q[on] ^= sv[None, :, b]
    return q * (1.0 / 2**bits)


def scale_to_box(U: np.ndarray, bounds: np.ndarray) -> np.ndarray:
    """Map unit-box points ``U`` (n, d) to the box ``bounds`` (d, 2)."""
    b = _validate_bounds(bounds)
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
    b = _validate_bounds(bounds)
    return scale_to_box(sobol_unit(b.shape[0], n, seed), b)


def sobol_test_points(bounds: np.ndarray, n_offset: int, n_test: int, seed: int) -> np.ndarray:
    """Points ``n_offset .. n_offset + n_test - 1`` of the same Sobol sequence, (n_test, d)."""
    b = _validate_bounds(bounds)
    U = sobol_unit(b.shape[0], n_offset + n_test, seed)[n_offset:]
    return scale_to_box(U, b)
