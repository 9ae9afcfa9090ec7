"""SMC with adaptive tempering (bayescalib.inference.smc) on analytic posteriors.

Tolerances are several Monte Carlo standard deviations of the estimator,
measured over independent seeds with the same settings (numbers in the
comments); each test uses one fixed seed, so it is deterministic.
"""

import numpy as np
import pytest
from scipy import stats
from scipy.special import logsumexp

from bayescalib.inference.parameters import Normal, Parameter, ParameterSpace, Uniform
from bayescalib.inference.resampling import systematic_resample
from bayescalib.inference.smc import next_gamma, run_smc


def wmean_var(r, j=0):
    x = r.particles[:, j]
    m = r.weights @ x
    return m, r.weights @ (x - m) ** 2


def test_conjugate_gaussian_1d():
    # prior N(2, 1), likelihood N(0 | x, 1) -> posterior N(1, 0.5), log Z = -1 - 0.5 ln(4 pi).
    # Over 20 seeds (N=2000, n_rej=5, zeta=0.9): sd(log Z)=0.011, sd(mean)=0.019, sd(var)=0.013.
    # Tolerances = 5 sd. The box [-8, 12] truncates < 1e-15 of the prior mass.
    space = ParameterSpace([Parameter("x", "-", Normal(2.0, 1.0), -8.0, 12.0)])
    loglik = lambda X: -0.5 * X[:, 0] ** 2 - 0.5 * np.log(2 * np.pi)
    r = run_smc(loglik, space, n_particles=2000, n_rej=5, zeta=0.9, rng=np.random.default_rng(0))
    m, v = wmean_var(r)
    assert r.log_evidence == pytest.approx(-1 - 0.5 * np.log(4 * np.pi), abs=0.06)
    assert m == pytest.approx(1.0, abs=0.1)
    assert v == pytest.approx(0.5, abs=0.07)
    assert r.history["gamma"][-1] == 1.0
    assert np.all(np.diff(r.history["gamma"]) > 0)
    assert r.weights.sum() == pytest.approx(1.0, abs=1e-12)
    assert r.n_steps == len(r.history["gamma"])


def test_correlated_gaussian_2d():
    # prior U[-5, 5]^2; likelihood N(x; mu, S) with correlation 0.8 -> posterior N(mu, S)
    # (box truncation < 1e-9), Z = 1/100. Measured sd over 10 seeds (N=2000, n_rej=10,
    # zeta=0.9): mean 0.02 (in posterior sd), var ratio 0.02, corr 0.0044, log Z 0.027.
    # Tolerances ~5 sd.
    mu = np.array([0.5, -1.0])
    S = np.array([[0.25, 0.8 * 0.5 * 0.3], [0.8 * 0.5 * 0.3, 0.09]])
    Si = np.linalg.inv(S)
    c = -0.5 * np.log(np.linalg.det(2 * np.pi * S))
    loglik = lambda X: c - 0.5 * np.einsum("ni,ij,nj->n", X - mu, Si, X - mu)
    space = ParameterSpace([Parameter(n, "-", Uniform(-5, 5), -5, 5) for n in ("a", "b")])
    r = run_smc(loglik, space, n_particles=2000, n_rej=10, zeta=0.9, rng=np.random.default_rng(3))
    W, X = r.weights, r.particles
    m = W @ X
    C = ((X - m) * W[:, None]).T @ (X - m)
    sd = np.sqrt(np.diag(S))
    assert np.all(np.abs(m - mu) / sd < 0.1)
    assert np.allclose(np.diag(C) / np.diag(S), 1.0, atol=0.1)
    assert C[0, 1] / np.sqrt(C[0, 0] * C[1, 1]) == pytest.approx(0.8, abs=0.025)
    assert r.log_evidence == pytest.approx(np.log(1 / 100), abs=0.15)


def minson_loglik(X, s=0.1):
    a = -0.5 * np.sum((X - 0.5) ** 2, 1) / s**2
    b = -0.5 * np.sum((X + 0.5) ** 2, 1) / s**2
    c = -X.shape[1] * np.log(s * np.sqrt(2 * np.pi))
    return logsumexp(np.stack([np.log(0.1) + a, np.log(0.9) + b]), axis=0) + c


