"""The SMC's Metropolis-Hastings sweeps on a GP surrogate (bayescalib.inference.smc).

The sweeps evaluate the log-likelihood at the proposals inside the prior support only
and keep the current particles' tempered target instead of recomputing it. These
tests state what that must not change:

* every sweep is, bit for bit, the textbook random-walk MH sweep written out below
  (:func:`reference_sweeps`: the acceptance test for all particles, the target
  recomputed every sweep), including particles and proposals at -inf;
* the log-likelihood an SMC run reports at its particles is the GP mean there
  (to round-off: the same rows computed in other chunks round differently, rtol
  1e-12), and the surrogate was never asked about a point outside the prior box;
* the same seed gives bitwise the same run, with one thread or two; another seed
  another run.

The surrogates are built from fixed hyperparameters (no fitting), in 2-D (the
python64 study's shape: 64 points, a log-misfit GP under a bound) and 7-D (ARD).
"""

import numpy as np
import pytest

from bayescalib.inference.design import sobol_design
from bayescalib.inference.gp import GPSurrogate
from bayescalib.inference.parameters import Parameter, ParameterSpace, Uniform
from bayescalib.inference.smc import _proposal_factor, _tempered, mh_sweeps, run_smc


def reference_sweeps(X, ll, lp, gamma, chol, n_sweeps, loglik, logprior, rng, W):
    """Random-walk MH targeting exp(gamma log L) p, written out plainly: all N
    acceptance tests every sweep (a proposal outside the prior has log alpha = -inf;
    from a -inf state any finite proposal is accepted)."""
    X, ll, lp = X.copy(), ll.copy(), lp.copy()
    N, d = X.shape
    acc_sum, n_evals = 0.0, 0
    for _ in range(n_sweeps):
        Xp = X + rng.standard_normal((N, d)) @ chol.T
        log_u = np.log(rng.random(N))
        lpp = logprior(Xp)
        inside = np.isfinite(lpp)
        llp = np.full(N, -np.inf)
        if np.any(inside):
            out = np.asarray(loglik(Xp[inside]), float)
            llp[inside] = np.where(np.isnan(out) | (out == np.inf), -np.inf, out)
            n_evals += int(inside.sum())
        t_new = _tempered(llp, gamma) + lpp
        t_old = _tempered(ll, gamma) + lp
        new_ok, old_ok = np.isfinite(t_new), np.isfinite(t_old)
        diff = np.where(new_ok & old_ok, t_new - np.where(old_ok, t_old, 0.0), 0.0)
        log_alpha = np.where(~new_ok, -np.inf, np.where(~old_ok, np.inf, diff))
        accept = log_u < log_alpha
        X[accept], ll[accept], lp[accept] = Xp[accept], llp[accept], lpp[accept]
        acc_sum += float(W @ accept)
    return X, ll, lp, acc_sum / max(n_sweeps, 1), n_evals


def _space(box):
    return ParameterSpace([Parameter(f"p{j}", "-", Uniform(lo, hi), lo, hi)
                           for j, (lo, hi) in enumerate(box)])


def _gp(box, n, lengthscale, seed=0):
    """A log-misfit GP under the bound 0 of a Gaussian bump with a -inf corner."""
    box = np.asarray(box, float)
    X = sobol_design(box, n, seed)
    U = (X - box[:, 0]) / (box[:, 1] - box[:, 0])
    misfit = 40.0 * np.sum((U - 0.4) ** 2, axis=1)
    return GPSurrogate(X_train=X, y_train=np.log1p(misfit), shift=box[:, 0],
                       scale=box[:, 1] - box[:, 0], mean_const=float(np.log1p(misfit).mean()),
                       nugget=1e-6, variance=2.0, lengthscale=np.asarray(lengthscale, float),
                       ard=len(lengthscale) > 1, bound=0.0, warp=True, device="cpu")


BOX_2D = [[100.0, 800.0], [-0.8, 0.45]]
BOX_7D = [[100, 800], [-0.8, 0.5], [100, 800], [-0.8, 0.5], [300, 1500], [-0.8, 0.5], [0, 110]]


