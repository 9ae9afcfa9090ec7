"""The surrogate's discrete choices: the study's surrogate from its settings, the search
of the choices by the evidence, and the per-round refit of an active design.

The ``surrogate`` section makes some choices of the model directly and leaves others to
``auto`` (:func:`resolve_ard`, :func:`resolve_mean` for those decided by the dimension;
:func:`surrogate_settings` builds a validated section from Python).

Search of the discrete choices (:func:`fit_from_config`)
    Every candidate of kernel x output x input scale x frame (up to 24 GP fits in 3-7D,
    :func:`search_size`) is fitted by :func:`~bayescalib.inference.gp.fit.fit_gp` and
    the one with the largest evidence *of the log-likelihood values* is kept (type-II
    maximum likelihood over the model's discrete choices; a warped GP's evidence is
    carried to L by the Jacobian of the warping,
    :func:`~bayescalib.inference.gp.warping.evidence_of_loglik`). A model of L whose
    mean rises above the likelihood's bound inside the box is not chosen
    (:func:`_overshoots`).

Re-deciding the discrete choices (``surrogate.reselect_growth``; :func:`fit_round`)
    In an active design the training set grows by a small batch a round, so the winner
    seldom changes from one round to the next while the search dominates the round's
    time. :func:`fit_round` searches in full in round 0 and once the training set has
    grown by the fraction f since the last search (n >= (1 + f) n_search, a geometric
    schedule: O(log n) searches in a run), and in the other rounds refits only the
    previous choice on all current data (one GP fit; principal frame recomputed,
    warm-started from the previous hyperparameters), with a fall-back to the full search
    when that refit fails or overshoots the bound. Between growth steps the previous
    round's surrogate is also judged out of sample: when it mispredicted the values just
    solved in the posterior region by more than ``surrogate.reselect_error`` nats (the
    trust check's region), the choices are searched at once. The choice, n_search and
    why (``GPSurrogate.selection`` / ``selection_n`` / ``selection_reason`` /
    ``selection_error``) travel with the surrogate, stored in its file. The surrogate of
    the study's result is always a full search.

Competing fits in parallel (``threads``)
    The candidates of a full search are independent seeded fits: with ``threads`` > 1
    (the job's granted cores) they run on a pool of forked processes
    (:func:`_fit_candidates`) and are compared in the serial order, so the result is the
    serial search's, bit for bit.

The measurements behind the ``auto`` thresholds (:data:`ARD_FROM_DIM`,
:data:`LOG_INPUTS_FROM_DIM` and :data:`~bayescalib.inference.gp.inputs.LOG_INPUTS_NOTE`)
are in ``docs/surrogate.md``.
"""

from __future__ import annotations

import itertools
import logging
import math
from typing import Any

import numpy as np

from bayescalib.config import validate
from bayescalib.inference.gp.fit import fit_gp
from bayescalib.inference.gp.inputs import log_input_offsets, principal_frame
from bayescalib.inference.gp.kernels import KERNELS
from bayescalib.inference.gp.predictor import _REFIT, _SEARCH, GPSurrogate
from bayescalib.inference.gp.warping import evidence_of_loglik

__all__ = ["fit_from_config", "fit_round", "resolve_ard", "resolve_mean", "search_size",
           "surrogate_settings"]

log = logging.getLogger(__name__)

#: tolerated excess of a model of L over the likelihood's bound (nats)
OVERSHOOT_NATS = 0.5


def _overshoots(gp: GPSurrogate, bounds: np.ndarray, bound: float, n: int = 4096) -> bool:
    """True when the GP mean of L exceeds ``bound + OVERSHOOT_NATS`` somewhere in the
    box (scrambled Sobol sample of ``n`` points plus the training points)."""
    from bayescalib.inference.design import sobol_design

    Z = np.vstack([sobol_design(np.asarray(bounds, float), n, 12345), gp.X_train])
    return bool(np.max(gp.predict_latent(Z)) > bound + OVERSHOOT_NATS)


#: smallest number of parameters from which ``surrogate.mean: auto`` is the quadratic mean
QUADRATIC_MEAN_FROM_DIM = 3


