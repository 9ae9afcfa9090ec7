"""The GP's input coordinates: log inputs and the principal-axes frame.

The GP sees u = ((x' - shift) / scale) V: the inputs x in user units, logged where
their box allows (x'), scaled to the unit box by the design box, and rotated by V
(the identity when no frame is chosen).

Principal-axes frame (``rotation``; ``surrogate.frame``)
    An ARD kernel's length scales follow the input coordinates. A posterior with
    strongly correlated directions (a ridge such as E2 with nu2 and the inflow in
    the heterogeneous study) is then poorly described by axis-aligned length
    scales. With ``rotation = V`` (orthogonal, (d, d)) the GP's inputs are
    u V: the box-scaled inputs in the principal axes of the high-likelihood
    training points (:func:`principal_frame`; a tempered-likelihood-weighted
    covariance, a rough posterior covariance), so that the length scales follow
    the posterior's principal axes -- the input whitening of Bayesian-optimization
    and VBMC practice, reduced to its rotation (the ARD scales absorb the rest).
    On an ideal design it lowers the error of the log-likelihood in the posterior
    severalfold on a sloppy 4-D and a 7-D benchmark (``benchmarks/gp_rotation.py``;
    figures in ``docs/surrogate.md``).
    :func:`~bayescalib.inference.gp.selection.fit_from_config` fits both frames and
    keeps the larger evidence (``frame: auto``). A stationary kernel is translation
    invariant, so the frame needs no centre; an isotropic kernel is rotation
    invariant, so it keeps the axes. :func:`frame_extent` gives the image of the unit
    box in the frame (the bounds of the quadratic mean's centre,
    :mod:`bayescalib.inference.gp.mean`).

Log inputs (``log_offset``; ``surrogate.inputs``)
    Moduli and rates act multiplicatively: the FSI deformation depends on the
    inflow rate over E, so the high-likelihood set of the uncertain-inflow study is a
    wedge E ~ V_in whose width in E grows with E. A stationary kernel has one length
    scale for the whole wedge and misses its narrow end (low E, low V_in). In log
    coordinates the wedge is a band of constant width. With ``log_offset = c``
    ((d,), NaN for a linear input) input k enters as log(x_k + c_k) before the box
    scaling (the bounds are mapped the same way, so u stays in [0, 1]): the log
    input warping of Bayesian optimization for positive scale parameters (Snoek et
    al. 2014 warp every input with a learned Beta CDF; here the one fixed warping
    that suits scale parameters). :func:`log_input_offsets` gives
    c = max(0, 0.05 hi - lo) for a box [lo, hi] in [0, inf) (plain log x when
    lo >= 5 % of hi; a zero lower bound, such as an inflow rate's, is shifted) and
    NaN otherwise. On the uncertain-inflow study's own solves the log inputs cut the
    error at later solves in the posterior region several times
    (``benchmarks/inflow_surrogate.py``; figures in ``docs/surrogate.md``).
    :func:`~bayescalib.inference.gp.selection.fit_from_config` fits both scales and
    keeps the larger evidence (``inputs: auto``; the targets are the same, so the
    evidences compare directly) when the kernel has one length scale per input in three
    or more dimensions; with a single length scale, and in one or two dimensions (the
    2-D studies), ``auto`` keeps linear inputs (:data:`LOG_INPUTS_NOTE`).
"""

from __future__ import annotations

import numpy as np

__all__ = ["LOG_INPUTS_NOTE", "frame_extent", "log_input_offsets", "principal_frame",
           "warp_inputs"]

#: shift of a log input whose box starts near zero, as a share of its upper bound
LOG_OFFSET_SHARE = 0.05
#: why ``inputs: auto`` keeps linear inputs for a kernel with a single length scale and in
#: one or two dimensions (the 2-D studies): there the log inputs cost solves without a
#: better posterior (default study, one length scale), and with one length scale per input
#: and the fitted nugget gave the same accuracy as linear inputs (the smoke study,
#: benchmarks/bench_active_fsi.py); the measurements are in docs/surrogate.md
LOG_INPUTS_NOTE = ("log inputs are tried with per-input length scales from three "
                   "dimensions on only")


def log_input_offsets(bounds: np.ndarray) -> np.ndarray | None:
    """Offsets c (d,) of the log inputs for a design box (d, 2): input k enters the GP
    as log(x_k + c_k) when its box lies in [0, inf), with c_k = max(0, 0.05 hi - lo)
    (a box starting at zero, such as an inflow rate's, is shifted by 5 % of its upper
    bound; one starting at >= 5 % of it is logged as it is); NaN for the other inputs.
    None when no input qualifies."""
    b = np.asarray(bounds, float)
    lo, hi = b[:, 0], b[:, 1]
    ok = (lo >= 0.0) & (hi > lo) & np.isfinite(hi)
    if not ok.any():
        return None
    return np.where(ok, np.maximum(0.0, LOG_OFFSET_SHARE * hi - lo), np.nan)


