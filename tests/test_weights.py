"""Tests of bayescalib.inference.weights: the one module for weighted particles (normalization,
effective sample size, quantiles, KDE, HPD thresholds), against analytic answers."""

from __future__ import annotations

import numpy as np
import pytest
from _gaussian import COV, MEAN
from scipy import stats

from bayescalib.inference.weights import (
    ess,
    hpd_thresholds,
    hpd_thresholds_grid,
    kde_on_grid,
    log_ess,
    normalize_log_weights,
    normalize_weights,
    weighted_kde,
    weighted_quantile,
)

# --- weights and effective sample size ----------------------------------------------


def test_ess_of_equal_weights_is_the_particle_count_and_of_one_particle_is_one():
    assert ess(np.ones(250)) == pytest.approx(250.0)
    assert ess(np.r_[1.0, np.zeros(9)]) == pytest.approx(1.0)
    # k equal non-zero weights among N: ESS = k
    assert ess(np.r_[np.ones(7), np.zeros(93)]) == pytest.approx(7.0)


def test_ess_is_invariant_to_the_scale_of_the_weights_and_agrees_with_log_ess():
    rng = np.random.default_rng(3)
    logw = rng.normal(scale=3.0, size=400)
    W = normalize_log_weights(logw)
    assert W.sum() == pytest.approx(1.0)
    assert ess(W) == pytest.approx(ess(1e-30 * np.exp(logw)), rel=1e-12)
    assert np.exp(log_ess(logw)) == pytest.approx(ess(W), rel=1e-12)
    assert np.exp(log_ess(logw + 1234.5)) == pytest.approx(ess(W), rel=1e-10)


def test_log_ess_survives_weights_that_underflow_and_zero_weights():
    # exp(-800) underflows to 0: the log form still gives ESS = 2 for two equal weights
    assert np.exp(log_ess(np.array([-800.0, -800.0, -np.inf]))) == pytest.approx(2.0)
    assert log_ess(np.full(3, -np.inf)) == -np.inf
    with pytest.raises(ValueError, match="all particle weights are zero"):
        normalize_log_weights(np.full(3, -np.inf))
    with pytest.raises(ValueError, match="NaN"):
        normalize_log_weights(np.array([0.0, np.nan]))


def test_normalize_weights_names_the_argument_in_its_errors():
    assert normalize_weights(None, 4).tolist() == [0.25] * 4
    with pytest.raises(ValueError, match="w: length 3 does not match the 4 particles"):
        normalize_weights(np.ones(3), 4, "w")
    with pytest.raises(ValueError, match="weights: negative"):
        normalize_weights(np.r_[1.0, -1.0], 2)
    with pytest.raises(ValueError, match="weights: weights sum to zero"):
        normalize_weights(np.zeros(2), 2)


# --- quantiles ----------------------------------------------------------------------


def test_weighted_quantile_is_hazen_and_matches_the_analytic_quantile_of_an_importance_sample(
        weighted_gaussian):
    assert weighted_quantile(np.arange(5.0), None, 0.5) == 2.0
    # the ECDF passes through each value at the mid-point of its weight
    x, w3 = np.array([1.0, 2.0, 3.0]), np.array([1.0, 2.0, 1.0])
    assert weighted_quantile(x, w3, [0.125, 0.5, 0.875]).tolist() == [1.0, 2.0, 3.0]
    # importance sample of N(400, 80^2) (first column): ESS ~ 700, so the 5 % / 95 %
    # quantiles have sd ~ 80 * sqrt(0.05 * 0.95 / 700) / pdf(1.645) ~ 6.4; tolerance 4 sd.
    xs, w = weighted_gaussian
    q = weighted_quantile(xs[:, 0], w, [0.05, 0.5, 0.95])
    assert q == pytest.approx(stats.norm(400.0, 80.0).ppf([0.05, 0.5, 0.95]), abs=26.0)


# --- kernel density estimate and HPD thresholds ---------------------------------------


