"""Posterior check by importance sampling (bayescalib.inference.importance), on cases with
known answers: equal weights, Gaussian proposals whose weight tails have a known Pareto
shape, a shifted surrogate, failed solves.

Tolerances. The Pareto shape of weights from a Gaussian target N(0, 1) and proposal
N(0, s^2) in 1-D is xi = 1 - s^2 (w = exp(chi2_1 (1 - s^2) / 2), whose tail falls as
t^(-1 / (1 - s^2))); with 4000 draws the PSIS tail has 190 points, and the estimate's
sampling sd is about (1 + xi) / sqrt(190) ~ 0.1 plus the prior's pull towards 0.5, so
+-0.15. Monte Carlo errors of self-normalized means are sd / sqrt(ESS); means are checked
within 4 of them.
"""

from __future__ import annotations

import numpy as np
import pytest

from bayescalib.inference.importance import K_RELIABLE, importance_check, pareto_k, tail_size


def _gauss_case(s_q: float, shift: float, n: int, seed: int):
    """Draws of a surrogate posterior N(shift, s_q^2); true posterior N(0, 1)."""
    rng = np.random.default_rng(seed)
    x = shift + s_q * rng.standard_normal(n)
    L = -0.5 * x**2
    mu = -0.5 * ((x - shift) / s_q) ** 2
    return x[:, None], L, mu


def test_an_exact_surrogate_is_confirmed_with_equal_weights():
    x, L, _ = _gauss_case(1.0, 0.0, 64, 0)
    res = importance_check(x, L, L - 3.0)  # a constant offset does not matter
    assert res["confirmed"]
    assert res["log_weight_sd"] == pytest.approx(0.0, abs=1e-12)
    assert res["ess_fraction"] == pytest.approx(1.0)
    assert res["pareto_k"] is None
    assert res["shift_sd"] == pytest.approx([0.0], abs=1e-12)


@pytest.mark.parametrize("s_q", [0.5, 0.7, 0.9])
def test_pareto_k_of_gaussian_weights_is_one_minus_the_variance_ratio(s_q):
    _x, L, mu = _gauss_case(s_q, 0.0, 4000, 1)
    assert pareto_k(L - mu) == pytest.approx(1.0 - s_q**2, abs=0.15)


def test_a_surrogate_posterior_too_narrow_is_not_confirmed():
    """s = 0.5: the weights have infinite variance (xi = 0.75 > 0.7), and with 4000 draws
    the tail says so; with 32 (a study's budget) the tail seldom shows, but the real
    posterior's sd estimated from the weights is 1.4-1.7x the surrogate's in every seed.
    s = 0.9: confirmed (sd ratio 1.11, within the factor 1.2)."""
    many = importance_check(*_gauss_case(0.5, 0.0, 4000, 1))
    assert not many["confirmed"] and many["pareto_k"] >= K_RELIABLE
    assert "mass the surrogate's misses" in many["words"]
    for seed in range(5):
        few = importance_check(*_gauss_case(0.5, 0.0, 32, seed))
        assert not few["confirmed"], few["words"]
        assert few["sd_ratio"][0] > 1.2
    close = importance_check(*_gauss_case(0.9, 0.0, 400, 2))
    assert close["confirmed"], close["words"]
    # the importance estimate repairs the sd: 1 / 0.9 = 1.11 times the surrogate's
    assert close["sd_ratio"][0] == pytest.approx(1 / 0.9, abs=0.1)


def test_a_shifted_surrogate_is_caught_and_its_mean_corrected():
    """q = N(0.5, 1), pi = N(0, 1): log w = -x/2 + const, sd 0.5 nats, KL 0.125."""
    x, L, mu = _gauss_case(1.0, 0.5, 400, 3)
    res = importance_check(x, L, mu)
    assert not res["confirmed"] and "a mean moves" in res["words"]
    assert res["log_weight_sd"] == pytest.approx(0.5, rel=0.1)
    assert res["kl_estimate"] == pytest.approx(0.125, rel=0.2)
    se = res["sd_is"][0] / np.sqrt(res["ess_fraction"] * 400)
    assert abs(res["mean_is"][0] - 0.0) < 4 * se
    assert res["shift_sd"][0] == pytest.approx(-0.5, abs=4 * res["shift_se"][0])


def test_failed_solves_are_counted_and_left_out():
    x, L, mu = _gauss_case(1.0, 0.0, 50, 4)
    L[[3, 7]] = -np.inf
    L[11] = np.nan
    res = importance_check(x, L, mu)
    assert res["n_draws"] == 50 and res["n_failed"] == 3
    assert res["confirmed"]
    assert "3 of 50 draws failed to solve" in res["words"]
    none = importance_check(x[:2], np.array([-np.inf, np.nan]), mu[:2])
    assert not none["confirmed"] and "not possible" in none["words"]