def resolve_mean(mean: str, dim: int) -> str:
    """The ``surrogate.mean`` setting for a ``dim``-dimensional input: ``"auto"`` is the
    quadratic mean from :data:`QUADRATIC_MEAN_FROM_DIM` dimensions on, else constant."""
    if mean == "auto":
        return "quadratic" if dim >= QUADRATIC_MEAN_FROM_DIM else "constant"
    return mean


#: smallest number of parameters from which ``surrogate.ard: auto`` gives one length scale
#: per input. 2 since issue 17: with the fitted nugget, one length scale per input was more
#: accurate with fewer evaluations in 2-D (ridge2d, the 2-D FSI smoke study;
#: docs/surrogate.md).
ARD_FROM_DIM = 2
#: smallest number of parameters from which ``surrogate.inputs: auto`` tries log inputs
#: (with one length scale per input; :data:`~bayescalib.inference.gp.inputs.LOG_INPUTS_NOTE`)
LOG_INPUTS_FROM_DIM = 3


def resolve_ard(ard: bool | str, dim: int) -> bool:
    """The ``surrogate.ard`` setting for a ``dim``-dimensional input: ``"auto"`` is
    one length scale per input from :data:`ARD_FROM_DIM` (2) dimensions on (in 1-D the
    two are the same model)."""
    return dim >= ARD_FROM_DIM if ard == "auto" else bool(ard)


def _discrete_choices(surrogate: dict[str, Any], bounds: np.ndarray, bound: float | None
                      ) -> tuple[list[str], list[bool], list[np.ndarray | None], list[bool]]:
    """The values of the surrogate's discrete choices that a full search fits, for a
    validated ``surrogate`` section and a design box ``bounds`` (d, 2): kernels, outputs
    (warped: the log-misfit), input scales (None: linear, else the log offsets) and frames
    (True: the principal frame, computed from the data when there are at least two
    finite values). ``bound``: the log-likelihood's upper bound (None: unknown)."""
    d = int(np.shape(bounds)[0])
    ard = resolve_ard(surrogate["ard"], d)
    output = surrogate["output"]
    warps = [False] if bound is None or output == "loglik" else \
        [True] if output == "log_misfit" else [False, True]
    if surrogate["kernel"] != "auto":
        kernels = [surrogate["kernel"]]
    elif bound is None:  # uncapped: keep the paper's kernel (smoother ones overshoot more)
        kernels = ["matern32"]
    else:
        kernels = list(KERNELS)
    offsets = log_input_offsets(bounds)
    inputs_cfg = surrogate["inputs"]
    if inputs_cfg == "auto" and (not ard or d < LOG_INPUTS_FROM_DIM):
        inputs_cfg = "linear"  # log inputs cost the 2-D studies solves (LOG_INPUTS_NOTE)
    scales: list[np.ndarray | None] = \
        [None] if offsets is None or inputs_cfg == "linear" else \
        [offsets] if inputs_cfg == "log" else [None, offsets]
    frame = surrogate["frame"]
    frames = [False] if not ard or frame == "axes" else \
        [True] if frame == "principal" else [False, True]
    return kernels, warps, scales, frames


def search_size(surrogate: dict[str, Any], bounds: np.ndarray, *,
                bound_known: bool = True) -> int:
    """Number of candidate models a full search of the discrete choices fits
    (:func:`fit_from_config`), each with ``surrogate["restarts"]`` optimizer starts;
    known from the settings and the design box alone (the study's time guard,
    :mod:`bayescalib.inference.cost`)."""
    kernels, warps, scales, frames = _discrete_choices(
        surrogate, np.asarray(bounds, float), 0.0 if bound_known else None)
    return len(kernels) * len(warps) * len(scales) * len(frames)


