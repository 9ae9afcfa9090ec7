"""Posterior-targeted refinement points (bayescalib.refinement): where they go."""

from __future__ import annotations

import numpy as np
import pytest

from bayescalib.refinement import refinement_points

BOX = np.array([[100.0, 800.0], [-0.8, 0.5]])


def gaussian_particles(mean, sd, n=4000, seed=0):
    rng = np.random.default_rng(seed)
    X = np.asarray(mean) + rng.standard_normal((n, len(mean))) * np.asarray(sd)
    return X, np.full(n, 1.0 / n)


def test_points_lie_in_the_posterior_region_and_in_the_box():
    # posterior sd 35 Pa and 0.065: 5 % of each box width, wider than the kernel floor
    X, W = gaussian_particles([400.0, 0.3], [35.0, 0.065])
    P = refinement_points(X, W, 16, BOX, np.random.default_rng(1))
    assert P.shape == (16, 2)
    assert np.all(P >= BOX[:, 0]) and np.all(P <= BOX[:, 1])
    # the kernel doubles the variance (sd x sqrt 2): every point within 5 smoothed sd
    z = np.abs(P - [400.0, 0.3]) / (np.sqrt(2) * np.array([35.0, 0.065]))
    assert np.all(z < 5.0), z.max()


def test_a_spuriously_narrow_posterior_still_gets_spread_points():
    # sd 0.1 % of the box: the kernel floor (2 % of the box) keeps the points apart
    X, W = gaussian_particles([230.0, -0.22], [0.7, 0.0013])
    P = refinement_points(X, W, 8, BOX, np.random.default_rng(2), min_bandwidth=0.02)
    U = (P - BOX[:, 0]) / (BOX[:, 1] - BOX[:, 0])
    d = np.linalg.norm(U[:, None] - U[None], axis=2) + np.eye(len(U))
    assert d.min() > 0.01  # half the kernel floor
    assert np.all(np.abs(U - U.mean(axis=0)) < 0.15)  # still around the mode


def test_new_points_keep_away_from_the_design():
    X, W = gaussian_particles([400.0, 0.0], [70.0, 0.13])
    rng = np.random.default_rng(3)
    design = np.array([[400.0, 0.0], [380.0, 0.05], [420.0, -0.05]])
    P = refinement_points(X, W, 6, BOX, rng, design=design)
    U = (P - BOX[:, 0]) / (BOX[:, 1] - BOX[:, 0])
    Ud = (design - BOX[:, 0]) / (BOX[:, 1] - BOX[:, 0])
    nearest = np.linalg.norm(U[:, None] - Ud[None], axis=2).min(axis=1)
    # maximin against the design: no new point as close as the design points are
    # to each other (0.04 in normalized units)
    assert nearest.min() > 0.04


def test_maximin_spreads_better_than_a_random_subset():
    X, W = gaussian_particles([400.0, 0.0], [70.0, 0.13])
    P = refinement_points(X, W, 12, BOX, np.random.default_rng(4))

    def min_dist(Q):
        U = (Q - BOX[:, 0]) / (BOX[:, 1] - BOX[:, 0])
        return (np.linalg.norm(U[:, None] - U[None], axis=2) + 9 * np.eye(len(U))).min()

    rng = np.random.default_rng(5)
    random_subsets = [min_dist(X[rng.choice(len(X), 12, replace=False)]) for _ in range(50)]
    assert min_dist(P) > np.median(random_subsets)


def test_weights_decide_where_the_points_go():
    # two modes; all weight on the second: every point near the second
    X = np.array([[200.0, -0.5]] * 50 + [[600.0, 0.3]] * 50)
    W = np.r_[np.zeros(50), np.full(50, 1 / 50)]
    P = refinement_points(X, W, 5, BOX, np.random.default_rng(6))
    assert np.all(np.abs(P[:, 0] - 600.0) < 100.0)


def test_same_seed_same_points():
    X, W = gaussian_particles([400.0, 0.3], [35.0, 0.065])
    a = refinement_points(X, W, 8, BOX, np.random.default_rng(7))
    b = refinement_points(X, W, 8, BOX, np.random.default_rng(7))
    assert np.array_equal(a, b)


@pytest.mark.parametrize("kw, match", [
    ({"n": 0}, "n must be >= 1"),
    ({"bounds": BOX[:1]}, "bounds"),
    ({"weights": -np.ones(10)}, "weights"),
    ({"min_bandwidth": 0.0}, "min_bandwidth"),
])
def test_bad_arguments_are_named(kw, match):
    args = {"particles": np.full((10, 2), [400.0, 0.3]), "weights": np.full(10, 0.1), "n": 3,
            "bounds": BOX, "rng": np.random.default_rng(0)}
    args.update(kw)
    with pytest.raises(ValueError, match=match):
        refinement_points(**args)


def test_rounds_stop_once_the_posterior_settles_and_at_most_max_rounds(monkeypatch):
    """refine_calibration's stopping rule, with the solves, surrogate and SMC replaced by
    a calibration whose posterior mean of E moves by 10, 3, 0.5 and 0.1 sd (sd 10 Pa)."""
    import bayescalib.diagnosis.extended as ext
    from bayescalib import posterior
    from bayescalib.smc import SMCResult

    means = iter([500.0, 470.0, 465.0, 464.0])
    calls = []

    def fake_calibrate(*, parameters, X_new, reused, workdir, **_):
        calls.append((len(X_new), len(reused["X"]), str(workdir)))
        m = next(means)
        return {"parameters": parameters, "training": "t.h5", "particles": "p.h5",
                "log_evidence": 0.0, "n_new": len(X_new), "n_failed": 0,
                "posterior": {"mean": {"E": m}, "std": {"E": 10.0}}}

    X = np.full((20, 1), 400.0)
    monkeypatch.setattr(ext, "calibrate_with_points", fake_calibrate)
    monkeypatch.setattr(ext, "training_rows", lambda _: {"X": np.zeros((3, 1))})
    monkeypatch.setattr(posterior, "read_particles_h5", lambda _: SMCResult(
        particles=X, weights=np.full(20, 0.05), loglik=np.zeros(20), logprior=np.zeros(20),
        log_evidence=0.0, n_steps=1, n_loglik_evals=1, history={}))
    start = {"parameters": [{"name": "E", "unit": "Pa", "prior": {"type": "uniform", "lo": 100.0,
                                                                   "hi": 800.0}}],
             "training": "t.h5", "particles": "p.h5", "log_evidence": 0.0,
             "posterior": {"mean": {"E": 400.0}, "std": {"E": 10.0}}}

    _, hist = ext.refine_calibration(start, max_rounds=10, n_points=4, tol=1.0, seed=0,
                                     switches={}, workdir="w")
    assert [h["shift_sd"] for h in hist] == [None, 10.0, 3.0, 0.5]  # stops at <= 1 sd
    assert [c[0] for c in calls] == [4, 4, 4] and calls[0][2].endswith("round_1")

    means = iter([500.0, 470.0, 465.0, 464.0])
    calls.clear()
    _, hist = ext.refine_calibration(start, max_rounds=2, n_points=4, tol=1.0, seed=0,
                                     switches={}, workdir="w")
    assert len(hist) == 3 and hist[-1]["shift_sd"] == 3.0  # capped, not settled

    _, hist = ext.refine_calibration(start, max_rounds=0, n_points=4, tol=1.0, seed=0,
                                     switches={}, workdir="w")
    assert len(hist) == 1 and len(calls) == 2  # off: the calibration as given