def _cases():
    return {
        "2d": (_space(BOX_2D), _gp(BOX_2D, 64, [0.47])),
        "7d": (_space(BOX_7D), _gp(BOX_7D, 128, [0.6, 0.9, 0.7, 1.1, 0.8, 1.0, 1.3])),
    }


@pytest.mark.parametrize("case", ["2d", "7d"])
@pytest.mark.parametrize("gamma", [0.03, 1.0])
def test_sweeps_are_bitwise_the_plain_mh_sweeps(case, gamma):
    space, gp = _cases()[case]
    d = space.dim

    def loglik(X):  # the GP mean, with a -inf region (failed solves) in one corner
        out = gp.predict(X)
        U = (X - space.bounds[:, 0]) / (space.bounds[:, 1] - space.bounds[:, 0])
        return np.where(U[:, 0] + U[:, 1] > 1.6, -np.inf, out)

    rng0 = np.random.default_rng(5)
    N = 700
    X = space.sample_prior(N, rng0)
    lp = space.logprior(X)
    ll = loglik(X)
    ll[:20] = -np.inf  # particles that start where the likelihood has no support
    assert np.isinf(ll).sum() > 20
    W = rng0.random(N)
    W /= W.sum()
    # a wide proposal, so that many proposals leave the box
    width = space.bounds[:, 1] - space.bounds[:, 0]
    chol = _proposal_factor(np.diag((0.3 * width) ** 2), 1.0, width)
    fast = mh_sweeps(X, ll, lp, gamma, chol, 6, loglik, space.logprior,
                     np.random.default_rng(11), W)
    ref = reference_sweeps(X, ll, lp, gamma, chol, 6, loglik, space.logprior,
                           np.random.default_rng(11), W)
    for a, b in zip(fast[:3], ref[:3], strict=True):
        assert np.array_equal(a, b)
    assert fast[3] == ref[3] and fast[4] == ref[4]
    assert 0.0 < fast[3] < 1.0
    assert fast[4] < 6 * N  # some proposals were outside the box, not evaluated
    assert d == X.shape[1]


@pytest.mark.parametrize("case", ["2d", "7d"])
def test_loglik_at_the_particles_is_the_gp_mean_and_only_inside_the_box(case):
    space, gp = _cases()[case]
    asked = []

    def loglik(X):
        asked.append(X.copy())
        return gp.predict(X)

    r = run_smc(loglik, space, n_particles=1000, n_rej=3, zeta=0.9,
                rng=np.random.default_rng(0))
    # the reported log-likelihood is the surrogate's mean at the final particles
    # (recomputed here in other chunks: equal to round-off)
    np.testing.assert_allclose(r.loglik, gp.predict(r.particles), rtol=1e-12, atol=1e-12)
    np.testing.assert_array_equal(r.logprior, space.logprior(r.particles))
    pts = np.concatenate(asked)
    assert pts.shape[0] == r.n_loglik_evals
    assert np.all(np.isfinite(space.logprior(pts)))


@pytest.mark.parametrize("case", ["2d", "7d"])
def test_same_seed_same_run_with_one_or_two_threads(case):
    space, gp = _cases()[case]
    kw = {"n_particles": 1500, "n_rej": 3, "zeta": 0.9}
    gp.threads = 1
    r1 = run_smc(gp.predict, space, rng=np.random.default_rng(7), **kw)
    gp.threads = 2
    r2 = run_smc(gp.predict, space, rng=np.random.default_rng(7), **kw)
    r3 = run_smc(gp.predict, space, rng=np.random.default_rng(8), **kw)
    for a, b in ((r1.particles, r2.particles), (r1.weights, r2.weights),
                 (r1.loglik, r2.loglik)):
        assert np.array_equal(a, b)
    assert r1.log_evidence == r2.log_evidence and r1.n_loglik_evals == r2.n_loglik_evals
    assert not np.array_equal(r1.particles, r3.particles)
