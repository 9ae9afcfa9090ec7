"""The output emulator and the likelihood computed from it (bayescalib.inference.emulator)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.stats import multivariate_normal

from bayescalib.inference.emulator import (
    EmulatedLikelihood,
    OutputEmulator,
    fit_output_emulator,
    principal_outputs,
)
from bayescalib.inference.rounds import calibrate_outputs


class _FixedGP:
    """A stand-in coordinate GP with a given mean and variance at every point."""

    def __init__(self, mean: float, var: float) -> None:
        self.mean, self.var = mean, var

    def predict(self, X, return_var=False):
        X = np.atleast_2d(X)
        m, v = np.full(len(X), self.mean), np.full(len(X), self.var)
        return (m, v) if return_var else m


def _fixed_emulator(rng, m=6, k=3, a_hat=(0.4, -1.2, 2.0), s2=(0.3, 1.5, 0.01)):
    Q, _ = np.linalg.qr(rng.standard_normal((m, k)))
    return OutputEmulator(mean=rng.standard_normal(m), basis=Q.T,
                          components=[_FixedGP(a, v) for a, v in zip(a_hat, s2)],
                          discarded=0.0, n_train=10)


def test_principal_outputs_recover_a_low_rank_output_set_exactly():
    rng = np.random.default_rng(0)
    U = rng.standard_normal((30, 2)) @ rng.standard_normal((2, 12)) + 5.0
    mean, basis, coords, discarded = principal_outputs(U, energy_tol=1e-10)
    assert basis.shape == (2, 12)
    np.testing.assert_allclose(basis @ basis.T, np.eye(2), atol=1e-12)
    np.testing.assert_allclose(mean + coords @ basis, U, atol=1e-10)
    assert discarded < 1e-20


def test_principal_outputs_keep_the_fewest_components_within_the_energy_tolerance():
    rng = np.random.default_rng(1)
    scales = np.array([10.0, 3.0, 1.0, 0.1, 0.01])
    U = (rng.standard_normal((400, 5)) * scales) @ np.linalg.qr(rng.standard_normal((5, 5)))[0]
    _, S, _ = np.linalg.svd(U - U.mean(0), full_matrices=False)
    for tol in (1.5, 0.02, 1e-5):
        _, basis, _, discarded = principal_outputs(U, energy_tol=tol)
        k = basis.shape[0]
        assert discarded <= tol
        assert discarded == pytest.approx(np.sum(S[k:] ** 2) / 400)
        assert np.sum(S[k - 1:] ** 2) / 400 > tol  # one component fewer would not do


def test_emulated_likelihood_is_the_gaussian_marginal_over_the_emulator():
    # y | x ~ N(ubar + Phi^T a_hat, I + Phi^T diag(s^2) Phi) (Kennedy & O'Hagan), with
    # the likelihood's offset in place of the normalizing constant's -m/2 log(2 pi)
    rng = np.random.default_rng(2)
    em = _fixed_emulator(rng)
    y = rng.standard_normal(6) * 2.0
    lik = EmulatedLikelihood(em, y, offset=-3.0)
    a = np.array([c.mean for c in em.components])
    S = np.diag([c.var for c in em.components])
    ref = multivariate_normal(em.mean + a @ em.basis, np.eye(6) + em.basis.T @ S @ em.basis)
    expected = ref.logpdf(y) + 3.0 * np.log(2 * np.pi) - 3.0
    assert lik.predict(np.zeros((1, 2)))[0] == pytest.approx(expected, rel=1e-12)


def test_emulated_likelihood_variance_is_that_of_the_plug_in_quadratic():
    rng = np.random.default_rng(3)
    em = _fixed_emulator(rng)
    y = rng.standard_normal(6)
    lik = EmulatedLikelihood(em, y)
    _, var = lik.predict(np.zeros((1, 2)), return_var=True)
    a = np.array([c.mean for c in em.components])
    s = np.sqrt([c.var for c in em.components])
    draws = a + s * rng.standard_normal((400_000, 3))
    quad = -0.5 * np.sum((lik.c - draws) ** 2, axis=1)
    # Monte Carlo: 400 000 draws give the variance to about 0.5 % (kurtosis of a quadratic)
    assert var[0] == pytest.approx(np.var(quad), rel=0.02)


def test_emulated_likelihood_never_exceeds_the_bound_of_the_gaussian_likelihood():
    rng = np.random.default_rng(4)
    em = _fixed_emulator(rng, a_hat=(50.0, -80.0, 3.0), s2=(1e4, 0.0, 2.0))
    for y in (em.mean + np.array([50.0, -80.0, 3.0]) @ em.basis, rng.standard_normal(6)):
        lik = EmulatedLikelihood(em, y, offset=1.7)
        L = lik.predict(np.zeros((5, 2)))
        assert np.all(L <= 1.7) and np.all(L <= lik.bound)


def _linear_problem(n, seed=0):
    rng = np.random.default_rng(seed)
    A = rng.standard_normal((2, 15)) * 40.0
    bounds = np.array([[-1.0, 1.0], [-2.0, 0.5]])
    model = lambda X: np.atleast_2d(X) @ A + 3.0
    X = bounds[:, 0] + rng.random((n, 2)) * (bounds[:, 1] - bounds[:, 0])
    return model, bounds, X


def test_an_emulator_of_a_linear_model_gives_its_likelihood_to_a_small_fraction_of_a_nat():
    model, bounds, X = _linear_problem(25)
    em = fit_output_emulator(X, model(X), bounds, inputs="linear", restarts=1)
    assert em.n_components == 2  # the outputs span two directions
    truth = np.array([0.3, -0.7])
    y = model(truth)[0] + np.random.default_rng(9).standard_normal(15)
    lik = EmulatedLikelihood(em, y)
    G = np.random.default_rng(10).uniform(bounds[:, 0], bounds[:, 1], (200, 2))
    exact = -0.5 * np.sum((y - model(G)) ** 2, axis=1)
    near = exact > exact.max() - 20.0  # the region a posterior lives in
    # a GP of a linear function from 25 points: coordinates to ~1e-4 noise sd, so the
    # likelihood (values of order -1e4 nats over the box) to 0.05 nats where it matters
    np.testing.assert_allclose(lik.predict(G[near]), exact[near], atol=0.05)
    np.testing.assert_allclose(lik.plug_in(G), exact, rtol=1e-3, atol=0.05)
    # the outputs themselves (of order 100 noise sd over the box): to 1e-4 relative. A
    # single optimizer start ends at an optimum that moves with the BLAS summation order
    # (one thread, as the jobs run: 5e-3 absolute at the box's corners, 7e-5 relative)
    np.testing.assert_allclose(em.predict_outputs(G), model(G), rtol=1e-4, atol=1e-3)


def test_failed_evaluations_are_left_out_of_the_emulator():
    model, bounds, X = _linear_problem(20, seed=1)
    U = model(X)
    U[3, 4] = np.nan
    em = fit_output_emulator(X, U, bounds, inputs="linear", restarts=1)
    assert em.n_train == 19 and em.info["n_failed"] == 1
    with pytest.raises(ValueError, match="one output row per point"):
        fit_output_emulator(X[:5], U, bounds)
    with pytest.raises(ValueError, match="15 outputs"):
        EmulatedLikelihood(em, np.zeros(3))


def _coordinate_gps(X, Y, bounds, log_offset=None, device="cpu"):
    """Coordinate GPs with fixed, different ARD hyperparameters on the same inputs."""
    from bayescalib.inference.gp import GPSurrogate

    box = bounds.copy()
    if log_offset is not None:  # the log inputs' box in their own units
        logs = np.isfinite(log_offset)
        box[logs] = np.log(bounds[logs] + log_offset[logs, None])
    shift, scale = box[:, 0], box[:, 1] - box[:, 0]
    return [GPSurrogate(X_train=X, y_train=Y[:, j], shift=shift, scale=scale,
                        mean_const=0.1 * j, nugget=1e-6, variance=1.0 + j,
                        lengthscale=np.array([0.3 + 0.1 * j, 0.8 - 0.1 * j, 0.5]), ard=True,
                        kernel="matern52", log_offset=log_offset, device=device)
            for j in range(Y.shape[1])]


@pytest.mark.parametrize("log_inputs", [False, True])
def test_coordinate_gps_on_a_torch_device_are_evaluated_stacked_with_the_numpy_values(
        log_inputs):
    """On a torch device the coordinate GPs (same design points, their own
    hyperparameters) are evaluated in one batched pass; means and variances equal the
    NumPy path's to round-off (1e-10 of their size: float64 sums in another order)."""
    pytest.importorskip("torch")
    from bayescalib.inference.gp.predictor import StackedGPs

    rng = np.random.default_rng(11)
    bounds = np.array([[1.0, 5.0], [0.0, 2.0], [-1.0, 1.0]])
    X = rng.uniform(bounds[:, 0], bounds[:, 1], (40, 3))
    Y = np.column_stack([np.sin(X @ rng.standard_normal(3)) for _ in range(4)])
    offset = np.array([0.0, np.nan, np.nan]) if log_inputs else None
    cpu = OutputEmulator(mean=np.zeros(5), basis=np.eye(4, 5),
                         components=_coordinate_gps(X, Y, bounds, offset), discarded=0.0,
                         n_train=40)
    gpu = OutputEmulator(mean=np.zeros(5), basis=np.eye(4, 5),
                         components=_coordinate_gps(X, Y, bounds, offset, "torch:cpu"),
                         discarded=0.0, n_train=40)
    gpu.components[0].chunk_entries = 4 * 40 * 7  # several chunks of 7 points
    P = rng.uniform(bounds[:, 0], bounds[:, 1], (50, 3))
    a0, v0 = cpu.predict(P)
    a1, v1 = gpu.predict(P)
    assert cpu._stacked() is None and isinstance(gpu._stacked(), StackedGPs)
    np.testing.assert_allclose(a1, a0, rtol=0, atol=1e-10 * np.max(np.abs(a0)))
    np.testing.assert_allclose(v1, v0, rtol=0, atol=1e-10 * np.max(v0))
    assert np.ptp(np.median(v0, 0)) > 0.1 * np.median(v0)  # the GPs' own variances differ


