"""Gaussian static log-likelihood of a discrepancy (paper Sec. 2.3).

eq:staticlikeli / eq:loglik:

    log L = -n/2 log(2 pi sigma_N^2) - D^2 / (2 sigma_N^2)

with D the discrepancy of :mod:`bayescalib.measures` and n the number of
measurements: ``n_mp`` for the Euclidean measure, the number of model
interface nodes for the closest point projection, and 1 for the scalar RKHS
norm (see the justification in :mod:`bayescalib.measures`). Snapshots of an
observation set (e.g. one per flow rate) are conditionally independent, so
their log-likelihoods add. A failed or missing model snapshot (None), a
geometry the measure cannot evaluate, or a non-finite D give ``-inf``: the
value is never NaN.

Absolute check of the fit, the *fit check* (:func:`fit_check`; docs/glossary.md). The
likelihood states a noise model: with n measurements and the parameters at their true values,
D^2 / sigma_N^2 ~ chi2_n, so the misfit Phi = B - log L = D^2 / (2 sigma_N^2)
(B the bound at D = 0) is about n/2 +- sqrt(n/2). A surrogate can agree with
itself around a wrong mode; this check cannot be fooled that way: when even
the best solve misfits the data far more than the noise allows, either the
posterior mode has not been found, the model misses physics, or sigma_N is
smaller than the data's noise. It uses the likelihood's own assumptions only,
so it holds for every measure (for the RKHS norm n = 1 per snapshot).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:  # the measures (scipy.spatial) load with log_likelihood, not with the
    # noise settings that the study reads when the Snakefile is parsed
    from bayescalib.geometry.interface import Interface
    from bayescalib.io.observations import ObservationSet

__all__ = ["DEFAULT_SIGMA_N2", "FIT_P_VALUE", "fit_check", "gaussian_loglik", "log_likelihood",
           "sigma_n2_from_config"]

#: default noise variance sigma_N^2 in mm^2 (paper Sec. 4, later examples)
DEFAULT_SIGMA_N2 = 0.0005


def gaussian_loglik(D: float, n: int, sigma_n2: float) -> float:
    """eq:loglik: ``-n/2 log(2 pi sigma_n2) - D^2 / (2 sigma_n2)``.

    Parameters
    ----------
    D : float
        Discrepancy (mm, or the RKHS norm's units).
    n : int
        Number of measurements (>= 1).
    sigma_n2 : float
        Noise variance sigma_N^2 (> 0), in the squared units of D.

    Returns
    -------
    float
        The log-likelihood; ``-inf`` when D is NaN or infinite.
    """
    if not (isinstance(sigma_n2, (int, float)) and math.isfinite(sigma_n2) and sigma_n2 > 0):
        raise ValueError(f"sigma_n2 must be a positive finite number, got {sigma_n2!r}")
    if int(n) != n or n < 1:
        raise ValueError(f"the number of measurements n must be a positive integer, got {n!r}")
    D = float(D)
    if not math.isfinite(D):
        return -math.inf
    return -0.5 * n * math.log(2.0 * math.pi * sigma_n2) - D * D / (2.0 * sigma_n2)


def log_likelihood(
    model_snapshots: Sequence[Interface | None],
    observations: ObservationSet,
    measure: str,
    sigma_n2: float,
    **measure_options: Any,
) -> float:
    """Sum of eq:loglik over the snapshots of an observation set.

    Parameters
    ----------
    model_snapshots : sequence of Interface or None
        Model interface per observed snapshot, in the order of
        ``observations.snapshots``; None marks a failed forward solve.
    observations : ObservationSet
    measure : str
        "euclidean", "cpp" or "rkhs".
    sigma_n2 : float
        Noise variance (mm^2).
    **measure_options
        Passed to :func:`bayescalib.measures.compute`.

    Returns
    -------
    float
        Total log-likelihood, ``-inf`` if any snapshot failed or cannot be compared.

    Raises
    ------
    ValueError
        If the number of model snapshots differs from the observation set, or
        for bad options (unknown measure/option names, bad sigma_n2).
    """
    obs = list(observations.snapshots)
    models = list(model_snapshots)
    if len(models) != len(obs):
        raise ValueError(
            f"{len(models)} model snapshot(s) for {len(obs)} observed snapshot(s) "
            f"({', '.join(observations.labels)})"
        )
    if not (isinstance(sigma_n2, (int, float)) and math.isfinite(sigma_n2) and sigma_n2 > 0):
        raise ValueError(f"sigma_n2 must be a positive finite number, got {sigma_n2!r}")
    from bayescalib.geometry.interface import InterfaceError
    from bayescalib.measures import MeasureError, MeasureOptionError, compute

    total = 0.0
    failed = False
    for model, ob in zip(models, obs):
        if model is None:
            failed = True
            continue
        try:
            res = compute(measure, model, ob, **measure_options)
        except MeasureOptionError:
            raise
        except (MeasureError, InterfaceError):
            failed = True  # geometry the measure cannot evaluate (e.g. missed rays)
            continue
        total += gaussian_loglik(res.D, res.n, sigma_n2)
    return -math.inf if failed else total


#: upper-tail probability below which the best fit is called worse than the noise
FIT_P_VALUE = 1e-3


def fit_check(loglik: Sequence[float], bound: Sequence[float],
              n_measurements: Sequence[float]) -> dict[str, Any] | None:
    """Is the best solve's misfit what the likelihood's noise model expects?

    Parameters
    ----------
    loglik, bound, n_measurements
        Per solve (N,): the log-likelihood (-inf: failed), its bound B (the value at
        D = 0) and the number of measurements n summed over snapshots (NaN where
        unknown, e.g. tables of earlier runs).

    Returns
    -------
    dict or None
        None when no solve has all three values. Otherwise ``misfit_nats`` (B - L at
        the best solve), ``n_measurements``, ``expected_nats`` (n/2) and
        ``expected_sd_nats`` (sqrt(n/2)), ``p_value`` (upper tail of chi2_n at
        2 misfit), ``consistent`` (p >= :data:`FIT_P_VALUE`) and ``words``.
    """
    from scipy.stats import chi2

    L = np.asarray(loglik, float)
    B = np.asarray(bound, float)
    n = np.asarray(n_measurements, float)
    ok = np.isfinite(L) & np.isfinite(B) & np.isfinite(n) & (n >= 1)
    if not ok.any():
        return None
    idx = np.flatnonzero(ok)
    i = int(idx[np.argmax(L[idx])])
    misfit = max(float(B[i] - L[i]), 0.0)
    nm = int(n[i])
    p = float(chi2.sf(2.0 * misfit, nm))
    consistent = p >= FIT_P_VALUE
    expect = f"{nm / 2:.3g} +- {math.sqrt(nm / 2):.2g} nats for {nm} measurement(s)"
    if consistent:
        words = (f"the best solve fits the data as the likelihood's noise model expects "
                 f"(misfit {misfit:.3g} nats; noise alone gives {expect})")
    else:
        words = (f"the best solve misfits the data by {misfit:.3g} nats where the "
                 f"likelihood's noise model expects {expect} (p = {p:.1e}): the posterior "
                 "mode has not been found, or the model misses physics (run the diagnosis), "
                 "or sigma_N is smaller than the data's noise")
    return {"misfit_nats": misfit, "n_measurements": nm, "expected_nats": nm / 2,
            "expected_sd_nats": math.sqrt(nm / 2), "p_value": p,
            "consistent": bool(consistent), "words": words}


def sigma_n2_from_config(section: Mapping[str, Any]) -> float:
    """sigma_N^2 (mm^2) from a ``likelihood`` config section.

    ``sigma_n2`` when not null, else ``sigma_n ** 2``; when both are null the
    paper's 0.0005 mm^2. Giving both with ``sigma_n2 != sigma_n ** 2`` is an error.
    """
    s2 = section.get("sigma_n2")
    sn = section.get("sigma_n")
    for key, val in (("sigma_n2", s2), ("sigma_n", sn)):
        if val is not None and not (isinstance(val, (int, float)) and math.isfinite(val) and val > 0):
            raise ValueError(f"likelihood.{key} must be a positive number, got {val!r}")
    if s2 is not None and sn is not None and not math.isclose(float(s2), float(sn) ** 2, rel_tol=1e-9):
        raise ValueError(
            f"likelihood: sigma_n2 = {s2} and sigma_n = {sn} disagree (sigma_n^2 = {float(sn) ** 2}); give one"
        )
    if s2 is not None:
        return float(s2)
    if sn is not None:
        return float(sn) ** 2
    return DEFAULT_SIGMA_N2
