"""Active design (bayescalib.inference.active) and the bounded surrogate, as specifications.

Tolerances are stated where they are used; the analytic problems have closed-form
posteriors (Gaussian misfits inside the box, so truncation is negligible: the box
is at least 6 posterior sd from the mean in every direction).
"""

from __future__ import annotations

import numpy as np
import pytest

from bayescalib.config import validate
from bayescalib.inference.active import (
    acquire_round,
    candidate_pool,
    check_points,
    posterior_change,
    posterior_draws,
    select_batch,
    trust_check,
)
from bayescalib.inference.design import sobol_design
from bayescalib.inference.gp import GPSurrogate, fit_from_config, fit_gp
from bayescalib.inference.parameters import ParameterSpace
from bayescalib.inference.rounds import calibrate
from bayescalib.inference.smc import smc_from_config


def _space(bounds):
    return ParameterSpace.from_config([
        {"name": f"x{k}", "prior": {"type": "uniform", "lo": lo, "hi": hi}, "bounds": [lo, hi]}
        for k, (lo, hi) in enumerate(bounds)])


def _gaussian_misfit(mean, cov):
    """L = -0.5 (x - m)^T C^{-1} (x - m): a Gaussian misfit with bound 0."""
    P = np.linalg.inv(cov)
    m = np.asarray(mean, float)

    def loglik(X):
        R = np.atleast_2d(X) - m
        return -0.5 * np.einsum("ij,jk,ik->i", R, P, R)
    return loglik


def _active(**kw):
    return validate({"design": {"active": kw}}, "inference")["design"]["active"]


def _check(**kw):
    return validate({"posterior_check": kw}, "inference")["posterior_check"]


# ----------------------------------------------------------------- bounded surrogate
@pytest.mark.parametrize("output", ["log_misfit", "loglik", "auto"])
def test_the_surrogate_and_the_evidence_never_exceed_the_likelihood_bound(output, tmp_path):
    """The Gaussian log-likelihood is at most B = -n/2 log(2 pi sigma^2); so must be
    the surrogate everywhere (far extrapolation included) and the SMC evidence."""
    space = _space([(-5, 5), (-5, 5)])
    B = 3.7
    ll = _gaussian_misfit([0.3, -0.2], np.diag([0.05, 0.2]))
    X = sobol_design(space.bounds, 24, 0)
    L = B + ll(X)
    cfg = validate({"surrogate": {"output": output, "restarts": 1}}, "inference")["surrogate"]
    gp = fit_from_config(X, L, cfg, space.bounds, bound=B)
    Z = np.random.default_rng(1).uniform(-50, 50, (20000, 2))
    Z[:100] = np.random.default_rng(2).normal([0.3, -0.2], 0.05, (100, 2))
    assert gp.predict(Z).max() <= B
    gp.save(tmp_path / "gp.h5")
    again = GPSurrogate.load(tmp_path / "gp.h5")
    np.testing.assert_allclose(again.predict(Z[:500]), gp.predict(Z[:500]), rtol=0, atol=1e-9)
    smc = validate({"smc": {"n_particles": 500, "n_rej": 5, "zeta": 0.9}}, "inference")["smc"]
    res = smc_from_config(gp.predict, space, smc)
    assert res.log_evidence <= B  # uniform prior: log Z <= max L


def test_log_misfit_warping_round_trips_and_interpolates_the_training_values():
    space = _space([(0, 1), (0, 1)])
    B = 10.0
    X = sobol_design(space.bounds, 16, 3)
    L = B - 100.0 * np.sum((X - 0.4) ** 2, axis=1)
    gp = fit_gp(X, L, bounds=space.bounds, bound=B,
                warp=True, restarts=1,
                kernel="matern32", nugget="fixed", mean="constant", ard=False)
    assert gp.warped
    np.testing.assert_allclose(gp.loglik_train, L, rtol=0, atol=1e-9)
    np.testing.assert_allclose(gp.latent_from_loglik(gp.loglik_from_latent(gp.y_train)),
                               gp.y_train, atol=1e-12)
    # the nugget is 1e-5 of the warped range, so training values are met within 0.1 nat
    np.testing.assert_allclose(gp.predict(X), L, atol=0.1)


def test_auto_output_prefers_the_warped_model_for_a_compliance_like_misfit():
    """A misfit in 1/stiffness (as a displacement ~ 1/E): L spans five orders of
    magnitude over the box, which a stationary GP of L cannot follow; the warped GP
    explains the values far better (Jacobian-corrected evidence), so auto chooses it."""
    space = _space([(0, 1), (0, 1)])
    X = sobol_design(space.bounds, 32, 0)
    L = -0.5 * ((1 / (0.05 + X[:, 0]) - 1 / 0.55) / 0.05) ** 2 \
        - 0.5 * ((X[:, 1] - 0.5) / 0.02) ** 2
    cfg = validate({"surrogate": {"restarts": 1}}, "inference")["surrogate"]
    assert fit_from_config(X, L, cfg, space.bounds, bound=0.0).warped


