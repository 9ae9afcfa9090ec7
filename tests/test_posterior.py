"""Posterior summaries, KDE/HPD levels and storage (bayescalib.inference.posterior, bayescalib.kde)."""

import json

import numpy as np
import pytest
from scipy import stats

from bayescalib.inference.parameters import Normal, Parameter, ParameterSpace, Uniform
from bayescalib.inference.posterior import (
    against_bounds,
    laplace_approximation,
    read_particles_h5,
    summarize,
    write_netcdf,
    write_particles_h5,
)
from bayescalib.inference.smc import SMCResult, run_smc
from bayescalib.inference.weights import (
    weighted_kde,
    weighted_quantile,
)


def gaussian_loglik(mu, S):
    Si = np.linalg.inv(S)
    return lambda X: -0.5 * np.einsum("ni,ij,nj->n", X - mu, Si, X - mu)


# --- uncertain conditions -------------------------------------------------------------

Y_OBS, S_OBS = 0.5, 0.5


@pytest.fixture(scope="module")
def uncertain_run():
    """Extended posterior p(x, theta | y) with y = x + theta + noise, theta uncertain.

    log L(x, theta) = log N(y; x + theta, 0.5^2), x ~ U(-3, 3), theta ~ N(0, 1) on [-5, 5].
    Marginal q(x | y) (eq. uncertain_bayes) = N(y; x, 0.5^2 + 1) on [-3, 3]: a truncated
    normal with mean 0.5 and variance 1.25 (before truncation).
    """
    space = ParameterSpace([
        Parameter("x", "-", Uniform(-3, 3), -3, 3),
        Parameter("theta", "mm^2/s", Normal(0, 1), -5, 5, uncertain=True),
    ])
    loglik = lambda X: stats.norm(X[:, 0] + X[:, 1], S_OBS).logpdf(Y_OBS)
    r = run_smc(loglik, space, n_particles=4000, n_rej=10, zeta=0.9, rng=np.random.default_rng(7))
    return space, loglik, r


def test_marginalizing_theta_matches_analytic_marginal(uncertain_run):
    # Measured over 8 seeds (same settings): sd(mean) = 0.030, sd(var ratio) = 0.015,
    # sd(90 % interval ends) = 0.045, max|KDE - pdf| = 0.023 +- 0.006. Tolerances ~5 sd.
    space, loglik, r = uncertain_run
    sd = np.sqrt(1 + S_OBS**2)
    q = stats.truncnorm((-3 - Y_OBS) / sd, (3 - Y_OBS) / sd, loc=Y_OBS, scale=sd)
    s = summarize(r, space, loglik=loglik)
    assert s["calibrated"] == ["x"] and s["uncertain"] == ["theta"]
    assert s["gaussian"]["names"] == ["x"]
    assert s["gaussian"]["mean"][0] == pytest.approx(q.mean(), abs=0.15)
    assert s["gaussian"]["cov"][0][0] == pytest.approx(q.var(), rel=0.08)
    lo, hi = s["intervals"]["x"]["0.9"]
    assert lo == pytest.approx(q.ppf(0.05), abs=0.22) and hi == pytest.approx(q.ppf(0.95), abs=0.22)
    # the 1D KDE of the x column is the analytic marginal density
    g = np.linspace(-2.0, 3.0, 256)
    dens = weighted_kde(r.particles[:, 0], r.weights)(g[None, :])
    assert np.max(np.abs(dens - q.pdf(g))) < 0.05
    assert set(s["map"]) == {"x"} and set(s["map_full"]) == {"x", "theta"}
    assert set(s["map_marginal"]) == {"x"}
    json.dumps(s, allow_nan=False)


def test_laplace_marginal_block(uncertain_run):
    # The joint log posterior is exactly quadratic in (x, theta) near the MAP (flat prior
    # in x, Gaussian in theta): Laplace covariance of x = marginal variance 1.25.
    space, loglik, _r = uncertain_run
    lap = laplace_approximation(loglik, space, np.array([0.5, 0.0]))
    assert lap["positive_definite"] and lap["names"] == ["x"]
    assert lap["cov"][0][0] == pytest.approx(1 + S_OBS**2, rel=1e-5)


