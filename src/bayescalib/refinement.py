"""Posterior-targeted refinement of the design (sequential design rounds).

The scrambled Sobol design spreads the training points over the whole prior box
(paper Sec. 3.3: all emphasis on exploration). When the likelihood is sharp against
the box, few points fall where the posterior lives and the GP surrogate of the
log-likelihood can put a confident but spurious mode between training points. The
paper names the remedy: refine the samples in high posterior regions. One round of
refinement

1. resamples the current SMC particles (systematic resampling) and smooths the draws
   with a Gaussian kernel whose width per parameter is one posterior standard deviation,
   but at least ``min_bandwidth`` of the box width (so a spuriously narrow posterior
   still gets points around it, not on top of each other);
2. picks ``n`` of these candidates greedily by maximin distance (in box-normalized
   coordinates) to the existing design points and to the points already picked, so
   the new points fill the posterior region where the design is thin.

The new points are solved and added to the training table; the surrogate is refitted
and SMC rerun. A spurious surrogate mode is killed by the real log-likelihood at the
points placed on it, and the next round targets the corrected posterior.
"""

from __future__ import annotations

import numpy as np

from bayescalib.resampling import systematic_resample

__all__ = ["refinement_points"]


def refinement_points(
    particles: np.ndarray,
    weights: np.ndarray,
    n: int,
    bounds: np.ndarray,
    rng: np.random.Generator,
    design: np.ndarray | None = None,
    *,
    min_bandwidth: float = 0.02,
    pool_factor: int = 50,
) -> np.ndarray:
    """New design points in the posterior region (see the module docstring).

    Parameters
    ----------
    particles
        Final SMC particles, shape (N, d), in the parameters' units.
    weights
        Their normalized weights, shape (N,).
    n
        Number of points to return (>= 1).
    bounds
        Box of the design, shape (d, 2); points are kept inside it.
    rng
        Random generator (resampling and kernel draws).
    design
        Existing design points, shape (m, d), that the new points keep away from.
    min_bandwidth
        Lower bound of the kernel width, as a fraction of each box width.
    pool_factor
        Candidates drawn per returned point.

    Returns
    -------
    numpy.ndarray
        Shape (n, d), distinct, inside ``bounds``.
    """
    X = np.atleast_2d(np.asarray(particles, dtype=float))
    W = np.asarray(weights, dtype=float)
    b = np.asarray(bounds, dtype=float)
    n = int(n)
    if n < 1:
        raise ValueError(f"refinement: n must be >= 1, got {n}")
    if X.ndim != 2 or b.shape != (X.shape[1], 2):
        raise ValueError(f"refinement: particles (N, d) and bounds (d, 2) expected, got "
                         f"{X.shape} and {b.shape}")
    if W.shape != (X.shape[0],) or not np.all(np.isfinite(W)) or W.min() < 0 or W.sum() <= 0:
        raise ValueError("refinement: weights must be finite, non-negative, one per particle")
    if not 0 < min_bandwidth < 1:
        raise ValueError(f"refinement: min_bandwidth must be in (0, 1), got {min_bandwidth}")
    W = W / W.sum()
    lo, width = b[:, 0], b[:, 1] - b[:, 0]
    U = (X - lo) / width
    mean = W @ U
    sd = np.sqrt(np.maximum(W @ (U - mean) ** 2, 0.0))
    bw = np.maximum(sd, min_bandwidth)
    m = max(int(pool_factor), 1) * n
    pool = U[systematic_resample(W, rng, m)] + rng.standard_normal((m, U.shape[1])) * bw
    pool = np.clip(pool, 0.0, 1.0)
    if design is not None and np.size(design):
        old = (np.atleast_2d(np.asarray(design, dtype=float)) - lo) / width
        dmin = np.min(np.linalg.norm(pool[:, None, :] - old[None, :, :], axis=2), axis=1)
    else:
        dmin = np.full(m, np.inf)
    picked: list[int] = []
    for _ in range(n):
        # first pick without a design: the candidate nearest the posterior mean
        k = int(np.argmin(np.linalg.norm(pool - mean, axis=1))) if np.all(np.isinf(dmin)) \
            else int(np.argmax(dmin))
        picked.append(k)
        dmin = np.minimum(dmin, np.linalg.norm(pool - pool[k], axis=1))
    return lo + pool[picked] * width
