"""Active design: rounds of solves placed where the posterior lives, a posterior
check with real solves as the stop rule's last test, and an honest stop rule.

Each kind of "check" here has its own name (trust check, check points, check round,
posterior check); docs/glossary.md says what each is and which keys name it.

The paper fixes the design in advance (Sec. 3.2: a scrambled Sobol sample over
the prior box) and names the remedy for sharp likelihoods in Sec. 3.3: refine
where the posterior lives. This module makes that a sequential design with a
stated convergence criterion. Round 0 is the Sobol design (``n_initial``
points). Each round r then

1. fits the GP surrogate of the log-likelihood on all solves so far (with the
   log-misfit warping of :mod:`bayescalib.inference.gp.warping`, so it never exceeds the
   likelihood's upper bound) and runs SMC on it (Algorithm 1);
2. checks the surrogate of round r-1 against the solves it asked for
   (:func:`trust_check`): their log-likelihoods were *predicted before they were
   solved*, so the errors are out of sample and lie where the posterior lives.
   Reported with every round and in the reason's words; it decides nothing (a
   pointwise maximum error: on the 7-D heterogeneous study its 1 nat was never met
   while the posterior was right);
3. measures how far the posterior moved since round r-1 (:func:`posterior_change`,
   in posterior standard deviations, plus a Gaussian Hellinger distance): the
   posterior is *settled* when the mean moved by at most ``shift_tol`` sd and every
   sd changed by at most ``sd_tol``;
4. applies the stop rule (below), and unless it stops picks the next batch of
   ``batch_size`` points (:func:`select_batch`) and adds ``check_points`` random
   ones (:func:`check_points`), all run as ordinary parallel solve jobs.

Stop rule. Once the posterior has been settled for ``patience`` rounds in a row,
or when only :data:`RESERVE_LOOKS` looks of the check (``posterior_check.batch``
solves each, at most ``posterior_check.draws``) of the budget ``max_solves`` are left
(the batches are cut to leave them), the next batch is a *check round*: that many equally
weighted draws of the current posterior (:func:`posterior_draws`, stratified by its
clusters, :func:`posterior_clusters`), with the surrogate's log-likelihood at each
recorded. They are solved as design points a look of ``posterior_check.batch`` at a
time (the first in the next round, the others waiting in the batch's ``check``), and
after each look the draws solved so far are judged by importance sampling
(:func:`round_posterior_check`, :func:`bayescalib.inference.importance.sequential_check`:
log-weights L - mu, their spread, ESS, the corrected mean and sd, and each cluster's
mass): confirmed, refuted, or undecided, when the next look's draws are solved in the
next round. Confirmed, and the posterior refitted with the draws added settled against
the checked one (its moments within the stop rule's tolerances, and, with several
clusters, their masses, by nearest cluster centre, within ``posterior_check.mass_tol``
of those confirmed: on bimodal2d seed 3 a refit with the 32 check draws moved 5 % of the
mass between the modes while its moments moved by less than 0.2 sd, and the run said
converged at Hellinger 0.16): **converged**. A check whose looks are undecided while the
posterior refitted with its draws has already moved away from the checked one (beyond
those tolerances) is *superseded*: confirming it could no longer make the run converge,
so its remaining draws are not solved, and the round counts towards the next settled
streak. Not confirmed (or moved): the draws stay in the training set (where
the posterior lives, they are the most useful solves the rounds can get), the
settled streak starts again, and the rounds go on; when the budget is spent the
run stops **NOT converged** and says why (the posterior reported is the last
round's). A check round that does not fit in the budget left is not run, and the
reason says so. With ``posterior_check.draws`` 0 there are no check rounds, and the trust
check decides in their place: converged when the posterior is settled and the
surrogate predicted the new solves in the posterior region within ``gp_tol`` nats for
``patience`` rounds in a row (said in the reason: not checked with real solves of its
draws). The diagnosis's calibrations run this way; their posteriors are tested with
real solves by the diagnosis's own predictive check.

Check points. The trust check can only test the surrogate where the batch goes,
and an uncertainty-driven batch goes where the surrogate is unsure. A surrogate
that is confident and wrong about the rim of its posterior (too narrow: between
the training points a GP reverts to a mean placed above every observed misfit)
is never tested there, and the trust check and the posterior check then both pass
on a posterior that is too narrow. Each batch therefore carries a few *check points*
(:func:`check_points`, batch kind ``"check"``): points drawn at random from the
posterior widened by its own spread, chosen without the surrogate; their
predictions enter the trust check like the others.

Acquisition (:func:`select_batch`). Candidates are drawn from the current
posterior (resampled SMC particles, jittered by half a posterior sd per
parameter, reflected into the box) and, as many, for exploring: half of them
jittered particles with one coordinate redrawn over its whole range (lines
through the posterior along each axis), half uniformly over the box. Most of
a batch exploits: each candidate is scored by the uncertainty of the
unnormalized posterior where it is large,

    log a(x) = log var_L(x) + k (mean_L(x) + log p(x)),   k = ``posterior_power``,

the GP variance of the log-likelihood weighted by the surrogate posterior
density to the power k. k = 1 (the default) weighs the posterior once. k = 2 is
the "prospective uncertainty sampling" of VBMC (Acerbi 2018), a_pro = s^2(x)
q(x) exp(f(x)) with the surrogate posterior in place of the variational q, i.e.
the variance of the unnormalized posterior exp(L) p by the delta method
(var_L exp(2 mean_L) p^2), which also underlies BAPE (Kandasamy et al. 2017) and
the batch rules of Jarvenpaa et al. (2019); GPry's LogExp acquisition (Gammal et
al. 2023) is the same form with k = 4 zeta, zeta = d^-0.85 (k = 2.2 in 2D, 1.2 in
4D). Measured on ``benchmarks/bench_active.py`` (issue 17, docs/bench_active.md):
with k = 1, 35-39 % of the exploiting picks on the curved ridge lay outside the
99 % posterior region, with k = 2 9 %, yet the posterior was not more accurate,
and on the two-lobe problem k = 2 never probed the weak lobe and stopped as
converged on the main one; k = 1 stays the default. A batch
is chosen greedily: after each pick, the GP variance of the remaining
candidates is conditioned on that point (the variance of a GP does not depend
on the value that will be observed, so this is exact for the variance; the mean
is kept, as in the "kriging believer"), so the batch spreads over the
uncertain posterior region instead of piling up at its maximum. A share
``explore_fraction`` of each batch explores: among the exploring candidates that
the surrogate cannot rule out of the posterior region (probability at least
``P_PLAUSIBLE`` that their log-likelihood lies within ``delta`` of the best
solve), the one of largest GP variance, again with conditioning. Exploitation
alone settles on the first mode it finds and can declare convergence on it; the
exploring points probe the rest of the box where posterior mass is still
possible, and a mode they hit shows as a large error in the next trust check.
Failed solves are conditioned on in the same way: the acquisition does not
return to a point whose solve failed, while the GP itself is fitted on the
successful solves only (a failure carries no value of the log-likelihood to
fit). The failures mark where the model cannot be solved
(:mod:`bayescalib.inference.feasibility`): the sampler's likelihood is zero there
(:meth:`~bayescalib.inference.gp.predictor.GPSurrogate.loglik`), and each batch gets
``boundary_points`` that bisect the gaps between failed and successful solves where the
posterior leans on them (:func:`boundary_points`), since the acquisition, treating the
failures as known, would not go there.

All functions are pure (arrays in, arrays or plain dicts out) and seeded. The rounds
themselves are driven in one place, :mod:`bayescalib.inference.rounds`, which calls
:func:`acquire_round` once per round (through its ``decide`` step; so do the
Snakemake rules of ``workflow/rules/active.smk``).
"""

from __future__ import annotations

import logging
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

__all__ = [
    "ACQUISITIONS",
    "PosteriorDraws",
    "SelectBatch",
    "StopRule",
    "acquire_round",
    "candidate_pool",
    "check_points",
    "posterior_change",
    "posterior_clusters",
    "posterior_draws",
    "posterior_moments",
    "round_posterior_check",
    "round_record",
    "select_batch",
    "trust_check",
]

log = logging.getLogger(__name__)

#: probability level of the posterior region in which the trust check tests the surrogate
REGION_LEVEL = 0.99
#: jitter of the posterior candidates, in posterior standard deviations
BANDWIDTH = 0.5
#: share of the candidate pool that explores (axis lines through the posterior, uniform)
POOL_UNIFORM = 0.5
#: smallest probability of lying in the posterior region for an exploring pick
P_PLAUSIBLE = 1e-3
#: exponent of the surrogate posterior in the score of exploring picks
EXPLORE_TEMPER = 0.3


# ------------------------------------------------------------------- posterior
def posterior_moments(particles: np.ndarray, weights: np.ndarray) -> dict[str, np.ndarray]:
    """Weighted mean (d,), covariance (d, d) and sd (d,) of SMC particles."""
    X = np.atleast_2d(np.asarray(particles, float))
    W = np.asarray(weights, float)
    W = W / W.sum()
    mean = W @ X
    R = X - mean
    cov = (R * W[:, None]).T @ R
    return {"mean": mean, "cov": cov, "sd": np.sqrt(np.maximum(np.diag(cov), 0.0))}


