"""Detection trials of the linearized diagnosis (bayescalib.diagnosis.detection) on the
analytic stand-in model (a hidden base slip, candidates prestrain and base_slip, two
loadings, 1 um noise as in tests/data/analytic_concealed.yaml).

Rates are binomial: over N seeds a rate p has standard deviation sqrt(p (1 - p) / N);
the tolerances allow about 3 of them. With two candidates, the top-1 rate of an
effect far below detectability is the chance level 1/2 (two score statistics that are
chi2_1 under the null are equally likely to be the larger), not 0: what must vanish
there is a *significant* top-1 ranking (a false claim), at most about alpha / m.
"""

from __future__ import annotations

import numpy as np
import pytest

from bayescalib.diagnosis.detection import (
    detection_limit,
    detection_range,
    detection_trials,
    linear_detectable_magnitude,
    linearize,
    noisy_nodes,
)
from bayescalib.geometry.interface import Interface
from bayescalib.io.observations import add_noise
from bayescalib.models.analytic import interface

TRUTH = {"E": 400.0, "nu": 0.3}
LOADS = [50.0, 100.0]  # V: factors 0.5 and 1 of the nominal 100
STEPS = {"prestrain": 0.01, "base_slip": 0.005}
FD = {"E": 7.0, "nu": 0.0125}  # fd_step 0.01 of the box widths, as the diagnosis
SIGMA = 0.001
SETTINGS = {"alpha": 0.05, "r2_min": 0.5, "max_effects": 2,
            "ranges": {"prestrain": (-0.05, 0.05), "base_slip": (0.0, 0.03)}}


def _curves(params):
    return [Interface.polyline(interface({**params, "V": V})["current"]) for V in LOADS]


@pytest.fixture(scope="module")
def lin():
    base = _curves(TRUTH)
    fd = [_curves({**TRUTH, k: TRUTH[k] + h}) for k, h in FD.items()]
    cands = {n: _curves({**TRUTH, n: st}) for n, st in STEPS.items()}
    return base, fd, cands


def _trials(lin, slip, seeds, sigma=SIGMA):
    base, fd, cands = lin
    nodes = [c.points for c in _curves({**TRUTH, "base_slip": slip})]
    _, J, sigs = linearize(nodes, base, fd, list(FD.values()), cands, STEPS)
    return detection_trials(nodes, base, J, sigs, "base_slip", sigma=sigma, seeds=seeds,
                            **SETTINGS)


def test_linearize_reproduces_the_hidden_effect_to_first_order(lin):
    """The residual of the noise-free hidden truth is the slip's signature times phi
    (the model is linear in the slip). Not exactly: on a polyline of 66 nodes the
    normal turns by ~3 degrees at each vertex, so the distance of a moved node to the
    base curve and the offset of the moved curve at its projection differ by a few %
    of the move (4-5 % RMS, the same at 0.1 and 1 um: geometry, not nonlinearity);
    8 % is allowed."""
    base, fd, cands = lin
    for slip in (1e-4, 1e-3):
        nodes = [c.points for c in _curves({**TRUTH, "base_slip": slip})]
        y, J, sigs = linearize(nodes, base, fd, list(FD.values()), cands, STEPS)
        assert J.shape == (len(y), 2) and set(sigs) == set(STEPS)
        assert np.linalg.norm(y - slip * sigs["base_slip"]) <= 0.08 * np.linalg.norm(y)


def test_a_large_effect_is_always_named_and_a_tiny_one_never_claimed(lin):
    seeds = range(100)
    big = _trials(lin, 0.002, seeds)  # linear non-centrality far above the test's level
    assert big["top1"].mean() >= 0.97 and big["significant"].mean() >= 0.97
    assert big["mismatch"].mean() >= 0.97  # the re-fit test sees the mismatch
    tiny = _trials(lin, 1.0e-6, seeds)
    # chance level 1/2 for two candidates, +- 3 binomial sd (0.05 at N = 100)
    assert 0.35 <= tiny["top1"].mean() <= 0.65
    # a significant top-1 ranking is a false claim: at most alpha/m = 0.025 (+ 3 sd)
    assert (tiny["top1"] & tiny["significant"]).mean() <= 0.07


