"""Posterior check by importance sampling with real solves.

(The posterior check, not the trust check, the fit check or the diagnosis's predictive
check: docs/glossary.md.)

The surrogate posterior q(x) ∝ p(x) exp(mu(x)) (paper eq. posterior with the GP mean
mu in place of the log-likelihood L) is what the SMC samples. The posterior the user
wants is pi(x) ∝ p(x) exp(L(x)). Solving the forward model at S draws x_s ~ q gives
L(x_s), and the log importance weights

    log w_s = L(x_s) - mu(x_s)          (up to a constant: the prior cancels)

are all that is needed to judge q against pi where q puts its mass:

* their spread: a surrogate that is exact up to a constant gives equal weights. For
  small errors, KL(q || pi) ≈ Var_q(log w) / 2 (second-order expansion of the log
  normalizer), so the sd of the log weights is the surrogate's error *as it acts on
  the posterior*, in nats, whatever the dimension;
* Kish's effective sample size ESS = (sum w)^2 / sum w^2 (paper eq. ess), as a
  fraction of S;
* the Pareto shape k of the weights' upper tail (PSIS, Vehtari, Simpson, Gelman, Yao
  and Gabry 2024, "Pareto smoothed importance sampling", JMLR 25): k < 0.7 means the
  self-normalized estimates below are reliable; above it, pi has mass that q misses
  (a surrogate posterior too narrow or missing a mode), and no number of draws from q
  repairs it. The generalized Pareto fit is the empirical-Bayes estimate of Zhang and
  Stephens (2009, Technometrics 51), shrunk towards 0.5 by a prior worth 10
  observations as in PSIS, to the M = ceil(min(0.3 S, 3 sqrt(S))) largest weights:
  PSIS's large-sample tail 3 sqrt(S) (the same M as PSIS's from S = 225 on), with its
  small-sample cap 0.2 S relaxed to 0.3 S (20 weights at 64 draws instead of 13). A
  shape fitted to 13 weights has a sampling sd of about (1 + k) / sqrt(13) ~ 0.3, and,
  being scale-free, it reads any rise of the largest weights, however small, as a tail.
  Measured (benchmarks/bench_pareto_k.py, 500 seeded replicates a cell; docs/
  bench_active.md, "The Pareto-k test at 50-256 draws"), at 64 draws, PSIS's tail ->
  this one, refused by k: right posteriors (q = pi, the surrogate off by 0.1-0.6 nats)
  in 1-D with a bounded smooth error (true k < 0) 9-11 -> 4-9 %, with the sd-ratio
  study's smooth error 16-23 -> 4-11 %, with noise, and in 7-D, 0-4 -> 0-1 %; a missed
  lobe (20 % of pi's mass 4 sd from q's) 90-91 -> 98 %, at 3 sd 74-75 -> 88-89 %; a
  Student-t3 pi under a Gaussian q of its scale 88-89 -> 94-96 %; a q half as wide in
  one direction 34-35 -> 36 % (the whole check: 97-98 % either way). The candidates
  not taken: PSIS's sample-size threshold min(1 - 1/log10(S), 0.7) (0.45 at 64 draws)
  refuses 5-38 % of these right posteriors (PSIS's tail: 0-23 %; 7-D, noise 0.4 nats:
  2 -> 12 %); not
  judging k where the weights are nearly equal (largest normalized weight below 2 / S,
  or log-weight sd below 0.3 nats) or below 100 draws gives the missed lobe away
  (90-91 -> 44-45, 11-12 and 0 %, the whole check 16-19 %: a lobe just beyond the draws
  leaves the weights *more* nearly equal, log-weight sd 0.08 nats, than a right
  posterior's small error does); a threshold of 0.9 or 1.0 cuts the false refusals by
  a half to two thirds and loses 14-25 points of the 4-sd lobe's detection (21-33 at
  3 sd). With fewer than ``MIN_DRAWS`` = 50 draws k is not estimated (at 32 draws,
  the pipeline's default, the smoke study saw k 0.92 on weights of sd 0.11 nats), and
  the check's words say so. From 225 draws on M is PSIS's, and so are its refusals:
  1-D right posteriors are refused by k in 9-12 % (bounded error) and 23-34 % (the
  smooth error, whose pi has up to several times q's mass beyond 3 sd: partly true
  refusals) at 256 draws;
* the importance-sampling estimates of pi's mean and sd (self-normalized), their
  shift from q's in q's sd, and the Monte Carlo standard error of that shift
  (sd_q / sqrt(ESS) per parameter, the delta-method error of a self-normalized mean).

Draws whose solve failed carry no log-likelihood; they are counted and left out of
the estimates, and their share of the draws estimates the posterior mass where the
model cannot be solved, where the surrogate's values are extrapolations that no solve
can check. A check is *confirmed* only when that share is at most
``max_failed_fraction`` (with 32 draws and the default 0.1, three failures pass and
four do not: a posterior with 20 % of its mass where solves fail passes in 11 % of
checks, one with 5 % is refused in 7 %, binomial), k < 0.7 (or was not estimated),
ESS / S >= ``min_ess_fraction``, every mean
shift is within ``shift_tol`` sd plus twice its Monte Carlo error, every sd ratio
within a factor 1 + ``sd_tol`` and the log-weights' sd is at most
``max_log_weight_sd`` nats: then pi and q agree where q lives, as far as S solves can
tell. The last one is the surrogate's error where the posterior lives, stated in nats:
for log-normal weights ESS ≈ exp(-sd^2), so ESS >= 1/2 already bounds it by 0.83 nats,
but spurious surrogate mass (draws where the real likelihood is far below the
surrogate's: weights near 0) leaves the ESS high and shows only in the spread. With few draws the sd ratio is the most sensitive of these: for a surrogate
posterior half as wide as the real one (1-D Gaussians), 32 draws give an sd ratio of
1.4-1.7 in every seed tried (tests/test_importance.py), while the tail needs more
draws than that to show. A
surrogate can still miss mass far from where q lives (a second mode no draw reaches):
that is the active design's exploration's and the trust check's job, not this check's.

Sequential check (issue 38; :func:`sequential_check`, the active rounds' posterior
check). The draws (``posterior_check.draws``, at most) are solved in looks of
``posterior_check.batch`` (8), each look a stratified resample of the posterior (below),
and after each look every draw solved so far is judged:

* a *mass test* (:func:`cluster_mass_test`): the surrogate posterior's particles are cut
  into separated clusters (``active.posterior_clusters``: single linkage, clusters under
  10 % of the mass merged into a neighbour); the real posterior's mass of each,
  estimated from the draws by importance weights post-stratified by cluster
  (pi_c = q_c r_c / sum q_j r_j, r_c the mean weight of the draws in c), with a
  delta-method standard error, against the surrogate's mass q_c. A surrogate exact in
  shape inside each mode but wrong in their masses gives log-weights constant per
  cluster and nearly equal overall (sd 0.1 nats for 73 / 27 % against 68 / 32 %): the
  fixed tests above pass it (measured: every seed), while the mass test reads the
  difference from a few draws per cluster. The draws are stratified by cluster (the
  particles ordered by cluster before each look's systematic resample), so a cluster of
  q_c gets within one of its share of every look;
* early looks: *confirmed* when every fixed test passes, every cluster's mass is within
  ``mass_tol`` with confidence (|D_c| + z se_c <= mass_tol, at least 3 draws in each
  cluster) and the log-weights' sd is below ``clear_log_weight_sd`` (0.2 nats: a
  Gaussian posterior off by the tolerances, 0.2 sd in a mean or a factor 1.2 in an sd,
  has log-weights of sd >= 0.2 nats) with confidence (chi-square bound); *refuted* when
  a cluster's mass is off by more than ``mass_tol`` with confidence (|D_c| - z se_c >
  mass_tol), the log-weights' sd is above ``max_log_weight_sd`` with confidence, or the
  failed draws' share is above ``max_failed_fraction`` with confidence (Clopper-Pearson);
  else the next look;
* the last look (all draws solved): confirmed when the fixed tests pass and the masses
  are within ``mass_tol`` with confidence, else refuted. A last look the budget cut
  short confirms only as an early look does.

Error rates, as designed: the confidence bounds spend ``alpha`` (0.05) over the looks,
alpha / 2 at the last and alpha / (2 (K - 1)) at each of the K - 1 early ones (union
bound), one-sided z. (i) False confirmation of a posterior whose cluster masses are off
by more than ``mass_tol`` (0.05): at most alpha, up to the normal approximation of the
self-normalized estimate. (ii) False *early* refutation of a posterior within the
tolerances: at most alpha. (iii) Everything the fixed check refuses at 32 draws the
sequential check refuses as well or better, since its early confirmation asks more
(the fixed tests on fewer draws *and* a log-weight sd below 0.2 nats with confidence):
its false-confirmation rates are those of the fixed check, not better (a mean 0.5 sd
off passes the fixed test |shift| <= shift_tol + 2 MC errors, about 0.55 sd at 32
draws, in 90 % of checks). (iv) Not controlled: a right multi-cluster posterior whose
surrogate errs by much at the draws is refused at the last look when its masses cannot
be bounded within ``mass_tol``: the standard error of D_c is about q(1 - q) sigma
sqrt(1/n_1 + 1/n_2) for log-weight noise sigma, 0.023 at sigma 0.3 nats, 32 draws and
73 / 27 %, and the bound |D| + 1.96 se then exceeds 0.05 in most checks.
Measured (benchmarks/bench_sequential_check.py, 400 seeds a case, docs/
bench_sequential_check.md): false refutation 0-0.5 % and false confirmation of the 5 %
and 10 % mass shifts 0-5 % at 0.02-0.1 nats of surrogate noise, with 8-17 draws on
average on the right posteriors instead of 32; at 0.3 nats the right two-mode posterior
is refused in most checks (iv).
Pure functions over arrays.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

__all__ = ["cluster_mass_test", "importance_check", "pareto_k", "sequential_check",
           "tail_size"]

#: PSIS threshold on the Pareto shape above which importance-sampling estimates are unreliable
K_RELIABLE = 0.7
#: fewest draws from which the Pareto shape is estimated: from a tail of 7 (32 draws) the
#: fitted shape of nearly equal weights came out anywhere up to 0.9 (the smoke study:
#: log-weight sd 0.11 nats, ESS 99 %, k 0.92)
MIN_DRAWS = 50
#: fewest positive exceedances a Pareto shape is fitted to
MIN_TAIL = 10
#: fraction of the draws the tail holds at most (PSIS: 0.2; module docstring)
TAIL_FRACTION = 0.3


def tail_size(S: int) -> int:
    """Number of largest weights the Pareto shape is fitted to: ceil(min(0.3 S, 3 sqrt S)),
    PSIS's large-sample tail 3 sqrt S from S = 100 on (PSIS's own M from S = 225 on:
    below, PSIS caps it at 0.2 S; module docstring)."""
    return math.ceil(min(TAIL_FRACTION * S, 3.0 * math.sqrt(S)))


def _gpd_shape(excess: np.ndarray) -> float:
    """Shape xi of a generalized Pareto distribution fitted to positive exceedances
    (sorted ascending), by Zhang and Stephens' (2009) empirical-Bayes estimate.

    With theta = -xi / sigma the profile maximum-likelihood shape is
    xi(theta) = mean(log(1 - theta x)) and the profile log-likelihood
    l(theta) = n (log(-theta / xi(theta)) - xi(theta) - 1). theta is averaged over a
    grid of m = 30 + floor(sqrt(n)) values, weighted by exp(l) (the posterior mean
    under their prior), and xi is its profile value there.
    """
    x = np.asarray(excess, float)
    n = x.size
    m = 30 + int(math.sqrt(n))
    j = np.arange(1, m + 1, dtype=float)
    quartile = x[max(int(n / 4 + 0.5) - 1, 0)]
    theta = 1.0 / x[-1] + (1.0 - np.sqrt(m / (j - 0.5))) / (3.0 * quartile)
    xi = np.log1p(-np.outer(theta, x)).mean(axis=1)
    prof = n * (np.log(-theta / xi) - xi - 1.0)
    w = np.exp(prof - prof.max())
    w /= w.sum()
    theta_hat = float(np.sum(w * theta))
    return float(np.log1p(-theta_hat * x).mean())


def pareto_k(log_weights: np.ndarray) -> float | None:
    """PSIS diagnostic: the Pareto shape of the upper tail of the importance weights.

    Parameters
    ----------
    log_weights
        (S,) finite log importance weights (any constant offset).

    Returns
    -------
    float or None
        The shape k of a generalized Pareto fit to the M = :func:`tail_size` (S) =
        ceil(min(0.3 S, 3 sqrt(S))) largest weights above the next largest, shrunk as in
        PSIS: (M k + 10 * 0.5) / (M + 10). None when S < ``MIN_DRAWS`` (too few draws) or
        the tail is flat (fewer than ``MIN_TAIL`` of its weights above the next largest,
        or all equal: k = -inf in the limit, reported as None).
    """
    lw = np.sort(np.asarray(log_weights, float))
    S = lw.size
    M = tail_size(S)
    if S < MIN_DRAWS or S < M + 1:
        return None
    w = np.exp(lw - lw[-1])
    excess = w[S - M:] - w[S - M - 1]
    if not np.all(excess > 0):  # ties with the threshold: drop them
        excess = excess[excess > 0]
    if excess.size < MIN_TAIL or excess[-1] <= excess[0] * (1 + 1e-12):
        return None
    k = _gpd_shape(excess)
    n = excess.size
    return float((n * k + 10 * 0.5) / (n + 10))


#: z-score of the test that the draws represent the posterior they were drawn from (their
#: sample mean and sd against the posterior's): two-sided 3.5 sigma, 5e-4 per test, about
#: 0.6 % for 7 parameters' means and sds together when the draws do represent it
REPRESENT_Z = 3.5


def importance_check(X: np.ndarray, loglik: np.ndarray, surrogate_mean: np.ndarray, *,
                     min_ess_fraction: float = 0.5, shift_tol: float = 0.2,
                     sd_tol: float = 0.2, max_log_weight_sd: float = 1.0,
                     max_failed_fraction: float = 0.1,
                     posterior_mean: np.ndarray | None = None,
                     posterior_sd: np.ndarray | None = None) -> dict[str, Any]:
    """Compare the surrogate posterior with the real one at real solves of its draws.

    Parameters
    ----------
    X
        (S, d) equally weighted draws of the surrogate posterior (resampled particles).
    loglik
        (S,) real log-likelihoods there (-inf or NaN: failed solve, left out).
    surrogate_mean
        (S,) the surrogate's log-likelihood (its mean) at the same draws.
    min_ess_fraction, shift_tol, sd_tol, max_log_weight_sd, max_failed_fraction
        Thresholds of the verdict (module docstring).
    posterior_mean, posterior_sd
        (d,) the moments of the whole surrogate posterior the draws come from (its
        weighted particles), or None. Given, the draws must represent it: their sample
        mean within ``REPRESENT_Z / sqrt(S)`` posterior sd of its mean and their sd within a
        factor ``exp(REPRESENT_Z / sqrt(2 (S - 1)))`` of its sd (the sampling spread of a
        Gaussian's mean and sd, 3.5 sigma). The importance estimates above are moments of
        the draws; a tail of the posterior that S draws seldom reach (mass where the
        surrogate is unsure and few solves are) leaves them unchanged while it inflates
        the sd the user reads, so a check whose draws missed it is not a check of that
        posterior. Measured on the heterogeneous FSI study with the output emulator: 6 %
        of the mass in a tail to E2 > 300 Pa made the posterior's sd of E2 111 Pa (its
        interquartile range 138-220 Pa), while 32 draws had an sd of 51 Pa and confirmed.

    Returns
    -------
    dict
        ``n_draws``, ``n_failed``, ``log_weight_sd`` (nats), ``kl_estimate``
        (Var(log w) / 2), ``ess_fraction``, ``pareto_k`` (None: not estimable),
        ``mean_q``, ``sd_q``, ``mean_is``, ``sd_is`` (d,), ``shift_sd`` (d,: IS mean minus
        q's, in q's sd), ``shift_se`` (d,: its Monte Carlo standard error, same units),
        ``sd_ratio`` (d,: IS sd over q's), ``confirmed`` (bool), the thresholds, and
        ``words`` (one sentence); with the posterior's moments also ``draws_shift_sd``
        and ``draws_sd_ratio`` (d,: the draws' mean minus the posterior's, in its sd; the
        draws' sd over its) and ``representative`` (bool).
    """
    X = np.atleast_2d(np.asarray(X, float))
    L = np.asarray(loglik, float)
    mu = np.asarray(surrogate_mean, float)
    if not (X.shape[0] == L.size == mu.size):
        raise ValueError(f"importance_check: {X.shape[0]} draws, {L.size} log-likelihoods and "
                         f"{mu.size} surrogate values must agree")
    ok = np.isfinite(L) & np.isfinite(mu)
    S = int(ok.sum())
    n_failed = int((~ok).sum())
    failed_fraction = n_failed / max(int(L.size), 1)
    out: dict[str, Any] = {"n_draws": int(L.size), "n_failed": n_failed,
                           "failed_fraction": failed_fraction,
                           "max_failed_fraction": float(max_failed_fraction)}
    if S < 2:
        out.update(confirmed=False, words=(
            f"posterior check not possible: {S} of {L.size} draws solved (the posterior "
            f"lies where the model cannot be solved)"))
        return out
    Xs = X[ok]
    lw = L[ok] - mu[ok]
    W = np.exp(lw - lw.max())
    W /= W.sum()
    ess = 1.0 / float(np.sum(W**2))
    mean_q = Xs.mean(axis=0)
    sd_q = Xs.std(axis=0)
    mean_is = W @ Xs
    sd_is = np.sqrt(np.maximum(W @ (Xs - mean_is) ** 2, 0.0))
    scale = np.where(sd_q > 0, sd_q, 1.0)
    shift = (mean_is - mean_q) / scale
    shift_se = sd_is / scale / math.sqrt(ess)
    k = pareto_k(lw)
    lsd = float(np.std(lw, ddof=1))
    ess_frac = ess / S
    tail_ok = k is None or k < K_RELIABLE
    shift_ok = bool(np.all(np.abs(shift) <= shift_tol + 2.0 * shift_se))
    ratio = sd_is / scale
    sd_ok = bool(np.all((ratio <= 1.0 + sd_tol) & (ratio >= 1.0 / (1.0 + sd_tol))))
    spread_ok = lsd <= max_log_weight_sd
    represent_ok = True
    if posterior_sd is not None:
        p_sd = np.asarray(posterior_sd, float).reshape(-1)
        p_scale = np.where(p_sd > 0, p_sd, 1.0)
        d_shift = (mean_q - np.asarray(posterior_mean, float).reshape(-1)) / p_scale
        d_ratio = sd_q / p_scale
        band = math.exp(REPRESENT_Z / math.sqrt(2.0 * (S - 1)))
        represent_ok = bool(np.all(np.abs(d_shift) <= REPRESENT_Z / math.sqrt(S))
                            and np.all((d_ratio <= band) & (d_ratio >= 1.0 / band)))
        out.update(draws_shift_sd=d_shift.tolist(), draws_sd_ratio=d_ratio.tolist(),
                   representative=represent_ok)
    solved_ok = failed_fraction <= max_failed_fraction
    confirmed = bool(solved_ok and tail_ok and ess_frac >= min_ess_fraction and shift_ok
                     and sd_ok and spread_ok and represent_ok)
    out.update(
        log_weight_sd=lsd, kl_estimate=0.5 * lsd**2, ess_fraction=float(ess_frac),
        pareto_k=k, mean_q=mean_q.tolist(), sd_q=sd_q.tolist(), mean_is=mean_is.tolist(),
        sd_is=sd_is.tolist(), shift_sd=shift.tolist(), shift_se=shift_se.tolist(),
        sd_ratio=ratio.tolist(), confirmed=confirmed,
        min_ess_fraction=float(min_ess_fraction), shift_tol=float(shift_tol),
        sd_tol=float(sd_tol), max_log_weight_sd=float(max_log_weight_sd))
    if k is not None:
        k_words = f"Pareto k {k:.2f}"
    elif S < MIN_DRAWS:
        k_words = (f"Pareto k not judged (its tail is estimated from {MIN_DRAWS} draws on, "
                   f"{S} solved)")
    else:
        k_words = "Pareto k not judged (the largest weights are equal: no tail)"
    failed_words = f" ({n_failed} of {L.size} draws failed to solve)" if n_failed else ""
    head = (f"{S} real solves of posterior draws{failed_words}: log-weight sd {lsd:.2g} nats, ESS "
            f"{100 * ess_frac:.0f} %, {k_words}, largest "
            f"mean shift {np.max(np.abs(shift)):.2g} sd (MC error {np.max(shift_se):.2g}), sd "
            f"ratio {np.min(ratio):.2f}-{np.max(ratio):.2f}")
    if confirmed:
        out["words"] = head + ": the real posterior agrees with the surrogate's where it lives."
    else:
        why = []
        if not solved_ok:
            why.append(f"{n_failed} of {L.size} draws could not be solved: about "
                       f"{100 * failed_fraction:.0f} % of the posterior lies where the model "
                       f"fails (above {100 * max_failed_fraction:g} %), and the surrogate's "
                       f"values there are extrapolations no solve checks")
        if not tail_ok:
            why.append(f"Pareto k >= {K_RELIABLE}: the real posterior has mass the surrogate's misses")
        if ess_frac < min_ess_fraction:
            why.append(f"ESS below {100 * min_ess_fraction:.0f} %")
        if not shift_ok:
            why.append(f"a mean moves by more than {shift_tol:g} sd")
        if not sd_ok:
            why.append(f"an sd changes by more than a factor {1 + sd_tol:g}")
        if not spread_ok:
            why.append(f"the log-weights spread by more than {max_log_weight_sd:g} nats")
        if not represent_ok:
            why.append(f"the draws do not represent the posterior they were drawn from (their "
                       f"sd {np.min(d_ratio):.2f}-{np.max(d_ratio):.2f} of its, mean off by up to "
                       f"{np.max(np.abs(d_shift)):.2g} of its sd): a tail of it that "
                       f"{S} draws did not reach is unchecked")
        out["words"] = head + ": NOT confirmed (" + "; ".join(why) + ")."
    return out


# ------------------------------------------------------------ sequential check
#: fewest draws of a cluster before its mass is judged at an early look (at the last look: 2)
MIN_CLUSTER_DRAWS = 3
#: floor on the sd of a cluster's log-weights (nats) in the mass test's standard error: a
#: surrogate exact up to a constant per cluster gives equal weights and no spread to estimate
MASS_SD_FLOOR = 0.02


def clear_log_weight_sd(shift_tol: float, sd_tol: float) -> float:
    """The log-weight sd (nats) below which a Gaussian posterior is within the check's
    tolerances: a mean off by ``shift_tol`` sd gives log-weights of sd ``shift_tol``
    nats, an sd too small by a factor 1 + ``sd_tol`` gives (1 - (1 + sd_tol)^-2) / sqrt 2
    (too large by that factor: more), per parameter; the smaller of the two (0.2 nats at
    the defaults, KL(q || pi) about 0.02 nats). An early look confirms only when the
    log-weights' sd is below it with confidence (module docstring of the sequential
    check)."""
    return float(min(shift_tol, (1.0 - (1.0 + sd_tol) ** -2) / math.sqrt(2.0)))


def look_alpha(alpha: float, look: int, n_looks: int) -> float:
    """The error rate spent at look ``look`` of ``n_looks``: alpha with one look; else
    alpha / 2 at the last look and alpha / (2 (n_looks - 1)) at each early one (most of
    it kept for the last look, where a check that has not stopped must decide)."""
    K = max(int(n_looks), 1)
    if K == 1:
        return float(alpha)
    return float(alpha) / 2.0 if int(look) >= K else float(alpha) / (2.0 * (K - 1))


def cluster_mass_test(loglik: np.ndarray, surrogate_mean: np.ndarray, labels: np.ndarray,
                      cluster_mass: np.ndarray, *, tol: float, z: float,
                      min_draws: int = MIN_CLUSTER_DRAWS) -> dict[str, Any]:
    """Does the surrogate posterior give each cluster of its particles the real
    posterior's mass, within ``tol``?

    Post-stratified importance estimate: with q_c the surrogate's mass of cluster c
    (known from its weighted particles), r_c the mean importance weight w = exp(L - mu)
    of the draws in c, the real posterior's mass is pi_c = q_c r_c / sum_j q_j r_j (exact
    as r_c -> E_q[w | c]). Its delta-method variance: var(log r_c) ~ CV_c^2 / n_c (CV_c
    the weights' coefficient of variation in c, at least ``MASS_SD_FLOOR``), propagated
    through the softmax. D_c = pi_c - q_c. A surrogate exact in shape within each mode
    but wrong in the modes' masses gives log-weights constant per cluster: D_c is then
    known almost exactly from a few draws, where the draws' share of a cluster (a
    binomial proportion, sd 0.08 for 27 % at 32 draws) could not see a 5 % shift.

    Returns ``n`` (per cluster), ``q``, ``pi``, ``diff`` (D_c), ``se``, ``upper`` (|D_c| +
    z se_c), ``lower`` (|D_c| - z se_c), ``judged`` (every cluster has ``min_draws``
    solved draws), ``within`` (judged and every upper bound <= tol), ``off`` (some lower
    bound > tol), ``max_diff`` (max |D_c|).
    """
    L = np.asarray(loglik, float)
    mu = np.asarray(surrogate_mean, float)
    lab = np.asarray(labels, int)
    q = np.asarray(cluster_mass, float)
    q = q / q.sum()
    C = q.size
    ok = np.isfinite(L) & np.isfinite(mu)
    lw = L[ok] - mu[ok]
    lab = lab[ok]
    n = np.bincount(lab, minlength=C)[:C]
    out: dict[str, Any] = {"n": n.tolist(), "q": q.tolist(), "tol": float(tol), "z": float(z)}
    if C == 1:
        out.update(pi=[1.0], diff=[0.0], se=[0.0], upper=[0.0], lower=[0.0], judged=True,
                   within=True, off=False, max_diff=0.0)
        return out
    if lw.size == 0 or np.any(n == 0):
        out.update(judged=False, within=False, off=False, max_diff=None)
        return out
    w = np.exp(lw - lw.max())
    r = np.array([w[lab == c].mean() for c in range(C)])
    v = np.empty(C)
    for c in range(C):
        wc = w[lab == c]
        cv2 = (np.var(wc, ddof=1) / r[c] ** 2) if wc.size >= 2 else math.inf
        v[c] = max(cv2, MASS_SD_FLOOR**2) / wc.size
    pi = q * r / np.sum(q * r)
    J = pi[:, None] * (np.eye(C) - pi[None, :])
    se = np.sqrt((J**2) @ v) if np.all(np.isfinite(v)) else np.full(C, math.inf)
    diff = pi - q
    upper = np.abs(diff) + z * se
    lower = np.abs(diff) - z * se
    judged = bool(np.all(n >= min_draws))
    out.update(pi=pi.tolist(), diff=diff.tolist(), se=se.tolist(), upper=upper.tolist(),
               lower=lower.tolist(), judged=judged,
               within=bool(judged and np.all(upper <= tol)), off=bool(np.any(lower > tol)),
               max_diff=float(np.max(np.abs(diff))))
    return out


def sequential_check(X: np.ndarray, loglik: np.ndarray, surrogate_mean: np.ndarray, *,
                     labels: np.ndarray | None = None,
                     cluster_mass: np.ndarray | None = None,
                     look: int = 1, n_looks: int = 1, final: bool = True,
                     max_draws: int | None = None, mass_tol: float = 0.05, alpha: float = 0.05,
                     min_ess_fraction: float = 0.5, shift_tol: float = 0.2,
                     sd_tol: float = 0.2, max_log_weight_sd: float = 1.0,
                     max_failed_fraction: float = 0.1,
                     posterior_mean: np.ndarray | None = None,
                     posterior_sd: np.ndarray | None = None) -> dict[str, Any]:
    """One look of the sequential posterior check: the draws solved so far judged.

    Parameters
    ----------
    X, loglik, surrogate_mean, posterior_mean, posterior_sd, min_ess_fraction, shift_tol,
    sd_tol, max_log_weight_sd, max_failed_fraction
        As :func:`importance_check`, over every draw solved so far.
    labels, cluster_mass
        (S,) the cluster of the surrogate posterior's particles each draw came from and
        (C,) the clusters' masses under the surrogate (None: one cluster).
    look, n_looks, final
        This look's index (1-based), the most looks the check may take (for the error
        spending: ``alpha / n_looks`` per look) and whether it is the last (the maximum
        of draws is solved, or the budget allows no more).
    max_draws
        The check's maximum of draws (None: these draws). A last look with fewer (cut
        by the budget) confirms only as an early look does.
    mass_tol, alpha
        The mass tolerance and the nominal error rate (the sequential check's section
        of the module docstring).

    Returns
    -------
    dict
        :func:`importance_check`'s result plus ``mass`` (:func:`cluster_mass_test`),
        ``log_weight_sd_upper`` / ``_lower`` (its confidence bounds), ``clear_sd``,
        ``look``, ``n_looks``, ``final``, ``decision`` (``"confirmed"``, ``"refuted"``
        or ``"continue"``); ``confirmed`` is ``decision == "confirmed"`` and ``words`` say
        which test decided.
    """
    from scipy.stats import beta, chi2, norm

    L = np.asarray(loglik, float)
    S_all = L.size
    res = importance_check(X, L, surrogate_mean, min_ess_fraction=min_ess_fraction,
                           shift_tol=shift_tol, sd_tol=sd_tol,
                           max_log_weight_sd=max_log_weight_sd,
                           max_failed_fraction=max_failed_fraction,
                           posterior_mean=posterior_mean, posterior_sd=posterior_sd)
    a = look_alpha(alpha, look, n_looks)
    z = float(norm.ppf(1.0 - a))
    lab = np.zeros(S_all, int) if labels is None else np.asarray(labels, int)
    qm = np.ones(1) if cluster_mass is None else np.asarray(cluster_mass, float)
    mass = cluster_mass_test(L, surrogate_mean, lab, qm, tol=mass_tol, z=z,
                             min_draws=2 if final else MIN_CLUSTER_DRAWS)
    clear = clear_log_weight_sd(shift_tol, sd_tol)
    fixed_ok = bool(res["confirmed"])
    S = S_all - res["n_failed"]
    sd_up = sd_lo = None
    if S >= 3 and "log_weight_sd" in res:
        s = res["log_weight_sd"]
        sd_up = s * math.sqrt((S - 1) / chi2.ppf(a, S - 1))
        sd_lo = s * math.sqrt((S - 1) / chi2.ppf(1.0 - a, S - 1))
    fail_lo = (float(beta.ppf(a, res["n_failed"], S_all - res["n_failed"] + 1))
               if res["n_failed"] else 0.0)
    complete = max_draws is None or S_all >= int(max_draws)
    early_ok = bool(fixed_ok and mass["within"] and sd_up is not None and sd_up <= clear)
    if final and complete:
        decision = "confirmed" if fixed_ok and mass["within"] else "refuted"
    elif final:
        decision = "confirmed" if early_ok else "refuted"
    elif mass["off"] or (sd_lo is not None and sd_lo > max_log_weight_sd) \
            or fail_lo > max_failed_fraction:
        decision = "refuted"
    elif early_ok:
        decision = "confirmed"
    else:
        decision = "continue"
    res.update(mass=mass, log_weight_sd_upper=sd_up, log_weight_sd_lower=sd_lo,
               clear_sd=clear, look=int(look), n_looks=int(n_looks), final=bool(final),
               alpha=float(alpha), mass_tol=float(mass_tol), decision=decision,
               confirmed=decision == "confirmed")
    head = res["words"]
    C = len(mass["q"])
    if C > 1 and mass.get("max_diff") is not None:
        mass_words = (f"{C} clusters of the posterior: largest mass difference "
                      f"{mass['max_diff']:.3f} (upper bound {max(mass['upper']):.3f}, "
                      f"tolerance {mass_tol:g})")
    elif C > 1:
        mass_words = f"{C} clusters of the posterior, a cluster without solved draws"
    else:
        mass_words = "one cluster"
    look_words = (f"look {look} of at most {n_looks}, {S_all} draws; {mass_words}"
                  if n_looks > 1 else f"{S_all} draws; {mass_words}")
    if decision == "confirmed" and not (final and complete):
        res["words"] = (f"{look_words}: confirmed early (log-weight sd below {sd_up:.2g} nats "
                        f"with confidence, under {clear:.2g}). " + head)
    elif decision == "continue":
        res["words"] = f"{look_words}: undecided, more draws are solved. " + head
    elif decision == "refuted" and fixed_ok:
        if not complete and mass["within"]:
            why = (f"the budget cut the check at {S_all} of {max_draws} draws, and the "
                   f"log-weights' sd is not below {clear:.2g} nats with confidence")
        elif not mass.get("judged"):
            why = "a cluster of the posterior has too few solved draws"
        else:
            why = "the posterior's clusters carry masses off by more than the tolerance"

        res["words"] = f"{look_words}: NOT confirmed ({why}). " + head
    else:
        res["words"] = f"{look_words}. " + head
    return res