# ------------------------------------------------------------------------ checks
def test_trust_check_counts_a_spurious_mode_with_its_full_error():
    """A point the surrogate put at the top of the posterior but whose real value is
    far below fails the check even though its real value lies outside the region."""
    out = trust_check(np.array([0.0, -1.0]), np.array([0.1, 0.1]), np.array([-200.0, -1.2]),
                      loglik_best=0.0, dim=2, tol_nats=1.0)
    assert out["n_region"] == 2 and not out["passed"]
    assert out["max_abs_error"] == pytest.approx(200.0)


def test_trust_check_is_inconclusive_without_points_in_the_posterior_region():
    out = trust_check(np.array([-50.0]), np.array([1.0]), np.array([-50.5]), 0.0, 2, 1.0)
    assert out["n_region"] == 0 and not out["passed"]


def test_trust_check_passes_accurate_predictions_and_reports_failed_solves():
    out = trust_check(np.array([0.0, -1.0, -2.0]), np.array([0.3] * 3),
                      np.array([0.2, -1.1, -np.inf]), 0.2, 2, 1.0)
    assert out["passed"] and out["n_failed"] == 1 and out["n_failed_in_region"] == 1
    assert out["max_abs_error"] == pytest.approx(0.2)


def test_posterior_change_is_measured_in_posterior_sd():
    a = {"mean": np.array([0.0, 0.0]), "sd": np.array([1.0, 2.0]), "cov": np.diag([1.0, 4.0])}
    assert posterior_change(a, a)["shift_sd"] == 0 and posterior_change(a, a)["hellinger"] == 0
    b = {"mean": np.array([0.5, 0.0]), "sd": np.array([0.5, 2.0]), "cov": np.diag([0.25, 4.0])}
    ch = posterior_change(a, b)
    assert ch["shift_sd"] == pytest.approx(1.0)  # 0.5 over the smaller sd 0.5
    assert ch["sd_change"] == pytest.approx(1.0)  # sd halved: ratio 2
    assert 0 < ch["hellinger"] < 1


# ------------------------------------------------------------------- acquisition
def _fitted(n=16, seed=0):
    space = _space([(-3, 3), (-3, 3)])
    ll = _gaussian_misfit([0.5, -0.5], np.array([[0.3, 0.1], [0.1, 0.2]]))
    X = sobol_design(space.bounds, n, seed)
    gp = fit_gp(X, ll(X), bounds=space.bounds, bound=0.0, restarts=1,
                kernel="matern32", nugget="fixed", mean="constant", ard=False, warp=True)
    return space, ll, X, gp


def test_a_batch_spreads_out_and_avoids_failed_points():
    space, _, _X, gp = _fitted()
    rng = np.random.default_rng(0)
    pool = space.sample_prior(3000, rng)
    batch = select_batch(gp, pool, space.logprior(pool), 8, posterior_power=2.0)
    P = batch["points"]
    d = np.linalg.norm(P[:, None] - P[None], axis=2) + np.eye(8) * 1e9
    top8 = pool[np.argsort(-(gp.predict(pool, True)[1]))[:8]]
    d_top = np.linalg.norm(top8[:, None] - top8[None], axis=2) + np.eye(8) * 1e9
    assert len({tuple(p) for p in P}) == 8
    assert d.min() > d_top.min()  # conditioning spreads the batch
    # a failed point at the first pick: the next batch does not return next to it
    again = select_batch(gp, pool, space.logprior(pool), 8, posterior_power=2.0,
                         failed=P[:1])
    assert np.linalg.norm(again["points"] - P[0], axis=1).min() > 1e-3


def test_the_exploiting_batch_lies_where_the_posterior_mass_is():
    """Under a 2D Gaussian posterior the log-likelihood drop below the mode of a
    posterior draw is Exp(1): 1 nat on average. A batch of exploiting picks scored
    by VBMC's prospective uncertainty (the surrogate posterior squared,
    posterior_power 2) lies in that mass: averaged over four designs (16 Sobol
    points and 8 posterior draws, the log-misfit GP, candidates from the SMC
    particles as in a round), its mean drop is at most 2 nats. Weighing the posterior
    once (power 1, the default) sends the picks further down the tails,
    by at least 0.75 nats more on average (measured: 1.5 against 2.9)."""
    space = _space([(-5, 5), (-5, 5)])
    m, C = np.array([0.5, -0.5]), np.array([[0.3, 0.1], [0.1, 0.2]])
    ll = _gaussian_misfit(m, C)
    smc = validate({"smc": {"n_particles": 1000, "n_rej": 5, "zeta": 0.9}}, "inference")["smc"]
    drops = {1.0: [], 2.0: []}
    for seed in range(4):
        rng = np.random.default_rng(seed)
        X = np.vstack([sobol_design(space.bounds, 16, seed), rng.multivariate_normal(m, C, 8)])
        gp = fit_gp(X, ll(X), bounds=space.bounds, bound=0.0, restarts=1,
                    warp=True, kernel="matern32", nugget="fixed", mean="constant", ard=False)
        res = smc_from_config(gp.predict, space, {**smc, "seed": seed})
        pool = candidate_pool(res.particles, res.weights, space.bounds, 3000,
                              np.random.default_rng(seed))
        for k, found in drops.items():
            batch = select_batch(gp, pool, space.logprior(pool), 8, posterior_power=k)
            found.append(float(np.mean(-ll(batch["points"]))))
    assert np.mean(drops[2.0]) <= 2.0
    assert np.mean(drops[1.0]) >= np.mean(drops[2.0]) + 0.75


