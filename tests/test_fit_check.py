"""The absolute check of the fit (bayescalib.inference.likelihood.fit_check), as
specifications: under the likelihood's own noise model the best misfit is n/2 +-
sqrt(n/2); a misfit far above it is flagged, whatever the surrogate says."""

from __future__ import annotations

import numpy as np
import pytest

from bayescalib.inference.likelihood import FIT_P_VALUE, fit_check
from bayescalib.inference.parameters import ParameterSpace
from bayescalib.inference.rounds import calibrate


@pytest.mark.parametrize("n", [1, 10, 40])
def test_noise_alone_is_flagged_at_the_stated_rate(n):
    # Misfit at the true parameters: Phi = |e|^2 / (2 sigma^2), e ~ N(0, sigma^2 I_n).
    # Over 4000 noise draws the flag rate is FIT_P_VALUE = 1e-3 (4 expected); more than
    # 15 has probability ~1e-5 under Poisson(4).
    rng = np.random.default_rng(n)
    sigma, B = 0.01, -5.0
    flags = 0
    for _ in range(4000):
        e = sigma * rng.standard_normal(n)
        phi = float(e @ e) / (2 * sigma**2)
        flags += not fit_check([B - phi], [B], [n])["consistent"]
    assert flags <= 15


def test_a_misfit_far_above_the_noise_is_flagged_with_its_causes():
    n = 40
    ok = fit_check([-(n / 2)], [0.0], [n])
    assert ok["consistent"] and ok["expected_nats"] == 20 and ok["p_value"] > 0.4
    bad = fit_check([-(n / 2 + 8 * np.sqrt(n / 2))], [0.0], [n])
    assert not bad["consistent"] and bad["p_value"] < FIT_P_VALUE
    assert "mode has not been found" in bad["words"] and "misses physics" in bad["words"]


def test_the_best_solve_is_judged_and_unknowns_are_left_out():
    L = [-np.inf, -500.0, -21.0, -3.0]
    B = [0.0, 0.0, 0.0, np.nan]  # the best L has no bound (a table of earlier runs)
    n = [40, 40, 40, 40]
    fit = fit_check(L, B, n)
    assert fit["misfit_nats"] == pytest.approx(21.0) and fit["consistent"]
    assert fit_check([-1.0], [np.nan], [3]) is None
    assert fit_check([-np.inf], [0.0], [3]) is None
    assert fit_check([-1.0], [0.0], [np.nan]) is None


def _linear_problem(bias: float):
    """y = A theta + bias + noise, n = 30, sigma = 1: a Gaussian posterior in 2D."""
    rng = np.random.default_rng(5)
    s = np.linspace(0.0, 1.0, 30)
    A = np.column_stack([s, 1.0 - s**2])
    truth = np.array([0.4, -0.2])
    y = A @ truth + bias * np.sin(6 * s) + rng.standard_normal(30)
    B = -15.0 * np.log(2 * np.pi)

    def loglik(X):
        R = np.atleast_2d(X) @ A.T - y
        return B - 0.5 * np.sum(R * R, axis=1)
    return loglik, B


@pytest.mark.parametrize("bias, consistent", [(0.0, True), (3.0, False)])
def test_a_converged_calibration_of_a_model_that_misses_physics_is_flagged(bias, consistent):
    """The surrogate converges in both cases (it agrees with itself and the posterior
    settles); only the fit check tells that the model with a structured error of
    three noise sd (bias) cannot explain the data: the best misfit is 42 nats where the
    noise explains 15 +- 3.9 (without the bias: 11)."""
    loglik, B = _linear_problem(bias)
    space = ParameterSpace.from_config([
        {"name": f"x{k}", "prior": {"type": "uniform", "lo": -3.0, "hi": 3.0},
         "bounds": [-3.0, 3.0]} for k in range(2)])
    res = calibrate(loglik, space, bound=B, n_measurements=30,
                    active={"n_initial": 16, "batch_size": 8, "max_solves": 96},
                    surrogate={"restarts": 2}, smc={"n_particles": 2000, "zeta": 0.95,
                                                    "n_rej": 10})
    assert res.converged, res.reason
    assert res.fit["consistent"] is consistent, res.fit
