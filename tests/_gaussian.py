"""A correlated 2-D Gaussian in (E, nu) and a weighted importance sample of it: the
analytic reference of the weights and plotting tests."""

from __future__ import annotations

import numpy as np

MEAN = np.array([400.0, 0.1])
COV = np.array([[80.0**2, 0.8 * 80.0 * 0.15], [0.8 * 80.0 * 0.15, 0.15**2]])


def importance_sample(n: int = 1500, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Draws from a 1.5x wider Gaussian, weighted to N(MEAN, COV): (n, 2) and (n,)."""
    rng = np.random.default_rng(seed)
    prop_cov = 2.25 * COV
    x = rng.multivariate_normal(MEAN, prop_cov, size=n)
    ic, ip = np.linalg.inv(COV), np.linalg.inv(prop_cov)
    d = x - MEAN
    logw = -0.5 * np.einsum("ni,ij,nj->n", d, ic, d) + 0.5 * np.einsum("ni,ij,nj->n", d, ip, d)
    w = np.exp(logw - logw.max())
    return x, w / w.sum()