def test_gps_that_differ_in_their_design_points_are_not_stacked():
    pytest.importorskip("torch")
    from bayescalib.inference.gp.predictor import StackedGPs

    rng = np.random.default_rng(12)
    bounds = np.array([[0.0, 1.0]] * 3)
    X = rng.random((20, 3))
    Y = rng.standard_normal((20, 2))
    gps = _coordinate_gps(X, Y, bounds, device="torch:cpu")
    assert StackedGPs.compatible(gps)
    other = _coordinate_gps(X + 1e-3, Y, bounds, device="torch:cpu")
    assert not StackedGPs.compatible([gps[0], other[1]])
    assert not StackedGPs.compatible(_coordinate_gps(X, Y, bounds))  # the NumPy device
    assert not StackedGPs.compatible(gps[:1])
    with pytest.raises(ValueError, match="cannot be stacked"):
        StackedGPs([gps[0], other[1]])


def test_an_emulator_file_reproduces_its_likelihood_and_is_told_from_a_gp_file(tmp_path):
    """The file a train_surrogate job writes (kind 'emulator') reads back to the same
    predictions, bit for bit, and :func:`load_surrogate` tells it from a GP file; the
    stages' interface (n_train, n_excluded, threads, hyperparameters) is kept."""
    from bayescalib.inference.emulator import load_surrogate
    from bayescalib.inference.gp import GPSurrogate, fit_gp

    model, bounds, X = _linear_problem(20, seed=2)
    U = model(X)
    U[5] = np.nan
    em = fit_output_emulator(X, U, bounds, inputs="linear", restarts=1)
    lik = EmulatedLikelihood(em, model(np.array([0.1, -0.4]))[0] + 0.5, offset=-7.0)
    lik.save(tmp_path / "e.h5")
    back = load_surrogate(tmp_path / "e.h5", device="cpu")
    assert isinstance(back, EmulatedLikelihood)
    G = np.random.default_rng(3).uniform(bounds[:, 0], bounds[:, 1], (50, 2))
    for a, b in zip(lik.predict(G, return_var=True), back.predict(G, return_var=True),
                    strict=True):
        np.testing.assert_array_equal(a, b)
    assert (back.n_train, back.n_excluded) == (19, 1)
    # the failed solve marks where the model cannot be solved, through the file too
    assert back.n_failed == lik.n_failed == 1
    assert np.isneginf(back.loglik(X[5:6])).all() and np.isneginf(lik.loglik(X[5:6])).all()
    np.testing.assert_array_equal(back.loglik(G), lik.loglik(G))
    ok = ~lik.emulator.components[0].infeasible(G)
    np.testing.assert_array_equal(lik.loglik(G)[ok], lik.predict(G)[ok])
    # a failure that says nothing of the model (a time limit) marks nothing
    none = fit_output_emulator(X, U, bounds, inputs="linear", restarts=1,
                               failed=np.zeros(len(X), bool))
    assert EmulatedLikelihood(none, lik.y).n_failed == 0
    back.threads = 2
    assert back.threads == 2 and all(gp.threads == 2 for gp in back.emulator.components)
    np.testing.assert_array_equal(back.predict(G), lik.predict(G))
    hp = back.hyperparameters
    assert hp["output"] == "outputs" and hp["components"] == em.n_components
    assert hp["bound"] <= -7.0
    gp = fit_gp(X[:10], -np.sum(X[:10] ** 2, axis=1), restarts=1, bounds=bounds,
                kernel="matern32", nugget="fixed", mean="constant", ard=False)
    gp.save(tmp_path / "g.h5")
    assert isinstance(load_surrogate(tmp_path / "g.h5", device="cpu"), GPSurrogate)
    with pytest.raises(ValueError, match="not a bayescalib GP surrogate"):
        GPSurrogate.load(tmp_path / "e.h5")


