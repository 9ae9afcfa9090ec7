"""Sequential Monte Carlo with adaptive tempering (paper Sec. 3.1, Algorithm alg:smc).

The sampler moves N weighted particles from the prior p(x) to the posterior
through the tempered densities of eq. (transition)

    pi_gamma(x)  proportional to  exp(gamma * log L(x)) * p(x),   0 = gamma_0 < ... < gamma_S = 1.

One step s (Algorithm alg:smc):

1. **Adaptive tempering.** Find gamma_s in (gamma_{s-1}, 1] such that the
   effective sample size (eq. ess) of the reweighted particles equals
   ``zeta * ESS_{s-1}``. ESS is a continuous, decreasing function of gamma, so
   ``scipy.optimize.brentq`` brackets the root on (gamma_{s-1}, 1]; if even
   gamma = 1 keeps ESS above the target (no root below 1), gamma_s = 1.
   Particles whose log-likelihood is -inf (outside the likelihood's support,
   e.g. failed regions) get weight zero for any gamma > 0; ``ESS_{s-1}`` is
   therefore measured over the particles with finite log-likelihood so that
   the root is well defined.
2. **Reweighting.** w_i <- w_i * exp((gamma_s - gamma_{s-1}) log L(x_i)).
   The log-evidence accumulates log sum_i W_i exp((gamma_s - gamma_{s-1}) log L(x_i))
   (W normalized weights before the step): the log of the weighted mean
   incremental weight; the sum over steps estimates log Z = log int L p dx.
3. **Resampling** when ESS < ess_min_ratio * N: *systematic* resampling
   (:mod:`bayescalib.inference.resampling`), weights reset to 1/N.
4. **Rejuvenation.** ``n_rej`` random-walk Metropolis-Hastings sweeps that
   leave pi_gamma_s invariant, applied to every particle (weights unchanged).
   Proposal x' = x + N(0, c^2 (2.38^2 / d) Sigma), with Sigma the weighted
   particle covariance at this step and, following Minson et al. (2013,
   CATMIP), c = a + b * acc, a = 1/9, b = 8/9, where acc is the mean
   (weighted) acceptance rate of the previous step's sweeps (acc = 1 before the
   first step, i.e. the classic 2.38^2/d scale). Proposals outside the prior
   support are rejected without evaluating the likelihood; -inf log-likelihood
   or log-prior never produces NaN (a move from a -inf state to a finite one is
   always accepted, a move to a -inf state never).
5. Repeat until gamma = 1 (the last step always ends at gamma = 1 and is
   rejuvenated as well); the returned weights are normalized.

The random stream is the ``numpy.random.Generator`` passed in: the same seed
and the same deterministic ``loglik`` give bitwise identical results.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np
from scipy.special import logsumexp

from bayescalib.inference.resampling import systematic_resample
from bayescalib.inference.weights import ess, log_ess, normalize_log_weights

__all__ = ["MINSON_A", "MINSON_B", "SMCResult", "next_gamma", "run_smc", "smc_from_config",
           "weighted_cov"]

log = logging.getLogger(__name__)

MINSON_A = 1.0 / 9.0
MINSON_B = 8.0 / 9.0


class PriorLike(Protocol):  # pragma: no cover - typing only
    def logprior(self, X: np.ndarray) -> np.ndarray: ...

    def sample_prior(self, n: int, rng: np.random.Generator) -> np.ndarray: ...


@dataclass
class SMCResult:
    """Final particle approximation of the posterior (eq. smcdirac).

    Attributes
    ----------
    particles : (N, d) particle positions in user units.
    weights : (N,) normalized weights.
    loglik : (N,) log-likelihood at the particles.
    logprior : (N,) log prior (box-truncated) at the particles.
    log_evidence : SMC estimate of log Z = log int L(x) p(x) dx.
    history : dict of (n_steps,) arrays: ``gamma``, ``ess`` (after reweighting,
        before resampling), ``resampled`` (bool), ``acceptance`` (weighted mean
        MH acceptance rate of the step), ``scale`` (c^2 * 2.38^2/d used in the
        step), ``log_evidence_increment``, ``n_loglik_evals``, ``time_s``.
    n_steps : number of tempering steps.
    n_loglik_evals : total number of points the log-likelihood was evaluated at.
    names : parameter names (column order).
    """

    particles: np.ndarray
    weights: np.ndarray
    loglik: np.ndarray
    logprior: np.ndarray
    log_evidence: float
    history: dict[str, np.ndarray]
    n_steps: int
    n_loglik_evals: int = 0
    names: list[str] = field(default_factory=list)

    @property
    def log_posterior(self) -> np.ndarray:
        """Unnormalized log posterior log L + log p at the particles, (N,)."""
        with np.errstate(invalid="ignore"):
            out = self.loglik + self.logprior
        return np.where(np.isnan(out), -np.inf, out)

    @property
    def ess(self) -> float:
        return ess(self.weights)


# ---------------------------------------------------------------------------
# building blocks (pure functions)
# ---------------------------------------------------------------------------


def _tempered(ll: np.ndarray, gamma: float) -> np.ndarray:
    """gamma * log L with the convention 0 * (-inf) = 0 and gamma * (-inf) = -inf."""
    fin = np.isfinite(ll)
    if gamma == 0.0:
        return np.zeros_like(ll)
    return np.where(fin, gamma * np.where(fin, ll, 0.0), -np.inf)


def next_gamma(ll: np.ndarray, logw: np.ndarray, gamma: float, zeta: float) -> float:
    """Next temperature (paper Algorithm alg:smc): ESS(gamma') = zeta * ESS_alive.

    Parameters
    ----------
    ll : (N,) log-likelihood (may hold -inf).
    logw : (N,) current log weights.
    gamma : current temperature.
    zeta : target ratio of consecutive ESS, in (0, 1).

    Returns
    -------
    float
        gamma' in (gamma, 1]; 1.0 if no gamma' < 1 reaches the target.
    """
    fin = np.isfinite(ll)
    if not np.any(fin & np.isfinite(logw)):
        raise ValueError("no particle has a finite log-likelihood and non-zero weight")
    llf = ll[fin]
    lwf = logw[fin]
    log_target = np.log(zeta) + log_ess(lwf)

    def f(g: float) -> float:
        return log_ess(lwf + (g - gamma) * llf) - log_target

    if f(1.0) >= 0.0:
        return 1.0
    # imported here: the jobs that read particles only (bayescalib.inference.posterior,
    # e.g. the predictive solves in the point job server) need no scipy.optimize
    from scipy.optimize import brentq

    return float(brentq(f, gamma, 1.0, xtol=1e-14, rtol=4 * np.finfo(float).eps, maxiter=500))


def weighted_cov(X: np.ndarray, W: np.ndarray) -> np.ndarray:
    """Weighted covariance (d, d) of particles X (N, d) with normalized weights W (N,).

    Uses the reliability-weights correction 1 / (1 - sum W^2) (unbiased for
    equal weights).
    """
    mu = W @ X
    Xc = X - mu
    denom = 1.0 - np.sum(W * W)
    if denom <= 0:
        denom = 1.0
    return (Xc * W[:, None]).T @ Xc / denom


def _proposal_factor(cov: np.ndarray, scale2: float, bounds_width: np.ndarray | None) -> np.ndarray:
    """Lower-triangular L with L L^T = scale2 * cov, regularized if not positive definite."""
    d = cov.shape[0]
    C = scale2 * np.atleast_2d(cov)
    jitter_ref = (bounds_width**2 if bounds_width is not None else np.ones(d)) * 1e-12
    try:
        return np.linalg.cholesky(C + np.diag(jitter_ref))
    except np.linalg.LinAlgError:
        vals, vecs = np.linalg.eigh(0.5 * (C + C.T))
        floor = max(vals.max() * 1e-10, 0.0) + jitter_ref.max()
        vals = np.maximum(vals, floor)
        return np.linalg.cholesky((vecs * vals) @ vecs.T)


def _safe_loglik(loglik: Callable[[np.ndarray], np.ndarray], X: np.ndarray) -> np.ndarray:
    out = np.asarray(loglik(X), dtype=float).reshape(-1)
    if out.shape[0] != X.shape[0]:
        raise ValueError(f"loglik returned {out.shape[0]} values for {X.shape[0]} points")
    # NaN (e.g. a failed evaluation) and +inf are treated as "no support"
    return np.where(np.isnan(out) | (out == np.inf), -np.inf, out)


def mh_sweeps(
    X: np.ndarray,
    ll: np.ndarray,
    lp: np.ndarray,
    gamma: float,
    chol: np.ndarray,
    n_sweeps: int,
    loglik: Callable[[np.ndarray], np.ndarray],
    logprior: Callable[[np.ndarray], np.ndarray],
    rng: np.random.Generator,
    W: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, float, int]:
    """``n_sweeps`` random-walk MH sweeps targeting pi_gamma for all particles.

    Returns
    -------
    X, ll, lp : updated copies.
    acc : weighted mean acceptance rate over the sweeps.
    n_evals : number of loglik evaluations (proposals inside the prior support).
    """
    X, ll, lp = X.copy(), ll.copy(), lp.copy()
    N, d = X.shape
    acc_sum = 0.0
    n_evals = 0
    # the current particles' tempered log target, kept up to date on acceptance
    # (elementwise, so bitwise the values recomputing it every sweep would give)
    t_old = _tempered(ll, gamma) + lp
    old_ok = np.isfinite(t_old)
    t_old_0 = np.where(old_ok, t_old, 0.0)  # 0 where -inf (then log alpha = +inf)
    for _ in range(n_sweeps):
        Xp = X + rng.standard_normal((N, d)) @ chol.T
        log_u = np.log(rng.random(N))
        lpp = logprior(Xp)
        # a proposal outside the prior support is rejected (log alpha = -inf): the
        # likelihood and the acceptance test are evaluated at the others only
        idx = np.flatnonzero(np.isfinite(lpp))
        if idx.size == 0:
            continue
        Xi = Xp if idx.size == N else np.take(Xp, idx, axis=0)
        llp = _safe_loglik(loglik, Xi)
        n_evals += int(idx.size)
        t_new = _tempered(llp, gamma) + np.take(lpp, idx)
        new_ok = np.isfinite(t_new)
        ok_i = np.take(old_ok, idx)
        diff = np.where(new_ok & ok_i, t_new - np.take(t_old_0, idx), 0.0)
        log_alpha = np.where(~new_ok, -np.inf, np.where(~ok_i, np.inf, diff))
        acc_i = np.take(log_u, idx) < log_alpha
        a = idx[acc_i]
        if a.size == 0:
            continue
        accept = np.zeros(N, dtype=bool)
        accept[a] = True
        X = np.where(accept[:, None], Xp, X)
        lp = np.where(accept, lpp, lp)
        ll[a] = llp[acc_i]
        old_ok[a] = True  # a proposal with a -inf target is never accepted
        t_old_0[a] = t_new[acc_i]
        acc_sum += float(W @ accept)
    return X, ll, lp, acc_sum / max(n_sweeps, 1), n_evals


# ---------------------------------------------------------------------------
# driver
# ---------------------------------------------------------------------------


def _prior_functions(space: Any):
    if hasattr(space, "logprior") and hasattr(space, "sample_prior"):
        return space.logprior, space.sample_prior
    if hasattr(space, "logpdf") and hasattr(space, "sample"):
        return space.logpdf, space.sample
    raise TypeError("space must provide logprior/sample_prior (ParameterSpace) or logpdf/sample")


def run_smc(
    loglik: Callable[[np.ndarray], np.ndarray],
    space: Any,
    *,
    n_particles: int,
    n_rej: int,
    zeta: float,
    ess_min_ratio: float = 0.5,
    rng: np.random.Generator,
    callback: Callable[[dict[str, Any]], None] | None = None,
    max_steps: int = 10000,
) -> SMCResult:
    """Run adaptive-tempering SMC (paper Algorithm alg:smc) on ``loglik`` and the prior of ``space``.

    Parameters
    ----------
    loglik
        Vectorized log-likelihood: X (M, d) in user units -> (M,). -inf (or NaN)
        marks points outside its support.
    space
        A :class:`~bayescalib.inference.parameters.ParameterSpace` (``logprior``,
        ``sample_prior``), or any object with ``logpdf(X)`` and ``sample(n, rng)``.
    n_particles
        N.
    n_rej
        Metropolis-Hastings sweeps per tempering step.
    zeta
        Target ESS ratio between consecutive steps, in (0, 1).
    ess_min_ratio
        Resample when ESS < ess_min_ratio * N.
    rng
        Random generator; the only source of randomness.
    callback
        Called after every step with a dict (step, gamma, ess, resampled,
        acceptance, scale, log_evidence, time_s).
    max_steps
        Safety limit on the number of tempering steps.

    Returns
    -------
    SMCResult

    Raises
    ------
    ValueError
        Bad arguments, or the log-likelihood is -inf at every prior draw.
    RuntimeError
        If gamma = 1 is not reached within ``max_steps`` steps.
    """
    if n_particles < 2:
        raise ValueError(f"n_particles must be >= 2, got {n_particles}")
    if n_rej < 0:
        raise ValueError(f"n_rej must be >= 0, got {n_rej}")
    if not 0.0 < zeta < 1.0:
        raise ValueError(f"zeta must lie in (0, 1), got {zeta}")
    if not 0.0 < ess_min_ratio <= 1.0:
        raise ValueError(f"ess_min_ratio must lie in (0, 1], got {ess_min_ratio}")
    logprior, sample_prior = _prior_functions(space)
    names = list(getattr(space, "names", []))
    bounds = getattr(space, "bounds", None)
    width = None if bounds is None else np.asarray(bounds)[:, 1] - np.asarray(bounds)[:, 0]

    t0 = time.perf_counter()
    N = int(n_particles)
    X = np.asarray(sample_prior(N, rng), dtype=float)
    if X.ndim == 1:
        X = X[:, None]
    d = X.shape[1]
    lp = np.asarray(logprior(X), dtype=float)
    ll = _safe_loglik(loglik, X)
    n_evals = N
    if not np.any(np.isfinite(ll)):
        raise ValueError("the log-likelihood is -inf (or NaN) at every prior draw")
    logw = np.zeros(N)
    gamma = 0.0
    log_z = 0.0
    acc = 1.0
    hist: dict[str, list] = {
        k: []
        for k in (
            "gamma",
            "ess",
            "resampled",
            "acceptance",
            "scale",
            "log_evidence_increment",
            "n_loglik_evals",
            "time_s",
        )
    }
    step = 0
    while gamma < 1.0:
        step += 1
        if step > max_steps:
            raise RuntimeError(
                f"SMC did not reach gamma = 1 within max_steps = {max_steps} (gamma = {gamma:.3g})"
            )
        g_new = next_gamma(ll, logw, gamma, zeta)
        # reweight (eq. transition) and accumulate the evidence
        incr = _tempered(ll, g_new - gamma)
        W_prev = normalize_log_weights(logw)
        with np.errstate(divide="ignore"):
            log_inc = float(logsumexp(np.log(W_prev) + incr))
        log_z += log_inc
        logw = logw + incr
        logw = logw - logsumexp(logw)
        gamma = g_new
        ess_now = float(np.exp(log_ess(logw)))
        resampled = ess_now < ess_min_ratio * N
        if resampled:
            idx = systematic_resample(np.exp(logw), rng)
            X, ll, lp = X[idx], ll[idx], lp[idx]
            logw = np.full(N, -np.log(N))
        W = np.exp(logw)
        # rejuvenate (Minson et al. 2013 scaling)
        scale2 = (2.38**2 / d) * (MINSON_A + MINSON_B * acc) ** 2
        evals_step = 0
        if n_rej > 0:
            chol = _proposal_factor(weighted_cov(X, W), scale2, width)
            X, ll, lp, acc, evals_step = mh_sweeps(
                X, ll, lp, gamma, chol, n_rej, loglik, logprior, rng, W
            )
            n_evals += evals_step
        elapsed = time.perf_counter() - t0
        for k, v in (
            ("gamma", gamma),
            ("ess", ess_now),
            ("resampled", resampled),
            ("acceptance", acc),
            ("scale", scale2),
            ("log_evidence_increment", log_inc),
            ("n_loglik_evals", evals_step),
            ("time_s", elapsed),
        ):
            hist[k].append(v)
        info = {
            "step": step,
            "gamma": gamma,
            "ess": ess_now,
            "resampled": resampled,
            "acceptance": acc,
            "scale": scale2,
            "log_evidence": log_z,
            "time_s": elapsed,
        }
        log.info(
            "SMC step %d: gamma=%.6g ESS=%.1f%s acc=%.3f scale=%.3g logZ=%.4f",
            step,
            gamma,
            ess_now,
            " (resampled)" if resampled else "",
            acc,
            scale2,
            log_z,
        )
        if callback is not None:
            callback(info)

    history = {k: np.asarray(v) for k, v in hist.items()}
    return SMCResult(
        particles=X,
        weights=np.exp(logw) / np.exp(logw).sum(),
        loglik=ll,
        logprior=lp,
        log_evidence=float(log_z),
        history=history,
        n_steps=step,
        n_loglik_evals=n_evals,
        names=names,
    )


def smc_from_config(loglik: Callable[[np.ndarray], np.ndarray], space: Any,
                    smc: dict[str, Any]) -> SMCResult:
    """:func:`run_smc` with the settings of a validated ``smc`` config section
    (its ``seed`` seeds the generator)."""
    return run_smc(loglik, space, n_particles=smc["n_particles"], n_rej=smc["n_rej"],
                   zeta=smc["zeta"], ess_min_ratio=smc["ess_min_ratio"],
                   max_steps=smc["max_steps"], rng=np.random.default_rng(smc["seed"]))