def test_map_by_binning_differs_from_joint_map():
    # Mixture in (x, theta): a sharp, light component A at (0.5, 0) (weight 0.3, sd 0.02 in
    # both) and a broad-in-theta, heavy component B at x = -0.5 (weight 0.7, sd 0.03 in x,
    # theta ~ U(-1, 1)). The joint density peaks in A (119 vs 6.5) but the x-marginal
    # peaks in B (9.3 vs 6.0); -0.5 is a bin centre of 30 bins on [-1, 1].
    rng = np.random.default_rng(0)
    n = 20000
    a = rng.random(n) < 0.3
    X = np.where(a[:, None], rng.normal([0.5, 0.0], 0.02, (n, 2)),
                 np.column_stack([rng.normal(-0.5, 0.03, n), rng.uniform(-1, 1, n)]))
    dens = (0.3 * stats.norm(0.5, 0.02).pdf(X[:, 0]) * stats.norm(0, 0.02).pdf(X[:, 1])
            + 0.7 * stats.norm(-0.5, 0.03).pdf(X[:, 0]) * 0.5 * (np.abs(X[:, 1]) <= 1))
    space = ParameterSpace([Parameter("x", "-", Uniform(-1, 1), -1, 1),
                            Parameter("theta", "-", Uniform(-1, 1), -1, 1, uncertain=True)])
    res = SMCResult(particles=X, weights=np.full(n, 1 / n), loglik=np.log(dens),
                    logprior=np.full(n, np.log(0.25)), log_evidence=0.0, history={}, n_steps=1)
    s = summarize(res, space)
    assert s["map_bins"] == 30
    assert s["map_marginal"]["x"] == pytest.approx(-0.5, abs=1e-12)
    assert s["map"]["x"] == pytest.approx(0.5, abs=0.05)
    s10 = summarize(res, space, map_bins=10)  # bin centres -0.9, -0.7, ..., -0.5 is one
    assert s10["map_bins"] == 10 and s10["map_marginal"]["x"] == pytest.approx(-0.5, abs=1e-12)


# --- Laplace, intervals, Gaussian ---------------------------------------------------


def test_laplace_gaussian_with_normal_prior_and_saddle():
    # Likelihood N(x; 0, S) and priors: uniform (flat) in a, N(0, 1) in b -> posterior
    # precision S^-1 + diag(0, 1). Central differences are exact for quadratics up to
    # round-off (h = 1e-3 of the box): rel 1e-5.
    S = np.array([[0.5, 0.2], [0.2, 0.4]])
    space = ParameterSpace([Parameter("a", "-", Uniform(-5, 5), -5, 5),
                            Parameter("b", "-", Normal(0, 1), -5, 5)])
    lap = laplace_approximation(gaussian_loglik(np.zeros(2), S), space, np.zeros(2))
    expect = np.linalg.inv(np.linalg.inv(S) + np.diag([0.0, 1.0]))
    assert lap["positive_definite"]
    assert np.allclose(lap["cov"], expect, rtol=1e-5)
    saddle = laplace_approximation(lambda X: X[:, 0] ** 2 - X[:, 1] ** 2, space, np.zeros(2))
    assert saddle["positive_definite"] is False and saddle["cov"] is None
    assert min(saddle["eigenvalues"]) < 0 and "not positive definite" in saddle["note"]


def test_weighted_intervals_and_moments():
    # Importance-weighted N(0, 1) from U(-5, 5) draws (N = 100000, Kish ESS ~ 35000):
    # SE of the 5 %/95 % quantiles ~ 0.011, of the mean ~ 0.005, of the variance ~ 0.008.
    rng = np.random.default_rng(3)
    x = rng.uniform(-5, 5, 100000)
    w = stats.norm.pdf(x)
    w /= w.sum()
    space = ParameterSpace([Parameter("a", "-", Uniform(-5, 5), -5, 5)])
    res = SMCResult(particles=x[:, None], weights=w, loglik=stats.norm.logpdf(x),
                    logprior=np.full(x.size, -np.log(10)), log_evidence=-np.log(10),
                    history={}, n_steps=1)
    s = summarize(res, space, levels=(0.5, 0.9))
    assert s["intervals"]["a"]["0.9"] == pytest.approx([-1.6449, 1.6449], abs=0.06)
    assert s["intervals"]["a"]["0.5"] == pytest.approx([-0.6745, 0.6745], abs=0.04)
    assert s["mean"]["a"] == pytest.approx(0.0, abs=0.025)
    assert s["cov"][0][0] == pytest.approx(1.0, abs=0.04)
    assert s["map"]["a"] == pytest.approx(0.0, abs=0.01)
    assert weighted_quantile(np.arange(5.0), None, 0.5) == 2.0


