"""Priors, parameters and the parameter space (bayescalib.inference.parameters) and the inference schema."""

import json

import numpy as np
import pytest
from scipy import integrate, stats

from bayescalib.config import ConfigError, validate
from bayescalib.inference.parameters import (
    LogNormal,
    Normal,
    Parameter,
    ParameterError,
    ParameterSpace,
    ScaledBeta,
    Uniform,
)

PAPER_INFORMED = [
    {"name": "E", "unit": "Pa", "target": "material.E",
     "prior": {"type": "lognormal", "mu": 5.86, "sigma": 0.4}, "bounds": [100.0, 800.0],
     "ground_truth": 400.0},
    {"name": "nu", "unit": "-", "target": "material.nu",
     "prior": {"type": "beta", "a": 43 / 13, "b": 22 / 13, "lo": -0.8, "hi": 0.5},
     "ground_truth": 0.3},
    {"name": "V_in", "unit": "mm^2/s", "target": "inflow.rate", "uncertain": True,
     "prior": {"type": "beta", "a": 2.6, "b": 1.4}, "bounds": [0.0, 110.0],
     "ground_truth": 100.0},
]


def test_prior_densities_match_scipy():
    # Exact formulas: agreement to float round-off (1e-12).
    x = np.linspace(0.05, 0.95, 7)
    assert np.allclose(Uniform(0, 2).logpdf(x), np.log(0.5), atol=1e-12)
    assert np.allclose(Normal(1, 2).logpdf(x), stats.norm(1, 2).logpdf(x), atol=1e-12)
    assert np.allclose(
        LogNormal(0.1, 0.5).logpdf(x), stats.lognorm(0.5, scale=np.exp(0.1)).logpdf(x), atol=1e-12
    )
    b = ScaledBeta(2.0, 3.0, -1.0, 3.0)
    xb = -1.0 + 4.0 * x
    assert np.allclose(b.logpdf(xb), stats.beta(2, 3).logpdf(x) - np.log(4.0), atol=1e-12)
    assert Uniform(0, 1).logpdf(1.5) == -np.inf
    assert LogNormal(0, 1).logpdf(-1.0) == -np.inf


def test_paper_prior_modes_and_means():
    # Paper Sec. 4.3: modes ~300 Pa, 0.2, 88 mm^2/s (closed forms, round-off tolerance).
    assert LogNormal(5.86, 0.4).mode == pytest.approx(np.exp(5.86 - 0.16), rel=1e-12)
    assert abs(LogNormal(5.86, 0.4).mode - 300.0) < 2.0
    assert ScaledBeta(43 / 13, 22 / 13, -0.8, 0.5).mode == pytest.approx(0.2, abs=1e-12)
    assert ScaledBeta(2.6, 1.4, 0.0, 110.0).mode == pytest.approx(88.0, abs=1e-12)
    assert ScaledBeta(2.6, 1.4, 0.0, 110.0).mean == pytest.approx(110 * 2.6 / 4.0, rel=1e-12)
    assert Normal(3.0, 1.0).mode == 3.0


def test_ppf_inverts_cdf():
    u = np.linspace(0.01, 0.99, 11)
    for p in (Uniform(-1, 2), Normal(0, 3), LogNormal(1, 0.3), ScaledBeta(2.6, 1.4, 0, 110)):
        assert np.allclose(p.cdf(p.ppf(u)), u, atol=1e-10)


def test_truncated_prior_is_normalized_on_box():
    # The box-truncated density integrates to 1 (quad accuracy ~1e-8).
    par = Parameter("E", "Pa", LogNormal(5.86, 0.4), 100.0, 800.0)
    val, _ = integrate.quad(lambda x: np.exp(par.logpdf(np.array([x]))[0]), 100.0, 800.0)
    assert val == pytest.approx(1.0, abs=1e-8)
    assert par.logpdf(np.array([99.0, 801.0])).tolist() == [-np.inf, -np.inf]


def test_sample_prior_follows_truncated_distribution():
    # KS test of 4000 draws against the truncated CDF; p > 1e-3 fails for a wrong
    # sampler essentially always and for a correct one with probability 1e-3
    # (fixed seed: deterministic).
    space = ParameterSpace.from_config(PAPER_INFORMED)
    X = space.sample_prior(4000, np.random.default_rng(1))
    b = space.bounds
    assert np.all((X >= b[:, 0]) & (X <= b[:, 1]))
    par = space.parameters[0]
    cdf = lambda x: (par.prior.cdf(x) - par._cdf_lo) / (par._cdf_hi - par._cdf_lo)
    assert stats.kstest(X[:, 0], cdf).pvalue > 1e-3
    assert stats.kstest(X[:, 2], ScaledBeta(2.6, 1.4, 0, 110).cdf).pvalue > 1e-3
    assert np.all(np.isfinite(space.logprior(X)))