def test_acquire_round_refuses_records_that_are_not_the_chosen_batch():
    space, ll, X, gp = _fitted()
    a = _active(n_initial=16, batch_size=4, max_solves=40)
    W = np.full(len(X), 1.0 / len(X))
    rec0 = acquire_round(0, X, ll(X), gp, X, W, 0.0, space, a, None, _check())
    # the batch of 4 and the default single check point
    assert not rec0["stop"] and len(rec0["next"]["points"]) == 5
    assert rec0["next"]["kind"] == ["acquired"] * 4 + ["check"]
    wrong = np.vstack([X, X[:5] + 0.01])
    with pytest.raises(ValueError, match="not the batch"):
        acquire_round(1, wrong, ll(wrong), gp, X, W, 0.0, space, a, rec0, _check())


# ------------------------------------------------------------------ the whole loop
def _assert_closed_form(res, mean, cov):
    """The result's weighted moments: means within 0.3 sd, sds within 25 %."""
    sd = np.sqrt(np.diag(cov))
    W = res.smc.weights / res.smc.weights.sum()
    m = W @ res.smc.particles
    s = np.sqrt(W @ (res.smc.particles - m) ** 2)
    assert np.all(np.abs(m - mean) / sd < 0.3), (m, mean)
    assert np.all(np.abs(s / sd - 1) < 0.25), (s, sd)


def test_active_calibration_converges_to_the_closed_form_posterior():
    """Correlated 2D Gaussian (closed form). The stop rule's own tolerances (0.2 sd in
    the mean, 20 % in the sd) plus SMC noise (N = 2000: about 0.05 sd) bound the
    error, so means within 0.3 sd and sds within 25 % are required."""
    mean, cov = np.array([0.4, -0.3]), np.array([[0.09, 0.06], [0.06, 0.16]])
    space = _space([(-3, 3), (-3, 3)])
    res = calibrate(_gaussian_misfit(mean, cov), space, bound=0.0,
                    active={"n_initial": 16, "batch_size": 8, "max_solves": 96},
                    surrogate={"restarts": 2}, smc={"n_particles": 2000, "zeta": 0.95,
                                                    "n_rej": 10})
    assert res.converged, res.reason
    assert res.n_evaluations <= 96
    _assert_closed_form(res, mean, cov)
    # the stop rule's last test: the rounds before the last were the looks of a
    # sequential check of the checked round's posterior (posterior_check.batch 8 draws a
    # look, at most draws 32), evaluated as design points, and they confirmed it
    last = res.rounds[-1]
    pc = res.posterior_check
    assert last["posterior_check"] is pc and pc["decision"] == "confirmed", pc["words"]
    checked = res.rounds[pc["round"]]
    looks = res.rounds[pc["round"]:-1]
    assert all(rec["next"]["kind"] == ["posterior_check"] * 8 for rec in looks)
    assert len(looks) == pc["look"] and pc["n_draws"] == 8 * pc["look"] <= 32
    draws = np.concatenate([np.asarray(rec["next"]["points"]) for rec in looks])
    np.testing.assert_array_equal(res.X[-len(draws):], draws)
    assert checked["next"]["check"]["round"] == pc["round"]
    assert pc["log_weight_sd"] < 0.5
    assert res.reason.startswith(f"converged after round {last['round']}")
    assert f"confirmed by {pc['n_draws']} real solves of its draws" in res.reason, res.reason


def test_without_check_rounds_a_round_counts_only_when_settled_and_trusted():
    """posterior_check.draws 0 (the diagnosis's calibrations, which check their posteriors
    themselves): no check round is run, the pointwise trust check decides in its place
    (as the stop rule did before the check rounds), and the reason says the posterior
    was not checked with real solves of its draws."""
    mean, cov = np.array([0.4, -0.3]), np.array([[0.09, 0.06], [0.06, 0.16]])
    space = _space([(-3, 3), (-3, 3)])
    records = []
    res = calibrate(_gaussian_misfit(mean, cov), space, bound=0.0,
                    active={"n_initial": 16, "batch_size": 8, "max_solves": 96},
                    surrogate={"restarts": 2}, smc={"n_particles": 2000, "zeta": 0.95,
                                                    "n_rej": 10},
                    posterior_check={"draws": 0}, callback=records.append)
    assert res.converged, res.reason
    assert "NOT checked with real solves of its draws" in res.reason, res.reason
    assert all("posterior_check" not in (rec.get("next") or {}).get("kind", [])
               for rec in records)
    for rec in records[1:]:
        counted = rec["settled"] and rec["trusted"]
        assert (rec["settled_streak"] > 0) == counted, rec
    _assert_closed_form(res, mean, cov)


