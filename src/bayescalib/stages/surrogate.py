"""Stage ``train_surrogate`` (rules ``train_surrogate`` and ``train_round``): the GP
surrogate of the log-likelihood (paper Sec. 3.2), or the output emulator of the
residual vectors (``surrogate.target: outputs``), fitted to a training table.

Failed solves are left out of the fit (those that mark where the model cannot be solved
shape its infeasible region, :mod:`bayescalib.inference.feasibility`); a table with too
few values or with repeated points is refused (:func:`loglik_training_set`, which the
GP convergence stage, :mod:`bayescalib.stages.convergence`, fits too). An active
round refits the previous round's discrete choices until the training set has grown
enough or they mispredict the round's new values; a full search fits its candidates on
the job's threads; a fit whose training table is the same as an earlier full search's
reuses its file (:func:`bayescalib.stages.files.reuse_output`).
"""

from __future__ import annotations

import logging
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from bayescalib.stages.errors import PipelineError
from bayescalib.stages.files import read_stage_file, reuse_output

__all__ = ["loglik_bound", "loglik_training_set", "train_surrogate"]

log = logging.getLogger("bayescalib")


def train_surrogate(training_path: str | Path, surrogate: Mapping[str, Any],
          parameters: Sequence[Mapping[str, Any]], out_path: str | Path, *,
          reuse: Sequence[str | Path] = (), previous: str | Path | None = None,
          threads: int = 1) -> None:
    """Fit the GP surrogate on the training points (failed runs left out).

    ``previous``: the surrogate file of the previous active round. Its discrete choices
    (kernel, output, inputs, frame) are refitted instead of searched again until the
    training set has grown by ``surrogate.reselect_growth`` since their last full search,
    or until it mispredicts the new values by more than ``surrogate.reselect_error``
    (:func:`bayescalib.inference.gp.selection.fit_round`). None or empty (round 0, a fixed
    design, the study's final surrogate; a rule's absent input): a full search.

    ``threads``: the job's granted cores (the job server passes the rule's ``threads``);
    a full search fits its candidates on that many processes (the same surrogate, bit
    for bit).

    ``reuse``: (training table, surrogate) of an earlier fit with the same settings
    (the last active round's); when the training table holds the same content and that
    surrogate searched the discrete choices in full, it is copied instead of fitted again
    (:func:`bayescalib.stages.files.reuse_output`). A round's refit is not reused: the
    study's surrogate is a full search."""
    from bayescalib.inference.parameters import ParameterSpace
    from bayescalib.inference.rounds import Evaluations, fit_surrogate

    if reuse and not _full_search(reuse[-1]):
        log.info("train_surrogate: '%s' refitted the previous round's choices: the "
                 "discrete choices are searched in full for the study's surrogate", reuse[-1])
    elif reuse_output(training_path, reuse, out_path, "train_surrogate"):
        return
    tab = read_stage_file(training_path, "training table")
    use = tab["is_train"].astype(bool)
    loglik_training_set(tab)  # refuses too few values and repeated points
    rows = Evaluations.from_rows(tab).take(use)
    if surrogate["target"] == "outputs":
        if rows.residuals.shape[1] == 0:
            raise PipelineError(
                f"surrogate.target is 'outputs' but the training table '{training_path}' "
                "holds no residual vectors (it was gathered before they were recorded): "
                "delete it and the discrepancy records of this measure, then rerun (the "
                "solves are kept)")
        if rows.likelihood_bound() is None:
            raise PipelineError(
                f"surrogate.target is 'outputs' but the training table '{training_path}' "
                "records no likelihood bound: gather it again")
    prev = None if not previous else read_stage_file(previous, "surrogate", device="cpu")
    try:
        fitted = fit_surrogate(rows, surrogate, ParameterSpace.from_config(parameters).bounds,
                               prev, threads=threads)
    except (RuntimeError, ValueError, ArithmeticError, np.linalg.LinAlgError) as exc:
        raise PipelineError(_fit_failure(rows, surrogate, training_path, exc)) from None
    fitted.save(out_path)
    if surrogate["target"] == "outputs":
        em = fitted.emulator
        log.info("output emulator on %d points (%d excluded): %d of %d outputs' principal "
                 "directions, discarded %.3g (noise units^2 per point), log inputs %s",
                 fitted.n_train, fitted.n_excluded, em.n_components, rows.residuals.shape[1],
                 em.discarded, em.log_inputs)
    else:
        log.info("GP surrogate on %d points (%d excluded, %d of them marking where the "
                 "model cannot be solved), choices %s (%s): %s", fitted.n_train,
                 fitted.n_excluded, fitted.n_failed, fitted.selection,
                 fitted.selection_reason or "reason not recorded", fitted.hyperparameters)