def _gaussian_distances(m0, C0, m1, C1) -> tuple[float, float]:
    """Hellinger distance and KL(N0 || N1) between two Gaussians (nan if singular)."""
    d = len(m0)
    try:
        C = 0.5 * (C0 + C1)
        s0, ld0 = np.linalg.slogdet(C0)
        s1, ld1 = np.linalg.slogdet(C1)
        s, ld = np.linalg.slogdet(C)
        if min(s0, s1, s) <= 0:
            return math.nan, math.nan
        dm = np.asarray(m1) - np.asarray(m0)
        bc = math.exp(0.25 * ld0 + 0.25 * ld1 - 0.5 * ld - 0.125 * dm @ np.linalg.solve(C, dm))
        h = math.sqrt(max(0.0, 1.0 - bc))
        C1inv = np.linalg.inv(C1)
        kl = 0.5 * (np.trace(C1inv @ C0) + dm @ C1inv @ dm - d + ld1 - ld0)
        return h, float(kl)
    except (np.linalg.LinAlgError, ValueError, OverflowError):
        return math.nan, math.nan


def posterior_change(previous: Mapping[str, Any], current: Mapping[str, Any]) -> dict[str, float]:
    """How far the posterior moved between two rounds.

    Parameters
    ----------
    previous, current
        Moments as returned by :func:`posterior_moments` (``mean``, ``cov``, ``sd``).

    Returns
    -------
    dict
        ``shift_sd``: max over parameters of |mean change| / sd, with the smaller of
        the two rounds' sds (a posterior that narrows spuriously does not hide its
        move); ``sd_change``: max over parameters of |sd ratio - 1| (ratio >= 1 taken
        both ways); ``hellinger`` and ``kl``: between the two rounds' moment-matched
        Gaussians (KL(current || previous)).
    """
    m0, m1 = np.asarray(previous["mean"], float), np.asarray(current["mean"], float)
    s0, s1 = np.asarray(previous["sd"], float), np.asarray(current["sd"], float)
    tiny = 1e-300
    shift = float(np.max(np.abs(m1 - m0) / np.maximum(np.minimum(s0, s1), tiny)))
    ratio = np.maximum(s1, tiny) / np.maximum(s0, tiny)
    sd_change = float(np.max(np.maximum(ratio, 1.0 / ratio)) - 1.0)
    h, kl = _gaussian_distances(m1, np.asarray(current["cov"], float), m0,
                                np.asarray(previous["cov"], float))
    return {"shift_sd": shift, "sd_change": sd_change, "hellinger": h, "kl": kl}


# ------------------------------------------------------------------ trust check
def trust_check(pred_mean: np.ndarray, pred_sd: np.ndarray, loglik: np.ndarray,
                loglik_best: float, dim: int, tol_nats: float) -> dict[str, Any]:
    """Out-of-sample check of the surrogate at the newly solved points.

    Parameters
    ----------
    pred_mean, pred_sd
        The surrogate's log-likelihood mean and sd at the new points, (q,), predicted
        *before* these points were solved.
    loglik
        Their real log-likelihoods, (q,) (-inf for failed solves).
    loglik_best
        Largest real log-likelihood of all solves so far.
    dim
        Number of parameters.
    tol_nats
        Tolerance on the prediction error in the posterior region (nats).

    Returns
    -------
    dict
        ``passed`` is true when at least one new point lies in the posterior region
        and every such point was predicted within ``tol_nats``. The posterior region
        is where the real *or* the predicted log-likelihood is within
        ``delta = chi2_{dim}(0.99) / 2`` of ``loglik_best`` (it holds 99 % of a
        Gaussian posterior's mass); a point the surrogate placed in the region but
        whose real value is far below (a spurious mode) counts with its full error.
        Also ``in_region`` (q,) bool, ``n_region``, ``max_abs_error`` and ``rms_error`` there (nats),
        ``coverage_2sd`` (share of region points within 2 predicted sd) and
        ``n_failed`` (failed solves among the new points; a failure where the
        surrogate put posterior mass is counted in ``n_failed_in_region``).
    """
    from scipy.stats import chi2

    mu = np.asarray(pred_mean, float)
    sd = np.asarray(pred_sd, float)
    L = np.asarray(loglik, float)
    delta = 0.5 * float(chi2.ppf(REGION_LEVEL, dim))
    ok = np.isfinite(L)
    top = np.where(ok, np.maximum(L, mu), mu)
    region = top >= loglik_best - delta
    in_region = region & ok
    err = np.where(ok, L - mu, np.nan)
    e = np.abs(err[in_region])
    out: dict[str, Any] = {
        "delta_nats": delta,
        "tol_nats": float(tol_nats),
        "n_points": int(L.size),
        "n_failed": int((~ok).sum()),
        "n_region": int(in_region.sum()),
        "n_failed_in_region": int((region & ~ok).sum()),
        "errors": err,
        "in_region": in_region,
        "max_abs_error": float(e.max()) if e.size else None,
        "rms_error": float(np.sqrt(np.mean(e**2))) if e.size else None,
        "coverage_2sd": float(np.mean(e <= 2.0 * np.maximum(sd[in_region], 1e-12)))
        if e.size else None,
    }
    out["passed"] = bool(e.size > 0 and e.max() <= tol_nats)
    return out


# ------------------------------------------------------------------ acquisition
def _reflect(U: np.ndarray) -> np.ndarray:
    """Reflect unit-box coordinates into [0, 1] (a jittered draw stays inside)."""
    U = np.mod(U, 2.0)
    return np.where(U > 1.0, 2.0 - U, U)


def candidate_pool(particles: np.ndarray, weights: np.ndarray, bounds: np.ndarray, n: int,
                   rng: np.random.Generator, *, uniform_fraction: float = POOL_UNIFORM,
                   bandwidth: float = BANDWIDTH) -> np.ndarray:
    """Candidate points for the next batch, (n, d) in user units.

    ``(1 - uniform_fraction) n`` are resampled particles jittered by ``bandwidth``
    posterior sd per parameter (at least 0.5 % of the box), reflected into the box.
    The last ``round(uniform_fraction n)`` rows are the exploring candidates: half
    of them (rounded down) are such jittered particles with one coordinate, chosen
    at random, redrawn uniformly over its range (*line* candidates: they reach a
    mode that differs from the current one in one parameter, such as the second
    branch of a Poisson's ratio whose effect is not monotonic, which a uniform draw
    in several dimensions almost never hits); the rest are uniform over the box.
    """
    from bayescalib.inference.resampling import systematic_resample

    b = np.asarray(bounds, float)
    lo, width = b[:, 0], b[:, 1] - b[:, 0]
    X = np.atleast_2d(np.asarray(particles, float))
    W = np.asarray(weights, float)
    W = W / W.sum()
    n_explore = round(n * float(uniform_fraction))
    n_post = int(n) - n_explore
    U = (X - lo) / width
    mean = W @ U
    sd = np.sqrt(np.maximum(W @ (U - mean) ** 2, 0.0))
    jitter = bandwidth * np.maximum(sd, 0.005)
    post = U[systematic_resample(W, rng, n_post)] + rng.standard_normal((n_post, U.shape[1])) * jitter
    n_line = n_explore // 2  # exploring: jittered particles with one coordinate redrawn
    line = _reflect(U[systematic_resample(W, rng, n_line)]
                    + rng.standard_normal((n_line, U.shape[1])) * jitter)
    line[np.arange(n_line), rng.integers(0, U.shape[1], n_line)] = rng.random(n_line)
    pool = np.vstack([_reflect(post), line, rng.random((n_explore - n_line, U.shape[1]))])
    return lo + pool * width