def test_lighter_round_smc_still_reports_the_posterior_with_the_full_settings():
    """design.active.smc lightens the rounds' sampler only: the result is sampled once
    more, with the study's settings, on the last round's surrogate. Same closed-form
    Gaussian and tolerances as above (the rounds' 300 particles add about 0.06 sd of
    noise to the stop rule's view of the mean, well inside its 0.2 sd)."""
    mean, cov = np.array([0.4, -0.3]), np.array([[0.09, 0.06], [0.06, 0.16]])
    space = _space([(-3, 3), (-3, 3)])
    res = calibrate(_gaussian_misfit(mean, cov), space, bound=0.0,
                    active={"n_initial": 16, "batch_size": 8, "max_solves": 96,
                            "smc": {"n_particles": 300, "n_rej": 5}},
                    surrogate={"restarts": 2}, smc={"n_particles": 2000, "zeta": 0.95,
                                                    "n_rej": 10})
    assert res.converged, res.reason
    assert res.smc.particles.shape[0] == 2000
    _assert_closed_form(res, mean, cov)


def test_round_smc_overrides_only_what_it_names():
    from bayescalib.config import round_smc

    smc = {"n_particles": 5000, "n_rej": 20, "zeta": 0.995, "seed": 3}
    assert round_smc(smc, {"smc": {}}) == smc
    assert round_smc(smc, {"smc": {"n_particles": 500}}) == {**smc, "n_particles": 500}


def test_a_spuriously_confident_start_is_caught_and_repaired():
    """A likelihood 60x narrower than the box: 8 Sobol points miss it, and the round-0
    surrogate (the paper's Matérn 3/2 of L; a squared-exponential kernel would fit
    this quadratic L exactly) is confidently wrong. The next round's trust check must
    catch it (no convergence declared on it), and the rounds must end at the true
    posterior."""
    mean, cov = np.array([0.63, 0.21]), np.diag([0.01, 0.015]) ** 2
    space = _space([(0, 1), (0, 1)])
    records = []
    res = calibrate(_gaussian_misfit(mean, cov), space, bound=0.0,
                    active={"n_initial": 8, "batch_size": 8, "max_solves": 120},
                    surrogate={"restarts": 2, "kernel": "matern32", "output": "loglik"},
                    smc={"n_particles": 2000, "zeta": 0.95,
                                                    "n_rej": 10},
                    callback=records.append)
    r0 = np.asarray(records[0]["posterior"]["mean"])
    assert np.max(np.abs(r0 - mean) / np.sqrt(np.diag(cov))) > 3  # round 0 is wrong
    assert not records[1]["trusted"]
    assert res.converged, res.reason
    W = res.smc.weights / res.smc.weights.sum()
    m = W @ res.smc.particles
    assert np.all(np.abs(m - mean) / np.sqrt(np.diag(cov)) < 0.3)


def test_a_spent_budget_is_reported_as_not_converged():
    space = _space([(0, 1), (0, 1)])
    res = calibrate(_gaussian_misfit([0.63, 0.21], np.diag([0.01, 0.015]) ** 2), space,
                    bound=0.0, active={"n_initial": 8, "batch_size": 4, "max_solves": 14},
                    surrogate={"restarts": 1}, smc={"n_particles": 300, "n_rej": 3,
                                                    "zeta": 0.9})
    assert res.n_evaluations == 14 and not res.converged
    assert res.reason.startswith("NOT converged") and "max_solves = 14" in res.reason
    # the first look (posterior_check.batch 8 draws) of the posterior check never fits
    # in the 6 solves after round 0
    assert "posterior check's first 8 draws do not fit" in res.reason, res.reason
    assert res.posterior_check is None
    none = calibrate(_gaussian_misfit([0.63, 0.21], np.diag([0.01, 0.015]) ** 2), space,
                     bound=0.0, active={"n_initial": 8, "batch_size": 4, "max_solves": 8},
                     surrogate={"restarts": 1}, smc={"n_particles": 300, "n_rej": 3,
                                                     "zeta": 0.9},
                     posterior_check={"draws": 0})
    assert none.posterior_check is None


def test_the_rounds_are_reproducible():
    space = _space([(-3, 3), (-3, 3)])
    kw = {"bound": 0.0, "active": {"n_initial": 8, "batch_size": 4, "max_solves": 16},
              "surrogate": {"restarts": 1}, "smc": {"n_particles": 300, "n_rej": 3, "zeta": 0.9}}
    ll = _gaussian_misfit([0.0, 0.5], np.diag([0.2, 0.3]))
    a, b = calibrate(ll, space, **kw), calibrate(ll, space, **kw)
    np.testing.assert_array_equal(a.X, b.X)


def test_the_exploring_candidates_include_lines_through_the_posterior_along_each_axis():
    """A posterior concentrated at c: half the pool jitters around c; of the exploring
    half, the first half are lines through c (one coordinate redrawn over its whole
    range, the others within the jitter of c), the rest uniform over the box."""
    rng = np.random.default_rng(0)
    c = np.array([0.3, 0.6, 0.8])
    particles = c + 1e-4 * rng.standard_normal((500, 3))
    pool = candidate_pool(particles, np.ones(500), np.array([[0.0, 1.0]] * 3), 400,
                          np.random.default_rng(1))
    post, line, uniform = pool[:200], pool[200:300], pool[300:]
    assert np.all(np.abs(post - c) < 0.05)
    off = np.abs(line - c) > 0.05  # the jitter is 0.5 % of the box here
    assert np.all(off.sum(axis=1) <= 1)
    for k in range(3):  # every axis is redrawn, over most of its range
        redrawn = line[np.abs(line[:, k] - c[k]) > 1e-3, k]
        assert redrawn.size >= 15 and np.ptp(redrawn) > 0.8
    assert np.mean(np.all(np.abs(uniform - c) > 0.05, axis=1)) > 0.6


