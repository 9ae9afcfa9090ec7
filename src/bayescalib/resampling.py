"""Resampling of weighted particles (SMC, paper Algorithm alg:smc "Resample").

Systematic resampling is used throughout: one uniform draw u ~ U[0, 1/N) and
the N stratified points u + i/N are pushed through the inverse of the
cumulative weights. It is unbiased (E[#copies of i] = N w_i), costs O(N), and
has lower variance than multinomial resampling (Douc & Cappe 2005;
Chopin & Papaspiliopoulos 2020, ch. 9).
"""

from __future__ import annotations

import numpy as np

__all__ = ["ess", "normalize_log_weights", "systematic_resample"]


def normalize_log_weights(logw: np.ndarray) -> np.ndarray:
    """Normalized weights W (N,) from log weights (N,), robust to -inf entries.

    Raises
    ------
    ValueError
        If every weight is zero (all log weights -inf) or any is NaN/+inf.
    """
    logw = np.asarray(logw, dtype=float)
    if np.any(np.isnan(logw)) or np.any(logw == np.inf):
        raise ValueError("log weights contain NaN or +inf")
    m = np.max(logw)
    if not np.isfinite(m):
        raise ValueError("all particle weights are zero (log-likelihood -inf everywhere)")
    w = np.exp(logw - m)
    return w / w.sum()


def ess(logw: np.ndarray) -> float:
    """Effective sample size 1 / sum(W_i^2) (paper eq. ess) from log weights."""
    W = normalize_log_weights(logw)
    return float(1.0 / np.sum(W * W))


def systematic_resample(W: np.ndarray, rng: np.random.Generator, n: int | None = None) -> np.ndarray:
    """Indices (n,) of a systematic resample of normalized weights ``W`` (N,)."""
    W = np.asarray(W, dtype=float)
    n = W.size if n is None else int(n)
    cw = np.cumsum(W)
    cw[-1] = 1.0  # guard against round-off
    u = (rng.random() + np.arange(n)) / n
    idx = np.searchsorted(cw, u, side="right")
    return np.minimum(idx, W.size - 1)
