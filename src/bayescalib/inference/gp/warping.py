"""The GP's output transform: the log-misfit warping of the log-likelihood.

Log-misfit warping (``bound``; the default of the pipeline)
    The Gaussian log-likelihood (eq. loglik) is L = B - Phi with the known
    upper bound B = -n/2 log(2 pi sigma_N^2) and the misfit Phi = D^2 / (2
    sigma_N^2) >= 0. With ``bound=B`` the GP models the warped output
    g = log(1 + Phi) = log(1 + B - L) instead of L (:func:`log_misfit`), and
    predictions map back through L = B - expm1(max(g, 0))
    (:func:`loglik_from_log_misfit`). Hence (i) the surrogate never exceeds the
    bound, so neither does the SMC log-evidence; (ii) the many orders of
    magnitude that Phi spans over a prior box (sharply peaked likelihoods) are
    compressed to a few units of g, where a stationary GP fits well; (iii) far
    from the data the GP reverts to its constant mean, which is placed *above*
    the largest g (m = max(g) + f_m (max(g) - min(g)), :func:`~bayescalib.inference.gp.fit.fit_gp`):
    a low likelihood, never a spurious mode between training points. This is the
    log-discrepancy model of GP-accelerated ABC (Wilkinson 2014; Jarvenpaa et al.
    2018), applied to the Gaussian likelihood's misfit. The latent variance maps to
    the likelihood scale by the delta method, var(L) = exp(2 g) var(g)
    (:func:`latent_variance_to_loglik`).

Evidence of the log-likelihood values
    A warped GP's evidence is that of the values g. Carried to the units of L by the
    Jacobian of the warping, log p(L) = log p(g) + sum_i log|dg/dL|_i = log p(g) -
    sum_i g_i (warped GPs, Snelson et al. 2004; :func:`evidence_of_loglik`), so that the
    search of the discrete choices compares the evidences of GPs of g and of L like with
    like (:func:`~bayescalib.inference.gp.selection.fit_from_config`).

Without a bound the GP models L itself (the paper's surrogate, uncapped); with a bound
and ``warp=False`` it models L and its predictions are capped at B
(:meth:`~bayescalib.inference.gp.predictor.GPSurrogate.loglik_from_latent`).
"""

from __future__ import annotations

import numpy as np

__all__ = ["evidence_of_loglik", "latent_variance_to_loglik", "log_misfit",
           "loglik_from_log_misfit"]


def log_misfit(L: np.ndarray, bound: float) -> np.ndarray:
    """The warped output g = log(1 + B - L) of log-likelihoods L (any shape); values above
    the bound B (round-off) count as g = 0."""
    return np.log1p(np.maximum(bound - L, 0.0))


def loglik_from_log_misfit(g: np.ndarray, bound: float) -> np.ndarray:
    """Log-likelihoods L = B - expm1(max(g, 0)) of warped values g (never above B)."""
    return bound - np.expm1(np.maximum(g, 0.0))


def latent_variance_to_loglik(g: np.ndarray, var_g: np.ndarray) -> np.ndarray:
    """The variance of L from the latent mean g and variance var_g of the warped GP (delta
    method): var(L) = exp(2 max(g, 0)) var(g)."""
    return np.exp(2.0 * np.maximum(g, 0.0)) * var_g


def evidence_of_loglik(log_evidence: float, y: np.ndarray, warped: bool) -> float:
    """The log evidence of the log-likelihood values of a GP with log evidence
    ``log_evidence`` and targets ``y``: for the log-misfit GP (``warped``) carried to L by
    the warping's Jacobian, log p(g) - sum_i g_i; otherwise unchanged."""
    return log_evidence - (float(np.sum(y)) if warped else 0.0)