@pytest.mark.parametrize("narrow", [4.0, 1.0])
def test_random_check_points_catch_a_surrogate_that_is_confident_and_too_narrow(narrow):
    """A 4D Gaussian likelihood (sd 0.05 in a unit box). The surrogate is trained on a
    log-likelihood ``narrow`` times too narrow (sd 0.0125), densely enough to be
    confident about it: its posterior is 4x too narrow, and an uncertainty-driven
    acquisition has no reason to look at the rim it is sure of. The batch's random
    check points (the posterior widened by its own spread) land in the true
    posterior's core, where the surrogate predicts them about d (1 - 1/k^2) = 3.75 nats
    too low on average (more for the farther ones): every seed's check must miss by
    more than twice gp_tol (1 nat), so the round
    cannot count towards convergence. Control (narrow = 1, the right surrogate): the
    same check points are predicted within gp_tol, so they cost no convergence."""
    d, mean, sd = 4, np.full(4, 0.5), 0.05
    space = _space([(0, 1)] * d)
    truth = _gaussian_misfit(mean, np.eye(d) * sd**2)
    wrong = _gaussian_misfit(mean, np.eye(d) * (sd / narrow) ** 2)
    rng = np.random.default_rng(0)
    X = np.vstack([sobol_design(space.bounds, 32, 0),
                   mean + (sd / narrow) * rng.standard_normal((96, d))])
    X = np.clip(X, 0.0, 1.0)
    gp = fit_gp(X, wrong(X), ard=True, bounds=space.bounds, bound=0.0, warp=False,
                restarts=1, kernel="rbf", nugget="fixed", mean="constant")
    smc = smc_from_config(gp.predict, space, validate(
        {"smc": {"n_particles": 2000, "n_rej": 10, "zeta": 0.95}}, "inference")["smc"])
    active = _active(n_initial=32, batch_size=8, check_points=3, max_solves=1000, seed=0)
    worst = []
    for seed in range(5):
        active["seed"] = seed
        rec = acquire_round(0, X, wrong(X), gp, smc.particles, smc.weights, smc.log_evidence,
                            space, active, None, _check())
        nxt = rec["next"]
        assert nxt["kind"] == ["acquired"] * 8 + ["check"] * 3
        P = np.asarray(nxt["points"])
        trust = trust_check(np.asarray(nxt["mean"]), np.asarray(nxt["sd"]), truth(P),
                            float(np.max(truth(X))), d, active["stop"]["gp_tol"])
        worst.append(float(np.max(np.abs(trust["errors"][8:]))))
        if narrow > 1:
            assert not trust["passed"]
            # the next round says why, in words
            L = np.concatenate([wrong(X), truth(P)])
            rec1 = acquire_round(1, np.vstack([X, P]), L, gp, smc.particles, smc.weights,
                                 smc.log_evidence, space, active, rec, _check())
            assert "likely too narrow" in rec1["reason"], rec1["reason"]
            t1 = rec1["trust"]  # the reason also gives the typical error, not only the largest
            assert (f"RMS {t1['rms_error']:.3g} nats over {t1['n_region']} point(s)"
                    in rec1["reason"]), rec1["reason"]
    if narrow > 1:
        assert min(worst) > 2.0 * active["stop"]["gp_tol"], worst
    else:
        assert max(worst) <= active["stop"]["gp_tol"], worst


def test_check_points_are_the_posterior_widened_by_its_own_spread():
    """Draws from N(m, C) convolved with N(0, C): mean m and covariance 2C (20 000 draws:
    sampling error of the covariance entries about 1 %, tolerance 5 %)."""
    rng = np.random.default_rng(3)
    C = np.array([[0.004, 0.002], [0.002, 0.003]])
    P = rng.multivariate_normal([0.5, 0.4], C, 20000)
    D = check_points(P, np.ones(len(P)), np.array([[0.0, 1.0], [0.0, 1.0]]), 20000,
                     np.random.default_rng(4))
    np.testing.assert_allclose(D.mean(0), [0.5, 0.4], atol=0.003)
    np.testing.assert_allclose(np.cov(D.T), 2 * C, rtol=0.05)


def test_ard_auto_gives_one_length_scale_per_input_from_two_dimensions_on():
    """The default ``surrogate.ard: auto`` gives every input its own length scale from two
    dimensions on (the 6D/7D studies, the diagnosis's extended models, and since issue 17
    the 2-D studies: with the fitted nugget ridge2d and the FSI smoke study were more
    accurate with it, docs/bench_active.md) and one in 1-D (the same model); an explicit
    true/false is obeyed (false: the paper's single length scale in 2-D)."""
    rng = np.random.default_rng(3)
    cfg = validate({"surrogate": {"restarts": 1, "kernel": "matern32",
                                  "output": "loglik"}}, "inference")["surrogate"]
    assert cfg["ard"] == "auto"
    for d in (1, 2, 3):
        box = np.array([[0.0, 1.0]] * d)
        X = rng.uniform(size=(30, d))
        L = -0.5 * np.sum(((X - 0.5) / np.r_[0.1, np.full(d - 1, 0.5)]) ** 2, axis=1)
        gp = fit_from_config(X, L, cfg, box)
        assert gp.ard is (d >= 2) and np.size(gp.lengthscale) == d
        if d >= 2:
            gp = fit_from_config(X, L, {**cfg, "ard": False}, box)
            assert gp.ard is False and np.size(gp.lengthscale) == 1