# --- KDE and HPD levels -------------------------------------------------------------


# --- storage ------------------------------------------------------------------------


@pytest.fixture(scope="module")
def small_run():
    space = ParameterSpace([Parameter("E", "Pa", Uniform(100, 800), 100, 800),
                            Parameter("nu", "-", Uniform(-0.8, 0.5), -0.8, 0.5)])
    S = np.array([[60.0**2, 0.5 * 60 * 0.1], [0.5 * 60 * 0.1, 0.1**2]])
    ll = gaussian_loglik(np.array([400.0, 0.2]), S)
    r = run_smc(ll, space, n_particles=1000, n_rej=5, zeta=0.9, rng=np.random.default_rng(0))
    return space, r


def test_particles_h5_round_trip(tmp_path, small_run):
    space, r = small_run
    p = tmp_path / "particles.h5"
    write_particles_h5(p, r, space)
    back = read_particles_h5(p)
    for k in ("particles", "weights", "loglik", "logprior"):
        assert np.array_equal(getattr(back, k), getattr(r, k))
    assert back.log_evidence == r.log_evidence and back.n_steps == r.n_steps
    assert back.names == ["E", "nu"]
    assert set(back.history) == set(r.history)
    assert np.array_equal(back.history["gamma"], r.history["gamma"])


def test_netcdf_export_layout(tmp_path, small_run):
    import netCDF4

    space, r = small_run
    p = tmp_path / "posterior.nc"
    idx = write_netcdf(p, r, space, np.random.default_rng(0), n_draws=4000)
    with netCDF4.Dataset(p) as ds:
        assert set(ds.groups) == {"posterior", "sample_stats"}
        post = ds["posterior"]
        assert post["E"].dimensions == ("chain", "draw") and post["E"].shape == (1, 4000)
        assert post["E"].units == "Pa"
        E = post["E"][:].data[0]
        st = ds["sample_stats"]
        assert {"lp", "surrogate_loglik", "log_weight", "particle_index"} <= set(st.variables)
        assert np.array_equal(st["particle_index"][:].data[0], idx)
    assert np.array_equal(E, r.particles[idx, 0])
    # systematic resampling is unbiased: mean of draws within 5 SE of the weighted mean
    m = r.weights @ r.particles[:, 0]
    sd = np.sqrt(r.weights @ (r.particles[:, 0] - m) ** 2)
    assert abs(E.mean() - m) < 5 * sd / np.sqrt(4000)


def test_netcdf_is_arviz_inference_data_without_warnings(tmp_path, small_run):
    """ArviZ reads the export and summarizes it without a shape warning; its mean
    agrees with the weighted particle mean."""
    import warnings

    from bayescalib.inference.posterior import _arviz

    az = _arviz()
    space, r = small_run
    p = tmp_path / "posterior.nc"
    write_netcdf(p, r, space, np.random.default_rng(0), n_draws=2000)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        idata = az.from_netcdf(p)
        summ = az.summary(idata, var_names=["E", "nu"], kind="stats")
    assert idata.posterior["E"].shape == (1, 2000)
    assert idata.posterior["E"].attrs["units"] == "Pa"
    assert "lp" in idata.sample_stats
    m = r.weights @ r.particles[:, 0]
    sd = np.sqrt(r.weights @ (r.particles[:, 0] - m) ** 2)
    assert abs(summ.loc["E", "mean"] - m) < 5 * sd / np.sqrt(2000)


# --- a posterior cut by its box ---------------------------------------------------------

