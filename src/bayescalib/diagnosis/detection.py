"""Detection limits of the attribution: how large a hidden effect must be to be named.

The full diagnosis (:func:`bayescalib.diagnosis.stage.run_diagnosis`) calibrates the
base model, checks it and ranks the candidate physics by the score test of
:func:`~bayescalib.diagnosis.attribution.attribute`. Repeating it for many noise seeds and
magnitudes of a hidden effect is far too costly with a real forward model, so the
detection limits are measured on a *linearized* stand-in that keeps the data, the
residual and the ranking code of the diagnosis and replaces only the calibration:

1. Real forward solves at the truth ``theta_0`` give the base model's interfaces
   ``C_0`` (one per snapshot), its finite-difference Jacobian ``J`` (n x p, the steps
   the diagnosis uses) and each candidate's signature ``g_c`` (its step), all as normal
   offsets along the observed nodes (:func:`bayescalib.diagnosis.residuals.offsets`,
   the diagnosis's own function); see :func:`linearize`.
2. A real solve with the hidden effect at magnitude ``phi`` gives the noise-free
   observed nodes (the hidden truth's interface nodes, as synthetic observations are
   made).
3. For each noise seed the nodes get Gaussian coordinate noise of sd ``sigma`` (the
   generator and draw order of the synthetic observations, so seed ``s`` gives the
   same noisy data as ``observations.seed: s``); the residual ``y`` is their signed
   distance to ``C_0``. The base parameters are fitted by one Gauss-Newton step on the
   linearized base model, ``dtheta = (W J)^+ W y`` with ``W = diag(1/sigma)`` (what E,
   nu, ... can absorb is absorbed, as by the calibrated posterior mean), leaving
   ``r = y - J dtheta``; the attribution is then run on ``(r, J, g, v)`` with
   ``v_j = sigma^2 + sigma_L^2 [J (J^T J)^+ J^T]_jj``: the noise plus the spread of the
   linearized posterior's prediction with the likelihood's sd ``sigma_L`` (the
   diagnosis's ``v = var_k o_kj + sigma^2`` over posterior draws).
4. A trial *names* the hidden candidate when it is ranked first (top-1); it is also
   recorded whether its score test is significant at the diagnosis's level
   (``alpha / m``, Bonferroni over the ``m`` candidates), whether the greedy selection
   keeps it, and whether the re-fit test (:func:`~bayescalib.diagnosis.attribution.refit_test`)
   rejects the base model at level ``alpha`` (a mismatch beyond what E, nu absorb).

The detection limit (:func:`detection_limit`) is the smallest magnitude whose top-1
rate reaches a level (80 %), interpolated in ``log phi`` between the grid points that
bracket the first crossing.

What this does *not* include, by construction: the surrogate and the SMC posterior of
the real calibration (its mean is replaced by the linearized least-squares fit, so a
calibration that misses the best fit is not modelled), the linearization point (the
diagnosis linearizes at the biased posterior mean, this at the truth), the Monte-Carlo
error of ``v`` from a few posterior draws, and the predictive check that decides
whether the diagnosis attributes at all. Because the score test projects ``J`` out, the
Gauss-Newton step does not change the ranking of a linear model; it matters for the
re-fit test and for what the residual shows. The nonlinearity of the hidden effect in
``phi`` *is* included (real solves at every magnitude), as is the nonlinearity of the
geometry (the residual of the noisy nodes is a real closest-point distance).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from bayescalib.diagnosis.attribution import attribute, refit_test
from bayescalib.diagnosis.residuals import offsets

__all__ = ["detection_limit", "detection_range", "detection_trials", "linear_detectable_magnitude", "linearize",
           "noisy_nodes", "top1_rates"]


def linearize(nodes: Sequence[np.ndarray], base: Sequence[Any],
              fd: Sequence[Sequence[Any]], fd_steps: Sequence[float],
              candidates: Mapping[str, Sequence[Any]],
              candidate_steps: Mapping[str, float]) -> tuple[np.ndarray, np.ndarray, dict]:
    """Residual, base Jacobian and candidate signatures along the observed nodes.

    The same construction as the diagnosis's attribution step (offsets from the base
    prediction ``C_0``, forward differences), at the nodes ``nodes``.

    Parameters
    ----------
    nodes
        Per snapshot, (n_s, 2) observed nodes, mm.
    base
        Per snapshot, the base model's :class:`~bayescalib.geometry.interface.Interface`
        ``C_0`` (the reference of the offsets).
    fd
        Per base parameter, the interfaces (per snapshot) solved at its step.
    fd_steps
        (p,) the steps, in parameter units.
    candidates
        ``name -> interfaces (per snapshot)`` solved with the candidate at its step.
    candidate_steps
        ``name -> step`` of ``phi``, in the candidate's unit.

    Returns
    -------
    y : (n,)
        Signed distance of the nodes to ``C_0``, mm (+ into the fluid), n = sum n_s.
    J : (n, p)
        mm per parameter unit.
    signatures : dict
        ``name -> (n,)``, mm per unit ``phi``.
    """
    from bayescalib.diagnosis.attribution import jacobian_from_offsets, signature_from_offsets

    names = list(candidates)
    others = [*fd, *(candidates[n] for n in names)]
    ys, os_ = [], []
    for s, pts in enumerate(nodes):
        y, o = offsets(np.asarray(pts, dtype=float), base[s], [c[s] for c in others])
        ys.append(y)
        os_.append(o)
    y = np.concatenate(ys)
    O = np.concatenate(os_, axis=1) if os_ else np.zeros((len(others), 0))
    p = len(fd)
    J = jacobian_from_offsets(list(O[:p]), np.zeros(len(y)), list(fd_steps))
    sigs = {n: signature_from_offsets(O[p + i], 0.0, float(candidate_steps[n]))
            for i, n in enumerate(names)}
    return y, J, sigs


def noisy_nodes(nodes: Sequence[np.ndarray], sigma: float, seed: int) -> list[np.ndarray]:
    """The observed nodes with Gaussian coordinate noise, as the synthetic observations
    of ``observations.seed: seed`` (:func:`bayescalib.stages.observe.observe`: one generator,
    snapshots in order, ``points + sigma N(0, I)``).

    Parameters
    ----------
    nodes
        Per snapshot, (n_s, 2) noise-free nodes, mm.
    sigma
        Noise sd per coordinate, mm.
    seed
        Seed of the generator.

    Returns
    -------
    list of (n_s, 2) arrays, mm.
    """
    rng = np.random.default_rng(int(seed))
    return [np.asarray(p, dtype=float) + sigma * rng.standard_normal(np.shape(p))
            for p in nodes]


def _prediction_variance(J: np.ndarray, sigma_l: float) -> np.ndarray:
    """Diagonal of ``sigma_l^2 J (J^T J)^+ J^T``: the spread of the prediction under the
    linearized posterior of a likelihood with sd ``sigma_l`` (flat prior), (n,) mm^2."""
    if J.shape[1] == 0 or sigma_l == 0:
        return np.zeros(J.shape[0])
    G = np.linalg.pinv(J.T @ J)
    return sigma_l**2 * np.einsum("ij,jk,ik->i", J, G, J)


def detection_trials(
    nodes: Sequence[np.ndarray],
    base: Sequence[Any],
    J: np.ndarray,
    signatures: Mapping[str, np.ndarray],
    hidden: str,
    *,
    sigma: float,
    seeds: Sequence[int],
    sigma_likelihood: float | None = None,
    alpha: float = 0.05,
    r2_min: float = 0.5,
    max_effects: int = 2,
    ranges: Mapping[str, tuple[float, float]] | None = None,
) -> dict[str, np.ndarray]:
    """Noise trials of the linearized diagnosis for one hidden truth (module docstring).

    Parameters
    ----------
    nodes
        Per snapshot, (n_s, 2) noise-free observed nodes of the hidden truth, mm.
    base
        Per snapshot, the base model's interface at the truth (reference ``C_0``).
    J
        (n, p) base Jacobian at the truth along these nodes (:func:`linearize`), mm per unit.
    signatures
        ``name -> (n,)`` candidate signatures, mm per unit ``phi``.
    hidden
        Name of the hidden candidate (the one that should be ranked first).
    sigma
        Observation noise sd per coordinate, mm.
    seeds
        Noise seeds, one trial each (:func:`noisy_nodes`).
    sigma_likelihood
        Likelihood sd of the calibration, mm (None: ``sigma``); sets the posterior
        spread in ``v``.
    alpha, r2_min, max_effects, ranges
        As in :func:`~bayescalib.diagnosis.attribution.attribute` (the diagnosis's
        ``diagnose`` settings and the candidates' prior ranges).

    Returns
    -------
    dict of (n_seeds,) arrays
        ``top1`` (bool: the hidden candidate is ranked first), ``significant`` (its
        p-value is below ``alpha / m``), ``selected`` (the greedy selection keeps it),
        ``mismatch`` (the re-fit test rejects the base model at ``alpha``), ``top``
        (name of the first-ranked candidate), ``phi_hat`` (the hidden candidate's
        one-step estimate, its unit) and ``statistic`` (its score statistic).
    """
    J = np.asarray(J, dtype=float)
    n = J.shape[0]
    if hidden not in signatures:
        raise ValueError(f"hidden candidate {hidden!r} has no signature")
    sl = float(sigma if sigma_likelihood is None else sigma_likelihood)
    v = sigma**2 + _prediction_variance(J, sl)
    w = 1.0 / sigma
    out: dict[str, list] = {k: [] for k in ("top1", "significant", "selected", "mismatch",
                                            "top", "phi_hat", "statistic")}
    for seed in seeds:
        noisy = noisy_nodes(nodes, sigma, seed)
        y = np.concatenate([offsets(p, base[s], [])[0] for s, p in enumerate(noisy)])
        if len(y) != n:
            raise ValueError(f"{len(y)} observed nodes but J has {n} rows")
        # Gauss-Newton fit of the base parameters on the linearized base model
        step = (np.linalg.lstsq(J * w, y * w, rcond=1e-10)[0] if J.shape[1]
                else np.zeros(0))
        r = y - J @ step
        attr = attribute(r, J, signatures, v, alpha=alpha, r2_min=r2_min,
                         max_effects=max_effects, ranges=ranges)
        row = next(t for t in attr["ranking"] if t["candidate"] == hidden)
        out["top"].append(attr["ranking"][0]["candidate"])
        out["top1"].append(attr["ranking"][0]["candidate"] == hidden)
        out["significant"].append(row["p_value"] < attr["threshold"])
        out["selected"].append(hidden in attr["selected"])
        out["mismatch"].append(refit_test(y, J, np.full(n, sigma**2))["p_value"] < alpha)
        out["phi_hat"].append(row["phi_hat"])
        out["statistic"].append(row["score_statistic"])
    return {k: np.asarray(val) for k, val in out.items()}


def top1_rates(trials: Sequence[Mapping[str, np.ndarray]], key: str = "top1") -> np.ndarray:
    """Fraction of trials with ``key`` true, per magnitude: (n_magnitudes,)."""
    return np.array([float(np.mean(t[key])) for t in trials])


def detection_limit(magnitudes: Sequence[float], rates: Sequence[float],
                    level: float = 0.8) -> tuple[float, str]:
    """Smallest magnitude whose rate reaches ``level``, interpolated in log magnitude.

    Parameters
    ----------
    magnitudes
        (k,) increasing positive magnitudes (NaN rates, e.g. failed solves, are skipped).
    rates
        (k,) top-1 rates in [0, 1].
    level
        Required rate.

    Returns
    -------
    limit : float
        The magnitude where the rate first reaches ``level`` (log-linear between the
        bracketing grid points); the smallest tested magnitude when already reached
        there; the largest tested one when never reached.
    kind : str
        ``"interpolated"``, ``"<= min tested"`` or ``"> max tested"``.
    """
    m = np.asarray(magnitudes, dtype=float)
    r = np.asarray(rates, dtype=float)
    ok = np.isfinite(r)
    m, r = m[ok], r[ok]
    if m.size == 0:
        raise ValueError("detection_limit: no finite rate")
    if np.any(m <= 0) or np.any(np.diff(m) <= 0):
        raise ValueError("detection_limit: magnitudes must be positive and increasing")
    hit = np.flatnonzero(r >= level)
    if hit.size == 0:
        return float(m[-1]), "> max tested"
    i = int(hit[0])
    if i == 0:
        return float(m[0]), "<= min tested"
    t = (level - r[i - 1]) / (r[i] - r[i - 1])
    return float(np.exp(np.log(m[i - 1]) + t * (np.log(m[i]) - np.log(m[i - 1])))), "interpolated"


def detection_range(magnitudes: Sequence[float], rates: Sequence[float],
                    level: float = 0.8) -> dict[str, Any]:
    """The detection limit and what happens above it.

    A rate need not stay above ``level`` once reached: at large magnitudes a nonlinear
    effect may look more like another candidate than like its own signature (taken at
    the candidate's step), which is then ranked first.

    Parameters
    ----------
    magnitudes, rates, level
        As in :func:`detection_limit`.

    Returns
    -------
    dict
        ``limit`` and ``kind`` (:func:`detection_limit`); ``lost_above``: the magnitude
        above the limit where the rate falls below ``level`` again (log-linear between
        the bracketing grid points; None when it does not); ``max_rate`` and ``at``: the
        largest rate and its magnitude.
    """
    m = np.asarray(magnitudes, dtype=float)
    r = np.asarray(rates, dtype=float)
    limit, kind = detection_limit(m, r, level)
    ok = np.isfinite(r)
    m, r = m[ok], r[ok]
    k = int(np.argmax(r))
    out = {"limit": limit, "kind": kind, "lost_above": None, "max_rate": float(r[k]),
           "at": float(m[k])}
    if kind == "> max tested":
        return out
    i = int(np.flatnonzero(r >= level)[0])
    below = np.flatnonzero(r[i:] < level)
    if below.size:
        j = i + int(below[0])
        t = (r[j - 1] - level) / (r[j - 1] - r[j])
        out["lost_above"] = float(np.exp(np.log(m[j - 1]) + t * (np.log(m[j]) - np.log(m[j - 1]))))
    return out


def linear_detectable_magnitude(J: np.ndarray, g: np.ndarray, sigma: float,
                                z: float = 4.0) -> float:
    """Magnitude ``phi`` at which the linear score test's non-centrality reaches ``z``:
    ``phi = z sigma / |Q g|`` with ``Q`` the projector removing ``J``'s columns (the part
    of the signature E, nu cannot mimic). A first guess of the detection limit, used to
    centre a grid of magnitudes (inf when the signature is fully absorbed, as the score
    test's ``identifiable < 1e-8`` treats it).

    Parameters
    ----------
    J
        (n, p) base Jacobian, mm per unit.
    g
        (n,) signature, mm per unit ``phi``.
    sigma
        Noise sd, mm.
    z
        Required ``|Q g| phi / sigma``.
    """
    J = np.asarray(J, dtype=float)
    g = np.asarray(g, dtype=float)
    full = float(np.linalg.norm(g))
    if J.shape[1]:
        g = g - J @ np.linalg.lstsq(J, g, rcond=1e-10)[0]
    norm = float(np.linalg.norm(g))
    # below 1e-8 of the signature's own size the remainder is round-off: absorbed
    return float(z * sigma / norm) if norm > 1e-8 * full else float("inf")