# ---------------------------------------------------------- the posterior check round
def test_the_budget_keeps_room_for_the_check_round_and_is_never_exceeded():
    """40 solves, 8 Sobol points, batches of 4 + 1 check point and a check of 16 draws:
    the batches are cut so that the last 16 solves of the budget are the check's, and
    no run ever evaluates more than max_solves points."""
    space = _space([(-3, 3), (-3, 3)])
    ll = _gaussian_misfit([0.2, -0.4], np.array([[0.2, 0.05], [0.05, 0.1]]))
    res = calibrate(ll, space, bound=0.0,
                    active={"n_initial": 8, "batch_size": 4, "max_solves": 40,
                            "stop": {"patience": 50}},  # never settled long enough
                    posterior_check={"draws": 16}, surrogate={"restarts": 1},
                    smc={"n_particles": 500, "n_rej": 5, "zeta": 0.9})
    assert res.n_evaluations <= 40
    sizes = [rec["n_solves"] for rec in res.rounds]
    assert all(n <= 40 for n in sizes)
    kinds = [rec["next"]["kind"] for rec in res.rounds if "next" in rec]
    # the check round comes once the budget left is its 16 draws; its looks (8 draws
    # each, posterior_check.batch) are the last batches
    first = next(i for i, k in enumerate(kinds) if "posterior_check" in k)
    assert res.rounds[first]["n_solves"] == 40 - 16
    assert all(k == ["posterior_check"] * 8 for k in kinds[first:])
    assert len(kinds) - first <= 2
    assert res.rounds[-1]["posterior_check"] is not None


def test_a_posterior_too_narrow_is_not_confirmed_and_the_rounds_go_on():
    """The surrogate is forced to be confidently wrong: trained on a log-likelihood 4x
    too narrow (4D Gaussian, sd 0.05 in a unit box; see the check points' test). Its
    posterior does not move between rounds (the same surrogate and particles are
    passed), so with patience 1 round 1 asks for a check round of 32 draws. The real
    log-likelihoods at those draws rise where the surrogate's fall (its sd 4x too
    small: sd ratio far above 1 + sd_tol), so round 2 must not confirm it, must not
    converge, must restart the settled streak and must choose an ordinary batch."""
    d, mean, sd = 4, np.full(4, 0.5), 0.05
    space = _space([(0, 1)] * d)
    truth = _gaussian_misfit(mean, np.eye(d) * sd**2)
    wrong = _gaussian_misfit(mean, np.eye(d) * (sd / 4.0) ** 2)
    rng = np.random.default_rng(0)
    X = np.clip(np.vstack([sobol_design(space.bounds, 32, 0),
                           mean + (sd / 4.0) * rng.standard_normal((96, d))]), 0.0, 1.0)
    gp = fit_gp(X, wrong(X), ard=True, bounds=space.bounds, bound=0.0, warp=False,
                restarts=1, kernel="rbf", nugget="fixed", mean="constant")
    smc = smc_from_config(gp.predict, space, validate(
        {"smc": {"n_particles": 2000, "n_rej": 10, "zeta": 0.95}}, "inference")["smc"])
    active = _active(n_initial=32, batch_size=8, max_solves=1000, seed=0,
                     stop={"patience": 1})
    check = _check(draws=32, batch=0)  # one look of 32 draws (the sequential check: below)
    post = (smc.particles, smc.weights, smc.log_evidence, space, active)
    L = wrong(X)
    rec0 = acquire_round(0, X, L, gp, *post, None, check)
    X1 = np.vstack([X, rec0["next"]["points"]])
    L1 = np.concatenate([L, truth(np.asarray(rec0["next"]["points"]))])
    rec1 = acquire_round(1, X1, L1, gp, *post, rec0, check)
    assert rec1["settled"] and not rec1["stop"]
    assert rec1["next"]["kind"] == ["posterior_check"] * 32
    D = np.asarray(rec1["next"]["points"])
    X2, L2 = np.vstack([X1, D]), np.concatenate([L1, truth(D)])
    rec2 = acquire_round(2, X2, L2, gp, *post, rec1, check)
    pc = rec2["posterior_check"]
    assert pc is not None and pc["round"] == 1 and not pc["confirmed"], pc["words"]
    assert max(pc["sd_ratio"].values()) > 1.2
    assert not rec2["converged"] and not rec2["stop"] and rec2["settled_streak"] == 0
    assert "NOT confirmed" in rec2["reason"], rec2["reason"]
    assert "posterior_check" not in rec2["next"]["kind"]