def _linear_gaussian_study():
    """A 2-D linear least-squares problem whose posterior is Gaussian in closed form
    (flat prior, posterior far inside the box)."""
    from bayescalib.inference.parameters import ParameterSpace

    rng = np.random.default_rng(5)
    A = rng.standard_normal((2, 12)) * 30.0
    y = np.array([0.2, -0.3]) @ A + rng.standard_normal(12)
    space = ParameterSpace.from_config(
        [{"name": n, "prior": {"type": "uniform", "lo": -1.0, "hi": 1.0}, "bounds": [-1.0, 1.0]}
         for n in ("a", "b")])
    cov = np.linalg.inv(A @ A.T)
    return (lambda X: np.atleast_2d(X) @ A), y, space, cov @ A @ y, cov


_SMC = {"n_particles": 2000, "n_rej": 10, "zeta": 0.99}


def test_calibrate_outputs_converges_on_the_closed_form_posterior():
    outputs, y, space, mean, cov = _linear_gaussian_study()
    res = calibrate_outputs(outputs, y, space,
                            active={"n_initial": 16, "batch_size": 16, "max_solves": 64,
                                    "smc": _SMC},
                            posterior_check={"draws": 16}, smc={**_SMC, "n_particles": 8000})
    assert res.converged, res.reason
    # every batch is made of posterior draws: the last round's confirmed the posterior
    assert len(res.loglik) <= 64 and res.rounds[-1]["posterior_check"]["confirmed"]
    assert all(set(r["next"]["kind"]) <= {"posterior_check", "probe"}
               for r in res.rounds[:-1])
    W = res.smc.weights
    m = W @ res.smc.particles
    sd = np.sqrt(W @ (res.smc.particles - m) ** 2)
    # 8000 particles: mean and sd within 0.1 posterior sd (Monte Carlo error ~0.02)
    ref_sd = np.sqrt(np.diag(cov))
    assert np.all(np.abs(m - mean) / ref_sd < 0.1)
    assert np.all(np.abs(sd / ref_sd - 1.0) < 0.1)


def test_calibrate_outputs_says_not_converged_when_the_budget_is_spent():
    outputs, y, space, _, _ = _linear_gaussian_study()
    failed = []

    def flaky(X):  # every fifth evaluation fails: a row of NaN, left out of the emulator
        U = outputs(X)
        U[::5] = np.nan
        failed.append(int(np.isnan(U[:, 0]).sum()))
        return U

    # 17: after the Sobol design one evaluation is left, too few for a check round
    res = calibrate_outputs(flaky, y, space,
                            active={"n_initial": 16, "batch_size": 8, "max_solves": 17},
                            smc=_SMC)
    assert not res.converged and res.reason.startswith("NOT converged")
    assert len(res.rounds) == 1 and len(res.loglik) == 16
    assert sum(failed) == 4 and np.sum(np.isinf(res.loglik)) == 4
    assert res.surrogate.emulator.n_train == 12
