"""Specification of the joint re-fit of base parameters and registration.

``joint_fit`` is damped Gauss-Newton whose every returned point was confirmed by its own
solve; ``laplace_draws`` draws the base parameters from the joint fit's Gaussian
approximation with the registration marginalized. Both are checked on problems solved
by hand: an exponential response where the undamped step overshoots, and a linear
Gaussian model whose marginal posterior is known exactly.
"""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from bayescalib.diagnosis.registration import joint_fit, laplace_draws

X = np.linspace(0.0, 1.0, 40)
G = 1.0 + X**2  # shape of the response; a shift (the registration) is not one
A_TRUE, SHIFT_TRUE = 1.5, 0.3
H = np.array([1e-6])
LO, HI = np.array([-5.0]), np.array([5.0])
V = np.full(len(X), 1e-4)


def _exponential_case(fail_at: int | None = None):
    """Observations exp(a) g(x) + shift; the model exp(a) g(x); registration 'shift'."""
    obs = np.exp(A_TRUE) * G + SHIFT_TRUE
    calls = []

    def evaluate(th, est):
        calls.append((th.copy(), dict(est)))
        if fail_at is not None and len(calls) == fail_at:
            return "wall-clock time limit reached"
        model = np.exp(th[0]) * G
        r = (obs - est["shift"]) - model
        J = ((np.exp(th[0] + H[0]) - np.exp(th[0])) * G / H[0])[:, None]
        return r, J, np.ones((len(X), 1))

    return evaluate, calls


def test_an_overshooting_step_is_halved_and_the_fit_reaches_the_truth():
    # from a = 0 the Gauss-Newton step is e^1.5 - 1 = 3.48: it lands at 3.48, twice past
    # the truth, where the misfit is larger; halved, it lands at 1.74 and converges
    evaluate, _ = _exponential_case()
    fit = joint_fit(evaluate, np.array([0.0]), {"shift": 0.0}, [0], H, LO, HI, V,
                    ["shift"], ["a"])
    rejected = [it for it in fit.iterations if it.get("rejected")]
    assert len(rejected) >= 1 and rejected[0]["theta"]["a"] == pytest.approx(np.e**1.5 - 1,
                                                                              rel=1e-4)
    # noiseless data: the truth to the finite-difference Jacobian's accuracy
    assert fit.theta[0] == pytest.approx(A_TRUE, abs=1e-4)
    assert fit.estimate["shift"] == pytest.approx(SHIFT_TRUE, abs=1e-3)
    # accepted points never raise the misfit
    accepted = [it["chi2_at_point"] for it in fit.iterations if not it.get("rejected")]
    assert all(b <= a for a, b in itertools.pairwise(accepted))


def test_the_returned_point_is_one_whose_misfit_was_measured_at_its_own_solve():
    evaluate, calls = _exponential_case()
    fit = joint_fit(evaluate, np.array([0.0]), {"shift": 0.0}, [0], H, LO, HI, V,
                    ["shift"], ["a"], max_iterations=3)
    solved = [c[0][0] for c in calls]
    assert fit.theta[0] in solved
    r, _, _ = evaluate(fit.theta, fit.estimate)
    assert fit.chi2 == pytest.approx(float(np.sum(r**2 / V)))


def test_a_failed_solve_ends_the_fit_and_keeps_the_last_confirmed_point():
    evaluate, calls = _exponential_case(fail_at=2)
    fit = joint_fit(evaluate, np.array([0.0]), {"shift": 0.0}, [0], H, LO, HI, V,
                    ["shift"], ["a"])
    assert len(calls) == 2
    assert fit.theta[0] == 0.0 and np.isfinite(fit.chi2)
    assert fit.iterations[-1] == {"failed": "wall-clock time limit reached"}


def test_no_solve_at_all_returns_no_linearization():
    evaluate, _ = _exponential_case(fail_at=1)
    fit = joint_fit(evaluate, np.array([0.0]), {"shift": 0.0}, [0], H, LO, HI, V,
                    ["shift"], ["a"])
    assert fit.J is None and fit.chi2 == float("inf")


def test_laplace_draws_are_the_exact_posterior_of_a_linear_gaussian_model():
    # linear model r = J dtheta + noise, flat prior: the posterior of theta is
    # N(theta*, (J^T V^-1 J)^-1) exactly
    rng = np.random.default_rng(0)
    n = 60
    J = rng.standard_normal((n, 2)) * [1.0, 0.1]  # one stiff and one sloppy direction
    J[:, 1] += 0.08 * J[:, 0]
    v = np.full(n, 0.25)
    exact = np.linalg.inv(J.T @ J / 0.25)
    theta = np.array([1.0, 2.0])
    d = laplace_draws(J, v, theta, np.full(2, -1e9), np.full(2, 1e9), 40000,
                      np.random.default_rng(1))
    # 40000 draws: sample (co)variances within ~1 % (sqrt(2/40000) = 0.7 %); 4 % allowed
    np.testing.assert_allclose(np.cov(d.T), exact, rtol=0.04,
                               atol=0.04 * np.sqrt(exact[0, 0] * exact[1, 1]))
    assert np.all(np.abs(d.mean(axis=0) - theta) <= 4 * np.sqrt(np.diag(exact) / 4e4))


def test_laplace_draws_stay_in_the_prior_box_and_are_reproducible():
    rng = np.random.default_rng(2)
    J = rng.standard_normal((30, 2))
    v = np.full(30, 4.0)  # wide posterior: much of it outside the box
    lo, hi = np.array([0.0, 0.0]), np.array([1.0, 1.0])
    a = laplace_draws(J, v, np.array([0.9, 0.5]), lo, hi, 500, np.random.default_rng(3))
    b = laplace_draws(J, v, np.array([0.9, 0.5]), lo, hi, 500, np.random.default_rng(3))
    assert np.all((a >= lo) & (a <= hi))
    np.testing.assert_array_equal(a, b)