def test_the_check_rounds_points_are_draws_of_the_posterior():
    """Weighted particles of N(m, C) (importance weights of a wider Gaussian): 2000
    draws have mean m and sd sqrt(diag C) within Monte Carlo tolerance (standard error
    of the mean sd/sqrt(2000) = 0.022 sd, tolerance 0.1 sd; of the sd about 1.6 %,
    tolerance 6 %), none repeats and none is a point of the design so far."""
    rng = np.random.default_rng(5)
    m, s = np.array([0.4, 0.6]), np.array([0.05, 0.08])
    P = m + 2.0 * s * rng.standard_normal((40000, 2))
    logw = -0.5 * np.sum(((P - m) / s) ** 2, 1) + 0.5 * np.sum(((P - m) / (2 * s)) ** 2, 1)
    W = np.exp(logw - logw.max())
    P[1] = P[0]  # a repeated particle (a rejected move)
    D = posterior_draws(P, W, 2000, np.random.default_rng(1), exclude=P[:3])
    assert D.shape == (2000, 2)
    assert np.all(np.abs(D.mean(0) - m) / s < 0.1), D.mean(0)
    assert np.all(np.abs(D.std(0) / s - 1) < 0.06), D.std(0)
    assert len(np.unique(D, axis=0)) == 2000
    assert not any(np.all(D == x, axis=1).any() for x in P[:3])


def test_a_round_whose_whole_batch_failed_says_so_and_where_to_look():
    """Every solve after the Sobol design fails (e.g. a wall-clock limit on a loaded
    machine): the rounds learn nothing, and their reason must say that, not merely that
    no new solve fell in the posterior region."""
    mean, cov = np.array([0.4, -0.3]), np.array([[0.09, 0.06], [0.06, 0.16]])
    space = _space([(-3, 3), (-3, 3)])
    good = _gaussian_misfit(mean, cov)
    calls = []

    def failing_after_round_0(X):
        calls.append(len(X))
        return good(X) if len(calls) == 1 else np.full(len(X), -np.inf)

    records = []
    res = calibrate(failing_after_round_0, space, bound=0.0,
                    active={"n_initial": 16, "batch_size": 8, "max_solves": 32},
                    surrogate={"restarts": 1}, smc={"n_particles": 500, "zeta": 0.9,
                                                   "n_rej": 5},
                    callback=records.append)
    assert not res.converged
    assert len(records) >= 2 and len(res.loglik) == 32
    for rec in records[1:]:
        n = rec["trust"]["n_batch"]
        assert rec["trust"]["n_batch_failed"] == n > 0
        assert f"every one of the {n} solves of the last batch failed" in rec["reason"], \
            rec["reason"]
        assert "time_limit_s" in rec["reason"]
    assert "n_batch_failed" not in (records[0]["trust"] or {})


def test_draws_acquisition_checks_every_round_and_cuts_the_last_to_the_budget():
    """acquisition 'draws' (the output emulator's rounds): every batch is a check round
    of posterior_check.draws draws (batch_size when that is 0), from round 0 on, without
    waiting for the posterior to settle; the last batch takes the solves left, and with
    fewer than 2 left (no check possible) the run stops NOT converged. A round whose
    draws confirm the posterior that drew them, which then stays settled, converges."""
    space, ll, X, gp = _fitted()
    W = np.full(len(X), 1.0 / len(X))
    post = (X, W, 0.0, space)

    def rnd(r, Xr, prev, check, **act):
        return acquire_round(r, Xr, ll(Xr), gp, *post, _active(**act), prev, check,
                             acquisition="draws")

    rec0 = rnd(0, X, None, _check(draws=6), n_initial=16, batch_size=4, max_solves=40)
    assert rec0["next"]["kind"] == ["posterior_check"] * 6
    assert "draws of this posterior are solved next" in rec0["reason"]
    rec0b = rnd(0, X, None, _check(draws=0), n_initial=16, batch_size=4, max_solves=40)
    assert rec0b["next"]["kind"] == ["posterior_check"] * 4
    cut = rnd(0, X, None, _check(draws=6), n_initial=16, batch_size=4, max_solves=19)
    assert len(cut["next"]["points"]) == 3
    spent = rnd(0, X, None, _check(draws=6), n_initial=16, batch_size=4, max_solves=17)
    assert spent["stop"] and not spent["converged"] and "NOT converged" in spent["reason"]
    # the surrogate is exact where the draws fall (the same particles each round): the
    # check confirms, the posterior did not move, and the run converges in round 1
    X1 = np.vstack([X, rec0["next"]["points"]])
    rec1 = rnd(1, X1, rec0, _check(draws=6), n_initial=16, batch_size=4, max_solves=40)
    assert rec1["posterior_check"]["round"] == 0 and rec1["posterior_check"]["confirmed"]
    assert rec1["converged"] and rec1["stop"], rec1["reason"]
    assert "confirmed by 6 real solves of its draws" in rec1["reason"]
    with pytest.raises(ValueError, match="acquisition"):
        acquire_round(0, X, ll(X), gp, *post, _active(), None, _check(), acquisition="ucb")