def warp_inputs(X: np.ndarray, log_offset: np.ndarray | None) -> np.ndarray:
    """log(x_k + c_k) for the inputs with a finite offset c_k, x_k for the others
    (X (..., d) in user units; a value at or below -c_k maps to log of the smallest
    positive float instead of -inf)."""
    X = np.asarray(X, float)
    if log_offset is None:
        return X
    m = np.isfinite(log_offset)
    out = X.copy()
    out[..., m] = np.log(np.maximum(X[..., m] + log_offset[m], np.finfo(float).tiny))
    return out


def frame_extent(rotation: np.ndarray | None, d: int) -> tuple[np.ndarray, np.ndarray]:
    """Lower and upper ends (d,) of the unit box [0, 1]^d in the GP's input frame u V:
    coordinate j of u V ranges over [sum_i min(0, V_ij), sum_i max(0, V_ij)]."""
    if rotation is None:
        return np.zeros(d), np.ones(d)
    V = np.asarray(rotation, float)
    return np.minimum(V, 0.0).sum(0), np.maximum(V, 0.0).sum(0)


#: smallest effective number of training points behind :func:`principal_frame`'s
#: covariance, as a multiple of the dimension d (and at least a fifth of the points)
FRAME_ESS_PER_DIM = 2.0
#: regularization of that covariance (box units): sd added in every direction
FRAME_REG_SD = 0.01


def principal_frame(X: np.ndarray, L: np.ndarray, bounds: np.ndarray,
                    log_offset: np.ndarray | None = None) -> np.ndarray:
    """Orthogonal matrix V (d, d) whose columns are the principal axes of the
    high-likelihood training points, in box-scaled coordinates u = (x - lo) / (hi - lo).

    The covariance is that of the training points weighted by
    w_i ~ exp(beta (L_i - max L)), beta in (0, 1] the largest value giving an
    effective sample size (sum w)^2 / sum w^2 of at least
    max(FRAME_ESS_PER_DIM d, n / 5) (tempering, as in SMC, so that a few top points
    cannot make it degenerate), plus FRAME_REG_SD^2 I. With an active design most
    points lie in the posterior, so this is a rough, widened estimate of the
    posterior's covariance; only its eigenvectors are used. An ARD kernel on
    u V has its length scales along the posterior's principal axes instead of the
    parameter axes, which suits a posterior with strongly correlated (ridge)
    directions; for an isotropic kernel the frame changes nothing. Columns are
    sorted by increasing variance, each signed so that its largest entry is
    positive (deterministic).

    Parameters
    ----------
    X
        (n, d) training inputs in user units (finite values only).
    L
        (n,) their log-likelihoods (finite).
    bounds
        (d, 2) design box.
    log_offset
        (d,) offsets of the GP's log inputs (:func:`warp_inputs`): the frame is that of
        the box-scaled warped inputs. None: linear inputs.

    Returns
    -------
    (d, d) orthogonal matrix.
    """
    X = warp_inputs(np.asarray(X, float), log_offset)
    L = np.asarray(L, float)
    b = warp_inputs(np.asarray(bounds, float).T, log_offset).T
    n, d = X.shape
    U = (X - b[:, 0]) / (b[:, 1] - b[:, 0])
    dL = L - L.max()
    min_ess = min(float(n), max(FRAME_ESS_PER_DIM * d, n / 5.0))

    def ess(beta: float) -> float:
        w = np.exp(beta * dL)
        return float(w.sum() ** 2 / (w * w).sum())

    beta = 1.0
    if ess(1.0) < min_ess:  # ess falls as beta rises: bisect in log beta
        lo, hi = -12.0, 0.0
        for _ in range(50):
            mid = 0.5 * (lo + hi)
            lo, hi = (mid, hi) if ess(10.0**mid) >= min_ess else (lo, mid)
        beta = 10.0**lo
    w = np.exp(beta * dL)
    w /= w.sum()
    R = U - w @ U
    C = (R * w[:, None]).T @ R + FRAME_REG_SD**2 * np.eye(d)
    _, V = np.linalg.eigh(C)
    k = np.argmax(np.abs(V), axis=0)
    return V * np.sign(V[k, np.arange(d)])
