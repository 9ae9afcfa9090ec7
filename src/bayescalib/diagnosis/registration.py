"""Joint re-fit of the base parameters and a rigid registration of the observations.

When the block test (:func:`~bayescalib.diagnosis.attribution.block_test`) finds a
significant rigid misplacement of the observed interfaces (translation, rotation,
scale), the base posterior has usually absorbed part of it: E and nu moved to bend the
model towards the misplaced data. The registration ``rho`` and the base parameters
``theta`` are then fitted jointly by Gauss-Newton on

    chi2(theta, rho) = sum_i r_i(theta, rho)^2 / v_i,

with ``r`` the normal offsets of the registered observations from the model interface
(the discrepancy of the paper's closest-point projection, Eq. (9)), re-linearized with
real solves at every iterate. The rotation trades off against E and nu, and undamped
Gauss-Newton overshoots (E 341 -> 667 -> 100 -> 203 -> 253 Pa for a truth of 400 on the
misregistered analytic case), so a step that raises chi2 at its own solve is halved back
towards the last accepted point, and only points confirmed by a solve are returned.

What the registered model predicts is then judged with draws that do not depend on how
the base posterior absorbed the misplacement: the Laplace approximation at the joint
fit, ``N(theta*, (J^T V^-1 J)^-1)`` (the Gauss-Newton information of the base
parameters with the observations registered by the fit's estimate), truncated to the
prior box.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from bayescalib.diagnosis.attribution import block_test

#: Solve-confirmed Gauss-Newton iterations of the joint fit (each costs 1 + p solves).
MAX_ITERATIONS = 8

Evaluation = tuple[np.ndarray, np.ndarray, np.ndarray]
"""What one linearization returns: residual r (n,), base Jacobian J (n, q), block B (n, k)."""


@dataclass
class JointFit:
    """Result of :func:`joint_fit`.

    Attributes
    ----------
    theta
        (p,) base parameters of the best solve-confirmed iterate.
    estimate
        The registration at that iterate, by mode.
    chi2
        ``sum r^2 / v`` there, at its own solve (``inf`` when no iterate solved).
    J
        (n, q) base Jacobian there (``None`` when no iterate solved), for
        :func:`laplace_draws`.
    iterations
        One record per iterate: ``chi2_at_point``, and either the accepted step's
        ``chi2`` / ``p_after`` / ``estimate`` / ``theta`` or ``rejected`` / ``failed``.
    """

    theta: np.ndarray
    estimate: dict[str, float]
    chi2: float = float("inf")
    J: np.ndarray | None = None
    iterations: list[dict[str, Any]] = field(default_factory=list)


def joint_fit(evaluate: Callable[[np.ndarray, Mapping[str, float]], Evaluation | str],
              theta0: np.ndarray, estimate0: Mapping[str, float], free: Sequence[int],
              h: np.ndarray, lo: np.ndarray, hi: np.ndarray, v: np.ndarray,
              modes: Sequence[str], names: Sequence[str],
              max_iterations: int = MAX_ITERATIONS) -> JointFit:
    """Damped Gauss-Newton fit of base parameters and registration, confirmed by solves.

    Parameters
    ----------
    evaluate
        ``evaluate(theta, estimate)`` solves at ``theta`` (and its finite-difference
        neighbours) and returns the residual of the observations registered by
        ``estimate``, the base Jacobian over the ``free`` parameters and the
        registration signatures; or a string saying why the solves failed.
    theta0
        (p,) starting base parameters (clipped to the box).
    estimate0
        Starting registration, by mode.
    free
        Indices of the parameters whose Jacobian columns ``evaluate`` returns.
    h
        (p,) finite-difference steps; a step smaller than 0.1 ``h`` in every free
        parameter ends the fit.
    lo, hi
        (p,) prior box.
    v
        (n,) noise variances, mm^2.
    modes, names
        Registration modes and parameter names (for the records).
    max_iterations
        Iterates solved at most.

    Returns
    -------
    JointFit
        The best iterate whose chi2 was measured at its own solve.
    """
    free = list(free)
    h = np.asarray(h, dtype=float)
    th = np.clip(np.asarray(theta0, dtype=float), lo, hi)
    est = {m: float(estimate0[m]) for m in modes}
    fit = JointFit(theta=th.copy(), estimate=dict(est))
    small = 0.1 * np.abs(h[free])
    for _ in range(max_iterations):
        got = evaluate(th, est)
        if isinstance(got, str):
            fit.iterations.append({"failed": got})
            break
        r, J, B = got
        chi2_here = float(np.sum(np.asarray(r, float) ** 2 / np.asarray(v, float)))
        if np.isfinite(fit.chi2) and chi2_here > fit.chi2:
            # worse than the last accepted point: halve the step back towards it
            fit.iterations.append({"chi2_at_point": chi2_here, "rejected": True,
                                   "theta": dict(zip(names, map(float, th), strict=True))})
            step = th - fit.theta
            th = fit.theta + 0.5 * step
            est = {m: fit.estimate[m] + 0.5 * (est[m] - fit.estimate[m]) for m in modes}
            if np.all(np.abs(0.5 * step[free]) <= small):
                break
            continue
        fit.theta, fit.estimate, fit.chi2, fit.J = th.copy(), dict(est), chi2_here, J
        bt = block_test(r, J, B, v, modes)
        est = {m: est[m] + bt["estimate"][m] for m in modes}
        dth = np.zeros(len(th))
        dth[free] = bt["base_step"]
        th = np.clip(th + dth, lo, hi)
        fit.iterations.append({"chi2_at_point": chi2_here, "chi2": bt["chi2_after"],
                               "p_after": bt["p_after"], "estimate": dict(est),
                               "theta": dict(zip(names, map(float, th), strict=True))})
        if np.all(np.abs((th - fit.theta)[free]) <= small):
            break
    return fit


def laplace_draws(J: np.ndarray, v: np.ndarray, theta: np.ndarray, lo: np.ndarray,
                  hi: np.ndarray, n: int, rng: np.random.Generator) -> np.ndarray:
    """Draws of the base parameters from the Laplace approximation at the joint fit.

    The observations are registered once, by the fit's estimate, so the draws are of the
    base parameters *given* that registration: ``N(theta*, (J^T V^-1 J)^+)``. (With the
    registration marginalized instead, the draws would move E and nu along their
    trade-off with the rotation while the observations stay where the estimate put them:
    they are not the registered model's posterior.) Draws outside the prior box
    are redrawn (the posterior truncated to it); after 64 rounds the remainder is
    clipped.

    Parameters
    ----------
    J
        (n_obs, q) base Jacobian at ``theta``, mm per unit of each parameter.
    v
        (n_obs,) noise variances, mm^2.
    theta
        (q,) the joint fit's base parameters.
    lo, hi
        (q,) prior box.
    n
        Number of draws.
    rng
        Seeded generator.

    Returns
    -------
    numpy.ndarray
        (n, q) draws.
    """
    w = 1.0 / np.sqrt(np.asarray(v, dtype=float))
    A = np.asarray(J, float) * w[:, None]
    q = A.shape[1]
    cov = np.linalg.pinv(A.T @ A, rcond=1e-12, hermitian=True)
    lam, U = np.linalg.eigh(0.5 * (cov + cov.T))
    L = U * np.sqrt(np.clip(lam, 0.0, None))
    theta = np.asarray(theta, dtype=float)
    out = np.empty((n, q))
    todo = np.arange(n)
    for _ in range(64):
        x = theta + rng.standard_normal((len(todo), q)) @ L.T
        inside = np.all((x >= lo) & (x <= hi), axis=1)
        out[todo[inside]] = x[inside]
        todo = todo[~inside]
        if not len(todo):
            break
    if len(todo):
        out[todo] = np.clip(theta + rng.standard_normal((len(todo), q)) @ L.T, lo, hi)
    return out