def test_a_posterior_that_lies_where_solves_fail_is_not_confirmed():
    """An exact surrogate everywhere the model solves, but a quarter of its posterior
    where solves fail: the draws that solve agree perfectly, and still the check refuses,
    since the surrogate's values where the solves fail are extrapolations nothing checks.
    The boundary is the share of failed draws against max_failed_fraction (0.1: 3 of 32
    pass, 4 do not)."""
    x, L, _ = _gauss_case(1.0, 0.0, 32, 5)
    mu = L.copy()
    fails = np.argsort(x[:, 0])[-8:]  # the upper quarter of the posterior cannot be solved
    L[fails] = -np.inf
    res = importance_check(x, L, mu)
    assert res["n_failed"] == 8 and res["failed_fraction"] == pytest.approx(0.25)
    assert res["log_weight_sd"] == pytest.approx(0.0, abs=1e-12)  # the rest is exact
    assert not res["confirmed"]
    assert "8 of 32 draws could not be solved" in res["words"]
    assert "about 25 % of the posterior" in res["words"]
    for n_fail, confirmed in ((3, True), (4, False)):
        L3 = mu.copy()
        L3[fails[:n_fail]] = -np.inf
        assert importance_check(x, L3, mu)["confirmed"] is confirmed
    assert importance_check(x, L, mu, max_failed_fraction=0.25)["confirmed"]


def test_mismatched_lengths_are_an_error():
    with pytest.raises(ValueError, match="must agree"):
        importance_check(np.zeros((3, 2)), np.zeros(3), np.zeros(2))


def test_small_errors_with_few_draws_are_confirmed_and_leave_the_tail_unjudged():
    """A surrogate off by 0.1 nats of noise at 32 draws (the smoke study's case: ESS 99 %):
    a Pareto shape fitted to the 7 largest of 32 nearly equal weights means nothing, so it
    is not estimated below 50 draws, and the check confirms."""
    rng = np.random.default_rng(5)
    x, L, _ = _gauss_case(1.0, 0.0, 32, 5)
    res = importance_check(x, L, L + 0.1 * rng.standard_normal(32))
    assert res["pareto_k"] is None
    assert res["confirmed"], res["words"]
    assert res["log_weight_sd"] == pytest.approx(0.1, rel=0.35)


def test_spurious_surrogate_mass_is_caught_by_the_spread_of_the_log_weights():
    """A tenth of the draws lie where the real log-likelihood is 10 nats below the
    surrogate's (mass the surrogate invented): the other weights are equal, so the ESS is
    90 %, and the means and sds barely move if the spurious draws sit at the centre; the
    log-weights' sd (3 nats) says it."""
    x, L, _ = _gauss_case(1.0, 0.0, 40, 6)
    x[:4, 0] = [-0.05, 0.05, -0.1, 0.1]  # near the centre: moments hardly change
    mu = L.copy()
    mu[:4] = L[:4] + 10.0
    res = importance_check(x, L, mu)
    assert res["ess_fraction"] == pytest.approx(0.9, abs=0.01)
    assert res["log_weight_sd"] > 2.5
    assert not res["confirmed"] and "log-weights spread" in res["words"]


def test_draws_that_miss_a_tail_of_the_posterior_do_not_confirm_it():
    """Given the moments of the whole posterior the draws came from, the check first asks
    whether they represent it. A posterior with 6 % of its mass in a far tail (the
    heterogeneous study's E2 with the output emulator: sd 111 Pa from a tail above 300 Pa,
    interquartile range 138-220 Pa) checked by draws from its bulk only: the importance
    estimates agree with the draws (exact surrogate) but the draws' sd is half the
    posterior's, so it is NOT confirmed, and the words say why. The same draws against
    the bulk's own moments are confirmed. Draws of a Gaussian posterior (7-D, 32 draws,
    systematic resampling of 5000 particles) are refused by this test in 2.5 % of 400
    seeds (measured); tolerance: at most 5 % of 200 seeds."""
    from bayescalib.inference.active import posterior_draws

    rng = np.random.default_rng(3)
    bulk = rng.standard_normal((32, 2))
    zeros = np.zeros(32)
    post = np.vstack([rng.standard_normal((9400, 2)),
                      np.column_stack([6.0 + 2.0 * rng.standard_normal(600),
                                       rng.standard_normal(600)])])
    res = importance_check(bulk, zeros, zeros, posterior_mean=post.mean(axis=0),
                           posterior_sd=post.std(axis=0))
    assert res["log_weight_sd"] == 0.0 and not res["representative"]
    assert res["draws_sd_ratio"][0] < 0.64 and not res["confirmed"]
    assert "do not represent the posterior" in res["words"]
    own = importance_check(bulk, zeros, zeros, posterior_mean=np.zeros(2),
                           posterior_sd=np.ones(2))
    assert own["representative"] and own["confirmed"]
    refused = 0
    for seed in range(200):
        P = np.random.default_rng(seed).standard_normal((5000, 7))
        D = posterior_draws(P, np.ones(5000), 32, np.random.default_rng(seed + 1000))
        r = importance_check(D, zeros, zeros, posterior_mean=P.mean(axis=0),
                             posterior_sd=P.std(axis=0))
        refused += not r["representative"]
    assert refused <= 10, refused

