"""What the rounds have not explored: basins of the solved log-likelihoods that the
posterior does not hold, and the posterior mass they could carry.

Why the stop rule needs it. The posterior check
(:func:`~bayescalib.inference.active.round_posterior_check`; terms: docs/glossary.md)
solves draws of the surrogate posterior and compares: it tests the posterior where its
draws go, and no draw goes to a mode the surrogate does not know. On a posterior with two
modes about 16 sd apart (``benchmarks/bench_modes.py``), a GP fitted to the bowl of one
mode predicts the other region low and confidently: its sd there is a few nats, so no
upper-confidence bound of the surrogate reaches the missing mode (measured: the
optimistic excess mass of the GP at the verdict was 1.2 % when a mode with 73 % of the
mass was missing, 1.8 % when both were found). The solves themselves know better. A
Gaussian-misfit log-likelihood is close to quadratic in the parameters around each
mode, so the design points that fall in another mode's basin rise towards it: the highest
of them is higher than its neighbours (a *local maximum of the data*), and a quadratic
through it and its neighbours points at that mode's peak, its height and its width.

The audit (:func:`audit`). For every local maximum of the solved log-likelihoods (a
finite solve at least as high as its ``2 d`` nearest finite neighbours, in box-scaled
coordinates u = (x - lo) / (hi - lo)):

1. fit L(u) ~ c + g.v + 1/2 v'Hv, v = u - u_i, by least squares through it and its
   nearest neighbours (a full Hessian for d <= 3, a diagonal one above: 1 + 2d
   coefficients, so that 7 parameters need 15 neighbours, not 36);
2. maximize the quadratic in the box within the trust radius (the distance to the
   farthest neighbour of the fit): the basin's estimated peak u*, L*; curvatures that are
   not negative are set to the trust radius's (a flat or rising direction is given the
   width of the fit's support);
3. its posterior mass if the quadratic is right, relative to the posterior's evidence Z:

       m = exp(L* + log p(x*) - log Z) (2 pi)^(d/2) |-H|^(-1/2) prod(hi - lo),

   (the Laplace approximation of the basin's integral of exp(L) p);
4. *held* when the posterior's particles carry at least a quarter of m inside the
   basin's ellipsoid (v - v*)'(-H)(v - v*) <= chi2_0.99(d) (or at least a quarter of
   the particles' mass when m exceeds 1); above 3 dimensions also when the local
   maximum itself lies in the posterior's region (below) and no higher than the
   posterior's own Gaussian says, by chi2_0.99(d) / 2: the posterior's own top, whose
   diagonal quadratic overshoots along a tilted ridge (on ``hetero7d``'s ridge E_i ~ q
   the top solves' quadratics rose to the likelihood's bound where few particles lie,
   "up to 100 % of the mass", round after round).

A second pass (``found_by`` 2 in the record) looks for basins whose solves all have a
higher neighbour in the mode that was found (the rounds put their solves there, nearer
to a Sobol point of another basin than that basin's other solves). It takes the solves
the posterior does not hold: those

* outside the particles' region: the nearest particles that carry 0.5 % of the weight
  lie farther away than 6 times the radius they need around the particles at the
  region's 1 % edge (a weighted k-nearest-neighbour density, per mode whatever the
  number of modes; the factor keeps a posterior's tail, such as the arms of a curved
  ridge, in its region: 3 was measured too small on ``ridge2d``);
* and not explained, by more than chi2_0.99(d) / 2 nats, by a held basin of the first
  pass (its fitted quadratic with its own curvature; a full quadratic above d = 3 where
  the solves allow) nor by the posterior's own Gaussian (the particles' mean and
  covariance: L = log Z + log N(x) - log p(x)): the held mode's slope is explained,
  another basin rising above it is not.

Among these solves alone, a solve at least as high as its ``2 d`` nearest is a basin,
fitted through its nearest solves of the same set by steps 1-4 with a full quadratic
(with d spare solves; above 3 dimensions wherever they hold one more solve than its
coefficients: a missing mode's region, where
the log-likelihood is that mode's own quadratic, may hold few: on ``bimodal4d`` 16 solves,
and a fit asking for d spare ones left the mode unseen; else a diagonal one). Above 3
dimensions the first pass's local maxima among these solves are fitted again so (their
first fit is diagonal and can put a rotated narrow mode's peak 10 nats low: bimodal4d
seed 11 said converged with 73 % of the mass missing); a basin of this pass
whose estimated peak lies in the particles' region counts as held (a slope of the
posterior's own mode).

A basin not held is *refuted* when a solve inside its ellipsoid (v - v*)'P(v - v*) <=
chi2_0.99(d) lies below the quadratic's value there, L* - 1/2 (v - v*)'P(v - v*), by more
than chi2_0.99(d) / 2 nats: the data contradict the peak the quadratic claims (a curved
ridge's arm, whose local quadratic rises towards the bound off the ridge; the probe sent
to that peak finds it low, and the quadratic refitted through the probe claims a peak a
little farther on). A refuted basin is not counted and not probed. A real mode's basin
is not refuted by solves on its own slopes (they follow its quadratic) but can be by a
solve that its estimated ellipsoid, too wide or misplaced, takes in; measured on
``bimodal2d`` (``docs/bench_modes.md``).

The unexplored mass is the sum of m over the basins not held (each capped at 1: a
quadratic can overshoot, and the audit says so: "up to"). The stop rule does not say
converged while it exceeds ``design.active.stop.unexplored_mass``; each batch then
carries a *probe* at each such basin's estimated peak (:func:`probe_points`), so the
next round's data either confirm the basin (the GP then learns the mode, the posterior
takes its mass) or lower its estimate.

What it guarantees, and what not. A mode is seen once one solve lies in its basin and
is higher than its ``2 d`` nearest neighbours among all the solves (first pass), or
among the solves the posterior does not hold (second pass): a basin all of whose solves
have a higher neighbour in the mode that was found is seen, provided one of them lies
outside that mode's particles' region, above the held quadratics and the posterior's
Gaussian by chi2_0.99(d) / 2, and is higher than its ``2 d`` nearest such solves. Not
seen: a mode whose basin holds no solve (narrower than the spacing of the design); one
whose solves each have a higher neighbour that the posterior does not hold either (a
third basin's, or a slope of the held mode that neither its quadratic nor its Gaussian
explains: a mode far from quadratic); one whose solves lie within 6 k-nearest-neighbour
radii of the particles' edge. The audit reports the design's fill distance (the largest
distance from a point of the box to its nearest solve, estimated on a Sobol sample, in
box units) with every verdict so that the user reads the scale below which the box is
not explored. Measured on the two-mode benchmark (``benchmarks/bench_modes.py``,
``docs/bench_modes.md``): with the first pass alone, converged with a mode missing in 1
of 20 design seeds (seed 19: the two solves in the missing mode's basin each had a
higher neighbour among the solves of the mode found), against 3 of 6 seeds without the
audit; with the second pass seed 19 converges with both modes (the seeds rerun and the
cost of the second pass's false basins on ``ridge2d`` and ``sloppy4d``: that file).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from typing import Any

import numpy as np
from scipy.spatial import cKDTree
from scipy.stats import chi2

__all__ = ["audit", "contradicted", "fill_distance", "probe_points"]

#: a basin is held when the posterior's particles carry this share of its estimated mass
HELD_SHARE = 0.25
#: the basin's ellipsoid for the particles' mass: this chi-square level
BASIN_LEVEL = 0.99
#: a probe closer than this share of the trust radius to a solve is moved aside (a peak
#: already solved: the surrogate, not the data, misses it)
PROBE_SEPARATION = 0.1
#: the posterior's region (pass 2): where the nearest particles carrying this share of
#: the weight lie within the radius they need at the REGION_LEVEL quantile of the
#: particles themselves
REGION_SHARE = 0.005
REGION_LEVEL = 0.99
#: ... times this factor (the region reaches past the particles' edge: a solve in the
#: posterior's tail is the posterior's slope, not another basin)
REGION_FACTOR = 6.0


def _posterior_region(Up: np.ndarray, W: np.ndarray) -> Callable[[np.ndarray], np.ndarray]:
    """The posterior's region as a test on points u (box units): u lies in it when the
    particles nearest to u carry ``REGION_SHARE`` of the weight within ``REGION_FACTOR``
    times the ``REGION_LEVEL`` quantile (weighted) of the same radius over the
    particles themselves: the particle density at u is at least 6^-d that of the 1 %
    of the posterior where it is thinnest. Per mode, whatever the number of modes (a
    weighted k-nearest-neighbour density, k = N * REGION_SHARE for equal weights).
    Returns ``ratio(Q)`` for points Q (m, d): u lies in the region where it is <= 1."""
    keep = W > 0
    Up, W = Up[keep], W[keep] / W[keep].sum()
    k = int(min(len(W), max(64, math.ceil(4 * REGION_SHARE * len(W)))))
    ptree = cKDTree(Up)

    def radius(Q: np.ndarray) -> np.ndarray:
        dist, idx = ptree.query(Q, k=k)
        dist, idx = dist.reshape(len(Q), k), idx.reshape(len(Q), k)
        cum = np.cumsum(W[idx], axis=1)
        reached = cum >= REGION_SHARE
        j = np.argmax(reached, axis=1)
        r = dist[np.arange(len(Q)), j]
        r[~reached.any(axis=1)] = np.inf
        return r

    rp = radius(Up)
    order = np.argsort(rp)
    cw = np.cumsum(W[order])
    r_max = float(rp[order][min(np.searchsorted(cw, REGION_LEVEL), len(cw) - 1)])
    r_max = max(r_max, 1e-12)  # coincident particles

    def ratio(Q: np.ndarray) -> np.ndarray:
        return radius(np.atleast_2d(Q)) / (REGION_FACTOR * r_max)

    return ratio


def _design_matrix(V: np.ndarray, full: bool) -> np.ndarray:
    n, d = V.shape
    cols = [np.ones(n)]
    cols += [V[:, k] for k in range(d)]
    if full:
        for a in range(d):
            for b in range(a, d):
                cols.append(V[:, a] * V[:, b] * (0.5 if a == b else 1.0))
    else:
        cols += [0.5 * V[:, k] ** 2 for k in range(d)]
    return np.column_stack(cols)


def _unpack(coef: np.ndarray, d: int, full: bool) -> tuple[float, np.ndarray, np.ndarray]:
    c, g = float(coef[0]), coef[1:1 + d]
    H = np.zeros((d, d))
    if full:
        k = 1 + d
        for a in range(d):
            for b in range(a, d):
                H[a, b] = H[b, a] = coef[k]
                k += 1
    else:
        H[np.diag_indices(d)] = coef[1 + d:]
    return c, g, H


def _concave(H: np.ndarray, radius: float) -> tuple[np.ndarray, np.ndarray]:
    """-H made positive definite: eigenvalues not above the trust radius's curvature
    1 / radius^2 are raised to it. Returns (P, eigenvalues of P)."""
    lam, Q = np.linalg.eigh(-0.5 * (H + H.T))
    floor = 1.0 / radius ** 2
    lam = np.maximum(lam, floor)
    return (Q * lam) @ Q.T, lam


def _peak(c: float, g: np.ndarray, P: np.ndarray, u0: np.ndarray,
          radius: float) -> tuple[np.ndarray, float]:
    """Maximum of c + g.v - 1/2 v'Pv over the ball |v| <= radius and the unit box
    (u0 + v in [0, 1]^d): Newton step, shortened to the ball, then projected on the box
    (a few projected-gradient steps refine it when the box cuts)."""
    v = np.linalg.solve(P, g)
    nv = float(np.linalg.norm(v))
    if nv > radius:
        v *= radius / nv
    u = np.clip(u0 + v, 0.0, 1.0)
    step = 1.0 / float(np.linalg.eigvalsh(P).max())
    for _ in range(50):  # projected gradient ascent on the concave model in the box
        vv = u - u0
        grad = g - P @ vv
        un = np.clip(u + step * grad, 0.0, 1.0)
        dv = un - u0
        nd = float(np.linalg.norm(dv))
        if nd > radius:
            un = np.clip(u0 + dv * radius / nd, 0.0, 1.0)
        if np.max(np.abs(un - u)) < 1e-10:
            break
        u = un
    vv = u - u0
    return u, float(c + g @ vv - 0.5 * vv @ P @ vv)


def contradicted(U: np.ndarray, L: np.ndarray, u_star: np.ndarray, L_star: float,
                 P: np.ndarray, level: float) -> bool:
    """Does a solve refute a basin's quadratic? True when a solve u_j (rows of ``U``,
    box units; log-likelihoods ``L``) inside the basin's ellipsoid q_j = (u_j - u*)'P
    (u_j - u*) <= ``level`` lies below the quadratic's value there, L* - q_j / 2, by more
    than ``level`` / 2 nats (``level``: chi2_0.99(d); the module docstring)."""
    D = np.atleast_2d(U) - u_star
    q = np.einsum("ij,jk,ik->i", D, P, D)
    return bool(np.any((q <= level) & (np.asarray(L) < L_star - 0.5 * q - 0.5 * level)))


def audit(X: np.ndarray, L: np.ndarray, particles: np.ndarray, weights: np.ndarray,
          log_evidence: float, space, bound: float | None = None) -> dict[str, Any]:
    """The basins of the solved log-likelihoods and the posterior mass the posterior
    does not hold (the module docstring).

    Parameters
    ----------
    X, L
        Solved design points (n, d) in user units and their log-likelihoods (n,), -inf
        where a solve failed (ignored).
    particles, weights
        The posterior (SMC on the surrogate), (N, d) and (N,).
    log_evidence
        log Z of that posterior (the SMC estimate: log of the integral of exp(L) p).
    space
        :class:`~bayescalib.inference.parameters.ParameterSpace`: bounds and log-prior.
    bound
        The log-likelihood's known upper bound (a perfect fit), or None: no estimated
        peak exceeds it (a quadratic through few, distant solves can overshoot by
        thousands of nats).

    Returns
    -------
    dict
        ``basins``: one dict per local maximum of the data, highest first: ``point``
        (the solve, user units), ``loglik``, ``peak`` (estimated, user units),
        ``peak_loglik``, ``mass`` (estimated posterior mass, capped at 1), ``held``
        (mass of the particles in the basin), ``is_held``, ``refuted`` (a solve inside
        the basin contradicts its quadratic), ``found_by`` (1: a local
        maximum of all the solves; 2: of the solves the posterior does not hold);
        ``unexplored_mass`` (sum of ``mass`` over the basins neither held nor refuted);
        ``fill_distance`` (box units); ``n_outside`` (the solves of the second pass).
    """
    X = np.atleast_2d(np.asarray(X, float))
    L = np.asarray(L, float)
    bounds = np.asarray(space.bounds, float)
    lo, width = bounds[:, 0], bounds[:, 1] - bounds[:, 0]
    d = X.shape[1]
    ok = np.isfinite(L)
    U, Lf = (X[ok] - lo) / width, L[ok]
    out: dict[str, Any] = {"basins": [], "unexplored_mass": 0.0,
                           "fill_distance": fill_distance(X, bounds), "n_outside": 0}
    full = d <= 3
    n_coef = 1 + d + (d * (d + 1) // 2 if full else d)
    n_fit = n_coef + d
    n_full = 1 + d + d * (d + 1) // 2 + d  # a full quadratic's fit (the second pass)
    n_nb = 2 * d
    if len(Lf) < max(n_fit, n_nb + 1):
        return out
    tree = cKDTree(U)
    _, nb = tree.query(U, k=n_nb + 1)
    local_max = np.array([Lf[i] >= Lf[nb[i, 1:]].max() for i in range(len(Lf))])
    W = np.asarray(weights, float)
    W = W / W.sum()
    Up = (np.asarray(particles, float) - lo) / width
    level = float(chi2.ppf(BASIN_LEVEL, d))
    log_box = float(np.log(width).sum())
    unexplored = 0.0
    region_u = _posterior_region(Up, W)
    held_models: list[tuple[np.ndarray, float, np.ndarray, np.ndarray]] = []
    tol = 0.5 * level
    # the posterior's own Gaussian (the particles' mean and covariance) at the solves:
    # L(x) = log Z + log N(x; mean, cov) - log p(x) where the posterior is that Gaussian
    mu = W @ Up
    C = (Up - mu).T @ ((Up - mu) * W[:, None]) + 1e-12 * np.eye(d)
    sign, logdet = np.linalg.slogdet(C)
    gauss = None
    if sign > 0:
        D = U - mu
        log_n = -0.5 * np.einsum("ij,jk,ik->i", D, np.linalg.inv(C), D) \
            - 0.5 * (d * math.log(2 * math.pi) + logdet) - log_box
        gauss = float(log_evidence) + log_n - space.logprior(X[ok])

    def basin(i: int, idx: np.ndarray, dist: np.ndarray, found_by: int,
              fit_full: bool | None = None) -> None:
        nonlocal unexplored
        V = U[idx] - U[i]
        fit_full = (full or found_by == 2) if fit_full is None else fit_full
        A = _design_matrix(V, fit_full)
        coef, *_ = np.linalg.lstsq(A, Lf[idx], rcond=None)
        c, g, H = _unpack(coef, d, fit_full)
        resid = Lf[idx] - A @ coef
        spread = float(np.sum((Lf[idx] - Lf[idx].mean()) ** 2))
        fit_r2 = 1.0 - float(resid @ resid) / spread if spread > 0 else 1.0
        radius = float(max(dist[-1], 1e-6))
        P, lam = _concave(H, radius)
        u_star, L_star = _peak(c, g, P, U[i], radius)
        if bound is not None:
            L_star = min(L_star, float(bound))
        L_star = max(L_star, float(Lf[i]))  # the peak is at least the solve
        x_star = lo + u_star * width
        log_vol = 0.5 * d * math.log(2 * math.pi) - 0.5 * float(np.log(lam).sum()) + log_box
        log_m = L_star + float(space.logprior(x_star[None, :])[0]) + log_vol \
            - float(log_evidence)
        mass = float(math.exp(min(log_m, 0.0)))
        D = Up - u_star
        inside = np.einsum("ij,jk,ik->i", D, P, D) <= level
        held = float(W[inside].sum())
        is_held = held >= HELD_SHARE * mass
        refuted = contradicted(U, Lf, u_star, L_star, P, level)
        if found_by == 2 and not is_held:
            # a slope of the posterior's own region: its peak lies in that region
            is_held = bool(region_u(u_star[None, :])[0] <= 1.0)
        elif not is_held and not fit_full and gauss is not None \
                and Lf[i] <= gauss[i] + tol and region_u(U[i][None, :])[0] <= 1.0:
            # the posterior's own top: the local maximum of the data lies in the
            # posterior's region, as high as its Gaussian says; its diagonal quadratic
            # (above 3 dimensions) overshoots along a tilted ridge. Where the quadratic
            # is full (d <= 3) it is trusted: a lobe beside the posterior's mode, whose
            # top lies in the mode's region, keeps its own test (lobe2d: 4 of 20 seeds
            # converged earlier with the lobe's mass 1-1.5 % short, Hellinger 0.05-0.056)
            is_held = True
        if is_held:
            # its model for pass 2: a full quadratic where the solves allow (above
            # d = 3 the basin's own fit is diagonal, and a rotated basin's slope would
            # not be explained), with the fit's own curvature, floored (where not
            # negative) at the box's width only, not at the trust radius's
            cm, gm, Hm = c, g, H
            if not full and len(Lf) >= n_full:
                _, idf = tree.query(U[i], k=n_full)
                Af = _design_matrix(U[idf] - U[i], True)
                cf, *_ = np.linalg.lstsq(Af, Lf[idf], rcond=None)
                cm, gm, Hm = _unpack(cf, d, True)
            lam_h, Q_h = np.linalg.eigh(-0.5 * (Hm + Hm.T))
            held_models.append((U[i], cm, gm, (Q_h * np.maximum(lam_h, 1.0)) @ Q_h.T))
        elif not refuted:
            unexplored += mass
        out["basins"].append({
            "point": X[ok][i].tolist(), "loglik": float(Lf[i]), "peak": x_star.tolist(),
            "peak_loglik": float(L_star), "mass": mass, "log_mass": float(log_m),
            "held": held, "is_held": bool(is_held), "refuted": refuted and not is_held,
            "trust_radius": radius,
            "found_by": found_by, "fit_r2": fit_r2,
            "region_ratio": float(region_u(U[i][None, :])[0]),
        })

    # pass 1: the local maxima of all the solves
    for i in np.flatnonzero(local_max):
        dist, idx = tree.query(U[i], k=n_fit)
        basin(int(i), idx, dist, 1)
    # pass 2: the local maxima among the solves the posterior does not hold (outside the
    # particles' region, explained neither by the posterior's Gaussian nor by the
    # quadratic of a held basin), fitted by full quadratics through such solves only
    region_ratio = region_u(U)
    outside = region_ratio > 1.0
    if gauss is not None:  # the posterior's own Gaussian explains too
        outside &= Lf > gauss + tol
    for u_i, c, g, P in held_models:
        D = U - u_i
        q = c + D @ g - 0.5 * np.einsum("ij,jk,ik->i", D, P, D)
        outside &= Lf > q + tol
    sub = np.flatnonzero(outside)
    # a full quadratic where the solves allow (with d spare solves; above 3 dimensions
    # at least one spare), else (above 3 dimensions) a diagonal one: a missing mode's region may hold
    # fewer solves than n_full (bimodal4d: 16 against 19, and the mode was missed);
    # there the log-likelihood is that mode's quadratic, which a full fit recovers
    n_full_min = n_full if full else n_full - d + 1  # d <= 3: as measured over 80 runs
    k_sub = min(len(sub), n_full) if len(sub) >= n_full_min else n_fit
    if len(sub) >= max(k_sub, n_nb + 1):
        sub_tree = cKDTree(U[sub])
        _, nb2 = sub_tree.query(U[sub], k=n_nb + 1)
        for j, i in enumerate(sub):
            # a local maximum of all the solves was fitted by the first pass; above 3
            # dimensions diagonally, which underestimates a rotated narrow mode's peak
            # (bimodal4d seed 11: its centre found, its height 10 nats low, its mass
            # 2e-4, never probed, converged with 73 % missing): fitted again here
            if (not local_max[i] or not full) and Lf[i] >= Lf[sub[nb2[j, 1:]]].max():
                dist, idx = sub_tree.query(U[i], k=k_sub)
                basin(int(i), sub[idx], dist, 2, fit_full=k_sub >= n_full_min)
    out["n_outside"] = int(outside.sum())
    out["basins"].sort(key=lambda b: -b["peak_loglik"])
    out["unexplored_mass"] = float(min(unexplored, 1.0))
    return out


def probe_points(result: Mapping[str, Any], X: np.ndarray, bounds: np.ndarray, n: int,
                 tol: float, rng: np.random.Generator) -> np.ndarray:
    """Up to ``n`` points that probe the basins the posterior does not hold, (k, d) in
    user units: each such basin's estimated peak, largest estimated mass first (only
    basins of estimated mass above ``tol``). A peak that a solve already sits on (closer
    than ``PROBE_SEPARATION`` trust radii) is probed a random half trust radius away."""
    bounds = np.asarray(bounds, float)
    lo, width = bounds[:, 0], bounds[:, 1] - bounds[:, 0]
    U = (np.atleast_2d(np.asarray(X, float)) - lo) / width
    todo = sorted((b for b in result["basins"]
                   if not b["is_held"] and not b.get("refuted") and b["mass"] > tol),
                  key=lambda b: -b["mass"])
    picks: list[np.ndarray] = []
    for b in todo[:max(int(n), 0)]:
        u = (np.asarray(b["peak"], float) - lo) / width
        r = float(b["trust_radius"])
        taken = np.vstack([U] + [p[None, :] for p in picks]) if picks else U
        if np.min(np.linalg.norm(taken - u, axis=1)) < PROBE_SEPARATION * r:
            step = rng.standard_normal(len(u))
            u = np.clip(u + 0.5 * r * step / np.linalg.norm(step), 0.0, 1.0)
        picks.append(u)
    if not picks:
        return np.empty((0, bounds.shape[0]))
    return lo + np.vstack(picks) * width


def fill_distance(X: np.ndarray, bounds: np.ndarray, n_probe: int = 4096) -> float:
    """The largest distance from a point of the box to its nearest design point, in box
    units (u in [0, 1]^d), estimated on a fixed scrambled Sobol sample of ``n_probe``
    points (seeded: same design, same value)."""
    from scipy.stats import qmc

    bounds = np.asarray(bounds, float)
    lo, width = bounds[:, 0], bounds[:, 1] - bounds[:, 0]
    U = (np.atleast_2d(np.asarray(X, float)) - lo) / width
    S = qmc.Sobol(U.shape[1], scramble=True, seed=0xF111).random(n_probe)
    dist, _ = cKDTree(U).query(S)
    return float(dist.max())
