"""Convergence of the GP surrogate over the number of training points (paper Sec. 3.2).

For each n in ``n_train_list`` the surrogate is fitted to the first n points of the
Sobol design by one fit function (the study's:
:func:`~bayescalib.inference.gp.selection.fit_from_config` with its ``surrogate`` section,
so that the GP measured is the GP the study calibrates with) -- the prefix property of
:mod:`bayescalib.inference.design` makes the designs nested -- and its mean is compared
with the true log-likelihood at ``n_test`` held-out *later* points of the same Sobol sequence (indices
n_max .. n_max + n_test):

    l2_error  = || mean(X_test) - L(X_test) ||_2                (vector 2-norm)
    rmse      = l2_error / sqrt(n_test)
    rel_error = l2_error / || L(X_test) - mean(L(X_test)) ||_2   (relative to the spread of L)

As a cheap proxy that needs no extra solves, the closed-form leave-one-out
residuals alpha_i / [(K + sigma_n^2 I)^{-1}]_ii at fixed hyperparameters
(Rasmussen & Williams 2006, eq. 5.12) are summarized as ``loo_rmse`` and
``loo_rel_error`` (relative to the spread of the training values).

Non-finite L at test points (failed runs) are left out of the errors; their
number is reported as ``n_test_failed``.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from typing import Any

import numpy as np

from bayescalib.inference.design import sobol_design, sobol_test_points
from bayescalib.inference.gp import GPSurrogate, fit_from_config, surrogate_settings

__all__ = ["convergence_study", "convergence_study_function"]


def convergence_study(
    X: np.ndarray,
    y: np.ndarray,
    X_test: np.ndarray,
    y_test: np.ndarray,
    n_train_list: Sequence[int],
    fit: Callable[[np.ndarray, np.ndarray], GPSurrogate],
) -> dict[str, list]:
    """GP error against held-out data for nested training sets.

    Parameters
    ----------
    X, y
        (n_max, d), (n_max,) training pool in Sobol order; the first n rows are
        used for each n in ``n_train_list`` (non-finite y are excluded by the fit).
    X_test, y_test
        (n_test, d), (n_test,) held-out later Sobol points and their true L.
    n_train_list
        Increasing training sizes, each <= n_max.
    fit
        ``fit(X[:n], y[:n])`` -> the surrogate of n points (the study's:
        :func:`~bayescalib.inference.gp.selection.fit_from_config` with its settings).

    Returns
    -------
    dict of lists (one entry per n): ``n_train``, ``n_used``, ``n_excluded``,
    ``l2_error``, ``rmse``, ``rel_error``, ``loo_rmse``, ``loo_rel_error``,
    ``surrogate`` (the fitted GP's hyperparameters, what was chosen included), and the
    scalar ``n_test``, ``n_test_failed``.
    """
    X = np.asarray(X, float)
    y = np.asarray(y, float)
    X_test = np.asarray(X_test, float)
    y_test = np.asarray(y_test, float)
    ok = np.isfinite(y_test)
    Xt, yt = X_test[ok], y_test[ok]
    if yt.size == 0:
        raise ValueError("no finite test values")
    spread = float(np.linalg.norm(yt - yt.mean())) or 1.0
    out: dict[str, Any] = {k: [] for k in (
        "n_train", "n_used", "n_excluded", "l2_error", "rmse", "rel_error", "loo_rmse",
        "loo_rel_error", "surrogate"
    )}
    for n in n_train_list:
        n = int(n)
        if n > X.shape[0]:
            raise ValueError(f"n_train = {n} exceeds the training pool ({X.shape[0]} points)")
        gp = fit(X[:n], y[:n])
        err = gp.predict(Xt) - yt
        l2 = float(np.linalg.norm(err))
        loo = gp.loo_residuals()
        ytr = gp.loglik_train
        tr_spread = float(np.linalg.norm(ytr - ytr.mean())) or 1.0
        out["n_train"].append(n)
        out["n_used"].append(gp.n_train)
        out["n_excluded"].append(gp.n_excluded)
        out["l2_error"].append(l2)
        out["rmse"].append(l2 / np.sqrt(yt.size))
        out["rel_error"].append(l2 / spread)
        out["loo_rmse"].append(float(np.sqrt(np.mean(loo**2))))
        out["loo_rel_error"].append(float(np.linalg.norm(loo)) / tr_spread)
        out["surrogate"].append(gp.hyperparameters)
    out["n_test"] = int(y_test.size)
    out["n_test_failed"] = int((~ok).sum())
    return out


def convergence_study_function(
    loglik: Callable[[np.ndarray], np.ndarray],
    bounds: np.ndarray,
    n_train_list: Sequence[int],
    *,
    surrogate: Mapping[str, Any] | None = None,
    bound: float | None = None,
    n_test: int = 100,
    design_seed: int = 0,
) -> dict[str, list]:
    """:func:`convergence_study` for a cheap vectorized ``loglik`` (X (M, d) -> (M,)).

    Builds the Sobol training pool (first max(n_train_list) points) and the
    ``n_test`` later points of the same sequence, evaluates ``loglik`` on both, and
    fits :func:`~bayescalib.inference.gp.selection.fit_from_config` with the validated
    ``surrogate`` section (None: the schema's defaults,
    :func:`~bayescalib.inference.gp.selection.surrogate_settings`), the design box
    ``bounds`` and the log-likelihood's upper bound ``bound`` (None: unknown).
    """
    settings = dict(surrogate_settings() if surrogate is None else surrogate)
    n_max = int(max(n_train_list))
    X = sobol_design(bounds, n_max, design_seed)
    Xt = sobol_test_points(bounds, n_max, n_test, design_seed)
    return convergence_study(
        X, loglik(X), Xt, loglik(Xt), n_train_list,
        fit=lambda Xn, yn: fit_from_config(Xn, yn, settings, bounds, bound=bound))