def select_batch(gp, pool: np.ndarray, logprior: np.ndarray, q: int, *, posterior_power: float,
                 failed: np.ndarray | None = None, n_explore: int = 0,
                 threshold: float | None = None, explore_mask: np.ndarray | None = None) -> dict[str, np.ndarray]:
    """Greedy batch of ``q`` candidates by prospective uncertainty (module docstring).

    Parameters
    ----------
    gp
        :class:`~bayescalib.inference.gp.predictor.GPSurrogate` of the log-likelihood.
    pool
        Candidates (M, d) in user units.
    logprior
        Log prior density at the candidates (M,).
    q
        Batch size (<= M).
    posterior_power
        Power k of the surrogate posterior in the score of the exploiting picks,
        log a = log var_L + k (mean_L + log p) (``design.active.posterior_power``;
        2 is VBMC's prospective uncertainty sampling, 1 weighs the posterior once).
    failed
        Points (F, d) whose solves failed: conditioned on like picked points.
    n_explore
        How many of the ``q`` picks explore (the last ones of the batch).
    threshold
        Log-likelihood above which a point lies in the posterior region (exploring
        picks need a probability of at least ``P_PLAUSIBLE`` to exceed it).
    explore_mask
        (M,) bool: candidates eligible for exploring picks (the exploring ones: lines and uniform).

    Returns
    -------
    dict
        ``points`` (q, d); ``index`` (q,) into ``pool``; ``mean`` and ``sd`` (q,): the
        surrogate's log-likelihood prediction at each picked point before any of the
        batch is solved (for the next round's trust check); ``score`` (q,): log a at
        the time of the pick.
    """
    P = np.atleast_2d(np.asarray(pool, float))
    F = np.empty((0, P.shape[1])) if failed is None else np.atleast_2d(np.asarray(failed, float))
    F = F.reshape(-1, P.shape[1])
    M, nf = P.shape[0], F.shape[0]
    q = int(q)
    if not 1 <= q <= M:
        raise ValueError(f"batch size must be in 1..{M}, got {q}")
    S = np.vstack([F, P])  # conditioning set: failed points first, then candidates
    g, var_g = gp.predict_latent(S, return_var=True)
    var_g = np.asarray(var_g, float).copy()
    V = gp.latent_cov_factor(S)  # (n, nf + M)
    mean_L = gp.loglik_from_latent(g)[nf:]
    scale2 = _loglik_var_scale(gp, g)
    base = mean_L + np.asarray(logprior, float)
    cols: list[np.ndarray] = []

    def condition(k: int) -> None:
        c = gp.latent_kernel(S, S[k : k + 1])[:, 0] - V.T @ V[:, k]
        for col in cols:
            c -= col * col[k]
        ck = max(c[k], 0.0) + gp.nugget
        col = c / math.sqrt(ck)
        cols.append(col)
        np.subtract(var_g, col * col, out=var_g)
        np.maximum(var_g, 0.0, out=var_g)

    for k in range(nf):
        condition(k)
    pred_sd = np.sqrt(scale2[nf:] * var_g[nf:])  # before any pick of this batch
    n_explore = int(n_explore) if threshold is not None else 0
    plausible = np.zeros(M, bool)
    if n_explore:
        from scipy.special import log_ndtr

        sd_g = np.sqrt(np.maximum(var_g[nf:], 1e-300))
        if gp.warped:  # L >= threshold  <=>  g <= log1p(B - threshold)
            z = (np.log1p(max(gp.bound - threshold, 0.0)) - g[nf:]) / sd_g
        else:
            z = (g[nf:] - threshold) / sd_g
        plausible = log_ndtr(z) >= np.log(P_PLAUSIBLE)
        if explore_mask is not None:
            plausible &= np.asarray(explore_mask, bool)
    picked: list[int] = []
    scores: list[float] = []
    for b in range(q):
        explore = b >= q - n_explore and plausible.any()
        with np.errstate(divide="ignore"):
            if explore:  # prospective uncertainty under a flattened posterior
                score = np.where(plausible, np.log(scale2[nf:] * var_g[nf:])
                                 + EXPLORE_TEMPER * base, -np.inf)
            else:
                score = np.log(scale2[nf:] * var_g[nf:]) + float(posterior_power) * base
        score[picked] = -np.inf
        k = int(np.argmax(score))
        if not np.isfinite(score[k]):  # nothing uncertain left: take the best unpicked mean
            rest = np.where(np.isin(np.arange(M), picked), -np.inf, base)
            k = int(np.argmax(rest))
        picked.append(k)
        scores.append(float(score[k]))
        condition(nf + k)
    idx = np.asarray(picked)
    return {"points": P[idx], "index": idx, "mean": mean_L[idx], "sd": pred_sd[idx],
            "score": np.asarray(scores)}


# ------------------------------------------------------------------ one round
#: basins the round record lists (the largest not held)
MAX_BASINS_RECORDED = 5


def unheld_basins(explored: Mapping[str, Any]) -> list[dict[str, Any]]:
    """The basins of :func:`~bayescalib.inference.exploration.audit` that the posterior
    does not hold and the solves do not refute, largest estimated mass first (the first
    is the one the reason names), at most ``MAX_BASINS_RECORDED``."""
    return sorted((b for b in explored["basins"]
                   if not b["is_held"] and not b.get("refuted")),  # older records lack it
                  key=lambda b: -b["mass"])[:MAX_BASINS_RECORDED]


def _round_seed(seed: int, r: int) -> np.random.Generator:
    return np.random.default_rng([int(seed), int(r), 0x5EED])


#: the design batches leave room for this many looks of the sequential posterior check
#: (``posterior_check.batch`` draws each, at most ``posterior_check.draws``); the check
#: round starts once no more than that is left. Two: one look confirms only a posterior
#: whose draws represent it (8 draws of a curved ridge often do not), and a whole check
#: (32 draws) held back from a budget of 64 left half of it to check the posterior of
#: round 2 (``benchmarks/bench_modes.py``, ``docs/bench_modes.md``)
RESERVE_LOOKS = 2


@dataclass(frozen=True)
class StopRule:
    """The stop rule of the module docstring, over the round records.

    Attributes
    ----------
    shift_tol, sd_tol : settled when the posterior mean moved by at most ``shift_tol``
        sd and every sd changed by at most ``sd_tol`` (``design.active.stop``).
    gp_tol : the trust check's tolerance in nats.
    patience : settled rounds in a row before a check round.
    unexplored_mass : the most posterior mass the exploration audit may leave unheld.
    max_solves : the budget.
    n_draws : the size of a check round (0: no check rounds: settled and trusted for
        ``patience`` rounds converges).
    draws_only : every round is a check round (the output emulator's rounds).
    batch : draws solved per look of the sequential check (0: all ``n_draws`` at once).
    """

    shift_tol: float
    sd_tol: float
    gp_tol: float
    patience: int
    unexplored_mass: float
    max_solves: int
    n_draws: int
    draws_only: bool
    batch: int = 0

    @classmethod
    def from_config(cls, active: Mapping[str, Any], posterior_check: Mapping[str, Any],
                    draws_only: bool) -> StopRule:
        """From the validated ``design.active`` and ``posterior_check`` sections; with
        ``draws_only`` a check round is ``design.active.batch_size`` draws when
        ``posterior_check.draws`` is 0."""
        s = active["stop"]
        n_draws = (int(posterior_check["draws"])
                   or (int(active["batch_size"]) if draws_only else 0))
        return cls(float(s["shift_tol"]), float(s["sd_tol"]), float(s["gp_tol"]),
                   int(s["patience"]), float(s["unexplored_mass"]), int(active["max_solves"]),
                   n_draws, bool(draws_only),
                   0 if draws_only else int(posterior_check["batch"]))

    @property
    def first_look(self) -> int:
        """Draws solved by a check round's first look."""
        return min(self.batch, self.n_draws) if self.batch > 0 else self.n_draws

    def settled(self, change: Mapping[str, float] | None) -> bool:
        """Did the posterior settle (None: round 0, no change to judge)?"""
        return change is not None and (change["shift_sd"] <= self.shift_tol
                                       and change["sd_change"] <= self.sd_tol)

    def explored(self, unexplored_mass: float) -> bool:
        """May the posterior be said to hold every basin the solves show?"""
        return bool(unexplored_mass <= self.unexplored_mass)

    def apply(self, rec: dict[str, Any], previous: Mapping[str, Any] | None) -> dict[str, Any]:
        """Set ``settled_streak``, ``converged`` and ``stop`` of round record ``rec``
        (its ``settled``, ``trusted``, ``explored`` and ``posterior_check`` set), and
        return what the next batch must be: ``check_round_next`` (a check round),
        ``n_draws`` (its size, cut to the budget when every round is one),
        ``check_round_fits`` (a check round fits in the budget) and ``budget_left``."""
        pc = rec["posterior_check"]
        budget_left = self.max_solves - int(rec["n_solves"])
        if pc is not None and pc.get("decision") == "continue":
            # the sequential check is undecided: its next look's draws are solved next
            rec["settled_streak"] = 0
            rec["converged"] = False
            rec["stop"] = False
            n_next = min(self.batch, budget_left,
                         len(rec["check_state"]["pending"]["points"]))
            return {"check_round_next": True, "continue_check": True, "n_draws": n_next,
                    "check_round_fits": True, "budget_left": budget_left,
                    "reserve": n_next, "check_state": rec["check_state"]}
        # without check rounds (draws: 0) the pointwise trust check stands in for the
        # posterior check, as in the stop rule before it: a round counts when settled and
        # trusted (the diagnosis's calibrations, which check their posteriors themselves)
        counts = rec["settled"] and rec["explored"] and (self.n_draws > 0 or rec["trusted"])
        if pc is None:
            streak = (int(previous.get("settled_streak", 0)) if previous else 0) + 1 \
                if counts else 0
        elif pc.get("decision") == "superseded":  # the streak starts with this round
            streak = int(counts)
        else:  # after a check round the streak starts again (unless it converged)
            streak = 0
        rec["settled_streak"] = streak
        if pc is not None:  # settled against the posterior the check confirmed
            since = pc.get("change_since_checked") or rec["change"]
            rec["converged"] = bool(pc["confirmed"] and self.settled(since)
                                    and pc.get("mass_settled", True) and rec["explored"])
        else:  # without a posterior check (draws: 0): settled and trusted, patience rounds
            rec["converged"] = self.n_draws == 0 and streak >= self.patience
        n_draws = self.n_draws
        first = self.first_look
        if self.draws_only:  # every round is a check round; the last one with the solves left
            n_draws = min(n_draws, budget_left)
            check_round_fits = check_round_next = n_draws >= 2
            reserve = n_draws
        else:
            # a check round needs room for its first look; the design batches leave room
            # for RESERVE_LOOKS looks (at most n_draws), and the check starts once no more
            # than that is left
            check_round_fits = 0 < first <= budget_left
            reserve = min(n_draws, RESERVE_LOOKS * first)
            check_round_next = check_round_fits and (streak >= self.patience
                                                     or budget_left - reserve < 1)
            n_draws = min(n_draws, max(budget_left, 0))
        rec["stop"] = bool(rec["converged"] or budget_left <= 0
                           or (self.draws_only and not check_round_next))
        return {"check_round_next": check_round_next, "n_draws": n_draws,
                "check_round_fits": check_round_fits, "budget_left": budget_left,
                "reserve": reserve if check_round_fits else 0,
                "look": n_draws if self.draws_only else first, "max_draws": self.n_draws}