def _truncated_draws(centre_sd: float, sd: float, n: int = 4000, seed: int = 3) -> np.ndarray:
    """Exact draws of N(800 - centre_sd * sd, sd^2) truncated to the box [100, 800]."""
    mu = 800.0 - centre_sd * sd
    q = stats.truncnorm((100.0 - mu) / sd, (800.0 - mu) / sd, loc=mu, scale=sd)
    return q.rvs(size=n, random_state=np.random.default_rng(seed))


@pytest.mark.parametrize("centre_sd, sd, cut", [
    (0.0, 1.1, True),     # the half-ellipse's E of docs/scan_geometry.md: 798.9 +- 1.1
    (-3.0, 1.1, True),    # its mode beyond the end: all the mass piled there
    (1.0, 18.0, True),    # the density at the end 61 % of the peak
    (3.5, 18.0, False),   # 0.2 %: the box does not cut it
    (0.0, 120.0, True),   # a broad posterior (sd 0.17 of the box) still pressing on it
])
def test_a_posterior_cut_by_the_end_of_its_box_is_flagged(centre_sd, sd, cut):
    """Truncated Gaussians with known density at the box's upper end: flagged when their
    centre lies within about 2.4 sd of it (the strip estimate of half an sd), never at
    3.5 sd; the lower end (700 Pa away) never."""
    space = ParameterSpace([Parameter("E", "Pa", Uniform(100.0, 800.0), 100.0, 800.0)])
    x = _truncated_draws(centre_sd, sd)
    found = against_bounds(x[:, None], np.ones_like(x), space)
    assert [(c["name"], c["side"], c["bound"]) for c in found] == (
        [("E", "upper", 800.0)] if cut else [])
    if cut and centre_sd <= 0:
        assert found[0]["density_ratio"] > 0.5


def test_a_posterior_spread_over_its_box_is_not_flagged():
    """nu hardly informed (uniform over the box: sd 0.29 of it) and a broad Gaussian (sd
    0.25 of it): the prior decides their ends, as expected; nothing is flagged. Equal or
    unequal weights give the same answer for the same distribution."""
    rng = np.random.default_rng(0)
    space = ParameterSpace([Parameter("nu", "-", Uniform(-0.8, 0.45), -0.8, 0.45),
                            Parameter("E", "Pa", Uniform(100.0, 800.0), 100.0, 800.0)])
    X = np.column_stack([rng.uniform(-0.8, 0.45, 4000),
                         np.clip(rng.normal(450.0, 175.0, 4000), 100.0, 800.0)])
    assert against_bounds(X, np.ones(4000), space) == []
    w = rng.uniform(0.5, 1.5, 4000)
    assert against_bounds(X, w, space) == []


def test_an_end_at_the_models_own_limit_is_not_flagged():
    """nu's box ending at 0.5, the fsi model's limit (the smoke study: nu 0.20 +- 0.21,
    its density at 0.5 still a third of its peak): no prior can widen it, so it is not
    flagged; the same posterior under a box ending at 0.45 (a prior's choice) is."""
    def space(hi):
        return ParameterSpace([Parameter("nu", "-", Uniform(-0.8, hi), -0.8, hi,
                                         target="material.nu")])
    rng = np.random.default_rng(1)
    x = rng.normal(0.2, 0.21, 20000)
    for hi, flagged in ((0.5, False), (0.45, True)):
        keep = x[(x > -0.8) & (x < hi)]
        found = against_bounds(keep[:, None], np.ones_like(keep), space(hi))
        assert [(c["side"], c["bound"]) for c in found] == ([("upper", hi)] if flagged else [])


def test_the_summary_carries_the_cut_ends():
    """summarize puts the flags in posterior.json (against_bounds), in user units."""
    space = ParameterSpace([Parameter("E", "Pa", Uniform(100.0, 800.0), 100.0, 800.0)])
    x = _truncated_draws(0.0, 1.1, n=1000)
    r = SMCResult(particles=x[:, None], weights=np.ones(1000) / 1000, loglik=np.zeros(1000),
                  logprior=np.zeros(1000), log_evidence=0.0, n_steps=1, history={})
    s = summarize(r, space)
    assert [(c["name"], c["side"]) for c in s["against_bounds"]] == [("E", "upper")]
    json.dumps(s)  # JSON-serializable