def test_the_rate_grows_with_the_magnitude_and_falls_with_the_noise(lin):
    seeds = range(60)
    rates = [(_trials(lin, s, seeds)["significant"]).mean() for s in (2e-4, 5e-4, 1e-3)]
    assert rates[0] < rates[1] < rates[2]
    # twice the noise: the same magnitude is seen less often
    assert _trials(lin, 5e-4, seeds, sigma=2 * SIGMA)["significant"].mean() < rates[1]


def test_seeds_are_reproducible(lin):
    a = _trials(lin, 5e-4, [3, 4, 5])
    b = _trials(lin, 5e-4, [3, 4, 5])
    for k in a:
        np.testing.assert_array_equal(a[k], b[k])
    c = _trials(lin, 5e-4, [6, 7, 8])
    assert not np.array_equal(a["statistic"], c["statistic"])


def test_noise_is_that_of_the_synthetic_observations():
    """Seed s gives the nodes that observations.seed: s gives (stages.observe: one
    generator, add_noise snapshot by snapshot)."""
    curves = _curves(TRUTH)
    rng = np.random.default_rng(11)
    expected = [add_noise(c, SIGMA, rng).points for c in curves]
    got = noisy_nodes([c.points for c in curves], SIGMA, 11)
    for e, g in zip(expected, got, strict=True):
        np.testing.assert_array_equal(e, g)


def test_detection_limit_interpolates_in_log_magnitude():
    m = [1e-4, 1e-3, 1e-2]
    # 0.6 -> 1.0 between 1e-3 and 1e-2: 0.8 is half-way in log, at 10^-2.5
    lim, kind = detection_limit(m, [0.1, 0.6, 1.0])
    assert kind == "interpolated" and lim == pytest.approx(10**-2.5, rel=1e-12)
    assert detection_limit(m, [0.9, 1.0, 1.0]) == (1e-4, "<= min tested")
    assert detection_limit(m, [0.1, 0.5, 0.7]) == (1e-2, "> max tested")
    # a failed solve (NaN) is skipped: the crossing is between 1e-4 and 1e-2
    lim, kind = detection_limit(m, [0.6, np.nan, 1.0])
    assert kind == "interpolated" and lim == pytest.approx(1e-3, rel=1e-12)
    with pytest.raises(ValueError, match="increasing"):
        detection_limit([1e-3, 1e-4], [0.1, 0.9])


def test_detection_range_says_where_a_nonlinear_effect_is_lost_again():
    m = [1.0, 10.0, 100.0, 1000.0]
    rng_ = detection_range(m, [0.2, 0.9, 0.6, 0.1])
    # reached half-way in log between 1 and 10 (0.2 -> 0.9 passes 0.8 at 6/7 of the way)
    assert rng_["limit"] == pytest.approx(10 ** (6 / 7), rel=1e-12)
    # lost again between 10 and 100: 0.9 -> 0.6 passes 0.8 at 1/3 of the way
    assert rng_["lost_above"] == pytest.approx(10 ** (4 / 3), rel=1e-12)
    assert (rng_["max_rate"], rng_["at"]) == (0.9, 10.0)
    assert detection_range(m, [0.2, 0.9, 1.0, 1.0])["lost_above"] is None
    never = detection_range(m, [0.2, 0.7, 0.5, 0.1])
    assert never["kind"] == "> max tested" and (never["max_rate"], never["at"]) == (0.7, 10.0)


def test_linear_detectable_magnitude_ignores_what_the_base_absorbs():
    J = np.array([[1.0], [1.0], [0.0]])
    g = np.array([2.0, 2.0, 0.5])  # only the last entry is beyond J's reach
    assert linear_detectable_magnitude(J, g, 0.001, z=4.0) == pytest.approx(0.008)
    assert linear_detectable_magnitude(J, J[:, 0], 0.001) == float("inf")