def test_weighted_kde_1d_standard_normal():
    # N = 5000 draws: Scott bandwidth h ~ 0.18 -> bias at 0 ~ 0.0065, noise sd ~ 0.007.
    x = np.random.default_rng(0).normal(size=5000)
    g = np.linspace(-6, 6, 601)
    d = weighted_kde(x)(g[None, :])
    assert np.max(np.abs(d - stats.norm.pdf(g))) < 0.035
    assert np.trapezoid(d, g) == pytest.approx(1.0, abs=1e-3)


def test_kde_on_grid_orientation_and_hpd_thresholds():
    rng = np.random.default_rng(1)
    x = rng.normal(2.0, 0.3, 4000)
    y = rng.normal(-1.0, 1.0, 4000)
    gx, gy, D = kde_on_grid(weighted_kde(np.column_stack([x, y])), (0, 4), (-4, 2), n=80)
    assert D.shape == (80, 80)
    i, j = np.unravel_index(np.argmax(D), D.shape)
    assert abs(gx[j] - 2.0) < 0.15 and abs(gy[i] + 1.0) < 0.4  # density[i, j] at (gx[j], gy[i])
    # grid mode: for N(0, I_2) the mass-l contour is f = (1 - l) / (2 pi); 601^2 grid on
    # [-6, 6]^2 -> discretization error well below 1 %.
    g = np.linspace(-6, 6, 601)
    XX, YY = np.meshgrid(g, g)
    f = np.exp(-0.5 * (XX**2 + YY**2)) / (2 * np.pi)
    lv = np.array([0.5, 0.9, 0.99])
    assert np.allclose(hpd_thresholds_grid(f, lv), (1 - lv) / (2 * np.pi), rtol=0.01)
    # weighted-sample mode: 2 pi f(X) ~ U(0, 1), so the (1-l)-quantile has SE
    # sqrt(l (1 - l) / N) <= 0.005 for N = 10000; tolerance 0.025.
    Z = rng.normal(size=(10000, 2))
    fz = np.exp(-0.5 * (Z**2).sum(1)) / (2 * np.pi)
    t = hpd_thresholds(fz, np.ones(10000), lv)
    assert np.allclose(2 * np.pi * t, 1 - lv, atol=0.025)
    with pytest.raises(ValueError):
        hpd_thresholds_grid(f, [1.5])


def test_hpd_thresholds_match_analytic_gaussian():
    """For a 2-D Gaussian the mass of {f >= t} is 1 - t/f_max, so t_p = f_max (1 - p).

    The estimate is an empirical quantile of f(X): its standard deviation is
    f_max * sqrt(p (1 - p) / N) (delta method with dM/dt = -1/f_max). We
    allow 5 standard deviations.
    """
    rng = np.random.default_rng(1)
    n = 20000
    x = rng.multivariate_normal(MEAN, COV, size=n)
    ic = np.linalg.inv(COV)
    fmax = 1.0 / (2 * np.pi * np.sqrt(np.linalg.det(COV)))
    d = x - MEAN
    f = fmax * np.exp(-0.5 * np.einsum("ni,ij,nj->n", d, ic, d))
    levels = np.array([0.5, 0.9, 0.99])
    t = hpd_thresholds(f, None, levels)
    tol = 5 * np.sqrt(levels * (1 - levels) / n)
    np.testing.assert_array_less(np.abs(t / fmax - (1 - levels)), tol)
    assert np.all(np.diff(t) < 0)  # larger mass, lower threshold


def test_hpd_thresholds_weighted_importance_sample(weighted_gaussian):
    """Same analytic check with importance weights; MC error uses the Kish ESS."""
    x, w = weighted_gaussian
    ic = np.linalg.inv(COV)
    fmax = 1.0 / (2 * np.pi * np.sqrt(np.linalg.det(COV)))
    d = x - MEAN
    f = fmax * np.exp(-0.5 * np.einsum("ni,ij,nj->n", d, ic, d))
    ess = 1.0 / np.sum(w**2)
    levels = np.array([0.5, 0.9])
    t = hpd_thresholds(f, w, levels)
    tol = 5 * np.sqrt(levels * (1 - levels) / ess)
    np.testing.assert_array_less(np.abs(t / fmax - (1 - levels)), tol)