def _search_settings(X: np.ndarray, y: np.ndarray, surrogate: dict[str, Any],
                     bounds: np.ndarray, bound: float | None
                     ) -> tuple[dict[str, Any], list[tuple[str, bool, np.ndarray | None,
                                                           np.ndarray | None]]]:
    """The keyword arguments of :func:`fit_gp` shared by every candidate of the surrogate's
    discrete choices, and the candidates (kernel, warp, log_offset, rotation) in the order
    :func:`fit_from_config` fits them (a principal frame computed from ``X``, ``y``)."""
    kw = {"ard": resolve_ard(surrogate["ard"], np.shape(X)[1]),
          "optimizer": surrogate["optimizer"],
          "restarts": surrogate["restarts"], "seed": surrogate["seed"], "bounds": bounds,
          "mean_offset_factor": surrogate["mean_offset_factor"],
          "nugget_factor": surrogate["nugget_factor"], "bound": bound,
          "nugget": surrogate["nugget"], "nugget_floor": surrogate["nugget_floor"],
          "mean": resolve_mean(surrogate["mean"], np.shape(X)[1])}
    kernels, warps, scales, frames = _discrete_choices(surrogate, bounds, bound)
    Xa, ya = np.asarray(X, float), np.asarray(y, float).reshape(-1)
    ok = np.isfinite(ya) & np.all(np.isfinite(Xa), axis=1)
    inputs: list[tuple[np.ndarray | None, np.ndarray | None]] = []
    for log_offset in scales:
        rotations: list[np.ndarray | None] = [None]
        if frames != [False] and ok.sum() >= 2:
            V = principal_frame(Xa[ok], ya[ok], bounds, log_offset)
            rotations = [V if principal else None for principal in frames]
        inputs += [(log_offset, rotation) for rotation in rotations]
    return kw, [(kernel, warp, log_offset, rotation)
                for kernel, warp, (log_offset, rotation) in
                itertools.product(kernels, warps, inputs)]


def _describe(kernel: str, warp: bool, log_offset: np.ndarray | None,
              rotation: np.ndarray | None) -> str:
    return f"{kernel} of {'log-misfit' if warp else 'L'}" + \
        ("" if rotation is None else " (principal axes)") + \
        ("" if log_offset is None else " (log inputs)")


def _fit_candidate(X: np.ndarray, y: np.ndarray, kw: dict[str, Any], bounds: np.ndarray,
                   bound: float | None, candidate: tuple[str, bool, np.ndarray | None,
                                                         np.ndarray | None],
                   warm_start: tuple[float, np.ndarray] | None = None) -> GPSurrogate | None:
    """:func:`fit_gp` of one candidate of the discrete choices; None when the fit fails or
    a model of L overshoots the bound inside the box (:func:`_overshoots`)."""
    kernel, warp, log_offset, rotation = candidate
    what = _describe(*candidate)
    try:
        gp = fit_gp(X, y, warp=warp, kernel=kernel, rotation=rotation,
                    log_offset=log_offset, warm_start=warm_start, **kw)
    except (RuntimeError, np.linalg.LinAlgError) as exc:
        log.warning("surrogate %s: fit failed: %s", what, exc)
        return None
    if bound is not None and not gp.warped and _overshoots(gp, bounds, bound):
        log.info("surrogate %s: rejected, its mean exceeds the likelihood's "
                 "upper bound %.6g inside the box", what, bound)
        return None
    return gp


def _fit_one(args: tuple) -> GPSurrogate | None:
    """:func:`_fit_candidate` in a worker process of :func:`_fit_candidates`; its
    prediction cache (rebuilt on demand) is not sent back."""
    gp = _fit_candidate(*args)
    if gp is not None:
        gp._cache.clear()
    return gp


def _can_fork() -> bool:
    """Whether the candidates may be fitted in forked processes: the platform forks, this
    process is not itself a pool's (daemonic) worker, and it has not initialized CUDA (a
    forked child cannot use it)."""
    import multiprocessing as mp
    import sys

    if "fork" not in mp.get_all_start_methods() or mp.current_process().daemon:
        return False
    torch = sys.modules.get("torch")
    try:
        return not (torch is not None and torch.cuda.is_initialized())
    except AttributeError:  # pragma: no cover - a torch without cuda
        return True


def _fit_candidates(X: np.ndarray, y: np.ndarray, kw: dict[str, Any], bounds: np.ndarray,
                    bound: float | None, candidates: list, threads: int
                    ) -> list[GPSurrogate | None]:
    """:func:`_fit_candidate` of every candidate, in their order: serially, or with
    ``threads`` > 1 on a pool of that many forked processes (at most one per candidate).
    Each fit is independent and seeded (``kw["seed"]``), so the fits are those of the
    serial loop, bit for bit; where processes cannot be forked (:func:`_can_fork`) the
    loop is serial."""
    n = min(int(threads), len(candidates))
    if n <= 1 or not _can_fork():
        return [_fit_candidate(X, y, kw, bounds, bound, c) for c in candidates]
    import multiprocessing as mp

    with mp.get_context("fork").Pool(n) as pool:
        return pool.map(_fit_one, [(X, y, kw, bounds, bound, c) for c in candidates],
                        chunksize=1)