def test_minson_bimodal_4d():
    # Minson et al. (2013): modes 0.1 at +0.5*1 and 0.9 at -0.5*1, sigma 0.1, prior U[-2,2]^4:
    # per-dimension mean -0.4, variance 0.1 (0.09 + 0.01), log Z = ln 4^-4.
    # Over 8 seeds with N=4000 (n_rej=10, zeta=0.9): sd(mode weight)=0.005, max over
    # dimensions of |mean + 0.4| = 0.007 +- 0.003, of |var - 0.1| = 0.005 +- 0.002,
    # sd(log Z)=0.046. Tolerances ~5-6 sd.
    space = ParameterSpace([Parameter(f"x{i}", "-", Uniform(-2, 2), -2, 2) for i in range(4)])
    r = run_smc(minson_loglik, space, n_particles=4000, n_rej=10, zeta=0.9,
                rng=np.random.default_rng(11))
    W, X = r.weights, r.particles
    w_pos = W[X.sum(1) > 0].sum()
    assert w_pos == pytest.approx(0.1, abs=0.03)
    m = W @ X
    v = W @ (X - m) ** 2
    assert np.allclose(m, -0.4, atol=0.025)
    assert np.allclose(v, 0.1, atol=0.015)
    assert r.log_evidence == pytest.approx(np.log(4.0**-4), abs=0.25)


BANANA_BOX = np.array([[100.0, 800.0], [-0.8, 0.5]])


def banana_loglik(X):
    """A curved band in (E, nu) where low E goes with low nu (like the paper's posterior)."""
    e = (X[:, 0] - 100) / 700
    n = (X[:, 1] + 0.8) / 1.3
    return -0.5 * ((n - 0.25 - 0.8 * e**1.5) / 0.04) ** 2 - 0.5 * ((e - 0.4) / 0.2) ** 2


def test_banana_against_dense_grid():
    # Reference: 801 x 801 grid of the posterior (uniform prior) -- quadrature error far
    # below the Monte Carlo error. Over 10 seeds (N=2000, n_rej=10, zeta=0.95): sd of the
    # mean error 0.02 posterior sd; variance ratio 0.98 +- 0.027; correlation 0.951 +- 0.0024
    # (reference 0.953); marginal Kolmogorov distance 0.02 +- 0.007. Tolerances ~5 sd.
    space = ParameterSpace([
        Parameter("E", "Pa", Uniform(100, 800), 100, 800),
        Parameter("nu", "-", Uniform(-0.8, 0.5), -0.8, 0.5),
    ])
    g1 = np.linspace(100, 800, 801)
    g2 = np.linspace(-0.8, 0.5, 801)
    G1, G2 = np.meshgrid(g1, g2, indexing="ij")
    L = banana_loglik(np.column_stack([G1.ravel(), G2.ravel()])).reshape(G1.shape)
    P = np.exp(L - L.max())
    P /= P.sum()
    m_ref = np.array([(P * G1).sum(), (P * G2).sum()])
    d1, d2 = G1 - m_ref[0], G2 - m_ref[1]
    C_ref = np.array([[(P * d1 * d1).sum(), (P * d1 * d2).sum()],
                      [(P * d1 * d2).sum(), (P * d2 * d2).sum()]])
    r = run_smc(banana_loglik, space, n_particles=2000, n_rej=10, zeta=0.95,
                rng=np.random.default_rng(5))
    W, X = r.weights, r.particles
    m = W @ X
    C = ((X - m) * W[:, None]).T @ (X - m)
    assert np.all(np.abs(m - m_ref) / np.sqrt(np.diag(C_ref)) < 0.1)
    assert np.allclose(np.diag(C) / np.diag(C_ref), 1.0, atol=0.15)
    corr = lambda A: A[0, 1] / np.sqrt(A[0, 0] * A[1, 1])
    assert corr(C) == pytest.approx(corr(C_ref), abs=0.015)
    for j, (g, pm) in enumerate([(g1, P.sum(1)), (g2, P.sum(0))]):
        o = np.argsort(X[:, j])
        F_smc = np.interp(g, X[o, j], np.cumsum(W[o]), left=0.0, right=1.0)
        assert np.max(np.abs(np.cumsum(pm) - F_smc)) < 0.06


def test_seeded_reproducibility_is_bitwise():
    space = ParameterSpace([Parameter(n, "-", Uniform(-2, 2), -2, 2) for n in "ab"])
    kw = {"n_particles": 500, "n_rej": 3, "zeta": 0.9}
    r1 = run_smc(minson_loglik, space, rng=np.random.default_rng(42), **kw)
    r2 = run_smc(minson_loglik, space, rng=np.random.default_rng(42), **kw)
    r3 = run_smc(minson_loglik, space, rng=np.random.default_rng(43), **kw)
    assert np.array_equal(r1.particles, r2.particles)
    assert np.array_equal(r1.weights, r2.weights)
    assert r1.log_evidence == r2.log_evidence
    for k in r1.history:
        if k != "time_s":
            assert np.array_equal(r1.history[k], r2.history[k])
    assert not np.array_equal(r1.particles, r3.particles)