def acquire_round(r: int, X: np.ndarray, L: np.ndarray, gp, particles: np.ndarray,
                  weights: np.ndarray, log_evidence: float, space, active: Mapping[str, Any],
                  previous: Mapping[str, Any] | None,
                  posterior_check: Mapping[str, Any],
                  acquisition: str = "select") -> dict[str, Any]:
    """Everything decided at the end of round ``r``: trust check, posterior check (of a
    check round), stop rule, next batch.

    The round's record (:func:`round_record`: its posterior, the trust check, the
    posterior's change, the posterior check of a check round, the exploration audit),
    then the :class:`StopRule` and, unless it stops, the acquisition's next batch
    (:data:`ACQUISITIONS`).

    Parameters
    ----------
    r
        Round index (0 = the Sobol design).
    X, L
        All solved design points of rounds 0..r, (n, d), and their log-likelihoods
        (n,), -inf for failed solves; the last rows are round r's batch.
    gp
        The surrogate fitted on them.
    particles, weights, log_evidence
        SMC on that surrogate.
    space
        :class:`~bayescalib.inference.parameters.ParameterSpace`.
    active
        The validated ``design.active`` config section.
    previous
        The record this function returned for round r-1 (None for round 0).
    posterior_check
        The validated ``posterior_check`` section: ``draws`` (the size of a check
        round) and the thresholds of
        :func:`~bayescalib.inference.importance.importance_check`.
    acquisition
        ``select`` (:class:`SelectBatch`): batches chosen by :func:`select_batch`, check
        rounds once the posterior has settled (the module docstring). ``draws``
        (:class:`PosteriorDraws`): every batch is a check round of
        ``posterior_check.draws`` draws (``design.active.batch_size`` when that is 0),
        cut to the budget left: the rounds of the output emulator
        (``surrogate.target: outputs``, :mod:`bayescalib.inference.emulator`), whose
        surrogate has no variance-driven acquisition and whose best design points are
        where the posterior lives. Converged when a round's draws confirm the posterior
        that drew them and the posterior refitted with them is settled.

    Returns
    -------
    dict
        Plain JSON-able record: ``round``, ``n_solves``, ``n_failed``, ``posterior``
        (mean, sd, cov, log_evidence), ``against_bounds`` (the box's ends that cut it,
        :func:`~bayescalib.inference.posterior.against_bounds`), ``trust`` (:func:`trust_check` of this round's
        batch, None in round 0), ``change`` (:func:`posterior_change` from round r-1),
        ``exploration``, ``explored``, ``settled``, ``trusted``, ``settled_streak``,
        ``posterior_check`` (the importance check of round r-1's posterior when this
        round's batch was its check round, else None), ``stop``, ``converged``,
        ``reason``, and ``next`` (the batch for round r+1: ``points``, ``mean``, ``sd``,
        ``score``, ``kind``) unless it stops.
    """
    if acquisition not in ACQUISITIONS:
        raise ValueError(f"acquisition must be one of {sorted(ACQUISITIONS)}, got "
                         f"{acquisition!r}")
    X = np.atleast_2d(np.asarray(X, float))
    L = np.asarray(L, float)
    rule = StopRule.from_config(active, posterior_check, acquisition == "draws")
    rec, explored = round_record(r, X, L, gp, particles, weights, log_evidence, space,
                                 previous, posterior_check, rule)
    step = rule.apply(rec, previous)
    rec["reason"] = _reason(rec, rule, step, active["stop"], posterior_check)
    if not rec["stop"]:
        rec["next"] = ACQUISITIONS[acquisition](active).next_batch(
            r, X, L, gp, particles, weights, space, explored, step)
    return rec


def round_record(r: int, X: np.ndarray, L: np.ndarray, gp, particles: np.ndarray,
                 weights: np.ndarray, log_evidence: float, space,
                 previous: Mapping[str, Any] | None, posterior_check: Mapping[str, Any],
                 rule: StopRule) -> tuple[dict[str, Any], dict[str, Any]]:
    """What round r found, before the stop rule: its posterior, the trust check of
    round r-1's batch, the posterior's change, the posterior check when that batch was
    a check round, the exploration audit, and whether the posterior is ``settled``,
    ``trusted`` and ``explored``. Returns the record and the audit
    (:func:`~bayescalib.inference.exploration.audit`)."""
    from bayescalib.inference.exploration import audit
    from bayescalib.inference.posterior import against_bounds

    n, d = X.shape
    moments = posterior_moments(particles, weights)
    rec: dict[str, Any] = {
        "round": int(r),
        "n_solves": int(n),
        "n_failed": int((~np.isfinite(L)).sum()),
        "posterior": {"mean": moments["mean"].tolist(), "sd": moments["sd"].tolist(),
                      "cov": moments["cov"].tolist(), "log_evidence": float(log_evidence)},
        "names": list(space.names),
        # the ends of the box that cut this round's posterior (said on the console)
        "against_bounds": against_bounds(particles, weights, space),
        "trust": None,
        "change": None,
        "posterior_check": None,
    }
    finite = np.isfinite(L)
    best = float(L[finite].max()) if finite.any() else -math.inf
    if previous is not None:
        nxt = previous["next"]
        q_prev = len(nxt["points"])
        new_X = X[n - q_prev:]
        if not np.allclose(new_X, np.asarray(nxt["points"], float), rtol=1e-9, atol=1e-12):
            raise ValueError(
                f"round {r}: the last {q_prev} design points are not the batch that round "
                f"{r - 1} chose; the run records do not belong to this active design")
        trust = trust_check(np.asarray(nxt["mean"], float), np.asarray(nxt["sd"], float),
                            L[n - q_prev:], best, d, rule.gp_tol)
        rec["trust"] = {k: (v.tolist() if isinstance(v, np.ndarray) else v)
                        for k, v in trust.items()}
        rec["trust"]["n_batch"] = int(q_prev)
        rec["trust"]["n_batch_failed"] = int((~np.isfinite(L[n - q_prev:])).sum())
        kinds = np.asarray(nxt.get("kind", ["acquired"] * q_prev))
        is_check_point = kinds == "check"
        err, region = trust["errors"], trust["in_region"]
        rec["trust"]["check_errors"] = err[is_check_point].tolist()
        rec["trust"]["check_max_underprediction"] = (
            float(np.max(err[is_check_point & region])) if np.any(is_check_point & region)
            else None)
        drawn = kinds == "posterior_check"
        if drawn.any() and np.all(drawn | (kinds == "probe")):  # a check round (+ probes)
            rec["posterior_check"], state = _check_look(
                nxt, drawn, L[n - q_prev:], posterior_check, space.names, r, n, rule,
                previous, moments, particles, weights)
            if state is not None:
                rec["check_state"] = state
        prev_post = {k: np.asarray(v, float) for k, v in previous["posterior"].items()
                     if k in ("mean", "sd", "cov")}
        rec["change"] = posterior_change(prev_post, moments)
    explored = audit(X, L, particles, weights, log_evidence, space,
                     bound=getattr(gp, "bound", None))
    rec["exploration"] = {
        "unexplored_mass": explored["unexplored_mass"],
        "fill_distance": explored["fill_distance"],
        "basins": unheld_basins(explored),
    }
    rec["explored"] = rule.explored(explored["unexplored_mass"])
    rec["settled"] = bool(rule.settled(rec["change"]))
    rec["trusted"] = bool(rec["trust"] is not None and rec["trust"]["passed"])
    return rec, explored


def _finite_or_none(a) -> list:
    return [float(v) if math.isfinite(v) else None for v in np.asarray(a, float).tolist()]


def _none_to_nan(a) -> np.ndarray:
    return np.array([math.nan if v is None else v for v in a], float)


def _masses_by_center(particles: np.ndarray, weights: np.ndarray, centers: np.ndarray,
                      sd: np.ndarray) -> np.ndarray:
    """The posterior mass nearest to each of ``centers`` (C, d), distances in units of
    ``sd`` (d,)."""
    P = np.atleast_2d(np.asarray(particles, float))
    W = np.asarray(weights, float) / np.sum(weights)
    scale = np.where(np.asarray(sd, float) > 0, sd, 1.0)
    d2 = (((P[:, None, :] - centers[None, :, :]) / scale) ** 2).sum(axis=2)
    return np.bincount(np.argmin(d2, axis=1), weights=W, minlength=len(centers))