def _evidence_of_L(gp: GPSurrogate) -> float:
    """The evidence of the log-likelihood values (the warped GP's carried to L by the
    Jacobian of the warping, :func:`fit_from_config`)."""
    return evidence_of_loglik(gp.log_marginal_likelihood, gp.y_train, gp.warped)


def surrogate_settings(**settings: Any) -> dict[str, Any]:
    """A validated ``surrogate`` section: ``settings`` (keys of the section, e.g.
    ``kernel="matern32"``) over the schema's defaults; the way from Python to the study's
    surrogate, :func:`fit_from_config` (``fit_from_config(X, y, surrogate_settings(),
    bounds)`` fits what a study with no ``surrogate`` section fits).

    Raises
    ------
    bayescalib.config.ConfigError
        Naming a key the section does not have or a value it does not allow.
    """
    return validate({"surrogate": settings}, "inference", where="surrogate_settings")["surrogate"]


def fit_from_config(X: np.ndarray, y: np.ndarray, surrogate: dict[str, Any],
                    bounds: np.ndarray, *, bound: float | None = None,
                    threads: int = 1) -> GPSurrogate:
    """:func:`fit_gp` with the settings of a validated ``surrogate`` config section.

    ``surrogate["output"]`` chooses what the GP models when the log-likelihood's
    upper bound ``bound`` is known: ``log_misfit`` (the warped output), ``loglik``
    (L itself, capped at the bound) or ``auto``; ``surrogate["kernel"]`` one of
    :data:`KERNELS` or ``auto``. Every candidate model is fitted and the one with
    the largest evidence *of the log-likelihood values* wins (type-II maximum
    likelihood over the model's discrete choices). The warped model's evidence
    is carried to the units of L by the Jacobian of the warping,
    log p(L) = log p(g) + sum_i log|dg/dL|_i = log p(g) - sum_i g_i (warped GPs,
    Snelson et al. 2004), so all evidences compare like with like. A model of L
    whose mean rises above the bound inside the box (by more than
    ``OVERSHOOT_NATS``, on a Sobol sample) contradicts what is known and is not
    chosen: capping it would leave a plateau of spurious maximal likelihood.
    Without a bound the GP models L with the paper's kernel.

    ``surrogate["frame"]`` chooses the GP's input coordinates when the kernel has
    one length scale per input (``ard``): ``axes`` (the box-scaled parameters),
    ``principal`` (rotated to the principal axes of the high-likelihood training
    points, :func:`principal_frame`) or ``auto`` (both, chosen by the same evidence
    rule). An isotropic kernel does not depend on the rotation, so it keeps ``axes``.

    ``surrogate["inputs"]`` chooses the scale of the inputs: ``linear``, ``log`` (the
    inputs whose box lies in [0, inf) enter as logs,
    :func:`~bayescalib.inference.gp.inputs.log_input_offsets`) or
    ``auto``: with one length scale per input (``ard``) in three or more dimensions,
    both, by the same evidence rule (the principal frame is computed in each scale);
    with a single length scale or in one or two dimensions, ``linear`` (see
    :data:`~bayescalib.inference.gp.inputs.LOG_INPUTS_NOTE`). Without an input that
    qualifies, ``log`` and ``auto`` are ``linear``.

    ``threads`` > 1 (the job's granted cores): the candidates are fitted by that many
    forked worker processes (:func:`_fit_candidates`), each candidate alone with its own
    seeded starts as in the serial search, and compared in the serial order: the same
    winner, bit for bit.
    """
    kw, candidates = _search_settings(X, y, surrogate, bounds, bound)
    best, best_ev = None, -math.inf
    fits = _fit_candidates(X, y, kw, bounds, bound, candidates, threads)
    for candidate, gp in zip(candidates, fits, strict=True):
        if gp is None:
            continue
        ev = _evidence_of_L(gp)
        log.info("surrogate %s: evidence of L %.6g", _describe(*candidate), ev)
        if best is None or ev > best_ev:
            best, best_ev = gp, ev
    if best is None:
        raise RuntimeError("every GP surrogate fit failed")
    if len(candidates) > 1:
        log.info("surrogate chosen: %s of %s%s%s", best.kernel,
                 "log-misfit" if best.warped else "L",
                 "" if best.rotation is None else " (principal axes)",
                 "" if best.log_offset is None else " (log inputs)")
    best.selection, best.selection_n = _SEARCH, best.n_train
    return best



