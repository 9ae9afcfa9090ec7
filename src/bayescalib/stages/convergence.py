"""Stage ``convergence`` (rule ``convergence``, ``scripts/convergence.py``): the error of
the GP surrogate over the number of training points, against the held-out Sobol points
of the training table (paper Sec. 4.3).

The GP of each size n is the study's surrogate fitted to the first n training points:
the same values (:func:`bayescalib.stages.surrogate.loglik_training_set`), bound and
``surrogate`` section; only the training size varies.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from bayescalib.stages.files import read_stage_file, write_json
from bayescalib.stages.surrogate import loglik_bound, loglik_training_set

__all__ = ["convergence"]


def convergence(training_path: str | Path, surrogate: Mapping[str, Any],
                parameters: Sequence[Mapping[str, Any]], n_train_list: Sequence[int],
                out_path: str | Path) -> dict[str, Any]:
    """GP convergence over n_train against the held-out Sobol points (paper Sec. 4.3).

    The GP of each n is the study's surrogate fitted to the first n training points: the
    values :func:`bayescalib.stages.surrogate.train_surrogate` fits
    (:func:`bayescalib.stages.surrogate.loglik_training_set`), the likelihood's bound of
    the whole table, and :func:`bayescalib.inference.gp.selection.fit_from_config`
    with the study's ``surrogate`` section (kernel, output, ard, frame, inputs, mean,
    nugget and the optimizer's settings, searched as the study's surrogate searches
    them); only the training size varies. At the full training set it is the study's
    surrogate. ``surrogate`` in the record: each n's hyperparameters."""
    from bayescalib.inference.convergence import convergence_study
    from bayescalib.inference.gp import fit_from_config
    from bayescalib.inference.parameters import ParameterSpace

    tab = read_stage_file(training_path, "training table")
    tr = tab["is_train"].astype(bool)
    X, L = loglik_training_set(tab)
    bounds = ParameterSpace.from_config(parameters).bounds
    bound = loglik_bound(tab, tr)
    settings = dict(surrogate)
    res = convergence_study(
        X, L, tab["X"][~tr], tab["loglik"][~tr], n_train_list=list(n_train_list),
        fit=lambda Xn, Ln: fit_from_config(Xn, Ln, settings, bounds, bound=bound))
    write_json(out_path, res)
    return res