def _check_look(nxt: Mapping[str, Any], drawn: np.ndarray, L_batch: np.ndarray,
                posterior_check: Mapping[str, Any], names: Sequence[str], r: int, n: int,
                rule: StopRule, previous: Mapping[str, Any],
                moments: Mapping[str, np.ndarray], particles: np.ndarray,
                weights: np.ndarray) -> tuple[dict[str, Any], dict | None]:
    """One look of the sequential posterior check in round ``r``: the draws of the
    check round solved so far (earlier looks' and this batch's) judged by
    :func:`round_posterior_check`. Returns its record (with ``change_since_checked``: the
    posterior's change since the checked round) and, when it is undecided, the state the
    next look continues from (``check_state``: the draws solved so far and those
    pending)."""
    pts = np.asarray(nxt["points"], float)[drawn]
    Lb = np.asarray(L_batch, float)[drawn]
    check = nxt.get("check")
    if check is None:  # a record without the sequential state: one look at these draws
        batch = {"points": pts, "mean": np.asarray(nxt["mean"], float)[drawn]}
        return round_posterior_check(batch, Lb, posterior_check, names, r - 1,
                                     posterior=previous["posterior"]), None
    solved, pending = check["solved"], check["pending"]
    d = pts.shape[1]
    P = np.vstack([np.asarray(solved["points"], float).reshape(-1, d), pts])
    M = np.concatenate([np.asarray(solved["mean"], float), np.asarray(check["batch_mean"], float)])
    LL = np.concatenate([_none_to_nan(solved["loglik"]), Lb])
    lab = np.concatenate([np.asarray(solved["cluster"], int),
                          np.asarray(check["batch_cluster"], int)])
    final = len(pending["points"]) == 0 or rule.max_solves - n <= 0
    pc = round_posterior_check({"points": P, "mean": M, "cluster": lab}, LL, posterior_check,
                               names, int(check["round"]), posterior=check["posterior"],
                               cluster_mass=check["cluster_mass"], look=int(check["look"]),
                               n_looks=int(check["n_looks"]), final=final,
                               max_draws=int(check["max_draws"]))
    checked = {k: np.asarray(v, float) for k, v in check["posterior"].items()}
    pc["change_since_checked"] = posterior_change(checked, moments)
    if "cluster_center" in check and len(check["cluster_mass"]) > 1:
        # the posterior refitted with the draws must keep the masses the check confirmed:
        # its particles' mass by nearest cluster centre of the checked posterior (in its sd)
        now = _masses_by_center(particles, weights, np.asarray(check["cluster_center"], float),
                                checked["sd"])
        moved = float(np.max(np.abs(now - np.asarray(check["cluster_mass"], float))))
        pc["cluster_mass_now"] = now.tolist()
        pc["mass_change_since_checked"] = moved
        pc["mass_settled"] = bool(moved <= float(posterior_check["mass_tol"]))
    supersede_if_moved(pc, rule)
    if pc["decision"] != "continue":
        return pc, None
    state = {k: check[k] for k in ("round", "posterior", "cluster_mass", "cluster_center",
                                   "n_looks", "max_draws", "look") if k in check}
    state["solved"] = {"points": P.tolist(), "mean": M.tolist(), "loglik": _finite_or_none(LL),
                       "cluster": lab.tolist()}
    state["pending"] = pending
    return pc, state


def supersede_if_moved(pc: dict[str, Any], rule: StopRule) -> None:
    """Mark an undecided look ``pc`` of the sequential check *superseded* when the
    posterior refitted with its draws has moved away from the one the check tests (its
    ``change_since_checked`` not settled by ``rule``, or ``mass_settled`` False).

    Confirming the checked posterior could then no longer make the run converge (the
    stop rule wants the confirmed posterior settled against the checked one), so the
    check's remaining draws are not solved; the draws solved stay design points. On
    ridge2d with a budget of 64 the check of round 2's posterior, 0.3 sd from where the
    rounds settled, took every solve left in undecided looks
    (``docs/bench_modes.md``)."""
    if pc["decision"] != "continue" or (rule.settled(pc["change_since_checked"])
                                        and pc.get("mass_settled", True)):
        return
    pc["decision"] = "superseded"
    ch = pc["change_since_checked"]
    moved = (f"its mean by {ch['shift_sd']:.2g} sd, its sd by {ch['sd_change']:.2g}"
             + (f", its clusters' masses by {pc['mass_change_since_checked']:.2g}"
                if not pc.get("mass_settled", True) else ""))
    pc["words"] = (f"superseded after {pc['n_draws']} draws: the posterior refitted with "
                   f"them moved away from the one checked ({moved}), so its check was "
                   f"stopped and the draws kept as design points; undecided until then ("
                   + pc["words"] + ")")


def _reason(rec: Mapping[str, Any], rule: StopRule, step: Mapping[str, Any],
            stop_cfg: Mapping[str, Any], posterior_check: Mapping[str, Any]) -> str:
    """Plain words: the stop rule's verdict on round ``rec`` and why."""
    r, n, pc = rec["round"], rec["n_solves"], rec["posterior_check"]
    streak, budget_left, n_draws = rec["settled_streak"], step["budget_left"], step["n_draws"]
    if rec["converged"] and pc is not None:
        return (f"converged after round {r} with {n} solves: the posterior of round {r - 1} "
                f"confirmed by {pc['n_draws'] - pc['n_failed']} real solves of its draws "
                f"(log-weight sd {pc['log_weight_sd']:.2g} nats, ESS "
                f"{100 * pc['ess_fraction']:.0f} %), and it moved by "
                f"{rec['change']['shift_sd']:.2g} sd (sd change "
                f"{rec['change']['sd_change']:.2g}) when they were added; "
                + _explored_words(rec))
    if rec["converged"]:
        return (f"converged after round {r} with {n} solves: in the last {streak} round(s) "
                f"the posterior moved by at most {stop_cfg['shift_tol']:g} sd (now "
                f"{rec['change']['shift_sd']:.3g} sd, sd change "
                f"{rec['change']['sd_change']:.3g}) and the surrogate predicted the new "
                f"solves in the posterior region within {stop_cfg['gp_tol']:g} nats (max "
                f"error {rec['trust']['max_abs_error']:.3g}); NOT checked with real solves of "
                f"its draws (posterior_check.draws: 0); " + _explored_words(rec))
    if step.get("continue_check"):
        return (f"continue: the posterior check of round {pc['round']} is undecided after "
                f"{pc['n_draws']} draws ({pc['words']}); the next {n_draws} of its draws are "
                f"solved next.")
    why_not = _why_not(rec, stop_cfg, posterior_check, budget_left)
    if rec["stop"]:
        return (f"NOT converged: the budget design.active.max_solves = {rule.max_solves} is "
                f"spent after round {r}. " + why_not
                + " The posterior reported is that of the last round; raise "
                "design.active.max_solves to go on (finished solves are kept).")
    if step["check_round_next"] and rule.draws_only:
        return (f"continue: {n_draws} draws of this posterior are solved next, "
                f"its posterior check and the next design points. " + why_not)
    if step["check_round_next"]:
        why = (f"the posterior settled for {streak} round(s) in a row"
               if streak >= rule.patience else
               f"{budget_left} solves are left, the last for the posterior check")
        return (f"continue: {why}; {n_draws} draws of it are solved next as its "
                f"posterior check. " + why_not)
    return "continue: " + why_not


def _posterior_draw_batch(r: int, X: np.ndarray, gp, particles: np.ndarray,
                          weights: np.ndarray, space, explored: Mapping[str, Any],
                          active: Mapping[str, Any], n_draws: int,
                          n_probes: int, look: int = 0, max_draws: int | None = None
                          ) -> dict[str, Any]:
    """The batch of a check round: ``n_draws`` equally weighted draws of the posterior
    (:func:`posterior_draws`, stratified by its clusters, :func:`posterior_clusters`;
    batch kind ``"posterior_check"``), of which the first ``look`` (0: all) are solved
    next round for the first look of the sequential posterior check and the others wait
    in ``check["pending"]`` for the looks after it, and ``n_probes`` probes of the
    unheld basins (:func:`~bayescalib.inference.exploration.probe_points`). ``check``
    carries what the looks need: the checked round and posterior, the clusters' masses,
    the surrogate's log-likelihood at the draws, the looks' count for the error
    spending."""
    look = int(look) if look and int(look) < n_draws else int(n_draws)
    labels, cluster_mass = posterior_clusters(particles, weights, seed=int(active["seed"]) + r)
    D, lab = posterior_draws(particles, weights, n_draws,
                             np.random.default_rng([int(active["seed"]), int(r), 0x15C4]),
                             exclude=X, labels=labels, batch=look)
    mean_all, sd_all = _predict_loglik(gp, D)
    m = posterior_moments(particles, weights)
    Pn = np.atleast_2d(np.asarray(particles, float))
    Wn = np.asarray(weights, float) / np.sum(weights)
    centers = [(Wn[labels == c] @ Pn[labels == c] / Wn[labels == c].sum()).tolist()
               for c in range(len(cluster_mass))]
    check = {"round": int(r),
             "posterior": {k: m[k].tolist() for k in ("mean", "sd", "cov")},
             "cluster_mass": cluster_mass.tolist(), "cluster_center": centers,
             "n_looks": math.ceil(n_draws / look), "max_draws": int(max_draws or n_draws),
             "look": 1, "batch_mean": mean_all[:look].tolist(),
             "batch_cluster": lab[:look].tolist(),
             "solved": {"points": [], "mean": [], "loglik": [], "cluster": []},
             "pending": {"points": D[look:].tolist(), "mean": mean_all[look:].tolist(),
                         "cluster": lab[look:].tolist()}}
    batch = {"points": D[:look].tolist(), "mean": mean_all[:look].tolist(),
             "sd": sd_all[:look].tolist(), "score": [], "kind": ["posterior_check"] * look,
             "check": check}
    return _with_probes(batch, r, X, gp, space, explored, active, n_probes)