def _fit_failure(rows, surrogate: Mapping[str, Any], training_path: str | Path,
                 exc: BaseException) -> str:
    """What to say when the surrogate cannot be fitted, with the settings to try."""
    if surrogate["target"] == "outputs":
        R = rows.residuals
        return (f"the output emulator cannot be fitted to the "
                f"{int(np.isfinite(R).all(1).sum())} residual vectors of '{training_path}' "
                f"({R.shape[1]} outputs): {type(exc).__name__}: {exc}. Try more "
                f"surrogate.restarts (now {surrogate['restarts']}) or a larger "
                f"surrogate.outputs.nugget_floor (now "
                f"{surrogate['outputs']['nugget_floor']:g}).")
    Lf = rows.loglik[np.isfinite(rows.loglik)]
    return (f"the GP surrogate cannot be fitted to the {Lf.size} log-likelihood "
            f"values (range {Lf.min():.6g} to {Lf.max():.6g}): {type(exc).__name__}: {exc}. "
            "Try more surrogate.restarts (now "
            f"{surrogate['restarts']}), the other surrogate.optimizer (now "
            f"'{surrogate['optimizer']}'), a larger surrogate.nugget_factor (now "
            f"{surrogate['nugget_factor']:g}) or surrogate.nugget_floor (now "
            f"{surrogate['nugget_floor']:g}; surrogate.nugget is '{surrogate['nugget']}'), "
            "or a larger likelihood.sigma_n2 if the values are extreme.")


def loglik_training_set(tab: Mapping[str, Any]) -> tuple[np.ndarray, np.ndarray]:
    """The inputs and log-likelihoods the GP surrogate is fitted to: the training
    points of the table (``is_train``), a failure for the machine's sake (no value and
    no infeasible region, :mod:`bayescalib.inference.feasibility`) as NaN, an infeasible
    point's -inf kept. Refuses a table with fewer than 3 finite values or with repeated
    points. The study's surrogate (:func:`train_surrogate`) and the GP convergence study
    (:func:`bayescalib.stages.convergence.convergence`) fit these, the latter their prefixes."""
    train_mask = tab["is_train"].astype(bool)
    X, L = tab["X"][train_mask], tab["loglik"][train_mask]
    finite = np.isfinite(L)
    if finite.sum() == 0:
        reasons = sorted({r for r, ok in zip(tab["reason"], train_mask, strict=True) if ok and r})
        raise PipelineError(
            f"all {len(L)} design points failed or have a log-likelihood of -inf, so no "
            "surrogate can be trained. Reasons seen: "
            + ("; ".join(reasons[:5]) or "none recorded")
            + ". Check the forward model settings, the parameter bounds, and sigma_n."
        )
    if finite.sum() < 3:
        raise PipelineError(
            f"only {int(finite.sum())} of {len(L)} design points succeeded; at least 3 are "
            "needed to train the surrogate: increase design.n_train or narrow the bounds"
        )
    _validate_distinct(X, finite, tab["names"])
    from bayescalib.inference.feasibility import fit_targets

    return X, fit_targets(L, [r for r, use in zip(tab["reason"], train_mask, strict=True) if use])


def _full_search(surrogate_path: str | Path) -> bool:
    """False when the surrogate file records a refit of an earlier round's discrete
    choices (:func:`bayescalib.inference.gp.selection.fit_round`); True otherwise (a full
    search, a file written before the record, or one that cannot be read: then
    :func:`bayescalib.stages.files.reuse_output` decides)."""
    import h5py

    try:
        with h5py.File(surrogate_path, "r") as f:
            value = f.attrs.get("selection", "search")
    except OSError:
        return True
    return (value.decode() if isinstance(value, bytes) else str(value)) != "refit"


def loglik_bound(tab: Mapping[str, Any], use: np.ndarray | None = None) -> float | None:
    """Upper bound of the log-likelihood over the training table's points (the
    largest per-point bound), or None when the table has none (older tables)."""
    b = np.asarray(tab["bound"], float)
    if use is not None:
        b = b[np.asarray(use, bool)]
    b = b[np.isfinite(b)]
    return float(b.max()) if b.size else None


def _validate_distinct(X: np.ndarray, use: np.ndarray, names: Sequence[str]) -> None:
    """Refuse repeated design points: a Sobol design never repeats one, so a repeat
    means run records that do not belong to this design."""
    idx = np.flatnonzero(use)
    _, inverse, counts = np.unique(X[idx], axis=0, return_inverse=True, return_counts=True)
    if np.all(counts == 1):
        return
    k = int(np.flatnonzero(counts > 1)[0])
    pts = idx[np.flatnonzero(inverse.ravel() == k)]
    values = ", ".join(f"{n}={v:g}" for n, v in zip(names, X[pts[0]], strict=False))
    raise PipelineError(
        f"design points {', '.join(map(str, pts.tolist()))} have the same parameter values "
        f"({values}); {int((counts - 1).sum())} repeated point(s) in all. A Sobol design "
        "never repeats a point, so these run records do not belong to the design: delete "
        "the results/<study>/runs folder (or the repeated records) and rerun."
    )