def test_space_from_config_properties():
    space = ParameterSpace.from_config(PAPER_INFORMED)
    assert space.names == ["E", "nu", "V_in"]
    assert space.units == ["Pa", "-", "mm^2/s"]
    assert space.dim == 3
    assert space.calibrated_mask.tolist() == [True, True, False]
    assert space.calibrated_names == ["E", "nu"]
    assert np.allclose(space.bounds, [[100, 800], [-0.8, 0.5], [0, 110]])
    assert space.ground_truth.tolist() == [400.0, 0.3, 100.0]
    assert space.targets == ["material.E", "material.nu", "inflow.rate"]
    lp = space.logprior(np.array([[400.0, 0.2, 88.0], [50.0, 0.2, 88.0], [np.nan, 0.0, 1.0]]))
    assert np.isfinite(lp[0]) and lp[1] == -np.inf and lp[2] == -np.inf
    json.dumps(space.to_config())
    again = ParameterSpace.from_config(space.to_config())
    assert again.names == space.names and np.allclose(again.bounds, space.bounds)


@pytest.mark.parametrize(
    "entry, words",
    [
        ({"name": "E", "prior": {"type": "uniform", "lo": 800, "hi": 100}}, ["'E'", "lo"]),
        ({"name": "E", "prior": {"type": "uniform"}, "bounds": [5, 5]}, ["'E'"]),
        ({"name": "E", "prior": {"type": "normal", "mu": 0, "sigma": -1}, "bounds": [0, 1]}, ["'E'", "sigma"]),
        ({"name": "E", "prior": {"type": "lognormal", "mu": 0, "sigma": 0}, "bounds": [0, 1]}, ["'E'", "sigma"]),
        ({"name": "nu", "prior": {"type": "beta", "a": 0, "b": 1, "lo": 0, "hi": 1}}, ["'nu'", "a > 0"]),
        ({"name": "E", "prior": {"type": "gamma", "k": 1}}, ["'E'", "unknown prior type"]),
        ({"name": "E", "prior": {"type": "normal", "mu": 0, "sigma": 1}}, ["'E'", "bounds"]),
        ({"name": "E", "prior": {"type": "uniform", "lo": 0, "hi": 1}, "ground_truth": 2.0}, ["'E'", "ground truth"]),
        ({"name": "E", "prior": {"type": "lognormal", "mu": 0, "sigma": 1}, "bounds": [-2, -1]}, ["'E'", "no mass"]),
        ({"name": "E", "prior": {"type": "uniform", "lo": 0, "hi": 1}, "colour": 1}, ["'E'", "colour"]),
    ],
)
def test_bad_input_names_the_parameter(entry, words):
    with pytest.raises(ParameterError) as exc:
        ParameterSpace.from_config([entry])
    for w in words:
        assert w in str(exc.value)
    assert isinstance(exc.value, ValueError)


def test_duplicate_names_rejected():
    p = Parameter("E", "Pa", Uniform(0, 1), 0, 1)
    with pytest.raises(ParameterError, match="'E'"):
        ParameterSpace([p, p])


def test_schema_defaults_and_unknown_keys():
    cfg = validate({"parameters": PAPER_INFORMED}, "inference")
    assert cfg["smc"] == {"n_particles": 5000, "n_rej": 20, "zeta": 0.995,
                          "ess_min_ratio": 0.5, "max_steps": 10000, "seed": 0,
                          "max_memory_gib": 4.0}
    assert cfg["surrogate"]["mean_offset_factor"] == 1.0
    assert cfg["surrogate"]["nugget_factor"] == 1e-5
    assert cfg["posterior"]["levels"] == [0.5, 0.9, 0.99]
    assert cfg["parameters"][0]["uncertain"] is False
    ParameterSpace.from_config(cfg["parameters"])  # the validated section builds a space
    with pytest.raises(ConfigError, match="n_particle"):
        validate({"smc": {"n_particle": 10}}, "inference")
    with pytest.raises(ConfigError):
        validate({"parameters": [{"name": "E", "prior": {"type": "normal", "mu": 1}}]}, "inference")