def test_hpd_thresholds_hold_exactly_the_requested_weighted_mass():
    rng = np.random.default_rng(2)
    f = rng.uniform(size=500)
    w = rng.uniform(size=500)
    w /= w.sum()
    for p, t in zip((0.3, 0.7, 0.95), hpd_thresholds(f, w, (0.3, 0.7, 0.95))):
        assert w[f >= t].sum() >= p - 1e-12
        assert w[f > t].sum() < p


def test_hpd_thresholds_grid_match_analytic_gaussian():
    g = np.linspace(-8, 8, 801)
    X, Y = np.meshgrid(g, g)
    f = np.exp(-0.5 * (X**2 + Y**2)) / (2 * np.pi)
    levels = [0.5, 0.9]
    t = hpd_thresholds_grid(f, levels)
    np.testing.assert_allclose(t * 2 * np.pi, 1 - np.array(levels), atol=2e-3)


def test_weighted_kde_recovers_density_of_importance_sample(weighted_gaussian):
    x, w = weighted_gaussian
    kde = weighted_kde(x, w)
    fmax = 1.0 / (2 * np.pi * np.sqrt(np.linalg.det(COV)))
    # KDE smoothing lowers the peak: with Scott's factor h the KDE of a Gaussian is
    # the Gaussian with covariance (1 + h^2) C, whose peak is fmax / (1 + h^2).
    h2 = kde.factor**2
    assert kde(MEAN[:, None])[0] == pytest.approx(fmax / (1 + h2), rel=0.15)