def _matches(candidate: tuple[str, bool, np.ndarray | None, np.ndarray | None],
             previous: GPSurrogate) -> bool:
    """True when ``candidate`` (kernel, warp, log_offset, rotation) makes the same discrete
    choices as ``previous``: kernel, output (log-misfit or L), input scale (log or linear)
    and frame (principal or axes; the rotation itself is recomputed from current data)."""
    kernel, warp, log_offset, rotation = candidate
    return (kernel == previous.kernel and bool(warp) == previous.warped
            and (log_offset is None) == (previous.log_offset is None)
            and (rotation is None) == (previous.rotation is None))


#: the refit of :func:`fit_round` starts its first optimizer run at the previous round's
#: kernel variance and length scales (else at the default start, as the full search)
REFIT_WARM_START = True


def _misprediction(previous: GPSurrogate, X: np.ndarray, y: np.ndarray) -> float | None:
    """The largest error (nats) of ``previous`` at the new values: the rows of (X, y) with
    a finite value that are not among ``previous.X_train``, in the posterior region as
    the trust check defines it (:func:`~bayescalib.inference.active.trust_check`: the real
    or the predicted value within chi2_d(REGION_LEVEL) / 2 of the best value now). None
    when no new value lies in that region (nothing to judge the choice by)."""
    from bayescalib.inference.active import trust_check

    Xa, ya = np.asarray(X, float), np.asarray(y, float).reshape(-1)
    ok = np.isfinite(ya) & np.all(np.isfinite(Xa), axis=1)
    known = {row.tobytes() for row in np.ascontiguousarray(previous.X_train, float)}
    new = ok & np.array([row.tobytes() not in known for row in np.ascontiguousarray(Xa)],
                        bool)
    if not new.any():
        return None
    mean = np.asarray(previous.predict(Xa[new]), float)
    trust = trust_check(mean, np.zeros_like(mean), ya[new], float(ya[ok].max()),
                        Xa.shape[1], math.inf)
    return trust["max_abs_error"]


def _searched(gp: GPSurrogate, reason: str, error: float | None) -> GPSurrogate:
    gp.selection_reason = reason
    gp.selection_error = math.nan if error is None else float(error)
    return gp