def test_a_posterior_cut_by_failed_solves_converges_to_the_posterior_where_the_model_solves():
    """The model cannot be solved for x0 > 0.5, which cuts the Gaussian posterior
    (x0 ~ N(0.4, 0.3^2), x1 ~ N(-0.3, 0.4^2), independent) at 0.26 sd above its mean:
    37 % of its mass lies where every solve fails. Failed solves are infeasible
    (bayescalib.inference.feasibility), so the answer is the posterior restricted to
    x0 <= 0.5, a truncated normal in x0 with closed-form moments. Without that region
    the surrogate extrapolates across the cut, its draws fail there, and the posterior
    check refuses it (4 of 32 failed draws already do). The rule puts the boundary half
    way between a failed and a successful solve; the boundary points bisect those gaps
    where the posterior leans on them. Tolerances from benchmarks/bench_feasibility.py
    (design seeds 0-2 with region and boundary points: means 0.15-0.32 sd off, sds
    10-15 % wide, 8-15 % of the mass beyond the cut; before: 0.9 sd, 50 %, 37 %, and
    "converged"): means within 0.4 sd, sds within 25 %, at most 20 % of the mass beyond
    the cut (the check lets 3 of 32 draws fail, and the posterior refitted with the
    check's draws, which fill the feasible side, may lean further before it settles)."""
    from scipy.stats import truncnorm

    mean, sd = np.array([0.4, -0.3]), np.array([0.3, 0.4])
    space = _space([(-3, 3), (-3, 3)])
    gauss = _gaussian_misfit(mean, np.diag(sd**2))

    def cut(X):
        X = np.atleast_2d(X)
        return np.where(X[:, 0] > 0.5, -np.inf, gauss(X))

    res = calibrate(cut, space, bound=0.0,
                    active={"n_initial": 16, "batch_size": 8, "max_solves": 200},
                    surrogate={"restarts": 2}, smc={"n_particles": 2000, "zeta": 0.95,
                                                    "n_rej": 10})
    assert res.converged, res.reason
    assert res.surrogate.n_failed == int((~np.isfinite(res.loglik)).sum()) > 0
    t = truncnorm(-np.inf, (0.5 - mean[0]) / sd[0], loc=mean[0], scale=sd[0])
    ref_mean, ref_sd = np.array([t.mean(), mean[1]]), np.array([t.std(), sd[1]])
    W = res.smc.weights / res.smc.weights.sum()
    m = W @ res.smc.particles
    s = np.sqrt(W @ (res.smc.particles - m) ** 2)
    assert np.all(np.abs(m - ref_mean) / ref_sd < 0.4), (m, ref_mean)
    assert np.all(np.abs(s / ref_sd - 1) < 0.25), (s, ref_sd)
    beyond = res.smc.particles[:, 0] > 0.5
    assert W[beyond].sum() < 0.2, W[beyond].sum()  # the true posterior has none there
    assert any("boundary" in (r.get("next") or {}).get("kind", []) for r in res.rounds)
    assert res.posterior_check["failed_fraction"] <= 0.1, res.posterior_check["words"]


def test_boundary_points_bisect_the_gaps_the_posterior_leans_on_and_never_repeat():
    """One failed solve beside the posterior: the boundary point is the midpoint of it and
    its nearest success; once that midpoint is a design point (its solve failed for the
    machine's sake: no value, so the pair is unchanged), it is not proposed again."""
    from bayescalib.inference.active import boundary_points

    space, ll, X, gp = _fitted()
    assert boundary_points(gp, X, np.ones(len(X)), 2).shape == (0, 2)  # no failures
    L = ll(X)
    f = int(np.argmax(L))  # the failure where the posterior is
    L[f] = -np.inf
    gp_f = fit_gp(X, L, bounds=space.bounds, bound=0.0,
                  warp=True, restarts=1,
                  kernel="matern32", nugget="fixed", mean="constant", ard=False)
    P = X[f] + np.random.default_rng(0).normal(0.0, 0.05, (400, 2))
    B = boundary_points(gp_f, P, np.ones(len(P)), 1)
    ok = np.delete(X, f, axis=0)
    assert B.shape == (1, 2)
    assert tuple(B[0]) in {tuple(0.5 * (X[f] + x)) for x in ok}  # a failure-success midpoint
    again = boundary_points(gp_f, P, np.ones(len(P)), 1, exclude=np.vstack([X, B]))
    assert not any(np.array_equal(b, B[0]) for b in again)


def test_without_failed_solves_the_sampled_log_likelihood_is_the_surrogate_mean_bitwise():
    space, ll, X, gp = _fitted()
    assert gp.X_failed is None and gp.n_failed == 0
    P = np.random.default_rng(3).uniform(-1, 1, (500, 2))
    np.testing.assert_array_equal(gp.loglik(P), gp.predict(P))
    L = ll(X)
    L[[2, 5]] = -np.inf
    gp_f = fit_gp(X, L, bounds=space.bounds, bound=0.0,
                  warp=True, kernel="matern32", nugget="fixed", mean="constant", ard=False)
    assert gp_f.n_failed == 2 and gp_f.n_excluded == 2
    np.testing.assert_array_equal(gp_f.infeasible(X[[2, 5]]), [True, True])
    assert not gp_f.infeasible(np.delete(X, [2, 5], axis=0)).any()
    inf = gp_f.infeasible(P)
    assert np.all(np.isneginf(gp_f.loglik(P)[inf]))
    np.testing.assert_array_equal(gp_f.loglik(P)[~inf], gp_f.predict(P)[~inf])