def _with_probes(batch: dict[str, Any], r: int, X: np.ndarray, gp, space,
                 explored: Mapping[str, Any], active: Mapping[str, Any],
                 n_probes: int) -> dict[str, Any]:
    """``batch`` with up to ``n_probes`` probes of the unheld basins added (batch kind
    ``"probe"``; :func:`~bayescalib.inference.exploration.probe_points`; none where every
    basin is held or refuted)."""
    from bayescalib.inference.exploration import probe_points

    if n_probes <= 0:
        return batch
    probes = probe_points(explored, X, space.bounds, n_probes,
                          float(active["stop"]["unexplored_mass"]),
                          np.random.default_rng([int(active["seed"]), int(r), 0xB451]))
    if not len(probes):
        return batch
    pm, ps = _predict_loglik(gp, probes)
    return {**batch, "points": batch["points"] + probes.tolist(),
            "mean": list(batch["mean"]) + pm.tolist(), "sd": list(batch["sd"]) + ps.tolist(),
            "kind": list(batch["kind"]) + ["probe"] * len(probes)}


def _next_look_batch(gp, step: Mapping[str, Any]) -> dict[str, Any]:
    """The batch of an undecided sequential check's next look: the next ``step
    ["n_draws"]`` of its pending draws, with the surrogate's log-likelihood at them as
    the check recorded it (``check["batch_mean"]``) and as this round's surrogate
    predicts it (``mean``, ``sd``: for the trust check)."""
    st = step["check_state"]
    k = int(step["n_draws"])
    pend = st["pending"]
    P = np.asarray(pend["points"], float)[:k]
    mean, sd = _predict_loglik(gp, P)
    check = {**{key: st[key] for key in ("round", "posterior", "cluster_mass",
                                         "cluster_center", "n_looks", "max_draws")
                 if key in st},
             "look": int(st["look"]) + 1, "batch_mean": pend["mean"][:k],
             "batch_cluster": pend["cluster"][:k], "solved": st["solved"],
             "pending": {key: v[k:] for key, v in pend.items()}}
    return {"points": P.tolist(), "mean": mean.tolist(), "sd": sd.tolist(), "score": [],
            "kind": ["posterior_check"] * len(P), "check": check}


@dataclass(frozen=True)
class PosteriorDraws:
    """Every batch a check round of posterior draws, with the probes of the unheld
    basins: the output emulator's rounds (``surrogate.target: outputs``), whose surrogate
    has no variance-driven acquisition and whose best design points are where the
    posterior lives."""

    active: Mapping[str, Any]

    def next_batch(self, r: int, X: np.ndarray, L: np.ndarray, gp, particles: np.ndarray,
                   weights: np.ndarray, space, explored: Mapping[str, Any],
                   step: Mapping[str, Any]) -> dict[str, Any]:
        n_draws = int(step["n_draws"])
        return _posterior_draw_batch(r, X, gp, particles, weights, space, explored,
                                     self.active, n_draws,
                                     min(int(self.active["probes"]),
                                         int(step["budget_left"]) - n_draws))


@dataclass(frozen=True)
class SelectBatch:
    """Batches chosen by :func:`select_batch` from a pool of candidates around the
    posterior and over the box, with check points, boundary points and probes; a check
    round of posterior draws when the stop rule asks for one (the module docstring)."""

    active: Mapping[str, Any]

    def next_batch(self, r: int, X: np.ndarray, L: np.ndarray, gp, particles: np.ndarray,
                   weights: np.ndarray, space, explored: Mapping[str, Any],
                   step: Mapping[str, Any]) -> dict[str, Any]:
        from scipy.stats import chi2

        from bayescalib.inference.exploration import probe_points

        active = self.active
        # a check round carries the probes of the basins still open in the solves the
        # budget leaves beside its look (the run cannot converge while they are open)
        n_probes = int(active["probes"])
        if step.get("continue_check"):
            batch = _next_look_batch(gp, step)
            return _with_probes(batch, r, X, gp, space, explored, active,
                                min(n_probes, int(step["budget_left"]) - len(batch["points"])))
        if step["check_round_next"]:
            first = min(int(step["look"]), int(step["n_draws"]))
            return _posterior_draw_batch(r, X, gp, particles, weights, space, explored,
                                         active, int(step["n_draws"]),
                                         min(n_probes, int(step["budget_left"]) - first),
                                         look=int(step["look"]), max_draws=int(step["max_draws"]))
        d = X.shape[1]
        finite = np.isfinite(L)
        best = float(L[finite].max()) if finite.any() else -math.inf
        reserve = int(step["reserve"])
        room = int(step["budget_left"]) - reserve  # >= 1 here
        rng = _round_seed(active["seed"], r)
        probes = probe_points(explored, X, space.bounds, min(int(active["probes"]), room - 1),
                              float(active["stop"]["unexplored_mass"]),
                              np.random.default_rng([int(active["seed"]), int(r), 0xB451]))
        room -= len(probes)
        pool = candidate_pool(particles, weights, space.bounds, int(active["pool_size"]), rng)
        q = min(int(active["batch_size"]), room)
        n_check_points = min(int(active["check_points"]), room - q)
        n_explore = math.floor(q * float(active["explore_fraction"]) + 0.5)
        exploring = np.arange(len(pool)) >= len(pool) - round(len(pool) * POOL_UNIFORM)
        threshold = best - 0.5 * float(chi2.ppf(REGION_LEVEL, d))
        batch = select_batch(gp, pool, space.logprior(pool), q,
                             posterior_power=float(active["posterior_power"]), failed=X[~finite],
                             n_explore=n_explore, threshold=threshold, explore_mask=exploring)
        points, mean, sd = batch["points"], batch["mean"], batch["sd"]
        kind = ["acquired"] * len(points)
        extra = []
        if n_check_points:
            extra.append((check_points(particles, weights, space.bounds, n_check_points,
                                       np.random.default_rng([int(active["seed"]), int(r),
                                                              0xC4EC])), "check"))
        n_edge = min(int(active["boundary_points"]), room - q - n_check_points)
        if n_edge > 0 and getattr(gp, "X_failed", None) is not None:
            extra.append((boundary_points(gp, particles, weights, n_edge, exclude=X),
                          "boundary"))
        extra.append((probes, "probe"))
        for P, k in extra:
            if len(P):
                m, s = _predict_loglik(gp, P)
                points, mean, sd = np.vstack([points, P]), np.concatenate([mean, m]), \
                    np.concatenate([sd, s])
                kind += [k] * len(P)
        return {"points": points.tolist(), "mean": mean.tolist(), "sd": sd.tolist(),
                "score": batch["score"].tolist(), "kind": kind}


#: the acquisitions by name (``acquire_round``'s ``acquisition``)
ACQUISITIONS = {"select": SelectBatch, "draws": PosteriorDraws}


#: boundary points (:func:`boundary_points`): a failed solve and its nearest successful one
#: closer than this many posterior sd are not bisected further
BOUNDARY_RESOLUTION_SD = 0.25


def boundary_points(gp, particles: np.ndarray, weights: np.ndarray, n: int,
                    exclude: np.ndarray | None = None) -> np.ndarray:
    """Points that bisect the boundary of the failed region where the posterior meets
    it, (k, d) in user units, k <= n.

    The region rule (:class:`~bayescalib.inference.feasibility.FailedRegion`) puts the
    boundary between a successful solve o and a failed one f half way: the true one lies
    somewhere on the segment, and solving its midpoint m = (f + o) / 2 (user units)
    halves that uncertainty. The pairs that matter are those the posterior leans on:
    each particle's nearest successful and nearest failed solve (the surrogate's input
    coordinates), for the particles at least half as far from that failure as from that
    success (distance ratio >= 1/2: near the boundary); a pair's weight is the posterior
    weight of its particles. Kept: the ``n`` heaviest pairs more than
    :data:`BOUNDARY_RESOLUTION_SD` posterior sd apart. Where successful solves are dense
    (the posterior's side) and failed ones sparse, the rule's boundary leans into the
    failed side, and the acquisition, which conditions on failed points as known, never
    places points there: without these the posterior keeps mass where solves fail.
    A midpoint already among ``exclude`` (the design so far: its solve failed for the
    machine's sake, so the pair is still there) is skipped, since design points may
    not repeat.
    """
    from scipy.spatial import cKDTree

    P = np.atleast_2d(np.asarray(particles, float))
    if n < 1 or getattr(gp, "X_failed", None) is None:
        return np.empty((0, P.shape[1]))
    W = np.asarray(weights, float)
    W = W / W.sum()
    F, O = gp.X_failed, gp.X_train
    U = gp.scale_inputs(P)
    d_ok, i_ok = cKDTree(gp.scale_inputs(O)).query(U, k=1)
    d_f, i_f = cKDTree(gp.scale_inputs(F)).query(U, k=1)
    near = d_ok >= 0.5 * d_f
    if not near.any():
        return np.empty((0, P.shape[1]))
    pairs: dict[tuple[int, int], float] = {}
    for a, b, w in zip(i_ok[near].tolist(), i_f[near].tolist(), W[near].tolist(), strict=True):
        pairs[(a, b)] = pairs.get((a, b), 0.0) + w
    sd = posterior_moments(P, W)["sd"]
    scale = np.where(sd > 0, sd, 1.0)
    seen = set() if exclude is None else {tuple(x) for x in np.atleast_2d(exclude).tolist()}
    out = []
    for (a, b), _w in sorted(pairs.items(), key=lambda kv: (-kv[1], kv[0])):
        m = 0.5 * (F[b] + O[a])
        if np.sqrt(np.sum(((F[b] - O[a]) / scale) ** 2)) > BOUNDARY_RESOLUTION_SD \
                and tuple(m.tolist()) not in seen:
            out.append(m)
            if len(out) == n:
                break
    return np.asarray(out, float).reshape(-1, P.shape[1])