def fit_round(X: np.ndarray, y: np.ndarray, surrogate: dict[str, Any], bounds: np.ndarray, *,
              bound: float | None = None, previous: GPSurrogate | None = None,
              threads: int = 1) -> GPSurrogate:
    """The surrogate of one round of the active design: :func:`fit_from_config` (the full
    search of the discrete choices: kernel x output x input scale x frame) only when the
    training set has grown enough since the last full search or the previous round's
    surrogate mispredicted the new values, else a refit of the previous round's choice.

    Rule (``surrogate["reselect_growth"]`` = f >= 0, ``surrogate["reselect_error"]`` =
    e > 0 nats). With n the number of finite training values now and n_s that of the last
    full search (``previous.selection_n``), the candidates are searched in full when

    - previous is None (reason ``"round 0"``: also a fixed design and a study's surrogate),
    - f = 0, n_s is unknown, or n >= (1 + f) n_s (``"growth"``),
    - the previous choice is not among the candidates of ``surrogate`` (``"settings
      changed"``),
    - the previous surrogate predicted the new values (rows not in its training set) in
      the posterior region (the trust check's region: the real or the predicted value
      within chi2_d(0.99) / 2 of the best value, :func:`_misprediction`) with a largest
      error above e (``"mispredicted"``): the out-of-sample check of the previous choice,
      the same test as the rounds' trust check at the points just solved.

    Otherwise only the previous choice is fitted (``"predicted well"``, or ``"no new
    value in the region"``), on all current data (the principal frame, if chosen,
    recomputed from them), its first optimizer start at the previous kernel variance and
    length scales, and fitted nugget (warm start: with a fitted nugget one start more,
    before the default ones; the other ``restarts - 1`` starts as in :func:`fit_gp`). A
    refit that fails, or a model of L whose mean exceeds the bound inside the box
    (:func:`_overshoots`), falls back to the full search (``"refit rejected"``). With
    f = 0 the result is that of :func:`fit_from_config`, bit for bit.

    The discrete choices are chosen by the evidence among models fitted to the same
    data (type-II maximum likelihood); between searches the evidences of the candidates
    change slowly as a design grows by small batches, so re-deciding them every round
    mostly refits the same choice. The refit keeps the choice's continuous
    hyperparameters (variance, length scales, quadratic mean) optimal for current data.
    A choice that mispredicts what the round just solved where the posterior lives is
    in doubt, and is searched again at once instead of at the next growth step.

    Parameters
    ----------
    X
        (n, d) training inputs in user units.
    y
        (n,) their log-likelihoods (non-finite: failed, left out).
    surrogate
        A validated ``surrogate`` config section.
    bounds
        (d, 2) design box.
    bound
        Upper bound of the log-likelihood; None: unknown.
    previous
        The previous round's surrogate (None: round 0).
    threads
        Processes of a full search (:func:`fit_from_config`); the job's granted cores.

    Returns
    -------
    GPSurrogate
        With ``selection`` ``"search"`` (and ``selection_n`` = its n) after a full search,
        ``"refit"`` (``selection_n`` carried over from ``previous``) after a refit;
        ``selection_reason`` the reason above and ``selection_error`` the previous
        surrogate's largest error at the new values in the region (NaN: none, or no
        previous).
    """
    def search(reason: str, error: float | None = None) -> GPSurrogate:
        gp = fit_from_config(X, y, surrogate, bounds, bound=bound, threads=threads)
        return _searched(gp, reason, error)

    if previous is None:
        return search("round 0")
    if previous.dim != np.shape(X)[1]:
        log.info("surrogate: the previous round's surrogate has %d inputs, the data %d: "
                 "full search", previous.dim, np.shape(X)[1])
        return search("settings changed")
    growth = float(surrogate["reselect_growth"])
    tol = float(surrogate["reselect_error"])
    error = _misprediction(previous, X, y)
    ya = np.asarray(y, float).reshape(-1)
    n = int((np.isfinite(ya) & np.all(np.isfinite(np.asarray(X, float)), axis=1)).sum())
    n_s = int(previous.selection_n)
    if growth <= 0 or n_s < 1 or n >= (1.0 + growth) * n_s:
        if growth > 0 and n_s >= 1:
            log.info("surrogate: %d training values, %.3g times the %d of the last search "
                     "of the discrete choices: searched again", n, n / n_s, n_s)
        return search("growth", error)
    kw, candidates = _search_settings(X, y, surrogate, bounds, bound)
    same = [c for c in candidates if _matches(c, previous)]
    what = _describe(previous.kernel, previous.warped, previous.log_offset, previous.rotation)
    if not same or kw["ard"] != previous.ard or kw["mean"] != previous.mean_function \
            or (kw["nugget"] == "fit") != previous.nugget_fitted:
        log.info("surrogate: the previous choice (%s) is not among the candidates of the "
                 "settings: full search", what)
        return search("settings changed", error)
    if error is not None and error > tol:
        log.info("surrogate: the previous choice (%s) missed the new values in the "
                 "posterior region by up to %.3g nats (surrogate.reselect_error %.3g): "
                 "full search", what, error, tol)
        return search("mispredicted", error)
    candidate = same[0]
    warm = (float(previous.variance), np.array(previous.lengthscale, float),
            float(previous.nugget) if previous.nugget_fitted else None) \
        if REFIT_WARM_START else None
    gp = _fit_candidate(X, y, kw, bounds, bound, candidate, warm_start=warm)
    if gp is None:
        log.info("surrogate: the refit of %s was rejected: full search",
                 _describe(*candidate))
        return search("refit rejected", error)
    gp.selection, gp.selection_n = _REFIT, n_s
    _searched(gp, "no new value in the region" if error is None else "predicted well", error)
    log.info("surrogate: %s refitted on %d values (choices searched at %d; next search "
             "from %d; largest error at the new values in the region %s nats), evidence "
             "of L %.6g", _describe(*candidate), n, n_s, math.ceil((1.0 + growth) * n_s),
             "-" if error is None else f"{error:.3g}", _evidence_of_L(gp))
    return gp