# --- The Pareto-k test at 64 draws (issue 17; benchmarks/bench_pareto_k.py) -------------
#
# Rates over 400 seeded replicates; the bounds sit about 2 binomial sds (sqrt(p (1 - p) /
# 400): 1.2 % at p = 6 %, 0.7 % at 98 %) from the measured rates, on the side that matters.
# PSIS's own tail (13 weights at 64 draws, before issue 17) measured on the same replicates:
# right posteriors refused by k in 8.5 % (smooth error) and 1.5 % (noise), the missed lobe
# in 91 %, the t3 posterior in 86 %: the bounds below are the longer tail's.

def _bounded_error(x: np.ndarray, rng: np.random.Generator, J: int = 20) -> np.ndarray:
    """A random smooth bounded function of x (J random Fourier features of length scale
    1), centred and scaled to unit sd on the draws."""
    om = rng.standard_normal(J)
    b = rng.uniform(0.0, 2.0 * np.pi, J)
    h = np.cos(np.outer(x, om) + b).sum(axis=1)
    return (h - h.mean()) / h.std()


def _refusal_rates(make, n: int = 400) -> tuple[float, float]:
    """Shares of n seeded cases refused on the Pareto shape and confirmed."""
    k_refused = confirmed = 0
    for r in range(n):
        res = importance_check(*make(r))
        k_refused += "mass the surrogate's misses" in res["words"]
        confirmed += res["confirmed"]
    return k_refused / n, confirmed / n


@pytest.mark.parametrize("kind, eps, max_k_refused, min_confirmed", [
    ("smooth", 0.2, 0.08, 0.91),  # measured 6.0 % refused by k, 94.0 % confirmed
    ("noise", 0.3, 0.01, 0.98),   # measured 0 %, 100 %
])
def test_right_posteriors_at_64_draws_are_seldom_refused_on_the_pareto_shape(
        kind, eps, max_k_refused, min_confirmed):
    """q = pi = N(0, 1) in 1-D, the surrogate off by a bounded smooth error or by noise of
    eps nats: the weights are bounded (true Pareto shape < 0), so every refusal on k is
    false. The shape is fitted to the 20 largest of 64 weights (0.3 S)."""
    def make(r):
        rng = np.random.default_rng([17, 64, r])
        x = rng.standard_normal(64)
        L = -0.5 * x**2
        err = _bounded_error(x, rng) if kind == "smooth" else rng.standard_normal(64)
        return x[:, None], L, L + eps * err

    k_refused, confirmed = _refusal_rates(make)
    assert k_refused <= max_k_refused
    assert confirmed >= min_confirmed


def test_a_missed_lobe_at_64_draws_is_refused_on_the_pareto_shape():
    """pi = 0.8 N(0, 1) + 0.2 N(4, 1), q = N(0, 1) (the main lobe): the draws seldom reach
    the lobe, the weights look nearly equal (log-weight sd about 0.09 nats), the means and
    sds barely move, and only the tail's shape says that pi has mass q misses. Measured:
    98.3 % refused on k (the other criteria alone: 16-19 %, benchmarks/bench_pareto_k.py)."""
    def make(r):
        rng = np.random.default_rng([18, 64, r])
        x = rng.standard_normal(64)
        L = np.logaddexp(np.log(0.8) - 0.5 * x**2, np.log(0.2) - 0.5 * (x - 4.0) ** 2)
        return x[:, None], L, -0.5 * x**2

    k_refused, confirmed = _refusal_rates(make)
    assert k_refused >= 0.95
    assert confirmed <= 0.05


def test_a_heavy_tailed_posterior_at_64_draws_is_refused_on_the_pareto_shape():
    """pi a Student t with 3 degrees of freedom (scale 1), q = N(0, 1): weights
    w ~ exp(x^2 / 2) |x|^-4, an infinite-variance tail. Measured: 95.3 % refused on k."""
    def make(r):
        rng = np.random.default_rng([19, 64, r])
        x = rng.standard_normal(64)
        return x[:, None], -2.0 * np.log1p(x**2 / 3.0), -0.5 * x**2

    k_refused, _confirmed = _refusal_rates(make)
    assert k_refused >= 0.92


def test_the_pareto_shape_is_fitted_to_a_longer_tail_below_225_draws():
    """M = ceil(min(0.3 S, 3 sqrt S)): 15 weights at 50 draws, 20 at 64, PSIS's 3 sqrt S
    from 100 on (30; 48 at 256, 190 at 4000)."""
    assert [tail_size(S) for S in (50, 64, 100, 128, 256, 4000)] == [15, 20, 30, 34, 48, 190]


def test_the_words_say_when_the_pareto_shape_was_not_judged():
    x, L, _ = _gauss_case(1.0, 0.0, 49, 7)
    res = importance_check(x, L, L + 0.1 * np.random.default_rng(7).standard_normal(49))
    assert res["pareto_k"] is None
    assert "Pareto k not judged (its tail is estimated from 50 draws on, 49 solved)" in res["words"]
    x, L, _ = _gauss_case(1.0, 0.0, 64, 8)
    flat = importance_check(x, L, L)  # an exact surrogate: equal weights
    assert flat["pareto_k"] is None and "no tail" in flat["words"]
