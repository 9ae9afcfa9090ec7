"""Resampling of weighted particles (SMC, paper Algorithm alg:smc "Resample").

Systematic resampling is used throughout: one uniform draw u ~ U[0, 1/N) and
the N stratified points u + i/N are pushed through the inverse of the
cumulative weights. It is unbiased (E[#copies of i] = N w_i), costs O(N), and
has lower variance than multinomial resampling (Douc & Cappe 2005;
Chopin & Papaspiliopoulos 2020, ch. 9).
"""

from __future__ import annotations

import numpy as np

__all__ = ["systematic_resample"]


def systematic_resample(W: np.ndarray, rng: np.random.Generator, n: int | None = None) -> np.ndarray:
    """Indices (n,) of a systematic resample of normalized weights ``W`` (N,)."""
    W = np.asarray(W, dtype=float)
    n = W.size if n is None else int(n)
    cw = np.cumsum(W)
    cw[-1] = 1.0  # guard against round-off
    u = (rng.random() + np.arange(n)) / n
    idx = np.searchsorted(cw, u, side="right")
    return np.minimum(idx, W.size - 1)