def test_minus_inf_loglik_on_half_the_box():
    # log L = log N(x; 0, 0.3^2 I) for x0 < 0 and -inf for x0 >= 0; prior U[-1,1]^2.
    # Posterior: x0 ~ N(0, 0.3^2) truncated to [-1, 0], x1 ~ N(0, 0.3^2) truncated to [-1, 1];
    # Z = P(-1<x0<0) P(-1<x1<1) / 4. Tolerances ~5 MC sd (over 10 seeds at N=2000:
    # sd(mean x0) = 0.004, sd(log Z) = 0.039).
    s = 0.3

    def loglik(X):
        ll = stats.norm(0, s).logpdf(X).sum(1)
        return np.where(X[:, 0] < 0, ll, -np.inf)

    space = ParameterSpace([Parameter(n, "-", Uniform(-1, 1), -1, 1) for n in "ab"])
    seen = []
    r = run_smc(loglik, space, n_particles=2000, n_rej=5, zeta=0.9,
                rng=np.random.default_rng(2), callback=seen.append)
    assert np.all(np.isfinite(r.weights)) and not np.any(np.isnan(r.particles))
    assert np.all(r.particles[r.weights > 0, 0] < 0)
    assert np.all(np.isfinite(r.loglik[r.weights > 0]))
    t0 = stats.truncnorm(-1 / s, 0, scale=s)
    assert r.weights @ r.particles[:, 0] == pytest.approx(t0.mean(), abs=0.02)
    logz = np.log((stats.norm.cdf(0, 0, s) - stats.norm.cdf(-1, 0, s))
                  * (stats.norm.cdf(1, 0, s) - stats.norm.cdf(-1, 0, s)) / 4)
    assert r.log_evidence == pytest.approx(logz, abs=0.2)
    assert len(seen) == r.n_steps and seen[-1]["gamma"] == 1.0
    assert {"gamma", "ess", "acceptance", "scale", "resampled"} <= set(seen[0])


def test_loglik_minus_inf_everywhere_is_an_error():
    space = ParameterSpace([Parameter("a", "-", Uniform(0, 1), 0, 1)])
    with pytest.raises(ValueError, match="-inf"):
        run_smc(lambda X: np.full(len(X), -np.inf), space, n_particles=50, n_rej=1, zeta=0.9,
                rng=np.random.default_rng(0))


def test_next_gamma_hits_target_ess_and_caps_at_one():
    rng = np.random.default_rng(0)
    ll = rng.normal(size=1000) * 10
    logw = np.zeros(1000)
    g = next_gamma(ll, logw, 0.0, 0.9)
    w = np.exp(g * ll - np.max(g * ll))
    assert (w.sum() ** 2 / (w**2).sum()) == pytest.approx(900.0, rel=1e-8)
    assert next_gamma(np.full(10, -3.0), np.zeros(10), 0.2, 0.9) == 1.0  # flat: jump to 1


def test_systematic_resampling_counts():
    # Systematic resampling gives floor(N w_i) or ceil(N w_i) copies of particle i.
    rng = np.random.default_rng(0)
    W = rng.random(100)
    W /= W.sum()
    idx = systematic_resample(W, rng)
    counts = np.bincount(idx, minlength=100)
    assert np.all(counts >= np.floor(100 * W) - 1e-9) and np.all(counts <= np.ceil(100 * W) + 1e-9)


def test_history_and_scale_rule():
    space = ParameterSpace([Parameter("x", "-", Normal(2.0, 1.0), -8.0, 12.0)])
    loglik = lambda X: -0.5 * X[:, 0] ** 2
    r = run_smc(loglik, space, n_particles=300, n_rej=2, zeta=0.8, rng=np.random.default_rng(0))
    h = r.history
    # Minson et al. rule: scale_s = 2.38^2/d * (1/9 + 8/9 * acc_{s-1})^2, acc_0 = 1.
    acc_prev = np.concatenate([[1.0], h["acceptance"][:-1]])
    assert np.allclose(h["scale"], 2.38**2 * (1 / 9 + 8 / 9 * acc_prev) ** 2)
    assert np.all((h["acceptance"] >= 0) & (h["acceptance"] <= 1))
    assert r.log_evidence == pytest.approx(h["log_evidence_increment"].sum())