def test_bounded_kde_keeps_its_mass_at_the_prior_bound():
    """Particles of a density that is flat up to a bound (a posterior truncated by its
    prior box): the plain KDE drops to about half at the bound; the reflected one stays
    flat there and integrates to 1 inside the box."""

    rng = np.random.default_rng(0)
    x = rng.uniform(100.0, 800.0, 20000)
    g = np.linspace(100.0, 800.0, 1401)
    plain = weighted_kde(x)(g[None, :])
    bounded = weighted_kde(x, support=[[100.0, 800.0]])(g[None, :])
    flat = 1.0 / 700.0
    assert plain[0] < 0.6 * flat  # the boundary bias the correction removes
    assert bounded[0] == pytest.approx(flat, rel=0.1)
    assert bounded[len(g) // 2] == pytest.approx(flat, rel=0.1)
    assert np.trapezoid(bounded, g) == pytest.approx(1.0, abs=0.01)
    assert weighted_kde(x, support=[[100.0, 800.0]])(np.array([[99.0, 801.0]])).tolist() == [0, 0]
    # 2D: one bounded axis, one free
    xy = np.column_stack([x, rng.normal(size=x.size)])
    k2 = weighted_kde(xy, support=[[100.0, 800.0], [-np.inf, np.inf]])
    at_edge = k2(np.array([[100.0], [0.0]]))[0]
    inside = k2(np.array([[450.0], [0.0]]))[0]
    assert at_edge == pytest.approx(inside, rel=0.15)


@pytest.mark.parametrize("support", [None, [[100.0, 800.0], [-0.8, 0.5]]])
def test_kde_on_grid_by_binning_equals_the_pointwise_kde(support):
    # A correlated cloud (rho 0.9) near the box's upper nu face: the binned FFT grid
    # agrees with the pointwise KDE (reflection included) to 2 % of the peak; the
    # binning error is O((step / bandwidth)^2) and the bandwidth is ~2.6 steps in E.
    from bayescalib.inference.weights import _binned_kde_grid, kde_on_grid, weighted_kde

    rng = np.random.default_rng(0)
    cov = [[80.0**2, 0.9 * 80 * 0.2], [0.9 * 80 * 0.2, 0.2**2]]
    X = rng.multivariate_normal([400.0, 0.2], cov, 5000)
    X = X[(X[:, 1] <= 0.5) & (X[:, 1] >= -0.8) & (X[:, 0] >= 100) & (X[:, 0] <= 800)]
    kde = weighted_kde(X, rng.random(len(X)), support=support)
    gx, gy, dens = kde_on_grid(kde, (100.0, 800.0), (-0.8, 0.5), 100)
    binned = _binned_kde_grid(kde, gx, gy)
    assert binned is not None and np.array_equal(dens, binned)  # the binned path is taken
    xx, yy = np.meshgrid(gx, gy)
    ref = kde(np.vstack([xx.ravel(), yy.ravel()])).reshape(xx.shape)
    assert np.max(np.abs(dens - ref)) <= 0.02 * ref.max()


def test_kde_on_grid_falls_back_to_pointwise_below_two_grid_steps():
    from bayescalib.inference.weights import _binned_kde_grid, kde_on_grid, weighted_kde

    rng = np.random.default_rng(1)
    X = rng.normal([0.5, 0.5], [0.004, 0.3], size=(400, 2))
    kde = weighted_kde(X, None)
    gx, gy, dens = kde_on_grid(kde, (0.0, 1.0), (0.0, 1.0), 50)
    assert _binned_kde_grid(kde, gx, gy) is None
    xx, yy = np.meshgrid(gx, gy)
    assert np.array_equal(dens, kde(np.vstack([xx.ravel(), yy.ravel()])).reshape(xx.shape))


def test_kde_evaluation_is_scipys_sum_near_the_particles_and_zero_far_from_them():
    """The KDE skips points farther than KDE_RADIUS kernel sds (Mahalanobis) from every
    particle: there it returns 0 where scipy's full sum is below e^-40 of the kernel's
    peak; at every other point it returns scipy's sum (to 1e-12 relative: scipy whitens
    the points as one matrix, whose product rounds by its size). After a bandwidth
    change the same holds with the new bandwidth."""
    from bayescalib.inference.weights import KDE_RADIUS

    rng = np.random.default_rng(2)
    X = rng.multivariate_normal([400.0, 0.2], [[30.0**2, 0.5], [0.5, 0.03**2]], 3000)
    w = rng.random(3000)
    kde = weighted_kde(X, w)
    ref = stats.gaussian_kde(X.T, weights=w / w.sum())
    gx, gy = np.meshgrid(np.linspace(100, 800, 120), np.linspace(-0.8, 0.5, 120))
    P = np.vstack([gx.ravel(), gy.ravel()])
    peak = 1.0 / (2 * np.pi * np.sqrt(np.linalg.det(ref.covariance)))
    for _ in range(2):
        got, full = kde(P), ref(P)
        far = got == 0.0
        assert 0.5 < far.mean() < 1.0  # most of the box is far from this narrow cloud
        assert np.all(full[far] <= np.exp(-0.5 * KDE_RADIUS**2) * peak)
        assert np.allclose(got[~far], full[~far], rtol=1e-12, atol=0.0)
        assert np.allclose(kde(X[:50].T), ref(X[:50].T), rtol=1e-12, atol=0.0)
        kde.set_bandwidth(0.5 * kde.factor)
        ref.set_bandwidth(0.5 * ref.factor)
        peak = 1.0 / (2 * np.pi * np.sqrt(np.linalg.det(ref.covariance)))


def test_reflected_kde_on_a_grid_agrees_with_the_untruncated_sum():
    """A narrow cloud against the box's upper nu face, on a grid too coarse for the
    binned path (the pointwise one with its mirror images): the figure's grid equals the
    full reflected sum (every image, every grid point) to 1e-13 of its peak (round-off;
    the kernels left out are below e^-40 of a kernel's peak)."""
    from bayescalib.inference.weights import BoundedKDE, _binned_kde_grid

    rng = np.random.default_rng(4)
    X = rng.normal([400.0, 0.47], [5.0, 0.02], size=(4000, 2))
    X = X[X[:, 1] <= 0.5]
    box = [[100.0, 800.0], [-0.8, 0.5]]
    kde = weighted_kde(X, None, support=box)
    gx, gy, dens = kde_on_grid(kde, box[0], box[1], 100)
    assert _binned_kde_grid(kde, gx, gy) is None  # bandwidth below two grid steps
    full = BoundedKDE(stats.gaussian_kde(X.T), box)
    xx, yy = np.meshgrid(gx, gy)
    ref = full(np.vstack([xx.ravel(), yy.ravel()])).reshape(xx.shape)
    assert ref.max() > 0
    assert np.max(np.abs(dens - ref)) <= 1e-13 * ref.max()
