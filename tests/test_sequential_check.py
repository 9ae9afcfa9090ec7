"""The sequential posterior check (issue 38 item 2): it confirms a right posterior,
refutes a posterior whose modes carry the wrong masses, stops early on a clear case, and
its error rates over seeds stay within the stated ones.

The cases are those of ``benchmarks/bench_sequential_check.py``: a surrogate posterior q
known to be right or wrong, 4000 exact draws of it as particles, the surrogate's
log-likelihood at a draw log q + iid noise (the GP's error, in nats) and the real one
log pi (analytic: no GP, no solve).
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
import bench_sequential_check as bsc

from bayescalib.inference.active import posterior_clusters, posterior_draws
from bayescalib.inference.importance import (
    cluster_mass_test,
    importance_check,
    look_alpha,
    sequential_check,
)


def _particles(case, n=4000):
    _, (_, sample_q), _ = bsc.CASES[case]
    P = sample_q(np.random.default_rng([7, len(case)]), n)
    labels, masses = posterior_clusters(P, np.ones(n))
    return P, labels, masses


def _looks(case, seed, noise=0.1, draws=32, batch=8):
    """The looks of one sequential check of ``case``: a list of each look's result."""
    (log_pi, _), (log_q, _), _ = bsc.CASES[case]
    P, labels, masses = _particles(case)
    rng = np.random.default_rng([seed, 0xC0FF])
    D, lab = posterior_draws(P, np.ones(len(P)), draws, rng, labels=labels, batch=batch)
    L, mu = log_pi(D), log_q(D) + noise * rng.standard_normal(draws)
    out = []
    K = -(-draws // batch)
    for look in range(1, K + 1):
        n = min(look * batch, draws)
        res = sequential_check(D[:n], L[:n], mu[:n], labels=lab[:n], cluster_mass=masses,
                               look=look, n_looks=K, final=n >= draws, max_draws=draws,
                               posterior_mean=P.mean(axis=0), posterior_sd=P.std(axis=0))
        out.append(res)
        if res["decision"] != "continue":
            break
    return out, (D, L, mu)


def test_the_clusters_are_the_modes_and_one_for_a_gaussian():
    """Two modes 16 sd apart with 73 % / 27 % of the mass: two clusters with those masses
    (up to the particles' sampling); a Gaussian: one cluster, and no mass test."""
    P, labels, masses = _particles("bimodal_right")
    assert len(masses) == 2 and abs(masses[0] - 0.73) < 0.02
    near1 = np.linalg.norm(P - bsc.M1, axis=1) < 0.5
    assert np.all(labels[near1] == 0) and np.all(labels[~near1] == 1)
    _, _, m1 = _particles("gauss_right")
    assert len(m1) == 1


def test_draws_are_stratified_by_cluster_in_every_look():
    """Each look of 8 draws is its own systematic resample of the particles ordered by
    cluster: the 27 % mode gets 2 or 3 draws of every 8 (8 x 0.27 = 2.2)."""
    P, labels, _ = _particles("bimodal_right")
    D, lab = posterior_draws(P, np.ones(len(P)), 32, np.random.default_rng(3), labels=labels,
                             batch=8)
    assert D.shape == (32, 2)
    for k in range(4):
        assert int(np.sum(lab[8 * k:8 * k + 8] == 1)) in (2, 3)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_right_two_mode_posterior_is_confirmed_early(seed):
    """q = pi with 0.1-nat surrogate error at the draws: confirmed, before the 32 draws
    (the mass test's bound and the log-weights' sd are clear after 8-24)."""
    looks, _ = _looks("bimodal_right", seed)
    assert looks[-1]["decision"] == "confirmed", looks[-1]["words"]
    assert looks[-1]["n_draws"] < 32
    assert abs(looks[-1]["mass"]["diff"][0]) < 0.02


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_ten_percent_mode_mass_shift_is_refuted_where_the_fixed_check_confirms(seed):
    """q gives the modes 63 % / 37 % where pi gives 73 % / 27 %: inside each mode q is
    exact, so the log-weights are two constants (0.15 and -0.32 nats) and the fixed
    check's tests (sd 0.2 nats, ESS 96 %, moments within tolerance) pass on all 32
    draws; the mass test sees the difference of 0.10 and refutes, early."""
    looks, (D, L, mu) = _looks("bimodal_shift10", seed)
    assert looks[-1]["decision"] == "refuted", looks[-1]["words"]
    assert looks[-1]["n_draws"] < 32
    assert looks[-1]["mass"]["lower"][0] > 0.05
    assert abs(looks[-1]["mass"]["pi"][0] - 0.73) < 0.03
    assert importance_check(D, L, mu)["confirmed"]


def test_the_mass_test_estimates_the_real_mass_from_constant_log_weights():
    """Two clusters, q = (0.6, 0.4), log-weights log(0.7/0.6) and log(0.3/0.4) exactly:
    pi = (0.7, 0.3) from 3 draws each, with the floor's small standard error."""
    lw = np.r_[np.full(3, np.log(0.7 / 0.6)), np.full(3, np.log(0.3 / 0.4))]
    res = cluster_mass_test(lw, np.zeros(6), np.r_[np.zeros(3), np.ones(3)].astype(int),
                            np.array([0.6, 0.4]), tol=0.05, z=2.0)
    np.testing.assert_allclose(res["pi"], [0.7, 0.3], atol=1e-12)
    assert res["off"] and not res["within"] and max(res["se"]) < 0.01


def test_the_error_is_spent_mostly_at_the_last_look():
    """alpha 0.05 over 4 looks: 0.05/6 at each of the 3 early ones, 0.025 at the last
    (sum 0.05); one look: all of it."""
    assert look_alpha(0.05, 1, 1) == 0.05
    spent = [look_alpha(0.05, k, 4) for k in range(1, 5)]
    assert spent[-1] == 0.025 and sum(spent) == pytest.approx(0.05)


def test_error_rates_over_seeds_are_within_the_stated_ones():
    """100 seeds a case (noise 0.1 nats): false refutation of the right two-mode
    posterior at most 5 %; false confirmation of the 10 % mass shift at most 5 %
    (nominal alpha 0.05; measured 0 % over 400 seeds, benchmarks/
    bench_sequential_check.py) and of the 5 % one, which lies on the tolerance (its
    particles' masses are 0.677 against 0.73: a difference of 0.053), at most 8 %
    (alpha plus two binomial sd at 100 seeds; measured 5.2 % over 400), and on the
    too-narrow Gaussian the sequential check
    confirms no more often than the fixed check on the same draws plus 5 points (the
    same guarantee where the mass test has nothing to say), with fewer draws on average
    on the right posteriors."""
    right = bsc.run_case("bimodal_right", 100, 0.1)
    assert right["sequential_error"] <= 0.05 and right["sequential_mean_draws"] < 24
    assert bsc.run_case("bimodal_shift10", 100, 0.1)["sequential_error"] <= 0.05
    assert bsc.run_case("bimodal_shift5", 100, 0.1)["sequential_error"] <= 0.08
    narrow = bsc.run_case("gauss_narrow", 100, 0.1)
    assert narrow["sequential_error"] <= narrow["fixed_error"] + 0.05
    gauss = bsc.run_case("gauss_right", 100, 0.1)
    assert gauss["sequential_error"] <= gauss["fixed_error"] + 0.02
    assert gauss["sequential_mean_draws"] < 24


def test_a_refit_that_moves_mode_mass_after_the_check_is_not_converged():
    """The check confirmed a posterior with masses 0.73 / 0.27; the posterior refitted
    with its draws has its moments settled but holds 0.68 / 0.32 (bimodal2d seed 3 before
    this rule: converged at Hellinger 0.16). Not converged; with the masses kept, it is."""
    from bayescalib.inference.active import StopRule, _masses_by_center

    centers = np.array([bsc.M1, bsc.M2])
    P = np.vstack([np.tile(bsc.M1, (68, 1)), np.tile(bsc.M2, (32, 1))])
    now = _masses_by_center(P, np.ones(100), centers, np.array([0.8, 0.45]))
    np.testing.assert_allclose(now, [0.68, 0.32])
    rule = StopRule(0.2, 0.2, 1.0, 2, 0.02, 128, 32, False, 8)
    change = {"shift_sd": 0.1, "sd_change": 0.1, "hellinger": 0.05, "kl": 0.01}
    for settled, converged in ((False, False), (True, True)):
        rec = {"n_solves": 100, "settled": True, "explored": True, "trusted": True,
               "change": change,
               "posterior_check": {"confirmed": True, "decision": "confirmed",
                                   "change_since_checked": change, "mass_settled": settled}}
        rule.apply(rec, None)
        assert rec["converged"] is converged


def test_an_undecided_check_of_a_posterior_that_moved_is_superseded():
    """An undecided look whose refitted posterior moved beyond the stop rule's tolerances
    from the checked one (mean or sd, or the clusters' masses) is superseded: its check
    stops, its words say why; one that stayed keeps looking; a decided look is left."""
    from bayescalib.inference.active import StopRule, supersede_if_moved

    rule = StopRule(0.2, 0.2, 1.0, 2, 0.02, 64, 32, False, 8)
    still = {"shift_sd": 0.05, "sd_change": 0.03}
    moved = {"shift_sd": 0.3, "sd_change": 0.03}
    cases = [({"decision": "continue", "change_since_checked": moved}, "superseded"),
             ({"decision": "continue", "change_since_checked": still}, "continue"),
             ({"decision": "continue", "change_since_checked": still, "mass_settled": False,
               "mass_change_since_checked": 0.08}, "superseded"),
             ({"decision": "refuted", "change_since_checked": moved}, "refuted")]
    for pc, decision in cases:
        pc.update(n_draws=8, words="look 1 of at most 4")
        supersede_if_moved(pc, rule)
        assert pc["decision"] == decision
        assert ("superseded after 8 draws" in pc["words"]) is (decision == "superseded")
    assert "masses by 0.08" in cases[2][0]["words"]


def test_a_superseded_check_starts_the_next_settled_streak():
    """After a superseded check the round counts towards the next streak when it is
    settled and explored (not converged; a design round next at patience 2 with the budget
    to spare), and the streak is 0 when it is not."""
    from bayescalib.inference.active import StopRule

    rule = StopRule(0.2, 0.2, 1.0, 2, 0.02, 128, 32, False, 8)
    change = {"shift_sd": 0.1, "sd_change": 0.1}
    for settled, streak in ((True, 1), (False, 0)):
        rec = {"n_solves": 48, "settled": settled, "explored": True, "trusted": True,
               "change": change,
               "posterior_check": {"confirmed": False, "decision": "superseded",
                                   "change_since_checked": change}}
        step = rule.apply(rec, None)
        assert rec["settled_streak"] == streak
        assert not rec["converged"] and not rec["stop"]
        assert not step["check_round_next"]


def test_the_design_batches_leave_room_for_two_looks_of_the_check():
    """With 32 check draws in looks of 8 and a budget of 64, the design batches keep 16
    solves back (not 32) and the check round starts once 16 are left, with all of them;
    with the whole check in one look (batch 0) they keep its 32."""
    from bayescalib.inference.active import RESERVE_LOOKS, StopRule

    assert RESERVE_LOOKS == 2
    rule = StopRule(0.2, 0.2, 1.0, 2, 0.02, 64, 32, False, 8)
    for n_solves, check_next, n_draws in ((32, False, 32), (40, False, 24), (48, True, 16),
                                          (52, True, 12)):
        rec = {"n_solves": n_solves, "settled": False, "explored": True, "trusted": True,
               "change": {"shift_sd": 1.0, "sd_change": 1.0}, "posterior_check": None}
        step = rule.apply(rec, None)
        assert step["check_round_next"] is check_next, n_solves
        assert step["reserve"] == 16 and step["n_draws"] == n_draws, n_solves
    one_look = StopRule(0.2, 0.2, 1.0, 2, 0.02, 64, 32, False, 0)
    rec = {"n_solves": 32, "settled": False, "explored": True, "trusted": True,
           "change": {"shift_sd": 1.0, "sd_change": 1.0}, "posterior_check": None}
    step = one_look.apply(rec, None)
    assert step["check_round_next"] and step["n_draws"] == 32


@pytest.mark.parametrize("seed", [0, 1])
def test_the_fixed_design_check_tests_the_modes_masses(seed):
    """The fixed design's final check (one look at all its draws) has the mass test: a
    two-mode posterior whose masses are 10 % off is not confirmed, the right one is, and
    on a Gaussian (one cluster) it says what the importance check says."""
    from bayescalib.inference.active import final_posterior_check

    section = {"mass_tol": 0.05, "alpha": 0.05, "min_ess_fraction": 0.5, "shift_tol": 0.2,
               "sd_tol": 0.2, "max_log_weight_sd": 1.0, "max_failed_fraction": 0.1}
    for case, confirmed in (("bimodal_right", True), ("bimodal_shift10", False),
                            ("gauss_right", True)):
        (log_pi, _), (log_q, _), _ = bsc.CASES[case]
        P, _, masses = _particles(case)
        rng = np.random.default_rng([seed, 0xF1])
        D = P[rng.choice(len(P), 32, replace=False)]
        L, mu = log_pi(D), log_q(D) + 0.02 * rng.standard_normal(32)
        res = final_posterior_check(D, L, mu, P, np.ones(len(P)), section)
        assert res["confirmed"] is confirmed, (case, res["words"])
        assert len(res["mass"]["q"]) == len(masses)
        assert "look" not in res["words"].split(":")[0]
        if len(masses) == 1:
            plain = importance_check(D, L, mu, posterior_mean=P.mean(axis=0),
                                     posterior_sd=P.std(axis=0))
            assert plain["confirmed"] is res["confirmed"]


def test_the_reason_names_a_superseded_check_and_why():
    """The round's words say that round 2's check was stopped, after how many draws and
    how far the posterior moved; the console's line says it in a few words."""
    from bayescalib.execution.progress import _decision
    from bayescalib.inference.active import StopRule, _why_not, supersede_if_moved

    rule = StopRule(0.2, 0.2, 1.0, 2, 0.02, 64, 32, False, 8)
    pc = {"round": 2, "decision": "continue", "confirmed": False, "n_draws": 8,
          "change_since_checked": {"shift_sd": 0.27, "sd_change": 0.16},
          "words": "look 1 of at most 4, 8 draws; one cluster: undecided"}
    supersede_if_moved(pc, rule)
    rec = {"round": 3, "trust": {"n_batch": 8, "n_batch_failed": 0, "passed": True},
           "change": {"shift_sd": 0.27, "sd_change": 0.16}, "posterior_check": pc,
           "explored": True, "settled": False, "settled_streak": 0}
    words = _why_not(rec, {"shift_tol": 0.2, "sd_tol": 0.2, "gp_tol": 1.0, "patience": 2},
                     {"draws": 32, "batch": 8}, 24)
    assert "posterior check of round 2 was superseded after 8 draws" in words
    assert "its mean by 0.27 sd" in words
    assert "moved away from round 2's" in _decision({**rec, "next": {"kind": ["acquired"]}})