def posterior_draws(particles: np.ndarray, weights: np.ndarray, n: int,
                    rng: np.random.Generator, exclude: np.ndarray | None = None,
                    labels: np.ndarray | None = None, batch: int = 0):
    """``n`` equally weighted draws of an SMC posterior, (n, d): its particles resampled
    systematically (as :func:`bayescalib.inference.posterior.equal_weight_draws`).

    SMC particles repeat (a move that was rejected keeps the point), and a check round's
    draws become design points, which may not repeat: a draw equal to an earlier one or
    to a row of ``exclude`` (the design so far) is replaced by another particle drawn
    with the weights (at most 100 tries; then it is kept, and the pipeline refuses it).

    With ``labels`` (the particles' clusters, :func:`posterior_clusters`) the particles
    are ordered by cluster before the systematic resampling, so that the draws are
    stratified by cluster (each cluster gets within one of its share n q_c), each
    consecutive block of ``batch`` draws (0: all n) being such a resample on its own (the
    looks of the sequential check); returns the draws and their clusters.
    """
    from bayescalib.inference.resampling import systematic_resample

    P = np.atleast_2d(np.asarray(particles, float))
    W = np.asarray(weights, float)
    W = W / W.sum()
    order = (np.arange(P.shape[0]) if labels is None
             else np.argsort(np.asarray(labels, int), kind="stable"))
    seen = {tuple(x) for x in (np.empty((0, P.shape[1])) if exclude is None
                               else np.atleast_2d(np.asarray(exclude, float)))}
    step = int(batch) if batch and int(batch) > 0 else max(int(n), 1)
    picks = []
    for start in range(0, int(n), step):
        m = min(step, int(n) - start)
        picks.extend(order[systematic_resample(W[order], rng, m)].tolist())
    out, got = [], []
    for i in picks:
        for _ in range(100):
            if tuple(P[i]) not in seen:
                break
            i = int(rng.choice(P.shape[0], p=W))
        seen.add(tuple(P[i]))
        out.append(P[i])
        got.append(i)
    D = np.asarray(out, float).reshape(int(n), P.shape[1])
    if labels is None:
        return D
    return D, np.asarray(labels, int)[np.asarray(got, int)]


#: clusters of the posterior (:func:`posterior_clusters`) lighter than this are merged into
#: their nearest heavier one: a cluster must get draws at every look of a sequential check
MIN_CLUSTER_MASS = 0.1
#: single-linkage cut between clusters, in median nearest-neighbour distances of the
#: resampled particles (standardized by the posterior sd)
CLUSTER_GAP = 6.0
#: resampled particles the clusters are found among
CLUSTER_POINTS = 1000


