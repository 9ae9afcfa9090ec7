"""Tests of the Gaussian static log-likelihood (eq:loglik) over observation sets."""

from __future__ import annotations

import math

import numpy as np
import pytest
from _interface_shapes import arc, circle

from bayescalib.geometry.interface import Interface
from bayescalib.inference.likelihood import gaussian_loglik, log_likelihood, sigma_n2_from_config
from bayescalib.io.observations import ObservationSet
from bayescalib.measures import MeasureOptionError, compute


def test_gaussian_loglik_formula():
    # hand value: n = 3, sigma^2 = 0.0004, D = 0.02
    expected = -1.5 * math.log(2 * math.pi * 0.0004) - 0.02**2 / (2 * 0.0004)
    assert gaussian_loglik(0.02, 3, 0.0004) == pytest.approx(expected, rel=1e-14)
    # equals the sum of n independent N(0, sigma^2) log densities when D = ||d||
    d = np.array([0.01, -0.005, 0.012])
    from scipy.stats import norm

    ref = norm.logpdf(d, scale=0.02).sum()
    assert gaussian_loglik(np.linalg.norm(d), 3, 0.0004) == pytest.approx(ref, rel=1e-12)
    assert gaussian_loglik(math.nan, 3, 0.0004) == -math.inf
    assert gaussian_loglik(math.inf, 1, 0.0004) == -math.inf
    with pytest.raises(ValueError):
        gaussian_loglik(0.1, 0, 0.1)
    with pytest.raises(ValueError):
        gaussian_loglik(0.1, 1, 0.0)


@pytest.mark.parametrize("measure, opts", [("cpp", {}), ("euclidean", {"n_points": 5}), ("rkhs", {"sigma_w": 0.005})])
def test_log_likelihood_sums_snapshots(measure, opts):
    obs = ObservationSet([arc(0.4, 80), arc(0.42, 80)], ["q50", "q100"], [50.0, 100.0])
    models = [arc(0.405, 66), arc(0.41, 66)]
    total = log_likelihood(models, obs, measure, 0.0005, **opts)
    parts = [compute(measure, m, o, **opts) for m, o in zip(models, obs.snapshots)]
    expected = sum(gaussian_loglik(r.D, r.n, 0.0005) for r in parts)
    assert total == pytest.approx(expected, rel=1e-12)
    n_expected = {"cpp": 66, "euclidean": 5, "rkhs": 1}[measure]
    assert all(r.n == n_expected for r in parts)


def test_failed_snapshot_gives_minus_inf_never_nan():
    obs = ObservationSet([arc(0.4, 80), arc(0.42, 80)])
    assert log_likelihood([arc(0.4, 66), None], obs, "cpp", 0.0005) == -math.inf
    # a model the measurement lines miss: penalty by default (finite), -inf when asked to raise
    tiny = Interface.polyline([[5.0, 5.0], [5.1, 5.0]])
    v = log_likelihood([tiny, tiny], obs, "euclidean", 0.0005)
    assert math.isfinite(v)
    assert log_likelihood([tiny, tiny], obs, "euclidean", 0.0005, on_miss="raise") == -math.inf


def test_log_likelihood_errors():
    obs = ObservationSet([circle(0.4, 50)])
    with pytest.raises(ValueError, match="1 observed"):
        log_likelihood([circle(0.4, 50), circle(0.4, 50)], obs, "cpp", 0.0005)
    with pytest.raises(MeasureOptionError):
        log_likelihood([circle(0.4, 50)], obs, "nope", 0.0005)
    with pytest.raises(ValueError, match="sigma_n2"):
        log_likelihood([circle(0.4, 50)], obs, "cpp", -1.0)


def test_sigma_n2_from_config():
    assert sigma_n2_from_config({"sigma_n2": 0.0004, "sigma_n": None}) == 0.0004
    assert sigma_n2_from_config({"sigma_n2": None, "sigma_n": 0.01}) == pytest.approx(1e-4)
    assert sigma_n2_from_config({"sigma_n2": None, "sigma_n": None}) == 0.0005
    assert sigma_n2_from_config({}) == 0.0005
    with pytest.raises(ValueError, match="disagree"):
        sigma_n2_from_config({"sigma_n2": 0.0005, "sigma_n": 0.01})
    with pytest.raises(ValueError):
        sigma_n2_from_config({"sigma_n2": -1, "sigma_n": None})


def test_schema_defaults_and_errors():
    from bayescalib.config import ConfigError, validate

    cfg = validate({}, "measures")
    assert cfg["measure"]["rkhs"]["sigma_w"] == 0.005
    assert cfg["measure"]["euclidean"]["n_points"] == 10
    assert cfg["measure"]["name"] == "rkhs"
    assert cfg["observations"]["source"] == "synthetic"
    assert cfg["likelihood"] == {"sigma_n2": 0.0005, "sigma_n": None}
    assert sigma_n2_from_config(cfg["likelihood"]) == 0.0005
    # sigma_n given: no sigma_n2 default is filled in, so the two cannot disagree
    only_sn = validate({"likelihood": {"sigma_n": 0.01}}, "measures")["likelihood"]
    assert only_sn == {"sigma_n": 0.01}
    assert sigma_n2_from_config(only_sn) == pytest.approx(1e-4)
    files = validate(
        {"observations": {"source": "files", "files": [{"path": "a.png", "pixel_size": 0.01}]}}, "measures"
    )
    assert files["observations"]["files"][0]["units"] == "mm"
    with pytest.raises(ConfigError, match="sigma_ww"):
        validate({"measure": {"rkhs": {"sigma_ww": 1}}}, "measures")
    with pytest.raises(ConfigError, match="sigma_w"):
        validate({"measure": {"rkhs": {"sigma_w": -1}}}, "measures")
    # every option of the validated section is accepted by the measure functions
    from _interface_shapes import arc

    for name in ("rkhs", "euclidean", "cpp"):
        res = compute(name, arc(0.4, 30), arc(0.41, 40), **cfg["measure"][name])
        assert math.isfinite(res.D)
