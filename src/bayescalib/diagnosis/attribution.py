"""Attribution of a model-form mismatch to candidate physics (step 3 of the diagnosis).

Linearize the predicted interface (as normal offsets along the observed nodes, see
:mod:`bayescalib.diagnosis.residuals`) about the posterior mean ``theta_hat`` of the
base model, extended by candidate ``c`` with parameter ``phi_c`` (``phi_c = 0`` is the
base model, so the extension is nested):

    y = f(theta_hat) + J dtheta + g_c phi_c + e,      e ~ N(0, V),  V = diag(v)

with ``J`` (n x p) the finite-difference Jacobian of the offsets in the base (and
uncertain) parameters and ``g_c`` (n) the *signature* of candidate ``c``: the change of
the predicted interface per unit ``phi_c`` at ``theta_hat``. What the base parameters
can absorb is projected out: with the whitened ``A = V^-1/2 J``, ``b = V^-1/2 g_c`` and
residual ``e = V^-1/2 r`` (``r = y - f(theta_hat)``) and the projector
``Q = I - A A^+`` onto the complement of the columns of ``A``,

    U = (Q b)^T (Q e),   I = (Q b)^T (Q b),   S = U^2 / I ~ chi2_1  under phi_c = 0,

Rao's score statistic for ``phi_c = 0`` with ``dtheta`` profiled out (the score and
the efficient information of the linear Gaussian model). ``phi_hat = U / I`` is the
one-step estimate of ``phi_c``. The *explained fraction* is the part of the residual
beyond noise that the candidate removes: with ``d = n - rank(A)`` (the expected
``|Q e|^2`` under pure noise), ``S / max(|Q e|^2 - d, S)``. ``identifiable = |Q b| / |b|`` is the part of the
signature the base parameters cannot mimic (near 0: the effect is confounded with E,
nu, ... and cannot be told apart with these data).

Selection is greedy (orthogonal matching pursuit): the best candidate is kept if its
p-value is below ``alpha / m`` (Bonferroni over the ``m`` candidates); a second one is
tested with ``J`` and the first signature projected out and kept if it is significant
and either adds at least ``r2_gain_min`` to the explained fraction or explains at least
``r2_min`` of what the selection so far leaves beyond noise (its own explained fraction
with the first signature projected out; up to ``max_effects``). The second clause keeps a
smaller effect beside a dominant one: on the FSI benchmark with growth 0.015 and
attachment 2e-4 mm/Pa hidden together, attachment came second with p 1e-12 and phi_hat
2.09e-4 mm/Pa, explaining 63 % of what growth left but only 5 % of the whole. A
proposal is no verdict: every selected set is calibrated with real solves and kept only
when its Bayes factor and its fit say so (:mod:`bayescalib.diagnosis.stage`). A candidate
whose one-step estimate ``phi_hat`` lies far outside its plausible range (``ranges``,
with a margin of half the range's width) is not selected: an effect that needs an
absurd magnitude is not the cause. It is not hidden either: when such a candidate is
significant and alone explains at least ``r2_min``, the verdict says so (its estimate
and the range it leaves) instead of "no candidate explains the mismatch", and the
diagnosis sets it aside by name (:func:`bayescalib.diagnosis.stage.set_aside_candidates`).
The selection *explains* the mismatch when together it explains at least ``r2_min`` of
the residual beyond noise; otherwise the verdict is "no candidate explains the
mismatch" (a significant but partial fit is reported as such, never as the cause).

Before any candidate is blamed, the base model is re-fitted locally: one Gauss–Newton
step ``dtheta = A^+ e`` from the posterior mean leaves the whitened residual ``Q e``.
Under an adequate base model, ``|Q e|^2 ~ chi2_(n - rank A)`` (the *re-fit test*). When
the predictive check fails but the re-fit test passes, the base parameters can absorb
the mismatch: the calibration missed the best fit (typically a surrogate trained on
too few design points near a narrow posterior), and no physics is missing.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from scipy.stats import chi2

__all__ = ["ScoreTest", "attribute", "block_test", "jacobian_from_offsets", "refit_test",
           "score_test", "signature_from_offsets"]


@dataclass
class ScoreTest:
    """Score test of one candidate (or of a candidate given others)."""

    name: str
    statistic: float
    p_value: float
    phi_hat: float
    explained: float
    identifiable: float

    def to_json(self) -> dict:
        return {"candidate": self.name, "score_statistic": self.statistic,
                "p_value": self.p_value, "phi_hat": self.phi_hat,
                "explained_fraction": self.explained, "identifiable_fraction": self.identifiable}


def _projector(A: np.ndarray) -> np.ndarray:
    n = A.shape[0]
    if A.size == 0:
        return np.eye(n)
    U, s, _ = np.linalg.svd(A, full_matrices=False)
    keep = s > s.max() * 1e-10 if s.size else np.zeros(0, dtype=bool)
    U = U[:, keep]
    return np.eye(n) - U @ U.T


def score_test(name: str, r: np.ndarray, J: np.ndarray, g: np.ndarray, v: np.ndarray) -> ScoreTest:
    """Score test of ``phi = 0`` for signature ``g`` with nuisance Jacobian ``J``.

    Parameters
    ----------
    r
        (n,) residual, mm.
    J
        (n, p) nuisance Jacobian (mm per parameter unit); may have p = 0 columns.
    g
        (n,) signature, mm per unit phi.
    v
        (n,) residual variances, mm^2.
    """
    w = 1.0 / np.sqrt(np.asarray(v, dtype=float))
    A = np.asarray(J, dtype=float).reshape(len(r), -1) * w[:, None]
    b = np.asarray(g, dtype=float) * w
    e = np.asarray(r, dtype=float) * w
    Q = _projector(A)
    qb, qe = Q @ b, Q @ e
    info = float(qb @ qb)
    nb = float(np.linalg.norm(b))
    ident = float(np.sqrt(info) / nb) if nb > 0 else 0.0
    if info <= 1e-300 or ident < 1e-8:
        return ScoreTest(name, 0.0, 1.0, 0.0, 0.0, ident)
    U = float(qb @ qe)
    S = U * U / info
    dof = len(r) - int(np.linalg.matrix_rank(A)) if A.size else len(r)
    return ScoreTest(name, S, float(chi2.sf(S, 1)), U / info,
                     _excess_fraction(float(qe @ qe), float(qe @ qe) - S, dof), ident)


def _excess_fraction(before: float, after: float, dof: int) -> float:
    """Fraction of the residual *beyond noise* that a fit removed.

    ``before`` and ``after`` are whitened squared residual norms; under pure noise
    ``before`` is about ``dof``. The structured part is ``before - dof``; the fraction
    removed is ``(before - after) / max(before - dof, before - after)`` (1 when the
    remainder is at the noise level or below).
    """
    removed = before - after
    denom = max(before - dof, removed)
    return float(removed / denom) if denom > 0 else 0.0


def attribute(
    r: np.ndarray,
    J: np.ndarray,
    signatures: Mapping[str, np.ndarray],
    v: np.ndarray,
    *,
    alpha: float = 0.05,
    r2_min: float = 0.5,
    r2_gain_min: float = 0.1,
    max_effects: int = 2,
    ranges: Mapping[str, tuple[float, float]] | None = None,
) -> dict:
    """Rank candidates and select up to ``max_effects`` of them (see module docstring).

    Returns
    -------
    dict
        ``ranking`` (score tests, best first), ``selected`` (names), ``explained``
        (joint explained fraction of the selection), ``threshold`` (p-value level after
        Bonferroni), ``verdict`` (plain words) and ``steps`` (the greedy selection).
    """
    ranges = dict(ranges or {})

    def plausible(t: ScoreTest) -> bool:
        # the one-step estimate of phi must lie in the candidate's range (with a margin
        # of half its width): an effect that needs an absurd phi is not the cause
        if t.name not in ranges:
            return True
        lo, hi = ranges[t.name]
        pad = 0.5 * (hi - lo)
        return lo - pad <= t.phi_hat <= hi + pad

    names = list(signatures)
    m = max(len(names), 1)
    level = alpha / m
    tests = sorted((score_test(n, r, J, signatures[n], v) for n in names),
                   key=lambda t: -t.statistic)
    selected: list[str] = []
    steps = []
    explained = 0.0
    w = 1.0 / np.sqrt(np.asarray(v, dtype=float))
    e = np.asarray(r, dtype=float) * w
    Q0 = _projector(np.asarray(J, dtype=float).reshape(len(r), -1) * w[:, None])
    total = float(np.sum((Q0 @ e) ** 2))
    dof = len(r) - (int(np.linalg.matrix_rank(np.asarray(J, dtype=float).reshape(len(r), -1)))
                    if np.size(J) else 0)
    for step in range(max_effects):
        nuis = np.column_stack([np.asarray(J, dtype=float).reshape(len(r), -1)]
                               + [signatures[n][:, None] for n in selected])
        cands = [t for t in (score_test(n, r, nuis, signatures[n], v)
                             for n in names if n not in selected) if plausible(t)]
        if not cands:
            break
        best = max(cands, key=lambda t: t.statistic)
        A = np.column_stack([nuis, signatures[best.name]]) * w[:, None]
        joint = _excess_fraction(total, float(np.sum((_projector(A) @ e) ** 2)), dof)
        ok = best.p_value < level and (
            step == 0 or joint - explained >= r2_gain_min or best.explained >= r2_min)
        steps.append({**best.to_json(), "joint_explained": joint, "accepted": bool(ok)})
        if not ok:
            break
        selected.append(best.name)
        explained = joint
        if explained >= 0.95:
            break
    if selected and explained < r2_min:
        for st in steps:
            st["accepted"] = False
        partial, selected = selected, []
    else:
        partial = []
    # significant candidates that would explain most of the mismatch at a magnitude
    # outside their plausible range: never "no candidate explains it" without them
    aside = [t for t in tests if not plausible(t) and t.p_value < level
             and t.explained >= r2_min]
    if selected:
        verdict = (f"the mismatch is explained by {' + '.join(selected)} "
                   f"({100 * explained:.0f} % of the residual beyond noise that the base "
                   "parameters cannot absorb)")
    else:
        verdict = ("no candidate within its plausible range explains the mismatch" if aside
                   else "no candidate explains the mismatch")
        if partial:
            verdict += (f": the best, {' + '.join(partial)}, is significant but explains "
                        f"only {100 * explained:.0f} % of it")
            explained = 0.0
        for t in aside:
            lo, hi = ranges[t.name]
            verdict += (f"; {t.name} would explain {100 * t.explained:.0f} % of it, but its "
                        f"estimated magnitude {t.phi_hat:.3g} lies outside its plausible "
                        f"range [{lo:.3g}, {hi:.3g}]")
    ranking = [{**t.to_json(), "phi_hat_plausible": plausible(t)} for t in tests]
    return {"ranking": ranking, "selected": selected,
            "explained": explained, "threshold": level, "verdict": verdict, "steps": steps}


def block_test(r: np.ndarray, J: np.ndarray, B: np.ndarray, v: np.ndarray,
               names: Sequence[str]) -> dict:
    """Score test of a block of ``k`` nuisance effects (e.g. a rigid misregistration).

    The multi-column form of :func:`score_test`: with ``Q`` the projector that removes
    the base parameters' Jacobian, ``S = e^T Q B (B^T Q B)^+ B^T Q e ~ chi2_k`` under
    ``effects = 0``; the one-step estimate is ``(Q B)^+ Q e``. The block *explains* the
    mismatch when the residual left after fitting the base parameters and the block
    together is consistent with noise (``p_after``).

    Parameters
    ----------
    r
        (n,) residual, mm.
    J
        (n, p) base Jacobian.
    B
        (n, k) block signatures (mm per unit of each effect).
    v
        (n,) noise variances, mm^2.
    names
        The ``k`` effect names.

    Returns
    -------
    dict
        ``statistic``, ``dof``, ``p_value``, ``estimate`` (by name), ``explained_fraction``
        (of the residual beyond noise, see :func:`score_test`), ``identifiable_fraction``
        (``|Q B|_F / |B|_F``), ``chi2_after``, ``dof_after``, ``p_after`` and
        ``base_step`` (the base parameters' Gauss–Newton step of the joint fit, (p,)).
    """
    r = np.asarray(r, dtype=float)
    w = 1.0 / np.sqrt(np.asarray(v, dtype=float))
    A = np.asarray(J, dtype=float).reshape(len(r), -1) * w[:, None]
    Bw = np.asarray(B, dtype=float).reshape(len(r), -1) * w[:, None]
    e = r * w
    Q = _projector(A)
    qB, qe = Q @ Bw, Q @ e
    # the rank of what the base parameters cannot mimic, relative to the block's own size
    tol = 1e-8 * (np.linalg.norm(Bw, 2) if Bw.size else 0.0)
    k = int(np.linalg.matrix_rank(qB, tol=tol)) if qB.size and tol > 0 else 0
    est = np.zeros(Bw.shape[1])
    if k:  # minimum-norm least squares on the identifiable directions only
        U, sv, Vt = np.linalg.svd(qB, full_matrices=False)
        keep = sv > tol
        est = Vt[keep].T @ ((U[:, keep].T @ qe) / sv[keep])
    fitted = qB @ est
    # the base parameters' part of the joint fit: the Gauss-Newton step of theta with the
    # block at its estimate (dtheta = A^+ (e - B est))
    base_step = (np.linalg.lstsq(A, e - Bw @ est, rcond=1e-10)[0] if A.shape[1]
                 else np.zeros(0))
    S = float(fitted @ fitted)
    before = float(qe @ qe)
    rank_a = int(np.linalg.matrix_rank(A)) if A.size else 0
    dof_after = max(len(r) - rank_a - k, 1)
    nb = float(np.linalg.norm(Bw))
    return {"statistic": S, "dof": k, "p_value": float(chi2.sf(S, k)) if k else 1.0,
            "estimate": {n: float(x) for n, x in zip(names, est, strict=True)},
            "explained_fraction": _excess_fraction(before, before - S, len(r) - rank_a),
            "identifiable_fraction": float(np.linalg.norm(qB) / nb) if nb > 0 else 0.0,
            "chi2_after": before - S, "dof_after": dof_after,
            "p_after": float(chi2.sf(before - S, dof_after)),
            "base_step": [float(x) for x in base_step]}


def refit_test(r: np.ndarray, J: np.ndarray, v: np.ndarray) -> dict:
    """Re-fit test of the base model (see the module docstring).

    Parameters
    ----------
    r
        (n,) residual at the posterior mean, mm.
    J
        (n, p) Jacobian of the base parameters (mm per parameter unit).
    v
        (n,) noise variances, mm^2 (observation noise only: under an adequate model
        the re-fitted residual is noise).

    Returns
    -------
    dict
        ``chi2`` (whitened squared residual after the Gauss–Newton step), ``dof``
        (``n - rank J``), ``p_value`` (upper tail of chi2_dof), ``absorbed_fraction``
        (part of the whitened squared residual the step removes) and ``step`` (the
        Gauss–Newton step ``dtheta``, (p,), in parameter units).
    """
    r = np.asarray(r, dtype=float)
    w = 1.0 / np.sqrt(np.asarray(v, dtype=float))
    A = np.asarray(J, dtype=float).reshape(len(r), -1) * w[:, None]
    e = r * w
    if A.shape[1]:
        step, *_ = np.linalg.lstsq(A, e, rcond=1e-10)
        rank = int(np.linalg.matrix_rank(A))
    else:
        step, rank = np.zeros(0), 0
    rest = float(np.sum((_projector(A) @ e) ** 2))
    before = float(e @ e)
    dof = max(len(r) - rank, 1)
    return {"chi2": rest, "dof": dof, "p_value": float(chi2.sf(rest, dof)),
            "absorbed_fraction": float(1.0 - rest / before) if before > 0 else 0.0,
            "step": [float(x) for x in step]}


def signature_from_offsets(o_plus: np.ndarray, o_base: np.ndarray, h: float) -> np.ndarray:
    """Forward-difference signature ``(o(phi = h) - o(0)) / h`` (mm per unit phi)."""
    return (np.asarray(o_plus) - np.asarray(o_base)) / float(h)


def jacobian_from_offsets(o_steps: Sequence[np.ndarray], o_base: np.ndarray,
                          steps: Sequence[float]) -> np.ndarray:
    """Forward-difference Jacobian, columns ``(o_i - o_base) / h_i``, shape (n, p)."""
    if not o_steps:
        return np.zeros((len(o_base), 0))
    return np.column_stack([(np.asarray(o) - np.asarray(o_base)) / float(h)
                            for o, h in zip(o_steps, steps, strict=True)])