def posterior_clusters(particles: np.ndarray, weights: np.ndarray,
                       seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """The separated clusters (modes) of an SMC posterior: (N,) labels of the particles
    and (C,) the clusters' masses, heaviest first.

    ``CLUSTER_POINTS`` particles resampled with the weights (duplicates dropped), in
    coordinates standardized by the posterior sd, are cut by single linkage at
    ``CLUSTER_GAP`` times their median nearest-neighbour distance; every particle takes
    its nearest resampled point's cluster, and clusters lighter than ``MIN_CLUSTER_MASS``
    join the heavier cluster nearest to their particles. The sequential check's mass test
    (:func:`bayescalib.inference.importance.cluster_mass_test`) stratifies by these
    clusters; any partition fixed before the draws are solved keeps its error rates
    (post-stratification), so a ridge cut in two or an isolated tail is harmless: it
    only asks the mass test about the pieces.
    """
    from scipy.cluster.hierarchy import fcluster, linkage
    from scipy.spatial import cKDTree

    from bayescalib.inference.resampling import systematic_resample

    P = np.atleast_2d(np.asarray(particles, float))
    W = np.asarray(weights, float)
    W = W / W.sum()
    N = P.shape[0]
    single = (np.zeros(N, int), np.ones(1))
    m = W @ P
    sd = np.sqrt(np.maximum(W @ (P - m) ** 2, 0.0))
    U = (P - m) / np.where(sd > 0, sd, 1.0)
    idx = np.unique(systematic_resample(W, np.random.default_rng([int(seed), 0xC1A5]),
                                        min(CLUSTER_POINTS, N)))
    Uu = np.unique(U[idx], axis=0)
    if Uu.shape[0] < 4:
        return single
    nn = cKDTree(Uu).query(Uu, k=2)[0][:, 1]
    cut = CLUSTER_GAP * float(np.median(nn))
    if not cut > 0:
        return single
    lab_u = fcluster(linkage(Uu, "single"), cut, "distance") - 1
    lab = lab_u[cKDTree(Uu).query(U, k=1)[1]]
    mass = np.bincount(lab, weights=W)
    big = np.flatnonzero(mass >= MIN_CLUSTER_MASS)
    if big.size <= 1:
        return single
    in_big = np.isin(lab, big)
    if not in_big.all():
        lab[~in_big] = lab[in_big][cKDTree(U[in_big]).query(U[~in_big], k=1)[1]]
    mass = np.bincount(lab, weights=W)
    order = big[np.argsort(-mass[big], kind="stable")]
    relabel = np.full(lab.max() + 1, -1)
    relabel[order] = np.arange(order.size)
    return relabel[lab], mass[order]


def round_posterior_check(batch: Mapping[str, Any], L: np.ndarray,
                          posterior_check: Mapping[str, Any],
                          names: Sequence[str], checked_round: int,
                          posterior: Mapping[str, Any] | None = None, *,
                          cluster_mass: Sequence[float] | None = None, look: int = 1,
                          n_looks: int = 1, final: bool = True,
                          max_draws: int | None = None) -> dict[str, Any]:
    """One look of the sequential posterior check
    (:func:`~bayescalib.inference.importance.sequential_check`) of a check round: the
    real log-likelihoods ``L`` (q,) of the draws ``batch["points"]`` solved so far
    against the surrogate's ``batch["mean"]`` recorded when they were drawn, with their
    clusters ``batch["cluster"]`` (absent: one cluster) of masses ``cluster_mass``;
    ``posterior`` (the checked round's record, ``mean`` and ``sd``): the draws must
    represent it. ``look``, ``n_looks``, ``final``, ``max_draws``: as
    :func:`~bayescalib.inference.importance.sequential_check` (the defaults: one look at
    every draw). The per-parameter lists are keyed by name; ``round`` is the round whose
    posterior was checked; ``decision`` is ``confirmed``, ``refuted`` or ``continue``."""
    res = _sequential_check(batch["points"], L, batch["mean"], posterior_check,
                            labels=batch.get("cluster"), cluster_mass=cluster_mass,
                            look=look, n_looks=n_looks, final=final, max_draws=max_draws,
                            posterior_mean=None if posterior is None else posterior["mean"],
                            posterior_sd=None if posterior is None else posterior["sd"])
    for key in ("mean_q", "sd_q", "mean_is", "sd_is", "shift_sd", "shift_se", "sd_ratio",
                "draws_shift_sd", "draws_sd_ratio"):
        if key in res:
            res[key] = dict(zip(names, res[key], strict=True))
    return {"round": int(checked_round), **res}


def final_posterior_check(X: np.ndarray, L: np.ndarray, surrogate_mean: np.ndarray,
                          particles: np.ndarray, weights: np.ndarray,
                          posterior_check: Mapping[str, Any]) -> dict[str, Any]:
    """The posterior check of a fixed design: the draws ``X`` (S, d) of the final
    posterior (equally weighted resamples of its ``particles``, (N, d), ``weights``)
    with their real log-likelihoods ``L`` (S,) and the surrogate's ``surrogate_mean``
    (S,), judged in one look by the tests of the active rounds' check
    (:func:`~bayescalib.inference.importance.sequential_check` with every draw solved):
    the importance check and the mass test of the posterior's clusters
    (:func:`posterior_clusters`; each draw in its particle's cluster), so that a
    posterior whose separated modes carry masses off by more than
    ``posterior_check.mass_tol`` is not confirmed here either. One cluster: the
    importance check's verdict. ``posterior_check``: the validated section."""
    from scipy.spatial import cKDTree

    P = np.atleast_2d(np.asarray(particles, float))
    X = np.atleast_2d(np.asarray(X, float))
    labels, masses = posterior_clusters(P, weights)
    lab = labels[cKDTree(P).query(X, k=1)[1]]
    m = posterior_moments(P, np.asarray(weights, float))
    return _sequential_check(X, L, surrogate_mean, posterior_check, labels=lab,
                             cluster_mass=masses, posterior_mean=m["mean"],
                             posterior_sd=m["sd"])


def _sequential_check(X, L, surrogate_mean, posterior_check: Mapping[str, Any],
                      **kw: Any) -> dict[str, Any]:
    """:func:`~bayescalib.inference.importance.sequential_check` with the thresholds of
    the validated ``posterior_check`` section (``kw``: the look and the clusters)."""
    from bayescalib.inference.importance import sequential_check

    return sequential_check(np.asarray(X, float), np.asarray(L, float),
                            np.asarray(surrogate_mean, float),
                            mass_tol=posterior_check["mass_tol"],
                            alpha=posterior_check["alpha"],
                            min_ess_fraction=posterior_check["min_ess_fraction"],
                            shift_tol=posterior_check["shift_tol"],
                            sd_tol=posterior_check["sd_tol"],
                            max_log_weight_sd=posterior_check["max_log_weight_sd"],
                            max_failed_fraction=posterior_check["max_failed_fraction"], **kw)


def check_points(particles: np.ndarray, weights: np.ndarray, bounds: np.ndarray, n: int,
                 rng: np.random.Generator) -> np.ndarray:
    """Points of the trust check that the surrogate does not choose, (n, d) in user units.

    Each is a resampled particle plus a Gaussian step with the posterior covariance
    (the posterior convolved with itself: its spread times sqrt 2 in every direction),
    reflected into the box. They are drawn at random, not by the GP's variance: a GP
    that is confident without evidence (a surrogate posterior too narrow, its rim
    predicted far below the truth with a small variance) is never where an
    uncertainty-driven acquisition looks, and the trust check tests only where the
    batch goes. For a correct posterior they lie mostly inside its 99 % region, where
    the surrogate must be accurate anyway; for a Gaussian one that is k times too
    narrow in d dimensions, they lie in the true posterior's core while the surrogate
    predicts them d (1 - 1/k^2) nats too low on average (a drop of d nats from the
    mode where the truth drops d/k^2), so the trust check fails once that exceeds
    ``gp_tol``.
    """
    from bayescalib.inference.resampling import systematic_resample

    b = np.asarray(bounds, float)
    lo, width = b[:, 0], b[:, 1] - b[:, 0]
    U = (np.atleast_2d(np.asarray(particles, float)) - lo) / width
    W = np.asarray(weights, float)
    cov = posterior_moments(U, W)["cov"]
    d = U.shape[1]
    Lc = np.linalg.cholesky(cov + 1e-10 * np.eye(d))  # a degenerate cloud still draws
    base = U[systematic_resample(W / W.sum(), rng, int(n))]
    return lo + _reflect(base + rng.standard_normal((int(n), d)) @ Lc.T) * width


def _loglik_var_scale(gp, g: np.ndarray) -> np.ndarray:
    """(dL/dg)^2 at latent values g: var(L) = this times var(g) (delta method when
    warped, L = B - expm1(g); 1 otherwise)."""
    return np.exp(2.0 * np.maximum(g, 0.0)) if gp.warped else np.ones_like(g)


def _predict_loglik(gp, X: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The surrogate's log-likelihood mean and sd at X (M,), as :func:`select_batch`
    reports them for its picks (an output emulator's
    :class:`~bayescalib.inference.emulator.EmulatedLikelihood`: its marginal
    log-likelihood and the sd of the plug-in one)."""
    if not hasattr(gp, "predict_latent"):
        mean, var = gp.predict(X, return_var=True)
        return np.asarray(mean, float), np.sqrt(np.maximum(var, 0.0))
    g, var_g = gp.predict_latent(X, return_var=True)
    return gp.loglik_from_latent(g), np.sqrt(_loglik_var_scale(gp, g) * np.maximum(var_g, 0.0))


def _why_not(rec: Mapping[str, Any], stop_cfg: Mapping[str, Any],
             posterior_check: Mapping[str, Any],
             budget_left: int) -> str:
    """Plain words: why round ``rec`` has not converged (the posterior check's verdict,
    the posterior's change, the trust check's numbers)."""
    if rec["trust"] is None:
        return "round 0 has no out-of-sample check yet."
    parts = []
    t, c, pc = rec["trust"], rec["change"], rec.get("posterior_check")
    if t.get("n_batch") and t.get("n_batch_failed") == t["n_batch"]:
        # nothing was learnt this round: say so first, and where to look
        parts.append(f"every one of the {t['n_batch']} solves of the last batch failed, so the "
                     f"surrogate learnt nothing new (their run records give the reasons; a "
                     f"wall-clock time limit points at the machine's load or at "
                     f"forward_model.time_limit_s)")
    if not rec.get("explored", True):
        parts.append(_unexplored_words(rec))
    if pc is not None:
        if pc.get("decision") == "superseded":
            parts.append(f"the posterior check of round {pc['round']} was {pc['words']}")
        elif not pc["confirmed"]:
            parts.append(f"the posterior of round {pc['round']} was NOT confirmed by real "
                         f"solves of its draws ({pc['words']})")
        else:
            moved = (f" (its clusters' masses by {pc['mass_change_since_checked']:.3g}, "
                     f"tolerance posterior_check.mass_tol {posterior_check['mass_tol']:g})"
                     if not pc.get("mass_settled", True) else "")
            parts.append(f"the posterior of round {pc['round']} was confirmed by real solves "
                         f"of its draws, but it moved when they were added{moved}")
    if not rec["settled"]:
        parts.append(f"the posterior moved by {c['shift_sd']:.3g} sd (tolerance "
                     f"{stop_cfg['shift_tol']:g}) and its sd changed by {c['sd_change']:.3g} "
                     f"(tolerance {stop_cfg['sd_tol']:g})")
    elif pc is None and int(posterior_check["draws"]) > 0:
        parts.append(f"the posterior settled in {rec['settled_streak']} round(s) in a row, "
                     f"{stop_cfg['patience']} needed before its posterior check")
    elif pc is None and t["passed"]:
        parts.append(f"settled and trusted in {rec['settled_streak']} round(s) in a row, "
                     f"{stop_cfg['patience']} needed")
    n_draws = int(posterior_check["draws"])
    first = min(int(posterior_check["batch"]) or n_draws, n_draws)
    if first > budget_left and (pc is None or not pc["confirmed"]):
        parts.append(f"the posterior check's first {first} draws do not fit in the "
                     f"{max(budget_left, 0)} solve(s) left of the budget")
    if not t["passed"]:  # decides only without check rounds (posterior_check.draws 0)
        if t["n_region"] == 0:
            parts.append("no new solve fell in the posterior region")
        else:
            parts.append(f"the surrogate missed new solves in the posterior region by up to "
                         f"{t['max_abs_error']:.3g} nats (tolerance {stop_cfg['gp_tol']:g}; RMS "
                         f"{t['rms_error']:.3g} nats over {t['n_region']} point(s))")
            under = t.get("check_max_underprediction")
            if under is not None and under > stop_cfg["gp_tol"]:
                parts.append(f"a random check point in the posterior region has a log-likelihood "
                             f"{under:.3g} nats above the surrogate's prediction: the surrogate "
                             f"posterior is likely too narrow")
    return "; ".join(parts) + "."


def _unexplored_words(rec: Mapping[str, Any]) -> str:
    """Plain words: the basins of the solves that the posterior does not hold."""
    e = rec["exploration"]
    b = e["basins"][0]
    where = ", ".join(f"{n} = {v:.4g}" for n, v in zip(rec["names"], b["peak"], strict=True))
    more = (f" ({len(e['basins'])} such basins)" if len(e["basins"]) > 1 else "")
    return (f"the solves rise towards a region the posterior does not hold: a quadratic "
            f"through the solve of log-likelihood {b['loglik']:.4g} and its neighbours peaks "
            f"near {where}, where up to {100 * e['unexplored_mass']:.0f} % of the posterior "
            f"mass could lie{more}; it is probed next")


def _explored_words(rec: Mapping[str, Any]) -> str:
    """Plain words: what the verdict answers for outside the posterior."""
    e = rec["exploration"]
    return (f"no basin of the solves outside it could hold more than "
            f"{100 * e['unexplored_mass']:.2g} % of the mass (modes narrower than the design's "
            f"spacing, {e['fill_distance']:.2g} of the box at most, are not seen)")


# ------------------------------------------------------------- in-process driver
def history_table(rounds: Sequence[Mapping[str, Any]]) -> list[dict[str, Any]]:
    """Compact per-round history for summary.json (no batches, no covariances)."""
    out = []
    for rec in rounds:
        t, c, pc = rec.get("trust"), rec.get("change"), rec.get("posterior_check")
        out.append({
            "round": rec["round"], "n_solves": rec["n_solves"], "n_failed": rec["n_failed"],
            "posterior_mean": dict(zip(rec["names"], rec["posterior"]["mean"], strict=True)),
            "posterior_sd": dict(zip(rec["names"], rec["posterior"]["sd"], strict=True)),
            "log_evidence": rec["posterior"]["log_evidence"],
            "gp_max_error_nats": None if t is None else t["max_abs_error"],
            "gp_points_in_region": None if t is None else t["n_region"],
            "shift_sd": None if c is None else c["shift_sd"],
            "sd_change": None if c is None else c["sd_change"],
            "hellinger": None if c is None else c["hellinger"],
            "settled": rec["settled"],
            "posterior_check_confirmed": None if pc is None else bool(pc["confirmed"]),
            "log_weight_sd": None if pc is None else pc.get("log_weight_sd"),
            "ess_fraction": None if pc is None else pc.get("ess_fraction"),
            "explored": rec.get("explored"),
            "unexplored_mass": (rec.get("exploration") or {}).get("unexplored_mass"),
            "unexplored_peak": _first_peak(rec),
            "fill_distance": (rec.get("exploration") or {}).get("fill_distance"),
        })
    return out


def _first_peak(rec: Mapping[str, Any]) -> dict[str, float] | None:
    """The estimated peak of the largest basin the posterior does not hold, by name."""
    basins = (rec.get("exploration") or {}).get("basins") or []
    if not basins:
        return None
    return dict(zip(rec["names"], basins[0]["peak"], strict=True))
